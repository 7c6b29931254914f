"""2D lidar against analytic ranges, noise statistics, invalid beams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.robot import load_robot
from simnav.sensors.presets import LIDAR2D_PRESETS
from simnav.sim import SimConfig, Simulator

NO_CAMERA = ["sensors.camera.rate_hz=0.001"]


def analytic_ranges(origin_xy, yaw, angles, inner=(0.05, 0.05, 5.95, 3.95)) -> np.ndarray:
    """Distances from a point inside an axis-aligned rectangle to its boundary along each beam."""
    x0, y0, x1, y1 = inner
    a = yaw + angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (x1 - origin_xy[0]) / c, np.where(c < 0, (x0 - origin_xy[0]) / c, np.inf))
        ty = np.where(s > 0, (y1 - origin_xy[1]) / s, np.where(s < 0, (y0 - origin_xy[1]) / s, np.inf))
    return np.minimum(tx, ty)


def scan_in_box(box_room, overrides, seed=0):
    robot = load_robot("giraff", NO_CAMERA + overrides)
    with Simulator(box_room, robot, SimConfig(), seed=seed) as sim:
        sim.step(0.0, 0.0)
        return sim.latest("laser_front"), sim


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0])
def test_noise_free_lidar_matches_the_room(box_room, yaw_deg):
    world = box_room.model_copy(update={"spawns": [box_room.spawns[0].model_copy(update={"yaw_deg": yaw_deg})]})
    scan, sim = scan_in_box(world, ["sensors.laser_front.noise_std_m=0"])
    mount = scan.T_base_sensor[:2, 3]
    yaw = math.radians(yaw_deg)
    origin = np.array([3.0, 2.0]) + [mount[0] * math.cos(yaw), mount[0] * math.sin(yaw)]
    expected = analytic_ranges(origin, yaw, scan.angles_rad)
    assert scan.valid.all()
    np.testing.assert_allclose(scan.ranges_m, expected, atol=1e-4)


def test_noisy_lidar_within_three_sigma(box_room):
    scan, _ = scan_in_box(box_room, ["sensors.laser_front.noise_std_m=0.01"])
    expected = analytic_ranges([3.22, 2.0], 0.0, scan.angles_rad)
    error = scan.ranges_m - expected
    assert np.mean(np.abs(error) <= 0.03) >= 0.99
    assert np.all(np.abs(error) <= 0.05)
    assert 0.008 < np.std(error) < 0.012


def test_preset_geometry(box_room):
    scan, _ = scan_in_box(box_room, [])
    p = LIDAR2D_PRESETS["hokuyo_urg04lx"]
    assert len(scan.ranges_m) == p.beams == 682
    assert math.isclose(scan.angles_rad[-1] - scan.angles_rad[0], math.radians(p.fov_deg), rel_tol=1e-9)
    assert scan.ranges_m.dtype == np.float32


def test_out_of_range_and_dropouts_are_zero_never_nan(box_room):
    scan, _ = scan_in_box(box_room, ["sensors.laser_front.max_range_m=2.5", "sensors.laser_front.dropout_prob=0.2"])
    expected = analytic_ranges([3.22, 2.0], 0.0, scan.angles_rad)
    assert np.isfinite(scan.ranges_m).all()
    assert (scan.ranges_m[expected > 2.6] == 0).all()
    near = expected < 2.4
    assert 0.1 < np.mean(scan.ranges_m[near] == 0) < 0.3
    assert scan.ranges_m.max() <= 2.5


def test_lidar_does_not_see_the_robot_itself(box_room):
    scan, _ = scan_in_box(box_room, ["sensors.laser_front.fov_deg=360", "sensors.laser_front.noise_std_m=0"])
    assert scan.ranges_m[scan.valid].min() > 0.5  # the base polygon is within 0.5 m of the scanner


def test_rotated_mount_sees_backwards(box_room):
    scan, _ = scan_in_box(box_room, ["sensors.laser_front.mount.rpy_deg=[0,0,180]",
                                     "sensors.laser_front.mount.xyz_m=[-0.2,0,0.3]",
                                     "sensors.laser_front.noise_std_m=0"])
    centre = np.argmin(np.abs(scan.angles_rad))
    assert scan.ranges_m[centre] == pytest.approx(2.8 - 0.05, abs=1e-3)  # scanner at x = 2.8, wall face at 0.05
