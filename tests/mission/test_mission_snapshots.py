"""scripts/mission_snapshots.py: a mission replayed from its folder is the same run, drawn at the chosen times."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simnav.io import read_tum

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "mission_snapshots.py"
MISSION = ["--world", "office", "--agents", "3", "--robots", "1", "--duration", "6", "--seed", "2"]


def _script():
    spec = importlib.util.spec_from_file_location("mission_snapshots", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def mission_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("snapshots") / "run"
    result = subprocess.run([sys.executable, "-m", "simnav.cli", "mission", *MISSION, "--out", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return out


def test_the_replay_is_the_recorded_mission(mission_dir) -> None:
    recorder, _, _ = _script().replay(mission_dir, [2.0, 5.0])
    gt = read_tum(mission_dir / "trajectory_gt.txt")
    assert [round(v.time_s, 2) for v in recorder.views] == [2.0, 5.0]
    for view in recorder.views:
        k = int(np.argmin(np.abs(gt.stamps_s - view.time_s)))
        assert np.allclose(view.T_world_base[:2, 2], gt.T[k][:2, 3], atol=1e-6)  # the same run, not a similar one
        assert view.people_xy.shape == (3, 2) and view.robots_xy.shape == (1, 2) and view.leaves.shape == (8, 2, 2)
        assert len(view.waypoints) >= 1 and view.state in {"navigating", "turning", "squeezing", "reached", "yielding",
                                                            "waiting", "recovering", "blocked"}


def test_the_views_are_drawn_and_bad_input_is_one_line(mission_dir, tmp_path) -> None:
    png = tmp_path / "views.png"
    result = subprocess.run([sys.executable, str(SCRIPT), str(mission_dir), "--times", "1", "3", "--out", str(png)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "2 views" in result.stdout and png.stat().st_size > 20_000
    no_intervention = subprocess.run([sys.executable, str(SCRIPT), str(mission_dir)], capture_output=True, text=True)
    assert no_intervention.returncode == 1 and "has 0 intervention(s)" in no_intervention.stderr
    assert "Traceback" not in no_intervention.stderr
    missing = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert missing.returncode == 1 and "world.yaml: not found" in missing.stderr


def test_a_replay_that_leaves_the_recorded_run_is_drawn_with_a_warning(mission_dir, tmp_path) -> None:
    # the same folder, its recorded trajectory moved 0.3 m along x from 2 s on (as if other code had run it)
    moved = tmp_path / "moved"
    moved.mkdir()
    for f in ("world.yaml", "robot.yaml", "mission.yaml", "report.json"):
        (moved / f).write_text((mission_dir / f).read_text())
    lines = []
    for line in (mission_dir / "trajectory_gt.txt").read_text().splitlines():
        cols = line.split()
        if cols and not line.startswith("#") and float(cols[0]) >= 2.0:
            cols[1] = f"{float(cols[1]) + 0.3:.6f}"
        lines.append(" ".join(cols))
    (moved / "trajectory_gt.txt").write_text("\n".join(lines) + "\n")
    script = _script()
    recorder, _, _ = script.replay(mission_dir, [1.0, 3.0])
    assert script.divergence(mission_dir, recorder.views) is None
    time_s, distance_m = script.divergence(moved, recorder.views)
    assert time_s == pytest.approx(3.0) and distance_m == pytest.approx(0.3, abs=1e-3)
    result = subprocess.run([sys.executable, str(SCRIPT), str(moved), "--times", "1", "3", "--out",
                             str(tmp_path / "v.png")], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and "2 views" in result.stdout
    assert "warning: the replay is not the recorded run: at 3.0 s" in result.stderr
