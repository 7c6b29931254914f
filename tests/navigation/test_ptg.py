"""PTG families: path geometry against closed forms, alpha <-> index, commands, and the inverse map (MRPT's tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.errors import ConfigError
from simnav.navigation.ptg import PTG, PTG_FAMILIES, PTGConfig, alpha_to_index, index_to_alpha

V, W = 0.6, math.radians(90.0)
FAMILY_CASES = [(f, b) for f in PTG_FAMILIES for b in (False, True)]


@pytest.fixture(scope="module")
def ptgs() -> dict[tuple[str, bool], PTG]:
    return {(f, b): PTG(family=f, backward=b, num_paths=31, v_max_mps=V, w_max_radps=W) for f, b in FAMILY_CASES}


def test_alpha_index_convention() -> None:
    N = 121
    k = np.arange(N)
    a = index_to_alpha(k, N)
    np.testing.assert_allclose(a, np.pi * (-1 + 2 * (k + 0.5) / N))
    assert a[60] == 0.0 and -np.pi < a[0] and a[-1] < np.pi
    np.testing.assert_allclose(a, -a[::-1], atol=1e-15)
    np.testing.assert_array_equal(alpha_to_index(a, N), k)
    # wrapping and clamping: +-pi and 3 pi map to the last path, a bit above -pi to the first
    assert alpha_to_index(np.pi, N) == N - 1 and alpha_to_index(-np.pi, N) == N - 1
    assert alpha_to_index(3 * np.pi, N) == N - 1 and alpha_to_index(-np.pi + 1e-6, N) == 0
    assert alpha_to_index(a[17] + 0.49 * 2 * np.pi / N, N) == 17
    assert isinstance(alpha_to_index(0.3, N), int) and isinstance(index_to_alpha(3, N), float)


@pytest.mark.parametrize("family, backward", FAMILY_CASES)
def test_paths_start_at_origin_in_the_commanded_direction(ptgs, family, backward) -> None:
    p = ptgs[(family, backward)]
    np.testing.assert_array_equal(p.poses[:, 0], 0.0)
    np.testing.assert_array_equal(p.dist_m[:, 0], 0.0)
    assert np.all(p.num_samples >= 2)
    v0, w0 = p.commands[:, 0], p.commands[:, 1]
    assert np.all(np.abs(v0) <= V + 1e-12) and np.all(np.abs(w0) <= W + 1e-12)
    step = p.poses[:, 1] - p.poses[:, 0]
    moving = np.abs(v0) > 1e-3
    assert np.all(np.sign(step[moving, 0]) == np.sign(v0[moving]))  # drives forward / backward as commanded
    turning = np.abs(w0) > 1e-3
    assert np.all(np.sign(step[turning, 2]) == np.sign(w0[turning]))
    assert p.direction_to_motion_command(3) == (float(v0[3]), float(w0[3]))
    # monotone distance and time, ending at the horizon unless the turn limit stopped the path
    last = p.num_samples - 1
    assert np.all(np.diff(p.dist_m, axis=1) >= 0) and np.all(np.diff(p.time_s, axis=1) >= 0)
    turned = np.abs(p.poses[np.arange(p.num_paths), last, 2])
    at_ref = np.isclose(p.path_end_norm, 1.0)
    assert np.all(at_ref | np.isclose(turned, p.config.max_turn_rad))


def test_initial_commands_follow_mrpt_formulas(ptgs) -> None:
    a = ptgs[("C", False)].alphas_rad
    np.testing.assert_allclose(ptgs[("C", False)].commands, np.c_[np.full_like(a, V), a / np.pi * W])
    np.testing.assert_allclose(ptgs[("C", True)].commands, -np.c_[np.full_like(a, V), a / np.pi * W])
    al = ptgs[("alpha", False)].commands
    np.testing.assert_allclose(al[:, 0], V * np.exp(-((a / math.radians(45)) ** 2)))
    np.testing.assert_allclose(al[:, 1], W * (1 / (1 + np.exp(-a / math.radians(45))) - 0.5))
    cs = ptgs[("CS", False)].commands
    np.testing.assert_allclose(cs[:, 1], np.sign(a) * W * (1 - np.exp(-(a**2))))
    ccs = ptgs[("CCS", False)].commands
    nz = np.abs(a) > 1e-9
    np.testing.assert_allclose(ccs[nz, 0], -V)  # reverse arc first (u = |alpha| / 2 > 0)


@pytest.mark.parametrize("backward", [False, True])
def test_c_paths_are_arcs_of_the_analytic_radius(ptgs, backward) -> None:
    p = ptgs[("C", backward)]
    r_ref = p.config.turning_radius_ref_m
    for k in (0, 3, 9, 14, 20, 27, 30):
        a = p.alphas_rad[k]
        n = p.num_samples[k]
        xy, phi, d = p.poses[k, :n, :2], p.poses[k, :n, 2], p.dist_m[k, :n]
        R = (V / W) * np.pi / a  # signed: > 0 turns left (forward)
        np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1] - R), abs(R), atol=1e-9)
        # pseudo-metres: d = |theta| sqrt(R^2 + r_ref^2), and theta = phi
        np.testing.assert_allclose(d, np.abs(phi) * math.hypot(R, r_ref), rtol=1e-9, atol=1e-12)
    k0 = p.num_paths // 2  # alpha = 0: straight to the horizon
    n = p.num_samples[k0]
    np.testing.assert_allclose(p.poses[k0, :n, 1:], 0.0, atol=1e-12)
    assert p.poses[k0, n - 1, 0] == pytest.approx(-5.0 if backward else 5.0)


def test_cs_turns_then_goes_straight_and_alpha_converges_to_alpha(ptgs) -> None:
    cs = ptgs[("CS", False)]
    k = 27
    a = cs.alphas_rad[k]
    T = 0.847 * math.sqrt(abs(a)) / W
    n = cs.num_samples[k]
    after = cs.time_s[k, :n] >= T - 1e-9
    heading = 0.847 * math.sqrt(abs(a)) * (1 - math.exp(-(a**2)))
    np.testing.assert_allclose(cs.poses[k, :n, 2][after], heading, atol=1e-9)
    al = ptgs[("alpha", False)]
    end = al.poses[np.arange(al.num_paths), al.num_samples - 1, 2]
    np.testing.assert_allclose(np.angle(np.exp(1j * (end - al.alphas_rad))), 0.0, atol=0.02)


@pytest.mark.parametrize("family", PTG_FAMILIES)
def test_step_and_distance_are_consistent(ptgs, family) -> None:
    """MRPT's test: dist(step_for_distance(d)) is within 5 cm of d for d below half the horizon."""
    p = ptgs[(family, False)]
    for k in range(p.num_paths):
        for d in np.linspace(0, min(p.ref_distance_m / 2, p.dist_m[k, p.num_samples[k] - 1]), 25):
            n = p.step_for_distance(k, d)
            assert abs(p.dist_m[k, n] - d) < 0.05
            assert n == 0 or p.dist_m[k, n] <= d


@pytest.mark.parametrize("family, backward", FAMILY_CASES)
def test_inverse_map_round_trip(ptgs, family, backward) -> None:
    p = ptgs[(family, backward)]
    rng = np.random.default_rng(7)
    k = rng.integers(0, p.num_paths, 300)
    d = rng.uniform(0.02, 1.0, 300) * p.path_end_norm[k]
    xy = np.array([p.pose_at(kk, dd)[:2] for kk, dd in zip(k, d)])
    k2, d2, exact, err = p.inverse_map_ws2tp_many(xy)
    assert exact.all() and np.all(err <= 0.10)
    back = np.array([p.pose_at(kk, dd)[:2] for kk, dd in zip(k2, d2)])
    np.testing.assert_allclose(back, xy, atol=0.01)  # (k', d') lands on the point (paths may cross)
    if family == "alpha":  # the alpha paths do not cross: the same path and distance come back
        np.testing.assert_array_equal(k2, k)
        np.testing.assert_allclose(d2, d, atol=1e-3)
    one = p.inverse_map_ws2tp(*xy[0])
    assert (one.k, one.exact) == (k2[0], True) and one.alpha_rad == p.alphas_rad[one.k]


def test_inverse_map_of_a_point_on_a_circle_matches_the_closed_form() -> None:
    p = PTG(family="C", num_paths=121, v_max_mps=V, w_max_radps=W)
    k = 75
    R = (V / W) * np.pi / p.alphas_rad[k]
    theta = 1.1
    tp = p.inverse_map_ws2tp(R * math.sin(theta), R * (1 - math.cos(theta)))
    assert tp.exact and tp.k == k
    assert tp.d_norm * p.ref_distance_m == pytest.approx(theta * math.hypot(R, p.config.turning_radius_ref_m),
                                                         abs=1e-3)


def test_inverse_map_answers_every_target(ptgs) -> None:
    """Targets behind, beside, at and far beyond the horizon all get a path and a distance (never "no command")."""
    c = ptgs[("C", False)]
    far = c.inverse_map_ws2tp(20.0, 0.0)
    assert far.k == c.num_paths // 2 and not far.exact and far.d_norm == pytest.approx(4.0, abs=0.01)
    assert c.inverse_map_ws2tp(0.0, 10.0).d_norm > 1.0
    behind = c.inverse_map_ws2tp(-3.0, 0.0)  # forward arcs never get there: sharpest turn, finite distance
    assert not behind.exact and behind.k in (0, c.num_paths - 1) and 0.5 < behind.d_norm < 1.0
    assert c.inverse_map_ws2tp(-0.4, 0.05).d_norm > 0  # close behind: still a direction and a distance
    back = ptgs[("C", True)].inverse_map_ws2tp(-3.0, 0.0)  # ... which the backward PTG reaches exactly
    assert back.exact and back.k == c.num_paths // 2 and back.d_norm == pytest.approx(0.6, abs=1e-6)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-30, 30, size=(120, 2))
    for p in ptgs.values():
        k, d, exact, err = p.inverse_map_ws2tp_many(pts)
        assert np.all((k >= 0) & (k < p.num_paths)) and np.all(np.isfinite(d)) and np.all(d >= 0)
        assert np.all(d[np.hypot(*pts.T) > 1.2 * p.ref_distance_m] > 1.0)


def test_pose_at_interpolates_and_clamps(ptgs) -> None:
    p = ptgs[("C", False)]
    k = 20
    np.testing.assert_allclose(p.pose_at(k, 0.0), 0.0)
    np.testing.assert_allclose(p.pose_at(k, 5.0), p.poses[k, p.num_samples[k] - 1])
    n = 40
    np.testing.assert_allclose(p.pose_at(k, p.dist_m[k, n] / p.ref_distance_m), p.poses[k, n], atol=1e-12)


def test_config_validation_and_overrides() -> None:
    with pytest.raises(ConfigError):
        PTGConfig(family="S")
    with pytest.raises(ConfigError):
        PTGConfig(num_paths=1)
    with pytest.raises(ConfigError):
        PTGConfig(v_max_mps=0.0)
    p = PTG(PTGConfig(family="CS", num_paths=11), ref_distance_m=2.0)
    assert p.config.family == "CS" and p.num_paths == 11 and p.ref_distance_m == 2.0
    assert p.poses.shape[0] == 11 and not p.poses.flags.writeable
    assert "score_priority" not in p.config.path_parameters()


def test_default_ptg() -> None:
    p = PTG()
    assert (p.num_paths, p.ref_distance_m, p.config.family) == (121, 5.0, "C")
    assert p.direction_to_motion_command(60) == (pytest.approx(0.6), 0.0)
    assert np.all(p.path_end_norm <= 1.0 + 1e-12) and p.path_end_norm[60] == pytest.approx(1.0)
    steps = np.diff(p.poses, axis=1)
    assert np.hypot(steps[..., 0], steps[..., 1]).max() <= p.config.sample_step_m + 1e-9
    assert np.abs(steps[..., 2]).max() <= p.config.sample_step_rad + 1e-9
