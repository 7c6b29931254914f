"""What every planar scan odometry takes and returns, and the conversion of any scan into an upright one.

Scanners can be mounted rotated or upside-down. :func:`planar_scan` turns a :class:`LaserScan` into an *upright
virtual scanner* in the base plane: origin at the mount's (x, y), x axis along the mount's forward direction
projected on the floor, beams sorted counter-clockwise. Odometries estimate the motion of that virtual frame and
report it for the base: ``T_prev_curr(base) = T_base_laser @ T_prev_curr(laser) @ inv(T_base_laser)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from simnav.geometry import se2
from simnav.sensors.readings import LaserScan, RGBDFrame


@dataclass(frozen=True)
class OdometryEstimate:
    """The result for one scan.

    Attributes:
        stamp_s: the scan's time stamp, s.
        T_odom_base: (3, 3) SE(2) pose of the base in the odom frame (odom = base pose at the first scan).
        twist_base: (3,) velocity of the base in its own frame over the last interval: vx, vy (m/s), wz (rad/s).
        covariance: (3, 3) covariance of the last increment (dx m, dy m, dyaw rad) in the base frame.
        degenerate: True when a motion direction was unobservable (e.g. a featureless corridor).
        valid_points: number of valid beams used.
        runtime_s: wall time spent on this scan, s.
    """

    stamp_s: float
    T_odom_base: np.ndarray
    twist_base: np.ndarray
    covariance: np.ndarray
    degenerate: bool = False
    valid_points: int = 0
    runtime_s: float = 0.0
    extra: dict = field(default_factory=dict, repr=False)

    @property
    def T_odom_base_3d(self) -> np.ndarray:
        """(4, 4) the same pose as an SE(3) matrix (for TUM files)."""
        return se2.to_se3(self.T_odom_base)


class ScanOdometry(Protocol):
    """A planar scan odometry: feed scans in time order, get one estimate per scan."""

    def process(self, scan: LaserScan) -> OdometryEstimate:
        """Estimate the motion since the previous scan; never raises on bad data (see the module docs)."""
        ...

    def reset(self) -> None:
        """Forget all history; the next scan starts a new odom frame."""
        ...


@dataclass(frozen=True)
class CameraOdometryEstimate:
    """The result for one depth / RGB-D frame.

    Attributes:
        stamp_s: the frame's time stamp, s.
        T_odom_camera: (4, 4) SE(3) pose of the camera optical frame in the odom frame (odom = optical frame of
            the first frame).
        T_odom_base: (4, 4) SE(3) pose of the base, through the camera mount: the odom frame of the base is the
            base at the first frame, so ``T_odom_base = T_base_camera @ T_odom_camera @ inv(T_base_camera)``.
        twist_camera: (6,) velocity of the camera in its own optical frame over the last interval, (v, w):
            m/s, rad/s, translational part first.
        covariance: (6, 6) covariance of the last increment's twist (v, w) times the interval, in the optical frame.
        degenerate: True when a motion direction was unobservable (e.g. a flat wall filling the view).
        valid_points: number of valid pixels used at the finest level.
        runtime_s: wall time spent on this frame, s.
        extra: method-specific outputs (scene flow, labels, ...), documented by each method.
    """

    stamp_s: float
    T_odom_camera: np.ndarray
    T_odom_base: np.ndarray
    twist_camera: np.ndarray
    covariance: np.ndarray
    degenerate: bool = False
    valid_points: int = 0
    runtime_s: float = 0.0
    extra: dict = field(default_factory=dict, repr=False)


class FrameOdometry(Protocol):
    """A depth or RGB-D odometry: feed frames in time order, get one estimate per frame."""

    def process(self, frame: RGBDFrame) -> CameraOdometryEstimate:
        """Estimate the motion since the previous frame; never raises on bad data (too few valid pixels keeps
        the constant-velocity prior and inflates the covariance)."""
        ...

    def reset(self) -> None:
        """Forget all history; the next frame starts a new odom frame."""
        ...


@dataclass(frozen=True)
class PlanarScan:
    """A scan from an upright virtual scanner in the base plane.

    Attributes:
        stamp_s: time stamp, s.
        ranges_m: (N,) float64 ranges, 0 = invalid (never NaN/inf).
        angles_rad: (N,) strictly increasing beam angles in the virtual scanner frame, within (-pi, pi].
        T_base_laser: (3, 3) SE(2) pose of the virtual scanner in the base frame.
        max_range_m: maximum range, m.
    """

    stamp_s: float
    ranges_m: np.ndarray
    angles_rad: np.ndarray
    T_base_laser: np.ndarray
    max_range_m: float


def planar_scan(scan: LaserScan) -> PlanarScan:
    """Upright, sorted, sanitised version of ``scan`` (invalid ranges, NaN and inf become 0)."""
    R = scan.T_base_sensor[:3, :3]
    forward = R[:, 0]
    mount_yaw = math.atan2(forward[1], forward[0])
    beams = R @ np.stack([np.cos(scan.angles_rad), np.sin(scan.angles_rad), np.zeros(len(scan.angles_rad))])
    angles = se2.wrap_angle(np.arctan2(beams[1], beams[0]) - mount_yaw)
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges >= scan.min_range_m) & (ranges <= scan.max_range_m)
    ranges = np.where(ok, ranges, 0.0)
    order = np.argsort(angles, kind="stable")
    T_base_laser = se2.from_xy_yaw(scan.T_base_sensor[0, 3], scan.T_base_sensor[1, 3], mount_yaw)
    return PlanarScan(scan.stamp_s, ranges[order], np.asarray(angles)[order], T_base_laser, scan.max_range_m)


def laser_to_base_motion(T_prev_curr_laser: np.ndarray, T_base_laser: np.ndarray) -> np.ndarray:
    """(3, 3) motion of the base between two scans, from the motion of the scanner frame."""
    return T_base_laser @ T_prev_curr_laser @ se2.inverse(T_base_laser)
