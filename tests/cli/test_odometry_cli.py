"""``simnav odometry`` and ``simnav eval`` on a tiny recording: trajectories written, metrics, one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import simnav.odometry
from simnav.cli import app
from simnav.geometry import se2
from simnav.io import read_carmen, read_tum, read_tum_covariance, sidecar_path
from simnav.odometry import OdometryEstimate

runner = CliRunner()


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A 2 s `simnav record` folder: groundtruth.txt, laser_front.clf, wheels.txt, robot.yaml."""
    out = tmp_path_factory.mktemp("rec") / "giraff"
    result = runner.invoke(app, ["record", "--duration", "2", "--no-cameras", "--agents", "0", "--robots", "0",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def simnav_cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "400"}  # one error line must stay one line however long the path
    return subprocess.run([sys.executable, "-m", "simnav.cli", *args], capture_output=True, text=True, timeout=120,
                          env=env)


def test_wheel_odometry_of_a_record_folder_writes_a_tum_trajectory(recording, tmp_path):
    out = tmp_path / "wheels" / "est.txt"
    result = runner.invoke(app, ["odometry", "wheels", str(recording), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "distance travelled" in result.output
    est = read_tum(out)
    wheel_lines = [line for line in (recording / "wheels.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(est) == len(wheel_lines) > 50
    np.testing.assert_allclose(est.T[0], np.eye(4), atol=1e-9)
    odom = read_carmen(recording / "laser_front.clf").odom  # the recorder logs the same dead reckoning
    np.testing.assert_allclose(est.T[:, :2, 3], odom.poses_xyt[:, :2], atol=2e-6)

    from_log = tmp_path / "from_log.txt"
    result = runner.invoke(app, ["odometry", "wheels", str(recording / "laser_front.clf"), "--out", str(from_log)])
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(read_tum(from_log).T, est.T, atol=2e-6)


def test_wheel_odometry_drive_overrides_and_default_run_folder(recording, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["odometry", "wheels", str(recording), "--set", "wheel_radius_m=0.15"])
    assert result.exit_code == 0, result.output
    runs = [p for p in (tmp_path / "runs").iterdir() if p.name != "latest"]
    assert len(runs) == 1 and runs[0].name.endswith("-odometry-wheels")
    assert (tmp_path / "runs" / "latest").resolve() == runs[0].resolve()
    doubled = read_tum(runs[0] / "est.txt")
    nominal = read_carmen(recording / "laser_front.clf").odom
    np.testing.assert_allclose(doubled.T[-1, 0, 3], 2 * nominal.poses_xyt[-1, 0], rtol=1e-4)

    bad = runner.invoke(app, ["odometry", "wheels", str(recording), "--set", "wheel_radius=0.1"])
    assert bad.exit_code == 2 and "wheel_radius_m" in bad.output


def test_eval_of_the_ground_truth_against_itself_is_zero(recording, tmp_path):
    plot, report = tmp_path / "eval.png", tmp_path / "eval.json"
    gt = recording / "groundtruth.txt"
    result = runner.invoke(app, ["eval", str(gt), str(recording), "--plot", str(plot), "--json", str(report)])
    assert result.exit_code == 0, result.output
    assert "RPE translation" in result.output and "ATE" in result.output
    metrics = json.loads(report.read_text())
    assert metrics["rpe"]["pairs"] > 10 and metrics["ate"]["pairs"] == len(read_tum(gt))
    for key in ("trans_rmse_cm_s", "rot_rmse_deg_s"):
        assert metrics["rpe"][key] == pytest.approx(0.0, abs=1e-9)
    assert metrics["ate"]["rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert plot.read_bytes()[:4] == b"\x89PNG"


def test_eval_of_wheel_odometry_against_carmen_truepos(recording, tmp_path):
    est = tmp_path / "est.txt"
    assert runner.invoke(app, ["odometry", "wheels", str(recording), "--out", str(est)]).exit_code == 0
    report = tmp_path / "m.json"
    result = runner.invoke(app, ["eval", str(tmp_path), str(recording / "laser_front.clf"), "--json", str(report),
                                 "--delta", "0.5"])
    assert result.exit_code == 0, result.output
    metrics = json.loads(report.read_text())
    assert metrics["ground_truth"].endswith("laser_front.clf") and metrics["rpe"]["delta_s"] == 0.5
    assert 0 < metrics["ate"]["rmse_m"] < 0.05  # wheel slip over 2 s: millimetres


def test_eval_of_a_missing_file_is_one_clear_line(recording, tmp_path):
    missing = tmp_path / "no_such_estimate.txt"
    result = simnav_cli("eval", str(missing), str(recording))
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and str(missing) in lines[0], result.stderr
    assert "Traceback" not in result.stderr + result.stdout

    result = simnav_cli("eval", str(recording / "groundtruth.txt"), str(tmp_path / "no_gt"))
    assert result.returncode == 2 and "no_gt" in result.stderr and "Traceback" not in result.stderr


def test_eval_of_trajectories_that_do_not_overlap_names_both(recording, tmp_path):
    late = tmp_path / "late.txt"
    gt = read_tum(recording / "groundtruth.txt")
    lines = [f"{t + 1000:.6f} {T[0, 3]:.6f} {T[1, 3]:.6f} 0 0 0 0 1" for t, T in zip(gt.stamps_s, gt.T)]
    late.write_text("\n".join(lines) + "\n")
    result = runner.invoke(app, ["eval", str(late), str(recording)])
    assert result.exit_code == 2
    text = " ".join(result.output.split())
    assert "do not overlap in time" in text and "late.txt" in text


def test_unknown_method_lists_the_available_ones(recording):
    result = runner.invoke(app, ["odometry", "icp", str(recording)])
    assert result.exit_code == 2
    text = " ".join(result.output.split())
    assert "unknown odometry method 'icp'" in text and "rf2o, srf, wheels" in text


def test_missing_input_and_bad_format_are_user_errors(recording, tmp_path):
    result = runner.invoke(app, ["odometry", "wheels", str(tmp_path / "nothing")])
    assert result.exit_code == 2 and "nothing" in result.output
    result = runner.invoke(app, ["odometry", "wheels", str(recording), "--format", "kitti"])
    assert result.exit_code == 2 and "--format" in result.output


class ReplayOdometry:
    """A stand-in scan odometry: replays the logged odometry poses, one unobservable direction every 5th scan."""

    def __init__(self, poses_xyt: np.ndarray, scale: float = 1.0) -> None:
        self._poses, self._scale, self._k = poses_xyt, scale, 0

    def process(self, scan) -> OdometryEstimate:
        x, y, yaw = self._poses[self._k]
        degenerate = self._k % 5 == 4
        cov = np.diag([1e-4, np.inf if degenerate else 1e-4, 1e-6])
        self._k += 1
        return OdometryEstimate(scan.stamp_s, se2.from_xy_yaw(self._scale * x, self._scale * y, yaw), np.zeros(3),
                                cov, degenerate=degenerate, valid_points=int((scan.ranges_m > 0).sum()))

    def reset(self) -> None:
        self._k = 0


def test_scan_odometry_pipeline_writes_poses_covariances_and_summary(recording, tmp_path, monkeypatch):
    log = read_carmen(recording / "laser_front.clf")
    made = {}

    def make(name: str, **config) -> ReplayOdometry:
        made.update(name=name, config=config)
        return ReplayOdometry(log.robot_poses, **config)

    monkeypatch.setitem(simnav.odometry.SCAN_ODOMETRIES, "replay", "never.imported:ReplayOdometry")
    monkeypatch.setattr(simnav.odometry, "make_scan_odometry", make)
    out = tmp_path / "est.txt"
    result = runner.invoke(app, ["odometry", "replay", str(recording), "--out", str(out), "--set", "scale=1.0"])
    assert result.exit_code == 0, result.output
    assert made == {"name": "replay", "config": {"scale": 1.0}}
    text = " ".join(result.output.split())
    for row in ("scans", "valid scans", "degenerate scans", "runtime per scan", "distance travelled"):
        assert row in text
    est = read_tum(out)
    assert len(est) == len(log.scans)
    np.testing.assert_allclose(est.stamps_s, [s.stamp_s for s in log.scans])
    stamps, covs = read_tum_covariance(sidecar_path(out))
    assert covs.shape == (len(log.scans), 3, 3) and np.isfinite(covs).all()
    assert covs[4, 1, 1] == pytest.approx(1e12) and covs[3, 1, 1] == pytest.approx(1e-4)
    evaluated = runner.invoke(app, ["eval", str(out), str(recording)])
    assert evaluated.exit_code == 0, evaluated.output


def test_a_scan_odometry_that_is_not_installed_is_one_clear_error(recording, monkeypatch):
    monkeypatch.setitem(simnav.odometry.SCAN_ODOMETRIES, "ghost", "simnav.odometry.ghost:Ghost")
    result = runner.invoke(app, ["odometry", "ghost", str(recording)])
    assert result.exit_code == 2
    assert "odometry 'ghost' is not available" in " ".join(result.output.split())
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_rf2o_on_the_recording(recording, tmp_path):
    pytest.importorskip("simnav.odometry.rf2o")
    out = tmp_path / "rf2o" / "est.txt"
    result = runner.invoke(app, ["odometry", "rf2o", str(recording), "--out", str(out)])
    assert result.exit_code == 0, result.output
    est = read_tum(out)
    assert len(est) == len(read_carmen(recording / "laser_front.clf").scans)
    assert sidecar_path(out).is_file()
    evaluated = runner.invoke(app, ["eval", str(out), str(recording)])
    assert evaluated.exit_code == 0, evaluated.output
