"""The simnav command line: listing, recording, and one clear error (exit code 2, no traceback) on bad input."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from simnav.cli import app
from simnav.io import RGBDDataset, read_carmen, read_tum

runner = CliRunner()
FAST = ["--set", "sensors.camera.preset=kinect_qqvga", "--set", "sensors.camera.rate_hz=10"]


def simnav(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simnav.cli", *args], capture_output=True, text=True, timeout=300)


def test_listing_commands():
    for command, expected in (("worlds", "office"), ("robots", "rhodon"), ("version", "mujoco")):
        result = runner.invoke(app, [command])
        assert result.exit_code == 0, result.output
        assert expected in result.output


def test_unknown_world_is_one_clear_error_without_traceback():
    result = simnav("record", "--world", "atlantis", "--duration", "1")
    assert result.returncode == 2
    assert "unknown world 'atlantis'" in result.stderr and "office" in result.stderr
    assert "Traceback" not in result.stderr + result.stdout


def test_malformed_robot_yaml_names_the_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("prisms:\n  - {name: base, z_min_m: 0, z_max_m: 0.3, polygon: [[0, 0], [1, 0]]}\n")
    result = simnav("record", "--robot", str(bad), "--duration", "1")
    assert result.returncode == 2
    assert str(bad) in result.stderr and "prisms.0.polygon" in result.stderr
    assert "Traceback" not in result.stderr


def test_bad_override_is_reported():
    result = runner.invoke(app, ["record", "--duration", "1", "--set", "sensors.camera.rate_hz=-3"])
    assert result.exit_code == 2
    assert "rate_hz" in result.output


def tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_record_writes_a_usable_dataset_and_same_seed_same_bytes(tmp_path):
    args = ["record", "--duration", "2", "--agents", "4", "--seed", "5", *FAST]
    first = runner.invoke(app, [*args, "--out", str(tmp_path / "a")])
    assert first.exit_code == 0, first.output
    second = runner.invoke(app, [*args, "--out", str(tmp_path / "b")])
    assert second.exit_code == 0, second.output
    a, b = tree_digest(tmp_path / "a"), tree_digest(tmp_path / "b")
    assert a == b
    root = tmp_path / "a"
    for name in ("groundtruth.txt", "laser_front.clf", "wheels.txt", "camera/rgb.txt", "camera/depth.txt",
                 "camera/camera.yaml", "camera/groundtruth.txt", "record.yaml", "world.yaml", "robot.yaml"):
        assert (root / name).is_file(), name
    gt = read_tum(root / "groundtruth.txt")
    assert len(gt) == 41 and gt.stamps_s[-1] == pytest.approx(2.0)
    log = read_carmen(root / "laser_front.clf")
    assert len(log.scans) == 21 and len(log.truepos.stamps_s) == 21
    assert len(log.scans[0].ranges_m) == 682
    dataset = RGBDDataset(root / "camera")
    assert len(dataset) == 21
    frame = dataset[3]
    assert frame.depth_m.shape == (120, 160) and frame.rgb.shape == (120, 160, 3)
    assert np.isfinite(frame.depth_m).all() and (frame.depth_m > 0).mean() > 0.5
    assert dataset.groundtruth is not None and len(dataset.groundtruth) == 21
    different = runner.invoke(app, [*args[:-6], "--seed", "6", *FAST, "--out", str(tmp_path / "c")])
    assert different.exit_code == 0
    assert tree_digest(tmp_path / "c")["groundtruth.txt"] != a["groundtruth.txt"] or \
        tree_digest(tmp_path / "c")["laser_front.clf"] != a["laser_front.clf"]
