"""Differential-drive kinematics, limits, raw units and wheel odometry across the int32 position wrap-around."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from simnav.hardware.kinematics import (
    DiffDrive,
    TwistRamp,
    WheelOdometer,
    clamp_wheels,
    position_delta,
    rad_s_to_raw,
    raw_to_rad_s,
    to_int32,
)

MINIBOT = DiffDrive(wheel_radius_m=0.033, wheel_separation_m=0.16)
speeds = st.floats(-1.0, 1.0)


@given(speeds, speeds)
def test_wheel_speeds_and_twist_are_inverse(v, w):
    left, right = MINIBOT.wheel_speeds(v, w)
    assert MINIBOT.twist(left, right) == pytest.approx((v, w), abs=1e-12)


def test_wheel_speeds_of_pure_motions():
    assert MINIBOT.wheel_speeds(0.33, 0.0) == pytest.approx((10.0, 10.0))
    left, right = MINIBOT.wheel_speeds(0.0, 1.0)  # turning left: left wheel back, right wheel forward
    assert left == pytest.approx(-0.08 / 0.033) and right == pytest.approx(0.08 / 0.033)


@given(st.floats(-50, 50), st.floats(-50, 50), st.floats(0.5, 20))
def test_clamping_keeps_the_curvature(left, right, limit):
    cl, cr = clamp_wheels(left, right, limit)
    assert max(abs(cl), abs(cr)) <= limit + 1e-9
    assert cl * right == pytest.approx(cr * left, abs=1e-9)  # same ratio
    if max(abs(left), abs(right)) <= limit:
        assert (cl, cr) == (left, right)


def test_ramp_limits_the_change_per_period():
    ramp = TwistRamp(max_acc_m_s2=1.0, max_ang_acc_rad_s2=2.0)
    assert ramp.step(0.5, -1.0, 0.1) == pytest.approx((0.1, -0.2))
    for _ in range(10):
        v, w = ramp.step(0.5, -1.0, 0.1)
    assert (v, w) == pytest.approx((0.5, -1.0))


def test_raw_velocity_units():
    assert raw_to_rad_s(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert rad_s_to_raw(raw_to_rad_s(265)) == 265 and rad_s_to_raw(-raw_to_rad_s(337)) == -337


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-100_000, 100_000))
def test_position_delta_crosses_the_int32_wrap(start, step):
    end = to_int32(start + step)
    assert position_delta(start, end) == step
    assert position_delta(start & 0xFFFFFFFF, end & 0xFFFFFFFF) == step  # also from the SDK's unsigned reads


def test_odometry_straight_across_the_wrap_around():
    odometer = WheelOdometer(MINIBOT, signs=(1, -1))  # the right servo is mounted mirrored
    left, right = 2**31 - 1000, -(2**31) + 1000
    odometer.update(left, right)
    for _ in range(10):  # 400 ticks forward per step: both counters wrap
        left, right = to_int32(left + 400), to_int32(right - 400)
        x, y, yaw = odometer.update(left & 0xFFFFFFFF, right & 0xFFFFFFFF)
    assert odometer.ticks == (4000, 4000)
    assert x == pytest.approx(4000 / 4096 * 2 * math.pi * 0.033) and y == pytest.approx(0) and yaw == 0


def test_odometry_turns_in_place():
    odometer = WheelOdometer(MINIBOT, signs=(1, 1))
    odometer.update(0, 0)
    ticks = round(math.pi / 2 * 0.08 / 0.033 / (2 * math.pi) * 4096)  # a quarter turn of the base
    x, y, yaw = odometer.update(-ticks, ticks)
    assert yaw == pytest.approx(math.pi / 2, abs=2e-3) and x == pytest.approx(0, abs=1e-9)
