"""TUM RGB-D dataset layout: writer/reader round trip, determinism, association, camera.yaml."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from simnav.io import (
    TUM_FR1_K,
    DataFormatError,
    MissingDataError,
    RGBDDataset,
    RGBDDatasetWriter,
    TumWriter,
    load_pixel_motion,
)
from simnav.sensors.readings import RGBDFrame

H, W = 48, 64
K = np.array([[80.5, 0.0, 31.75], [0.0, 81.25, 23.5], [0.0, 0.0, 1.0]])
T_BASE_CAM = np.array(
    [[0.0, 0.0, 1.0, 0.25], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.8], [0.0, 0.0, 0.0, 1.0]]
)


def _frame(stamp: float, seed: int, *, rgb: bool = True, sim: bool = True) -> RGBDFrame:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.3, 8.0, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.1] = 0.0
    depth[0, 0] = np.nan
    depth[0, 1] = np.inf
    return RGBDFrame(
        sensor="rgbd_front",
        stamp_s=stamp,
        depth_m=depth,
        rgb=rng.integers(0, 256, (H, W, 3), dtype=np.uint8) if rgb else None,
        K=K,
        T_base_sensor=T_BASE_CAM,
        body_id=rng.integers(-1, 7, (H, W)).astype(np.int32) if sim else None,
        velocity_optical=rng.normal(size=(3, H, W)).astype(np.float32) if sim else None,
    )


def _frames() -> list[RGBDFrame]:
    frames = [_frame(1305031102.175304 + k / 30.0, seed=k) for k in range(3)]
    return frames + [_frame(1305031102.3, 9, rgb=False)]


def _write(root, frames) -> None:
    with RGBDDatasetWriter(root) as w:
        for f in frames:
            w.write_frame(f)


def test_round_trip(tmp_path):
    frames = _frames()
    _write(tmp_path / "seq", frames)
    ds = RGBDDataset(tmp_path / "seq")
    assert len(ds) == 4
    for src, got in zip(frames, ds, strict=True):
        assert got.stamp_s == pytest.approx(src.stamp_s, abs=1e-6)
        assert got.sensor == "rgbd_front"
        assert got.depth_m.dtype == np.float32 and got.depth_m.shape == (H, W)
        ok = np.isfinite(src.depth_m) & (src.depth_m > 0)
        np.testing.assert_array_equal(got.depth_m > 0, ok)
        np.testing.assert_allclose(got.depth_m[ok], src.depth_m[ok], atol=2e-4)  # 1/5000 m quantisation
        np.testing.assert_array_equal(got.K, K)
        np.testing.assert_array_equal(got.T_base_sensor, T_BASE_CAM)
        np.testing.assert_array_equal(got.body_id, src.body_id)
        np.testing.assert_array_equal(got.velocity_optical, src.velocity_optical)
        assert got.velocity_optical.dtype == np.float32
        if src.rgb is None:
            assert got.rgb is None
        else:
            assert got.rgb.dtype == np.uint8
            np.testing.assert_array_equal(got.rgb, src.rgb)


def test_index_files_follow_tum_layout(tmp_path):
    root = tmp_path / "rgbd_dataset_sim_office"
    _write(root, _frames())
    rgb = (root / "rgb.txt").read_text().splitlines()
    assert rgb[:3] == ["# color images", "# file: 'rgbd_dataset_sim_office'", "# timestamp filename"]
    assert rgb[3] == "1305031102.175304 rgb/1305031102.175304.png"
    assert len(rgb) == 3 + 3  # the depth-only frame has no rgb line
    depth = (root / "depth.txt").read_text().splitlines()
    assert depth[0] == "# depth maps" and len(depth) == 3 + 4
    assert depth[-1] == "1305031102.300000 depth/1305031102.300000.png"
    assert (root / "segmentation/1305031102.175304.png").is_file()
    assert (root / "motion/1305031102.175304.npz").is_file()
    motion = (root / "motion.txt").read_text().splitlines()
    assert motion[3] == "1305031102.175304 motion/1305031102.175304.npz"
    raw = np.load(root / "motion/1305031102.175304.npz")
    assert list(raw.keys()) == ["shape", "pixels", "velocity_optical"]  # only the moving pixels are stored
    assert tuple(raw["shape"]) == (3, H, W) and raw["velocity_optical"].shape == (len(raw["pixels"]), 3)


def test_two_writes_give_byte_identical_trees(tmp_path):
    for name in ("a", "b"):
        _write(tmp_path / name / "seq", _frames())
        with TumWriter(tmp_path / name / "seq" / "groundtruth.txt") as gt:
            gt.write(1305031102.175304, T_BASE_CAM)

    def tree(root):
        files = sorted(p for p in root.rglob("*") if p.is_file())
        return {p.relative_to(root).as_posix(): p.read_bytes() for p in files}

    a, b = tree(tmp_path / "a"), tree(tmp_path / "b")
    assert len(a) == 4 + 2 + 4 + 3 + 4 * 2  # 4 indexes, camera.yaml + groundtruth, depth, rgb, seg + motion
    assert a.keys() == b.keys()
    assert all(a[k] == b[k] for k in a)


def test_camera_yaml_and_groundtruth(tmp_path):
    root = tmp_path / "seq"
    _write(root, _frames()[:1])
    with TumWriter(root / "groundtruth.txt") as gt:
        gt.write(1.0, T_BASE_CAM)
    import yaml

    cam = yaml.safe_load((root / "camera.yaml").read_text())
    assert (cam["width"], cam["height"]) == (W, H)
    assert (cam["fx"], cam["fy"], cam["cx"], cam["cy"]) == (80.5, 81.25, 31.75, 23.5)
    assert cam["depth_scale"] == 5000.0
    np.testing.assert_array_equal(cam["T_base_camera"], T_BASE_CAM)
    ds = RGBDDataset(root)
    np.testing.assert_array_equal(ds.K, K)
    assert ds.groundtruth is not None and len(ds.groundtruth) == 1


def test_missing_camera_yaml_uses_tum_defaults(tmp_path, caplog):
    root = tmp_path / "seq"
    _write(root, _frames()[:2])
    (root / "camera.yaml").unlink()
    with caplog.at_level(logging.WARNING):
        ds = RGBDDataset(root)
    assert "camera.yaml" in caplog.text
    np.testing.assert_array_equal(ds[0].K, TUM_FR1_K)
    np.testing.assert_array_equal(TUM_FR1_K[[0, 1, 0, 1], [0, 1, 2, 2]], [517.3, 516.5, 318.6, 255.3])


def _index(path, stamps, folder):
    lines = ["# header", "# file: 'x'", "# timestamp filename"]
    lines += [f"{s:.6f} {folder}/{s:.6f}.png" for s in stamps]
    path.write_text("\n".join(lines) + "\n")


def test_association_with_jittered_stamps(tmp_path):
    rng = np.random.default_rng(7)
    n = 40
    depth = 100.0 + np.arange(n) / 30.0 + rng.uniform(-0.003, 0.003, n)
    rgb = 100.0 + np.arange(n) / 30.0 + 0.006 + rng.uniform(-0.003, 0.003, n)
    keep = np.ones(n, bool)
    keep[[5, 17, 18]] = False  # dropped colour frames
    rgb = rgb[keep]
    _index(tmp_path / "depth.txt", depth, "depth")
    _index(tmp_path / "rgb.txt", rgb, "rgb")
    ds = RGBDDataset(tmp_path)
    pairs = ds.associate(max_dt_s=0.012)
    rgb_of_depth = np.cumsum(keep) - 1
    expected = [(i, int(rgb_of_depth[i])) for i in range(n) if keep[i]]
    assert pairs == expected
    assert len(ds) == n  # unpaired depth images stay, with rgb=None
    assert len(RGBDDataset(tmp_path, max_dt_s=0.012, require_rgb=True)) == n - 3
    np.testing.assert_allclose(ds.depth_stamps_s, depth, atol=1e-6)


def test_association_is_greedy_one_to_one(tmp_path):
    # both depth stamps are closest to rgb 1.010; the closer one (1.008) wins, the other takes the next best
    _index(tmp_path / "depth.txt", [1.000, 1.008], "depth")
    _index(tmp_path / "rgb.txt", [0.985, 1.010], "rgb")
    ds = RGBDDataset(tmp_path)
    assert ds.associate(max_dt_s=0.02) == [(0, 0), (1, 1)]
    assert ds.associate(max_dt_s=0.012) == [(1, 1)]


def test_errors_name_the_file(tmp_path):
    with pytest.raises(MissingDataError, match="nothere"):
        RGBDDataset(tmp_path / "nothere")
    with pytest.raises(MissingDataError, match="depth.txt"):
        RGBDDataset(tmp_path)
    (tmp_path / "depth.txt").write_text("# depth maps\n1.0 depth/1.0.png\n2.0\n")
    with pytest.raises(DataFormatError, match=r"depth\.txt:3: expected 'timestamp filename'"):
        RGBDDataset(tmp_path)
    (tmp_path / "depth.txt").write_text("1.0 depth/1.0.png\n")
    ds = RGBDDataset(tmp_path)
    with pytest.raises(MissingDataError, match=r"depth/1\.0\.png"):
        ds[0]
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DataFormatError, match="junk.npz"):
        load_pixel_motion(tmp_path / "junk.npz")


def test_writer_refuses_existing_dataset_and_duplicate_stamps(tmp_path):
    _write(tmp_path / "seq", _frames()[:1])
    with pytest.raises(DataFormatError, match="overwrite=True"):
        RGBDDatasetWriter(tmp_path / "seq")
    with RGBDDatasetWriter(tmp_path / "seq", overwrite=True) as w:
        w.write_frame(_frame(5.0, 1))
        with pytest.raises(DataFormatError, match="already written"):
            w.write_frame(_frame(5.0, 2))
        with pytest.raises(DataFormatError, match="differs"):
            small = _frame(6.0, 3)
            w.write_frame(RGBDFrame("c", 6.0, small.depth_m[:10], None, K, T_BASE_CAM))
    assert len(RGBDDataset(tmp_path / "seq")) == 1


def test_depth_encoding_clips_and_rounds(tmp_path):
    depth = np.array([[0.0, -1.0, 1e-5, 0.0001, 1.23456, 20.0]], dtype=np.float32)
    frame = RGBDFrame("c", 1.0, depth, None, K, np.eye(4))
    _write(tmp_path / "s", [frame])
    got = RGBDDataset(tmp_path / "s")[0].depth_m
    np.testing.assert_allclose(got, [[0.0, 0.0, 0.0, 0.0, 1.2346, 65535 / 5000]], atol=1e-6)


def test_writer_rejects_out_of_range_body_ids(tmp_path):
    frame = _frame(1.0, 0)
    bad = RGBDFrame("c", 1.0, frame.depth_m, None, K, T_BASE_CAM, body_id=np.full((H, W), 70000, np.int32))
    with RGBDDatasetWriter(tmp_path / "s") as w:
        with pytest.raises(DataFormatError, match=r"body ids must lie in \[-1, 65534\]"):
            w.write_frame(bad)
    assert not (tmp_path / "s" / "depth").exists()  # nothing half-written
