"""Per-pixel kernels of Joint-VO-SF (:mod:`simnav.odometry.vosf`), compiled with Numba.

Images are (h, w) float64 arrays indexed ``[v, u]`` (row, column); depth is the optical z in metres, 0 = invalid;
intensity is in [0, 1]. Pixel centres sit at integer coordinates. "Flat" arrays are the row-major ``ravel()`` of an
image, and a pixel list is an array of flat indices. Poses are (4, 4) ``T_b_a`` mapping points of the reference
(current) frame a into the target (previous) frame b. Twists are ``(nu, omega)``, translational part first.

Everything here is a pipeline stage that touches every pixel (pyramid, gradients, K-means, warping with the
residuals (1)–(2) and their Jacobians, IRLS with the Cauchy kernel (5), scene flow); written with numpy these stages
take hundreds of array calls per frame. ``@njit(cache=True)`` compiles on first use, then loads from
``__pycache__``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MASK4 = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
"""Separable 4-tap weights of the 2x downsampling (outer product sums to 1)."""

MODE_RAW, MODE_ROBUST, MODE_REFINE = 0, 1, 2
"""Pre-weighting of :func:`linearize`: none, (6), or (18)–(19)."""


# ----------------------------------------------------------------------------------------------------------------
# Pyramid and gradients


@njit(cache=True)
def downsample(depth: np.ndarray, intensity: np.ndarray, gate_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Halves an RGB-D image without mixing depths across discontinuities.

    Coarse pixel (v, u) is centred on the 2x2 block ``[2v, 2v+1] x [2u, 2u+1]``. Its reference depth is the second
    largest of that block (invalid when fewer than two are valid); the output depth is the ``MASK4`` x ``MASK4``
    weighted mean of the surrounding 4x4 block over the valid depths within ``gate_m`` of the reference, each
    further weighted by ``gate_m - |d - d_ref|``. Intensity is the plain ``MASK4`` x ``MASK4`` mean (gating it too
    makes the coarse intensities of two frames differ where the set of gated neighbours changes with the motion,
    e.g. on far, slanted floors). Taps outside the image are skipped.

    Args:
        depth: (h, w) depth, m, 0 = invalid.
        intensity: (h, w) intensity (any values if unused).
        gate_m: depth-similarity gate, m.

    Returns:
        ``(depth, intensity)`` of shape (h // 2, w // 2).
    """
    h, w = depth.shape
    h2, w2 = h // 2, w // 2
    d_out = np.zeros((h2, w2))
    i_out = np.zeros((h2, w2))
    for v in range(h2):
        for u in range(w2):
            a, b = depth[2 * v, 2 * u], depth[2 * v, 2 * u + 1]
            c, d = depth[2 * v + 1, 2 * u], depth[2 * v + 1, 2 * u + 1]
            hi1, lo1 = max(a, b), min(a, b)
            hi2, lo2 = max(c, d), min(c, d)
            ref = max(lo1, hi2) if hi1 >= hi2 else max(lo2, hi1)  # second largest of the four
            sw = sd = sm = smi = 0.0
            for dv in range(4):
                y = 2 * v - 1 + dv
                if y < 0 or y >= h:
                    continue
                for du in range(4):
                    x = 2 * u - 1 + du
                    if x < 0 or x >= w:
                        continue
                    m = MASK4[dv] * MASK4[du]
                    sm += m
                    smi += m * intensity[y, x]
                    z = depth[y, x]
                    if ref > 0 and z > 0:
                        diff = abs(z - ref)
                        if diff < gate_m:
                            wt = m * (gate_m - diff)
                            sw += wt
                            sd += wt * z
            if ref > 0 and sw > 0:
                d_out[v, u] = sd / sw
            i_out[v, u] = smi / sm
    return d_out, i_out


@njit(cache=True)
def gradients(depth: np.ndarray, intensity: np.ndarray, eps_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                                np.ndarray]:
    """Edge-aware image gradients (per pixel) of depth and intensity at valid-depth pixels.

    Along each axis the forward and backward differences are blended with the weight of each one being the
    *other* one's depth jump plus ``eps_m``, so the side across a depth discontinuity hardly counts; with a single
    valid neighbour its one-sided difference is used, with none the gradient is 0. Intensity uses the same
    (depth-based) weights, so it is not differentiated across depth edges either.

    Args:
        depth: (h, w) depth, m, 0 = invalid.
        intensity: (h, w) intensity.
        eps_m: regulariser of the weights, m.

    Returns:
        ``(dz_du, dz_dv, di_du, di_dv)``, each (h, w), per pixel; 0 at invalid pixels.
    """
    h, w = depth.shape
    gzu, gzv = np.zeros((h, w)), np.zeros((h, w))
    giu, giv = np.zeros((h, w)), np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            z = depth[v, u]
            if z <= 0:
                continue
            for axis in range(2):
                if axis == 0:
                    has_b, has_f = u > 0 and depth[v, u - 1] > 0, u < w - 1 and depth[v, u + 1] > 0
                    zb = depth[v, u - 1] if has_b else 0.0
                    zf = depth[v, u + 1] if has_f else 0.0
                    ib = intensity[v, u - 1] if has_b else 0.0
                    i_f = intensity[v, u + 1] if has_f else 0.0
                else:
                    has_b, has_f = v > 0 and depth[v - 1, u] > 0, v < h - 1 and depth[v + 1, u] > 0
                    zb = depth[v - 1, u] if has_b else 0.0
                    zf = depth[v + 1, u] if has_f else 0.0
                    ib = intensity[v - 1, u] if has_b else 0.0
                    i_f = intensity[v + 1, u] if has_f else 0.0
                gz = gi = 0.0
                if has_b and has_f:
                    wf = abs(z - zb) + eps_m  # weight of the forward difference: the backward jump
                    wb = abs(zf - z) + eps_m
                    gz = (wf * (zf - z) + wb * (z - zb)) / (wf + wb)
                    gi = (wf * (i_f - intensity[v, u]) + wb * (intensity[v, u] - ib)) / (wf + wb)
                elif has_f:
                    gz, gi = zf - z, i_f - intensity[v, u]
                elif has_b:
                    gz, gi = z - zb, intensity[v, u] - ib
                if axis == 0:
                    gzu[v, u], giu[v, u] = gz, gi
                else:
                    gzv[v, u], giv[v, u] = gz, gi
    return gzu, gzv, giu, giv


@njit(cache=True)
def depth_edges(depth: np.ndarray, threshold_m: float) -> np.ndarray:
    """(h, w) bool: valid pixels whose absolute depth differences to their 4 neighbours (an invalid or missing
    neighbour counts as depth 0) sum to ``threshold_m`` or more."""
    h, w = depth.shape
    out = np.zeros((h, w), dtype=np.bool_)
    for v in range(h):
        for u in range(w):
            z = depth[v, u]
            if z <= 0:
                continue
            s = abs((depth[v, u - 1] if u > 0 else 0.0) - z) + abs((depth[v, u + 1] if u < w - 1 else 0.0) - z)
            s += abs((depth[v - 1, u] if v > 0 else 0.0) - z) + abs((depth[v + 1, u] if v < h - 1 else 0.0) - z)
            out[v, u] = s >= threshold_m
    return out


# ----------------------------------------------------------------------------------------------------------------
# Geometric clustering


@njit(cache=True)
def kmeans(points: np.ndarray, centres: np.ndarray, max_iterations: int, tol_m: float) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    """Lloyd's K-means on 3D points from given initial centres (a centre that loses all its points stays put).

    Args:
        points: (n, 3) points, m.
        centres: (k, 3) initial centres, m (not modified).
        max_iterations: most assignment/update rounds.
        tol_m: stop once no centre moves more than this, m.

    Returns:
        ``(centres, labels)``: (k, 3) final centres and (n,) int32 label of every point (its nearest final centre).
    """
    n, k = points.shape[0], centres.shape[0]
    c = centres.copy()
    labels = np.zeros(n, dtype=np.int32)
    for _ in range(max_iterations):
        _nearest(points, c, labels)
        sums = np.zeros((k, 3))
        counts = np.zeros(k)
        for i in range(n):
            lab = labels[i]
            counts[lab] += 1.0
            for j in range(3):
                sums[lab, j] += points[i, j]
        moved = 0.0
        for lab in range(k):
            if counts[lab] > 0:
                shift = 0.0
                for j in range(3):
                    new = sums[lab, j] / counts[lab]
                    shift += (new - c[lab, j]) ** 2
                    c[lab, j] = new
                moved = max(moved, math.sqrt(shift))
        if moved < tol_m:
            break
    _nearest(points, c, labels)
    return c, labels


@njit(cache=True)
def _nearest(points: np.ndarray, centres: np.ndarray, labels: np.ndarray) -> None:
    """Writes the index of the nearest centre of every point into ``labels``."""
    for i in range(points.shape[0]):
        best, best_d = 0, np.inf
        for lab in range(centres.shape[0]):
            d = (points[i, 0] - centres[lab, 0]) ** 2 + (points[i, 1] - centres[lab, 1]) ** 2 \
                + (points[i, 2] - centres[lab, 2]) ** 2
            if d < best_d:
                best, best_d = lab, d
        labels[i] = best


@njit(cache=True)
def assign_labels(x: np.ndarray, y: np.ndarray, z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(h, w) int32 label of the nearest centre of every valid pixel's 3D point, -1 where ``z`` is 0.

    Args:
        x, y, z: (h, w) point coordinates in the optical frame, m (z = 0: invalid).
        centres: (k, 3) cluster centres, m.
    """
    h, w = z.shape
    out = np.full((h, w), -1, dtype=np.int32)
    for v in range(h):
        for u in range(w):
            if z[v, u] <= 0:
                continue
            best, best_d = 0, np.inf
            for lab in range(centres.shape[0]):
                d = (x[v, u] - centres[lab, 0]) ** 2 + (y[v, u] - centres[lab, 1]) ** 2 \
                    + (z[v, u] - centres[lab, 2]) ** 2
                if d < best_d:
                    best, best_d = lab, d
            out[v, u] = best
    return out


@njit(cache=True)
def connectivity(x: np.ndarray, y: np.ndarray, z: np.ndarray, labels: np.ndarray, k: int, gap_m: float,
                 gap_px: float, f_px: float) -> np.ndarray:
    """(k, k) bool graph G: clusters i != j are contiguous when some pair of 4-neighbouring pixels labelled i and
    j has 3D points closer than ``max(gap_m, gap_px * z / f_px)`` (z the nearer depth: ``gap_px`` pixel
    footprints)."""
    h, w = z.shape
    G = np.zeros((k, k), dtype=np.bool_)
    for v in range(h):
        for u in range(w):
            a = labels[v, u]
            if a < 0:
                continue
            for step in range(2):
                v2, u2 = (v, u + 1) if step == 0 else (v + 1, u)
                if v2 >= h or u2 >= w:
                    continue
                b = labels[v2, u2]
                if b < 0 or b == a:
                    continue
                d2 = (x[v, u] - x[v2, u2]) ** 2 + (y[v, u] - y[v2, u2]) ** 2 + (z[v, u] - z[v2, u2]) ** 2
                gap = max(gap_m, gap_px * min(z[v, u], z[v2, u2]) / f_px)
                if d2 < gap * gap:
                    G[a, b] = True
                    G[b, a] = True
    return G


# ----------------------------------------------------------------------------------------------------------------
# Warping, residuals and IRLS


@njit(cache=True)
def linearize(idx: np.ndarray, x1: np.ndarray, y1: np.ndarray, z1: np.ndarray, i1: np.ndarray,
              gz1_sq: np.ndarray, gi1_sq: np.ndarray, g1: np.ndarray, symmetric: bool, scale: np.ndarray,
              T: np.ndarray, cam: np.ndarray, z2: np.ndarray, i2: np.ndarray, gzu2: np.ndarray, gzv2: np.ndarray,
              giu2: np.ndarray, giv2: np.ndarray, b2: np.ndarray, use_photo: bool, gate_m: float, mode: int,
              alpha: float, kz: float, ki: float, r: np.ndarray, J: np.ndarray, ok: np.ndarray,
              b_warped: np.ndarray) -> None:
    """Warps reference pixels into the target image and linearises the residuals (1)–(2) for ``exp(delta) @ T``.

    For pixel x with point p: ``p' = T p``, ``W(x) = pi(p')``, ``r_Z = Z2(W) - p'_z`` and ``r_I = I2(W) - I1(x)``;
    the rows of ``J`` are their derivatives with respect to a twist ``delta`` applied on the left,
    ``[g, p' x g]`` with ``g`` the chain of the image gradient and the projection; the image gradient is the
    target's sampled at ``W`` or, with ``symmetric``, the mean of that and the reference's at x (ESM-like). Target
    values are sampled bilinearly when the 2x2 depths are all valid and span less than ``gate_m``, else from the
    nearest pixel (if valid). Both residuals (and rows) are multiplied by a pre-weight:

    * ``MODE_RAW``: 1 (residuals only);
    * ``MODE_ROBUST`` (6): ``Z1 (1 - B^T)``, ``B^T`` the target's moving-probability sampled at ``W``;
    * ``MODE_REFINE`` (18)–(19): ``scale * sqrt(K / (K + |grad|^2 + r^2))`` with ``K = kz`` (depth) or ``ki``
      (intensity), i.e. the square roots of the paper's weights normalised to 1 on smooth, aligned pixels.

    The photometric row is further multiplied by ``alpha``; without ``use_photo`` it is zero.

    Args:
        idx: (n,) flat indices of the reference pixels.
        x1, y1, z1, i1: flat reference point coordinates (m) and intensity.
        gz1_sq, gi1_sq: flat squared gradient norms of the reference depth and intensity (per pixel).
        g1: (4, h1 * w1) flat reference gradients ``dz/du, dz/dv, di/du, di/dv`` (used with ``symmetric``).
        symmetric: average the reference and target gradients.
        scale: (n,) extra factor per listed pixel (``MODE_REFINE``).
        T: (4, 4) current pose of the reference frame in the target frame.
        cam: (4,) target-level intrinsics ``fx, fy, cx, cy``, pixels.
        z2, i2, gzu2, gzv2, giu2, giv2: (h, w) target depth, intensity and their gradients.
        b2: (h, w) target moving-probability (zeros when none).
        use_photo: whether the photometric residual is used.
        gate_m: bilinear/nearest switch on the 2x2 depth span, m.
        mode: pre-weighting, see above.
        alpha: ``alpha_I``.
        kz, ki: ``K_Z`` and ``K_I`` of (18)–(19).
        r: (n, 2) out: weighted residuals (geometric, photometric).
        J: (n, 2, 6) out: weighted Jacobian rows.
        ok: (n,) out: whether the pixel warped to a valid target sample (and has a non-zero weight).
        b_warped: (n,) out: the target moving-probability at the warp (0 where not ok).
    """
    h, w = z2.shape
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    for k in range(idx.shape[0]):
        q = idx[k]
        ok[k] = False
        b_warped[k] = 0.0
        px = T[0, 0] * x1[q] + T[0, 1] * y1[q] + T[0, 2] * z1[q] + T[0, 3]
        py = T[1, 0] * x1[q] + T[1, 1] * y1[q] + T[1, 2] * z1[q] + T[1, 3]
        pz = T[2, 0] * x1[q] + T[2, 1] * y1[q] + T[2, 2] * z1[q] + T[2, 3]
        if pz <= 1e-3:
            continue
        u = fx * px / pz + cx
        v = fy * py / pz + cy
        if not (u >= 0.0 and u <= w - 1 and v >= 0.0 and v <= h - 1):
            continue
        u0 = min(int(u), w - 2) if w > 1 else 0
        v0 = min(int(v), h - 2) if h > 1 else 0
        a, c = u - u0, v - v0
        u1, v1 = min(u0 + 1, w - 1), min(v0 + 1, h - 1)
        d00, d01, d10, d11 = z2[v0, u0], z2[v0, u1], z2[v1, u0], z2[v1, u1]
        lo = min(min(d00, d01), min(d10, d11))
        hi = max(max(d00, d01), max(d10, d11))
        if lo > 0 and hi - lo < gate_m:
            w00, w01, w10, w11 = (1 - a) * (1 - c), a * (1 - c), (1 - a) * c, a * c
            zs = w00 * d00 + w01 * d01 + w10 * d10 + w11 * d11
            i_s = w00 * i2[v0, u0] + w01 * i2[v0, u1] + w10 * i2[v1, u0] + w11 * i2[v1, u1]
            zu = w00 * gzu2[v0, u0] + w01 * gzu2[v0, u1] + w10 * gzu2[v1, u0] + w11 * gzu2[v1, u1]
            zv = w00 * gzv2[v0, u0] + w01 * gzv2[v0, u1] + w10 * gzv2[v1, u0] + w11 * gzv2[v1, u1]
            iu = w00 * giu2[v0, u0] + w01 * giu2[v0, u1] + w10 * giu2[v1, u0] + w11 * giu2[v1, u1]
            iv = w00 * giv2[v0, u0] + w01 * giv2[v0, u1] + w10 * giv2[v1, u0] + w11 * giv2[v1, u1]
            bs = w00 * b2[v0, u0] + w01 * b2[v0, u1] + w10 * b2[v1, u0] + w11 * b2[v1, u1]
        else:
            un, vn = int(u + 0.5), int(v + 0.5)
            zs = z2[vn, un]
            if zs <= 0:
                continue
            i_s, zu, zv = i2[vn, un], gzu2[vn, un], gzv2[vn, un]
            iu, iv, bs = giu2[vn, un], giv2[vn, un], b2[vn, un]
        if symmetric:  # gradients of the mean of the two images (ESM-like)
            zu = 0.5 * (zu + g1[0, q])
            zv = 0.5 * (zv + g1[1, q])
            iu = 0.5 * (iu + g1[2, q])
            iv = 0.5 * (iv + g1[3, q])
        rz = zs - pz
        ri = i_s - i1[q] if use_photo else 0.0
        # Pre-weights of the two residuals.
        if mode == MODE_ROBUST:
            mz = z1[q] * (1.0 - bs)
            mi = alpha * mz
        elif mode == MODE_REFINE:
            mz = scale[k] * math.sqrt(kz / (kz + gz1_sq[q] + rz * rz))
            mi = alpha * scale[k] * math.sqrt(ki / (ki + gi1_sq[q] + ri * ri))
        else:
            mz, mi = 1.0, 1.0
        if not use_photo:
            mi = 0.0
        if mz <= 0.0:
            continue
        ok[k] = True
        b_warped[k] = bs
        r[k, 0] = mz * rz
        r[k, 1] = mi * ri
        # d(r_Z)/d(p') and d(r_I)/d(p') through the projection, then [g, p' x g] for the left twist.
        inv_z = 1.0 / pz
        gx = zu * fx * inv_z
        gy = zv * fy * inv_z
        gz = -(gx * px + gy * py) * inv_z - 1.0
        _jacobian_row(J, k, 0, mz, gx, gy, gz, px, py, pz)
        gx = iu * fx * inv_z
        gy = iv * fy * inv_z
        gz = -(gx * px + gy * py) * inv_z
        _jacobian_row(J, k, 1, mi, gx, gy, gz, px, py, pz)


@njit(cache=True)
def _jacobian_row(J: np.ndarray, k: int, row: int, m: float, gx: float, gy: float, gz: float, px: float,
                  py: float, pz: float) -> None:
    """Writes ``m * [g, p x g]`` into ``J[k, row]``."""
    J[k, row, 0] = m * gx
    J[k, row, 1] = m * gy
    J[k, row, 2] = m * gz
    J[k, row, 3] = m * (py * gz - pz * gy)
    J[k, row, 4] = m * (pz * gx - px * gz)
    J[k, row, 5] = m * (px * gy - py * gx)


@njit(cache=True)
def irls_cauchy(r: np.ndarray, J: np.ndarray, ok: np.ndarray, rows: int, c_factor: float, max_iterations: int,
                chi2_ratio: float, delta_tol: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Minimises ``sum F(r + J delta)`` with the Cauchy penalty (5) by iteratively reweighted least squares.

    Every iteration takes ``c = c_factor * mean |e|`` of the current residuals ``e = r + J delta`` (20), the
    weights ``1 / (1 + (e / c)^2)`` and solves the weighted normal equations for ``delta``; it stops when the
    weighted cost falls by less than ``1 - chi2_ratio`` or ``delta`` changes by less than ``delta_tol`` (max norm).

    Args:
        r: (n, 2) residuals; J: (n, 2, 6) Jacobian rows; ok: (n,) usable pixels.
        rows: residuals used per pixel: 1 (geometric only) or 2.
        c_factor: Cauchy scale relative to the mean absolute residual.
        max_iterations: most reweighted solves (at least one is made).
        chi2_ratio, delta_tol: stopping rules.

    Returns:
        ``(delta, H, s2, m)``: (6,) twist, (6, 6) weighted normal matrix of the last solve, weighted residual
        variance ``sum w e^2 / (m - 6)`` of the last solve, and the number of residuals m (0 = nothing to
        solve; delta is then 0).
    """
    n = r.shape[0]
    delta = np.zeros(6)
    H = np.zeros((6, 6))
    e = np.zeros((n, 2))
    last_chi2 = np.inf
    s2 = 0.0
    m = 0
    for k in range(n):
        if ok[k]:
            m += rows
    if m < 6:
        return delta, H, 0.0, 0
    for it in range(max(1, max_iterations)):
        # Residuals at the current twist and the Cauchy scale.
        d0, d1, d2, d3, d4, d5 = delta[0], delta[1], delta[2], delta[3], delta[4], delta[5]
        total = 0.0
        for k in range(n):
            if not ok[k]:
                continue
            for j in range(rows):
                ek = r[k, j]
                if it > 0:
                    ek += J[k, j, 0] * d0 + J[k, j, 1] * d1 + J[k, j, 2] * d2 + J[k, j, 3] * d3 \
                        + J[k, j, 4] * d4 + J[k, j, 5] * d5
                e[k, j] = ek
                total += abs(ek)
        inv_c2 = 1.0 / ((c_factor * total / m) ** 2 + 1e-30)
        # Weighted normal equations of the full twist (upper triangle in scalars).
        h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = 0.0
        h22 = h23 = h24 = h25 = h33 = h34 = h35 = h44 = h45 = h55 = 0.0
        g0 = g1 = g2 = g3 = g4 = g5 = 0.0
        chi2 = 0.0
        for k in range(n):
            if not ok[k]:
                continue
            for j in range(rows):
                ek = e[k, j]
                wt = 1.0 / (1.0 + ek * ek * inv_c2)
                chi2 += wt * ek * ek
                j0, j1, j2, j3, j4, j5 = J[k, j, 0], J[k, j, 1], J[k, j, 2], J[k, j, 3], J[k, j, 4], J[k, j, 5]
                w0, w1, w2, w3, w4, w5 = wt * j0, wt * j1, wt * j2, wt * j3, wt * j4, wt * j5
                rk = r[k, j]
                g0 += w0 * rk
                g1 += w1 * rk
                g2 += w2 * rk
                g3 += w3 * rk
                g4 += w4 * rk
                g5 += w5 * rk
                h00 += w0 * j0
                h01 += w0 * j1
                h02 += w0 * j2
                h03 += w0 * j3
                h04 += w0 * j4
                h05 += w0 * j5
                h11 += w1 * j1
                h12 += w1 * j2
                h13 += w1 * j3
                h14 += w1 * j4
                h15 += w1 * j5
                h22 += w2 * j2
                h23 += w2 * j3
                h24 += w2 * j4
                h25 += w2 * j5
                h33 += w3 * j3
                h34 += w3 * j4
                h35 += w3 * j5
                h44 += w4 * j4
                h45 += w4 * j5
                h55 += w5 * j5
        H = np.array([[h00, h01, h02, h03, h04, h05], [h01, h11, h12, h13, h14, h15],
                      [h02, h12, h22, h23, h24, h25], [h03, h13, h23, h33, h34, h35],
                      [h04, h14, h24, h34, h44, h45], [h05, h15, h25, h35, h45, h55]])
        g = np.array([g0, g1, g2, g3, g4, g5])
        s2 = chi2 / max(m - 6, 1)
        damp = 1e-9 * (np.trace(H) / 6.0) + 1e-15
        new = np.linalg.solve(H + damp * np.eye(6), -g)
        change = np.max(np.abs(new - delta))
        delta = new
        if chi2 > chi2_ratio * last_chi2 or change < delta_tol:
            break
        last_chi2 = chi2
    return delta, H, s2, m


@njit(cache=True)
def exp_compose(delta: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(4, 4) ``exp(delta) @ T`` for a twist ``delta = (nu, omega)``: the update of every Gauss-Newton step.

    Same map as :func:`simnav.geometry.se3.exp` (Rodrigues with the SO(3) left Jacobian, Taylor series below
    1e-4 rad), compiled because it runs dozens of times per frame.
    """
    wx, wy, wz = delta[3], delta[4], delta[5]
    th2 = wx * wx + wy * wy + wz * wz
    th = math.sqrt(th2)
    if th < 1e-4:
        a, b, c = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        a, b, c = math.sin(th) / th, (1.0 - math.cos(th)) / th2, (th - math.sin(th)) / (th2 * th)
    K = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    K2 = K @ K
    E = np.eye(4)
    E[:3, :3] = np.eye(3) + a * K + b * K2
    E[:3, 3] = (np.eye(3) + b * K + c * K2) @ delta[:3]
    return E @ T


# ----------------------------------------------------------------------------------------------------------------
# Scene flow


@njit(cache=True)
def scene_flow(x: np.ndarray, y: np.ndarray, z: np.ndarray, labels: np.ndarray, motions: np.ndarray,
               centres: np.ndarray, G: np.ndarray, sharpness_per_m: float, cutoff: float) -> np.ndarray:
    """Per-pixel 3D flow from per-cluster rigid motions, blended across contiguous cluster boundaries.

    Cluster l moves a point p by ``p - M_l p``, where the (4, 4) ``M_l`` maps the point to where it was at the
    previous frame; a pixel of cluster l takes the weighted mean of that flow over its own cluster and the
    clusters contiguous to it (``G``), with weights
    ``exp(-sharpness * (d_j - d_l))``, d the distance of p to each centre, dropped beyond ``cutoff``.

    Args:
        x, y, z: (h, w) points, m (z = 0: invalid).
        labels: (h, w) cluster of each pixel (-1 = invalid).
        motions: (k, 4, 4) per-cluster ``M`` (identity = no motion).
        centres: (k, 3) cluster centres, m.
        G: (k, k) contiguity graph.
        sharpness_per_m: blending sharpness, 1/m.
        cutoff: largest exponent kept.

    Returns:
        (3, h, w) float32 flow, m; NaN at invalid pixels.
    """
    h, w = z.shape
    k = centres.shape[0]
    out = np.full((3, h, w), np.nan, dtype=np.float32)
    for v in range(h):
        for u in range(w):
            lab = labels[v, u]
            if lab < 0:
                continue
            p0, p1, p2 = x[v, u], y[v, u], z[v, u]
            d_own = math.sqrt((p0 - centres[lab, 0]) ** 2 + (p1 - centres[lab, 1]) ** 2 + (p2 - centres[lab, 2]) ** 2)
            f0 = f1 = f2 = wsum = 0.0
            for j in range(k):
                if j != lab and not G[lab, j]:
                    continue
                wt = 1.0
                if j != lab:
                    dj = math.sqrt((p0 - centres[j, 0]) ** 2 + (p1 - centres[j, 1]) ** 2 + (p2 - centres[j, 2]) ** 2)
                    expo = sharpness_per_m * (dj - d_own)
                    if expo > cutoff:
                        continue
                    wt = math.exp(-expo)
                M = motions[j]
                f0 += wt * (p0 - M[0, 0] * p0 - M[0, 1] * p1 - M[0, 2] * p2 - M[0, 3])
                f1 += wt * (p1 - M[1, 0] * p0 - M[1, 1] * p1 - M[1, 2] * p2 - M[1, 3])
                f2 += wt * (p2 - M[2, 0] * p0 - M[2, 1] * p1 - M[2, 2] * p2 - M[2, 3])
                wsum += wt
            out[0, v, u] = f0 / wsum
            out[1, v, u] = f1 / wsum
            out[2, v, u] = f2 / wsum
    return out
