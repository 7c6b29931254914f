"""Obstacle points from the range sensors: level 2D lidar scans can be had apart (rays for the short-term memory)."""

from __future__ import annotations

import math

import numpy as np

from simnav.navigation.sensing import SensedObstacles, is_level_scan
from simnav.sensors.readings import LaserScan


def _scan(name: str, pitch_rad: float = 0.0, roll_rad: float = 0.0) -> LaserScan:
    angles = np.linspace(-1.0, 1.0, 21)
    cp, sp, cr, sr = math.cos(pitch_rad), math.sin(pitch_rad), math.cos(roll_rad), math.sin(roll_rad)
    T = np.eye(4)
    T[:3, :3] = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    T[:3, 3] = [0.2, 0.0, 0.3]
    return LaserScan(name, 1.0, np.full(21, 2.0, dtype=np.float32), angles, 10.0, 0.05, T)


def test_level_scans_upright_or_upside_down_are_split_from_tilted_ones() -> None:
    level, flipped, tilted = _scan("front"), _scan("rear", roll_rad=math.pi), _scan("tilted", pitch_rad=0.3)
    assert is_level_scan(level) and is_level_scan(flipped) and not is_level_scan(tilted)
    sensed = SensedObstacles()
    for reading in (level, flipped, tilted):
        sensed.add(reading, np.eye(3))
    other, scans = sensed.split_points_base(1.0, np.eye(3))
    assert len(scans) == 42 and len(other) == 21
    np.testing.assert_allclose(scans[:, 2], 0.3, atol=1e-9)           # in the lidars' plane
    assert len(sensed.points_base(1.0, np.eye(3))) == 63               # all of them together
    sensed.reset()
    assert [len(p) for p in sensed.split_points_base(1.0, np.eye(3))] == [0, 0]


def test_view_sectors_of_the_giraff_are_its_lidar_and_camera() -> None:
    from simnav.navigation.sensing import ViewSector, view_sectors
    from simnav.robot import load_robot

    lidar, camera = view_sectors(load_robot("giraff"))
    assert (lidar.x_m, lidar.half_angle_rad, lidar.range_m) == (0.22, math.radians(120.0), 5.6)
    assert camera.x_m == 0.05 and 0.4 < camera.half_angle_rad < 0.6  # Kinect: 57 degrees across
    behind, side, far = [-1.0, 0.0], [0.0, 1.0], [6.0, 0.0]
    assert lidar.contains(np.array([behind, side, far])).tolist() == [False, True, False]
    assert ViewSector(0.0, 0.0, 0.0, math.pi, 5.0).contains(np.array([behind])).tolist() == [True]


def test_the_giraffs_camera_sees_its_low_band_whole_only_from_the_floor_it_sees_and_never_its_head() -> None:
    from simnav.navigation.bands import robot_bands
    from simnav.navigation.sensing import camera_free_space
    from simnav.robot import load_robot

    robot = load_robot("giraff")  # camera 0.05 m ahead of the base origin, 1.12 m up, 30 deg down, 45.6 deg fovy
    base, pole, block, head = camera_free_space(robot, robot_bands(robot))
    lowest, highest = math.radians(30.0 + 45.6 / 2), math.radians(30.0 - 45.6 / 2)  # edges of the view, below level
    # the base band (0.02-0.34 m) from where the lower edge of the view meets 0.02 m on, up to the depth range
    assert math.isclose(base[0], 0.05 + (1.12 - 0.02) / math.tan(lowest), abs_tol=0.002)
    assert base[1] > 4.0
    # the pole band (0.34-1.02 m): from where the lower edge meets 0.34 m to where the upper edge meets 1.02 m
    assert math.isclose(pole[0], 0.05 + (1.12 - 0.34) / math.tan(lowest), abs_tol=0.002)
    assert math.isclose(pole[1], 0.05 + (1.12 - 1.02) / math.tan(highest), abs_tol=0.002)
    # above the camera (the upper edge of the view points down): never
    assert block[0] > block[1] and head[0] > head[1]
    # a camera turned sideways sees nothing of the cone ahead; without a camera there is nothing either
    sideways = [s.model_copy(update={"mount": s.mount.model_copy(update={"rpy_deg": (0.0, 30.0, 90.0)})})
                if s.type == "rgbd" else s for s in robot.sensors]
    for sensors in (sideways, [s for s in robot.sensors if s.type != "rgbd"]):
        free = camera_free_space(robot.model_copy(update={"sensors": sensors}), robot_bands(robot))
        assert np.all(free[:, 0] > free[:, 1])
