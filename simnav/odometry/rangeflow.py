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

The per-beam work (pyramid, gradients, warping, constraints and pre-weights, IRLS with its normal equations, the
motion filter) runs in Numba kernels (``@njit(cache=True, error_model="numpy")``: compiled on first use, then
loaded from ``__pycache__``). Written with numpy, these stages take about a thousand small array calls per scan,
2–4 ms for 1080 beams against a budget of 1 ms (``scripts/bench_scan_odometry_runtime.py``). Public functions keep
their numpy signatures and wrap the kernels (``_*_kernel``, ``_*_at`` for one beam). Helpers called per beam take
scalars: an array argument costs two reference-count updates per call, which tripled the pre-weighting time.
The loop over levels and warps runs in one kernel per scan too (:mod:`simnav.odometry.rangeflow_fused`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from functools import cached_property
from typing import TYPE_CHECKING, NamedTuple, TypeVar

import numpy as np
from numba import njit

from simnav.errors import ConfigError

if TYPE_CHECKING:
    from simnav.odometry.rangeflow_fused import PackedGeometry

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


def _f64(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous float64 array (no copy when it already is one), as the compiled kernels take."""
    return np.ascontiguousarray(a, dtype=np.float64)


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
        max_speed_m_s: an alignment implying a faster motion of the scanner is not believed (a scan blocked by
            something at the scanner, a door swinging across it): the constant-velocity prediction is reported
            instead, as for a scan with too few beams, m/s.
        max_yaw_rate_rad_s: the same for the rotation, rad/s.
    """

    pyramid_gate_m: float = 0.3
    smooth_finest: bool = True
    min_level_beams: int = 16
    min_valid_points: int = 20
    min_valid_fraction: float = 0.05
    lost_variance: float = 1.0
    degeneracy_threshold: float = 0.01
    degeneracy_spacing_deg: float = 2.0
    max_speed_m_s: float = 5.0
    max_yaw_rate_rad_s: float = 2 * math.pi

    def __post_init__(self) -> None:
        require(self.max_speed_m_s > 0 and self.max_yaw_rate_rad_s > 0, "max_speed_m_s, max_yaw_rate_rad_s must be > 0")
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
        ConfigError: an override names no field (the message lists the allowed ones), has a value of the wrong
            type (a number field given a string, say) or an invalid value.
    """
    defaults = {f.name: f.default for f in fields(cls)}
    unknown = sorted(set(overrides) - set(defaults))
    if unknown:
        raise ConfigError(f"unknown {owner} option(s): {', '.join(unknown)}; allowed: {', '.join(sorted(defaults))}")
    return cls(**{name: _typed(value, defaults[name], name, owner) for name, value in overrides.items()})


def _typed(value, default, name: str, owner: str):
    """``value`` for a field whose default is ``default``: a bool for a bool, an integer for an int, a number (as
    float) for a float, where a string that reads as one counts too (YAML reads ``1e-3`` and ``inf`` as strings);
    other fields take it as given. Raises :class:`ConfigError` naming the field otherwise."""
    if isinstance(default, bool):
        ok = isinstance(value, (bool, np.bool_))
    elif isinstance(default, int):
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    elif isinstance(default, float):
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                pass
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
        value = float(value) if ok else value
    else:
        return value
    if not ok:
        raise ConfigError(f"{owner} option {name}: expected {type(default).__name__}, got {value!r}")
    return value


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
    out = np.empty(len(window))
    _gated_average_kernel(_f64(ranges_m), np.ascontiguousarray(window, dtype=np.int64), float(gate_m), out)
    return out


@njit(cache=True, error_model="numpy")
def _gated_average_kernel(r: np.ndarray, window: np.ndarray, gate_m: float, out: np.ndarray) -> None:
    """Compiled :func:`gated_average`: writes the (m,) smoothed ranges into ``out``."""
    n = len(r)
    for i in range(window.shape[0]):
        centre = r[window[i, 2]]
        total = weighted = 0.0
        if centre > 0:
            for j in range(5):
                k = window[i, j]
                v = r[k] if k < n else 0.0
                w = GAUSS5[j] * (gate_m - abs(v - centre))
                if v > 0 and w > 0:
                    total += w
                    weighted += w * v
        out[i] = weighted / total if total > 0 else 0.0


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
    levels = [gated_average(ranges_m, geoms[0].window, gate_m) if smooth_finest else _f64(ranges_m)]
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
    n = len(r_m)
    grad, ok = np.empty(n), np.empty(n, dtype=np.bool_)
    _range_gradient_kernel(_f64(r_m), _f64(x_m), _f64(y_m), geom.prev, geom.next, geom.has_prev, geom.has_next,
                           geom.gap_next, grad, ok)
    return grad, ok


@njit(cache=True, error_model="numpy")
def _range_gradient_kernel(r: np.ndarray, x: np.ndarray, y: np.ndarray, prev: np.ndarray, nxt: np.ndarray,
                           has_prev: np.ndarray, has_next: np.ndarray, gap_next: np.ndarray, grad: np.ndarray,
                           ok: np.ndarray) -> None:
    """Compiled :func:`range_gradient`: writes ``grad`` (m/rad) and ``ok`` per beam.

    A beam's backward difference and distance are its previous beam's forward ones (``next[prev[n]] = n``).
    """
    n = len(r)
    fwd, dist = np.empty(n), np.empty(n)
    for i in range(n):
        q = nxt[i]
        fwd[i] = (r[q] - r[i]) / gap_next[i]
        dist[i] = math.sqrt((x[q] - x[i]) ** 2 + (y[q] - y[i]) ** 2)
    for i in range(n):
        p, q = prev[i], nxt[i]
        vb, vf = has_prev[i] and r[p] > 0, has_next[i] and r[q] > 0
        if vb and vf:
            grad[i] = (dist[i] * fwd[p] + dist[p] * fwd[i]) / max(dist[p] + dist[i], 1e-12)
        else:
            grad[i] = fwd[p] if vb else (fwd[i] if vf else 0.0)
        ok[i] = r[i] > 0 and (vb or vf)


def neighbour_difference(v: np.ndarray, ok: np.ndarray, geom: LevelGeometry) -> np.ndarray:
    """Central difference along the scan, per beam: ``(v[n+1] - v[n-1]) / 2``, one-sided at gaps, else 0.

    Args:
        v: (n,) values.
        ok: (n,) where ``v`` is defined.
        geom: the level's geometry.

    Returns:
        (n,) difference per beam (units of ``v``).
    """
    v, ok = _f64(v), np.ascontiguousarray(ok, dtype=np.bool_)
    out = np.empty(len(v))
    _neighbour_difference_kernel(v, ok, geom.prev, geom.next, geom.has_prev, geom.has_next, out)
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _neighbour_difference_at(v_prev: float, v: float, v_next: float, back: bool, forward: bool) -> float:
    """:func:`neighbour_difference` of one beam from its value, its neighbours' values and whether the backward
    and forward neighbours count (scalars only: array arguments would cost reference counting per beam)."""
    if back and forward:
        return 0.5 * (v_next - v_prev)
    if back:
        return v - v_prev
    return v_next - v if forward else 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _neighbours_ok(ok: bool, ok_prev: bool, ok_next: bool, has_prev: bool, has_next: bool) -> tuple[bool, bool]:
    """Whether a beam's backward and forward neighbours take part in :func:`neighbour_difference`."""
    return ok and has_prev and ok_prev, ok and has_next and ok_next


@njit(cache=True, error_model="numpy")
def _neighbour_difference_kernel(v: np.ndarray, ok: np.ndarray, prev: np.ndarray, nxt: np.ndarray,
                                 has_prev: np.ndarray, has_next: np.ndarray, out: np.ndarray) -> None:
    """Compiled :func:`neighbour_difference`: writes the (n,) differences into ``out``."""
    for i in range(len(v)):
        p, q = prev[i], nxt[i]
        back, forward = _neighbours_ok(ok[i], ok[p], ok[q], has_prev[i], has_next[i])
        out[i] = _neighbour_difference_at(v[p], v[i], v[q], back, forward)


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
    phi = _f64(phi_rad)
    out = np.empty(len(phi))
    _grid_index_kernel(phi, geom.angles_rad[0], geom.uniform_step_rad, geom.circular, geom.index_angles,
                       geom.index_values, out)
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _grid_index_at(phi: float, a0: float, step: float, circular: bool, index_angles: np.ndarray,
                   index_values: np.ndarray) -> float:
    """:func:`grid_index` of one direction; ``step`` is the uniform spacing or 0."""
    offset = _angle_offset(phi, a0)
    if step > 0:
        return _uniform_index(offset, step, circular, index_values[-1])
    x = a0 + offset
    if not index_angles[0] <= x <= index_angles[-1]:
        return np.nan
    # Linear interpolation between the knots around x (as np.interp).
    lo, hi = 0, len(index_angles) - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if index_angles[mid] <= x:
            lo = mid
        else:
            hi = mid
    if x == index_angles[hi]:
        return index_values[hi]
    slope = (index_values[hi] - index_values[lo]) / (index_angles[hi] - index_angles[lo])
    return slope * (x - index_angles[lo]) + index_values[lo]


@njit(cache=True, error_model="numpy", inline="always")
def _angle_offset(phi: float, a0: float) -> float:
    """Angle from the first beam ``a0`` to a direction ``phi`` in [-pi, pi], counter-clockwise, rad."""
    offset = phi - a0
    return offset + TWO_PI if offset < 0.0 else offset


@njit(cache=True, error_model="numpy", inline="always")
def _uniform_index(offset: float, step: float, circular: bool, last: float) -> float:
    """Fractional index of a direction ``offset`` rad past the first beam of a uniform grid (``step`` rad apart,
    last index ``last``); NaN beyond the last beam of a non-circular grid."""
    u = offset / step
    if circular:
        return u
    return min(u, last) if u <= last + 1e-9 else np.nan


@njit(cache=True, error_model="numpy")
def _grid_index_kernel(phi: np.ndarray, a0: float, step: float, circular: bool, index_angles: np.ndarray,
                       index_values: np.ndarray, out: np.ndarray) -> None:
    """Compiled :func:`grid_index`: writes the (k,) fractional indices into ``out``."""
    for i in range(len(phi)):
        out[i] = _grid_index_at(phi[i], a0, step, circular, index_angles, index_values)


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
    if keep not in ("closest", "farthest"):
        raise ValueError(f"keep must be 'closest' or 'farthest', got {keep!r}")
    return _warp_kernel(_f64(ranges_m), src.cos, src.sin, src.seg_a, src.seg_b, _f64(T_dst_src), dst.cos, dst.sin,
                        dst.angles_rad[0], dst.uniform_step_rad, dst.circular, dst.index_angles, dst.index_values,
                        keep == "farthest")


@njit(cache=True, error_model="numpy")
def _warp_kernel(ranges: np.ndarray, src_cos: np.ndarray, src_sin: np.ndarray, seg_a: np.ndarray,
                 seg_b: np.ndarray, T: np.ndarray, dst_cos: np.ndarray, dst_sin: np.ndarray, a0: float, step: float,
                 circular: bool, index_angles: np.ndarray, index_values: np.ndarray, farthest: bool) -> np.ndarray:
    """Compiled :func:`warp_scan`; the target grid is given by its cos/sin and :func:`grid_index` knots."""
    # 1. Move the points into the target frame and find their fractional beam index (NaN = invalid/outside).
    xw, yw, rho, u = _moved_points(ranges, src_cos, src_sin, T, a0, step, circular, index_angles, index_values)
    # 2. Project the segments and isolated points with a z-buffer.
    return _zbuffer(xw, yw, rho, u, seg_a, seg_b, dst_cos, dst_sin, circular, farthest)


# Minimax rational approximation of atan on [0, 0.66] (coefficients of the Cephes library's atan).
_ATAN_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
           -1.228866684490136173410e2, -6.485021904942025371773e1)
_ATAN_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
           4.853903996359136964868e2, 1.945506571482613964425e2)


@njit(cache=True, error_model="numpy", inline="always")
def atan2_vectorisable(y: float, x: float) -> float:
    """``math.atan2(y, x)`` within 2 ulp for finite inputs, without branches a loop could not vectorise.

    The libm call is not vectorised and took most of the time of moving a scan's points (about 20 ns per beam);
    this form runs several beams per instruction. The ratio ``min / max`` of ``|x|, |y|`` lies in [0, 1]; above
    0.66 it is mapped to ``(t - 1) / (t + 1)`` (adding pi/4), then octant and quadrant are restored by selects.
    Signed zeros of ``y`` are kept (``atan2(-0.0, -1) = -pi``); ``atan2(0, 0) = 0``.
    """
    p0, p1, p2, p3, p4 = _ATAN_P
    q0, q1, q2, q3, q4 = _ATAN_Q
    ax, ay = abs(x), abs(y)
    hi, lo = max(ax, ay), min(ax, ay)
    t = lo / hi if hi != 0.0 else 0.0
    big = t > 0.66
    t = (t - 1.0) / (t + 1.0) if big else t
    z = t * t
    num = (((p0 * z + p1) * z + p2) * z + p3) * z + p4
    den = ((((z + q0) * z + q1) * z + q2) * z + q3) * z + q4
    a = t + t * z * num / den
    a = a + 0.25 * math.pi if big else a
    a = 0.5 * math.pi - a if ay > ax else a
    a = math.pi - a if x < 0.0 else a
    return math.copysign(a, y)


@njit(cache=True, error_model="numpy")
def _moved_points(ranges: np.ndarray, src_cos: np.ndarray, src_sin: np.ndarray, T: np.ndarray, a0: float,
                  step: float, circular: bool, index_angles: np.ndarray,
                  index_values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(m,) x, y and range (m) of the source points in the target frame ``T @ p``, and their fractional index on
    the target grid (:func:`grid_index`; NaN for invalid points)."""
    m = len(ranges)
    xw, yw, rho, u = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    for i in range(m):  # separate loops: the arithmetic vectorises
        x, y = ranges[i] * src_cos[i], ranges[i] * src_sin[i]
        xw[i] = T[0, 0] * x + T[0, 1] * y + T[0, 2]
        yw[i] = T[1, 0] * x + T[1, 1] * y + T[1, 2]
        rho[i] = math.sqrt(xw[i] * xw[i] + yw[i] * yw[i])
    for i in range(m):
        u[i] = atan2_vectorisable(yw[i], xw[i])
    last = index_values[-1]
    for i in range(m):  # the uniform grid without array arguments: no reference counting per beam
        if not ranges[i] > 0:
            u[i] = np.nan
        elif step > 0:
            u[i] = _uniform_index(_angle_offset(u[i], a0), step, circular, last)
        else:
            u[i] = _grid_index_at(u[i], a0, step, circular, index_angles, index_values)
    return xw, yw, rho, u


@njit(cache=True, error_model="numpy")
def _zbuffer(xw: np.ndarray, yw: np.ndarray, rho: np.ndarray, u: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray,
             dst_cos: np.ndarray, dst_sin: np.ndarray, circular: bool, farthest: bool) -> np.ndarray:
    """(n,) target ranges from moved points (:func:`_moved_points`): each segment between neighbouring valid
    points fills the target beams it spans, points without a valid neighbour the nearest beam; each beam keeps
    the closest (or farthest) range, 0 where nothing projects.

    A segment from point a to point b gives every target beam k between the fractional indices ``u[a]`` and
    ``u[b]`` the exact range ``r = (Pa x D) / (e x D)`` (D the beam direction, e = b - a), clipped to the end
    ranges. The loops are written out: helpers taking arrays would cost reference counting per segment.
    """
    n, m = len(dst_cos), len(u)
    out = np.zeros(n) if farthest else np.full(n, np.inf)
    paired = np.zeros(m, dtype=np.bool_)
    for s in range(len(seg_a)):
        a, b = seg_a[s], seg_b[s]
        ua, ub = u[a], u[b]
        if circular:
            ub -= n * np.rint((ub - ua) / n)
        if not abs(ub - ua) < 0.5 * n:  # False for NaN
            continue
        paired[a] = True
        paired[b] = True
        k0, k1 = math.ceil(min(ua, ub) - 1e-9), math.floor(max(ua, ub) + 1e-9)
        dx, dy = xw[b] - xw[a], yw[b] - yw[a]
        num = xw[a] * dy - yw[a] * dx
        r_lo, r_hi = min(rho[a], rho[b]), max(rho[a], rho[b])
        for kk in range(k0, k1 + 1):
            k = kk % n if circular else kk
            if 0 <= k < n:
                den = dst_cos[k] * dy - dst_sin[k] * dx
                r = min(max(num / den if abs(den) > 1e-12 else r_lo, r_lo), r_hi)
                if _wins(r, out[k], farthest):
                    out[k] = r
    for i in range(m):
        if not paired[i] and np.isfinite(u[i]):
            k = int(np.rint(u[i])) % n
            if _wins(rho[i], out[k], farthest):
                out[k] = rho[i]
    if not farthest:
        for k in range(n):
            if out[k] == np.inf:
                out[k] = 0.0
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _wins(r: float, current: float, farthest: bool) -> bool:
    """Z-buffer test: whether range ``r`` replaces a beam's ``current`` one (closer, or farther for keyscans)."""
    return r > current if farthest else r < current


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
    n = len(r_ref_m)
    grad, ok = np.empty(n), np.empty(n, dtype=np.bool_)
    rows, A, rt, valid, mean_r = _flow_terms_kernel(_f64(r_ref_m), _f64(r_new_m), geom.cos, geom.sin, geom.prev,
                                                    geom.next, geom.has_prev, geom.has_next, geom.gap_next,
                                                    bool(symmetric), grad, ok)
    return FlowTerms(rows, A, rt, grad * geom.spacing_rad, ok, valid, mean_r)


@njit(cache=True, error_model="numpy")
def _flow_terms_kernel(r_ref: np.ndarray, r_new: np.ndarray, cos: np.ndarray, sin: np.ndarray, prev: np.ndarray,
                       nxt: np.ndarray, has_prev: np.ndarray, has_next: np.ndarray, gap_next: np.ndarray,
                       symmetric: bool, grad: np.ndarray,
                       ok: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Compiled :func:`flow_terms`: writes the gradient (m/rad) and its mask into ``grad``, ``ok`` and returns
    ``(rows, A, rt_m, valid, mean_range_m)``."""
    n = len(r_ref)
    # 1. Geometry used per beam (mean of both scans, or the reference) and temporal difference.
    valid, r, x, y, rt = np.empty(n, dtype=np.bool_), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        valid[i] = r_ref[i] > 0 and r_new[i] > 0
        r[i] = (0.5 * (r_ref[i] + r_new[i]) if symmetric else r_ref[i]) if valid[i] else 0.0
        x[i], y[i] = r[i] * cos[i], r[i] * sin[i]
        rt[i] = r_new[i] - r_ref[i] if valid[i] else 0.0
    # 2. Angular gradient.
    _range_gradient_kernel(r, x, y, prev, nxt, has_prev, has_next, gap_next, grad, ok)
    # 3. One constraint per beam with a gradient.
    rows = np.flatnonzero(ok)
    A = np.empty((len(rows), 3))
    total = 0.0
    for j in range(len(rows)):
        i = rows[j]
        c, s, g = cos[i], sin[i], grad[i]
        A[j, 0] = c + g * s / r[i]
        A[j, 1] = s - g * c / r[i]
        A[j, 2] = x[i] * s - y[i] * c - g  # x sin - y cos vanishes for points on their own beam
        total += r[i]
    return rows, A, rt, valid, total / len(rows) if len(rows) else 0.0


@dataclass(frozen=True)
class Preweights:
    """Pre-weights ``w = 1 / sqrt(floor + k_first (R_a² + R_t²) + k_second R_aa² + k_rt_a R_ta²)`` of the
    constraints, with the derivatives per beam (``R_aa``, ``R_ta``: :func:`neighbour_difference` of the gradient
    ``R_a`` and of ``R_t``).

    Attributes:
        floor: constant term, m².
        k_first: weight of the first-order terms.
        k_second: weight of ``R_aa²``.
        k_rt_a: weight of ``R_ta²``.
        normalise: scale the weights to a maximum of 1.
    """

    floor: float
    k_first: float
    k_second: float
    k_rt_a: float = 0.0
    normalise: bool = False

    @classmethod
    def rf2o(cls, eps_m2: float, k_d: float) -> Preweights:
        """RF2O's (3.71): ``1 / sqrt(eps + R_a² + R_t² + K_d (R_aa² + R_ta²))``, normalised."""
        return cls(eps_m2, 1.0, k_d, k_d, True)

    @classmethod
    def srf(cls, sigma_m: float, k_d: float, k_2d: float) -> Preweights:
        """SRF's (3.96): ``1 / sqrt(sigma_s² + K_D (R_a² + R_t²) + K_2D R_aa²)``, not normalised."""
        return cls(sigma_m**2, k_d, k_2d)

    @cached_property
    def args(self) -> tuple[float, float, float, float, bool]:
        """The fields as the compiled kernels take them."""
        return float(self.floor), float(self.k_first), float(self.k_second), float(self.k_rt_a), bool(self.normalise)


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
    return _preweights(terms, geom, Preweights.rf2o(eps_m2, k_d))


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
    return _preweights(terms, geom, Preweights.srf(sigma_m, k_d, k_2d))


def _preweights(terms: FlowTerms, geom: LevelGeometry, model: Preweights) -> np.ndarray:
    """(m,) pre-weights of ``terms.rows`` under ``model``."""
    return _preweights_kernel(terms.rows, terms.grad_beam_m, terms.grad_ok, terms.rt_m, terms.valid, geom.prev,
                              geom.next, geom.has_prev, geom.has_next, *model.args)


@njit(cache=True, error_model="numpy")
def _preweights_kernel(rows: np.ndarray, grad_beam: np.ndarray, grad_ok: np.ndarray, rt: np.ndarray,
                       valid: np.ndarray, prev: np.ndarray, nxt: np.ndarray, has_prev: np.ndarray,
                       has_next: np.ndarray, floor: float, k_first: float, k_second: float, k_rt_a: float,
                       normalise: bool) -> np.ndarray:
    """Compiled :func:`_preweights`: (m,) weights of ``rows`` (:class:`Preweights` fields as arguments)."""
    w = np.empty(len(rows))
    for j in range(len(rows)):
        i = rows[j]
        p, q = prev[i], nxt[i]
        back, forward = _neighbours_ok(grad_ok[i], grad_ok[p], grad_ok[q], has_prev[i], has_next[i])
        g_aa = _neighbour_difference_at(grad_beam[p], grad_beam[i], grad_beam[q], back, forward)
        var = floor + k_first * (grad_beam[i] ** 2 + rt[i] ** 2) + k_second * g_aa**2
        if k_rt_a != 0.0:
            back, forward = _neighbours_ok(valid[i], valid[p], valid[q], has_prev[i], has_next[i])
            var += k_rt_a * _neighbour_difference_at(rt[p], rt[i], rt[q], back, forward) ** 2
        w[j] = 1.0 / math.sqrt(var)
    if normalise and len(w):
        w /= w.max()
    return w


class WeightedConstraints(NamedTuple):
    """The pre-weighted range-flow constraints of one level, ``A xi = b``, ready for a robust solver.

    Attributes:
        A: (m, 3) pre-weighted coefficients of ``(vx, vy, w)``.
        b: (m,) pre-weighted right-hand side ``-w R_t``, m.
        information: (3, 3) :func:`unit_information` of the unweighted coefficients, or None if not asked for.
        mean_range_m: mean range of the constraints, m.
        rows: number of constraints.
    """

    A: np.ndarray
    b: np.ndarray
    information: np.ndarray | None
    mean_range_m: float
    rows: int


def weighted_constraints(r_ref_m: np.ndarray, r_new_m: np.ndarray, geom: LevelGeometry, symmetric: bool,
                         preweights: Preweights, information: bool = False) -> WeightedConstraints:
    """:func:`flow_terms` pre-weighted by ``preweights`` in one pass (the level solvers' hot path).

    Args:
        r_ref_m: (n,) reference ranges on the level grid, 0 = invalid.
        r_new_m: (n,) new ranges warped onto the same grid, 0 = invalid.
        geom: the level's geometry.
        symmetric: geometry at the mean of both scans (see :func:`flow_terms`).
        preweights: the pre-weight model.
        information: also return the geometric information of the constraints.

    Returns:
        The constraints; see :class:`WeightedConstraints`.
    """
    A, b, info, mean_r = _weighted_constraints_kernel(
        _f64(r_ref_m), _f64(r_new_m), geom.cos, geom.sin, geom.prev, geom.next, geom.has_prev, geom.has_next,
        geom.gap_next, geom.spacing_rad, bool(symmetric), *preweights.args, bool(information))
    return WeightedConstraints(A, b, info if information else None, mean_r, len(b))


@njit(cache=True, error_model="numpy")
def _weighted_constraints_kernel(r_ref: np.ndarray, r_new: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                                 prev: np.ndarray, nxt: np.ndarray, has_prev: np.ndarray, has_next: np.ndarray,
                                 gap_next: np.ndarray, spacing: np.ndarray, symmetric: bool,
                                 floor: float, k_first: float, k_second: float, k_rt_a: float, normalise: bool,
                                 information: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Compiled :func:`weighted_constraints`: ``(A, b, information or zeros, mean_range_m)``."""
    # 1. Constraints (3.64 / 3.91).
    n = len(r_ref)
    grad, ok = np.empty(n), np.empty(n, dtype=np.bool_)
    rows, A, rt, valid, mean_r = _flow_terms_kernel(r_ref, r_new, cos, sin, prev, nxt, has_prev, has_next, gap_next,
                                                    symmetric, grad, ok)
    # 2. Pre-weights (3.71 / 3.96) and the geometric information of the unweighted rows.
    w = _preweights_kernel(rows, grad * spacing, ok, rt, valid, prev, nxt, has_prev, has_next, floor, k_first,
                           k_second, k_rt_a, normalise)
    info = unit_information(A) if information else np.zeros((3, 3))
    # 3. Weighted rows.
    b = np.empty(len(rows))
    for j in range(len(rows)):
        b[j] = -w[j] * rt[rows[j]]
        for c in range(3):
            A[j, c] *= w[j]
    return A, b, info, mean_r


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


@njit(cache=True, error_model="numpy")
def _weighted_solve(At: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least squares of ``A xi = b`` with ``At = A^T`` ((3, m), C order: each pass is unit-stride),
    (m,) ``b`` and (m,) weights (empty = all 1).

    Returns:
        ``(xi, residuals A xi - b, A^T W A)``.
    """
    H, g = _normal_equations(At, b, w)
    xi = _solve_normal(H, g)
    r = np.empty(len(b))
    for i in range(len(b)):
        r[i] = At[0, i] * xi[0] + At[1, i] * xi[1] + At[2, i] * xi[2] - b[i]
    return xi, r, H


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})  # reassociation lets the sums vectorise
def _normal_equations(At: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A^T W A, A^T W b)`` ((3, 3), (3,)) of ``A xi = b`` (``At = A^T``) with (m,) weights (empty = all 1)."""
    h00 = h01 = h02 = h11 = h12 = h22 = g0 = g1 = g2 = 0.0
    weighted = len(w) > 0
    for i in range(len(b)):
        a0, a1, a2 = At[0, i], At[1, i], At[2, i]
        wi = w[i] if weighted else 1.0
        wa0, wa1, wa2 = wi * a0, wi * a1, wi * a2
        h00 += wa0 * a0
        h01 += wa0 * a1
        h02 += wa0 * a2
        h11 += wa1 * a1
        h12 += wa1 * a2
        h22 += wa2 * a2
        g0 += wa0 * b[i]
        g1 += wa1 * b[i]
        g2 += wa2 * b[i]
    H = np.empty((3, 3))
    H[0, 0], H[0, 1], H[0, 2], H[1, 1], H[1, 2], H[2, 2] = h00, h01, h02, h11, h12, h22
    H[1, 0], H[2, 0], H[2, 1] = h01, h02, h12
    return H, np.array([g0, g1, g2])


@njit(cache=True, error_model="numpy")
def _solve_normal(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Minimum-norm solution of ``H xi = g`` for a symmetric PSD (3, 3) ``H``.

    Well-conditioned systems are solved in closed form (adjugate); otherwise directions with eigenvalue below
    1e-12 of the largest get no update (they are unobservable).
    """
    a, b, c, d, e, f = H[0, 0], H[0, 1], H[0, 2], H[1, 1], H[1, 2], H[2, 2]
    c0, c1, c2 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c0 + b * c1 + c * c2
    if det > 1e-10 * a * d * f > 0:
        c4, c5 = b * c - a * e, a * f - c * c
        return np.array([c0 * g[0] + c1 * g[1] + c2 * g[2], c1 * g[0] + c5 * g[1] + c4 * g[2],
                         c2 * g[0] + c4 * g[1] + (a * d - b * b) * g[2]]) / det
    mu, V = eigh3(H)
    xi = np.zeros(3)
    for j in range(3):
        if mu[-1] > 0 and mu[j] > mu[-1] * 1e-12:
            xi += V[:, j] * ((V[0, j] * g[0] + V[1, j] * g[1] + V[2, j] * g[2]) / mu[j])
    return xi


@njit(cache=True, error_model="numpy")
def eigh3(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition of a symmetric (3, 3) matrix by cyclic Jacobi rotations (as ``np.linalg.eigh``).

    Args:
        S: (3, 3) symmetric matrix (only its upper triangle is read).

    Returns:
        ``(mu, V)``: (3,) eigenvalues in ascending order and (3, 3) orthonormal eigenvectors (columns).
    """
    a = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            a[i, j] = a[j, i] = S[i, j]
    V = np.eye(3)
    for _ in range(32):  # converges quadratically: a handful of sweeps
        off = abs(a[0, 1]) + abs(a[0, 2]) + abs(a[1, 2])
        if not off > 1e-18 * (abs(a[0, 0]) + abs(a[1, 1]) + abs(a[2, 2])):  # also stops on NaN
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p, q] != 0.0:
                _jacobi_rotate(a, V, p, q)
    order = [0, 1, 2]  # ascending eigenvalues (insertion sort)
    for i in (1, 2):
        for j in range(i, 0, -1):
            if a[order[j - 1], order[j - 1]] > a[order[j], order[j]]:
                order[j - 1], order[j] = order[j], order[j - 1]
    mu, W = np.empty(3), np.empty((3, 3))
    for c in range(3):
        mu[c] = a[order[c], order[c]]
        W[:, c] = V[:, order[c]]
    return mu, W


@njit(cache=True, error_model="numpy")
def _jacobi_rotate(a: np.ndarray, V: np.ndarray, p: int, q: int) -> None:
    """Zeroes ``a[p, q]`` by the rotation ``a <- J^T a J``, ``V <- V J`` (symmetric ``a``)."""
    theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
    t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
    c = 1.0 / math.sqrt(t * t + 1.0)
    s = t * c
    for k in range(3):  # columns p, q
        akp, akq = a[k, p], a[k, q]
        a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
    for k in range(3):  # rows p, q
        apk, aqk = a[p, k], a[q, k]
        a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
    a[p, q] = a[q, p] = 0.0
    for k in range(3):
        vkp, vkq = V[k, p], V[k, q]
        V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq


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
    return _covariance_eig(_f64(H), _f64(r), np.empty(0) if w is None else _f64(w))


@njit(cache=True, error_model="numpy")
def _covariance_eig(H: np.ndarray, r: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled :func:`weighted_covariance` (empty ``w`` = all 1); NaN when ``H`` is not finite."""
    s2, n_eff = 0.0, 0
    for i in range(len(r)):
        wi = w[i] if len(w) else 1.0
        s2 += wi * r[i] * r[i]
        if wi != 0.0:
            n_eff += 1
    s2 /= max(n_eff - 3, 1)
    if not np.all(np.isfinite(H)):
        return np.full(3, np.nan), np.full((3, 3), np.nan)
    mu, V = eigh3(H)
    lam = np.full(3, MAX_VARIANCE)
    for j in range(3):
        if mu[j] > max(mu[-1], 0.0) * 1e-12:
            lam[j] = min(max(s2 / mu[j], MIN_VARIANCE), MAX_VARIANCE)
    return lam, V


SolveResult = tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]
"""``(xi, covariance, normal, rows, eigenvalues, eigenvectors)`` of a solve, as the compiled solvers return it."""


@njit(cache=True, error_model="numpy")
def _solve_result(xi: np.ndarray, r: np.ndarray, H: np.ndarray, w: np.ndarray) -> SolveResult:
    """Covariance of a (weighted, empty ``w`` = all 1) solve with residuals ``r``, packed as a SolveResult."""
    lam, V = _covariance_eig(H, r, w)
    cov = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for k in range(3):
                cov[i, j] += V[i, k] * lam[k] * V[j, k]
    return xi, cov, H, len(r), lam, V


def _solution(result: SolveResult, lever_m: float) -> Solution:
    """A :class:`Solution` from a compiled solver's result."""
    xi, cov, H, rows, lam, V = result
    return Solution(xi, cov, H, rows, lever_m, (lam, V))


@njit(cache=True, error_model="numpy")
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
    return _solution(_irls_cauchy_kernel(_f64(A), _f64(b), int(iterations), float(k_ratio)), lever_m)


@njit(cache=True, error_model="numpy")
def _irls_cauchy_kernel(A: np.ndarray, b: np.ndarray, iterations: int, k_ratio: float) -> SolveResult:
    """Compiled :func:`irls_cauchy`."""
    At, w = np.ascontiguousarray(A.T), np.empty(0)
    xi, r, H = _weighted_solve(At, b, w)
    k = k_ratio * np.mean(np.abs(r))
    if not k > 1e-15:
        return _solve_result(xi, r, H, w)
    for _ in range(iterations):
        w = cauchy_weights(r, k)
        xi, r, H = _weighted_solve(At, b, w)
    return _solve_result(xi, r, H, w)


@njit(cache=True, error_model="numpy")
def truncated_parabola_weights(r: np.ndarray, c: float) -> np.ndarray:
    """IRLS weights of the smooth truncated parabola (3.100): ``1 - (r / c)²`` inside ``|r| <= c``, else 0."""
    return np.maximum(1.0 - (r / c) ** 2, 0.0)


@njit(cache=True, error_model="numpy")
def truncated_parabola_energy(r: np.ndarray, c: float) -> float:
    """Cost (3.95): ``sum r²/2 (1 - r²/(2c²))`` inside ``|r| <= c``, ``c²/4`` outside."""
    q = np.minimum((r / c) ** 2, 1.0)
    return 0.25 * c * c * np.sum(q * (2.0 - q))


@njit(cache=True, error_model="numpy")
def _upper_median(v: np.ndarray) -> float:
    """Element of rank ``len(v) // 2`` (the median for odd lengths, the upper median otherwise)."""
    return _select(v.copy(), len(v) // 2)


@njit(cache=True, error_model="numpy")
def _select(a: np.ndarray, k: int) -> float:
    """Element of rank ``k`` of ``a`` (quickselect; reorders ``a``)."""
    lo, hi = 0, len(a) - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return a[k]


@njit(cache=True, error_model="numpy")
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
    return _solution(_irls_truncated_parabola_kernel(_f64(A), _f64(b), int(max_iterations), float(mad_factor),
                                                     float(min_decrease)), lever_m)


@njit(cache=True, error_model="numpy")
def _irls_truncated_parabola_kernel(A: np.ndarray, b: np.ndarray, max_iterations: int, mad_factor: float,
                                    min_decrease: float) -> SolveResult:
    """Compiled :func:`irls_truncated_parabola`."""
    At, w = np.ascontiguousarray(A.T), np.empty(0)
    xi, r, H = _weighted_solve(At, b, w)
    c = mad_factor * median_absolute_deviation(r)
    if not c > 1e-15:
        return _solve_result(xi, r, H, w)
    w_next = np.empty(len(b))
    energy, inliers = _truncated_parabola_pass(r, c, w_next)
    for _ in range(max_iterations):
        if inliers < MIN_ROWS:
            break
        w, w_next = w_next, (w if len(w) else np.empty(len(b)))  # two buffers: this solve's weights, the next
        xi, r, H = _weighted_solve(At, b, w)
        last = energy
        energy, inliers = _truncated_parabola_pass(r, c, w_next)
        if not energy < min_decrease * last:
            break
    return _solve_result(xi, r, H, w)


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})  # reassociation lets the sum vectorise
def _truncated_parabola_pass(r: np.ndarray, c: float, w: np.ndarray) -> tuple[float, int]:
    """One pass over the residuals: writes :func:`truncated_parabola_weights` into ``w`` and returns the
    :func:`truncated_parabola_energy` and the number of non-zero weights."""
    total, inliers = 0.0, 0
    for i in range(len(r)):
        q = (r[i] / c) ** 2
        w[i] = max(1.0 - q, 0.0)
        q = min(q, 1.0)
        total += q * (2.0 - q)
        if w[i] != 0.0:
            inliers += 1
    return 0.25 * c * c * total, inliers


# ----------------------------------------------------------------------------------------------------------------
# Motion filter, degeneracy, SE(2) helpers


@njit(cache=True, error_model="numpy")
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
    xi = np.zeros(3)
    for j in range(3):
        gain = k_l + k_e * max(lam[j], 0.0)
        along_m = B[0, j] * xi_m[0] + B[1, j] * xi_m[1] + B[2, j] * xi_m[2]
        along_prior = B[0, j] * xi_prior[0] + B[1, j] * xi_prior[1] + B[2, j] * xi_prior[2]
        xi += B[:, j] * ((along_m + gain * along_prior) / (1.0 + gain))
    return xi


@njit(cache=True, error_model="numpy")
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
    info = np.zeros((3, 3))
    for i in range(A.shape[0]):
        norm = max(math.sqrt(A[i, 0] ** 2 + A[i, 1] ** 2), 1e-12)
        u0, u1, u2 = A[i, 0] / norm, A[i, 1] / norm, A[i, 2] / norm
        info[0, 0] += u0 * u0
        info[0, 1] += u0 * u1
        info[0, 2] += u0 * u2
        info[1, 1] += u1 * u1
        info[1, 2] += u1 * u2
        info[2, 2] += u2 * u2
    info[1, 0], info[2, 0], info[2, 1] = info[0, 1], info[0, 2], info[1, 2]
    return info


def _scaled_eigen(normal: np.ndarray, lever_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-decomposition of ``S N S`` with ``S = diag(1, 1, 1 / lever)``; also returns ``diag(S)``."""
    s = np.array([1.0, 1.0, 1.0 / max(lever_m, 1e-3)])
    mu, V = eigh3(_f64(normal * np.outer(s, s)))
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


@njit(cache=True, error_model="numpy")
def se2_exp(xi: np.ndarray) -> np.ndarray:
    """(3, 3) ``exp(hat(xi))`` of a (3,) twist (scalar fast path of :func:`simnav.geometry.se2.exp`)."""
    vx, vy, w = xi[0], xi[1], xi[2]
    s, c = math.sin(w), math.cos(w)
    if abs(w) < 1e-9:
        a, h = 1.0 - w * w / 6.0, 0.5 * w
    else:
        a, h = s / w, (1.0 - c) / w
    return _pose(c, s, a * vx - h * vy, h * vx + a * vy)


@njit(cache=True, error_model="numpy")
def se2_log(T: np.ndarray) -> np.ndarray:
    """(3,) twist of a (3, 3) pose (scalar fast path of :func:`simnav.geometry.se2.log`)."""
    w = math.atan2(T[1, 0], T[0, 0])
    half = 0.5 * w
    a = 1.0 - w * w / 12.0 if abs(w) < 1e-9 else half * math.cos(half) / math.sin(half)
    tx, ty = T[0, 2], T[1, 2]
    return np.array([a * tx + half * ty, -half * tx + a * ty, w])


@njit(cache=True, error_model="numpy")
def se2_inverse(T: np.ndarray) -> np.ndarray:
    """(3, 3) inverse of a (3, 3) pose (fast path of :func:`simnav.geometry.se2.inverse`)."""
    Ti = np.zeros((3, 3))
    Ti[0, 0], Ti[0, 1], Ti[1, 0], Ti[1, 1] = T[0, 0], T[1, 0], T[0, 1], T[1, 1]
    Ti[0, 2] = -(T[0, 0] * T[0, 2] + T[1, 0] * T[1, 2])
    Ti[1, 2] = -(T[0, 1] * T[0, 2] + T[1, 1] * T[1, 2])
    Ti[2, 2] = 1.0
    return Ti


@njit(cache=True, error_model="numpy")
def _pose(c: float, s: float, x: float, y: float) -> np.ndarray:
    """(3, 3) pose with rotation ``[[c, -s], [s, c]]`` and translation ``(x, y)``."""
    T = np.zeros((3, 3))
    T[0, 0], T[0, 1], T[0, 2] = c, -s, x
    T[1, 0], T[1, 1], T[1, 2] = s, c, y
    T[2, 2] = 1.0
    return T


@njit(cache=True, error_model="numpy")
def _compose(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(3, 3) product ``A @ B`` of two poses."""
    C = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return C


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
        packed: the geometry of all levels packed into flat arrays, or None.
        flat: (N,) the pyramid packed as ``packed`` lays it out (``pyramid`` holds views into it), or None.
    """

    stamp_s: float
    pyramid: list[np.ndarray]
    geoms: tuple[LevelGeometry, ...]
    valid_beams: int
    beams: int
    T_base_laser: np.ndarray
    packed: PackedGeometry | None = None
    flat: np.ndarray | None = None


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
    T, T_prior, moved = np.eye(3), se2_exp(_f64(xi_prior)), False
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
            T, moved = _filtered_update(T, T_prior, sol.xi, *sol.covariance_eig, k_l, k_e), True
            if math.sqrt(sol.xi @ sol.xi) < params.rewarp_tolerance:
                break
    return Alignment(T, solution, tuple(per_level))


@njit(cache=True, error_model="numpy")
def _filtered_update(T: np.ndarray, T_prior: np.ndarray, xi_m: np.ndarray, lam: np.ndarray, V: np.ndarray,
                     k_l: float, k_e: float) -> np.ndarray:
    """The running estimate ``T`` after a level solve ``xi_m`` (covariance eigenvalues ``lam``, eigenvectors
    ``V``): ``exp(motion_filter(xi_m, log(T_prior T^-1))) T`` (3.77 / 3.106)."""
    xi_prior_res = se2_log(_compose(T_prior, se2_inverse(T)))
    return _compose(se2_exp(motion_filter(xi_m, (lam, V), xi_prior_res, k_l, k_e)), T)


# ----------------------------------------------------------------------------------------------------------------
# One call per scan (packed pyramids, :mod:`simnav.odometry.rangeflow_fused`). These kernels live beside the ones
# they call: Numba's cache only notices edits to the file of the cached function itself.


@njit(cache=True, error_model="numpy")
def _pyramid_kernel(ranges: np.ndarray, windows: np.ndarray, offsets: np.ndarray, gate_m: float,
                    smooth_finest: bool, out: np.ndarray) -> None:
    """Compiled :func:`simnav.odometry.rangeflow_fused.build_packed_pyramid`: each level is the gated average of
    the one before it."""
    n0 = offsets[1]
    if smooth_finest:
        _gated_average_kernel(ranges, windows[:n0], gate_m, out[:n0])
    else:
        out[:n0] = ranges
    for lv in range(1, len(offsets) - 1):
        src = out[offsets[lv - 1]:offsets[lv]]
        _gated_average_kernel(src, windows[offsets[lv]:offsets[lv + 1]], gate_m, out[offsets[lv]:offsets[lv + 1]])


@njit(cache=True, error_model="numpy")
def _warp_levels_kernel(flat: np.ndarray, offsets: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                        seg_offsets: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, index_offsets: np.ndarray,
                        index_angles: np.ndarray, index_values: np.ndarray, a0: np.ndarray, step: np.ndarray,
                        circular: bool, T: np.ndarray, farthest: bool, out: np.ndarray) -> None:
    """Compiled :func:`simnav.odometry.rangeflow_fused.warp_packed`: writes every warped level into ``out``."""
    for lv in range(len(offsets) - 1):
        o0, o1 = offsets[lv], offsets[lv + 1]
        out[o0:o1] = _warp_level(flat[o0:o1], lv, offsets, cos, sin, seg_offsets, seg_a, seg_b, index_offsets,
                                 index_angles, index_values, a0, step, circular, T, farthest)


@njit(cache=True, error_model="numpy")
def _warp_level(ranges: np.ndarray, lv: int, offsets: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                seg_offsets: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, index_offsets: np.ndarray,
                index_angles: np.ndarray, index_values: np.ndarray, a0: np.ndarray, step: np.ndarray,
                circular: bool, T: np.ndarray, farthest: bool) -> np.ndarray:
    """:func:`_warp_kernel` of level ``lv`` onto itself (source and target grid)."""
    o0, o1 = offsets[lv], offsets[lv + 1]
    s0, s1 = seg_offsets[lv], seg_offsets[lv + 1]
    i0, i1 = index_offsets[lv], index_offsets[lv + 1]
    c, s = cos[o0:o1], sin[o0:o1]
    xw, yw, rho, u = _moved_points(ranges, c, s, T, a0[lv], step[lv], circular, index_angles[i0:i1],
                                   index_values[i0:i1])
    return _zbuffer(xw, yw, rho, u, seg_a[s0:s1], seg_b[s0:s1], c, s, circular, farthest)


@njit(cache=True, error_model="numpy")
def _coarse_to_fine_kernel(refs: np.ndarray, new: np.ndarray, offsets: np.ndarray, cos: np.ndarray,
                           sin: np.ndarray, spacing: np.ndarray, gap_next: np.ndarray, prev: np.ndarray,
                           nxt: np.ndarray, has_prev: np.ndarray, has_next: np.ndarray, seg_offsets: np.ndarray,
                           seg_a: np.ndarray, seg_b: np.ndarray, index_offsets: np.ndarray,
                           index_angles: np.ndarray, index_values: np.ndarray, a0: np.ndarray, step: np.ndarray,
                           circular: bool, T_prior: np.ndarray, k_l0: float, k_e0: float, max_rewarps: int,
                           rewarp_tolerance: float, symmetric: bool, floor: float, k_first: float,
                           k_second: float, k_rt_a: float, normalise: bool, robust: int, iterations: int,
                           param: float, min_decrease: float, info_level: int):
    """Compiled :func:`simnav.odometry.rangeflow_fused.coarse_to_fine_packed`: ``(T, solved, xi, covariance,
    normal, rows, lever, eigenvalues, eigenvectors, information)``, per-level arrays finest first."""
    levels = len(offsets) - 1
    T, moved = np.eye(3), False
    solved = np.zeros(levels, dtype=np.bool_)
    xi_l, cov_l, H_l = np.zeros((levels, 3)), np.zeros((levels, 3, 3)), np.zeros((levels, 3, 3))
    rows_l, lever_l = np.zeros(levels, dtype=np.int64), np.zeros(levels)
    lam_l, V_l, info = np.zeros((levels, 3)), np.zeros((levels, 3, 3)), np.zeros((3, 3))
    for stage in range(levels):
        lv = levels - 1 - stage
        o0, o1 = offsets[lv], offsets[lv + 1]
        k_l, k_e = k_l0 * math.exp(-stage), k_e0 * math.exp(-stage)
        for _ in range(max(max_rewarps, 1)):
            # 1. Warp the new scan onto the reference grid with the motion so far.
            warped = new[o0:o1] if not moved else _warp_level(
                new[o0:o1], lv, offsets, cos, sin, seg_offsets, seg_a, seg_b, index_offsets, index_angles,
                index_values, a0, step, circular, T, False)
            # 2. Pre-weighted constraints of every reference, stacked (3.99).
            A = np.empty((0, 3))
            b = np.empty(0)
            used, lever, info_sum = 0, 0.0, np.zeros((3, 3))
            for k in range(refs.shape[0]):
                A_k, b_k, info_k, mean_k = _weighted_constraints_kernel(
                    refs[k, o0:o1], warped, cos[o0:o1], sin[o0:o1], prev[o0:o1], nxt[o0:o1], has_prev[o0:o1],
                    has_next[o0:o1], gap_next[o0:o1], spacing[o0:o1], symmetric, floor, k_first, k_second,
                    k_rt_a, normalise, lv == info_level)
                if len(b_k) < MIN_ROWS:
                    continue
                if used == 0:
                    A, b = A_k, b_k
                else:
                    A, b = np.concatenate((A, A_k)), np.concatenate((b, b_k))
                used += 1
                lever += mean_k
                info_sum += info_k
            if used == 0:
                break
            # 3. Robust solve.
            if robust == 0:
                xi, cov, H, rows, lam, V = _irls_cauchy_kernel(A, b, iterations, param)
            else:
                xi, cov, H, rows, lam, V = _irls_truncated_parabola_kernel(A, b, iterations, param, min_decrease)
            solved[lv] = True
            xi_l[lv], cov_l[lv], H_l[lv], rows_l[lv], lever_l[lv] = xi, cov, H, rows, lever / used
            lam_l[lv], V_l[lv] = lam, V
            if lv == info_level:
                info = info_sum
            # 4. Filter against the prior residual motion and compose.
            T, moved = _filtered_update(T, T_prior, xi, lam, V, k_l, k_e), True
            if math.sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2]) < rewarp_tolerance:
                break
    return T, solved, xi_l, cov_l, H_l, rows_l, lever_l, lam_l, V_l, info
