"""Property tests of simnav.geometry.se3 (twist convention: translation first)."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.geometry import se3

N = 500


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_twists(rng: np.random.Generator, n: int, max_angle_rad: float = np.pi - 1e-3) -> np.ndarray:
    """(n, 6) twists with rotation angles uniform in [0, max_angle_rad)."""
    axes = _unit(rng.normal(size=(n, 3)))
    angles = rng.uniform(0.0, max_angle_rad, size=(n, 1))
    return np.concatenate([rng.normal(scale=2.0, size=(n, 3)), axes * angles], axis=1)


def _special_twists(rng: np.random.Generator) -> np.ndarray:
    """Twists with tiny and near-pi rotation angles, and pure translations."""
    angles = np.array([0.0, 1e-14, 1e-10, 1e-7, 1e-4, 9e-3, 1.1e-2, np.pi - 1e-2, np.pi - 1e-5, np.pi - 1e-8])
    axes = _unit(rng.normal(size=(len(angles), 3)))
    nu = rng.normal(size=(len(angles), 3))
    return np.concatenate([nu, axes * angles[:, None]], axis=1)


def _random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    return se3.exp(_random_twists(rng, n))


def _assert_rotation(R: np.ndarray) -> None:
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_hat_vee_and_skew() -> None:
    rng = np.random.default_rng(0)
    xi = rng.normal(size=(N, 6))
    np.testing.assert_array_equal(se3.vee(se3.hat(xi)), xi)
    w, v = rng.normal(size=(N, 3)), rng.normal(size=(N, 3))
    np.testing.assert_allclose((se3.skew(w) @ v[..., None])[..., 0], np.cross(w, v), atol=1e-12)
    X = se3.hat(xi[0])
    np.testing.assert_array_equal(X[:3, 3], xi[0, :3])  # translation first
    np.testing.assert_array_equal(X[3], np.zeros(4))


def test_log_exp_round_trip_random() -> None:
    rng = np.random.default_rng(0)
    xi = _random_twists(rng, N)
    T = se3.exp(xi)
    _assert_rotation(T[:, :3, :3])
    np.testing.assert_allclose(T[:, 3], np.broadcast_to([0, 0, 0, 1.0], (N, 4)), atol=0)
    np.testing.assert_allclose(se3.log(T), xi, atol=1e-9)


def test_log_exp_round_trip_tiny_and_near_pi() -> None:
    rng = np.random.default_rng(0)
    xi = _special_twists(rng)
    np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, atol=1e-8)
    for x in xi:  # unbatched calls agree with the batch
        np.testing.assert_allclose(se3.log(se3.exp(x)), x, atol=1e-8)


def test_single_twists_and_poses_match_the_batch() -> None:
    # One twist or pose takes a scalar path; it must agree with the batch formulas to rounding.
    rng = np.random.default_rng(1)
    xi = np.concatenate([_random_twists(rng, 200), _special_twists(rng), rng.normal(scale=1e-4, size=(50, 6))])
    T = se3.exp(xi)
    for x, T_x in zip(xi, T):
        np.testing.assert_allclose(se3.exp(x), T_x, rtol=0, atol=1e-14)
    w = se3.log(T)
    for T_x, w_x in zip(T, w):
        np.testing.assert_allclose(se3.log(T_x), w_x, rtol=0, atol=1e-12)


def test_exp_log_round_trip_random_poses() -> None:
    rng = np.random.default_rng(0)
    T = _random_poses(rng, N)
    np.testing.assert_allclose(se3.exp(se3.log(T)), T, atol=1e-10)


@pytest.mark.parametrize("axis", [*np.eye(3), _unit(np.array([1.0, -2.0, 0.5]))])
def test_exactly_pi_rotation(axis: np.ndarray) -> None:
    R = np.eye(3) + 2.0 * se3.skew(axis) @ se3.skew(axis)  # rotation by pi, built without trig
    w = se3.so3_log(R)
    np.testing.assert_allclose(np.linalg.norm(w), np.pi, atol=1e-12)
    np.testing.assert_allclose(np.abs(w @ axis), np.pi, atol=1e-12)
    np.testing.assert_allclose(se3.so3_exp(w), R, atol=1e-12)
    T = se3.from_rotation_translation(R, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(se3.exp(se3.log(T)), T, atol=1e-12)


def test_so3_log_is_accurate_just_below_pi() -> None:
    rng = np.random.default_rng(0)
    for eps in [1e-3, 1e-6, 1e-9, 1e-12]:
        w = _unit(rng.normal(size=3)) * (np.pi - eps)
        np.testing.assert_allclose(se3.so3_log(se3.so3_exp(w)), w, atol=1e-9)


def test_exp_of_doubled_twist_is_composition() -> None:
    rng = np.random.default_rng(0)
    xi = _random_twists(rng, N, max_angle_rad=3.0)
    T = se3.exp(xi)
    np.testing.assert_allclose(se3.exp(2.0 * xi), T @ T, atol=1e-10)
    np.testing.assert_allclose(se3.exp(-xi), se3.inverse(T), atol=1e-10)


def test_inverse_and_compose() -> None:
    rng = np.random.default_rng(0)
    T_a_b, T_b_c = _random_poses(rng, 2)
    I4 = np.eye(4)
    np.testing.assert_allclose(se3.compose(T_a_b, se3.inverse(T_a_b)), I4, atol=1e-12)
    np.testing.assert_allclose(se3.compose(se3.inverse(T_a_b), T_a_b), I4, atol=1e-12)
    np.testing.assert_allclose(se3.compose(T_a_b, T_b_c), T_a_b @ T_b_c, atol=1e-12)
    np.testing.assert_allclose(se3.compose(), I4)
    T_c_a = se3.inverse(se3.compose(T_a_b, T_b_c))
    np.testing.assert_allclose(T_c_a, se3.inverse(T_b_c) @ se3.inverse(T_a_b), atol=1e-12)
    np.testing.assert_allclose(se3.inverse(np.stack([T_a_b, T_b_c])) @ np.stack([T_a_b, T_b_c]),
                               np.broadcast_to(I4, (2, 4, 4)), atol=1e-12)


def _integrate_point(xi: np.ndarray, p0: np.ndarray, steps: int = 2000) -> np.ndarray:
    """RK4 integration over t in [0, 1] of the velocity field p' = nu + omega x p (eq. 3.7)."""
    nu, omega = xi[:3], xi[3:]

    def f(p: np.ndarray) -> np.ndarray:
        return nu + np.cross(omega, p)

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
        p0 = rng.normal(size=3)
        expected = se3.transform_points(se3.exp(xi), p0[None])[0]
        np.testing.assert_allclose(_integrate_point(xi, p0), expected, atol=1e-9)


def test_pure_translation_and_pure_rotation() -> None:
    T = se3.exp([1.0, 2.0, 3.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(T, se3.from_rotation_translation(np.eye(3), [1.0, 2.0, 3.0]), atol=0)
    T = se3.exp([0.0, 0.0, 0.0, 0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(se3.transform_points(T, [[1.0, 0.0, 0.0]]), [[0.0, 1.0, 0.0]], atol=1e-15)


def test_quaternion_round_trip() -> None:
    rng = np.random.default_rng(0)
    q = _unit(rng.normal(size=(N, 4)))
    q[:, 0] = np.abs(q[:, 0])
    for qi in q:
        T = se3.from_quat_wxyz(qi, [1.0, 2.0, 3.0])
        _assert_rotation(T[:3, :3])
        np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 3.0])
        np.testing.assert_allclose(se3.to_quat_wxyz(T), qi, atol=1e-12)
        np.testing.assert_allclose(se3.from_quat_wxyz(-3.0 * qi)[:3, :3], T[:3, :3], atol=1e-12)


def test_quaternion_known_values_and_sign() -> None:
    np.testing.assert_allclose(se3.to_quat_wxyz(np.eye(3)), [1.0, 0.0, 0.0, 0.0])
    R = se3.so3_exp([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(se3.to_quat_wxyz(R), [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-15)
    rng = np.random.default_rng(0)
    for T in _random_poses(rng, 100):
        q = se3.to_quat_wxyz(T)
        assert q[0] >= 0.0
        np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)
        np.testing.assert_allclose(se3.from_quat_wxyz(q)[:3, :3], T[:3, :3], atol=1e-12)
    with pytest.raises(ValueError):
        se3.from_quat_wxyz([0.0, 0.0, 0.0, 0.0])


def test_rpy_round_trip_and_convention() -> None:
    rng = np.random.default_rng(0)
    angles = np.c_[rng.uniform(-np.pi, np.pi, N), rng.uniform(-1.5, 1.5, N), rng.uniform(-np.pi, np.pi, N)]
    for roll, pitch, yaw in angles:
        T = se3.from_rpy(roll, pitch, yaw, [0.1, 0.2, 0.3])
        Rz, Ry, Rx = (se3.so3_exp(a * e) for a, e in zip([yaw, pitch, roll], np.eye(3)[::-1]))
        np.testing.assert_allclose(T[:3, :3], Rz @ Ry @ Rx, atol=1e-12)
        np.testing.assert_allclose(se3.to_rpy(T), [roll, pitch, yaw], atol=1e-10)
        np.testing.assert_allclose(se3.to_rpy(T[:3, :3]), [roll, pitch, yaw], atol=1e-10)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_rpy_gimbal_lock_reproduces_rotation(pitch: float) -> None:
    R = se3.rpy_to_matrix(0.7, pitch, -0.4)
    roll2, pitch2, yaw2 = se3.to_rpy(R)
    assert roll2 == 0.0
    np.testing.assert_allclose(pitch2, pitch, atol=1e-8)
    np.testing.assert_allclose(se3.rpy_to_matrix(roll2, pitch2, yaw2), R, atol=1e-12)


def test_interpolate_endpoints_and_midpoint() -> None:
    rng = np.random.default_rng(0)
    T_a, T_b = _random_poses(rng, 2)
    np.testing.assert_allclose(se3.interpolate(T_a, T_b, 0.0), T_a, atol=1e-12)
    np.testing.assert_allclose(se3.interpolate(T_a, T_b, 1.0), T_b, atol=1e-10)
    T_mid = se3.interpolate(T_a, T_b, 0.5)
    step = se3.inverse(T_a) @ T_mid
    np.testing.assert_allclose(T_a @ step @ step, T_b, atol=1e-10)
    # the midpoint is equidistant from both ends along the geodesic
    d_a = np.linalg.norm(se3.log(se3.inverse(T_a) @ T_mid))
    d_b = np.linalg.norm(se3.log(se3.inverse(T_mid) @ T_b))
    np.testing.assert_allclose(d_a, d_b, rtol=1e-9)


def test_adjoint_identity() -> None:
    rng = np.random.default_rng(0)
    poses = _random_poses(rng, 50)
    twists = rng.normal(size=(50, 6))
    for T, xi in zip(poses, twists):
        lhs = T @ se3.exp(xi) @ se3.inverse(T)
        np.testing.assert_allclose(se3.exp(se3.adjoint(T) @ xi), lhs, atol=1e-10)
        np.testing.assert_allclose(se3.hat(se3.adjoint(T) @ xi), T @ se3.hat(xi) @ se3.inverse(T), atol=1e-12)
    T1, T2 = poses[:2]
    np.testing.assert_allclose(se3.adjoint(T1 @ T2), se3.adjoint(T1) @ se3.adjoint(T2), atol=1e-12)
    np.testing.assert_allclose(se3.adjoint(se3.inverse(T1)), np.linalg.inv(se3.adjoint(T1)), atol=1e-10)


def test_transform_points_matches_homogeneous_product() -> None:
    rng = np.random.default_rng(0)
    T = _random_poses(rng, 1)[0]
    P = rng.normal(size=(20, 3))
    expected = (T @ np.c_[P, np.ones(20)].T).T[:, :3]
    np.testing.assert_allclose(se3.transform_points(T, P), expected, atol=1e-12)
    back = se3.transform_points(se3.inverse(T), se3.transform_points(T, P))
    np.testing.assert_allclose(back, P, atol=1e-12)


def test_shape_errors() -> None:
    with pytest.raises(ValueError):
        se3.exp(np.zeros(3))
    with pytest.raises(ValueError):
        se3.log(np.eye(3))
    with pytest.raises(ValueError):
        se3.transform_points(np.eye(4), np.zeros((5, 2)))
    with pytest.raises(ValueError):
        se3.to_rpy(np.eye(2))
