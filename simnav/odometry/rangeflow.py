"""Shared kernels of the planar range-flow odometries RF2O (thesis §3.F) and SRF-Odometry (§3.G).

Both methods align two scans densely: every beam gives one linear constraint on the scanner motion (the range
flow constraint), the constraints are minimised with a robust kernel by IRLS, and a coarse-to-fine pyramid with
warping widens the basin of convergence. This module holds the pieces they share; :mod:`simnav.odometry.rf2o` and
:mod:`simnav.odometry.srf` choose the constraint, kernel, pre-weights and filter constants.

Conventions:

* Scans are upright virtual scans (:func:`simnav.odometry.base.planar_scan`). Ranges are metres, 0 = invalid.
  Beams are reordered by :func:`beam_layout` so angles increase strictly and the field-of-view opening (if any)
  sits between the last and the first beam; angles may then exceed pi. A full turn is *circular*: the last beam
  neighbours the first. Angles need not be uniform: every per-beam spacing comes from the angle vector.
* Pyramids are lists indexed finest first (level 0 = full resolution); each coarser level halves the beams.
* ``T_ref_new`` is the (3, 3) SE(2) pose of the new scan's frame in the reference scan's frame, i.e. the motion
  of the scanner from the reference scan to the new one. Twists ``xi = (vx, vy, w)`` are per scan interval
  (m, m, rad), translational part first, ``T = exp(hat(xi))`` (thesis §3.B).
* Residuals are range differences in metres (after pre-weighting, in metres times a dimensionless weight).

Warping (3.73–3.75) projects the *segments* between consecutive beams of the warped scan onto the target grid
(exact ray/segment intersection for every target beam a segment spans) and keeps the closest range per beam
(z-buffer), as SRF-Odometry does; the keyscan of the multi-scan formulation keeps the farthest instead (§3.G.5).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import TypeVar

import numpy as np

from simnav.errors import ConfigError
from simnav.odometry.base import OdometryEstimate, PlanarScan, laser_to_base_motion, planar_scan
from simnav.sensors.readings import LaserScan

TWO_PI = 2.0 * math.pi
GAUSS5 = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
"""Binomial 5-tap kernel of the scan pyramid."""
MIN_VARIANCE = 1e-12
"""Floor of every covariance eigenvalue (m² or rad²), so covariances stay positive definite."""
MAX_VARIANCE = 1e6
"""Ceiling of every covariance eigenvalue (m² or rad²): an unobservable direction, kept finite."""
MIN_ROWS = 6
"""Fewest constraints a pyramid level needs to be solved."""

C = TypeVar("C")


# ----------------------------------------------------------------------------------------------------------------
# Configuration


@dataclass(frozen=True)
class RangeFlowConfig:
    """Options shared by RF2O and SRF-Odometry.

    Attributes:
        pyramid_gate_m: neighbours whose range differs from the centre beam by this much or more are not mixed
            into it when smoothing/downsampling (bilateral pyramid, §3.C), m.
        smooth_finest: also smooth the full-resolution level with the gated kernel (not downsampled).
        min_level_beams: coarsest pyramid level keeps at least this many beams.
        min_valid_points: a scan with fewer valid beams than this ...
        min_valid_fraction: ... or than this fraction of its beams is not aligned; the constant-velocity
            prediction is reported instead, with covariance ``lost_variance * I``.
        lost_variance: variance (m², m², rad²) reported for a predicted (not measured) increment, and added
            along the unobservable direction of a degenerate one.
        degeneracy_threshold: the estimate is flagged degenerate when the smallest eigenvalue of the geometric
            information (:func:`unit_information`, rotation scaled by the mean range) is below this fraction of
            the largest.
        degeneracy_spacing_deg: that information is taken at the pyramid level whose beam spacing is closest to
            this, deg: at full resolution range noise swamps the local surface orientation.
    """

    pyramid_gate_m: float = 0.3
    smooth_finest: bool = True
    min_level_beams: int = 16
    min_valid_points: int = 20
    min_valid_fraction: float = 0.05
    lost_variance: float = 1.0
    degeneracy_threshold: float = 0.01
    degeneracy_spacing_deg: float = 2.0

    def __post_init__(self) -> None:
        require(self.pyramid_gate_m > 0, "pyramid_gate_m must be > 0")
        require(self.min_level_beams >= 4, "min_level_beams must be >= 4")
        require(self.min_valid_points >= MIN_ROWS, f"min_valid_points must be >= {MIN_ROWS}")
        require(0 <= self.min_valid_fraction < 1, "min_valid_fraction must be in [0, 1)")
        require(self.lost_variance > 0, "lost_variance must be > 0")
        require(self.degeneracy_threshold >= 0, "degeneracy_threshold must be >= 0")
        require(self.degeneracy_spacing_deg > 0, "degeneracy_spacing_deg must be > 0")


def require(ok: bool, message: str) -> None:
    """Raises :class:`ConfigError` with ``message`` unless ``ok``."""
    if not ok:
        raise ConfigError(message)


def make_config(cls: type[C], overrides: dict, owner: str) -> C:
    """Builds a frozen config from keyword overrides, rejecting unknown names.

    Args:
        cls: the config dataclass.
        overrides: field name -> value.
        owner: name used in error messages (e.g. ``"RF2O"``).

    Returns:
        The config instance.

    Raises:
        ConfigError: an override names no field (the message lists the allowed ones) or a value is invalid.
    """
    allowed = sorted(f.name for f in fields(cls))
    unknown = sorted(set(overrides) - set(allowed))
    if unknown:
        raise ConfigError(f"unknown {owner} option(s): {', '.join(unknown)}; allowed: {', '.join(allowed)}")
    return cls(**overrides)


# ----------------------------------------------------------------------------------------------------------------
# Beam layout and pyramid geometry


@dataclass(frozen=True)
class BeamLayout:
    """Order of the beams of an upright scan as used by range flow.

    Attributes:
        take: (n,) indices into the :class:`PlanarScan` arrays (duplicate angles dropped, the widest angular gap
            moved between the last and the first beam).
        angles_rad: (n,) strictly increasing beam angles, rad (unwrapped: may exceed pi; span < 2 pi).
        circular: True when the beams cover a full turn (the last beam neighbours the first).
    """

    take: np.ndarray
    angles_rad: np.ndarray
    circular: bool


def beam_layout(angles_rad: np.ndarray, circular_gap_ratio: float = 2.0) -> BeamLayout:
    """Orders sorted beam angles for range flow and detects full-turn scanners.

    Args:
        angles_rad: (N,) sorted angles of an upright scan in (-pi, pi], rad.
        circular_gap_ratio: the scan is circular when its widest gap (wrap included) is at most this many
            times the median gap.

    Returns:
        The layout; see :class:`BeamLayout`.
    """
    a = np.asarray(angles_rad, dtype=np.float64)
    idx = np.flatnonzero(np.r_[True, np.diff(a) > 1e-9]) if len(a) else np.arange(0)
    if len(idx) >= 2 and a[idx[0]] + TWO_PI - a[idx[-1]] <= 1e-9:
        idx = idx[:-1]  # a beam at -pi and one at +pi are the same direction
    a = a[idx]
    if len(a) < 2:
        return BeamLayout(idx, a, False)
    gaps = np.diff(np.r_[a, a[0] + TWO_PI])
    widest = int(np.argmax(gaps))
    circular = bool(gaps[widest] <= circular_gap_ratio * np.median(gaps))
    if widest < len(a) - 1:  # rotate so the opening sits at the end
        idx = np.r_[idx[widest + 1:], idx[:widest + 1]]
        a = np.r_[a[widest + 1:], a[:widest + 1] + TWO_PI]
    return BeamLayout(idx, a, circular)


@dataclass(frozen=True)
class LevelGeometry:
    """Beam geometry of one pyramid level (shared by every scan of the same scanner).

    Attributes:
        angles_rad: (n,) increasing beam angles, rad.
        cos, sin: (n,) cosine and sine of the angles.
        spacing_rad: (n,) local angular spacing: mean gap to the existing neighbours, rad.
        prev, next: (n,) index of the previous / next beam (itself where there is none).
        has_prev, has_next: (n,) whether that neighbour exists (always, for a circular level).
        gap_prev, gap_next: (n,) angle to the previous / next beam, rad (1 where there is none).
        window: (n, 5) 5-tap window centred on each beam, ``n`` outside a non-circular scan.
        parent_window: (n, 5) window in the next finer level centred on this beam's parent, or None at level 0.
        seg_a, seg_b: (S,) first and second beam of every pair of neighbours (the segments warping projects).
        index_angles, index_values: knots mapping an angle to a fractional beam index (:func:`grid_index`).
        circular: whether the last beam neighbours the first.
        uniform_step_rad: the constant beam spacing if the angles are uniform (wrap included when circular),
            else 0 (fast path of :func:`grid_index`).
    """

    angles_rad: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    spacing_rad: np.ndarray
    prev: np.ndarray
    next: np.ndarray
    has_prev: np.ndarray
    has_next: np.ndarray
    gap_prev: np.ndarray
    gap_next: np.ndarray
    window: np.ndarray
    parent_window: np.ndarray | None
    seg_a: np.ndarray
    seg_b: np.ndarray
    index_angles: np.ndarray
    index_values: np.ndarray
    circular: bool
    uniform_step_rad: float = 0.0

    @property
    def n(self) -> int:
        """Number of beams."""
        return len(self.angles_rad)


def _window(centres: np.ndarray, n: int, circular: bool) -> np.ndarray:
    """(len(centres), 5) indices ``centre - 2 .. centre + 2``, wrapped (circular) or ``n`` outside [0, n)."""
    w = centres[:, None] + np.arange(-2, 3)[None, :]
    if circular:
        return w % n
    return np.where((w >= 0) & (w < n), w, n)


def level_geometry(angles_rad: np.ndarray, circular: bool, parent_window: np.ndarray | None = None) -> LevelGeometry:
    """Precomputes the neighbourhoods and index maps of one pyramid level.

    Args:
        angles_rad: (n,) increasing beam angles of the level, rad, n >= 2.
        circular: whether the last beam neighbours the first.
        parent_window: (n, 5) window in the finer level this level is downsampled from, or None.

    Returns:
        The level's geometry.
    """
    a = np.asarray(angles_rad, dtype=np.float64)
    n = len(a)
    i = np.arange(n)
    if circular:
        prev, nxt = (i - 1) % n, (i + 1) % n
        gaps = np.diff(np.r_[a, a[0] + TWO_PI])
        gap_next, gap_prev = gaps, np.roll(gaps, 1)
        has_prev = has_next = np.ones(n, dtype=bool)
        index_angles, index_values = np.r_[a, a[0] + TWO_PI], np.arange(n + 1, dtype=np.float64)
    else:
        prev, nxt = np.maximum(i - 1, 0), np.minimum(i + 1, n - 1)
        d = np.diff(a)
        gap_prev, gap_next = np.r_[1.0, d], np.r_[d, 1.0]
        has_prev, has_next = i > 0, i < n - 1
        index_angles, index_values = a, i.astype(np.float64)
    spacing = (gap_prev * has_prev + gap_next * has_next) / (has_prev.astype(float) + has_next)
    seg_a = i if circular else i[:-1]
    steps = np.diff(index_angles)
    uniform = float(steps.mean()) if np.ptp(steps) <= 1e-9 * abs(steps.mean()) else 0.0
    return LevelGeometry(a, np.cos(a), np.sin(a), spacing, prev, nxt, has_prev, has_next, gap_prev, gap_next,
                         _window(i, n, circular), parent_window, seg_a, nxt[seg_a], index_angles, index_values,
                         circular, uniform)


def pyramid_geometry(layout: BeamLayout, levels: int, min_level_beams: int) -> tuple[LevelGeometry, ...]:
    """Geometry of every pyramid level, finest first; each level keeps every second beam of the finer one.

    Args:
        layout: the scan's beam layout (at least 2 beams).
        levels: wanted number of levels.
        min_level_beams: no level is made with fewer beams (so fewer levels may result).

    Returns:
        Tuple of :class:`LevelGeometry`, finest first.
    """
    geoms = [level_geometry(layout.angles_rad, layout.circular)]
    while len(geoms) < levels and (geoms[-1].n + 1) // 2 >= min_level_beams:
        fine = geoms[-1]
        centres = np.arange(0, fine.n, 2)
        geoms.append(level_geometry(fine.angles_rad[centres], layout.circular,
                                    _window(centres, fine.n, layout.circular)))
    return tuple(geoms)


# ----------------------------------------------------------------------------------------------------------------
# Pyramid


def gated_average(ranges_m: np.ndarray, window: np.ndarray, gate_m: float) -> np.ndarray:
    """Bilateral 5-tap smoothing that does not mix points across depth discontinuities (§3.C, §3.F.5).

    Each output beam is the binomial-weighted mean of the window's valid ranges, every neighbour further weighted
    by ``gate_m - |r_k - r_centre|`` (neighbours at ``gate_m`` or more from the centre get no weight). An invalid
    centre gives an invalid output.

    Args:
        ranges_m: (n,) input ranges, 0 = invalid.
        window: (m, 5) indices into ``ranges_m`` (``n`` = outside the scan), centre in column 2.
        gate_m: range-similarity gate, m.

    Returns:
        (m,) smoothed ranges, 0 = invalid.
    """
    r = np.append(ranges_m, 0.0)
    nb = r[window]
    centre = nb[:, 2:3]
    w = GAUSS5 * np.clip(gate_m - np.abs(nb - centre), 0.0, None) * (nb > 0)
    total = w.sum(axis=1)
    out = np.zeros(len(nb))
    np.divide((w * nb).sum(axis=1), total, out=out, where=(centre[:, 0] > 0) & (total > 0))
    return out


def build_pyramid(ranges_m: np.ndarray, geoms: Sequence[LevelGeometry], gate_m: float,
                  smooth_finest: bool) -> list[np.ndarray]:
    """Range pyramid of one scan, finest first: each level halves the resolution with :func:`gated_average`.

    Args:
        ranges_m: (n,) ranges ordered as ``geoms[0]``, 0 = invalid.
        geoms: pyramid geometry from :func:`pyramid_geometry`.
        gate_m: range-similarity gate, m.
        smooth_finest: smooth level 0 too (without downsampling).

    Returns:
        List of (n_l,) range arrays, finest first.
    """
    levels = [gated_average(ranges_m, geoms[0].window, gate_m) if smooth_finest else np.asarray(ranges_m, float)]
    for g in geoms[1:]:
        levels.append(gated_average(levels[-1], g.parent_window, gate_m))
    return levels


# ----------------------------------------------------------------------------------------------------------------
# Derivatives


def range_gradient(r_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray,
                   geom: LevelGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive, distance-weighted angular range gradient (3.76 / 3.105).

    ``R_theta(n) = (d(n+1) R^-(n) + d(n) R^+(n)) / (d(n+1) + d(n))`` with ``R^-``, ``R^+`` the backward and
    forward differences divided by the actual angular gaps and ``d(n)`` the 2D distance between points n-1 and
    n: the neighbour with the smaller jump dominates. With one valid neighbour its one-sided difference is used.

    Args:
        r_m: (n,) ranges, 0 = invalid.
        x_m, y_m: (n,) the points in the scanner frame, m.
        geom: the level's geometry.

    Returns:
        ``(dr_dtheta, ok)``: (n,) gradient in m/rad, and (n,) bool mask of beams where it is defined (valid beam
        with at least one valid neighbour).
    """
    valid = r_m > 0
    p, q = geom.prev, geom.next
    vb = valid[p] & geom.has_prev
    vf = valid[q] & geom.has_next
    back = (r_m - r_m[p]) / geom.gap_prev
    fwd = (r_m[q] - r_m) / geom.gap_next
    db = np.hypot(x_m - x_m[p], y_m - y_m[p])
    df = np.hypot(x_m[q] - x_m, y_m[q] - y_m)
    both = (df * back + db * fwd) / np.maximum(db + df, 1e-12)
    grad = np.where(vb & vf, both, np.where(vb, back, np.where(vf, fwd, 0.0)))
    return grad, valid & (vb | vf)


def neighbour_difference(v: np.ndarray, ok: np.ndarray, geom: LevelGeometry) -> np.ndarray:
    """Central difference along the scan, per beam: ``(v[n+1] - v[n-1]) / 2``, one-sided at gaps, else 0.

    Args:
        v: (n,) values.
        ok: (n,) where ``v`` is defined.
        geom: the level's geometry.

    Returns:
        (n,) difference per beam (units of ``v``).
    """
    p, q = geom.prev, geom.next
    vb = ok[p] & geom.has_prev & ok
    vf = ok[q] & geom.has_next & ok
    central = 0.5 * (v[q] - v[p])
    return np.where(vb & vf, central, np.where(vb, v - v[p], np.where(vf, v[q] - v, 0.0)))


# ----------------------------------------------------------------------------------------------------------------
# Warping


def grid_index(phi_rad: np.ndarray, geom: LevelGeometry) -> np.ndarray:
    """Fractional beam index of directions on a level's (possibly non-uniform) angle grid (3.75).

    Args:
        phi_rad: (k,) directions in the scanner frame in [-pi, pi] (as from ``arctan2``), rad.
        geom: target level geometry.

    Returns:
        (k,) fractional indices in [0, n) (circular) or [0, n-1]; NaN outside a non-circular field of view.
    """
    a0 = geom.angles_rad[0]
    offset = phi_rad - a0
    offset += TWO_PI * (offset < 0.0)
    if geom.uniform_step_rad > 0:
        u = offset / geom.uniform_step_rad
        return u if geom.circular else np.where(u <= geom.n - 1 + 1e-9, np.minimum(u, geom.n - 1), np.nan)
    return np.interp(a0 + offset, geom.index_angles, geom.index_values, left=np.nan, right=np.nan)


def warp_scan(ranges_m: np.ndarray, src: LevelGeometry, T_dst_src: np.ndarray, dst: LevelGeometry,
              keep: str = "closest") -> np.ndarray:
    """Renders a scan from another viewpoint with a z-buffer (3.73–3.75).

    The valid points of the source scan are moved by ``T_dst_src``; every segment between two neighbouring
    valid points is intersected exactly with each target beam whose angle it spans, and each target beam keeps
    the closest (or farthest) of the ranges it receives. Points without a valid neighbour fall into the nearest
    target beam.

    Args:
        ranges_m: (n_src,) source ranges, 0 = invalid.
        src: geometry of the source level.
        T_dst_src: (3, 3) pose of the source scanner frame in the target scanner frame.
        dst: geometry of the target level.
        keep: ``"closest"`` (visible surface) or ``"farthest"`` (scene structure, for keyscans).

    Returns:
        (n_dst,) warped ranges, 0 where nothing projects.
    """
    # 1. Move the points into the target frame and find their fractional beam index (NaN = invalid/outside).
    R, t = T_dst_src[:2, :2], T_dst_src[:2, 2]
    x, y = ranges_m * src.cos, ranges_m * src.sin
    xw = R[0, 0] * x + R[0, 1] * y + t[0]
    yw = R[1, 0] * x + R[1, 1] * y + t[1]
    u = np.where(ranges_m > 0, grid_index(np.arctan2(yw, xw), dst), np.nan)
    n = dst.n
    # 2. Segments between neighbouring valid points and the target beams each one spans.
    ua, ub = u[src.seg_a], u[src.seg_b]
    if dst.circular:
        ub = ub - n * np.round((ub - ua) / n)
    sel = np.flatnonzero(np.abs(ub - ua) < 0.5 * n)  # False for NaN
    a, b, ua, ub = src.seg_a[sel], src.seg_b[sel], ua[sel], ub[sel]
    k0 = np.ceil(np.minimum(ua, ub) - 1e-9).astype(np.int64)
    count = np.maximum(np.floor(np.maximum(ua, ub) + 1e-9).astype(np.int64) - k0 + 1, 0)
    seg = np.repeat(np.arange(len(sel)), count)
    k = np.arange(len(seg)) - (np.cumsum(count) - count - k0)[seg]
    if dst.circular:
        k %= n
    else:
        inside = (k >= 0) & (k < n)
        seg, k = seg[inside], k[inside]
    # 3. Exact range of each spanned target beam on its segment: r = (Pa x D) / (e x D), clipped to the ends.
    xa, ya = xw[a], yw[a]
    dx, dy = xw[b] - xa, yw[b] - ya
    num = xa * dy - ya * dx
    ra, rb = np.hypot(xa, ya), np.hypot(xw[b], yw[b])
    r_lo, r_hi = np.minimum(ra, rb)[seg], np.maximum(ra, rb)[seg]
    den = dst.cos[k] * dy[seg] - dst.sin[k] * dx[seg]
    r_seg = np.clip(np.divide(num[seg], den, out=r_lo.copy(), where=np.abs(den) > 1e-12), r_lo, r_hi)
    # 4. Isolated points go to the nearest beam.
    lone = np.isfinite(u)
    lone[a] = False
    lone[b] = False
    if lone.any():
        lone = np.flatnonzero(lone)
        k = np.concatenate([k, np.rint(u[lone]).astype(np.int64) % n])
        r_seg = np.concatenate([r_seg, np.hypot(xw[lone], yw[lone])])
    # 5. Z-buffer.
    if keep == "closest":
        out = np.full(n, np.inf)
        np.minimum.at(out, k, r_seg)
        out[np.isinf(out)] = 0.0
    elif keep == "farthest":
        out = np.zeros(n)
        np.maximum.at(out, k, r_seg)
    else:
        raise ValueError(f"keep must be 'closest' or 'farthest', got {keep!r}")
    return out


# ----------------------------------------------------------------------------------------------------------------
# Range-flow constraints and pre-weights


@dataclass(frozen=True)
class FlowTerms:
    """The range-flow constraints between a reference scan and a warped new scan on one level.

    Attributes:
        rows: (m,) beam indices of the constraints.
        A: (m, 3) coefficients of ``(vx, vy, w)`` per constraint (unweighted).
        rt_m: (n,) temporal range difference ``R_new - R_ref`` per beam, m (0 where undefined).
        grad_beam_m: (n,) angular gradient per beam of the geometry used, m per beam (``dR/dtheta * spacing``).
        grad_ok: (n,) where the gradient is defined.
        valid: (n,) beams valid in both scans.
        mean_range_m: mean range of the constraints, m (lever arm used by :func:`degeneracy_ratio`).
    """

    rows: np.ndarray
    A: np.ndarray
    rt_m: np.ndarray
    grad_beam_m: np.ndarray
    grad_ok: np.ndarray
    valid: np.ndarray
    mean_range_m: float


def flow_terms(r_ref_m: np.ndarray, r_new_m: np.ndarray, geom: LevelGeometry, symmetric: bool = True) -> FlowTerms:
    """Range-flow constraints on the sensor motion (3.64 / 3.91).

    Per beam, with ``theta`` its angle, ``r`` the range and ``R_theta`` the gradient (3.105) of the geometry used,
    ``(cos + R_theta sin / r) vx + (sin - R_theta cos / r) vy + (x sin - y cos - R_theta) w + R_t = 0``
    with ``R_t = R_new - R_ref``. ``symmetric=True`` evaluates ``r, x, y, R_theta`` on the mean of both scans
    (3.90–3.92); ``False`` evaluates them on the reference scan (3.64 literally).

    Args:
        r_ref_m: (n,) reference ranges on the level grid, 0 = invalid.
        r_new_m: (n,) new ranges warped onto the same grid, 0 = invalid.
        geom: the level's geometry.
        symmetric: geometry at the mean of both scans.

    Returns:
        The constraints; see :class:`FlowTerms`.
    """
    valid = (r_ref_m > 0) & (r_new_m > 0)
    r = np.where(valid, 0.5 * (r_ref_m + r_new_m) if symmetric else r_ref_m, 0.0)
    x, y = r * geom.cos, r * geom.sin
    grad, grad_ok = range_gradient(r, x, y, geom)
    rows = np.flatnonzero(grad_ok)
    c, s, g, rr = geom.cos[rows], geom.sin[rows], grad[rows], r[rows]
    A = np.empty((len(rows), 3))
    A[:, 0] = c + g * s / rr
    A[:, 1] = s - g * c / rr
    A[:, 2] = x[rows] * s - y[rows] * c - g  # x sin - y cos vanishes for points on their own beam
    rt = np.where(valid, r_new_m - r_ref_m, 0.0)
    mean_r = float(rr.mean()) if len(rows) else 0.0
    return FlowTerms(rows, A, rt, grad * geom.spacing_rad, grad_ok, valid, mean_r)


def preweights_rf2o(terms: FlowTerms, geom: LevelGeometry, eps_m2: float, k_d: float) -> np.ndarray:
    """RF2O pre-weights (3.71) of the constraints, with derivatives per beam and ``Δt`` = one scan.

    ``w = 1 / sqrt(eps + R_a² + R_t² + K_d (R_aa² + R_ta²))``: small where the range function is nonlinear or
    discontinuous.

    Args:
        terms: constraints from :func:`flow_terms`.
        geom: the level's geometry.
        eps_m2: regulariser ``eps``, m².
        k_d: weight ``K_d`` of the second-order terms.

    Returns:
        (m,) weights of ``terms.rows``, normalised to a maximum of 1.
    """
    g_aa = neighbour_difference(terms.grad_beam_m, terms.grad_ok, geom)
    rt_a = neighbour_difference(terms.rt_m, terms.valid, geom)
    i = terms.rows
    var = eps_m2 + terms.grad_beam_m[i] ** 2 + terms.rt_m[i] ** 2 + k_d * (g_aa[i] ** 2 + rt_a[i] ** 2)
    return _normalised(1.0 / np.sqrt(var))


def preweights_srf(terms: FlowTerms, geom: LevelGeometry, sigma_m: float, k_d: float, k_2d: float) -> np.ndarray:
    """SRF pre-weights (3.96) of the constraints, with derivatives per beam.

    ``w = 1 / sqrt(sigma_s² + K_D (R_a² + R_t²) + K_2D R_aa²)``. The square root makes ``w²`` (the weight of the
    squared residual) an inverse variance.

    Args:
        terms: constraints from :func:`flow_terms`.
        geom: the level's geometry.
        sigma_m: sensor noise ``sigma_s``, m.
        k_d: ``K_D``.
        k_2d: ``K_2D``.

    Returns:
        (m,) weights of ``terms.rows``, not normalised (the multi-scan solver stacks several sets).
    """
    g_aa = neighbour_difference(terms.grad_beam_m, terms.grad_ok, geom)
    i = terms.rows
    var = sigma_m**2 + k_d * (terms.grad_beam_m[i] ** 2 + terms.rt_m[i] ** 2) + k_2d * g_aa[i] ** 2
    return 1.0 / np.sqrt(var)


def _normalised(w: np.ndarray) -> np.ndarray:
    """``w / max(w)`` (unchanged when empty)."""
    return w / w.max() if len(w) else w


# ----------------------------------------------------------------------------------------------------------------
# Robust solvers


@dataclass(frozen=True)
class Solution:
    """Result of one (robust) least-squares solve of stacked constraints ``A xi = b``.

    Attributes:
        xi: (3,) twist ``(vx, vy, w)`` per scan interval (m, m, rad).
        covariance: (3, 3) covariance of ``xi``.
        normal: (3, 3) weighted normal matrix ``A^T W A``.
        rows: number of constraints.
        lever_m: mean range of the constraints, m.
        covariance_eig: eigenvalues (3,) and eigenvectors (3, 3) of ``covariance``.
        information: (3, 3) geometric information of the constraints (:func:`unit_information`), or None.
    """

    xi: np.ndarray
    covariance: np.ndarray
    normal: np.ndarray
    rows: int
    lever_m: float
    covariance_eig: tuple[np.ndarray, np.ndarray]
    information: np.ndarray | None = None


_UPPER = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
"""Row and column of the 6 distinct entries of a symmetric (3, 3) matrix."""


class _LinearSystem:
    """Stacked constraints ``A xi = b`` ((m, 3), (m,)) with the per-row products that reweighted solves need."""

    def __init__(self, A: np.ndarray, b: np.ndarray) -> None:
        self.A, self.b = A, b
        At = np.ascontiguousarray(A.T)
        self.AA = At[_UPPER[0]] * At[_UPPER[1]]  # (6, m) distinct entries of a_i a_i^T
        self.Ab = At * b  # (3, m)

    def solve(self, w: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weighted least squares with (m,) weights (None = 1): ``(xi, residuals A xi - b, A^T W A)``."""
        h, g = (self.AA.sum(axis=1), self.Ab.sum(axis=1)) if w is None else (self.AA @ w, self.Ab @ w)
        a, b, c, d, e, f = h.tolist()
        H = np.array([[a, b, c], [b, d, e], [c, e, f]])
        xi = _solve_normal(H, g)
        return xi, self.A @ xi - self.b, H


def _solve_normal(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Minimum-norm solution of ``H xi = g`` for a symmetric PSD (3, 3) ``H``.

    Well-conditioned systems are solved in closed form (adjugate); otherwise directions with eigenvalue below
    1e-12 of the largest get no update (they are unobservable).
    """
    (a, b, c), (_, d, e), (_, _, f) = H.tolist()
    c0, c1, c2 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c0 + b * c1 + c * c2
    if det > 1e-10 * a * d * f > 0:
        g0, g1, g2 = g.tolist()
        c4, c5 = b * c - a * e, a * f - c * c
        return np.array([c0 * g0 + c1 * g1 + c2 * g2, c1 * g0 + c5 * g1 + c4 * g2,
                         c2 * g0 + c4 * g1 + (a * d - b * b) * g2]) / det
    mu, V = np.linalg.eigh(H)
    keep = mu > max(mu[-1], 0.0) * 1e-12
    inv = np.where(keep & (mu > 0), 1.0 / np.where(mu > 0, mu, 1.0), 0.0) if mu[-1] > 0 else np.zeros(3)
    return V @ (inv * (V.T @ g))


def weighted_covariance(H: np.ndarray, r: np.ndarray, w: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of a weighted least-squares solution: ``s² (A^T W A)^-1``, ``s² = sum(W r²) / (n_eff - 3)``.

    ``n_eff`` counts the constraints with non-zero weight. Eigenvalues are kept within
    [:data:`MIN_VARIANCE`, :data:`MAX_VARIANCE`]; directions ``H`` does not constrain (eigenvalue below 1e-12 of
    the largest) get :data:`MAX_VARIANCE`, so they stay finite.

    Args:
        H: (3, 3) ``A^T W A``.
        r: (m,) residuals at the solution.
        w: (m,) robust weights, or None for 1.

    Returns:
        Eigenvalues (3,) and eigenvectors (3, 3) of the covariance (columns).
    """
    if w is None:
        s2, n_eff = float(r @ r), len(r)
    else:
        s2, n_eff = float(w @ (r * r)), int(np.count_nonzero(w))
    s2 /= max(n_eff - 3, 1)
    mu, V = np.linalg.eigh(H)
    observed = mu > max(float(mu[-1]), 0.0) * 1e-12
    lam = np.clip(s2 / np.where(observed, mu, 1.0), MIN_VARIANCE, MAX_VARIANCE)
    return np.where(observed, lam, MAX_VARIANCE), V


def _solution(xi: np.ndarray, r: np.ndarray, w: np.ndarray | None, H: np.ndarray, lever_m: float) -> Solution:
    """Packs a solve into a :class:`Solution`."""
    lam, V = weighted_covariance(H, r, w)
    return Solution(xi, (V * lam) @ V.T, H, len(r), lever_m, (lam, V))


def cauchy_weights(r: np.ndarray, k: float) -> np.ndarray:
    """IRLS weights of the Cauchy M-estimator (3.68): ``1 / (1 + (r / k)²)``."""
    return 1.0 / (1.0 + (r / k) ** 2)


def irls_cauchy(A: np.ndarray, b: np.ndarray, iterations: int, k_ratio: float, lever_m: float) -> Solution:
    """Minimises ``sum F(A xi - b)`` with the Cauchy kernel (3.66–3.68) by IRLS.

    The kernel width is ``k = k_ratio * mean|r|`` of the plain least-squares residuals, then kept fixed.

    Args:
        A: (m, 3) pre-weighted constraint coefficients.
        b: (m,) pre-weighted right-hand side (``-w R_t``).
        iterations: reweighted solves after the first least-squares one.
        k_ratio: kernel width relative to the mean absolute least-squares residual.
        lever_m: mean range of the constraints, m (carried into the solution).

    Returns:
        The solution.
    """
    system = _LinearSystem(A, b)
    xi, r, H = system.solve(None)
    k = k_ratio * float(np.mean(np.abs(r)))
    if not k > 1e-15:
        return _solution(xi, r, None, H, lever_m)
    w = None
    for _ in range(iterations):
        w = cauchy_weights(r, k)
        xi, r, H = system.solve(w)
    return _solution(xi, r, w, H, lever_m)


def truncated_parabola_weights(r: np.ndarray, c: float) -> np.ndarray:
    """IRLS weights of the smooth truncated parabola (3.100): ``1 - (r / c)²`` inside ``|r| <= c``, else 0."""
    return np.clip(1.0 - (r / c) ** 2, 0.0, None)


def truncated_parabola_energy(r: np.ndarray, c: float) -> float:
    """Cost (3.95): ``sum r²/2 (1 - r²/(2c²))`` inside ``|r| <= c``, ``c²/4`` outside."""
    q = np.minimum((r / c) ** 2, 1.0)
    return float(0.25 * c * c * np.sum(q * (2.0 - q)))


def _upper_median(v: np.ndarray) -> float:
    """Element of rank ``len(v) // 2`` (the median for odd lengths, the upper median otherwise)."""
    k = len(v) // 2
    return float(np.partition(v, k)[k])


def median_absolute_deviation(r: np.ndarray) -> float:
    """``median(|r - median(r)|)`` of a non-empty array (upper medians)."""
    return _upper_median(np.abs(r - _upper_median(r)))


def irls_truncated_parabola(A: np.ndarray, b: np.ndarray, max_iterations: int, mad_factor: float,
                            min_decrease: float, lever_m: float) -> Solution:
    """Minimises ``sum F(A xi - b)`` with the smooth truncated parabola (3.94, 3.95, 3.100) by IRLS.

    ``c = mad_factor * MAD`` of the plain least-squares residuals, then fixed. Reweighted solves stop after
    ``max_iterations`` or once the cost drops by less than the fraction ``1 - min_decrease``.

    Args:
        A: (m, 3) pre-weighted constraint coefficients.
        b: (m,) pre-weighted right-hand side.
        max_iterations: most reweighted solves.
        mad_factor: ``c / MAD``.
        min_decrease: continue while ``cost_new < min_decrease * cost_old``.
        lever_m: mean range of the constraints, m.

    Returns:
        The solution.
    """
    system = _LinearSystem(A, b)
    xi, r, H = system.solve(None)
    c = mad_factor * median_absolute_deviation(r)
    if not c > 1e-15:
        return _solution(xi, r, None, H, lever_m)
    energy, w = truncated_parabola_energy(r, c), None
    for _ in range(max_iterations):
        w_new = truncated_parabola_weights(r, c)
        if np.count_nonzero(w_new) < MIN_ROWS:
            break
        w = w_new
        xi, r, H = system.solve(w)
        last, energy = energy, truncated_parabola_energy(r, c)
        if not energy < min_decrease * last:
            break
    return _solution(xi, r, w, H, lever_m)


# ----------------------------------------------------------------------------------------------------------------
# Motion filter, degeneracy, SE(2) helpers


def motion_filter(xi_m: np.ndarray, covariance_eig: tuple[np.ndarray, np.ndarray], xi_prior: np.ndarray,
                  k_l: float, k_e: float) -> np.ndarray:
    """Low-pass filter of a level's solution in the eigenspace of its covariance (3.77 / 3.106).

    Solves ``[(1 + k_l) I + k_e E] xi = xi_M + (k_l I + k_e E) xi_prior`` in the eigenbasis of the covariance
    (E = its eigenvalues): well-constrained directions keep the solver's value, poorly constrained ones lean on
    the prior.

    Args:
        xi_m: (3,) twist from the solver, per scan.
        covariance_eig: eigenvalues (3,) and eigenvectors (3, 3, columns) of its covariance.
        xi_prior: (3,) prior twist for the same quantity (the previous motion minus what is already estimated).
        k_l: constant blend ``k_l``.
        k_e: eigenvalue gain ``k_e``.

    Returns:
        (3,) filtered twist.
    """
    lam, B = covariance_eig
    gain = k_l + k_e * np.clip(lam, 0.0, None)
    return B @ ((B.T @ xi_m + gain * (B.T @ xi_prior)) / (1.0 + gain))


def unit_information(A: np.ndarray) -> np.ndarray:
    """Geometric information of range-flow constraints: ``sum u u^T`` with ``u = a / |(a_x, a_y)|``.

    A range-flow row is the surface normal divided by the cosine of the incidence angle; dividing by its
    translational norm leaves the point-to-line row ``(n, p x n)`` of every beam, so grazing beams (whose rows
    are large and noisy) do not dominate. Unweighted on purpose: it measures the scene, not the residuals.

    Args:
        A: (m, 3) unweighted constraint coefficients.

    Returns:
        (3, 3) information matrix in ``(vx, vy, w)``.
    """
    U = A / np.maximum(np.hypot(A[:, 0], A[:, 1]), 1e-12)[:, None]
    return U.T @ U


def _scaled_eigen(normal: np.ndarray, lever_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-decomposition of ``S N S`` with ``S = diag(1, 1, 1 / lever)``; also returns ``diag(S)``."""
    s = np.array([1.0, 1.0, 1.0 / max(lever_m, 1e-3)])
    mu, V = np.linalg.eigh(normal * np.outer(s, s))
    return mu, V, s


def degeneracy_ratio(normal: np.ndarray, lever_m: float) -> float:
    """Smallest over largest eigenvalue of an information matrix, rotation expressed as displacement.

    Args:
        normal: (3, 3) information (e.g. :func:`unit_information`) in ``(vx, vy, w)``.
        lever_m: length turning rotation into displacement (mean range), m.

    Returns:
        Ratio in [0, 1]; near 0 when a motion direction is unobservable (e.g. along a corridor).
    """
    mu, _, _ = _scaled_eigen(normal, lever_m)
    return float(max(mu[0], 0.0) / mu[-1]) if mu[-1] > 0 else 0.0


def weakest_direction(normal: np.ndarray, lever_m: float) -> np.ndarray:
    """(3,) unit twist direction (vx, vy, w) the information matrix constrains least (rotation scaled as in
    :func:`degeneracy_ratio`, then mapped back)."""
    _, V, s = _scaled_eigen(normal, lever_m)
    v = V[:, 0] * s
    return v / np.linalg.norm(v)


def se2_exp(xi: np.ndarray) -> np.ndarray:
    """(3, 3) ``exp(hat(xi))`` of a (3,) twist (scalar fast path of :func:`simnav.geometry.se2.exp`)."""
    vx, vy, w = float(xi[0]), float(xi[1]), float(xi[2])
    s, c = math.sin(w), math.cos(w)
    if abs(w) < 1e-9:
        a, h = 1.0 - w * w / 6.0, 0.5 * w
    else:
        a, h = s / w, (1.0 - c) / w
    return np.array([[c, -s, a * vx - h * vy], [s, c, h * vx + a * vy], [0.0, 0.0, 1.0]])


def se2_log(T: np.ndarray) -> np.ndarray:
    """(3,) twist of a (3, 3) pose (scalar fast path of :func:`simnav.geometry.se2.log`)."""
    w = math.atan2(T[1, 0], T[0, 0])
    half = 0.5 * w
    a = 1.0 - w * w / 12.0 if abs(w) < 1e-9 else half * math.cos(half) / math.sin(half)
    tx, ty = T[0, 2], T[1, 2]
    return np.array([a * tx + half * ty, -half * tx + a * ty, w])


def se2_inverse(T: np.ndarray) -> np.ndarray:
    """(3, 3) inverse of a (3, 3) pose (fast path of :func:`simnav.geometry.se2.inverse`)."""
    Ti = np.zeros((3, 3))
    Ti[:2, :2] = T[:2, :2].T
    Ti[:2, 2] = -T[:2, :2].T @ T[:2, 2]
    Ti[2, 2] = 1.0
    return Ti


def se2_adjoint(T: np.ndarray) -> np.ndarray:
    """(3, 3) adjoint of a pose acting on twists ``(vx, vy, w)``: ``T exp(xi) T^-1 = exp(Ad xi)``."""
    Ad = np.eye(3)
    Ad[:2, :2] = T[:2, :2]
    Ad[0, 2], Ad[1, 2] = T[1, 2], -T[0, 2]
    return Ad


# ----------------------------------------------------------------------------------------------------------------
# Coarse-to-fine estimation


@dataclass(frozen=True)
class ScanFrame:
    """A scan prepared for range flow.

    Attributes:
        stamp_s: time stamp, s.
        pyramid: list of (n_l,) ranges per level, finest first.
        geoms: geometry per level, finest first.
        valid_beams: valid beams of the raw scan.
        beams: beams of the raw scan.
        T_base_laser: (3, 3) pose of the upright virtual scanner in the base frame.
    """

    stamp_s: float
    pyramid: list[np.ndarray]
    geoms: tuple[LevelGeometry, ...]
    valid_beams: int
    beams: int
    T_base_laser: np.ndarray


LevelSolver = Callable[[Sequence[np.ndarray], np.ndarray, LevelGeometry, int], "Solution | None"]
"""``solve(references, warped_new, geometry, level_from_coarsest) -> Solution | None`` for one level."""


@dataclass(frozen=True)
class CoarseToFine:
    """Parameters of the coarse-to-fine loop (Algorithm 2).

    Attributes:
        k_l, k_e: motion-filter constants at the coarsest level; both scale by ``exp(-(l - 1))`` (3.78 / 3.107).
        max_rewarps: estimate-and-warp iterations per level (1 = RF2O's single solve per level).
        rewarp_tolerance: stop iterating a level once ``|xi_M|`` is below this (m and rad mixed, per scan).
    """

    k_l: float
    k_e: float
    max_rewarps: int = 1
    rewarp_tolerance: float = 0.0


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`coarse_to_fine`.

    Attributes:
        T_ref_new: (3, 3) estimated motion of the scanner from the reference scan to the new one.
        solution: solver result of the last solve at the finest level solved, or None if no level was solved.
        level_solutions: last solver result per level, finest first (None where the level was not solved).
    """

    T_ref_new: np.ndarray
    solution: Solution | None
    level_solutions: tuple[Solution | None, ...] = ()


def coarse_to_fine(references: Sequence[list[np.ndarray]], ref_geoms: Sequence[LevelGeometry],
                   new: ScanFrame, solve: LevelSolver, xi_prior: np.ndarray, params: CoarseToFine) -> Alignment:
    """Estimates the motion between a reference and a new scan from the coarsest to the finest level.

    At each level (and re-warp iteration) the new scan is warped onto the reference grid with the motion
    estimated so far (3.73–3.75), the level is solved, the solution is filtered against the prior (3.77 / 3.106)
    and composed on the left of the running estimate (the residual motion is expressed in the reference frame).

    Args:
        references: one or more reference pyramids on the grid ``ref_geoms`` (previous scan, warped keyscan).
        ref_geoms: geometry of the reference grid, finest first.
        new: the new scan.
        solve: level solver.
        xi_prior: (3,) predicted motion twist from the reference to the new scan (constant velocity).
        params: loop parameters.

    Returns:
        The alignment.
    """
    levels = min(len(ref_geoms), len(new.geoms))
    T, moved = np.eye(3), False
    solution, per_level = None, [None] * levels
    for step, lv in enumerate(range(levels - 1, -1, -1)):
        k_l, k_e = params.k_l * math.exp(-step), params.k_e * math.exp(-step)
        for _ in range(max(params.max_rewarps, 1)):
            # 1. Warp the new scan onto the reference grid with the motion so far.
            same = not moved and new.geoms[lv] is ref_geoms[lv]
            warped = new.pyramid[lv] if same else warp_scan(new.pyramid[lv], new.geoms[lv], T, ref_geoms[lv])
            # 2. Solve the level.
            sol = solve([ref[lv] for ref in references], warped, ref_geoms[lv], step)
            if sol is None:
                break
            solution = per_level[lv] = sol
            # 3. Filter against the prior residual motion and compose.
            xi_prior_res = se2_log(se2_exp(xi_prior) @ se2_inverse(T))
            xi = motion_filter(sol.xi, sol.covariance_eig, xi_prior_res, k_l, k_e)
            T, moved = se2_exp(xi) @ T, True
            if float(np.linalg.norm(sol.xi)) < params.rewarp_tolerance:
                break
    return Alignment(T, solution, tuple(per_level))


# ----------------------------------------------------------------------------------------------------------------
# Odometry bookkeeping shared by RF2O and SRF


class RangeFlowOdometry:
    """Scan-to-scan bookkeeping shared by the range-flow odometries.

    Subclasses set ``config``, implement :meth:`_levels` and :meth:`_align`, and may override
    :meth:`_after_scan`. Each call to :meth:`process` prepares the scan, aligns it (or predicts with constant
    velocity when the scan or its reference has too few valid beams, or the alignment fails), accumulates the
    base pose and reports twist, covariance and degeneracy. Nothing raises on bad data and no output is NaN.
    """

    config: RangeFlowConfig

    def __init__(self) -> None:
        self._layout_key: np.ndarray | None = None
        self._layout: BeamLayout | None = None
        self._geoms: tuple[LevelGeometry, ...] = ()
        self._info_cache: tuple[tuple[LevelGeometry, ...] | None, LevelGeometry | None] = (None, None)
        self._info_geom: LevelGeometry | None = None
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next scan starts a new odom frame."""
        self._ref: ScanFrame | None = None
        self._last_stamp_s: float | None = None
        self._T_odom_base = np.eye(3)
        self._xi_last = np.zeros(3)  # last laser increment, per scan
        self._twist_laser: np.ndarray | None = None  # last laser twist, per second

    # -- hooks ----------------------------------------------------------------------------------------------

    def _levels(self, beams: int) -> int:
        """Number of pyramid levels for a scan with ``beams`` beams."""
        raise NotImplementedError

    def _align(self, ref: ScanFrame, new: ScanFrame, xi_prior: np.ndarray) -> Alignment:
        """Motion from ``ref`` to ``new`` (both valid)."""
        raise NotImplementedError

    def _after_scan(self, new: ScanFrame | None, T_prev_new: np.ndarray, measured: bool) -> dict:
        """Called after each scan with the (valid) frame or None and the laser increment; returns extras."""
        return {}

    # -- pipeline -------------------------------------------------------------------------------------------

    def process(self, scan: LaserScan) -> OdometryEstimate:
        """Estimate the motion since the previous scan.

        Args:
            scan: the new scan (any mount; NaN/inf/out-of-range beams are treated as invalid).

        Returns:
            The estimate; see :class:`simnav.odometry.base.OdometryEstimate`.
        """
        t0 = time.perf_counter()
        # 1. Upright scan, layout and pyramid.
        ps = planar_scan(scan)
        frame = self._frame(ps)
        dt = ps.stamp_s - self._last_stamp_s if self._last_stamp_s is not None else 0.0
        xi_prior = self._prior(dt)
        # 2. Align with the reference, or predict.
        ref, first = self._ref, self._last_stamp_s is None
        alignment, cov_laser, degenerate, rows = None, None, True, 0
        if frame is not None and ref is not None:
            self._info_geom = self._information_level(ref.geoms)
            alignment = self._align(ref, frame, xi_prior)
        if alignment is not None and alignment.solution is not None and np.all(np.isfinite(alignment.T_ref_new)):
            T_inc = alignment.T_ref_new
            cov_laser, degenerate = self._covariance(alignment)
            rows = alignment.solution.rows
        else:
            T_inc = np.eye(3) if first else se2_exp(xi_prior)
        measured = cov_laser is not None
        # 3. Base increment, pose, twist and covariance.
        T_base_laser = ps.T_base_laser
        T_inc_base = laser_to_base_motion(T_inc, T_base_laser)
        self._T_odom_base = self._T_odom_base @ T_inc_base
        if measured:
            Ad = se2_adjoint(T_base_laser)
            cov = Ad @ cov_laser @ Ad.T
        else:
            cov = np.zeros((3, 3)) if first else self.config.lost_variance * np.eye(3)
        twist = se2_log(T_inc_base) / dt if dt > 0 else np.zeros(3)
        # 4. Remember the motion, the reference and the stamp.
        xi_inc = se2_log(T_inc)
        if not first:
            self._xi_last = xi_inc
            self._twist_laser = xi_inc / dt if dt > 0 else self._twist_laser
        extra = self._after_scan(frame, T_inc, measured)
        self._ref = frame
        self._last_stamp_s = ps.stamp_s
        extra.update(measured=measured, levels=len(frame.geoms) if frame is not None else 0)
        return OdometryEstimate(
            stamp_s=ps.stamp_s, T_odom_base=self._T_odom_base.copy(), twist_base=_finite(twist),
            covariance=_finite(0.5 * (cov + cov.T)), degenerate=bool(degenerate and not first),
            valid_points=int(rows), runtime_s=time.perf_counter() - t0, extra=extra)

    def _information_level(self, geoms: tuple[LevelGeometry, ...]) -> LevelGeometry:
        """The level whose beam spacing is closest to ``degeneracy_spacing_deg`` (level solvers attach the
        geometric information there)."""
        if self._info_cache[0] is not geoms:
            target = math.radians(self.config.degeneracy_spacing_deg)
            best = min(geoms, key=lambda g: abs(float(np.median(g.spacing_rad)) - target))
            self._info_cache = (geoms, best)
        return self._info_cache[1]

    def _covariance(self, alignment: Alignment) -> tuple[np.ndarray, bool]:
        """Laser-frame covariance of an alignment and its degeneracy flag.

        The covariance is the finest solve's; when the geometric information (attached at the level chosen by
        :meth:`_information_level`) is degenerate, ``lost_variance`` is added along its weakest direction.
        """
        cov = alignment.solution.covariance
        sol = next((s for s in alignment.level_solutions if s is not None and s.information is not None), None)
        if sol is None or degeneracy_ratio(sol.information, sol.lever_m) >= self.config.degeneracy_threshold:
            return cov, False
        v = weakest_direction(sol.information, sol.lever_m)
        return cov + self.config.lost_variance * np.outer(v, v), True

    def _frame(self, ps: PlanarScan) -> ScanFrame | None:
        """Layout, geometry and pyramid of a scan; None when it has too few valid beams."""
        layout, geoms = self._geometry(ps.angles_rad)
        ranges = ps.ranges_m[layout.take]
        valid = int(np.count_nonzero(ranges > 0))
        need = max(self.config.min_valid_points, math.ceil(self.config.min_valid_fraction * len(ps.ranges_m)))
        if valid < need or not geoms:
            return None
        pyramid = build_pyramid(ranges, geoms, self.config.pyramid_gate_m, self.config.smooth_finest)
        return ScanFrame(ps.stamp_s, pyramid, geoms, valid, len(ranges), ps.T_base_laser)

    def _geometry(self, angles_rad: np.ndarray) -> tuple[BeamLayout, tuple[LevelGeometry, ...]]:
        """Cached beam layout and pyramid geometry for an angle vector."""
        if self._layout_key is None or not np.array_equal(angles_rad, self._layout_key):
            layout = beam_layout(angles_rad)
            geoms = ()
            if len(layout.angles_rad) >= max(self.config.min_level_beams, MIN_ROWS):
                geoms = pyramid_geometry(layout, self._levels(len(layout.angles_rad)), self.config.min_level_beams)
            self._layout_key, self._layout, self._geoms = np.array(angles_rad, copy=True), layout, geoms
        return self._layout, self._geoms

    def _prior(self, dt: float) -> np.ndarray:
        """Constant-velocity prediction of the laser increment over ``dt`` seconds (per-scan twist)."""
        if self._twist_laser is not None and dt > 0:
            return self._twist_laser * dt
        return self._xi_last.copy()


def _finite(a: np.ndarray) -> np.ndarray:
    """``a`` with any non-finite entry replaced by 0 (a last guard; the pipeline should not produce any)."""
    return np.where(np.isfinite(a), a, 0.0)
