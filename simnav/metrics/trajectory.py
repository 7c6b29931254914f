"""Trajectory accuracy: RPE per second, ATE after alignment, KITTI-style drift per segment length, and a plot.

Every metric compares an estimate (e.g. ``T_odom_base`` of an odometry) with a ground truth (e.g.
``T_world_base``). Poses are associated by time stamp: the ground truth is interpolated at the estimate's stamps
between the two ground-truth poses that bracket each stamp (linear in translation, slerp in rotation), so both
trajectories may run at different rates; estimate poses outside the ground truth's time span are left out.
RPE and drift compare relative motions and so do not depend on the two reference frames; ATE first aligns the
estimate to the ground truth with Umeyama's method (evo).

Errors in the inputs (too few poses, stamps that do not increase, trajectories that do not overlap in time)
raise :class:`~simnav.io.DataFormatError` with a message saying which trajectory and what was expected.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from simnav.errors import ConfigError
from simnav.io import DataFormatError, Trajectory

DEFAULT_SEGMENTS_M = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
ALIGNMENTS = ("se3", "sim3", "none")
_STAMP_EPS_S = 1e-9
_PLANAR_Z_TOL_M = 1e-6
_PLANAR_TILT_TOL = 1e-8  # 1 - cos(tilt) for a 1.4e-4 rad tilt


# ----------------------------------------------------------------------------------------------------------
# Results


@dataclass(frozen=True, eq=False)
class RPEResult:
    """Relative pose error per second of motion.

    Attributes:
        delta_s: requested time between the two poses of a pair, s.
        tol_s: largest accepted deviation of a pair's time difference from ``delta_s``, s.
        pairs: number of pose pairs evaluated.
        trans_rmse_cm_s, trans_mean_cm_s, trans_median_cm_s, trans_max_cm_s: translational error per second
            of the pair, cm/s.
        rot_rmse_deg_s, rot_mean_deg_s, rot_median_deg_s, rot_max_deg_s: rotational error per second, deg/s.
        stamps_s: (pairs,) stamp of the first pose of each pair, s.
        trans_errors_cm_s: (pairs,) translational error of each pair, cm/s.
        rot_errors_deg_s: (pairs,) rotational error of each pair, deg/s.
    """

    delta_s: float
    tol_s: float
    pairs: int
    trans_rmse_cm_s: float
    trans_mean_cm_s: float
    trans_median_cm_s: float
    trans_max_cm_s: float
    rot_rmse_deg_s: float
    rot_mean_deg_s: float
    rot_median_deg_s: float
    rot_max_deg_s: float
    stamps_s: np.ndarray = field(repr=False)
    trans_errors_cm_s: np.ndarray = field(repr=False)
    rot_errors_deg_s: np.ndarray = field(repr=False)

    def as_dict(self) -> dict[str, float | int]:
        """The summary values (no per-pair arrays), JSON-ready."""
        return _scalars(self)


@dataclass(frozen=True, eq=False)
class ATEResult:
    """Absolute trajectory error after aligning the estimate to the ground truth.

    Attributes:
        align: the requested alignment: ``se3``, ``sim3`` or ``none``.
        alignment: the alignment actually used: ``align`` (3D Umeyama), ``se3-planar``/``sim3-planar`` (Umeyama
            in the x-y plane: a rotation about z, for planar trajectories or collinear positions), ``origin``
            (first poses made equal, when all positions coincide) or ``none``.
        pairs: number of associated poses.
        rmse_m, mean_m, median_m, max_m: statistics of the position errors, m.
        scale: scale applied to the estimate (1 unless ``sim3``).
        T_gt_est: (4, 4) rigid part of the alignment: ``aligned = T_gt_est @ (scaled estimate)``.
        stamps_s: (pairs,) stamps of the associated poses (the estimate's), s.
        errors_m: (pairs,) position error at each stamp, m.
        aligned: the aligned estimate at ``stamps_s`` (poses in the ground-truth frame).
        reference: the ground truth interpolated at ``stamps_s``.
    """

    align: str
    alignment: str
    pairs: int
    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    scale: float
    T_gt_est: np.ndarray = field(repr=False)
    stamps_s: np.ndarray = field(repr=False)
    errors_m: np.ndarray = field(repr=False)
    aligned: Trajectory = field(repr=False)
    reference: Trajectory = field(repr=False)

    def as_dict(self) -> dict[str, float | int | str]:
        """The summary values (no arrays or trajectories), JSON-ready."""
        return _scalars(self)


@dataclass(frozen=True)
class DriftResult:
    """Relative error over segments of one length, KITTI style.

    Attributes:
        length_m: segment length along the ground-truth path, m.
        segments: number of segments evaluated (one per start pose that has a segment of this length).
        translation_pct: mean translational error over the segments, % of ``length_m``.
        rotation_deg_per_m: mean rotational error over the segments per metre of path, deg/m.
        translation_median_pct: median translational error, % of ``length_m``.
        rotation_median_deg_per_m: median rotational error, deg/m.
    """

    length_m: float
    segments: int
    translation_pct: float
    rotation_deg_per_m: float
    translation_median_pct: float
    rotation_median_deg_per_m: float

    def as_dict(self) -> dict[str, float | int]:
        """All values, JSON-ready."""
        return _scalars(self)


def _scalars(result: object) -> dict:
    out = {}
    for name in result.__dataclass_fields__:  # type: ignore[attr-defined]
        value = getattr(result, name)
        if isinstance(value, bool | int | str):
            out[name] = value
        elif isinstance(value, float | np.floating):
            out[name] = float(value)
    return out


# ----------------------------------------------------------------------------------------------------------
# Metrics


def rpe_per_second(est: Trajectory, gt: Trajectory, delta_s: float = 1.0, tol_s: float = 0.05) -> RPEResult:
    """Relative pose error over pairs of estimate poses ``delta_s`` apart, per second.

    evo's RPE pairs poses by a number of frames or by travelled distance or angle, not by time, so this metric is
    computed here. Pairing: for each estimate pose i, the estimate pose j whose stamp is closest to
    ``t_i + delta_s``, if it is within ``tol_s`` of it. The ground truth is interpolated at both stamps (see the
    module docs); pairs with a stamp outside the ground truth's time span are skipped. The error of a pair is
    ``E = inv(inv(G_i) @ G_j) @ inv(E_i) @ E_j``; its translation norm and rotation angle are divided by the
    pair's actual time difference ``t_j - t_i``.

    Args:
        est: the estimate; stamps strictly increasing, s.
        gt: the ground truth; stamps strictly increasing, s.
        delta_s: time between the poses of a pair, s (> 0).
        tol_s: largest accepted deviation from ``delta_s``, s (>= 0, < ``delta_s``).

    Returns:
        The statistics in cm/s and deg/s, and the per-pair errors.

    Raises:
        ConfigError: ``delta_s`` or ``tol_s`` out of range.
        DataFormatError: a trajectory has fewer than 2 poses or stamps that do not increase, the two do not
            overlap in time, or no pair of poses ``delta_s`` apart lies within the ground truth.
    """
    if not (np.isfinite(delta_s) and delta_s > 0):
        raise ConfigError(f"RPE: delta_s must be > 0 s, got {delta_s}")
    if not (np.isfinite(tol_s) and 0 <= tol_s < delta_s):
        raise ConfigError(f"RPE: tol_s must be in [0, delta_s = {delta_s}) s, got {tol_s}")
    _check(est, "estimate")
    _check(gt, "ground truth")
    T_gt, covered = _interpolate(gt, est.stamps_s)
    _require_overlap(est, gt, int(covered.sum()))
    i, j = _pairs_by_time(est.stamps_s, delta_s, tol_s)
    keep = covered[i] & covered[j]
    i, j = i[keep], j[keep]
    if len(i) == 0:
        raise DataFormatError(
            f"RPE: no pair of estimate poses {delta_s:g} s (± {tol_s:g} s) apart within the ground truth's time "
            f"span ({_span(gt)}); the estimate covers {_span(est)}"
        )
    dt = est.stamps_s[j] - est.stamps_s[i]
    trans_m, rot_rad = _relative_errors(est.T[i], est.T[j], T_gt[i], T_gt[j])
    trans = trans_m / dt * 100.0
    rot = np.degrees(rot_rad) / dt
    return RPEResult(float(delta_s), float(tol_s), len(i), *_stats(trans), *_stats(rot), est.stamps_s[i], trans, rot)


def ate(est: Trajectory, gt: Trajectory, align: str = "se3") -> ATEResult:
    """Absolute trajectory error (position) after aligning the estimate to the ground truth.

    The ground truth is interpolated at the estimate's stamps (module docs; the equivalent of evo's
    ``associate_trajectories`` without its nearest-stamp error), then the estimate is aligned with evo's
    Umeyama alignment (``PoseTrajectory3D.align``): a rigid transform (``se3``), a similarity (``sim3``) or none.
    When both trajectories are planar (one height, z axes up, as for a wheeled robot) or the positions are
    collinear, the alignment is solved in the x-y plane (evo's Umeyama on x, y: a rotation about z): a 3D rotation
    could otherwise turn a mirrored estimate upside down to fit it, and is not determined for a straight run.
    When all positions coincide, the first poses are made equal.

    Args:
        est: the estimate; stamps strictly increasing, s.
        gt: the ground truth; stamps strictly increasing, s.
        align: ``se3``, ``sim3`` or ``none``.

    Returns:
        The statistics in m, the alignment and the aligned estimate.

    Raises:
        ConfigError: unknown ``align``.
        DataFormatError: a trajectory has fewer than 2 poses or stamps that do not increase, or the two overlap
            in fewer than 2 poses.
    """
    if align not in ALIGNMENTS:
        raise ConfigError(f"ATE: align must be one of {', '.join(ALIGNMENTS)}; got {align!r}")
    stamps, T_est, T_gt = _associate(est, gt)
    T_aligned, T_gt_est, scale, alignment = _align(T_est, T_gt, stamps, align)
    errors = np.linalg.norm(T_aligned[:, :3, 3] - T_gt[:, :3, 3], axis=1)
    rmse, mean, median, max_ = _stats(errors)
    return ATEResult(align, alignment, len(stamps), rmse, mean, median, max_, scale, T_gt_est, stamps, errors,
                     Trajectory(stamps, T_aligned), Trajectory(stamps, T_gt))


def drift_per_segment(
    est: Trajectory, gt: Trajectory, lengths_m: Iterable[float] = DEFAULT_SEGMENTS_M
) -> dict[float, DriftResult]:
    """KITTI-style drift: relative error of the estimate over path segments of given lengths.

    Both trajectories are taken at the estimate's stamps (ground truth interpolated, module docs). For every
    start pose i and length L, the segment ends at the first pose j whose distance along the ground-truth path
    from i is at least L; its error is ``E = inv(inv(G_i) @ G_j) @ inv(E_i) @ E_j`` (translation norm / L and
    rotation angle / L, as in the KITTI odometry benchmark), averaged over all segments of that length.

    Args:
        est: the estimate; stamps strictly increasing, s.
        gt: the ground truth; stamps strictly increasing, s.
        lengths_m: segment lengths, m (> 0).

    Returns:
        Length (float, m) -> drift, for the lengths the trajectory is long enough for (possibly none).

    Raises:
        ConfigError: a length is not positive.
        DataFormatError: a trajectory has fewer than 2 poses or stamps that do not increase, or the two overlap
            in fewer than 2 poses.
    """
    lengths = [float(L) for L in lengths_m]
    bad = [L for L in lengths if not (np.isfinite(L) and L > 0)]
    if bad:
        raise ConfigError(f"drift: segment lengths must be > 0 m, got {bad}")
    _, T_est, T_gt = _associate(est, gt)
    steps = np.linalg.norm(np.diff(T_gt[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    results = {}
    for L in lengths:
        end = np.searchsorted(dist, dist + L, side="left")
        start = np.nonzero(end < len(dist))[0]
        if len(start) == 0:
            continue
        trans_m, rot_rad = _relative_errors(T_est[start], T_est[end[start]], T_gt[start], T_gt[end[start]])
        trans_pct = trans_m / L * 100.0
        rot_deg_m = np.degrees(rot_rad) / L
        results[L] = DriftResult(L, len(start), float(trans_pct.mean()), float(rot_deg_m.mean()),
                                 float(np.median(trans_pct)), float(np.median(rot_deg_m)))
    return results


def planar_trajectory(stamps_s: np.ndarray, poses_xyt: np.ndarray) -> Trajectory:
    """A trajectory from planar poses, embedded in 3D (z = 0, rotation about z).

    Args:
        stamps_s: (N,) time stamps, s.
        poses_xyt: (N, 3) poses (x m, y m, yaw rad).

    Returns:
        The trajectory with (N, 4, 4) poses.
    """
    xyt = np.asarray(poses_xyt, dtype=np.float64).reshape(-1, 3)
    T = np.tile(np.eye(4), (len(xyt), 1, 1))
    c, s = np.cos(xyt[:, 2]), np.sin(xyt[:, 2])
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, :2, 3] = xyt[:, :2]
    return Trajectory(np.asarray(stamps_s, dtype=np.float64), T)


# ----------------------------------------------------------------------------------------------------------
# Plot


def plot_trajectories(est: Trajectory, gt: Trajectory, path: str | Path, aligned: ATEResult | None = None) -> Path:
    """Saves a PNG: x-y paths of the ground truth and the aligned estimate, and the position error over time.

    Args:
        est: the estimate.
        gt: the ground truth (drawn whole).
        path: the PNG file; missing parent folders are created.
        aligned: the ATE result whose aligned estimate and errors are drawn; computed with ``se3`` when None.

    Returns:
        ``path``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    result = aligned if aligned is not None else ate(est, gt, "se3")
    fig = Figure(figsize=(11, 4.8), layout="constrained")
    FigureCanvasAgg(fig)
    ax_xy, ax_err = fig.subplots(1, 2, width_ratios=(1, 1.3))
    ax_xy.plot(gt.T[:, 0, 3], gt.T[:, 1, 3], color="0.3", lw=1.5, label="ground truth")
    ax_xy.plot(result.aligned.T[:, 0, 3], result.aligned.T[:, 1, 3], color="tab:red", lw=1.0,
               label=f"estimate ({result.alignment} aligned)")
    ax_xy.plot(*gt.T[0, :2, 3], "o", color="0.3", ms=4)
    ax_xy.set(xlabel="x (m)", ylabel="y (m)", title="trajectories")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.grid(alpha=0.3)
    ax_xy.legend(loc="best", fontsize="small")
    ax_err.plot(result.stamps_s - result.stamps_s[0], result.errors_m, color="tab:red", lw=1.0)
    ax_err.axhline(result.rmse_m, color="0.4", ls="--", lw=0.8, label=f"RMSE {result.rmse_m:.3g} m")
    ax_err.set(xlabel="time since the first pose (s)", ylabel="position error (m)", title="ATE over time")
    ax_err.set_ylim(bottom=0)
    ax_err.grid(alpha=0.3)
    ax_err.legend(loc="upper left", fontsize="small")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


# ----------------------------------------------------------------------------------------------------------
# Association, relative errors, alignment


def _check(traj: Trajectory, what: str) -> None:
    if len(traj) < 2:
        raise DataFormatError(f"{what}: needs at least 2 poses, got {len(traj)}")
    if not np.isfinite(traj.stamps_s).all() or not np.isfinite(traj.T).all():
        raise DataFormatError(f"{what}: stamps and poses must be finite")
    steps = np.diff(traj.stamps_s)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise DataFormatError(
            f"{what}: time stamps must be strictly increasing; pose {k} at {traj.stamps_s[k]:.6f} s follows "
            f"{traj.stamps_s[k - 1]:.6f} s"
        )


def _span(traj: Trajectory) -> str:
    return f"{traj.stamps_s[0]:.3f} to {traj.stamps_s[-1]:.3f} s"


def _require_overlap(est: Trajectory, gt: Trajectory, covered: int) -> None:
    if covered == 0:
        raise DataFormatError(
            f"the estimate ({_span(est)}) and the ground truth ({_span(gt)}) do not overlap in time; "
            "are the stamps from the same clock?"
        )
    if covered < 2:
        raise DataFormatError(
            f"only {covered} estimate pose lies within the ground truth's time span ({_span(gt)}); need 2"
        )


def _interpolate(gt: Trajectory, stamps_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth at ``stamps_s``: (M, 4, 4) poses (identity where not covered) and the (M,) covered mask."""
    t = gt.stamps_s
    covered = (stamps_s >= t[0] - _STAMP_EPS_S) & (stamps_s <= t[-1] + _STAMP_EPS_S)
    k = np.clip(np.searchsorted(t, stamps_s, side="right") - 1, 0, len(t) - 2)
    s = np.clip((stamps_s - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
    T = np.tile(np.eye(4), (len(stamps_s), 1, 1))
    T[:, :3, 3] = gt.T[k, :3, 3] + s[:, None] * (gt.T[k + 1, :3, 3] - gt.T[k, :3, 3])
    if len(stamps_s):
        R_a = Rotation.from_matrix(gt.T[k, :3, :3])
        R_ab = R_a.inv() * Rotation.from_matrix(gt.T[k + 1, :3, :3])
        T[:, :3, :3] = (R_a * Rotation.from_rotvec(s[:, None] * R_ab.as_rotvec())).as_matrix()
    T[~covered] = np.eye(4)
    return T, covered


def _associate(est: Trajectory, gt: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (M,), estimate poses (M, 4, 4) and interpolated ground truth (M, 4, 4) at the covered stamps."""
    _check(est, "estimate")
    _check(gt, "ground truth")
    T_gt, covered = _interpolate(gt, est.stamps_s)
    _require_overlap(est, gt, int(covered.sum()))
    return est.stamps_s[covered], est.T[covered], T_gt[covered]


def _pairs_by_time(stamps_s: np.ndarray, delta_s: float, tol_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): j is the stamp closest to ``stamps[i] + delta_s`` and within ``tol_s`` of it."""
    target = stamps_s + delta_s
    hi = np.clip(np.searchsorted(stamps_s, target), 1, len(stamps_s) - 1)
    lo = hi - 1
    j = np.where(np.abs(stamps_s[lo] - target) <= np.abs(stamps_s[hi] - target), lo, hi)
    i = np.arange(len(stamps_s))
    ok = (np.abs(stamps_s[j] - target) <= tol_s + _STAMP_EPS_S) & (j > i)
    return i[ok], j[ok]


def _inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms."""
    R_t = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R_t, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angles (rad, in [0, pi]) of (..., 3, 3) rotations; accurate for small and large angles alike."""
    sin_axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arctan2(np.linalg.norm(sin_axis, axis=-1) / 2.0, cos)


def _relative_errors(
    T_est_i: np.ndarray, T_est_j: np.ndarray, T_gt_i: np.ndarray, T_gt_j: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Translation norms (m) and rotation angles (rad) of ``inv(inv(G_i) G_j) inv(E_i) E_j``, each (K,)."""
    T_gt_ij = _inverse(T_gt_i) @ T_gt_j
    T_est_ij = _inverse(T_est_i) @ T_est_j
    E = _inverse(T_gt_ij) @ T_est_ij
    return np.linalg.norm(E[:, :3, 3], axis=1), _rotation_angle(E[:, :3, :3])


def _stats(values: np.ndarray) -> tuple[float, float, float, float]:
    """RMSE, mean, median and maximum of (K,) values."""
    return (float(np.sqrt(np.mean(values**2))), float(np.mean(values)), float(np.median(values)),
            float(np.max(values)))


def _align(
    T_est: np.ndarray, T_gt: np.ndarray, stamps_s: np.ndarray, align: str
) -> tuple[np.ndarray, np.ndarray, float, str]:
    """Aligned estimate (M, 4, 4), the rigid part T_gt_est (4, 4), the scale and the alignment used."""
    if align == "none":
        return T_est.copy(), np.eye(4), 1.0, "none"
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PoseTrajectory3D

    with_scale = align == "sim3"
    if not (_is_planar(T_est) and _is_planar(T_gt)):
        traj = PoseTrajectory3D(poses_se3=list(T_est), timestamps=stamps_s.copy())
        ref = PoseTrajectory3D(poses_se3=list(T_gt), timestamps=stamps_s.copy())
        try:
            R, t, scale = traj.align(ref, correct_scale=with_scale)
            return np.stack(traj.poses_se3), _rigid(R, t), float(scale), align
        except GeometryException:  # collinear positions: the orientations fix the rotation about the line
            return _align_with_axes(T_est, T_gt, with_scale, align)
    try:
        T_gt_est, scale = _planar_umeyama(T_est[:, :3, 3], T_gt[:, :3, 3], with_scale)
        alignment = f"{align}-planar"
    except GeometryException:  # all positions coincide
        T_gt_est, scale, alignment = T_gt[0] @ _inverse(T_est[0]), 1.0, "origin"
    scaled = T_est.copy()
    scaled[:, :3, 3] *= scale
    return T_gt_est @ scaled, T_gt_est, float(scale), alignment


def _align_with_axes(T_est: np.ndarray, T_gt: np.ndarray, with_scale: bool, align: str
                     ) -> tuple[np.ndarray, np.ndarray, float, str]:
    """Umeyama on the positions plus points 1 m along each pose's x and y axes (a straight 3D run: the positions
    alone leave the rotation about the line free)."""
    from evo.core.geometry import GeometryException, umeyama_alignment

    def cloud(T: np.ndarray) -> np.ndarray:
        return np.concatenate([T[:, :3, 3], T[:, :3, 3] + T[:, :3, 0], T[:, :3, 3] + T[:, :3, 1]]).T

    try:
        R, t, scale = umeyama_alignment(cloud(T_est), cloud(T_gt), with_scale)
    except GeometryException:
        return T_gt[0] @ _inverse(T_est[0]) @ T_est, T_gt[0] @ _inverse(T_est[0]), 1.0, "origin"
    T_gt_est = _rigid(R, t)
    scaled = T_est.copy()
    scaled[:, :3, 3] *= scale
    return T_gt_est @ scaled, T_gt_est, float(scale), f"{align}-axes"


def _is_planar(T: np.ndarray) -> bool:
    """All poses at one height with an upright z axis (a planar robot's trajectory embedded in 3D)."""
    z = T[:, 2, 3]
    return bool(np.ptp(z) <= _PLANAR_Z_TOL_M and (T[:, 2, 2] >= 1.0 - _PLANAR_TILT_TOL).all())


def _planar_umeyama(p_est: np.ndarray, p_gt: np.ndarray, with_scale: bool) -> tuple[np.ndarray, float]:
    """Umeyama in the x-y plane lifted to 3D (rotation about z; z offset from the means)."""
    from evo.core.geometry import umeyama_alignment

    R2, t2, scale = umeyama_alignment(p_est[:, :2].T, p_gt[:, :2].T, with_scale)
    T = np.eye(4)
    T[:2, :2] = R2
    T[:2, 3] = t2
    T[2, 3] = np.mean(p_gt[:, 2]) - scale * np.mean(p_est[:, 2])
    return T, float(scale)


def _rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T

