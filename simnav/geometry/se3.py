"""Rigid-body transforms in 3D: SO(3), SE(3), twists, quaternions and roll-pitch-yaw angles.

Conventions (thesis §3.B):

* A pose is a (4, 4) homogeneous matrix ``T_a_b``: the pose of frame b expressed in frame a, so that
  ``p_a = T_a_b @ p_b`` and ``T_a_c = T_a_b @ T_b_c``. Translations are in metres, angles in radians.
* A twist is ``xi = (nu, omega) = (vx, vy, vz, wx, wy, wz)``, shape (6,), translational part first:
  ``hat(xi) = [[skew(omega), nu], [0, 0]]`` and ``T = exp(hat(xi))``. ``xi`` is the constant body velocity
  (m/s, rad/s) that moves frame a onto frame b in 1 s; ``log`` is its inverse, returning the rotation
  angle in [0, pi].
* Quaternions are ``(w, x, y, z)`` with ``w >= 0``; roll-pitch-yaw means
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

``exp``, ``log``, ``so3_exp``, ``so3_log``, ``skew``, ``hat``, ``vee`` and ``inverse`` also accept batches
(leading dimensions), e.g. ``exp`` maps (N, 6) twists to (N, 4, 4) poses.
"""

from __future__ import annotations

import math
from functools import reduce

import numpy as np
from numpy.typing import ArrayLike

# Below this rotation angle (rad) the coefficients with a cancellation use their Taylor series.
_SMALL_ANGLE_RAD = 1e-2
# Below this |R[0,0]|, |R[1,0]| norm the roll-pitch-yaw decomposition is treated as gimbal-locked.
_GIMBAL_EPS = 1e-10


def _as_float(x: ArrayLike, tail: tuple[int, ...], name: str) -> np.ndarray:
    """Converts ``x`` to a float64 array and checks that its trailing dimensions are ``tail``."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < len(tail) or a.shape[a.ndim - len(tail):] != tail:
        raise ValueError(f"{name} must have shape (..., {', '.join(map(str, tail))}), got {a.shape}")
    return a


def skew(w: ArrayLike) -> np.ndarray:
    """Skew-symmetric cross-product matrix.

    Args:
        w: (..., 3) vector.

    Returns:
        (..., 3, 3) matrix ``S`` with ``S @ v == np.cross(w, v)``.
    """
    w = _as_float(w, (3,), "w")
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def _unskew(S: np.ndarray) -> np.ndarray:
    """(..., 3) vector of the antisymmetric part of (..., 3, 3) ``S`` (``vee`` of ``(S - S^T) / 2``)."""
    A = S - np.swapaxes(S, -1, -2)
    return 0.5 * np.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], -1)


def hat(xi: ArrayLike) -> np.ndarray:
    """se(3) hat operator.

    Args:
        xi: (..., 6) twist ``(vx, vy, vz, wx, wy, wz)``, m/s and rad/s.

    Returns:
        (..., 4, 4) matrix ``[[skew(omega), nu], [0, 0]]``.
    """
    xi = _as_float(xi, (6,), "xi")
    X = np.zeros(xi.shape[:-1] + (4, 4))
    X[..., :3, :3] = skew(xi[..., 3:])
    X[..., :3, 3] = xi[..., :3]
    return X


def vee(X: ArrayLike) -> np.ndarray:
    """se(3) vee operator, the inverse of :func:`hat`.

    Args:
        X: (..., 4, 4) twist matrix (only the antisymmetric part of the rotation block is used).

    Returns:
        (..., 6) twist ``(nu, omega)``.
    """
    X = _as_float(X, (4, 4), "X")
    return np.concatenate([X[..., :3, 3], _unskew(X[..., :3, :3])], axis=-1)


def _sinc(x: np.ndarray) -> np.ndarray:
    """sin(x) / x, exact at 0."""
    return np.sinc(x / np.pi)


def _coeff_c(theta: np.ndarray) -> np.ndarray:
    """(theta - sin theta) / theta^3, with its Taylor series near 0."""
    t2 = theta * theta
    small = theta < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    exact = (safe - np.sin(safe)) / safe**3
    taylor = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0
    return np.where(small, taylor, exact)


def _coeff_d(theta: np.ndarray) -> np.ndarray:
    """(1 - (theta/2) cot(theta/2)) / theta^2, the K^2 coefficient of V^-1, with its Taylor series near 0."""
    t2 = theta * theta
    small = theta < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    half_cot = np.cos(safe / 2) / _sinc(safe / 2)
    exact = (1.0 - half_cot) / (safe * safe)
    taylor = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    return np.where(small, taylor, exact)


def so3_exp(w: ArrayLike) -> np.ndarray:
    """Rodrigues' formula: rotation vector to rotation matrix.

    Args:
        w: (..., 3) rotation vector (axis times angle), rad.

    Returns:
        (..., 3, 3) rotation matrix ``R = exp(skew(w))``.
    """
    w = _as_float(w, (3,), "w")
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    a = _sinc(theta)
    b = 0.5 * _sinc(theta / 2) ** 2  # (1 - cos theta) / theta^2 without cancellation
    return np.eye(3) + a * K + b * (K @ K)


def _rotation_angle(R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns ``(theta, cos_theta, s)`` with ``s = sin(theta) * axis`` for (..., 3, 3) rotations."""
    s = _unskew(R)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    theta = np.arctan2(np.linalg.norm(s, axis=-1), c)
    return theta, c, s


def _axis_near_pi(R: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Unit rotation axis from the symmetric part of R, for angles above pi/2 (well conditioned there).

    Uses ``(R + R^T)/2 - cos(theta) I = (1 - cos(theta)) n n^T``; the column with the largest diagonal entry
    gives ``n`` up to sign, which is taken from ``s = sin(theta) n``.
    """
    M = 0.5 * (R + np.swapaxes(R, -1, -2)) - c[..., None, None] * np.eye(3)
    k = np.argmax(np.diagonal(M, axis1=-2, axis2=-1), axis=-1)
    col = np.take_along_axis(M, k[..., None, None], axis=-1)[..., 0]
    n = col / np.maximum(np.linalg.norm(col, axis=-1, keepdims=True), 1e-300)
    sign = np.where(np.sum(n * s, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    return sign * n


def so3_log(R: ArrayLike) -> np.ndarray:
    """Rotation matrix to rotation vector, robust near 0 and near pi.

    Args:
        R: (..., 3, 3) rotation matrix.

    Returns:
        (..., 3) rotation vector ``w`` with ``|w|`` in [0, pi], rad. At exactly pi either sign of the axis
        may be returned (both are valid logarithms).
    """
    R = _as_float(R, (3, 3), "R")
    theta, c, s = _rotation_angle(R)
    w_small = s / _sinc(theta)[..., None]  # accurate while sin(theta) is not small (theta <= pi/2)
    w_large = theta[..., None] * _axis_near_pi(R, c, s)
    return np.where((c >= 0.0)[..., None], w_small, w_large)


def _v_matrix(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) left Jacobian ``V`` of SO(3) such that the translation of ``exp(xi)`` is ``V @ nu``."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    b = 0.5 * _sinc(theta / 2) ** 2
    return np.eye(3) + b * K + _coeff_c(theta) * (K @ K)


def _v_inverse(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) inverse of :func:`_v_matrix`: ``I - K/2 + D K^2``."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    return np.eye(3) - 0.5 * K + _coeff_d(theta) * (K @ K)


def exp(xi: ArrayLike) -> np.ndarray:
    """SE(3) exponential map.

    Args:
        xi: (6,) or (..., 6) twist ``(vx, vy, vz, wx, wy, wz)``, m/s and rad/s (motion during 1 s).

    Returns:
        (4, 4) or (..., 4, 4) pose ``T_a_b = exp(hat(xi))``.
    """
    xi = _as_float(xi, (6,), "xi")
    if xi.ndim == 1:
        return _exp_one(xi)
    w = xi[..., 3:]
    T = np.zeros(xi.shape[:-1] + (4, 4))
    T[..., :3, :3] = so3_exp(w)
    T[..., :3, 3] = (_v_matrix(w) @ xi[..., :3, None])[..., 0]
    T[..., 3, 3] = 1.0
    return T


def log(T: ArrayLike) -> np.ndarray:
    """SE(3) logarithm, the inverse of :func:`exp` (rotation angle in [0, pi]).

    Args:
        T: (4, 4) or (..., 4, 4) pose.

    Returns:
        (6,) or (..., 6) twist ``(vx, vy, vz, wx, wy, wz)``.
    """
    T = _as_float(T, (4, 4), "T")
    if T.ndim == 2:
        return _log_one(T)
    w = so3_log(T[..., :3, :3])
    nu = (_v_inverse(w) @ T[..., :3, 3, None])[..., 0]
    return np.concatenate([nu, w], axis=-1)


# One pose or twist at a time (the odometries' inner loops): the same formulas in scalars, about ten times faster
# than a batch of one through the numpy functions above.


def _coefficients_one(theta: float) -> tuple[float, float, float, float]:
    """``sin t / t``, ``(1 - cos t) / t^2``, ``(t - sin t) / t^3`` and ``(1 - (t/2) cot(t/2)) / t^2`` of one
    angle ``t`` >= 0 (Taylor series below ``_SMALL_ANGLE_RAD`` for the last two, as the batch versions)."""
    a = math.sin(theta) / theta if theta > 0.0 else 1.0
    half = math.sin(0.5 * theta) / (0.5 * theta) if theta > 0.0 else 1.0
    b = 0.5 * half * half
    t2 = theta * theta
    if theta < _SMALL_ANGLE_RAD:
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0
        d = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    else:
        c = (theta - math.sin(theta)) / theta**3
        d = (1.0 - math.cos(0.5 * theta) / half) / t2
    return a, b, c, d


def _skew_one(wx: float, wy: float, wz: float) -> np.ndarray:
    """(3, 3) :func:`skew` of one vector."""
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


def _exp_one(xi: np.ndarray) -> np.ndarray:
    """:func:`exp` of one (6,) twist."""
    wx, wy, wz = float(xi[3]), float(xi[4]), float(xi[5])
    a, b, c, _ = _coefficients_one(math.sqrt(wx * wx + wy * wy + wz * wz))
    K = _skew_one(wx, wy, wz)
    K2 = K @ K
    T = np.eye(4)
    T[:3, :3] += a * K + b * K2
    T[:3, 3] = xi[:3] + (b * K + c * K2) @ xi[:3]
    return T


def _log_one(T: np.ndarray) -> np.ndarray:
    """:func:`log` of one (4, 4) pose."""
    R = T[:3, :3]
    sx, sy, sz = 0.5 * (R[2, 1] - R[1, 2]), 0.5 * (R[0, 2] - R[2, 0]), 0.5 * (R[1, 0] - R[0, 1])
    cos_theta = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    theta = math.atan2(math.sqrt(sx * sx + sy * sy + sz * sz), cos_theta)
    if cos_theta >= 0.0:
        k = 1.0 / (math.sin(theta) / theta) if theta > 0.0 else 1.0
        w = np.array([sx * k, sy * k, sz * k])
    else:
        w = theta * _axis_near_pi(R, np.float64(cos_theta), np.array([sx, sy, sz]))
    _, _, _, d = _coefficients_one(theta)
    K = _skew_one(w[0], w[1], w[2])
    nu = T[:3, 3] - 0.5 * (K @ T[:3, 3]) + d * (K @ (K @ T[:3, 3]))
    return np.concatenate([nu, w])


def inverse(T: ArrayLike) -> np.ndarray:
    """Inverse of a rigid transform: ``T_b_a`` from ``T_a_b``.

    Args:
        T: (..., 4, 4) pose.

    Returns:
        (..., 4, 4) pose ``[[R^T, -R^T t], [0, 1]]``.
    """
    T = _as_float(T, (4, 4), "T")
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def compose(*Ts: ArrayLike) -> np.ndarray:
    """Chains poses left to right: ``compose(T_a_b, T_b_c, T_c_d) = T_a_d``.

    Args:
        *Ts: (4, 4) poses; none gives the identity.

    Returns:
        (4, 4) product pose.
    """
    mats = [_as_float(T, (4, 4), "T") for T in Ts]
    return reduce(np.matmul, mats, np.eye(4))


def from_rotation_translation(R: ArrayLike, t: ArrayLike | None = None) -> np.ndarray:
    """Builds a pose from a rotation and a translation.

    Args:
        R: (3, 3) rotation of frame b in frame a.
        t: (3,) origin of frame b in frame a, m; zero if omitted.

    Returns:
        (4, 4) pose ``T_a_b``.
    """
    T = np.eye(4)
    T[:3, :3] = _as_float(R, (3, 3), "R")
    if t is not None:
        T[:3, 3] = _as_float(t, (3,), "t")
    return T


def _rotation_block(R_or_T: ArrayLike) -> np.ndarray:
    """The (3, 3) rotation of a (3, 3) rotation or (4, 4) pose."""
    a = np.asarray(R_or_T, dtype=np.float64)
    if a.shape == (4, 4):
        return a[:3, :3]
    if a.shape == (3, 3):
        return a
    raise ValueError(f"expected a (3, 3) rotation or (4, 4) pose, got shape {a.shape}")


def quat_wxyz_to_matrix(q: ArrayLike) -> np.ndarray:
    """Unit quaternion to rotation matrix.

    Args:
        q: (4,) quaternion ``(w, x, y, z)``; normalised here, must be non-zero.

    Returns:
        (3, 3) rotation matrix.
    """
    q = _as_float(q, (4,), "q")
    norm = float(np.linalg.norm(q))
    if q.ndim != 1 or not norm > 0.0:
        raise ValueError(f"q must be a non-zero (4,) quaternion, got {q!r}")
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def from_quat_wxyz(q: ArrayLike, t: ArrayLike | None = None) -> np.ndarray:
    """Pose from a quaternion and a translation.

    Args:
        q: (4,) quaternion ``(w, x, y, z)`` of frame b in frame a (normalised here).
        t: (3,) origin of frame b in frame a, m; zero if omitted.

    Returns:
        (4, 4) pose ``T_a_b``.
    """
    return from_rotation_translation(quat_wxyz_to_matrix(q), t)


def to_quat_wxyz(R_or_T: ArrayLike) -> np.ndarray:
    """Rotation to unit quaternion (Shepperd's method).

    Args:
        R_or_T: (3, 3) rotation or (4, 4) pose.

    Returns:
        (4,) quaternion ``(w, x, y, z)``, unit norm, ``w >= 0``.
    """
    R = _rotation_block(R_or_T)
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        q = np.array([1 + tr, R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    elif k == 1:
        q = np.array([R[2, 1] - R[1, 2], 1 + 2 * R[0, 0] - tr, R[0, 1] + R[1, 0], R[0, 2] + R[2, 0]])
    elif k == 2:
        q = np.array([R[0, 2] - R[2, 0], R[0, 1] + R[1, 0], 1 + 2 * R[1, 1] - tr, R[1, 2] + R[2, 1]])
    else:
        q = np.array([R[1, 0] - R[0, 1], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1], 1 + 2 * R[2, 2] - tr])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def rpy_to_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Roll-pitch-yaw angles to rotation matrix.

    Args:
        roll_rad: rotation about x, rad.
        pitch_rad: rotation about y, rad.
        yaw_rad: rotation about z, rad.

    Returns:
        (3, 3) rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
    """
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float, t: ArrayLike | None = None) -> np.ndarray:
    """Pose from roll-pitch-yaw angles and a translation.

    Args:
        roll_rad: rotation about x, rad.
        pitch_rad: rotation about y, rad.
        yaw_rad: rotation about z, rad.
        t: (3,) translation, m; zero if omitted.

    Returns:
        (4, 4) pose with rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
    """
    return from_rotation_translation(rpy_to_matrix(roll_rad, pitch_rad, yaw_rad), t)


def to_rpy(R_or_T: ArrayLike) -> tuple[float, float, float]:
    """Rotation to roll-pitch-yaw angles, the inverse of :func:`rpy_to_matrix`.

    Args:
        R_or_T: (3, 3) rotation or (4, 4) pose.

    Returns:
        ``(roll, pitch, yaw)`` in rad; pitch in [-pi/2, pi/2], roll and yaw in [-pi, pi]. At gimbal lock
        (pitch = +-pi/2) roll is set to 0 and the whole rotation about z is reported as yaw.
    """
    R = _rotation_block(R_or_T)
    cos_pitch = float(np.hypot(R[0, 0], R[1, 0]))
    pitch = float(np.arctan2(-R[2, 0], cos_pitch))
    if cos_pitch < _GIMBAL_EPS:
        return 0.0, pitch, float(np.arctan2(-R[0, 1], R[1, 1]))
    return float(np.arctan2(R[2, 1], R[2, 2])), pitch, float(np.arctan2(R[1, 0], R[0, 0]))


def interpolate(T_a: ArrayLike, T_b: ArrayLike, s: float) -> np.ndarray:
    """Geodesic interpolation between two poses: ``T_a @ exp(s * log(inv(T_a) @ T_b))``.

    Args:
        T_a: (4, 4) pose at s = 0.
        T_b: (4, 4) pose at s = 1 (same reference frame as ``T_a``).
        s: interpolation parameter, normally in [0, 1] (other values extrapolate).

    Returns:
        (4, 4) interpolated pose in the same reference frame.
    """
    T_a = _as_float(T_a, (4, 4), "T_a")
    xi = log(inverse(T_a) @ _as_float(T_b, (4, 4), "T_b"))
    return T_a @ exp(s * xi)


def transform_points(T: ArrayLike, points: ArrayLike) -> np.ndarray:
    """Applies a pose to points: ``p_a = T_a_b @ p_b``.

    Args:
        T: (4, 4) pose ``T_a_b``.
        points: (N, 3) points in frame b, m.

    Returns:
        (N, 3) points in frame a, m.
    """
    T = _as_float(T, (4, 4), "T")
    P = _as_float(points, (3,), "points")
    return P @ T[:3, :3].T + T[:3, 3]


def adjoint(T: ArrayLike) -> np.ndarray:
    """Adjoint of a pose for twists ordered ``(nu, omega)``.

    Satisfies ``T @ exp(xi) @ inv(T) == exp(adjoint(T) @ xi)``, i.e. it maps a twist expressed in frame b
    to the same motion expressed in frame a.

    Args:
        T: (4, 4) pose ``T_a_b``.

    Returns:
        (6, 6) matrix ``[[R, skew(t) @ R], [0, R]]``.
    """
    T = _as_float(T, (4, 4), "T")
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[:3, 3:] = skew(t) @ R
    return Ad
