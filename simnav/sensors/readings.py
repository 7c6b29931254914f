"""Sensor readings: plain, immutable numpy containers shared by the simulator, hardware, odometry and I/O.

No simulator imports here: odometry and navigation consume these types unchanged whether the robot is simulated
or real. Conventions: times are seconds on the source's clock (the simulation clock in sim); invalid ranges and
depths are 0 (never NaN or inf); poses are 4x4 homogeneous ``T_a_b`` (pose of frame b in frame a).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LaserScan:
    """A planar range scan.

    Attributes:
        sensor: name of the sensor on the robot (e.g. ``"laser_front"``).
        stamp_s: acquisition time, s.
        ranges_m: (N,) float32 ranges in metres; 0 marks an invalid beam (no return, dropout, out of range).
        angles_rad: (N,) float64 beam angles in the sensor frame (x forward, y left, counter-clockwise positive);
            monotonic but not necessarily uniform; may span up to 360 degrees.
        max_range_m: the scanner's maximum range, m.
        min_range_m: the scanner's minimum range, m.
        T_base_sensor: (4, 4) mount pose of the scanner in the robot base frame.
    """

    sensor: str
    stamp_s: float
    ranges_m: np.ndarray
    angles_rad: np.ndarray
    max_range_m: float
    min_range_m: float
    T_base_sensor: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool mask of beams with a valid return."""
        return self.ranges_m > 0

    @property
    def angle_min_rad(self) -> float:
        return float(self.angles_rad[0])

    @property
    def angle_increment_rad(self) -> float:
        """Mean signed increment between consecutive beams, rad."""
        return float((self.angles_rad[-1] - self.angles_rad[0]) / max(len(self.angles_rad) - 1, 1))

    def points_sensor(self) -> np.ndarray:
        """(M, 2) valid returns as x, y in the sensor frame, m."""
        ok = self.valid
        r, a = self.ranges_m[ok].astype(np.float64), self.angles_rad[ok]
        return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)

    def points_base(self) -> np.ndarray:
        """(M, 3) valid returns in the robot base frame, m."""
        p = self.points_sensor()
        p_h = np.column_stack([p, np.zeros(len(p)), np.ones(len(p))])
        return (p_h @ self.T_base_sensor.T)[:, :3]


@dataclass(frozen=True)
class PointCloud:
    """A 3D lidar sweep.

    Attributes:
        sensor: sensor name.
        stamp_s: acquisition time, s.
        points_sensor: (N, 3) float32 points in the sensor frame, m (invalid beams removed).
        ranges_m: (rings, columns) float32 range image; 0 = invalid.
        T_base_sensor: (4, 4) mount pose in the base frame.
    """

    sensor: str
    stamp_s: float
    points_sensor: np.ndarray
    ranges_m: np.ndarray
    T_base_sensor: np.ndarray

    def points_base(self) -> np.ndarray:
        """(N, 3) points in the robot base frame, m."""
        p = self.points_sensor.astype(np.float64)
        return p @ self.T_base_sensor[:3, :3].T + self.T_base_sensor[:3, 3]


@dataclass(frozen=True)
class RGBDFrame:
    """A registered depth + colour frame from a pinhole camera (optical frame: z forward, x right, y down).

    Attributes:
        sensor: sensor name.
        stamp_s: acquisition time, s.
        depth_m: (H, W) float32 z-depth along the optical axis, m; 0 = invalid.
        rgb: (H, W, 3) uint8 colour image, or None if the camera has no colour stream.
        K: (3, 3) intrinsic matrix (pixel centres at integer coordinates).
        T_base_sensor: (4, 4) pose of the optical frame in the base frame.
        body_id: (H, W) int32 id of the simulated body each pixel sees (-1 = nothing); only in simulation.
        velocity_optical: (3, H, W) float32 world-frame velocity of the observed point, expressed in the optical
            frame, m/s (0 for static scenery); only in simulation.
    """

    sensor: str
    stamp_s: float
    depth_m: np.ndarray
    rgb: np.ndarray | None
    K: np.ndarray
    T_base_sensor: np.ndarray
    body_id: np.ndarray | None = None
    velocity_optical: np.ndarray | None = None

    @property
    def intensity(self) -> np.ndarray | None:
        """(H, W) float32 intensity in [0, 1] (ITU-R BT.601 luma of ``rgb``), or None."""
        if self.rgb is None:
            return None
        rgb = self.rgb.astype(np.float32) / 255.0
        return rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114


@dataclass(frozen=True)
class WheelTicks:
    """Cumulative wheel encoder counts of a differential drive.

    Attributes:
        sensor: sensor name.
        stamp_s: acquisition time, s.
        left_ticks, right_ticks: cumulative signed counts (forward positive).
        ticks_per_rev: encoder resolution.
        wheel_radius_m, wheel_separation_m: nominal kinematics, m.
    """

    sensor: str
    stamp_s: float
    left_ticks: int
    right_ticks: int
    ticks_per_rev: int
    wheel_radius_m: float
    wheel_separation_m: float


Reading = LaserScan | PointCloud | RGBDFrame | WheelTicks


@dataclass(frozen=True)
class ContactEvent:
    """The start of a contact between the robot and something else.

    Attributes:
        stamp_s: simulation time at onset, s.
        kind: ``"static"`` (walls, furniture), ``"agent"`` (person, other robot, door).
        other: name of the other body (e.g. ``"ped3"``, ``"world"``).
        position_world: (3,) contact point in the world frame, m.
        depth_m: penetration depth at onset (>= 0), m.
    """

    stamp_s: float
    kind: str
    other: str
    position_world: np.ndarray = field(repr=False)
    depth_m: float = 0.0
