"""DIFODO: dense visual odometry from depth images alone, by range flow (thesis §3.E; MRPT ``CDifodo``).

Every valid pixel gives one linear constraint on the camera velocity, the range flow constraint (3.23), written
with the trapezoidal depth gradient of both images (3.41) and the edge-aware gradients 3.42–3.45. The constraints
are weighted by the inverse of their expected error (3.33): the depth noise of a structured-light camera
(``sigma_z = k_z z^2``, §3.E.9) propagated through the constraint (3.30), plus a linearisation error from the
second derivatives of depth (3.32). Each level of a coarse-to-fine pyramid (built without mixing depths across
discontinuities, the new image warped into the previous one with the motion so far, §3.C.2, §3.E.6) is solved in
closed form by weighted least squares (3.25–3.27); its covariance (3.35) drives a low-pass filter in its eigenbasis
towards the previous velocity (3.36, constants 3.46). There is no robust kernel: moving objects bias the estimate
(§3.E.8).

Additions to the thesis, from the reference implementation (CDifodo) or needed on clean synthetic data:
CDifodo's first-order linearisation term (``linearization_k1``), which down-weights occlusion boundaries; pixels
without a neighbour on their own surface are edges and give no constraint (3.E.3 says they "must be ruled out");
warping rasterises triangles instead of splatting points, and an invalid pixel stays invalid in the pyramid
(:mod:`simnav.odometry.depth_pyramid`); a degenerate increment keeps the constant-velocity prediction along its
least-constrained translations (``hold_degenerate``).

Conventions:

* Frames are :class:`simnav.sensors.readings.RGBDFrame`; only ``depth_m``, ``K``, ``T_base_sensor`` and
  ``stamp_s`` are used. Poses and twists are of the optical frame (z forward, x right, y down).
* Twists ``xi = (vx, vy, vz, wx, wy, wz)`` are velocities in m/s and rad/s, translational part first; the motion
  of the camera over an interval ``dt`` is ``T_prev_curr = exp(xi dt)`` (:mod:`simnav.geometry.se3`).
* Pyramid levels are solved coarsest first; ``l = 1`` is the coarsest in the filter constants (3.46).

The per-pixel stages are Numba kernels (``@njit(cache=True)``: compiled on first use, about 10 s, then loaded from
``__pycache__``); helpers they call per pixel take scalars, as an array argument costs reference counting per
call. A QVGA frame takes 12-17 ms on one core, a QQVGA frame 3-5 ms, depending on the machine's load
(``scripts/bench_difodo_runtime.py``; a 30 Hz camera leaves 33 ms).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numba import njit

from simnav.geometry import se3
from simnav.odometry.base import CameraOdometryEstimate
from simnav.odometry.depth_pyramid import (
    LevelCamera,
    PyramidPlan,
    Workspace,
    build_pyramid,
    plan_pyramid,
    sanitize_depth,
    warp_depth,
)
from simnav.odometry.rangeflow import MAX_VARIANCE, MIN_VARIANCE, make_config, require
from simnav.sensors.readings import RGBDFrame

MIN_LEVEL_POINTS = 12
"""Fewest constraints a pyramid level needs to be solved (the covariance divides by ``N - 6``)."""


@dataclass(frozen=True)
class DifodoConfig:
    """DIFODO options; the defaults are the thesis' (§3.E.6, §3.E.9) unless stated.

    Attributes:
        max_rows: frames are first halved (with the gated filter) until they have at most this many rows; that is
            the finest level solved. 240 runs VGA or QVGA input at QVGA, as the thesis; 120 gives QQVGA.
        levels: coarse-to-fine levels; None = halve while the result keeps at least ``coarsest_rows`` rows.
        coarsest_rows: the automatic level count stops before this: 15 rows gives 5 levels from QVGA and 4 from
            QQVGA (coarsest 15 x 20, as in the thesis).
        depth_gate_m: the pyramid filter mixes only depths within this of the centre pixel's, m (CDifodo: 0.1).
        discontinuity_px: two neighbouring pixels lie on different surfaces when their depths differ by more than
            this many pixel footprints ``z / f`` (a surface seen at more than ``atan(6) = 80.5`` deg from its normal
            counts as a discontinuity): warping does not connect them, and a pixel with no neighbour on its own
            surface along u or along v is an edge and gives no constraint (not in the thesis).
        noise_kz: ``k_z`` of the depth noise ``sigma_z = k_z z^2`` (3.49), 1/m. The thesis value (with z in metres)
            is what balances the measurement error against the linearisation constants.
        linearization_kl: ``k_l`` of the linearisation error (3.32).
        linearization_k1: weight of CDifodo's first-order term ``Z_u^2 + Z_v^2 + (dt Z_t)^2`` added to the
            linearisation error (not in the thesis; CDifodo's ``kduv``); 0 = the thesis' weights.
        filter_k1: ``k_1`` of the velocity filter (3.36) at the coarsest level (3.46: ``0.5 e^-(l-1)``).
        filter_k2: ``k_2`` of the velocity filter at the coarsest level (3.46: ``0.05 e^-(l-1)``); it multiplies
            covariance eigenvalues of velocities, s²/m² (translation) and s²/rad² (rotation).
        nominal_rate_hz: frame rate assumed when the time stamps do not advance, Hz.
        min_valid_points: a frame with fewer valid pixels at the finest level than this ...
        min_valid_fraction: ... or than this fraction of them is not aligned; the constant-velocity prediction is
            reported instead, with covariance ``lost_variance * I`` (not in the thesis).
        lost_variance: variance (m², rad²) of a predicted increment, also added along the unobservable direction
            of a degenerate one.
        degeneracy_threshold: the estimate is flagged degenerate when the smallest eigenvalue of the geometric
            information (:attr:`LevelSystem.information`, rotation scaled by the mean depth) is below this fraction
            of the largest (not in the thesis, whose filter only damps such directions).
        degeneracy_spacing_deg: that information is taken at the level whose pixel spacing is closest to this, deg
            (at the finest level depth noise swamps the surface normals).
        hold_degenerate: a degenerate increment keeps the constant-velocity prediction along the translational part
            of its least-constrained directions (those below ``degeneracy_threshold``: e.g. along a corridor of
            floor and one wall, where the depth images do not change with the motion; along a plain wall filling
            the view, two). Without it the coarse levels' noise decides that motion. Not in the thesis.
        hold_degenerate_levels: also at every level as coarse as the degeneracy level or coarser, once a velocity
            was measured: a level whose information has exactly one direction below ``degeneracy_threshold`` (a
            corridor's floor and wall) keeps the prediction's translation along it, so the finer levels warp with
            that instead of with what the coarse levels' noise made of it. Not in the thesis.
    """

    max_rows: int = 240
    levels: int | None = None
    coarsest_rows: int = 15
    depth_gate_m: float = 0.1
    discontinuity_px: float = 6.0
    noise_kz: float = 2.8e-6
    linearization_kl: float = 5e-6
    linearization_k1: float = 2e-4
    filter_k1: float = 0.5
    filter_k2: float = 0.05
    nominal_rate_hz: float = 30.0
    min_valid_points: int = 100
    min_valid_fraction: float = 0.02
    lost_variance: float = 1.0
    degeneracy_threshold: float = 0.003
    degeneracy_spacing_deg: float = 2.0
    hold_degenerate: bool = True
    hold_degenerate_levels: bool = True

    def __post_init__(self) -> None:
        require(self.max_rows >= 4, "max_rows must be >= 4")
        require(self.levels is None or self.levels >= 1, "levels must be None or >= 1")
        require(self.coarsest_rows >= 2, "coarsest_rows must be >= 2")
        require(self.depth_gate_m > 0 and self.discontinuity_px > 0, "depth_gate_m and discontinuity_px must be > 0")
        require(self.noise_kz > 0, "noise_kz must be > 0")
        require(self.linearization_kl >= 0 and self.linearization_k1 >= 0, "linearization constants must be >= 0")
        require(self.filter_k1 >= 0 and self.filter_k2 >= 0, "filter_k1 and filter_k2 must be >= 0")
        require(self.nominal_rate_hz > 0, "nominal_rate_hz must be > 0")
        require(self.min_valid_points >= MIN_LEVEL_POINTS, f"min_valid_points must be >= {MIN_LEVEL_POINTS}")
        require(0 <= self.min_valid_fraction < 1, "min_valid_fraction must be in [0, 1)")
        require(self.lost_variance > 0, "lost_variance must be > 0")
        require(self.degeneracy_threshold >= 0, "degeneracy_threshold must be >= 0")
        require(self.degeneracy_spacing_deg > 0, "degeneracy_spacing_deg must be > 0")


# ----------------------------------------------------------------------------------------------------------------
# Constraints and weights


class LevelSystem(NamedTuple):
    """The normal equations of the weighted range-flow constraints of one level.

    Attributes:
        H: (6, 6) ``A^T W A``, the weights scaled so that its largest entry is 1 (only relative weights matter).
        g: (6,) ``A^T W B`` with ``B = -Z_t``, m/s.
        bb: ``B^T W B``, (m/s)².
        rows: number of constraints N.
        information: (6, 6) geometric information ``sum u u^T`` of the unweighted rows ``u`` divided by the norm of
            their translational part (zero unless asked for). That part is the surface normal scaled by the
            incidence and the gradient, so ``u`` is the point-to-plane row ``(n, p x n)`` and steep pixels do not
            dominate; unweighted on purpose, it measures the scene, not the residuals. A single plane gives rank 3
            (3.34).
        mean_depth_m: mean depth of the constraints, m.
    """

    H: np.ndarray
    g: np.ndarray
    bb: float
    rows: int
    information: np.ndarray
    mean_depth_m: float


def level_system(z_old: np.ndarray, z_new: np.ndarray, cam: LevelCamera, dt: float, xi_ref: np.ndarray,
                 cfg: DifodoConfig, information: bool = False, work: Workspace | None = None) -> LevelSystem:
    """Weighted range-flow constraints (3.23, 3.41, 3.33) between the previous frame and the warped new one.

    Geometry and gradients are taken at the mean of both images (trapezoidal rule, 3.41). A pixel valid in both
    images gives one constraint ``-a vx - b vy + c vz + (c y + b z) wx - (c x + a z) wy + (a y - b x) wz = -Z_t``
    with ``a = fx Z_u / z``, ``b = fy Z_v / z``, ``c = 1 + (a x + b y) / z`` and ``Z_t = (Z_new - Z_old) / dt``,
    unless it is an edge (see :func:`edge_aware_gradient`).

    The weight is ``1 / (sigma_m^2 + delta_l^2)`` (3.33): ``sigma_m`` from the depth noise (3.30, §3.E.9; see
    ``_measurement_variance``) and ``delta_l^2 = k_l [(dt Z_tu)^2 + (dt Z_tv)^2 + Z_uu^2 + Z_vv^2 + Z_uv^2]``
    (3.32, second derivatives by the stencil [-1 0 1] over the first ones) plus ``linearization_k1 [Z_u^2 + Z_v^2
    + (dt Z_t)^2]``.

    Args:
        z_old: (H, W) depth of the previous frame at this level, 0 = invalid.
        z_new: (H, W) new depth warped into the previous frame with the motion so far.
        cam: the level's intrinsics.
        dt: interval between the frames, s.
        xi_ref: (6,) velocity still expected at this level (for the error propagation of 3.30), m/s, rad/s.
        cfg: the options (noise, linearisation and discontinuity constants).
        information: also compute :attr:`LevelSystem.information` (else it is zero).
        work: scratch arrays of this size (None = fresh ones).

    Returns:
        The normal equations.
    """
    work = Workspace(*z_old.shape) if work is None else work
    H, g, bb, rows, info, mean_depth = _level_kernel(
        np.ascontiguousarray(z_old, dtype=np.float32), np.ascontiguousarray(z_new, dtype=np.float32),
        cam.x_over_z, cam.y_over_z, cam.fx, cam.fy, float(dt), np.ascontiguousarray(xi_ref, dtype=np.float64),
        cfg.noise_kz, cfg.linearization_kl, cfg.linearization_k1, cfg.discontinuity_px, information, work.real,
        work.flags)
    return LevelSystem(H, g, bb, rows, info, mean_depth)


def edge_aware_gradient(depth_m: np.ndarray, cam: LevelCamera,
                        discontinuity_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edge-aware depth gradients of one image (3.42–3.45), as :func:`level_system` computes them.

    ``Z_u = (r(u) Z^+ + r(u-1) Z^-) / (r(u) + r(u-1))`` with ``Z^+``, ``Z^-`` the forward and backward differences
    and ``r`` the inverse distance between the two points of each difference in the x-z plane (y-z plane for
    ``Z_v``): the closer neighbour dominates. A neighbour farther than ``discontinuity_px`` pixel footprints
    ``z / f`` lies across a discontinuity and is ignored; with one neighbour left its one-sided difference is
    used, with none the pixel is an edge (undefined).

    Args:
        depth_m: (H, W) depth, 0 = invalid.
        cam: its intrinsics.
        discontinuity_px: see :class:`DifodoConfig`.

    Returns:
        ``(Z_u, Z_v, defined_u, defined_v)``: (H, W) gradients in m per pixel and where they are defined.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float64)
    zu, zv = np.zeros(z.shape), np.zeros(z.shape)
    oku, okv = np.zeros(z.shape, dtype=np.bool_), np.zeros(z.shape, dtype=np.bool_)
    _gradients(z, cam.x_over_z, cam.y_over_z, cam.fx, cam.fy, discontinuity_px, zu, zv, oku, okv)
    return zu, zv, oku, okv


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "nsz"})
def _level_kernel(z_old: np.ndarray, z_new: np.ndarray, xn: np.ndarray, yn: np.ndarray, fx: float, fy: float,
                  dt: float, xi: np.ndarray, kz: float, kl: float, k1: float, discontinuity_px: float,
                  information: bool, real: np.ndarray,
                  flags: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int, np.ndarray, float]:
    """Compiled :func:`level_system` with scratch ``real`` (4, H, W) and ``flags`` (3, H, W); returns ``H, g,
    bb, rows, information, mean depth``."""
    h, w = z_old.shape
    z, zt, zu, zv = real[0], real[1], real[2], real[3]
    ok, oku, okv = flags[0], flags[1], flags[2]
    # 1. Mean ("inter") depth and temporal difference dt Z_t.
    for v in range(h):
        for u in range(w):
            ok[v, u] = z_old[v, u] > 0 and z_new[v, u] > 0
            z[v, u] = 0.5 * (np.float64(z_old[v, u]) + z_new[v, u]) if ok[v, u] else 0.0
            zt[v, u] = np.float64(z_new[v, u]) - z_old[v, u] if ok[v, u] else 0.0
    # 2. Edge-aware spatial gradients (3.42–3.45).
    _gradients(z, xn, yn, fx, fy, discontinuity_px, zu, zv, oku, okv)
    # 3. One weighted row per usable pixel (weight from the measurement error, 3.30, and the linearisation error,
    # 3.32), accumulated into the normal equations.
    Hm, g, info = np.zeros((6, 6)), np.zeros(6), np.zeros((6, 6))
    row = np.empty(6)
    bb, depth_sum, rows = 0.0, 0.0, 0
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = h22 = h23 = h24 = h25 = 0.0
    h33 = h34 = h35 = h44 = h45 = h55 = 0.0
    var_t = 1.0 / (2.0 * dt * dt)
    xi_s = (xi[0], xi[1], xi[2], xi[3], xi[4], xi[5])  # a tuple of scalars: no reference counting per pixel
    for v in range(h):
        va, vb = max(v - 1, 0), min(v + 1, h - 1)  # rows above and below (flags say whether they exist)
        for u in range(w):
            if not (oku[v, u] and okv[v, u]):
                continue
            ul, ur = max(u - 1, 0), min(u + 1, w - 1)
            has_l, has_r, has_a, has_b = u > 0, u < w - 1, v > 0, v < h - 1
            # Linearisation error: the first-order term, and (3.32) by the stencil [-1 0 1] over the first
            # derivatives.
            lin = k1 * (zu[v, u] ** 2 + zv[v, u] ** 2 + zt[v, u] ** 2) + kl * (
                _centred_squared(zt[v, ul], has_l and ok[v, ul], zt[v, u], zt[v, ur], has_r and ok[v, ur])
                + _centred_squared(zt[va, u], has_a and ok[va, u], zt[v, u], zt[vb, u], has_b and ok[vb, u])
                + _centred_squared(zu[v, ul], has_l and oku[v, ul], zu[v, u], zu[v, ur], has_r and oku[v, ur])
                + _centred_squared(zv[va, u], has_a and okv[va, u], zv[v, u], zv[vb, u], has_b and okv[vb, u])
                + _centred_squared(zv[v, ul], has_l and okv[v, ul], zv[v, u], zv[v, ur], has_r and okv[v, ur]))
            d = z[v, u]
            x, y = xn[u] * d, yn[v] * d
            ga, gb = fx * zu[v, u] / d, fy * zv[v, u] / d
            gc = 1.0 + ga * xn[u] + gb * yn[v]
            row[0], row[1], row[2] = -ga, -gb, gc
            row[3], row[4], row[5] = gc * y + gb * d, -(gc * x + ga * d), ga * y - gb * x
            weight = 1.0 / (_measurement_variance(xn[u], yn[v], d, ga, gb, gc, fx, fy, var_t, xi_s, kz) + lin)
            rhs = -zt[v, u] / dt
            # Upper triangle of the normal matrix in scalars (kept in registers; an array would be reloaded).
            r0, r1, r2, r3, r4, r5 = row[0], row[1], row[2], row[3], row[4], row[5]
            w0, w1, w2, w3, w4, w5 = weight * r0, weight * r1, weight * r2, weight * r3, weight * r4, weight * r5
            g0, g1, g2 = g0 + w0 * rhs, g1 + w1 * rhs, g2 + w2 * rhs
            g3, g4, g5 = g3 + w3 * rhs, g4 + w4 * rhs, g5 + w5 * rhs
            h00, h01, h02 = h00 + w0 * r0, h01 + w0 * r1, h02 + w0 * r2
            h03, h04, h05 = h03 + w0 * r3, h04 + w0 * r4, h05 + w0 * r5
            h11, h12, h13, h14, h15 = h11 + w1 * r1, h12 + w1 * r2, h13 + w1 * r3, h14 + w1 * r4, h15 + w1 * r5
            h22, h23, h24, h25 = h22 + w2 * r2, h23 + w2 * r3, h24 + w2 * r4, h25 + w2 * r5
            h33, h34, h35 = h33 + w3 * r3, h34 + w3 * r4, h35 + w3 * r5
            h44, h45, h55 = h44 + w4 * r4, h45 + w4 * r5, h55 + w5 * r5
            bb += weight * rhs * rhs
            if information:
                unit = 1.0 / max(ga * ga + gb * gb + gc * gc, 1e-300)
                for i in range(6):
                    for j in range(i, 6):
                        info[i, j] += unit * row[i] * row[j]
            depth_sum += d
            rows += 1
    # 4. Symmetrise, and scale the weights to at most 1 (only relative weights matter).
    Hm[0], Hm[1, 1:], Hm[2, 2:] = (h00, h01, h02, h03, h04, h05), (h11, h12, h13, h14, h15), (h22, h23, h24, h25)
    Hm[3, 3:], Hm[4, 4:], Hm[5, 5] = (h33, h34, h35), (h44, h45), h55
    g[:] = (g0, g1, g2, g3, g4, g5)
    scale = 1.0 / max(np.abs(Hm).max(), 1e-300)
    for i in range(6):
        for j in range(i + 1, 6):
            Hm[j, i], info[j, i] = Hm[i, j], info[i, j]
    return Hm * scale, g * scale, bb * scale, rows, info, depth_sum / max(rows, 1)


@njit(cache=True, error_model="numpy")
def _gradients(z: np.ndarray, xn: np.ndarray, yn: np.ndarray, fx: float, fy: float, discontinuity_px: float,
               zu: np.ndarray, zv: np.ndarray, oku: np.ndarray, okv: np.ndarray) -> None:
    """Compiled :func:`edge_aware_gradient` of a float64 depth image, written into ``zu, zv, oku, okv``.

    The difference and distance between two neighbours serve both of them: they are computed once per pair, a
    row at a time (to the right neighbour along u, lateral coordinate x; to the one below along v, lateral y).
    """
    h, w = z.shape
    right_diff, right_dist = np.zeros(w), np.zeros(w)
    above_diff, above_dist, below_diff, below_dist = np.zeros(w), np.zeros(w), np.zeros(w), np.zeros(w)
    for v in range(h):
        # 1. Pairs of this row with the next row (lateral coordinate y) and with the right neighbours (x).
        if v < h - 1:
            for u in range(w):
                below_diff[u] = z[v + 1, u] - z[v, u]
                lateral = yn[v + 1] * z[v + 1, u] - yn[v] * z[v, u]
                below_dist[u] = math.sqrt(below_diff[u] * below_diff[u] + lateral ** 2)
        for u in range(w - 1):
            right_diff[u] = z[v, u + 1] - z[v, u]
            lateral = xn[u + 1] * z[v, u + 1] - xn[u] * z[v, u]
            right_dist[u] = math.sqrt(right_diff[u] * right_diff[u] + lateral ** 2)
        # 2. Each valid pixel from its two pairs along each axis.
        for u in range(w):
            d = z[v, u]
            zu[v, u] = zv[v, u] = 0.0
            oku[v, u] = okv[v, u] = False
            if d <= 0:
                continue
            # (index u - 1 wraps at u = 0, where has_l is False and the value is ignored)
            has_l, has_r = u > 0 and z[v, u - 1] > 0, u < w - 1 and z[v, u + 1] > 0
            zu[v, u], oku[v, u] = _gradient_at(right_diff[u - 1], right_dist[u - 1], has_l, right_diff[u],
                                               right_dist[u], has_r, discontinuity_px * d / fx)
            has_a, has_b = v > 0 and z[v - 1, u] > 0, v < h - 1 and z[v + 1, u] > 0
            zv[v, u], okv[v, u] = _gradient_at(above_diff[u], above_dist[u], has_a, below_diff[u], below_dist[u],
                                               has_b, discontinuity_px * d / fy)
        above_diff, above_dist, below_diff, below_dist = below_diff, below_dist, above_diff, above_dist


@njit(cache=True, error_model="numpy", inline="always")
def _gradient_at(diff_p: float, dist_p: float, has_p: bool, diff_n: float, dist_n: float, has_n: bool,
                 limit: float) -> tuple[float, bool]:
    """Edge-aware gradient (3.44 / 3.45) of one pixel along one axis from the difference and distance to its
    previous and next neighbour (where those are valid); neighbours farther than ``limit`` (m) are ignored.
    Scalars only: array arguments would cost reference counting per pixel."""
    has_p = has_p and dist_p <= limit
    has_n = has_n and dist_n <= limit
    if has_p and has_n:  # weights r = 1 / dist of each side's own difference, written without divisions
        return (dist_p * diff_n + dist_n * diff_p + 1e-12 * (diff_n + diff_p)) / (dist_p + dist_n + 2e-12), True
    if has_n:
        return diff_n, True
    if has_p:
        return diff_p, True
    return 0.0, False


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "nsz"}, inline="always")
def _centred_squared(f_prev: float, has_prev: bool, f: float, f_next: float, has_next: bool) -> float:
    """``(f(+1) - f(-1))^2`` (stencil [-1 0 1]) from a pixel's value and its two neighbours' along one axis;
    next to a missing neighbour the difference is twice the one-sided one, without neighbours 0."""
    if has_prev and has_next:
        diff = f_next - f_prev
    elif has_next:
        diff = 2.0 * (f_next - f)
    elif has_prev:
        diff = 2.0 * (f - f_prev)
    else:
        diff = 0.0
    return diff * diff


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "nsz"}, inline="always")
def _measurement_variance(xz: float, yz: float, z: float, a: float, b: float, c: float, fx: float, fy: float,
                          var_t: float, xi: tuple[float, float, float, float, float, float], kz: float) -> float:
    """Variance of one constraint from the depth noise (3.30 with the covariances 3.47–3.56).

    ``sigma_m^2 = sigma_Zt^2 + (dR/dZ_u sigma_Zu)^2 + (dR/dZ_v sigma_Zv)^2 + k_z^2 z^2 (dR/dp . p)^2`` with
    ``sigma_Zt = k_z z^2 / (sqrt(2) dt)`` and ``sigma_Zu = sigma_Zv = k_z z^2 / (2 sqrt(2))`` (3.52). The covariance
    of ``p = (x, y, z)`` is ``k_z^2 z^2 p p^T`` (rank one, 3.50–3.55), so its term only needs the derivative of the
    constraint along the pixel's ray, ``dR/dp . p``.

    Args:
        xz, yz: ``x / z`` and ``y / z`` of the pixel.
        z: its depth, m.
        a, b, c: the coefficients of :func:`level_system`.
        fx, fy: focal lengths, pixels.
        var_t: ``1 / (2 dt^2)``, 1/s².
        xi: the six components of the expected velocity, m/s and rad/s.
        kz: ``k_z``, 1/m.
    """
    x, y = xz * z, yz * z
    p = xi[2] + y * xi[3] - x * xi[4]  # -dz/dt of the point
    q = -xi[0] - z * xi[4] + y * xi[5]  # dx/dt
    s = -xi[1] + z * xi[3] - x * xi[5]  # dy/dt
    d_zu = fx * (xz * p + q) / z
    d_zv = fy * (yz * p + s) / z
    d_ray = p - c * xi[2] + a * xi[0] + b * xi[1]
    sz2 = (kz * z * z) ** 2
    return sz2 * (var_t + 0.125 * (d_zu * d_zu + d_zv * d_zv)) + (kz * z * d_ray) ** 2


# ----------------------------------------------------------------------------------------------------------------
# Solution, covariance and filter


class LevelSolution(NamedTuple):
    """Weighted least-squares solution of one level (3.25–3.27) and its covariance (3.35).

    Attributes:
        xi: (6,) velocity, m/s and rad/s.
        eigvals: (6,) eigenvalues of the covariance, (m/s)² and (rad/s)² mixed.
        eigvecs: (6, 6) their eigenvectors (columns).
        rows: number of constraints.
    """

    xi: np.ndarray
    eigvals: np.ndarray
    eigvecs: np.ndarray
    rows: int

    @property
    def covariance(self) -> np.ndarray:
        """(6, 6) covariance of ``xi``."""
        return (self.eigvecs * self.eigvals) @ self.eigvecs.T


def solve_level(system: LevelSystem) -> LevelSolution | None:
    """Closed-form weighted least squares ``xi = (A^T W A)^-1 A^T W B`` and the covariance
    ``Sigma = |r|^2 / (N - 6) (A^T W A)^-1`` (3.35, ``r`` the weighted residuals).

    The normal matrix is inverted in its eigenbasis: directions whose eigenvalue is below ``1e-12`` of the largest
    get no update and the variance ``MAX_VARIANCE`` (the filter then keeps the previous velocity there). The
    residual is ``B^T W B - 2 xi^T A^T W B + xi^T A^T W A xi`` (no second pass over the pixels).

    Returns:
        The solution, or None with fewer than ``MIN_LEVEL_POINTS`` constraints or a zero normal matrix.
    """
    if system.rows < MIN_LEVEL_POINTS:
        return None
    mu, V = np.linalg.eigh(system.H)
    if not (np.all(np.isfinite(mu)) and mu[-1] > 0):
        return None
    floor = 1e-12 * mu[-1]
    inv = np.where(mu > floor, 1.0 / np.maximum(mu, floor), 0.0)
    xi = V @ (inv * (V.T @ system.g))
    residual = max(system.bb - 2.0 * xi @ system.g + xi @ system.H @ xi, 0.0)
    var = np.minimum(residual / (system.rows - 6) / np.maximum(mu, floor), MAX_VARIANCE)
    return LevelSolution(xi, var, V, system.rows)


def velocity_filter(sol: LevelSolution, xi_prior: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """Low-pass filter of a level's velocity in the eigenbasis of its covariance (3.36).

    Solves ``[(1 + k1) I + k2 D] xi_E = xi_E^s + (k1 I + k2 D) xi_E^prior`` per eigen-direction: well-constrained
    directions (small variance) keep the solver's value, poorly constrained ones lean on the prior.

    Args:
        sol: the level's solution and covariance eigen-decomposition.
        xi_prior: (6,) previous velocity minus the velocity already estimated by coarser levels.
        k1, k2: the level's filter constants (3.46).

    Returns:
        (6,) filtered velocity in the camera frame.
    """
    E = sol.eigvecs
    gain = k1 + k2 * sol.eigvals
    return E @ ((E.T @ sol.xi + gain * (E.T @ xi_prior)) / (1.0 + gain))


def degeneracy(information: np.ndarray, lever_m: float) -> tuple[float, np.ndarray]:
    """Smallest over largest eigenvalue of a geometric information matrix, rotation expressed as displacement.

    Args:
        information: (6, 6) information (:attr:`LevelSystem.information`) in ``(v, w)``.
        lever_m: length turning rotations into displacements (mean depth), m.

    Returns:
        ``(ratio, direction)``: the ratio in [0, 1] (near 0 when a motion is unobservable, e.g. facing a single
        wall) and the (6,) unit twist direction constrained least.
    """
    mu, V, s = _scaled_information(information, lever_m)
    ratio = float(max(mu[0], 0.0) / mu[-1]) if mu[-1] > 0 else 0.0
    v = V[:, 0] * s
    return ratio, v / np.linalg.norm(v)


def hold_weak_translations(xi: np.ndarray, xi_prediction: np.ndarray, information: np.ndarray, lever_m: float,
                           threshold: float) -> np.ndarray:
    """``xi`` with the translational part of its least-constrained directions taken from ``xi_prediction``.

    In the coordinates of :func:`degeneracy` (rotation as displacement at ``lever_m``) with ``U`` the eigenvectors
    of the information whose eigenvalue is below ``threshold`` times the largest (at least the weakest one), the
    twist moves by the translational part of ``U U^T (prediction - xi)``; its rotation stays as estimated. A
    corridor of floor and one wall has one such direction, a single plain wall three (two translations held).

    Args:
        xi: (6,) estimated velocity (v, w), m/s and rad/s.
        xi_prediction: (6,) predicted velocity, same units.
        information: (6, 6) geometric information (:attr:`LevelSystem.information`).
        lever_m: mean depth, m.
        threshold: eigenvalue ratio below which a direction is held (``degeneracy_threshold``).

    Returns:
        (6,) velocity.
    """
    mu, V, s = _scaled_information(information, lever_m)
    U = V[:, np.r_[True, mu[1:] < threshold * mu[-1]]]
    step = U @ (U.T @ ((xi_prediction - xi) / s))
    return xi + np.r_[step[:3], np.zeros(3)]


def _weak_count(information: np.ndarray, lever_m: float, threshold: float) -> int:
    """How many directions of the information (as :func:`degeneracy` scales it) lie below ``threshold`` times the
    largest."""
    mu = _scaled_information(information, lever_m)[0]
    return int(np.count_nonzero(mu < threshold * mu[-1])) if mu[-1] > 0 else 6


def _scaled_information(information: np.ndarray, lever_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues (ascending), eigenvectors and the (6,) scale ``s`` of the information of the twist divided by
    ``s`` (rotation times ``lever_m``: the displacement it causes at that distance)."""
    s = np.r_[np.ones(3), np.full(3, 1.0 / max(lever_m, 1e-3))]
    mu, V = np.linalg.eigh(information * np.outer(s, s))
    return mu, V, s


# ----------------------------------------------------------------------------------------------------------------
# Odometry


@dataclass(frozen=True)
class DepthFrame:
    """A depth frame prepared for DIFODO.

    Attributes:
        stamp_s: time stamp, s.
        pyramid: depth per level, finest first (float32, m, 0 = invalid).
        cameras: intrinsics per level, finest first.
        key: shape and intrinsics, to tell whether two frames can be aligned.
    """

    stamp_s: float
    pyramid: list[np.ndarray]
    cameras: tuple[LevelCamera, ...]
    key: tuple


class Alignment(NamedTuple):
    """Result of :meth:`DIFODO._align`.

    Attributes:
        T_prev_curr: (4, 4) motion of the camera from the previous frame to the new one.
        solution: solution of the finest level solved.
        information: geometric information at the degeneracy level and its lever (mean depth, m), or None.
        levels_solved: number of levels that had enough constraints.
    """

    T_prev_curr: np.ndarray
    solution: LevelSolution
    information: tuple[np.ndarray, float] | None
    levels_solved: int


class DIFODO:
    """DIFferential ODOmetry from depth images (§3.E); a :class:`simnav.odometry.base.FrameOdometry`.

    Args:
        config: the options; None = defaults.
        **overrides: :class:`DifodoConfig` fields to change (on top of ``config``); an unknown name or a bad value
            raises :class:`simnav.errors.ConfigError` listing the allowed ones.

    :meth:`process` never raises on bad depth values; it raises ``ValueError`` only for an image size the pyramid
    cannot use (see :func:`simnav.odometry.depth_pyramid.plan_pyramid`).
    """

    def __init__(self, config: DifodoConfig | None = None, **overrides) -> None:
        base = {} if config is None else {f.name: getattr(config, f.name) for f in fields(DifodoConfig)}
        self.config: DifodoConfig = make_config(DifodoConfig, {**base, **overrides}, "DIFODO")
        self._plans: dict[tuple[int, int], PyramidPlan] = {}
        self._cameras: dict[tuple, tuple[LevelCamera, ...]] = {}
        self._work: dict[tuple[int, int], Workspace] = {}
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next frame starts a new odom frame."""
        self._ref: DepthFrame | None = None
        self._last_stamp_s: float | None = None
        self._T_odom_camera = np.eye(4)
        self._xi_prev = np.zeros(6)  # last camera velocity (body twist), m/s and rad/s

    def process(self, frame: RGBDFrame) -> CameraOdometryEstimate:
        """Estimate the motion since the previous frame.

        Args:
            frame: the new frame; NaN, inf and non-positive depths are invalid.

        Returns:
            The estimate; see :class:`simnav.odometry.base.CameraOdometryEstimate`. ``extra`` holds ``measured``
            (False when the increment is a constant-velocity prediction or the first frame), ``levels`` (levels
            solved) and ``degeneracy_ratio``.

        Raises:
            ValueError: the depth image is not 2D or its size cannot be used by the pyramid.
        """
        t0 = time.perf_counter()
        cfg = self.config
        # 1. Pyramid of the new frame (None when it has too few valid pixels).
        new = self._frame(frame)
        first = self._last_stamp_s is None
        dt = frame.stamp_s - self._last_stamp_s if not first else 0.0
        dt = dt if dt > 0 and math.isfinite(dt) else 1.0 / cfg.nominal_rate_hz
        # 2. Align with the previous frame, or predict with constant velocity.
        ref, alignment = self._ref, None
        if new is not None and ref is not None and new.key == ref.key:
            alignment = self._align(ref, new, dt)
        if alignment is not None:
            cov, degenerate, ratio = self._covariance(alignment, dt)
            T_inc = self._held(alignment, dt) if degenerate and cfg.hold_degenerate else alignment.T_prev_curr
        else:
            T_inc = np.eye(4) if first else se3.exp(self._xi_prev * dt)
            cov = np.zeros((6, 6)) if first else cfg.lost_variance * np.eye(6)
            degenerate, ratio = not first, 0.0
        # 3. Pose, twist, base pose through the mount, and the prior of the next frame.
        self._T_odom_camera = self._T_odom_camera @ T_inc
        twist = se3.log(T_inc) / dt
        if alignment is not None:
            self._xi_prev = twist
        T_base_camera = np.asarray(frame.T_base_sensor, dtype=np.float64)
        T_odom_base = T_base_camera @ self._T_odom_camera @ se3.inverse(T_base_camera)
        self._ref = new
        self._last_stamp_s = frame.stamp_s
        extra = {"measured": alignment is not None, "levels": alignment.levels_solved if alignment else 0,
                 "degeneracy_ratio": ratio}
        return CameraOdometryEstimate(
            stamp_s=frame.stamp_s, T_odom_camera=self._T_odom_camera.copy(), T_odom_base=T_odom_base,
            twist_camera=_finite(twist), covariance=_finite(0.5 * (cov + cov.T)), degenerate=bool(degenerate),
            valid_points=alignment.solution.rows if alignment else 0, runtime_s=time.perf_counter() - t0,
            extra=extra)

    def _frame(self, frame: RGBDFrame) -> DepthFrame | None:
        """Sanitised depth pyramid of a frame; None when it has too few valid pixels or unusable intrinsics."""
        cfg = self.config
        depth = np.asarray(frame.depth_m)
        if depth.ndim != 2:
            raise ValueError(f"DIFODO needs a (H, W) depth image, got shape {depth.shape}")
        plan = self._plans.get(depth.shape)
        if plan is None:
            plan = self._plans[depth.shape] = plan_pyramid(depth.shape, cfg.max_rows, cfg.coarsest_rows, cfg.levels)
        K = np.asarray(frame.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            return None
        key = (depth.shape, tuple(K.ravel()))
        cameras = self._cameras.get(key)
        if cameras is None:
            cameras = self._cameras[key] = plan.cameras(K)
        pyramid = build_pyramid(sanitize_depth(depth), plan, cfg.depth_gate_m)
        valid = int(np.count_nonzero(pyramid[0]))
        if valid < max(cfg.min_valid_points, math.ceil(cfg.min_valid_fraction * pyramid[0].size)):
            return None
        return DepthFrame(frame.stamp_s, pyramid, cameras, key)

    def _align(self, ref: DepthFrame, new: DepthFrame, dt: float) -> Alignment | None:
        """Coarse-to-fine estimate of the motion from ``ref`` to ``new`` (Algorithm 1); None if no level solved."""
        cfg = self.config
        info_level = self._information_level(new.cameras)
        hold_levels = cfg.hold_degenerate and cfg.hold_degenerate_levels and bool(np.any(self._xi_prev != 0.0))
        T, solution, information, solved = np.eye(4), None, None, 0
        for step, lv in enumerate(range(len(new.pyramid) - 1, -1, -1)):
            cam, work = new.cameras[lv], self._workspace(new.pyramid[lv].shape)
            # 1. Warp the new image into the previous frame with the motion so far (not at the coarsest level).
            warped = new.pyramid[lv] if step == 0 else warp_depth(new.pyramid[lv], cam, T, cfg.discontinuity_px, work)
            # 2. What the previous velocity still predicts after the coarser levels.
            xi_rest = self._xi_prev - se3.log(T) / dt
            # 3. Weighted constraints and their closed-form solution.
            held = hold_levels and lv >= info_level
            system = level_system(ref.pyramid[lv], warped, cam, dt, xi_rest, cfg, lv == info_level or held, work)
            sol = solve_level(system)
            if sol is None:
                continue
            solved, solution = solved + 1, sol
            if lv == info_level:
                information = (system.information, system.mean_depth_m)
            # 4. Filter against the prior (3.36, 3.46), hold a corridor's weak translation at a coarse level, and
            #    compose on the left of the motion so far.
            k = math.exp(-step)
            xi = velocity_filter(sol, xi_rest, cfg.filter_k1 * k, cfg.filter_k2 * k)
            if held and _weak_count(system.information, system.mean_depth_m, cfg.degeneracy_threshold) == 1:
                xi = hold_weak_translations(xi, xi_rest, system.information, system.mean_depth_m,
                                            cfg.degeneracy_threshold)
            T = se3.exp(xi * dt) @ T
        if solution is None or not np.all(np.isfinite(T)):
            return None
        return Alignment(T, solution, information, solved)

    def _covariance(self, alignment: Alignment, dt: float) -> tuple[np.ndarray, bool, float]:
        """Covariance of the increment (the finest solve's times ``dt^2``, eigenvalues clipped to ``[MIN_VARIANCE,
        MAX_VARIANCE]``), degeneracy flag and ratio; a degenerate estimate gets ``lost_variance`` added along its
        weakest direction."""
        sol = alignment.solution
        var = np.clip(sol.eigvals * dt * dt, MIN_VARIANCE, MAX_VARIANCE)
        cov = (sol.eigvecs * var) @ sol.eigvecs.T
        if alignment.information is None:
            return cov, False, 1.0
        ratio, v = degeneracy(*alignment.information)
        if ratio >= self.config.degeneracy_threshold:
            return cov, False, ratio
        return cov + self.config.lost_variance * np.outer(v, v), True, ratio

    def _held(self, alignment: Alignment, dt: float) -> np.ndarray:
        """The increment of a degenerate alignment with its weak translations from the constant-velocity
        prediction (:func:`hold_weak_translations`)."""
        xi = se3.log(alignment.T_prev_curr) / dt
        return se3.exp(hold_weak_translations(xi, self._xi_prev, *alignment.information,
                                              self.config.degeneracy_threshold) * dt)

    def _information_level(self, cameras: tuple[LevelCamera, ...]) -> int:
        """Index of the level whose pixel spacing is closest to ``degeneracy_spacing_deg``."""
        target = math.radians(self.config.degeneracy_spacing_deg)
        return min(range(len(cameras)), key=lambda i: abs(math.atan(1.0 / cameras[i].fx) - target))

    def _workspace(self, shape: tuple[int, int]) -> Workspace:
        """Scratch arrays for one level size, kept from frame to frame."""
        work = self._work.get(shape)
        if work is None:
            work = self._work[shape] = Workspace(*shape)
        return work


def _finite(a: np.ndarray) -> np.ndarray:
    """``a`` with any non-finite entry replaced by 0 (a last guard; the pipeline should not produce any)."""
    return np.where(np.isfinite(a), a, 0.0)
