"""Rigid-body transforms in the plane: SE(2) poses and twists.

Conventions (thesis §3.B):

* A pose is a (3, 3) homogeneous matrix ``T_a_b``: the pose of frame b expressed in frame a, so that
  ``p_a = T_a_b @ p_b`` and ``T_a_c = T_a_b @ T_b_c``. Positions are in metres, angles in radians,
  counter-clockwise positive about the z axis.
* A twist is ``xi = (vx, vy, omega)``, shape (3,), translational part first:
  ``hat(xi) = [[0, -omega, vx], [omega, 0, vy], [0, 0, 0]]`` and ``T = exp(hat(xi))``. ``xi`` is the constant
  body velocity (m/s, rad/s) that moves frame a onto frame b in 1 s; ``log`` is its inverse, returning
  ``omega`` in (-pi, pi].

``exp``, ``log`` and ``inverse`` also accept batches (leading dimensions): ``exp`` maps (N, 3) twists to
(N, 3, 3) poses and ``log`` maps them back.
"""

from __future__ import annotations

from functools import reduce

import numpy as np
from numpy.typing import ArrayLike

from simnav.geometry import se3


def _as_float(x: ArrayLike, tail: tuple[int, ...], name: str) -> np.ndarray:
    """Converts ``x`` to a float64 array and checks that its trailing dimensions are ``tail``."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < len(tail) or a.shape[a.ndim - len(tail):] != tail:
        raise ValueError(f"{name} must have shape (..., {', '.join(map(str, tail))}), got {a.shape}")
    return a


def _sinc(x: np.ndarray) -> np.ndarray:
    """sin(x) / x, exact at 0."""
    return np.sinc(x / np.pi)


def wrap_angle(a_rad: ArrayLike) -> np.ndarray | float:
    """Wraps angles to (-pi, pi].

    Args:
        a_rad: scalar or array of angles, rad.

    Returns:
        Wrapped angle(s), rad; a float for scalar input, otherwise an array of the input's shape.
    """
    a = np.asarray(a_rad, dtype=np.float64)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    w = np.where(w <= -np.pi, w + 2.0 * np.pi, w)
    return float(w) if w.ndim == 0 else w


def _rotation(theta: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotation matrices for (...) angles in rad."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def exp(xi: ArrayLike) -> np.ndarray:
    """SE(2) exponential map (closed form ``t = V(omega) @ (vx, vy)``).

    Args:
        xi: (3,) or (N, 3) twist ``(vx, vy, omega)``, m/s and rad/s (motion during 1 s).

    Returns:
        (3, 3) or (N, 3, 3) pose ``T_a_b = exp(hat(xi))``.
    """
    xi = _as_float(xi, (3,), "xi")
    theta = xi[..., 2]
    a = _sinc(theta)  # sin(theta) / theta
    b = np.sin(theta / 2) * _sinc(theta / 2)  # (1 - cos(theta)) / theta without cancellation
    vx, vy = xi[..., 0], xi[..., 1]
    T = np.zeros(xi.shape[:-1] + (3, 3))
    T[..., :2, :2] = _rotation(theta)
    T[..., 0, 2] = a * vx - b * vy
    T[..., 1, 2] = b * vx + a * vy
    T[..., 2, 2] = 1.0
    return T


def log(T: ArrayLike) -> np.ndarray:
    """SE(2) logarithm, the inverse of :func:`exp`.

    Args:
        T: (3, 3) or (N, 3, 3) pose.

    Returns:
        (3,) or (N, 3) twist ``(vx, vy, omega)`` with ``omega`` in (-pi, pi].
    """
    T = _as_float(T, (3, 3), "T")
    theta = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    theta = np.where(theta <= -np.pi, np.pi, theta)  # atan2 gives -pi for a sin of -0.0
    half = theta / 2
    a = np.cos(half) / _sinc(half)  # (theta/2) cot(theta/2), finite for |theta| <= pi
    tx, ty = T[..., 0, 2], T[..., 1, 2]
    return np.stack([a * tx + half * ty, -half * tx + a * ty, theta], axis=-1)


def inverse(T: ArrayLike) -> np.ndarray:
    """Inverse of a planar rigid transform: ``T_b_a`` from ``T_a_b``.

    Args:
        T: (..., 3, 3) pose.

    Returns:
        (..., 3, 3) pose ``[[R^T, -R^T t], [0, 1]]``.
    """
    T = _as_float(T, (3, 3), "T")
    Rt = np.swapaxes(T[..., :2, :2], -1, -2)
    out = np.zeros_like(T)
    out[..., :2, :2] = Rt
    out[..., :2, 2] = -(Rt @ T[..., :2, 2, None])[..., 0]
    out[..., 2, 2] = 1.0
    return out


def compose(*Ts: ArrayLike) -> np.ndarray:
    """Chains poses left to right: ``compose(T_a_b, T_b_c, T_c_d) = T_a_d``.

    Args:
        *Ts: (3, 3) poses; none gives the identity.

    Returns:
        (3, 3) product pose.
    """
    mats = [_as_float(T, (3, 3), "T") for T in Ts]
    return reduce(np.matmul, mats, np.eye(3))


def from_xy_yaw(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """Pose from a position and a heading.

    Args:
        x_m: x of frame b's origin in frame a, m.
        y_m: y of frame b's origin in frame a, m.
        yaw_rad: heading of frame b's x axis in frame a, counter-clockwise, rad.

    Returns:
        (3, 3) pose ``T_a_b``.
    """
    T = np.eye(3)
    T[:2, :2] = _rotation(np.float64(yaw_rad))
    T[:2, 2] = (x_m, y_m)
    return T


def to_xy_yaw(T: ArrayLike) -> tuple[float, float, float]:
    """Position and heading of a pose.

    Args:
        T: (3, 3) pose ``T_a_b``.

    Returns:
        ``(x_m, y_m, yaw_rad)`` with yaw in (-pi, pi].
    """
    T = _as_float(T, (3, 3), "T")
    yaw = wrap_angle(np.arctan2(T[1, 0], T[0, 0]))
    return float(T[0, 2]), float(T[1, 2]), float(yaw)


def interpolate(T_a: ArrayLike, T_b: ArrayLike, s: float) -> np.ndarray:
    """Geodesic interpolation between two poses: ``T_a @ exp(s * log(inv(T_a) @ T_b))``.

    Args:
        T_a: (3, 3) pose at s = 0.
        T_b: (3, 3) pose at s = 1 (same reference frame as ``T_a``).
        s: interpolation parameter, normally in [0, 1] (other values extrapolate).

    Returns:
        (3, 3) interpolated pose in the same reference frame.
    """
    T_a = _as_float(T_a, (3, 3), "T_a")
    xi = log(inverse(T_a) @ _as_float(T_b, (3, 3), "T_b"))
    return T_a @ exp(s * xi)


def transform_points(T: ArrayLike, points: ArrayLike) -> np.ndarray:
    """Applies a pose to planar points: ``p_a = T_a_b @ p_b``.

    Args:
        T: (3, 3) pose ``T_a_b``.
        points: (N, 2) points in frame b, m.

    Returns:
        (N, 2) points in frame a, m.
    """
    T = _as_float(T, (3, 3), "T")
    P = _as_float(points, (2,), "points")
    return P @ T[:2, :2].T + T[:2, 2]


def to_se3(T: ArrayLike) -> np.ndarray:
    """Embeds a planar pose in 3D (z = 0, rotation about z).

    Args:
        T: (3, 3) planar pose ``T_a_b``.

    Returns:
        (4, 4) pose ``T_a_b`` with zero z translation, roll and pitch.
    """
    T = _as_float(T, (3, 3), "T")
    T4 = np.eye(4)
    T4[:2, :2] = T[:2, :2]
    T4[:2, 3] = T[:2, 2]
    return T4


def from_se3(T4: ArrayLike) -> np.ndarray:
    """Projects a 3D pose onto the plane: keeps x, y and the yaw of :func:`simnav.geometry.se3.to_rpy`.

    Args:
        T4: (4, 4) pose ``T_a_b``; its z translation, roll and pitch are dropped.

    Returns:
        (3, 3) planar pose ``T_a_b``.
    """
    T4 = _as_float(T4, (4, 4), "T4")
    _, _, yaw = se3.to_rpy(T4)
    return from_xy_yaw(float(T4[0, 3]), float(T4[1, 3]), yaw)
