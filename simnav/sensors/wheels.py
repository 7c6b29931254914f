"""Wheel encoders of a differential drive: wheel angles integrated from the base motion, slip noise per
reading interval, counts quantised to the encoder resolution."""

from __future__ import annotations

import math

import numpy as np

from simnav.robot.spec import Drive, WheelEncoderSensor
from simnav.sensors.readings import WheelTicks

DEFAULT_RATE_HZ = 50.0


class WheelEncoders:
    """Encoders on both wheels; :meth:`integrate` is called every physics step with the true base twist."""

    def __init__(self, spec: WheelEncoderSensor, drive: Drive) -> None:
        self.name = spec.name
        self.period_s = 1.0 / (spec.rate_hz or DEFAULT_RATE_HZ)
        self.latency_s = spec.latency_s
        self._drive = drive
        self.reset()

    def reset(self) -> None:
        """Zero the wheel angles and the counts."""
        self._true_rad = np.zeros(2)  # left, right wheel angles from the true motion
        self._last_true_rad = np.zeros(2)
        self._measured_rad = np.zeros(2)

    def integrate(self, v_m_s: float, w_rad_s: float, dt_s: float) -> None:
        """Advance the true wheel angles by one step of base motion (v forward, w counter-clockwise)."""
        half = self._drive.wheel_separation_m / 2
        wheel_speed = np.array([v_m_s - w_rad_s * half, v_m_s + w_rad_s * half]) / self._drive.wheel_radius_m
        self._true_rad += wheel_speed * dt_s

    def capture(self, stamp_s: float, rng: np.random.Generator) -> WheelTicks:
        """Counts at ``stamp_s``: the increment since the last reading, scaled by (1 + slip), accumulated."""
        increment = self._true_rad - self._last_true_rad
        self._last_true_rad = self._true_rad.copy()
        slip = rng.normal(0.0, self._drive.slip_std, 2) if self._drive.slip_std > 0 else 0.0
        self._measured_rad += increment * (1.0 + slip)
        ticks = np.floor(self._measured_rad / (2 * math.pi) * self._drive.ticks_per_rev).astype(np.int64)
        return WheelTicks(sensor=self.name, stamp_s=stamp_s, left_ticks=int(ticks[0]), right_ticks=int(ticks[1]),
                          ticks_per_rev=self._drive.ticks_per_rev, wheel_radius_m=self._drive.wheel_radius_m,
                          wheel_separation_m=self._drive.wheel_separation_m)
