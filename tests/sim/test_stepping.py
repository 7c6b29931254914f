"""The stepping loop's bookkeeping: when it pauses and what is due, past poses, lidar noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.robot import load_robot
from simnav.sensors.noise import lidar_noise
from simnav.sim import SimConfig, Simulator

LIDAR_ONLY = ["sensors.camera.rate_hz=0.001"]


def test_pauses_and_due_steps_follow_the_time_rules(box_room):
    with Simulator(box_room, load_robot("giraff", ["sensors=[]"]), SimConfig(physics_dt_s=0.005)) as sim:
        dt = sim.config.physics_dt_s
        for t in [0.0, 0.005, 0.0300000004, 0.03000002, 0.1234, 1.0 / 30.0, 7.0 / 3.0, 12.345678901]:
            pause, first = sim._steps_at(t)
            assert pause == math.ceil(t / dt - 1e-6)
            assert first == next(k for k in range(10**5) if t <= round(k * dt, 9) + 1e-9)


def test_past_poses_are_the_poses_after_each_stretch(box_room):
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY)) as sim:
        poses = {0.0: sim.T_world_base}
        for _ in range(30):
            sim.step(0.4, 1.0)
            poses[sim.time_s] = sim.T_world_base
        for t, T in poses.items():
            np.testing.assert_allclose(sim.T_world_base_at(t), T, atol=1e-12)
            np.testing.assert_allclose(sim.T_world_base_at(t + 0.002), T, atol=1e-12)  # within a physics step


@pytest.mark.parametrize(("std_m", "dropout"), [(0.01, 0.0), (0.0, 0.0), (0.05, 0.1), (0.0, 0.3)])
def test_lidar_noise_is_numpys_gaussian_noise_and_dropouts(std_m, dropout):
    ranges = np.concatenate([np.random.default_rng(2).uniform(0.0, 6.0, 500), [0.0, -0.0, 0.019, 5.6, np.inf]])
    rng = np.random.default_rng(4)
    valid = ranges > 0
    noisy = ranges + rng.normal(0.0, std_m, ranges.shape) if std_m > 0 else ranges.copy()
    if dropout > 0:
        valid &= rng.random(ranges.shape) >= dropout
    valid &= (noisy >= 0.02) & (noisy <= 5.6) & np.isfinite(noisy)
    expected = np.where(valid, noisy, 0.0).astype(np.float32)
    np.testing.assert_array_equal(lidar_noise(ranges, np.random.default_rng(4), std_m, dropout, 0.02, 5.6), expected)


def test_mujocos_timer_callback_is_put_back_after_each_step(box_room):
    """While the simulator steps, MuJoCo's stage timers read no clock (simnav.sim.native.quiet_timers); the timer
    callback in place before is in place again after each step, also when a step fails."""
    import ctypes

    from simnav.errors import SimnavError
    from simnav.sim import native

    assert native.MJCB_TIME, "the mujoco package's library exports mjcb_time"
    slot = ctypes.c_void_p.from_address(native.MJCB_TIME)
    before = slot.value
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY)) as sim:
        for _ in range(5):
            sim.step(0.4, 0.5)
            assert slot.value == before
        with pytest.raises(SimnavError):
            sim.step(math.nan, 0.0)
        assert slot.value == before
        sim._capture_due = None  # a failure inside the stepping loop
        with pytest.raises(TypeError):
            sim.step(0.4, 0.5)
        assert slot.value == before


def test_without_the_timer_callback_quieting_timers_does_nothing(monkeypatch):
    from simnav.sim import native

    monkeypatch.setattr(native, "_TIMER_SLOT", None)
    previous = native.quiet_timers()
    assert previous is None
    native.restore_timers(previous)  # nothing to put back, no error


def test_the_pose_history_is_a_bounded_deque_of_tuples():
    from collections import deque

    from simnav.sim.simulator import PoseHistory

    rng = np.random.default_rng(0)
    history, reference = PoseHistory(64), deque(maxlen=64)
    for k in range(150):
        entry = (k, *rng.normal(size=3).tolist())
        history.append(entry)
        reference.append(entry)
        if k in (0, 10, 63, 64, 65, 149):
            assert list(history) == list(reference) and len(history) == len(reference)
            for i in (0, len(reference) // 2, len(reference) - 1, -1, -len(reference)):
                assert history[i] == reference[i] and type(history[i][0]) is int
    with pytest.raises(IndexError):
        history[64]
