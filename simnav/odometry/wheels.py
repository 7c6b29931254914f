"""Wheel odometry: dead reckoning of a differential drive from cumulative encoder counts."""

from __future__ import annotations

import math

import numpy as np

from simnav.sensors.readings import WheelTicks


class WheelOdometry:
    """Integrates :class:`WheelTicks` into a planar pose ``(x, y, yaw)`` of the base in the ``odom`` frame.

    Each increment is integrated exactly along a circular arc (the exponential map of the se(2) twist).
    """

    def __init__(self) -> None:
        self._last: WheelTicks | None = None
        self.pose_xyt = np.zeros(3)
        self.twist = (0.0, 0.0)  # forward speed m/s, yaw rate rad/s over the last increment
        self.stamp_s = 0.0

    def update(self, ticks: WheelTicks) -> np.ndarray:
        """Add one reading; returns the (3,) pose ``x_m, y_m, yaw_rad`` of the base in the odom frame."""
        last, self._last = self._last, ticks
        self.stamp_s = ticks.stamp_s
        if last is None:
            return self.pose_xyt.copy()
        per_tick = 2 * math.pi * ticks.wheel_radius_m / ticks.ticks_per_rev
        d_left = (ticks.left_ticks - last.left_ticks) * per_tick
        d_right = (ticks.right_ticks - last.right_ticks) * per_tick
        ds = (d_left + d_right) / 2
        dyaw = (d_right - d_left) / ticks.wheel_separation_m
        self._integrate(ds, dyaw)
        dt = ticks.stamp_s - last.stamp_s
        self.twist = (ds / dt, dyaw / dt) if dt > 0 else (0.0, 0.0)
        return self.pose_xyt.copy()

    def _integrate(self, ds: float, dyaw: float) -> None:
        x, y, yaw = self.pose_xyt
        if abs(dyaw) < 1e-9:
            dx, dy = ds, 0.0
        else:
            radius = ds / dyaw
            dx, dy = radius * math.sin(dyaw), radius * (1 - math.cos(dyaw))
        c, s = math.cos(yaw), math.sin(yaw)
        yaw_new = math.atan2(math.sin(yaw + dyaw), math.cos(yaw + dyaw))
        self.pose_xyt = np.array([x + c * dx - s * dy, y + s * dx + c * dy, yaw_new])
