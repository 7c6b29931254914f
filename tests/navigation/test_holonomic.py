"""Holonomic methods in TP-space (thesis §6.C.3; MRPT's CHolonomicND / CHolonomicVFF, notes §1.3).

Scenes use N = 121 paths: path 60 is α = 0 (straight ahead), lower indices are negative α.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from simnav.errors import ConfigError, UnknownNameError
from simnav.navigation.holonomic import (
    Gap,
    HolonomicInput,
    HolonomicMethod,
    HolonomicND,
    HolonomicVFF,
    NDConfig,
    NDInfo,
    NDSituation,
    VFFConfig,
    alpha_to_index,
    index_to_alpha,
    make_holonomic,
)

N = 121
AHEAD = 60  # α = 0


def _free() -> np.ndarray:
    return np.ones(N)


def _blocked(lo: int, hi: int, dist: float, base: float = 1.0) -> np.ndarray:
    """Free (``base``) everywhere but paths lo..hi-1, free for ``dist``."""
    obs = np.full(N, base)
    obs[lo:hi] = dist
    return obs


def _nd(obs, alpha=0.0, dist=2.0, method=None, **inp):
    return (method or HolonomicND()).navigate(HolonomicInput(obs, alpha, dist, **inp))


def _vff(obs, alpha=0.0, dist=2.0, **inp):
    return HolonomicVFF().navigate(HolonomicInput(obs, alpha, dist, **inp))


# ----------------------------------------------------------------------------------------------------------------
# Direction grid
# ----------------------------------------------------------------------------------------------------------------


def test_index_to_alpha_is_cell_centred_and_mirror_exact():
    assert index_to_alpha(0, N) == pytest.approx(-math.pi + math.pi / N, abs=1e-15)
    assert index_to_alpha(N - 1, N) == pytest.approx(math.pi - math.pi / N, abs=1e-15)
    assert index_to_alpha(AHEAD, N) == 0.0
    k = np.arange(N)
    np.testing.assert_array_equal(index_to_alpha(k, N), -index_to_alpha(N - 1 - k, N))
    np.testing.assert_allclose(index_to_alpha(np.arange(4), 4), np.array([-3, -1, 1, 3]) * math.pi / 4)


def test_alpha_to_index_round_trips_and_wraps():
    k = np.arange(N)
    np.testing.assert_array_equal(alpha_to_index(index_to_alpha(k, N), N), k)
    assert all(alpha_to_index(index_to_alpha(i, N), N) == i for i in (0, 1, 59, 60, 119, 120))
    assert alpha_to_index(math.pi, N) == N - 1
    assert alpha_to_index(-math.pi, N) == N - 1  # wrapped to +π, as MRPT's wrapToPi
    assert alpha_to_index(-math.pi + 1e-9, N) == 0
    assert alpha_to_index(0.3 + 4 * math.pi, N) == alpha_to_index(0.3, N) == 66
    assert alpha_to_index(0.0, 4) == 2  # 1.5 rounds away from zero, as C's round
    assert isinstance(alpha_to_index(0.1, N), int)


# ----------------------------------------------------------------------------------------------------------------
# ND
# ----------------------------------------------------------------------------------------------------------------


def test_nd_free_space_heads_straight_at_the_target_at_full_speed():
    out = _nd(_free(), alpha=0.3, dist=2.0)
    assert out.situation == NDSituation.TARGET_DIRECTLY
    assert out.direction_k == 66 and out.direction_alpha_rad == index_to_alpha(66, N)
    assert out.speed == 1.0


@pytest.mark.parametrize(("dist", "speed"), [(2.0, 1.0), (0.2, 1.0), (0.05, 0.5), (0.02, 0.2), (0.0, 0.0)])
def test_nd_slows_down_within_the_approach_distance(dist, speed):
    # 0.6 m with refDistance 6 m = 0.1 in TP units
    out = _nd(_free(), alpha=-0.5, dist=dist, ref_distance_m=6.0)
    assert out.situation == NDSituation.TARGET_DIRECTLY and out.direction_k == alpha_to_index(-0.5, N)
    assert out.speed == pytest.approx(speed)


def test_nd_speed_options():
    assert _nd(_free(), dist=0.05, ref_distance_m=6.0, slow_down_near_target=False).speed == 1.0
    assert _nd(_free(), dist=0.05, ref_distance_m=6.0, max_robot_speed=0.4).speed == pytest.approx(0.2)
    assert _nd(_free(), dist=0.05).speed == pytest.approx(0.05 / 0.6)  # refDistance 1: 0.6 read as TP units


def test_nd_goes_straight_only_when_the_paths_near_the_target_are_free_beyond_it():
    obs = _blocked(57, 64, 0.5)  # ±3 paths around the target free for 0.5
    near = _nd(obs, dist=0.45)  # 0.5 >= 1.05 x 0.45
    assert near.situation == NDSituation.TARGET_DIRECTLY and near.direction_k == AHEAD
    assert near.speed == pytest.approx(0.45 / 0.6)
    far = _nd(obs, dist=0.48)  # 0.5 < 1.05 x 0.48: around the obstacle, through the first of two mirror gaps
    assert far.situation == NDSituation.WIDE_GAP and far.direction_k == 41


def test_nd_wall_across_the_target_takes_the_gap():
    obs = _blocked(80, 96, 1.0, base=0.3)  # a wall at 0.3 everywhere but an opening at paths 80..95
    out = _nd(obs, dist=2.0)
    assert out.situation == NDSituation.SMALL_GAP
    assert [(g.first_k, g.last_k, g.representative_k) for g in out.info.gaps] == [(80, 95, 88)]
    assert out.direction_k == 88  # the middle of the opening
    assert out.speed == 1.0  # the opening is free to the horizon


def test_nd_target_behind_an_obstacle_goes_around_through_the_nearer_valley():
    out = _nd(_blocked(45, 71, 0.4), dist=2.0)  # obstacle over paths 45..70, the target at 60 behind it
    assert out.situation == NDSituation.WIDE_GAP
    assert [(g.first_k, g.last_k, g.representative_k) for g in out.info.gaps] == [(0, 44, 29), (71, 120, 86)]
    assert out.direction_k == 86  # left valley (its border is 11 paths from the target, the right one's 16)
    assert out.speed == 1.0
    mirrored = _nd(_blocked(45, 71, 0.4)[::-1], dist=2.0)
    assert mirrored.direction_k == N - 1 - 86


def test_nd_symmetric_scene_is_deterministic():
    obs = _blocked(50, 71, 0.4)  # symmetric about the target path
    outs = [_nd(obs, dist=2.0) for _ in range(3)]
    g0, g1 = outs[0].info.gaps
    assert (g0.representative_k, g1.representative_k) == (34, 86)
    assert g0.score == pytest.approx(g1.score, abs=1e-12)
    assert all(o.direction_k == 34 for o in outs)  # tie: the first gap in search order, at negative α
    assert all(o == outs[0] for o in outs)


def test_nd_hysteresis_keeps_the_previous_side_until_reset():
    slightly_left = _blocked(49, 71, 0.4)  # the left valley is now 1 path nearer the target
    assert _nd(slightly_left).direction_k == 86
    nd = HolonomicND()
    assert _nd(_blocked(50, 71, 0.4), method=nd).direction_k == 34
    assert _nd(slightly_left, method=nd).direction_k == 33  # within 12 paths of the last choice: +0.4/3.9
    nd.reset()
    assert _nd(slightly_left, method=nd).direction_k == 86


def test_nd_blocked_all_around_stops():
    rng = np.random.default_rng(3)
    out = _nd(0.03 + 0.04 * rng.random(N), dist=2.0)
    assert out.situation == NDSituation.NO_WAY_FOUND and out.speed == 0.0 and out.info.gaps == ()
    crowded = _nd(0.03 + 0.04 * rng.random(N), dist=2.0, method=HolonomicND(crowded_floor_ratio=0.5))
    assert crowded.situation == NDSituation.NO_WAY_FOUND and crowded.speed == 0.0
    assert crowded.info.gaps and all(g.score == 0.0 for g in crowded.info.gaps)  # all too close to an obstacle
    assert out.direction_k == AHEAD and out.direction_alpha_rad == 0.0
    assert _nd(np.full(N, 0.1), dist=0.5).speed == 0.0


def test_nd_crowded_floor_finds_the_free_paths_mrpts_sweep_misses():
    # people all around: nothing free for 0.6 of the horizon but the seam's end paths; paths 80-90 free for 0.45,
    # the target straight ahead at 0.75
    obs = _blocked(80, 91, 0.45, base=0.1)
    obs[[0, -1]] = 1.0
    mrpt = _nd(obs, dist=0.75)
    assert mrpt.situation == NDSituation.NO_WAY_FOUND and mrpt.speed == 0.0 and mrpt.info.gaps == ()
    crowded = _nd(obs, dist=0.75, method=HolonomicND(crowded_floor_ratio=0.5))
    assert crowded.situation == NDSituation.SMALL_GAP and 80 <= crowded.direction_k <= 90 and crowded.speed > 0.0
    with pytest.raises(ConfigError, match="crowded_floor_ratio"):
        HolonomicND(crowded_floor_ratio=1.5)


def test_nd_gap_too_close_to_an_obstacle_is_refused():
    obs = _blocked(80, 90, 0.14, base=0.05)
    out = _nd(obs, dist=0.1)
    assert out.situation == NDSituation.NO_WAY_FOUND and out.speed == 0.0
    assert out.info.gaps == (Gap(80, 89, 85, 0.0),)
    allowed = _nd(obs, dist=0.1, method=HolonomicND(too_close_obstacle=0.1), slow_down_near_target=False)
    assert allowed.situation == NDSituation.SMALL_GAP and allowed.direction_k == 85
    assert allowed.speed == pytest.approx(0.14 / 0.4)  # risk: mean free distance in the gap / 0.4


def test_nd_speed_follows_the_free_distance_around_the_choice():
    out = _nd(_blocked(80, 96, 0.3, base=0.1), dist=0.25, ref_distance_m=10.0)
    assert out.situation == NDSituation.SMALL_GAP and out.direction_k == 88
    assert out.info.risk == pytest.approx(0.3) and out.speed == pytest.approx(0.75)
    direct = _nd(np.full(N, 0.2), dist=0.1, ref_distance_m=10.0)
    assert direct.situation == NDSituation.TARGET_DIRECTLY and direct.speed == pytest.approx(0.5)


def _reference_gaps(obs: np.ndarray, target_dist: float, floor_ratio: float | None = None) -> list[tuple[int, int]]:
    """MRPT's gap estimator written as its plain loops (threshold sweep, then the four sequential filters); with
    ``floor_ratio`` the sweep's floor is also at most that fraction of the deepest path (but the end ones)."""
    n = len(obs)
    top, bottom = max(obs[1:-1]), min(obs[1:-1])
    floor = min(target_dist, 0.6) if floor_ratio is None else min(target_dist, 0.6, floor_ratio * top)
    cand = []
    for r in 0.95 - 0.05 * np.arange(18):
        thr = r * top + (1 - r) * floor
        i = 0
        while i < n:
            if obs[i] >= thr:
                j = i
                while j + 1 < n and obs[j + 1] >= thr:
                    j += 1
                if j - i >= math.ceil(0.01 * n):
                    cand.append((i, j, max(obs[i:j + 1]), min(obs[i], obs[j])))
                i = j + 1
            else:
                i += 1
    gone = [False] * len(cand)
    for i, a in enumerate(cand):
        for j in range(i + 1, len(cand)):
            if not gone[i] and (a[0] == cand[j][0] or a[1] == cand[j][1]):
                gone[j] = True
    for i, a in enumerate(cand):
        gone[i] = gone[i] or a[2] - a[3] > 0.5 * (top - bottom)
    inside = [[i != j and b[0] >= a[0] and b[1] <= a[1] for j, b in enumerate(cand)] for i, a in enumerate(cand)]
    for i in range(len(cand)):
        if not gone[i] and sum(inside[i][j] and not gone[j] for j in range(len(cand))) > 1:
            gone[i] = True
    for i in range(len(cand)):
        for j in range(len(cand)):
            if not gone[i] and inside[i][j]:
                gone[j] = True
    return [(a[0], a[1]) for a, g in zip(cand, gone) if not g]


@pytest.mark.parametrize("n", [121, 31, 100])
@pytest.mark.parametrize("floor_ratio", [None, 0.5])
def test_nd_gap_search_matches_the_reference_loops(n, floor_ratio):
    rng = np.random.default_rng(n)
    k = np.arange(n)
    for trial in range(60):
        if trial % 2:
            obs = rng.random(n)  # jagged
        else:  # a few smooth valleys, plateaus at 1
            obs = 0.6 + 0.6 * np.sin(k * rng.uniform(0.05, 0.4) + rng.uniform(0, 6)) + 0.1 * rng.standard_normal(n)
        obs = np.clip(obs, 0.02, 1.0)
        dist = float(rng.choice([0.2, 0.5, 2.0]))
        if trial % 3 == 2:
            obs = obs * rng.uniform(0.1, 0.6)  # crowded: nothing free down to MRPT's floor
        method = HolonomicND(crowded_floor_ratio=floor_ratio)
        out = _nd(obs, alpha=float(rng.uniform(-math.pi, math.pi)), dist=dist, method=method)
        assert [(g.first_k, g.last_k) for g in out.info.gaps] == _reference_gaps(obs, dist, floor_ratio)


def _reference_nd(obs: np.ndarray, target_k: int, target_dist: float, last_k: int | None, max_obs: float = 1.0,
                  max_speed: float = 1.0, ref_m: float = 1.0, slow: bool = True, cfg: NDConfig = NDConfig()):
    """ND's decision written as plain loops over :func:`_reference_gaps` (MRPT's ``CHolonomicND::navigate``).

    Returns ``(direction_k, speed, situation, gaps)`` with gaps as (first_k, last_k, representative_k, score).
    The risk is ``np.mean``'s (numpy's pairwise sum, which the method reproduces: a plain sum may differ in the
    last bit, and the speed is compared exactly).
    """
    n = len(obs)
    td = max(0.01, target_dist)
    wide = math.floor(cfg.wide_gap_size_percent * n + 0.5)

    def circular(k):
        d = abs(k - target_k)
        return n - d if d > n / 2 else d

    alpha_t = index_to_alpha(target_k, n)
    px, py = td * math.cos(alpha_t), td * math.sin(alpha_t)
    w = cfg.factor_weights
    gaps = []
    for a, b in _reference_gaps(obs, target_dist, cfg.crowded_floor_ratio):
        if b - a < wide:
            rep = math.floor((a + b) / 2 + 0.5)
        else:
            rep = a + wide // 2 if circular(a) < circular(b) else b - wide // 2
        mean = sum(obs[a:b + 1]) / (b - a + 1)
        f1 = min(td, mean) / td if abs(rep - target_k) <= 1 and td < 1 else mean
        f2 = math.exp(-(circular(rep) / (n / 4)) ** 2)
        reach = min(obs[rep], max_obs, 0.95 * td)
        ux, uy = math.cos(index_to_alpha(rep, n)), math.sin(index_to_alpha(rep, n))
        along = min(max(px * ux + py * uy, 0.0), reach)
        f3 = 1 - min(max_obs, math.hypot(px - along * ux, py - along * uy)) / max_obs
        f4 = 1.0 if last_k is not None and abs(rep - last_k) <= int(0.1 * n) else 0.0
        score = (w[0] * f1 + w[1] * f2 + w[2] * f3 + w[3] * f4) / sum(w)
        gaps.append((a, b, rep, 0.0 if obs[rep] < cfg.too_close_obstacle else score))
    m = math.ceil(0.02 * n)
    lo, hi = 0, n - 1
    if m < target_k < n - m and all(v >= min(1.05 * td, 0.95 * max_obs) for v in obs[target_k - m:target_k + m + 1]):
        situation, k = NDSituation.TARGET_DIRECTLY, target_k
    elif not gaps or max(g[3] for g in gaps) <= 0:
        situation, k = NDSituation.NO_WAY_FOUND, n // 2  # the path at α = 0 (odd N), just above it (even N)
    else:
        best = max(g[3] for g in gaps)
        lo, hi, k, _ = next(g for g in gaps if g[3] >= best - 1e-9)
        situation = NDSituation.SMALL_GAP if hi - lo < wide else NDSituation.WIDE_GAP
    half = math.floor(cfg.risk_evaluation_sectors_percent * n + 0.5)
    risk = float(np.mean(obs[max(lo, k - half):min(hi, k + half) + 1]))
    if situation == NDSituation.NO_WAY_FOUND:
        speed = 0.0
    else:
        nearness = min(1.0, target_dist * ref_m / cfg.target_slow_approaching_distance_m) if slow else 1.0
        speed = max_speed * min(min(1.0, risk / cfg.risk_evaluation_distance), nearness)
    return k, speed, situation, gaps


_ND_OPTIONS = {"too_close_obstacle": 0.05, "wide_gap_size_percent": 0.1, "risk_evaluation_sectors_percent": 0.3,
               "factor_weights": (0.3, 1.0, 0.2, 2.0)}
_CROWDED = {"crowded_floor_ratio": 0.5}


@pytest.mark.parametrize(("n", "options"), [(121, {}), (31, {}), (100, {}), (121, _ND_OPTIONS), (100, _CROWDED),
                                            (31, {**_ND_OPTIONS, **_CROWDED})])
def test_nd_decisions_match_the_reference_loops_exactly(n, options):
    """The compiled ND and :func:`_reference_nd` agree to the bit on (direction_k, speed, situation) over 100 random
    scenes per case (400 in all), run in sequence through one instance so that the hysteresis plays."""
    rng = np.random.default_rng(1000 + n + len(options))
    k = np.arange(n)
    nd, last_k, seen = HolonomicND(**options), None, set()
    cfg = nd.config
    for trial in range(100):
        kind = trial % 5
        if kind == 0:
            obs = rng.random(n)  # jagged
        elif kind == 1:  # smooth valleys
            obs = 0.6 + 0.6 * np.sin(k * rng.uniform(0.05, 0.4) + rng.uniform(0, 6)) + 0.1 * rng.standard_normal(n)
        elif kind == 2:  # a wall with an opening, or an obstacle in free space
            lo, width = rng.integers(0, n), rng.integers(2, n // 2)
            obs = np.full(n, rng.uniform(0.05, 1.0))
            obs[lo:lo + width] = rng.uniform(0.0, 1.0)
        elif kind == 3:
            obs = np.round(4 * rng.random(n)) / 4  # plateaus: equal levels, tied scores
        else:
            obs = rng.random(n) ** 3  # mostly close
        obs = np.clip(obs, 0.0, 1.0)
        target_k = int(rng.integers(0, n))
        target_dist = float(rng.choice([0.0, 0.03, 0.2, 0.5, 0.9, 2.0, rng.uniform(0.0, 1.5)]))
        max_speed, ref_m, slow = float(rng.choice([1.0, 0.5])), float(rng.choice([1.0, 6.0])), bool(rng.random() < 0.5)
        out = nd.navigate(HolonomicInput.toward_path(obs, target_k, target_dist, max_robot_speed=max_speed,
                                                     ref_distance_m=ref_m, slow_down_near_target=slow))
        ref_k, ref_speed, ref_situation, ref_gaps = _reference_nd(obs, target_k, target_dist, last_k, 1.0, max_speed,
                                                                  ref_m, slow, cfg)
        assert (out.direction_k, out.speed, out.situation) == (ref_k, ref_speed, ref_situation), trial
        assert out.direction_alpha_rad == index_to_alpha(ref_k, n)
        assert [(g.first_k, g.last_k, g.representative_k) for g in out.info.gaps] == [g[:3] for g in ref_gaps]
        assert [g.score for g in out.info.gaps] == pytest.approx([g[3] for g in ref_gaps], abs=1e-12)
        last_k = None if ref_situation == NDSituation.NO_WAY_FOUND else ref_k
        seen.add(ref_situation)
    assert seen == set(NDSituation)


def test_nd_info_reads_as_an_ndinfo():
    out = _nd(_blocked(45, 71, 0.4), dist=2.0)
    info = out.info
    assert isinstance(info, NDInfo) and info.situation == NDSituation.WIDE_GAP and info.target_k == AHEAD
    plain = NDInfo(info.situation, info.target_k, info.gaps, info.evaluation, info.risk)
    assert info == plain and plain == info and hash(info) == hash(plain)
    assert repr(info) == repr(plain)
    assert all(type(g) is Gap and type(g.first_k) is int and type(g.score) is float for g in info.gaps)
    assert dataclasses.replace(info, risk=0.5) == dataclasses.replace(plain, risk=0.5)
    nd = HolonomicND()
    nd.config = NDConfig(too_close_obstacle=0.5)  # a replaced config takes effect
    assert _nd(_blocked(80, 96, 0.45, base=0.05), dist=2.0, method=nd).situation == NDSituation.NO_WAY_FOUND


# ----------------------------------------------------------------------------------------------------------------
# VFF
# ----------------------------------------------------------------------------------------------------------------


def test_vff_free_space_heads_straight_at_the_target():
    out = _vff(_free(), alpha=0.3, dist=2.0)
    assert out.direction_alpha_rad == pytest.approx(0.3, abs=1e-12) and out.direction_k == 66
    assert out.speed == 1.0 and out.situation == "FORCE_FIELD"


@pytest.mark.parametrize(("dist", "ref_m", "speed"), [(0.05, 1.0, 0.5), (0.01, 6.0, 0.6), (0.02, 6.0, 1.0)])
def test_vff_slows_down_within_the_approach_distance(dist, ref_m, speed):
    assert _vff(_free(), dist=dist, ref_distance_m=ref_m).speed == pytest.approx(speed)  # 0.1 m / refDistance


def test_vff_single_obstacle_force():
    obs = _free()
    obs[90] = 0.5  # one path at 0.5: the rest cancel out, this one pushes 20/N x (1/0.5 - 1) away from it
    out = _vff(obs, dist=2.0)
    a = index_to_alpha(90, N)
    push = -(20 / N) * np.array([math.cos(a), math.sin(a)])
    np.testing.assert_allclose(out.info.repulsive_force, push, atol=1e-12)
    assert out.direction_alpha_rad == pytest.approx(math.atan2(push[1], 20 + push[0]), abs=1e-12)
    assert out.speed == 1.0  # |push| = 0.165 < 6


def test_vff_obstacle_on_one_side_pushes_to_the_other_and_slows_down():
    out = _vff(_blocked(60, 91, 0.1), dist=2.0)  # close obstacle ahead-left
    assert out.direction_alpha_rad < -math.pi / 4 and out.direction_k < 45
    assert 0.1 < out.speed < 0.2 and out.speed == pytest.approx(out.info.obstacle_nearness)
    unslowed = _vff(_blocked(60, 91, 0.1), dist=2.0, slow_down_near_target=False)
    assert unslowed.speed == out.speed  # MRPT would return 0 here (upstream bug)


def test_vff_blocked_ahead_very_close_nearly_stops():
    out = _vff(_blocked(30, 91, 0.05), dist=2.0)  # the whole front half at 0.05
    assert out.speed < 0.05
    assert abs(out.direction_alpha_rad) > 3 * math.pi / 4  # pushed backwards
    assert _vff(_blocked(30, 91, 0.0), dist=2.0).speed < 1e-4  # 1/0 capped at 1e6: finite, ~0


def test_vff_uniform_obstacles_cancel_out():
    # MRPT's VFF only sees the resultant: the navigator's safety ramp must stop the robot here.
    out = _vff(np.full(N, 0.05), alpha=0.2, dist=2.0)
    assert out.speed == 1.0 and out.direction_alpha_rad == pytest.approx(0.2, abs=1e-12)


def test_vff_target_behind_an_obstacle_deflects_to_the_open_side():
    out = _vff(_blocked(45, 71, 0.3), dist=2.0)  # the obstacle reaches further right than left
    assert 0.05 < out.direction_alpha_rad < math.pi / 4 and out.direction_k == 62
    assert out.speed == pytest.approx(6 / math.hypot(*out.info.repulsive_force))


def test_vff_symmetric_scene_is_deterministic():
    outs = [_vff(_blocked(50, 71, 0.3), dist=2.0) for _ in range(3)]
    assert outs[0].direction_k == AHEAD and abs(outs[0].direction_alpha_rad) < 1e-12
    assert all(o == outs[0] for o in outs)


# ----------------------------------------------------------------------------------------------------------------
# Interface, factory, cost
# ----------------------------------------------------------------------------------------------------------------


def test_factory_defaults_are_mrpts():
    nd, vff = make_holonomic(), make_holonomic("VFF")
    assert isinstance(nd, HolonomicND) and isinstance(vff, HolonomicVFF)
    assert isinstance(nd, HolonomicMethod) and isinstance(vff, HolonomicMethod)
    assert nd.config == NDConfig(0.25, 0.25, 0.10, 0.4, 0.15, 0.60, (1.0, 0.5, 2.0, 0.4), None)
    assert vff.config == VFFConfig(0.10, 20.0)


def test_factory_options_and_errors():
    nd = make_holonomic("nd", TOO_CLOSE_OBSTACLE=0.1, factorWeights=[1, 1, 1, 1], wide_gap_size_percent=0.2)
    assert (nd.config.too_close_obstacle, nd.config.factor_weights) == (0.1, (1.0, 1.0, 1.0, 1.0))
    assert nd.config.wide_gap_size_percent == 0.2
    vff = make_holonomic("vff", TARGET_SLOW_APPROACHING_DISTANCE=0.3)
    assert vff.config.target_slow_approaching_distance_m == 0.3
    with pytest.raises(UnknownNameError, match="available: nd, vff"):
        make_holonomic("fulleval")
    with pytest.raises(KeyError):
        make_holonomic("fulleval")
    with pytest.raises(ConfigError, match="unknown ND option 'bogus'"):
        make_holonomic("nd", bogus=1)
    with pytest.raises(ConfigError, match="factor_weights"):
        make_holonomic("nd", factor_weights=(1, 2))


def test_input_is_validated_and_copied():
    obs = _free()
    inp = HolonomicInput(obs, 0.0, 1.0)
    obs[:] = 0.0
    assert inp.obstacles[0] == 1.0 and not inp.obstacles.flags.writeable
    assert inp.num_paths == N and inp.target_k == AHEAD
    via_k = HolonomicInput.toward_path(obs, 37, 0.5, ref_distance_m=6.0)
    assert via_k.target_k == 37 and via_k.target_alpha_rad == index_to_alpha(37, N) and via_k.ref_distance_m == 6.0
    with pytest.raises(ValueError):
        HolonomicInput.toward_path(obs, N, 0.5)
    for bad in (np.ones((2, N)), np.ones(2), np.r_[np.nan, np.ones(5)], -np.ones(5)):
        with pytest.raises(ValueError):
            HolonomicInput(bad, 0.0, 1.0)
    with pytest.raises(ValueError):
        HolonomicInput(obs, 0.0, -1.0)
    with pytest.raises(ValueError):
        HolonomicInput(obs, math.inf, 1.0)


def test_a_call_takes_well_under_a_millisecond():
    # The navigator runs one call per PTG (3) per step within a 1 ms step budget.
    rng = np.random.default_rng(0)
    inputs = [HolonomicInput(np.clip(rng.random(N) + 0.3, 0, 1), rng.uniform(-3, 3), 2.0) for _ in range(50)]
    for method in (HolonomicND(), HolonomicVFF()):
        method.navigate(inputs[0])  # compiles (or loads) the kernels
        best = math.inf
        for _ in range(3):
            start = time.perf_counter()
            for inp in inputs:
                method.navigate(inp)
            best = min(best, (time.perf_counter() - start) / len(inputs))
        assert best < 2e-4  # measured ~0.006 ms (ND), ~0.005 ms (VFF); loose for CI
