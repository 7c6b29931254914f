"""CARMEN logs: ROBOTLASER1 round trip, classic hand-written messages, skipped types, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.io import CarmenWriter, DataFormatError, MissingDataError, read_carmen
from simnav.sensors.readings import LaserScan


def _mount(x: float, y: float, yaw: float, upside_down: bool = False) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    if upside_down:
        T[:3, :3] = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # roll by pi
    T[:3, 3] = [x, y, 0.3]
    return T


def _hokuyo_scan(T_base_sensor: np.ndarray, seed: int = 0) -> LaserScan:
    """682 beams over 240 deg, 5.6 m max range, with dropouts."""
    rng = np.random.default_rng(seed)
    n = 682
    angles = np.linspace(-math.radians(120), math.radians(120), n)
    ranges = rng.uniform(0.05, 5.5, n).astype(np.float32)
    ranges[rng.random(n) < 0.15] = 0.0
    return LaserScan("laser_front", 12.3456789, ranges, angles, 5.6, 0.02, T_base_sensor)


def test_robotlaser_round_trip_682_beams_rotated_mount(tmp_path):
    mount = _mount(0.2, -0.1, math.radians(30))
    scan = _hokuyo_scan(mount)
    robot = np.array([3.0, -1.5, 2.5])
    path = tmp_path / "run.log"
    with CarmenWriter(path) as w:
        w.write_robotlaser(scan, None, robot, 0.4, -0.2)
    log = read_carmen(path)
    assert len(log.scans) == 1
    got = log.scans[0]
    assert got.sensor == "laser1"
    assert got.stamp_s == pytest.approx(12.345679, abs=1e-9)
    assert got.max_range_m == pytest.approx(5.6)
    np.testing.assert_allclose(got.angles_rad, scan.angles_rad, atol=1e-6)
    np.testing.assert_array_equal(got.valid, scan.valid)
    np.testing.assert_allclose(got.ranges_m[scan.valid], scan.ranges_m[scan.valid], atol=5e-4 + 1e-6)
    assert np.all(got.ranges_m[~scan.valid] == 0)
    yaw = math.atan2(got.T_base_sensor[1, 0], got.T_base_sensor[0, 0])
    assert yaw == pytest.approx(math.radians(30), abs=1e-6)
    np.testing.assert_allclose(got.T_base_sensor[:2, 3], [0.2, -0.1], atol=2e-6)
    np.testing.assert_allclose(log.robot_poses[0], robot, atol=1e-6)
    c, s = math.cos(robot[2]), math.sin(robot[2])
    expected_laser = [3.0 + 0.2 * c + 0.1 * s, -1.5 + 0.2 * s - 0.1 * c]
    np.testing.assert_allclose(log.laser_poses[0, :2], expected_laser, atol=1e-6)


def test_robotlaser_line_layout_and_no_return_convention(tmp_path):
    scan = LaserScan(
        "laser", 5.0, np.array([1.0, 0.0, np.nan, 7.0, 5.5999, 1e-5], dtype=np.float32),
        np.linspace(-0.5, 0.5, 6), 5.6, 0.0, np.eye(4),
    )
    path = tmp_path / "a.log"
    with CarmenWriter(path, hostname="robot7") as w:
        w.write_robotlaser(scan, None, np.zeros(3), 0.0, 0.0)
    line = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0].split()
    # type laser_type start_angle field_of_view angular_resolution | maximum_range accuracy remission_mode n
    assert line[:5] == ["ROBOTLASER1", "0", "-0.500000000", "1.000000000", "0.200000000"]
    assert line[5:9] == ["5.600", "0.010000", "0", "6"]
    # 0 / NaN / beyond max are no-returns written as maximum_range; valid beams never round to 5.600 or 0.000
    assert line[9:15] == ["1.000", "5.600", "5.600", "5.600", "5.599", "0.001"]
    assert line[15] == "0"  # no remissions
    assert line[-3:] == ["5.000000", "robot7", "5.000000"]
    assert len(line) == 6 + 24
    got = read_carmen(path).scans[0]
    np.testing.assert_array_equal(got.valid, [True, False, False, False, True, True])


def test_upside_down_mount_keeps_points_in_base(tmp_path):
    scan = _hokuyo_scan(_mount(0.1, 0.05, math.radians(180), upside_down=True), seed=2)
    with CarmenWriter(tmp_path / "u.log") as w:
        w.write_robotlaser(scan, None, np.array([1.0, 2.0, 0.3]), 0.0, 0.0)
    got = read_carmen(tmp_path / "u.log").scans[0]
    np.testing.assert_allclose(got.points_base()[:, :2], scan.points_base()[:, :2], atol=2e-3)


def test_writer_is_deterministic(tmp_path):
    def write(path):
        with CarmenWriter(path) as w:
            w.write_param("robot_front_laser_max", 5.6)
            for k in range(5):
                scan = _hokuyo_scan(_mount(0.2, 0.0, 0.0), seed=k)
                w.write_odom(k * 0.1, np.array([k * 0.1, -0.0, -1e-12]), 0.5, 0.0)
                w.write_robotlaser(scan, None, np.array([k * 0.1, 0.0, 0.0]), 0.5, 0.0)
                pose = np.array([k * 0.1, 0.0, 0.0])
                w.write_flaser(k * 0.1, scan.ranges_m[:181], pose, pose)
                w.write_truepos(k * 0.1, np.array([k * 0.1, 0.01, 0.0]), np.array([k * 0.1, 0.0, 0.0]))

    write(tmp_path / "a.log")
    write(tmp_path / "b.log")
    data = (tmp_path / "a.log").read_bytes()
    assert data == (tmp_path / "b.log").read_bytes()
    assert b"-0.000000" not in data
    log = read_carmen(tmp_path / "a.log")
    assert len(log.scans) == 10 and len(log.odom.stamps_s) == 5 and len(log.truepos.stamps_s) == 5


CLASSIC = """\
# CARMEN Logfile
# file format is one message per line
PARAM robot_front_laser_max 50.0
PARAM laser_front_laser_resolution 1.0 1082812353.546123 nohost 0.001
SYNC start
ODOM 0.100000 -0.200000 0.300000 0.400000 -0.050000 0.000000 1082812353.500000 nohost 0.010000
NMEAGGA 1 2 3 4 5 6 1082812353.5 nohost 0.02
FLASER 181 {flaser} 1.100000 2.200000 0.300000 1.000000 2.000000 0.300000 1082812353.600000 nohost 0.110000
TRUEPOS 5.0 6.0 -0.5 0.1 -0.2 0.3 1082812353.700000 nohost 0.2
RAWLASER1 0 -1.570796 3.141593 0.017453 81.9 0.01 0 4 1.0 nan -3.0 81.9 2 7 8 1082812353.8 nohost 0.3
RLASER 3 1.0 2.0 3.0 -0.250000 0.000000 3.141593 0.000000 0.000000 0.000000 1082812353.900000 nohost 0.4
SYNC stop
"""


def _classic_log(tmp_path):
    flaser = " ".join(["81.83" if k % 10 == 0 else f"{1 + k / 100:.2f}" for k in range(181)])
    path = tmp_path / "classic.clf"
    path.write_text(CLASSIC.format(flaser=flaser))
    return path


def test_classic_messages_parse(tmp_path):
    log = read_carmen(_classic_log(tmp_path))
    assert log.params == {"robot_front_laser_max": "50.0", "laser_front_laser_resolution": "1.0"}
    assert log.skipped == {"SYNC": 2, "NMEAGGA": 1}
    np.testing.assert_allclose(log.odom.stamps_s, [1082812353.5])
    np.testing.assert_allclose(log.odom.poses_xyt, [[0.1, -0.2, 0.3]])
    np.testing.assert_allclose(log.odom.tv_m_s, [0.4])
    np.testing.assert_allclose(log.odom.rv_rad_s, [-0.05])
    stamps, poses = log.truepos  # unpacks as (stamps, poses)
    np.testing.assert_allclose(stamps, [1082812353.7])
    np.testing.assert_allclose(poses, [[5.0, 6.0, -0.5]])
    np.testing.assert_allclose(log.truepos_odom, [[0.1, -0.2, 0.3]])

    flaser, raw, rear = log.scans
    assert flaser.sensor == "laser1" and raw.sensor == "laser1" and rear.sensor == "laser2"
    assert len(flaser.ranges_m) == 181
    np.testing.assert_allclose(flaser.angles_rad[[0, 90, 180]], [-math.pi / 2, 0.0, math.pi / 2])
    np.testing.assert_allclose(np.diff(flaser.angles_rad), math.radians(1.0), atol=1e-12)
    assert flaser.stamp_s == pytest.approx(1082812353.6)
    assert not flaser.valid[0] and not flaser.valid[10] and flaser.valid[1]
    assert flaser.ranges_m[1] == pytest.approx(1.01)
    # laser pose (1.1, 2.2, 0.3) vs odom pose (1.0, 2.0, 0.3): offset rotated into the robot frame
    c, s = math.cos(0.3), math.sin(0.3)
    offset = [c * 0.1 + s * 0.2, -s * 0.1 + c * 0.2]
    np.testing.assert_allclose(flaser.T_base_sensor[:2, 3], offset, atol=1e-9)
    np.testing.assert_allclose(flaser.T_base_sensor[:3, :3], np.eye(3), atol=1e-9)

    np.testing.assert_array_equal(raw.ranges_m, np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32))
    np.testing.assert_allclose(raw.angles_rad, -1.570796 + 0.017453 * np.arange(4))
    np.testing.assert_array_equal(raw.T_base_sensor, np.eye(4))
    assert np.all(np.isnan(log.laser_poses[1]))

    rear_yaw = math.atan2(rear.T_base_sensor[1, 0], rear.T_base_sensor[0, 0])
    assert abs(abs(rear_yaw) - math.pi) < 1e-5
    np.testing.assert_allclose(rear.T_base_sensor[:2, 3], [-0.25, 0.0], atol=1e-9)


def test_T_base_laser_override(tmp_path):
    T = _mount(0.3, 0.0, 0.0)
    log = read_carmen(_classic_log(tmp_path), T_base_laser=T)
    for scan in log.scans:
        np.testing.assert_array_equal(scan.T_base_sensor, T)


def test_truncated_robotlaser_names_file_line_and_type(tmp_path):
    scan = _hokuyo_scan(_mount(0.0, 0.0, 0.0))
    path = tmp_path / "cut.log"
    with CarmenWriter(path) as w:
        w.write_odom(1.0, np.zeros(3), 0.0, 0.0)
        w.write_robotlaser(scan, None, np.zeros(3), 0.0, 0.0)
    lines = path.read_text().splitlines()
    line_no = len(lines)
    lines[-1] = " ".join(lines[-1].split()[:500])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=rf"cut\.log:{line_no}: ROBOTLASER1: line ends early") as err:
        read_carmen(path)
    assert "num_readings" in str(err.value)  # the expected layout is spelled out


def test_malformed_fields(tmp_path):
    path = tmp_path / "bad.log"
    path.write_text("ODOM 1 2 x 0 0 0 1.0 host 1.0\n")
    with pytest.raises(DataFormatError, match=r"bad\.log:1: ODOM: field 3 \(theta\) must be a number"):
        read_carmen(path)
    path.write_text("# c\nODOM 1 2 3 0 0 0 1.0 host 1.0 extra\n")
    with pytest.raises(DataFormatError, match=r"bad\.log:2: ODOM: 1 unexpected extra fields"):
        read_carmen(path)
    path.write_text("FLASER 3.5 1 2 3 0 0 0 0 0 0 1 h 1\n")
    with pytest.raises(DataFormatError, match=r"FLASER: field 1 \(num_readings\) must be a non-negative int"):
        read_carmen(path)
    with pytest.raises(MissingDataError, match="nothere.log"):
        read_carmen(tmp_path / "nothere.log")


def test_writer_rejects_bad_words(tmp_path):
    with CarmenWriter(tmp_path / "w.log") as w:
        with pytest.raises(DataFormatError, match="PARAM value"):
            w.write_param("name", "two words")
    with pytest.raises(DataFormatError, match="hostname"):
        CarmenWriter(tmp_path / "h.log", hostname="my host")
