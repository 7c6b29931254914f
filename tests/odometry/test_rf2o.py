"""RF2O (thesis §3.F): accuracy on synthetic rooms, configuration, registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.errors import ConfigError
from simnav.geometry import se2
from simnav.odometry import make_scan_odometry
from simnav.odometry.rf2o import RF2O, RF2OConfig

T_WORLD_START = se2.from_xy_yaw(2.5, 2.2, 0.3)
T_MOTION = se2.from_xy_yaw(0.05, 0.02, math.radians(3.0))  # 5 cm forward, 2 cm left, 3 deg


def _pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (m) and |rotation| (deg) of ``inv(T_true) @ T_est``."""
    E = se2.inverse(T_true) @ T_est
    return math.hypot(E[0, 2], E[1, 2]), abs(math.degrees(math.atan2(E[1, 0], E[0, 0])))


def _two_scan_error(rangesim, noise_m: float, seed: int, T_motion: np.ndarray = T_MOTION, **config):
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), noise_m=noise_m, seed=seed)
    odo = RF2O(**config)
    odo.process(sim.scan(T_WORLD_START, 0.0))
    est = odo.process(sim.scan(T_WORLD_START @ T_motion, 0.1))
    return _pose_error(est.T_odom_base, T_motion)


def test_two_scans_noise_free(rangesim):
    dist, yaw = _two_scan_error(rangesim, 0.0, 0)
    assert dist < 1e-3 and yaw < 0.02  # measured: 0.05 mm, 0.003 deg


@pytest.mark.parametrize("seed", range(3))
def test_two_scans_with_1cm_noise(rangesim, seed):
    dist, yaw = _two_scan_error(rangesim, 0.01, seed)
    assert dist < 0.01 and yaw < 0.3  # measured: <= 1 mm, <= 0.02 deg


def test_large_motion_is_recovered_by_coarse_to_fine(rangesim):
    T_big = se2.from_xy_yaw(0.3, -0.1, math.radians(8.0))
    dist, yaw = _two_scan_error(rangesim, 0.01, 0, T_motion=T_big)
    assert dist < 0.01 and yaw < 0.3


def test_sequence_drift_is_below_one_percent(rangesim):
    poses = rangesim.trajectory(50, speed_mps=0.8)
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), noise_m=0.01, seed=4)
    odo = RF2O()
    out = [odo.process(sim.scan(T, 0.1 * i)) for i, T in enumerate(poses)]
    length = sum(np.hypot(*(se2.inverse(a) @ b)[:2, 2]) for a, b in zip(poses, poses[1:]))
    dist, yaw = _pose_error(out[-1].T_odom_base, se2.inverse(poses[0]) @ poses[-1])
    assert length > 3.5
    assert dist < 0.01 * length and yaw < 0.5  # measured: about 0.2 % and 0.1 deg
    assert not any(est.degenerate for est in out)


@pytest.mark.parametrize("config", [dict(inter_geometry=False), dict(smooth_finest=False), dict(cauchy_k_ratio=1.0),
                                    dict(levels=3, irls_iterations=2)])
def test_options_keep_the_estimate_accurate(rangesim, config):
    dist, yaw = _two_scan_error(rangesim, 0.01, 1, **config)
    assert dist < 0.01 and yaw < 0.3


def test_config_defaults_and_errors():
    cfg = RF2O().config
    assert isinstance(cfg, RF2OConfig)
    assert (cfg.levels, cfg.irls_iterations, cfg.filter_kl, cfg.filter_ke) == (5, 5, 0.05, 15e3)
    assert RF2O(levels=3).config.levels == 3
    with pytest.raises(ConfigError, match=r"unknown RF2O option\(s\): bogus; allowed: .*cauchy_k_ratio"):
        RF2O(bogus=1)
    with pytest.raises(ConfigError, match="cauchy_k_ratio"):
        RF2O(cauchy_k_ratio=0.0)
    with pytest.raises(ConfigError):
        make_scan_odometry("rf2o", mode="MA")  # an SRF option


def test_registry_builds_a_configured_rf2o():
    odo = make_scan_odometry("rf2o", levels=4)
    assert isinstance(odo, RF2O) and odo.config.levels == 4
