"""Synthetic laser scans for the range-flow odometry tests: a pure-numpy ray caster of 2D polygonal worlds.

Worlds are (M, 4) arrays of wall segments ``x0, y0, x1, y1`` in metres. :class:`ScanSimulator` casts the beams of
a scanner mounted on the base (any ``T_base_sensor``, e.g. upside-down or backward) from a base pose in the
world and returns :class:`LaserScan` objects, optionally with Gaussian range noise.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from simnav.geometry import se2, se3
from simnav.geometry.raycast2d import first_hits
from simnav.sensors.readings import LaserScan


def polygon(points: list[tuple[float, float]], closed: bool = True) -> np.ndarray:
    """(k, 4) segments joining consecutive points (and the last to the first when ``closed``)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    seg = np.hstack([p, q])
    return seg if closed else seg[:-1]


def box(cx: float, cy: float, w: float, h: float, yaw_deg: float = 0.0) -> np.ndarray:
    """(4, 4) segments of a w x h rectangle centred at (cx, cy), rotated by ``yaw_deg``."""
    corners = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    corners = se2.transform_points(se2.from_xy_yaw(cx, cy, math.radians(yaw_deg)), corners)
    return polygon([tuple(c) for c in corners])


def l_room() -> np.ndarray:
    """An irregular L-shaped 8 x 6 m room with a slanted wall, a pillar and three boxes (no symmetry)."""
    walls = polygon([(0, 0), (8, 0), (8, 2.5), (6.5, 3.2), (5, 3.2), (5, 6), (0, 6)])
    return np.vstack([walls, box(2.0, 1.2, 0.6, 0.4, 20), box(6.6, 1.0, 0.5, 0.5, 0), box(1.2, 4.6, 0.8, 0.3, -35),
                      box(3.9, 4.8, 0.25, 0.25, 10)])


def corridor(length_m: float = 400.0, width_m: float = 2.0) -> np.ndarray:
    """Two parallel featureless walls along x, from ``-length/2`` to ``+length/2``, ``width`` apart around y = 0."""
    h, w = length_m / 2, width_m / 2
    return np.array([[-h, -w, h, -w], [-h, w, h, w]], dtype=np.float64)


def uniform_angles(n: int, fov_deg: float) -> np.ndarray:
    """(n,) beam angles evenly covering ``fov_deg`` centred on the x axis (endpoint excluded for 360 degrees)."""
    if fov_deg >= 360.0:
        return np.linspace(-np.pi, np.pi, n, endpoint=False)
    half = math.radians(fov_deg) / 2
    return np.linspace(-half, half, n)


class ScanSimulator:
    """Casts scans of a scanner mounted on a base moving in a 2D world.

    Args:
        world: (M, 4) wall segments.
        angles_rad: (N,) beam angles in the sensor frame.
        T_base_sensor: (4, 4) mount; only mounts whose beams stay horizontal make sense.
        noise_m: standard deviation of the Gaussian range noise, m.
        max_range_m, min_range_m: beams outside are reported as 0.
        seed: noise seed.
    """

    def __init__(self, world: np.ndarray, angles_rad: np.ndarray, T_base_sensor: np.ndarray | None = None,
                 noise_m: float = 0.0, max_range_m: float = 30.0, min_range_m: float = 0.05, seed: int = 0) -> None:
        self.world = world
        self.angles_rad = np.asarray(angles_rad, dtype=np.float64)
        self.T_base_sensor = np.eye(4) if T_base_sensor is None else T_base_sensor
        self.noise_m, self.max_range_m, self.min_range_m = noise_m, max_range_m, min_range_m
        self.rng = np.random.default_rng(seed)

    def scan(self, T_world_base: np.ndarray, stamp_s: float = 0.0) -> LaserScan:
        """The scan seen from base pose ``T_world_base`` (3, 3)."""
        beams = np.stack([np.cos(self.angles_rad), np.sin(self.angles_rad), np.zeros_like(self.angles_rad)])
        dirs_base = (self.T_base_sensor[:3, :3] @ beams)[:2].T
        dirs = dirs_base @ T_world_base[:2, :2].T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origin = se2.transform_points(T_world_base, self.T_base_sensor[None, :2, 3])[0]
        r = first_hits(self.world, origin, dirs)
        if self.noise_m > 0:
            r = r + self.rng.normal(scale=self.noise_m, size=r.shape)
        r = np.where((r <= self.max_range_m) & (r >= self.min_range_m), r, 0.0)
        return LaserScan("laser", stamp_s, r.astype(np.float32), self.angles_rad.copy(), self.max_range_m,
                         self.min_range_m, self.T_base_sensor.copy())


def trajectory(n: int, speed_mps: float = 0.5, dt_s: float = 0.1, period_s: float = 5.0,
               start: tuple[float, float, float] = (1.0, 2.0, 0.0), yaw_amplitude_rad: float = 0.3) -> list[np.ndarray]:
    """n base poses ``T_world_base``, ``dt_s`` apart, along an S-curve heading +x: the heading oscillates with
    amplitude ``yaw_amplitude_rad`` and period ``period_s`` (yaw rate up to 0.38 rad/s by default).

    From the default start the curve stays in the lower arm of :func:`l_room` for paths up to 6 m.
    """
    poses, T = [], se2.from_xy_yaw(*start)
    omega = 2 * math.pi / period_s
    for i in range(n):
        poses.append(T)
        w = yaw_amplitude_rad * omega * math.cos(omega * (i + 0.5) * dt_s)
        T = T @ se2.exp(np.array([speed_mps * dt_s, 0.0, w * dt_s]))
    return poses


def mount(roll_deg: float = 0.0, yaw_deg: float = 0.0, x_m: float = 0.0, y_m: float = 0.0) -> np.ndarray:
    """(4, 4) scanner mount at (x, y, 0.3 m) with the given roll and yaw."""
    return se3.from_rpy(math.radians(roll_deg), 0.0, math.radians(yaw_deg), [x_m, y_m, 0.3])


@pytest.fixture
def rangesim() -> SimpleNamespace:
    """The helpers of this module: worlds, simulator, trajectories and mounts."""
    return SimpleNamespace(polygon=polygon, box=box, l_room=l_room, corridor=corridor, cast=first_hits,
                           uniform_angles=uniform_angles, ScanSimulator=ScanSimulator, trajectory=trajectory,
                           mount=mount)
