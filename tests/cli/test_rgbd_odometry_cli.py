"""``simnav odometry difodo|vosf`` on a tiny TUM RGB-D folder: trajectory, scene flow files, one-line errors.

The folder is written with :class:`RGBDDatasetWriter` from a pure-numpy ray cast of a textured 6 x 5 x 2.8 m box
room with a few boxes: 12 QQVGA frames at 30 Hz from a camera that moves 1.5 cm forward and turns 0.6 deg per frame,
with its optical-frame ground truth in groundtruth.txt (the layout `simnav record` writes for each camera).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from simnav.cli import app
from simnav.geometry import se3
from simnav.geometry.camera import R_BODY_OPTICAL, box_room_depth
from simnav.io import RGBDDatasetWriter, TumWriter, read_tum, read_tum_covariance, sidecar_path
from simnav.sensors.readings import RGBDFrame

runner = CliRunner()
H, W, FRAMES, DT_S = 120, 160, 12, 1.0 / 30.0
K = np.array([[131.25, 0.0, (W - 1) / 2], [0.0, 131.25, (H - 1) / 2], [0.0, 0.0, 1.0]])  # 525 px at VGA
ROOM = np.array([[-3.0, -2.5, 0.0], [3.0, 2.5, 2.8]])
BOXES = np.array([[[1.5, -1.8, 0.0], [2.3, -0.9, 0.9]], [[2.0, 0.5, 0.0], [2.9, 1.6, 1.6]],
                  [[0.8, -0.2, 0.0], [1.1, 0.3, 1.2]], [[1.2, 0.9, 1.0], [1.6, 1.3, 1.4]]])
T_BASE_CAMERA = se3.from_rotation_translation(R_BODY_OPTICAL, [0.1, 0.0, 1.0])


def _render(T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 z-depth (m) and (H, W, 3) uint8 colour (a 0.25 m 3D checker) seen from an optical frame."""
    depth, hit = box_room_depth(T_world_camera, K, (H, W), ROOM, BOXES)
    checker = np.floor(hit / 0.25 + 1e-6).astype(np.int64).sum(axis=-1) % 2
    grey = (70 + 110 * checker + 40 * np.cos(hit[..., 0] + 2 * hit[..., 1])).clip(0, 255).astype(np.uint8)
    return depth.astype(np.float32), np.repeat(grey[..., None], 3, axis=-1)


def _write_dataset(root: Path) -> list[np.ndarray]:
    """Writes the sequence into ``root``; returns the optical-frame poses T_world_camera."""
    T_base = se3.from_rpy(0.0, 0.0, math.radians(8.0), [-2.2, 0.2, 0.0])
    step = se3.exp(np.array([0.45, 0.0, 0.0, 0.0, 0.0, math.radians(18.0)]) * DT_S)  # base twist, 30 Hz
    poses = []
    with RGBDDatasetWriter(root) as rgbd, TumWriter(root / "groundtruth.txt") as gt:
        for i in range(FRAMES):
            T = T_base @ T_BASE_CAMERA
            depth, rgb = _render(T)
            stamp = 1000.0 + i * DT_S
            rgbd.write_frame(RGBDFrame("camera", stamp, depth, rgb, K, T_BASE_CAMERA))
            gt.write(stamp, T)
            poses.append(T)
            T_base = T_base @ step
    return poses


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    """A `simnav record`-like folder holding one camera: (record folder, optical poses); the camera is rec/camera."""
    record = tmp_path_factory.mktemp("rgbd") / "rec"
    poses = _write_dataset(record / "camera")
    return record, poses


def _lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.strip()]


def test_difodo_writes_one_camera_pose_per_frame(dataset, tmp_path):
    record, poses = dataset
    folder = record / "camera"
    out = tmp_path / "difodo" / "est.txt"
    result = runner.invoke(app, ["odometry", "difodo", str(folder), "--out", str(out)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    for row in ("frames", "frames aligned", "runtime per frame", "camera optical frame", "distance travelled"):
        assert row in text
    est, gt = read_tum(out), read_tum(folder / "groundtruth.txt")
    assert len(est) == FRAMES
    np.testing.assert_allclose(est.stamps_s, gt.stamps_s, atol=1e-6)
    np.testing.assert_allclose(est.T[0], np.eye(4), atol=1e-9)
    # the camera pose relative to the first frame, as in groundtruth.txt (0.165 m and 6.6 deg over the run)
    error = se3.log(se3.inverse(se3.inverse(poses[0]) @ poses[-1]) @ est.T[-1])
    assert np.linalg.norm(error[:3]) < 0.02 and math.degrees(np.linalg.norm(error[3:])) < 1.0
    stamps, covs = read_tum_covariance(sidecar_path(out))
    assert covs.shape == (FRAMES, 6, 6) and np.isfinite(covs).all()

    evaluated = runner.invoke(app, ["eval", str(out), str(folder), "--delta", "0.2"])
    assert evaluated.exit_code == 0, evaluated.output
    assert "RPE translation" in evaluated.output


def test_difodo_finds_the_camera_of_a_record_folder_and_writes_base_poses(dataset, tmp_path):
    record, poses = dataset
    out = tmp_path / "est.txt"
    result = runner.invoke(app, ["odometry", "difodo", str(record), "--out", str(out), "--base",
                                 "--set", "max_rows=60"])
    assert result.exit_code == 0, result.output
    assert "the base (T_odom_base)" in " ".join(result.output.split())
    est = read_tum(out)
    assert len(est) == FRAMES
    # base poses: the base moves along its own x axis and turns about z
    T_true = T_BASE_CAMERA @ se3.inverse(poses[0]) @ poses[-1] @ se3.inverse(T_BASE_CAMERA)
    assert np.linalg.norm(est.T[-1][:3, 3] - T_true[:3, 3]) < 0.03

    chosen = runner.invoke(app, ["odometry", "difodo", str(record), "--camera", "camera", "--out", str(out)])
    assert chosen.exit_code == 0, chosen.output


def test_vosf_writes_poses_and_scene_flow(dataset, tmp_path):
    pytest.importorskip("simnav.odometry.vosf")
    record, _ = dataset
    folder = record / "camera"
    out, flow = tmp_path / "est.txt", tmp_path / "flow"
    result = runner.invoke(app, ["odometry", "vosf", str(folder), "--out", str(out), "--flow-out", str(flow)])
    assert result.exit_code == 0, result.output
    assert "moving pixels" in " ".join(result.output.split())
    assert len(read_tum(out)) == FRAMES
    index = [line.split() for line in (flow / "flow.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(index) == FRAMES and all(len(row) == 4 for row in index)
    scene_flow = np.load(flow / index[-1][1])
    labels, moving = np.load(flow / index[-1][2]), np.load(flow / index[-1][3])
    assert scene_flow.shape == (3, H, W) and scene_flow.dtype == np.float32
    assert labels.shape == (H, W) and labels.dtype == np.int32 and moving.shape == (H, W) and moving.dtype == bool
    assert np.isfinite(scene_flow).mean() > 0.5  # a static scene: flow measured (and small) almost everywhere
    assert np.nanmax(np.abs(scene_flow)) < 0.05
    assert np.all(np.isnan(np.load(flow / index[0][1])))  # nothing to compare the first frame with
    clusters = [line.split() for line in (flow / "clusters.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(clusters) == FRAMES and len(clusters[-1]) > 2


def test_bad_inputs_are_one_line_errors(dataset, tmp_path):
    record, _ = dataset
    empty = tmp_path / "empty"
    empty.mkdir()
    a_file = tmp_path / "notes.txt"
    a_file.write_text("hello\n")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "depth.txt").write_text("# depth\n1.0 depth/1.0.png extra\n")
    cases = [
        (["odometry", "difodo", str(tmp_path / "nothing")], "input not found"),
        (["odometry", "difodo", str(empty)], "no depth.txt here or in a camera subfolder"),
        (["odometry", "vosf", str(a_file)], "got a file"),
        (["odometry", "difodo", str(broken)], "depth.txt:2"),
        (["odometry", "difodo", str(record), "--camera", "kinect"], "no camera 'kinect'"),
        (["odometry", "difodo", str(record), "--flow-out", str(tmp_path / "f")], "--flow-out"),
        (["odometry", "difodo", str(record), "--set", "max_rowz=120"], "max_rowz"),
        (["odometry", "difodo", str(record), "--laser", "laser_front"], "--laser does not apply"),
        (["odometry", "rf2o", str(record), "--camera", "camera"], "--camera does not apply"),
    ]
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        lines = _lines(result.output)
        assert len(lines) == 1 and message in lines[0], (args, result.output)
        assert result.exception is None or isinstance(result.exception, SystemExit)


def test_unknown_method_lists_planar_and_rgbd_methods(dataset):
    record, _ = dataset
    result = runner.invoke(app, ["odometry", "orb", str(record)])
    assert result.exit_code == 2
    assert "rf2o, srf, wheels, difodo, vosf" in " ".join(result.output.split())


def test_frame_odometry_registry_loads_its_modules_on_demand():
    import subprocess
    import sys

    code = ("import sys, simnav.odometry as o\n"
            "before = 'simnav.odometry.difodo' in sys.modules\n"
            "print(before, o.DIFODO.__name__, type(o.make_frame_odometry('difodo', max_rows=120)).__name__)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["False", "DIFODO", "DIFODO"]

    from simnav.errors import ConfigError, UnknownNameError
    from simnav.odometry import FRAME_ODOMETRIES, make_frame_odometry

    assert set(FRAME_ODOMETRIES) == {"difodo", "vosf"}
    with pytest.raises(UnknownNameError, match="available: difodo, vosf"):
        make_frame_odometry("orb")
    with pytest.raises(ConfigError, match="max_rowz"):
        make_frame_odometry("difodo", max_rowz=120)
