"""Differential-drive kinematics for the wheel servos: (v, w) <-> wheel speeds, limits, raw velocity units and wheel
odometry from multi-turn positions that wrap around.

Wheel speeds are "forward positive" (rad/s that move the robot forward); the sign that maps them onto a servo's own
direction (mirrored mounting, Drive Mode reverse bit) is the bridge's business.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simnav.geometry import se2
from simnav.hardware import control_table as ct


@dataclass(frozen=True)
class DiffDrive:
    """Wheel radius and separation (centre to centre), m."""

    wheel_radius_m: float
    wheel_separation_m: float

    def wheel_speeds(self, v_m_s: float, w_rad_s: float) -> tuple[float, float]:
        """Left and right wheel speeds, rad/s, for a forward speed (m/s) and a yaw rate (rad/s, CCW)."""
        half = self.wheel_separation_m / 2
        return (v_m_s - w_rad_s * half) / self.wheel_radius_m, (v_m_s + w_rad_s * half) / self.wheel_radius_m

    def twist(self, left_rad_s: float, right_rad_s: float) -> tuple[float, float]:
        """Forward speed (m/s) and yaw rate (rad/s) from the wheel speeds (rad/s)."""
        r = self.wheel_radius_m
        return r * (left_rad_s + right_rad_s) / 2, r * (right_rad_s - left_rad_s) / self.wheel_separation_m


def clamp_wheels(left_rad_s: float, right_rad_s: float, max_rad_s: float) -> tuple[float, float]:
    """Scale both wheel speeds down together so that neither exceeds ``max_rad_s`` (the path's curvature is kept)."""
    peak = max(abs(left_rad_s), abs(right_rad_s))
    if peak <= max_rad_s:
        return left_rad_s, right_rad_s
    scale = max_rad_s / peak
    return left_rad_s * scale, right_rad_s * scale


class TwistRamp:
    """Acceleration limits on a (v, w) command: each call moves at most ``max_acc * dt`` towards the target."""

    def __init__(self, max_acc_m_s2: float, max_ang_acc_rad_s2: float) -> None:
        self.max_acc_m_s2 = max_acc_m_s2
        self.max_ang_acc_rad_s2 = max_ang_acc_rad_s2
        self.v_m_s = 0.0
        self.w_rad_s = 0.0

    def step(self, v_m_s: float, w_rad_s: float, dt_s: float) -> tuple[float, float]:
        """The command after one period of ``dt_s`` seconds, (m/s, rad/s)."""
        dv, dw = self.max_acc_m_s2 * dt_s, self.max_ang_acc_rad_s2 * dt_s
        self.v_m_s += min(dv, max(-dv, v_m_s - self.v_m_s))
        self.w_rad_s += min(dw, max(-dw, w_rad_s - self.w_rad_s))
        return self.v_m_s, self.w_rad_s

    def reset(self, v_m_s: float = 0.0, w_rad_s: float = 0.0) -> None:
        """Set the current command (e.g. to zero after a stop)."""
        self.v_m_s, self.w_rad_s = v_m_s, w_rad_s


def rad_s_to_raw(rad_s: float) -> int:
    """Goal Velocity units (0.229 rpm) for a speed in rad/s, rounded."""
    return round(rad_s / ct.VELOCITY_UNIT_RAD_S)


def raw_to_rad_s(raw: int) -> float:
    """Speed in rad/s of a Present Velocity value."""
    return raw * ct.VELOCITY_UNIT_RAD_S


def to_int32(value: int) -> int:
    """A 4-byte register read as unsigned (as the SDK returns it) interpreted as two's complement."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value & 0x80000000 else value


def position_delta(previous: int, current: int) -> int:
    """Ticks moved between two int32 Present Position readings, across the int32 wrap-around (the shortest way)."""
    return to_int32(current - previous)


class WheelOdometer:
    """Dead reckoning from the wheel servos' multi-turn positions.

    Args:
        drive: wheel radius and separation.
        signs: per wheel (left, right), +1 or -1: the sign that turns a servo position into forward rotation.
    """

    def __init__(self, drive: DiffDrive, signs: tuple[int, int]) -> None:
        self.drive = drive
        self.signs = signs
        self._last: tuple[int, int] | None = None
        self.ticks = (0, 0)  # cumulative forward ticks since the first reading, left and right
        self.T_odom_base = np.eye(3)

    @property
    def pose_xyt(self) -> tuple[float, float, float]:
        """Pose of the base in the odom frame: x m, y m, yaw rad."""
        return se2.to_xy_yaw(self.T_odom_base)

    def rebase(self) -> None:
        """Forget the last reading (after a reconnect the servo may have rebooted): the next one moves nothing."""
        self._last = None

    def update(self, left_raw: int, right_raw: int) -> tuple[float, float, float]:
        """Add one reading of both Present Positions (raw, int32); returns the pose (x m, y m, yaw rad)."""
        current = (to_int32(left_raw), to_int32(right_raw))
        last, self._last = self._last, current
        if last is None:
            return self.pose_xyt
        steps = [s * position_delta(a, b) for s, a, b in zip(self.signs, last, current)]
        self.ticks = (self.ticks[0] + steps[0], self.ticks[1] + steps[1])
        per_tick = 2 * math.pi / ct.TICKS_PER_REV
        ds_m, dyaw_rad = self.drive.twist(steps[0] * per_tick, steps[1] * per_tick)
        # one increment along a circular arc: the exponential map of the twist
        self.T_odom_base = self.T_odom_base @ se2.exp((ds_m, 0.0, dyaw_rad))
        return self.pose_xyt
