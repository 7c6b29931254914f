"""Property tests of simnav.geometry.se2 (twist convention: (vx, vy, omega))."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.geometry import se2, se3

N = 500


def _random_twists(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) twists with omega in (-pi, pi)."""
    return np.c_[rng.normal(scale=2.0, size=(n, 2)), rng.uniform(-np.pi + 1e-9, np.pi - 1e-9, size=n)]


def _special_twists(rng: np.random.Generator) -> np.ndarray:
    omega = np.array([0.0, 1e-14, -1e-10, 1e-6, -1e-3, np.pi - 1e-3, -np.pi + 1e-6, np.pi - 1e-9, np.pi])
    return np.c_[rng.normal(size=(len(omega), 2)), omega]


def _random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    return se2.exp(_random_twists(rng, n))


def test_log_exp_round_trip_batched_and_single() -> None:
    rng = np.random.default_rng(0)
    xi = np.concatenate([_random_twists(rng, N), _special_twists(rng)])
    T = se2.exp(xi)
    assert T.shape == (len(xi), 3, 3)
    np.testing.assert_allclose(T[:, :2, :2] @ np.swapaxes(T[:, :2, :2], 1, 2),
                               np.broadcast_to(np.eye(2), (len(xi), 2, 2)), atol=1e-12)
    np.testing.assert_allclose(se2.log(T), xi, atol=1e-9)
    for x, Ti in zip(xi[:20], T[:20]):
        np.testing.assert_allclose(se2.exp(x), Ti, atol=1e-15)
        np.testing.assert_allclose(se2.log(Ti), x, atol=1e-9)


def test_exp_log_round_trip_poses() -> None:
    rng = np.random.default_rng(0)
    poses = np.stack([se2.from_xy_yaw(x, y, a) for x, y, a in
                      zip(rng.normal(size=N), rng.normal(size=N), rng.uniform(-4 * np.pi, 4 * np.pi, N))])
    np.testing.assert_allclose(se2.exp(se2.log(poses)), poses, atol=1e-10)
    omega = se2.log(poses)[:, 2]
    assert np.all((omega > -np.pi) & (omega <= np.pi))


def test_log_of_half_turn_is_positive_pi() -> None:
    T = se2.from_xy_yaw(1.0, 2.0, np.pi)
    T[1, 0], T[0, 1] = -0.0, 0.0
    xi = se2.log(T)
    assert xi[2] == np.pi
    np.testing.assert_allclose(se2.exp(xi), T, atol=1e-12)


def test_exp_of_doubled_twist_is_composition() -> None:
    rng = np.random.default_rng(0)
    xi = _random_twists(rng, N)
    T = se2.exp(xi)
    np.testing.assert_allclose(se2.exp(2.0 * xi), T @ T, atol=1e-10)
    np.testing.assert_allclose(se2.exp(-xi), se2.inverse(T), atol=1e-10)


def test_inverse_and_compose() -> None:
    rng = np.random.default_rng(0)
    T_a_b, T_b_c, T_c_d = _random_poses(rng, 3)
    np.testing.assert_allclose(se2.compose(T_a_b, se2.inverse(T_a_b)), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(se2.compose(T_a_b, T_b_c, T_c_d), T_a_b @ T_b_c @ T_c_d, atol=1e-12)
    np.testing.assert_allclose(se2.compose(), np.eye(3))


def _integrate_point(xi: np.ndarray, p0: np.ndarray, steps: int = 2000) -> np.ndarray:
    """RK4 integration over t in [0, 1] of the planar velocity field p' = nu + omega x p (eq. 3.7)."""
    vx, vy, w = xi

    def f(p: np.ndarray) -> np.ndarray:
        return np.array([vx - w * p[1], vy + w * p[0]])

    p, h = p0.copy(), 1.0 / steps
    for _ in range(steps):
        k1 = f(p)
        k2 = f(p + 0.5 * h * k1)
        k3 = f(p + 0.5 * h * k2)
        k4 = f(p + h * k3)
        p = p + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return p


def test_twist_is_constant_velocity_over_one_second() -> None:
    rng = np.random.default_rng(0)
    for xi in np.concatenate([_random_twists(rng, 10), _special_twists(rng)[[0, 3, -1]]]):
        p0 = rng.normal(size=2)
        expected = se2.transform_points(se2.exp(xi), p0[None])[0]
        np.testing.assert_allclose(_integrate_point(xi, p0), expected, atol=1e-9)


def test_robot_driving_on_an_arc() -> None:
    # v = 1 m/s forward, omega = pi/2 rad/s: a quarter circle of radius 2/pi, ending facing +y
    T = se2.exp([1.0, 0.0, np.pi / 2])
    r = 2.0 / np.pi
    np.testing.assert_allclose(se2.to_xy_yaw(T), [r, r, np.pi / 2], atol=1e-15)


def test_xy_yaw_round_trip_and_wrap() -> None:
    rng = np.random.default_rng(0)
    for x, y, yaw in zip(rng.normal(size=N), rng.normal(size=N), rng.uniform(-10, 10, N)):
        x2, y2, yaw2 = se2.to_xy_yaw(se2.from_xy_yaw(x, y, yaw))
        np.testing.assert_allclose([x2, y2], [x, y], atol=0)
        np.testing.assert_allclose(yaw2, se2.wrap_angle(yaw), atol=1e-12)


def test_wrap_angle() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(-50, 50, size=N)
    w = se2.wrap_angle(a)
    assert isinstance(w, np.ndarray) and w.shape == a.shape
    assert np.all((w > -np.pi) & (w <= np.pi))
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert se2.wrap_angle(np.pi) == np.pi
    assert se2.wrap_angle(-np.pi) == np.pi
    assert se2.wrap_angle(3 * np.pi) == pytest.approx(np.pi)
    assert isinstance(se2.wrap_angle(0.5), float)
    np.testing.assert_allclose(se2.wrap_angle(0.5), 0.5)


def test_interpolate_endpoints_and_midpoint() -> None:
    rng = np.random.default_rng(0)
    for T_a, T_b in _random_poses(rng, 40).reshape(20, 2, 3, 3):
        np.testing.assert_allclose(se2.interpolate(T_a, T_b, 0.0), T_a, atol=1e-12)
        np.testing.assert_allclose(se2.interpolate(T_a, T_b, 1.0), T_b, atol=1e-10)
        step = se2.inverse(T_a) @ se2.interpolate(T_a, T_b, 0.5)
        np.testing.assert_allclose(T_a @ step @ step, T_b, atol=1e-10)


def test_transform_points() -> None:
    T = se2.from_xy_yaw(1.0, 2.0, np.pi / 2)
    np.testing.assert_allclose(se2.transform_points(T, [[1.0, 0.0], [0.0, 0.0]]), [[1.0, 3.0], [1.0, 2.0]],
                               atol=1e-15)
    rng = np.random.default_rng(0)
    T = _random_poses(rng, 1)[0]
    P = rng.normal(size=(30, 2))
    np.testing.assert_allclose(se2.transform_points(T, P), (T @ np.c_[P, np.ones(30)].T).T[:, :2], atol=1e-12)


def test_se3_embedding_round_trip_and_consistency() -> None:
    rng = np.random.default_rng(0)
    xi = _random_twists(rng, 50)
    for x, T in zip(xi, se2.exp(xi)):
        T4 = se2.to_se3(T)
        np.testing.assert_allclose(se2.from_se3(T4), T, atol=1e-12)
        # the planar twist is the se(3) twist (vx, vy, 0, 0, 0, omega)
        np.testing.assert_allclose(T4, se3.exp([x[0], x[1], 0.0, 0.0, 0.0, x[2]]), atol=1e-12)
        P = rng.normal(size=(5, 2))
        np.testing.assert_allclose(se3.transform_points(T4, np.c_[P, np.zeros(5)])[:, :2],
                                   se2.transform_points(T, P), atol=1e-12)


def test_from_se3_projects_tilted_pose() -> None:
    T4 = se3.from_rpy(0.2, -0.3, 1.1, [1.0, -2.0, 0.7])
    np.testing.assert_allclose(se2.to_xy_yaw(se2.from_se3(T4)), [1.0, -2.0, 1.1], atol=1e-12)


def test_shape_errors() -> None:
    with pytest.raises(ValueError):
        se2.exp(np.zeros(6))
    with pytest.raises(ValueError):
        se2.log(np.eye(4))
    with pytest.raises(ValueError):
        se2.transform_points(np.eye(3), np.zeros((4, 3)))
