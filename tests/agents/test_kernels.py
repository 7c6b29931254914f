"""The Numba kernels of the crowd update give the numpy reference's results to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.agents.social_force import (
    Segments,
    SocialForceParams,
    all_pairs,
    resolve_overlaps_pairs,
    resolve_overlaps_pairs_reference,
    social_force_pairs,
    social_force_pairs_reference,
)


def _scene(seed: int, n: int, m: int, c: int) -> tuple:
    """n pedestrians, m random wall segments and c circles crowded into a 6 m square."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0.0, 6.0, (n, 2))
    vel = rng.normal(0.0, 0.8, (n, 2))
    angle = rng.uniform(-np.pi, np.pi, n)
    dirs = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    speeds = rng.uniform(0.0, 1.8, n)
    walls = rng.uniform(-0.5, 6.5, (m, 2, 2))
    walls[: m // 2, 1] = walls[: m // 2, 0] + rng.normal(0.0, 0.8, (m // 2, 2))  # some short ones
    circles = np.column_stack([rng.uniform(0.0, 6.0, (c, 2)), rng.uniform(0.2, 0.5, c)])
    circle_vel = rng.normal(0.0, 0.5, (c, 2))
    return pos, vel, dirs, speeds, Segments(walls), circles, circle_vel


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("params", [SocialForceParams(), SocialForceParams(wall_look_ahead_m=0.0, circle_steering=0.0)])
def test_social_force_kernel_matches_numpy(seed: int, params: SocialForceParams) -> None:
    pos, vel, dirs, speeds, segs, circles, circle_vel = _scene(seed, 3 + 4 * seed, 5 + 6 * seed, seed % 3)
    ped, seg = all_pairs(len(pos), len(segs))
    for circ, cvel in ((circles, circle_vel), (circles, None), (None, None)):
        args = (pos, vel, dirs, speeds, segs, ped, seg, circ, cvel, params)
        np.testing.assert_array_equal(social_force_pairs(*args), social_force_pairs_reference(*args))


@pytest.mark.parametrize("seed", range(6))
def test_resolve_overlaps_kernel_matches_numpy(seed: int) -> None:
    pos, vel, _, _, segs, circles, _ = _scene(seed, 4 + 5 * seed, 4 + 6 * seed, 1 + seed % 3)
    ped, seg = all_pairs(len(pos), len(segs))
    moved = pos + 0.3 * vel
    check = np.arange(len(ped)) % 3 != 0
    for prev, crossing in ((pos, check), (pos, None), (None, None)):
        args = (moved, 0.25, segs, ped, seg, circles, 40, prev, crossing)
        np.testing.assert_array_equal(resolve_overlaps_pairs(*args), resolve_overlaps_pairs_reference(*args))


def test_kernels_handle_nobody_and_no_walls() -> None:
    params = SocialForceParams()
    segs = Segments(np.zeros((0, 2, 2)))
    empty = np.zeros(0, dtype=np.int64)
    acc = social_force_pairs(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), segs, empty, empty,
                             None, None, params)
    assert acc.shape == (0, 2)
    one = np.array([[1.0, 2.0]])
    args = (one, np.zeros((1, 2)), np.array([[1.0, 0.0]]), np.array([1.0]), segs, empty, empty, None, None, params)
    np.testing.assert_array_equal(social_force_pairs(*args), social_force_pairs_reference(*args))
    np.testing.assert_array_equal(resolve_overlaps_pairs(one, 0.25, segs, empty, empty, None, 4, one, empty > 0), one)


@pytest.mark.parametrize("seed", range(4))
def test_blocking_kernel_matches_numpy(seed: int) -> None:
    from simnav.agents.kernels import closest_in_way

    rng = np.random.default_rng(seed)
    n, c = 2 + 3 * seed, seed % 3
    pos = rng.uniform(0.0, 3.0, (n, 2))
    angle = rng.uniform(-np.pi, np.pi, n)
    dirs = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    others = np.concatenate([pos, rng.uniform(0.0, 3.0, (c, 2))])
    reach = np.concatenate([np.full(n, 1.0), rng.uniform(1.0, 1.5, c)])
    # the numpy formulation
    rel = others[None, :, :] - pos[:, None, :]
    dist = np.linalg.norm(rel, axis=2)
    dist[:, :n] += np.eye(n) * 1e9
    ahead = np.sum(rel * dirs[:, None, :], axis=2) >= dist * np.cos(np.radians(60.0))
    in_way = ahead & (dist < reach[None, :])
    any_in_way, blocker = closest_in_way(pos, dirs, others, reach, float(np.cos(np.radians(60.0))))
    np.testing.assert_array_equal(any_in_way, np.any(in_way, axis=1))
    np.testing.assert_array_equal(blocker, np.argmin(np.where(in_way, dist, np.inf), axis=1))


def test_segment_grid_pairs_match_numpy() -> None:
    from simnav.agents.crowd import SegmentGrid

    rng = np.random.default_rng(1)
    segs = Segments(rng.uniform(0.0, 8.0, (30, 2, 2)))
    grid = SegmentGrid(segs, 2.0)
    points = rng.uniform(-3.0, 11.0, (40, 2))
    ped, seg = grid.pairs(points)
    # the numpy formulation: each point's cell list, in point order
    ij = np.floor((points - grid._origin) / grid._cell_m).astype(np.int64)
    expected_ped, expected_seg = [], []
    for k, (i, j) in enumerate(ij):
        if 0 <= i < grid._shape[0] and 0 <= j < grid._shape[1]:
            cell = i * grid._shape[1] + j
            listed = grid._idx[grid._ptr[cell] : grid._ptr[cell + 1]]
            expected_ped += [k] * len(listed)
            expected_seg += list(listed)
    np.testing.assert_array_equal(ped, expected_ped)
    np.testing.assert_array_equal(seg, expected_seg)


@pytest.mark.parametrize("seed", range(4))
def test_wanderer_drive_kernel_matches_numpy(seed: int) -> None:
    from simnav.agents.crowd import wrap_angle
    from simnav.agents.wanderers import MAX_YAW_RATE_RAD_S, STOP_DISTANCE_M, STOP_HALF_ANGLE_RAD, _drive

    rng = np.random.default_rng(seed)
    n, dt, speed_m_s = 1 + seed, 0.1, 0.5
    pos = rng.uniform(0.0, 3.0, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    to_next = rng.normal(0.0, 1.0, (n, 2))
    to_next[0] *= 1e-7 if seed == 1 else 1.0  # at the node
    points = np.concatenate([rng.uniform(0.0, 3.0, (3 * seed, 2)), pos])
    rel = points[None, :, :] - pos[:, None, :]
    heading, bearing = np.arctan2(to_next[:, 1], to_next[:, 0]), np.arctan2(rel[..., 1], rel[..., 0])
    new_yaw, rate, vel, new_pos, blocked = _drive(pos, yaw, to_next, heading, rel, bearing, speed_m_s, dt, 2.5)
    # the numpy formulation
    dist = np.linalg.norm(to_next, axis=1)
    error = np.where(dist > 1e-6, wrap_angle(heading - yaw), 0.0)
    expected_rate = np.sign(error) * np.minimum(np.abs(error) * 2.5, MAX_YAW_RATE_RAD_S)
    speed = np.minimum(speed_m_s * np.maximum(np.cos(error), 0.0) ** 2, dist / dt)
    gap = np.linalg.norm(rel, axis=2)
    in_cone = np.abs(wrap_angle(bearing - yaw[:, None])) <= STOP_HALF_ANGLE_RAD
    ahead = (gap <= STOP_DISTANCE_M) & (gap > 1e-9) & in_cone
    expected_blocked = np.any(ahead, axis=1)
    speed[expected_blocked] = 0.0
    expected_yaw = wrap_angle(yaw + expected_rate * dt)
    expected_vel = speed[:, None] * np.stack([np.cos(expected_yaw), np.sin(expected_yaw)], axis=1)
    np.testing.assert_array_equal(blocked, expected_blocked)
    np.testing.assert_array_equal(rate, expected_rate)
    np.testing.assert_array_equal(new_yaw, expected_yaw)
    np.testing.assert_array_equal(vel, expected_vel)
    np.testing.assert_array_equal(new_pos, pos + expected_vel * dt)
