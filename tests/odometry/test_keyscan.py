"""Learned keyscan policy (thesis §3.G.7): shipped models, monotonicity, the constrained fit, loading, use in SRF;
the keyscan overlap."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simnav.errors import ConfigError, UnknownNameError
from simnav.geometry import se2
from simnav.odometry.keyscan import (
    DEFAULT_EXPONENTS,
    LearnedKeyscanPolicy,
    available_presets,
    fit_logistic,
    fit_working_region,
    keyscan_overlap,
    monomials,
    sigmoid,
)
from simnav.odometry.rangeflow import level_geometry
from simnav.odometry.srf import KeyscanPolicy, SRFOdometry
from simnav.sensors.presets import LIDAR2D_PRESETS

PRESETS = sorted(LIDAR2D_PRESETS)
QUADRATIC = ((0, 0), (1, 0), (0, 1), (2, 0), (0, 2), (1, 1))
TRUE_COEFFICIENTS = np.array([3.0, -1.0, -6.0, -0.5, -4.0, -1.0])  # of QUADRATIC: 1, t, r, t², r², t·r


def _synthetic(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n pairs uniform in [0, 1] m x [-1, 1] rad labelled by Bernoulli draws of the true logistic model."""
    rng = np.random.default_rng(seed)
    t, r = rng.uniform(0, 1, n), rng.uniform(-1, 1, n)
    p = sigmoid(monomials(t, r, QUADRATIC) @ TRUE_COEFFICIENTS)
    return t, r, rng.random(n) < p


def _increases(policy: LearnedKeyscanPolicy, points: int = 201) -> tuple[float, float]:
    """Largest increase of P between neighbours of a grid over the domain, along t and along r."""
    t, r = np.meshgrid(np.linspace(0, policy.max_translation_m, points), np.linspace(0, policy.max_rotation_rad,
                                                                                        points))
    p = policy.probabilities(t.ravel(), r.ravel()).reshape(t.shape)
    return float(np.diff(p, axis=1).max()), float(np.diff(p, axis=0).max())


@pytest.mark.parametrize("preset", PRESETS)
def test_shipped_model_loads_for_every_lidar2d_preset(preset):
    assert preset in available_presets()
    policy = LearnedKeyscanPolicy.from_preset(preset)
    assert isinstance(policy, KeyscanPolicy) and policy.name == preset
    assert policy.exponents == DEFAULT_EXPONENTS
    assert 0.5 < policy.probability_good(0.0, 0.0) <= 1.0
    assert policy.max_rotation(0.0) > 0.02 and policy.max_translation(0.0) > 0.1  # a usable working region


@pytest.mark.parametrize("preset", PRESETS)
def test_keeps_the_keyscan_for_tiny_motions_and_replaces_it_for_large_ones(preset):
    policy = LearnedKeyscanPolicy.from_preset(preset)
    assert not policy.needs_new_keyscan(0.01, 0.005)
    assert not policy.needs_new_keyscan(0.01, -0.005)
    assert policy.needs_new_keyscan(1.0, 1.0)
    assert policy.needs_new_keyscan(1.0, -1.0)
    assert policy.needs_new_keyscan(0.0, 2.0) and policy.needs_new_keyscan(5.0, 0.0)  # beyond the samples
    assert policy.needs_new_keyscan(float("nan"), 0.0)


@pytest.mark.parametrize("preset", PRESETS)
def test_probability_decreases_along_rays_from_the_origin(preset):
    policy = LearnedKeyscanPolicy.from_preset(preset)
    s = np.linspace(0.0, 1.0, 101)
    for angle in np.linspace(0.0, math.pi / 2, 19):
        for sign in (1.0, -1.0):
            p = policy.probabilities(s * math.cos(angle), sign * s * math.sin(angle))
            assert np.all(np.diff(p) <= 1e-6), (angle, sign)  # constrained on a grid; tiny slack between nodes
    assert max(_increases(policy)) <= 1e-6


def test_boundary_extents_match_the_region_test():
    policy = LearnedKeyscanPolicy.from_preset("hokuyo_utm30lx", margin=0.0)
    r_max, t_max = policy.max_rotation(0.0), policy.max_translation(0.05)
    assert policy.inside(0.0, 0.99 * r_max) and not policy.inside(0.0, 1.01 * r_max)
    assert policy.inside(0.99 * t_max, 0.05)
    assert t_max == policy.max_translation_m or not policy.inside(1.01 * t_max, 0.05)
    assert policy.probability_good(0.0, r_max) == pytest.approx(policy.level, abs=1e-4)


def test_margin_shrinks_the_region():
    policy = LearnedKeyscanPolicy.from_preset("hokuyo_utm30lx", margin=0.0)
    r = 0.95 * policy.max_rotation(0.0)
    assert not policy.needs_new_keyscan(0.0, r)
    wide = LearnedKeyscanPolicy.from_preset("hokuyo_utm30lx", margin=0.2)
    assert wide.margin == 0.2 and wide.needs_new_keyscan(0.0, r)


@pytest.mark.parametrize("exponents", [QUADRATIC, DEFAULT_EXPONENTS])
def test_fit_recovers_a_known_logistic_model(exponents):
    t, r, good = _synthetic(40000)
    fitted = LearnedKeyscanPolicy(exponents, tuple(fit_working_region(t, r, good, exponents)))
    truth = LearnedKeyscanPolicy(QUADRATIC, tuple(TRUE_COEFFICIENTS))
    gt, gr = np.meshgrid(np.linspace(0, 1, 21), np.linspace(0, 1, 21))
    diff = fitted.probabilities(gt.ravel(), gr.ravel()) - truth.probabilities(gt.ravel(), gr.ravel())
    assert np.max(np.abs(diff)) < 0.04
    assert fitted.max_rotation(0.0) == pytest.approx(truth.max_rotation(0.0), abs=0.03)
    assert fitted.max_translation(0.1) == pytest.approx(truth.max_translation(0.1), abs=0.06)
    assert fitted.level == pytest.approx(truth.level, abs=0.02)


def test_fit_recovers_a_sharp_elliptic_boundary():
    rng = np.random.default_rng(1)
    t, r = rng.uniform(0, 1, 20000), rng.uniform(0, 1, 20000)
    good = (t / 0.7) ** 2 + (r / 0.3) ** 2 < 1.0
    coefficients = fit_working_region(t, r, good, ridge=1e-8)  # separable: a weak ridge keeps them finite
    assert np.all(np.isfinite(coefficients))
    predicted = sigmoid(monomials(t, r) @ coefficients) > 0.5
    assert np.mean(predicted == good) > 0.98
    policy = LearnedKeyscanPolicy(DEFAULT_EXPONENTS, tuple(coefficients), p_ratio=0.5 / sigmoid(coefficients[0]))
    assert policy.max_rotation(0.0) == pytest.approx(0.3, abs=0.02)
    assert policy.max_translation(0.0) == pytest.approx(0.7, abs=0.03)


@pytest.mark.parametrize("exponents", [QUADRATIC, DEFAULT_EXPONENTS])
def test_fit_keeps_the_model_monotone_when_the_data_is_not(exponents):
    rng = np.random.default_rng(2)
    t, r = rng.uniform(0, 1, 5000), rng.uniform(0, 1, 5000)
    good = rng.random(5000) < sigmoid(-1.0 + 2.0 * t - 3.0 * r)  # improves with translation: not physical
    policy = LearnedKeyscanPolicy(exponents, tuple(fit_working_region(t, r, good, exponents)))
    up_t, up_r = _increases(policy)
    assert up_t <= 1e-6 and up_r <= 1e-6
    p = policy.probabilities(np.linspace(0, 1, 11), np.full(11, 0.2))
    assert p[0] - p[-1] < 0.02  # as flat in t as the constraint allows
    assert policy.probability_good(0.0, 0.0) - policy.probability_good(0.0, 1.0) > 0.3  # the r trend is kept


def test_fit_logistic_needs_a_strictly_feasible_start():
    with pytest.raises(ValueError, match="strictly"):
        fit_logistic(np.ones((4, 2)), np.array([0, 1, 0, 1]), np.array([[0.0, 1.0]]), np.zeros(2))


def test_dict_round_trip():
    policy = LearnedKeyscanPolicy.from_preset("sick_lms200")
    assert LearnedKeyscanPolicy.from_dict(json.loads(json.dumps(policy.to_dict()))) == policy


def test_unknown_preset_lists_the_available_ones():
    with pytest.raises(UnknownNameError, match="hokuyo_utm30lx"):
        LearnedKeyscanPolicy.from_preset("velodyne_hdl64")


@pytest.mark.parametrize(
    ("text", "reason"),
    [("{not json", "JSON"),
     ('{"format": "simnav.keyscan_model/1", "p_ratio": 0.9}', "model"),
     ('{"format": "other"}', "format"),
     ('{"format": "simnav.keyscan_model/1", "p_ratio": 0.9, "domain": {"max_translation_m": 1,'
      ' "max_rotation_rad": 1}, "model": {"exponents": [[0, 0], [1, 0]], "coefficients": [1.0]}}', "coefficients")],
)
def test_malformed_file_gives_an_error_naming_it(tmp_path, text, reason):
    path = tmp_path / "broken_model.json"
    path.write_text(text)
    with pytest.raises(ConfigError, match=reason) as err:
        LearnedKeyscanPolicy.from_file(path)
    assert str(path) in str(err.value)


def test_bad_overrides_and_fields_are_config_errors():
    with pytest.raises(ConfigError, match="bad override"):
        LearnedKeyscanPolicy.from_preset("lds01", marg=0.2)
    with pytest.raises(ConfigError, match="margin"):
        LearnedKeyscanPolicy.from_preset("lds01", margin=-0.1)
    with pytest.raises(ConfigError, match="exponents"):
        LearnedKeyscanPolicy(((0, 0), (-1, 0)), (1.0, -1.0))


def test_missing_file_gives_an_error_naming_it(tmp_path):
    with pytest.raises(ConfigError, match="absent.json"):
        LearnedKeyscanPolicy.from_file(tmp_path / "absent.json")


def test_srf_multi_scan_with_the_learned_policy_creates_keyscans(rangesim):
    poses = rangesim.trajectory(60, speed_mps=0.6, yaw_amplitude_rad=0.4)
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), noise_m=0.01, seed=3)
    odo = SRFOdometry(mode="MA", keyscan_policy=LearnedKeyscanPolicy.from_preset("hokuyo_utm30lx"))
    out = [odo.process(sim.scan(T, 0.1 * i)) for i, T in enumerate(poses)]
    new = [o.extra["new_keyscan"] for o in out]
    assert new[0] and 2 <= sum(new[1:]) <= len(new) // 3  # keyscans are replaced, but not at every scan
    T_true = se2.inverse(poses[0]) @ poses[-1]
    E = se2.inverse(T_true) @ out[-1].T_odom_base
    assert math.hypot(E[0, 2], E[1, 2]) < 0.05 and abs(math.atan2(E[1, 0], E[0, 0])) < math.radians(1.0)


def test_srf_picks_the_learned_model_of_the_matching_preset():
    from simnav.odometry.srf import closest_preset
    from simnav.sensors.readings import LaserScan

    def scan(beams, fov_deg):
        angles = np.linspace(-np.radians(fov_deg) / 2, np.radians(fov_deg) / 2, beams)
        return LaserScan("l", 0.0, np.ones(beams, np.float32), angles, 30.0, 0.1, np.eye(4))

    assert closest_preset(scan(1080, 270)) == "hokuyo_utm30lx"
    assert closest_preset(scan(682, 240)) == "hokuyo_urg04lx"
    assert closest_preset(scan(361, 180)) == "sick_lms200"
    odometry = SRFOdometry(mode="MA")
    odometry.process(scan(1080, 270))
    assert isinstance(odometry._policy, LearnedKeyscanPolicy)
    with pytest.raises(ConfigError, match="keyscan_policy"):
        SRFOdometry(keyscan_policy="no_such_scanner")


def _overlap_of(sim, T_key: np.ndarray, T_new: np.ndarray, key_valid: np.ndarray | None = None) -> float:
    """keyscan_overlap of the scans cast from base poses T_key and T_new (scanner at the base origin), 2-degree
    bins, 0.3 m tolerance; ``key_valid`` masks keyscan beams."""
    geom = level_geometry(sim.angles_rad, circular=False)
    key = sim.scan(T_key).ranges_m.astype(np.float64)
    new = sim.scan(T_new).ranges_m.astype(np.float64)
    if key_valid is not None:
        key = np.where(key_valid, key, 0.0)
    return keyscan_overlap(key, geom, se2.inverse(T_new) @ T_key, new, geom, 0.3, 8)


def test_overlap_of_a_view_with_itself_is_one_and_falls_with_what_the_keyscan_missed(rangesim):
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270))
    T = se2.from_xy_yaw(2.5, 2.2, 0.3)
    assert _overlap_of(sim, T, T) == 1.0
    assert _overlap_of(sim, T, T @ se2.from_xy_yaw(0.05, 0.02, 0.03)) > 0.97  # a small motion changes little
    left_half = np.arange(1080) >= 540
    assert _overlap_of(sim, T, T, key_valid=left_half) == pytest.approx(0.5, abs=0.01)  # bins, not beams
    assert _overlap_of(sim, T, T, key_valid=np.zeros(1080, dtype=bool)) == 0.0


def test_overlap_needs_agreeing_ranges_and_a_valid_new_scan(rangesim):
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270))
    geom = level_geometry(sim.angles_rad, circular=False)
    r = sim.scan(se2.from_xy_yaw(2.5, 2.2, 0.3)).ranges_m.astype(np.float64)
    assert keyscan_overlap(r, geom, np.eye(3), r + 0.25, geom, 0.3, 8) == 1.0
    assert keyscan_overlap(r, geom, np.eye(3), r + 0.35, geom, 0.3, 8) == 0.0  # another surface
    assert keyscan_overlap(r, geom, np.eye(3), np.zeros_like(r), geom, 0.3, 8) == 0.0
