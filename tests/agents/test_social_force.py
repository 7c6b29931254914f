from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.agents.social_force import (
    SocialForceParams,
    elliptical_repulsion,
    integrate,
    resolve_overlaps,
    social_force,
)

PARAMS = SocialForceParams()
NO_WALLS = np.zeros((0, 2, 2))


def _potential(r: np.ndarray, step: np.ndarray, p: SocialForceParams) -> float:
    n1 = np.linalg.norm(r)
    n2 = np.linalg.norm(r - step)
    b = 0.5 * math.sqrt((n1 + n2) ** 2 - step @ step)
    return p.v0_m2_s2 * math.exp(-b / p.sigma_m)


@pytest.mark.parametrize(
    ("r", "step"),
    [
        ((0.8, 0.3), (0.0, 0.0)),
        ((0.8, 0.3), (0.5, 0.1)),
        ((-0.4, 1.1), (0.2, -0.4)),
        ((1.5, -0.2), (-0.6, 0.0)),
    ],
)
def test_elliptical_force_is_minus_gradient(r: tuple[float, float], step: tuple[float, float]) -> None:
    r_arr, step_arr, h = np.array(r), np.array(step), 1e-6
    numeric = np.array(
        [
            -(_potential(r_arr + dx, step_arr, PARAMS) - _potential(r_arr - dx, step_arr, PARAMS)) / (2 * h)
            for dx in (np.array([h, 0.0]), np.array([0.0, h]))
        ]
    )
    np.testing.assert_allclose(elliptical_repulsion(r_arr, step_arr, PARAMS), numeric, rtol=1e-5, atol=1e-9)


def test_still_partner_repels_radially_with_circular_potential() -> None:
    pos = np.array([[0.0, 0.0], [0.6, 0.0]])
    dirs = np.array([[-1.0, 0.0], [1.0, 0.0]])  # each faces away: partner outside the field of view
    acc = social_force(pos, np.zeros((2, 2)), dirs, np.zeros(2), NO_WALLS, params=PARAMS)
    expected = PARAMS.out_of_view_weight * PARAMS.v0_m2_s2 / PARAMS.sigma_m * math.exp(-0.6 / PARAMS.sigma_m)
    np.testing.assert_allclose(acc, [[-expected, 0.0], [expected, 0.0]], atol=1e-12)


def test_field_of_view_weights_partner_behind_less() -> None:
    pos = np.array([[0.0, 0.0], [0.7, 0.0]])
    facing = social_force(pos, np.zeros((2, 2)), np.array([[1.0, 0.0], [1.0, 0.0]]), np.zeros(2), NO_WALLS)
    # pedestrian 0 sees 1 ahead (weight 1), pedestrian 1 has 0 behind it (weight c)
    assert facing[0, 0] < 0 < facing[1, 0]
    assert facing[1, 0] == pytest.approx(-PARAMS.out_of_view_weight * facing[0, 0])


def test_driving_term_and_walls() -> None:
    acc = social_force(np.zeros((1, 2)), np.zeros((1, 2)), np.array([[1.0, 0.0]]), np.array([1.2]), NO_WALLS)
    np.testing.assert_allclose(acc, [[1.2 / PARAMS.tau_s, 0.0]])
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    pos = np.array([[0.3, 0.5], [0.0, -4.0]])
    acc = social_force(pos, np.zeros((2, 2)), np.array([[1.0, 0.0], [1.0, 0.0]]), np.zeros(2), wall)
    push = PARAMS.u0_m2_s2 / PARAMS.r_m * math.exp(-0.5 / PARAMS.r_m)
    np.testing.assert_allclose(acc[0], [0.0, push], atol=1e-5)  # away from the wall, on its side
    assert np.all(np.abs(acc[1]) < 1e-3)  # 4 m away: beyond the cutoff, only the tiny pedestrian term


def test_integrate_is_semi_implicit_with_speed_cap() -> None:
    pos, vel = np.zeros((2, 2)), np.array([[1.0, 0.0], [0.0, 0.0]])
    acc = np.array([[100.0, 0.0], [0.0, 1.0]])
    speeds = np.array([1.0, 1.0])
    new_pos, new_vel = integrate(pos, vel, acc, speeds, 0.1, PARAMS)
    np.testing.assert_allclose(new_vel, [[PARAMS.max_speed_factor, 0.0], [0.0, 0.1]])
    np.testing.assert_allclose(new_pos, pos + new_vel * 0.1)


def test_resolve_pushes_out_of_wall_on_own_side() -> None:
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    pos = np.array([[0.0, 0.1], [2.0, -0.05], [-2.0, 1.0]])
    out = resolve_overlaps(pos, 0.25, wall)
    assert out[0, 1] >= 0.25 and out[1, 1] <= -0.25  # never through the wall
    np.testing.assert_allclose(out[:, 0], pos[:, 0])
    np.testing.assert_allclose(out[2], pos[2])


def test_resolve_undoes_a_move_through_a_wall() -> None:
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    before = np.array([[0.0, 0.3]])
    out = resolve_overlaps(np.array([[0.0, -0.1]]), 0.25, wall, previous_xy=before)
    assert out[0, 1] >= 0.25


def test_resolve_separates_pairs_and_circles() -> None:
    pos = np.array([[0.0, 0.0], [0.3, 0.0], [0.3, 0.1], [5.0, 0.2]])
    circles = np.array([[5.0, 0.0, 0.3]])
    out = resolve_overlaps(pos, 0.25, NO_WALLS, circles, iterations=20)
    d = np.linalg.norm(out[:, None] - out[None], axis=2) + np.eye(4) * 9
    assert d.min() >= 0.5 - 1e-9
    assert np.linalg.norm(out[3] - circles[0, :2]) >= 0.55 - 1e-9


def test_resolve_pedestrian_against_wall_does_not_yield() -> None:
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    pos = np.array([[0.0, 0.26], [0.0, 0.6]])  # first one touches the wall, second overlaps it from above
    out = resolve_overlaps(pos, 0.25, wall)
    assert out[0, 1] >= 0.25
    assert out[1, 1] - out[0, 1] >= 0.5 - 1e-9


def test_head_on_in_corridor_pass_without_overlap() -> None:
    corridor = np.array([[[-5.0, 0.0], [25.0, 0.0]], [[-5.0, 2.5], [25.0, 2.5]]])
    # a few centimetres of lateral offset: an exactly symmetric encounter is an unstable equilibrium
    pos = np.array([[2.0, 1.22], [18.0, 1.28]])
    goals = np.array([[20.0, 1.25], [0.0, 1.25]])
    vel, speeds, dt = np.zeros((2, 2)), np.array([1.3, 1.4]), 0.02
    min_gap = np.inf
    for _ in range(1500):
        dirs = (goals - pos) / np.linalg.norm(goals - pos, axis=1, keepdims=True)
        acc = social_force(pos, vel, dirs, speeds, corridor, params=PARAMS)
        moved, _ = integrate(pos, vel, acc, speeds, dt, PARAMS)
        new = resolve_overlaps(moved, PARAMS.radius_m, corridor, previous_xy=pos)
        vel, pos = (new - pos) / dt, new
        min_gap = min(min_gap, np.linalg.norm(pos[0] - pos[1]))
        assert np.all(pos[:, 1] >= PARAMS.radius_m - 1e-6)
        assert np.all(pos[:, 1] <= 2.5 - PARAMS.radius_m + 1e-6)
    assert min_gap >= 2 * PARAMS.radius_m - 1e-6
    assert pos[0, 0] > 17.0 and pos[1, 0] < 3.0


def _wall_force(pos: np.ndarray, walls: np.ndarray, direction=(1.0, 0.0), **kw: float) -> np.ndarray:
    params = SocialForceParams(**kw)
    dirs = np.tile(np.asarray(direction, dtype=float), (len(pos), 1))
    return social_force(pos, np.zeros_like(pos), dirs, np.zeros(len(pos)), walls, params=params)


def test_wall_cut_into_pieces_pushes_like_one_wall() -> None:
    pos = np.array([[0.1, 0.4], [-2.3, -0.7]])
    whole = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    xs = np.linspace(-5.0, 5.0, 41)
    pieces = np.stack([np.stack([xs[:-1], np.zeros(40)], 1), np.stack([xs[1:], np.zeros(40)], 1)], axis=1)
    np.testing.assert_allclose(_wall_force(pos, pieces), _wall_force(pos, whole), atol=1e-12)


def test_corner_of_a_box_pushes_once() -> None:
    box = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]], [[1.0, 1.0], [0.0, 1.0]],
                    [[0.0, 1.0], [0.0, 0.0]]])
    pos = np.array([[1.3, 1.4]])
    corner = box[1, 1]
    d = np.linalg.norm(pos[0] - corner)
    expected = PARAMS.u0_m2_s2 / PARAMS.r_m * math.exp(-d / PARAMS.r_m) * (pos[0] - corner) / d
    np.testing.assert_allclose(_wall_force(pos, box, direction=(0.0, 1.0))[0], expected, rtol=1e-9)


def test_door_jambs_steer_but_do_not_brake_when_the_way_is_clear() -> None:
    t = 0.06  # a 1 m doorway in a wall along y = 0
    wall = np.array([[[-5, -t], [-0.5, -t]], [[-0.5, -t], [-0.5, t]], [[-0.5, t], [-5, t]],
                     [[5, -t], [0.5, -t]], [[0.5, -t], [0.5, t]], [[0.5, t], [5, t]]], dtype=float)
    pos = np.array([[0.1, -0.35]])
    through = _wall_force(pos, wall, direction=(0.0, 1.0))[0]
    plain = _wall_force(pos, wall, direction=(0.0, 1.0), wall_look_ahead_m=0.0)[0]
    assert through[1] == pytest.approx(0.0, abs=1e-12) and through[0] < 0.0  # centred, not held back
    assert plain[1] < -2.0  # plain H&M: the jambs brake harder than a 1 m/s walker can push
    assert through[0] == pytest.approx(plain[0])
    into_wall = _wall_force(np.array([[2.0, -0.35]]), wall, direction=(0.0, 1.0))[0]
    assert into_wall[1] < 0.0  # a wall straight ahead still brakes


def test_walls_out_of_reach_with_a_look_ahead_give_float_forces() -> None:
    # pedestrians near a wall's look-ahead stretch but beyond the repulsion cutoff: nothing is summed, and the
    # (empty) sum must still be a float array the look-ahead rule can modify
    pos = np.array([[0.0, 1.9], [3.0, 1.9]])
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    force = _wall_force(pos, wall, direction=(0.0, -1.0), wall_cutoff_m=1.0, wall_look_ahead_m=2.0)
    assert force.dtype == np.float64 and np.all(np.isfinite(force))
