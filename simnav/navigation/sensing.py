"""Obstacle points from every range sensor, in the base frame at the current instant (thesis §6.C.5-6).

Lidars, 3D lidars and depth cameras run at their own rates; the navigator runs at the control rate. The latest
reading of each sensor is kept with the pose it was taken at; at every step the points are moved into the current
base frame with the motion since then, so that a 10 Hz scan taken 80 ms ago still sits where the obstacles are.
The points of level 2D lidars (*scan points*) can be had apart: they are ends of rays in the lidar's plane, which
the navigator's short-term memory uses as evidence of free space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simnav.geometry import se2
from simnav.navigation.bands import FLOOR_TOLERANCE_M
from simnav.sensors.readings import LaserScan, PointCloud, Reading, RGBDFrame


@dataclass(frozen=True)
class SensingConfig:
    """How readings become obstacle points.

    Attributes:
        depth_stride: use every n-th row and column of depth images.
        max_age_s: readings older than this are forgotten, s.
        max_range_m: points farther than this from the sensor are ignored, m.
    """

    depth_stride: int = 4
    max_age_s: float = 0.5
    max_range_m: float = 8.0


@dataclass(frozen=True)
class ViewSector:
    """Where one range sensor sees on the floor plane: a circular sector in the base frame.

    Attributes:
        x_m, y_m: apex (the sensor's position), m.
        yaw_rad: direction of the sector's axis, rad.
        half_angle_rad: half its opening (pi or more: all around), rad.
        range_m: radius, m.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    half_angle_rad: float
    range_m: float

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(P,) whether each of the (P, 2) points (base frame, m) lies in the sector."""
        d = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - (self.x_m, self.y_m)
        inside = np.hypot(d[:, 0], d[:, 1]) <= self.range_m
        if self.half_angle_rad >= math.pi:
            return inside
        off = np.abs((np.arctan2(d[:, 1], d[:, 0]) - self.yaw_rad + math.pi) % (2 * math.pi) - math.pi)
        return inside & (off <= self.half_angle_rad)


def view_sectors(robot) -> list[ViewSector]:
    """The horizontal fields of view of a robot's range sensors (lidars, 3D lidars, depth cameras), one sector each.

    Args:
        robot: a :class:`simnav.robot.spec.RobotSpec`.
    """
    from simnav.sensors.presets import resolve_lidar2d, resolve_lidar3d, resolve_rgbd

    sectors = []
    for sensor in robot.sensors:
        if sensor.type == "lidar2d":
            p = resolve_lidar2d(sensor)
            half, reach = p.fov_rad / 2, p.max_range_m
        elif sensor.type == "lidar3d":
            half, reach = math.pi, resolve_lidar3d(sensor).max_range_m
        elif sensor.type == "rgbd":
            p = resolve_rgbd(sensor)
            half = math.atan(math.tan(math.radians(p.fovy_deg) / 2) * p.width / p.height)
            reach = p.max_range_m
        else:
            continue
        T = sensor.mount.T_base_sensor()
        sectors.append(ViewSector(float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0]), half, reach))
    return sectors


FORWARD_CAMERA_TOLERANCE_RAD = math.radians(5.0)
"""A depth camera whose heading (and roll) is within this of the base's x axis faces forward: it sees the cone of
the short-term memory."""


def camera_free_space(robot, bands, floor_m: float = FLOOR_TOLERANCE_M, step_m: float = 0.001) -> np.ndarray:
    """Per band, where a forward-facing depth camera sees the band's whole height: the short-term memory's
    free-space cone counts a cell of that band as seen free only there (:class:`simnav.navigation.memory.
    ShortTermMemory`).

    A cell at forward distance x (base frame) is in view for a band ``[z_min, z_max]`` when the points at
    ``max(z_min, floor_m)`` and at ``min(z_max, the robot's top)`` above it both lie inside the camera's vertical
    field of view and its depth range (the camera's lateral field is the memory's cone angle); between those
    heights everything is then in view too. A camera pitched down sees low bands only from some distance on and
    high bands only up to some distance, and nothing above its own height unless it looks up.

    Args:
        robot: a :class:`simnav.robot.spec.RobotSpec`.
        bands: its height bands (objects with ``z_min_m`` and ``z_max_m``, m).
        floor_m: the lowest height that matters (points below are the floor), m.
        step_m: resolution of the search along x, m.

    Returns:
        (B, 2) per band the interval [near, far] of forward distance from the base origin, m; an empty one
        (inf, -inf) where no forward-facing depth camera sees the band whole. With several cameras, the longest.
    """
    out = np.tile([math.inf, -math.inf], (len(bands), 1))
    top_m = max(prism.z_max_m for prism in robot.prisms)
    for camera in filter(None, map(_forward_camera, robot.sensors)):
        for b, band in enumerate(bands):
            near, far = _in_view_m(camera, max(band.z_min_m, floor_m), min(band.z_max_m, top_m), step_m)
            if far - near > out[b, 1] - out[b, 0]:
                out[b] = near, far
    return out


def _forward_camera(sensor) -> tuple[float, float, float, float, float, float] | None:
    """A depth camera facing forward (no yaw or roll beyond FORWARD_CAMERA_TOLERANCE_RAD) as (x m, height m, pitch
    down rad, half vertical field of view rad, min range m, max range m); None for any other sensor."""
    from simnav.sensors.presets import resolve_rgbd

    if sensor.type != "rgbd":
        return None
    T = sensor.mount.T_base_sensor()
    axis = T[:3, 0]  # the camera body's x axis is the optical axis
    yaw, roll = math.atan2(axis[1], axis[0]), math.atan2(T[2, 1], T[2, 2])
    if max(abs(yaw), abs(roll)) > FORWARD_CAMERA_TOLERANCE_RAD:
        return None
    p = resolve_rgbd(sensor)
    pitch_down = -math.asin(max(-1.0, min(1.0, axis[2])))
    return float(T[0, 3]), float(T[2, 3]), pitch_down, math.radians(p.fovy_deg) / 2, p.min_range_m, p.max_range_m


def _in_view_m(camera: tuple, z_low_m: float, z_high_m: float, step_m: float) -> tuple[float, float]:
    """The forward distances (base x, m) at which the camera sees both heights (m), as [near, far]; (inf, -inf)
    where it sees them nowhere."""
    x_m, height_m, pitch_down, half_fov, min_m, max_m = camera
    dx = np.arange(step_m, max_m + step_m, step_m)
    seen = np.ones_like(dx, dtype=bool)
    for z in (z_low_m, z_high_m):
        off_axis = pitch_down + np.arctan2(z - height_m, dx)  # angle above the optical axis, rad
        depth = dx * math.cos(pitch_down) - (z - height_m) * math.sin(pitch_down)
        seen &= (np.abs(off_axis) <= half_fov) & (depth >= min_m) & (depth <= max_m)
    if not seen.any():
        return math.inf, -math.inf
    return x_m + float(dx[seen][0]), x_m + float(dx[seen][-1])


LEVEL_SCAN_TILT_RAD = math.radians(2.0)
"""A 2D lidar whose scan plane is tilted at most this much from the floor (upright or upside down) is level."""


def is_level_scan(reading: Reading) -> bool:
    """Whether a reading is a 2D lidar scan whose plane is level in the base frame."""
    return isinstance(reading, LaserScan) and abs(reading.T_base_sensor[2, 2]) >= math.cos(LEVEL_SCAN_TILT_RAD)


def reading_points_base(reading: Reading, config: SensingConfig = SensingConfig()) -> np.ndarray | None:
    """(P, 3) obstacle points of one reading in the base frame at its stamp, m; None for non-range readings."""
    if isinstance(reading, LaserScan):
        pts = reading.points_base()  # valid beams only
        near = np.asarray(reading.ranges_m)[reading.valid] <= config.max_range_m
        return pts[near]
    if isinstance(reading, PointCloud):
        pts = reading.points_base()
        return pts[np.isfinite(pts).all(axis=1) & (np.linalg.norm(pts, axis=1) <= config.max_range_m)]
    if isinstance(reading, RGBDFrame):
        return _depth_points_base(reading, config)
    return None


def _depth_points_base(frame: RGBDFrame, config: SensingConfig) -> np.ndarray:
    """Back-project a strided depth image into the base frame."""
    s = config.depth_stride
    depth = np.asarray(frame.depth_m, dtype=np.float64)[::s, ::s]
    v, u = np.mgrid[0:frame.depth_m.shape[0]:s, 0:frame.depth_m.shape[1]:s]
    ok = np.isfinite(depth) & (depth > 0) & (depth <= config.max_range_m)
    z, u, v = depth[ok], u[ok], v[ok]
    K = frame.K
    optical = np.column_stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z])
    T = frame.T_base_sensor
    return optical @ T[:3, :3].T + T[:3, 3]


class SensedObstacles:
    """The latest points of every range sensor, brought to the current base frame.

    Args:
        config: options.
    """

    def __init__(self, config: SensingConfig = SensingConfig()) -> None:
        self.config = config
        self._latest: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        self._level_scans: set[str] = set()

    def reset(self) -> None:
        self._latest.clear()
        self._level_scans.clear()

    def add(self, reading: Reading, T_odom_base_at_stamp: np.ndarray) -> None:
        """Keep a reading's points with the (3, 3) SE(2) base pose at its stamp (in any fixed frame)."""
        pts = reading_points_base(reading, self.config)
        if pts is not None:
            self._latest[reading.sensor] = (reading.stamp_s, np.asarray(T_odom_base_at_stamp, dtype=np.float64), pts)
            if is_level_scan(reading):
                self._level_scans.add(reading.sensor)

    def points_base(self, now_s: float, T_odom_base_now: np.ndarray) -> np.ndarray:
        """(P, 3) all kept points in the base frame at ``now_s``, given the current pose in the same fixed frame."""
        other, scans = self.split_points_base(now_s, T_odom_base_now)
        return np.concatenate([other, scans]) if len(scans) else other

    def split_points_base(self, now_s: float, T_odom_base_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`points_base` as (P, 3) points of every other sensor and (S, 3) scan points of level 2D lidars."""
        clouds, scans = [], []
        T_base_odom = se2.inverse(T_odom_base_now)
        for sensor, (stamp, T_then, pts) in list(self._latest.items()):
            if now_s - stamp > self.config.max_age_s:
                del self._latest[sensor]
                continue
            T = T_base_odom @ T_then  # base at the stamp, seen from the base now
            xy = pts[:, :2] @ T[:2, :2].T + T[:2, 2]
            (scans if sensor in self._level_scans else clouds).append(np.column_stack([xy, pts[:, 2]]))
        return (np.concatenate(clouds) if clouds else np.zeros((0, 3)),
                np.concatenate(scans) if scans else np.zeros((0, 3)))
