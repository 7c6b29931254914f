"""TUM trajectory files: round trip, covariance sidecar, streaming writer, errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from simnav.io import (
    DataFormatError,
    MissingDataError,
    TumWriter,
    read_tum,
    read_tum_covariance,
    sidecar_path,
    write_tum,
)


def _poses(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    stamps = 1305031102.175304 + np.cumsum(rng.uniform(0.02, 0.05, n))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.uniform(-20.0, 20.0, (n, 3))
    return stamps, T


def _spd(n: int, dim: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, dim, dim)) * 1e-2
    return A @ A.transpose(0, 2, 1) + 1e-6 * np.eye(dim)


def test_round_trip_poses_within_micrometres(tmp_path):
    stamps, T = _poses(50)
    path = tmp_path / "est.txt"
    write_tum(path, stamps, T)
    traj = read_tum(path)
    assert len(traj) == 50
    np.testing.assert_allclose(traj.stamps_s, stamps, atol=1e-6, rtol=0)
    np.testing.assert_allclose(traj.positions_m, T[:, :3, 3], atol=1e-6, rtol=0)
    np.testing.assert_allclose(traj.T[:, :3, :3], T[:, :3, :3], atol=1e-8)
    q_in = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    dots = np.abs(np.sum(q_in * traj.quaternions_xyzw, axis=1))  # q and -q are the same rotation
    np.testing.assert_allclose(dots, 1.0, atol=1e-8)
    assert np.all(traj.quaternions_xyzw[:, 3] >= 0)


def test_file_layout_header_and_decimals(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [1.0, -1e-9, 2.5]  # -1e-9 must not print as "-0.000000"
    path = tmp_path / "t.txt"
    write_tum(path, [1305031102.175304], T[None])
    lines = path.read_text().splitlines()
    assert lines[0] == "# timestamp tx ty tz qx qy qz qw"
    assert lines[1] == (
        "1305031102.175304 1.000000 0.000000 2.500000 0.000000000 0.000000000 0.000000000 1.000000000"
    )


def test_reader_skips_comments_blank_lines_and_accepts_commas(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text(
        "# ground truth trajectory\n\n"
        "1.0 1 2 3 0 0 0 1\n"
        "   \n"
        "2.0,1,2,3,0,0,0.7071068,0.7071068\n"
        "3.0\t1 2 3 0 0 0 -2\n"  # not normalised, negative w
    )
    traj = read_tum(path)
    assert len(traj) == 3
    yaw90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    np.testing.assert_allclose(traj.T[1, :3, :3], yaw90, atol=1e-6)
    np.testing.assert_allclose(traj.T[2, :3, :3], np.eye(3), atol=1e-12)


def test_covariance_sidecar_se3_written_and_parsed(tmp_path):
    stamps, T = _poses(20)
    covs = _spd(20, 6)
    path = tmp_path / "est.txt"
    write_tum(path, stamps, T, covs)
    side = tmp_path / "est.cov.txt"
    assert sidecar_path(path) == side and side.is_file()
    header = [ln for ln in side.read_text().splitlines() if ln.startswith("#")]
    assert "x y z rx ry rz" in header[0]
    assert header[1].split()[1:4] == ["timestamp", "c_x_x", "c_x_y"]
    first = side.read_text().splitlines()[len(header)].split()
    assert len(first) == 1 + 21
    cs, cov = read_tum_covariance(side)
    np.testing.assert_allclose(cs, stamps, atol=1e-6, rtol=0)
    np.testing.assert_allclose(cov, covs, rtol=1e-9, atol=1e-18)
    assert len(read_tum(path)) == 20  # the trajectory file itself is unchanged by the sidecar


def test_covariance_sidecar_planar(tmp_path):
    stamps, T = _poses(5)
    covs = _spd(5, 3)
    path = tmp_path / "odom"
    write_tum(path, stamps, T, covs)
    side = tmp_path / "odom.cov"
    assert side.is_file()
    assert "x y yaw" in side.read_text().splitlines()[0]
    _, cov = read_tum_covariance(side)
    assert cov.shape == (5, 3, 3)
    np.testing.assert_allclose(cov, covs, rtol=1e-9, atol=1e-18)


def test_streaming_writer_equals_batch_writer_bytes(tmp_path):
    stamps, T = _poses(30)
    covs = _spd(30, 6)
    write_tum(tmp_path / "batch.txt", stamps, T, covs)
    with TumWriter(tmp_path / "stream.txt") as w:
        for s, pose, c in zip(stamps, T, covs, strict=True):
            w.write(s, pose, c)
        assert w.count == 30
    assert (tmp_path / "batch.txt").read_bytes() == (tmp_path / "stream.txt").read_bytes()
    assert (tmp_path / "batch.cov.txt").read_bytes() == (tmp_path / "stream.cov.txt").read_bytes()


def test_writing_twice_is_byte_identical(tmp_path):
    stamps, T = _poses(10, seed=3)
    write_tum(tmp_path / "a.txt", stamps, T)
    write_tum(tmp_path / "b.txt", stamps.copy(), T.copy())
    assert (tmp_path / "a.txt").read_bytes() == (tmp_path / "b.txt").read_bytes()


def test_malformed_line_names_file_and_line(tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n\n2.0 0 0 0 0 0 1\n")
    expected = r"bad\.txt:4: expected 'timestamp tx ty tz qx qy qz qw', got 7 values"
    with pytest.raises(DataFormatError, match=expected):
        read_tum(path)
    path.write_text("1.0 0 0 zero 0 0 0 1\n")
    with pytest.raises(DataFormatError, match=r"bad\.txt:1: expected numbers"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"bad\.txt:2: quaternion .* zero norm"):
        read_tum(path)


def test_missing_file_and_bad_inputs(tmp_path):
    with pytest.raises(MissingDataError, match="nothere.txt"):
        read_tum(tmp_path / "nothere.txt")
    stamps, T = _poses(3)
    bad = T.copy()
    bad[1, :3, :3] *= 2.0
    with pytest.raises(DataFormatError, match="pose 1"):
        write_tum(tmp_path / "x.txt", stamps, bad)
    with pytest.raises(DataFormatError, match="covariance"):
        with TumWriter(tmp_path / "y.txt") as w:
            w.write(0.0, np.eye(4))
            w.write(1.0, np.eye(4), np.eye(6))


def test_empty_trajectory(tmp_path):
    write_tum(tmp_path / "e.txt", np.zeros(0), np.zeros((0, 4, 4)))
    traj = read_tum(tmp_path / "e.txt")
    assert len(traj) == 0 and traj.T.shape == (0, 4, 4) and traj.positions_m.shape == (0, 3)


def test_evo_reads_our_files(tmp_path):
    file_interface = pytest.importorskip("evo.tools.file_interface")
    stamps, T = _poses(15)
    write_tum(tmp_path / "est.txt", stamps, T)
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "est.txt"))
    np.testing.assert_allclose(np.asarray(traj.poses_se3), T, atol=1e-6)
