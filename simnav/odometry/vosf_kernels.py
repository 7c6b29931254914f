"""Per-pixel kernels of Joint-VO-SF (:mod:`simnav.odometry.vosf`), compiled with Numba.

Images are (h, w) float64 arrays indexed ``[v, u]`` (row, column); depth is the optical z in metres, 0 = invalid;
intensity is in [0, 1]. Pixel centres sit at integer coordinates. "Flat" arrays are the row-major ``ravel()`` of an
image, and a pixel list is an array of flat indices. Poses are (4, 4) ``T_b_a`` mapping points of the reference
(current) frame a into the target (previous) frame b. Twists are ``(nu, omega)``, translational part first.

A pyramid level keeps its per-pixel data in one (h, w, ``PACK``) "pack" (channels ``C_Z``, ``C_I``, ``C_ZU``,
``C_ZV``, ``C_IU``, ``C_IV``, ``C_B``: depth, intensity, their gradients along u and v, moving probability): a
bilinear sample of all of them reads 4 neighbouring 64-byte rows instead of 28 scattered values.

Everything here is a pipeline stage that touches every pixel (pyramid, gradients, K-means, warping with the
residuals (1)–(2) and their Jacobians, IRLS with the Cauchy kernel (5), per-cluster residuals (7), scene flow).
Loops over at least ``PARALLEL_MIN`` (``PARALLEL_MIN_WARPS``) pixels run on Numba's threads (``NUMBA_NUM_THREADS`` or
:func:`numba.set_num_threads`; a ``_par`` driver with ``prange`` next to each kernel), shorter ones on the calling
thread. Sums are taken per block of ``BLOCK`` pixels and the blocks added in order, so the results do not depend on
the number of threads. Importing this module sets ``OMP_WAIT_POLICY=passive`` unless it is set; it takes effect if
Numba has not started its OpenMP threads yet (first parallel loop or ``numba.get_num_threads()``): idle threads then
sleep instead of spinning, and a sleeping thread gets its core back at once when another process runs there. With
spinning threads, a core shared with another busy process made a QVGA frame 3 to 8 times slower than on one thread.
Every kernel compiles with NumPy's error model (``error_model="numpy"``: no check before each division, where the
kernels guard their divisions themselves), which made a QVGA frame 6 % faster (``python scripts/bench_odometry_ab.py
REV --method vosf --threads 2``, same poses to the bit). ``@njit`` with ``cache=True`` compiles on first use, then
loads from ``__pycache__``.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numba import njit, prange

os.environ.setdefault("OMP_WAIT_POLICY", "passive")  # read when Numba's OpenMP threads start

MASK4 = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
"""Separable 4-tap weights of the 2x downsampling (outer product sums to 1)."""

MODE_ROBUST, MODE_REFINE = 1, 2
"""Pre-weighting of :func:`linearize`: (6) or (18)–(19)."""

PACK = 8
C_Z, C_I, C_ZU, C_ZV, C_IU, C_IV, C_B = range(7)
"""Channels of a level pack (the eighth pads a pixel to 64 bytes)."""

BLOCK = 512
"""Pixels per partial sum of the reductions (fixed, so any thread count gives the same numbers)."""

PARALLEL_MIN = 32768
"""Loops over fewer pixels run on the calling thread alone: waking the other threads would cost more than they save
(more so on a loaded machine)."""

PARALLEL_MIN_WARPS = 8192
"""The same for the warping kernels (:func:`linearize`, :func:`cluster_residuals`), about 10x slower per pixel, and
for the nearest-centre search of :func:`kmeans` (24 centres per point)."""

_N_NORMAL = 28  # 21 upper-triangle entries of H, 6 of the gradient, chi^2
_UPPER = np.array([[0, 1, 2, 3, 4, 5], [1, 6, 7, 8, 9, 10], [2, 7, 11, 12, 13, 14], [3, 8, 12, 15, 16, 17],
                   [4, 9, 13, 16, 18, 19], [5, 10, 14, 17, 19, 20]])
"""Index of H[a, b] among the 21 upper-triangle sums of :func:`_normal_block`."""


# ----------------------------------------------------------------------------------------------------------------
# Pyramid and gradients


@njit(cache=True, error_model="numpy")
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
    d_out = np.zeros((depth.shape[0] // 2, depth.shape[1] // 2))
    i_out = np.zeros_like(d_out)
    if depth.size >= PARALLEL_MIN:
        _downsample_par(depth, intensity, gate_m, d_out, i_out)
    else:
        for v in range(d_out.shape[0]):
            _downsample_row(depth, intensity, gate_m, v, d_out, i_out)
    return d_out, i_out


@njit(cache=True, error_model="numpy", parallel=True)
def _downsample_par(depth: np.ndarray, intensity: np.ndarray, gate_m: float, d_out: np.ndarray,
                    i_out: np.ndarray) -> None:
    for v in prange(d_out.shape[0]):
        _downsample_row(depth, intensity, gate_m, v, d_out, i_out)


@njit(cache=True, error_model="numpy")
def _downsample_row(depth: np.ndarray, intensity: np.ndarray, gate_m: float, v: int, d_out: np.ndarray,
                    i_out: np.ndarray) -> None:
    """Row v of :func:`downsample` into ``d_out``, ``i_out``."""
    h, w = depth.shape
    for u in range(d_out.shape[1]):
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


@njit(cache=True, error_model="numpy")
def level_pack(depth: np.ndarray, intensity: np.ndarray, eps_m: float) -> np.ndarray:
    """(h, w, ``PACK``) pack of a level: depth, intensity, their edge-aware gradients (:func:`_gradient`) at
    valid-depth pixels (0 elsewhere) and a zero moving probability.

    Args:
        depth: (h, w) depth, m, 0 = invalid.
        intensity: (h, w) intensity.
        eps_m: regulariser of the gradient weights, m.
    """
    out = np.zeros((depth.shape[0], depth.shape[1], PACK))
    if depth.size >= PARALLEL_MIN:
        _level_pack_par(depth, intensity, eps_m, out)
    else:
        for v in range(depth.shape[0]):
            _level_pack_row(depth, intensity, eps_m, v, out)
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def _level_pack_par(depth: np.ndarray, intensity: np.ndarray, eps_m: float, out: np.ndarray) -> None:
    for v in prange(depth.shape[0]):
        _level_pack_row(depth, intensity, eps_m, v, out)


@njit(cache=True, error_model="numpy")
def _level_pack_row(depth: np.ndarray, intensity: np.ndarray, eps_m: float, v: int, out: np.ndarray) -> None:
    """Row v of :func:`level_pack` into ``out``."""
    for u in range(depth.shape[1]):
        out[v, u, C_Z] = depth[v, u]
        out[v, u, C_I] = intensity[v, u]
        if depth[v, u] > 0:
            out[v, u, C_ZU], out[v, u, C_IU] = _gradient(depth, intensity, v, u, 0, 1, eps_m)
            out[v, u, C_ZV], out[v, u, C_IV] = _gradient(depth, intensity, v, u, 1, 0, eps_m)


@njit(cache=True, error_model="numpy")
def _gradient(depth: np.ndarray, intensity: np.ndarray, v: int, u: int, dv: int, du: int,
              eps_m: float) -> tuple[float, float]:
    """Edge-aware ``(dz, di)`` per pixel at valid pixel (v, u) along the step (dv, du).

    The forward and backward differences are blended with the weight of each one being the *other* one's depth
    jump plus ``eps_m``, so the side across a depth discontinuity hardly counts; with a single valid neighbour its
    one-sided difference is used, with none the gradient is 0. Intensity uses the same (depth-based) weights, so it
    is not differentiated across depth edges either.
    """
    h, w = depth.shape
    z, i0 = depth[v, u], intensity[v, u]
    vb, ub, vf, uf = v - dv, u - du, v + dv, u + du
    has_b = vb >= 0 and ub >= 0 and depth[vb, ub] > 0
    has_f = vf < h and uf < w and depth[vf, uf] > 0
    zb = depth[vb, ub] if has_b else 0.0
    zf = depth[vf, uf] if has_f else 0.0
    ib = intensity[vb, ub] if has_b else 0.0
    i_f = intensity[vf, uf] if has_f else 0.0
    if has_b and has_f:
        wf = abs(z - zb) + eps_m  # weight of the forward difference: the backward jump
        wb = abs(zf - z) + eps_m
        return (wf * (zf - z) + wb * (z - zb)) / (wf + wb), (wf * (i_f - i0) + wb * (i0 - ib)) / (wf + wb)
    if has_f:
        return zf - z, i_f - i0
    if has_b:
        return z - zb, i0 - ib
    return 0.0, 0.0


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def set_moving(pack: np.ndarray, labels: np.ndarray, b: np.ndarray) -> None:
    """Writes the moving probability ``b`` (k,) of every pixel's cluster into channel ``C_B`` of a (h, w, ``PACK``)
    pack (0 where ``labels`` (h, w) is -1)."""
    h, w = labels.shape
    for v in range(h):
        for u in range(w):
            pack[v, u, C_B] = b[labels[v, u]] if labels[v, u] >= 0 else 0.0


# ----------------------------------------------------------------------------------------------------------------
# Geometric clustering


@njit(cache=True, error_model="numpy")
def cell_medians(depth: np.ndarray, u_edges: np.ndarray, v_edges: np.ndarray) -> np.ndarray:
    """(rows * cols) median valid depth of each cell ``[v_edges[r], v_edges[r + 1]) x [u_edges[c], u_edges[c + 1])``
    of an image grid, row-major; NaN for a cell without valid depth."""
    rows, cols = v_edges.shape[0] - 1, u_edges.shape[0] - 1
    out = np.full(rows * cols, np.nan)
    valid = np.empty(depth.size)
    for r in range(rows):
        for c in range(cols):
            n = 0
            for v in range(v_edges[r], v_edges[r + 1]):
                for u in range(u_edges[c], u_edges[c + 1]):
                    if depth[v, u] > 0:
                        valid[n] = depth[v, u]
                        n += 1
            if n > 0:
                out[r * cols + c] = np.median(valid[:n])
    return out


BOUND_MARGIN_M = 1e-9
"""A point keeps its K-means centre without a search only if its bounds prove it nearer than any other by this
much, m (far more than the rounding of the bounds, so the labels are exactly Lloyd's)."""


@njit(cache=True, error_model="numpy")
def kmeans(points: np.ndarray, centres: np.ndarray, max_iterations: int, tol_m: float) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    """Lloyd's K-means on 3D points from given initial centres (a centre that loses all its points stays put).

    Each round assigns every point to its nearest centre, then moves every centre to the mean of its points; the
    assignments after the first skip the points whose Hamerly bounds (an upper bound on the distance to their centre,
    a lower bound on the distance to any other, both carried across rounds by how far the centres moved) prove their
    centre still nearest by ``BOUND_MARGIN_M``: the same labels and centres as a full search every round, with
    a fraction of the distances (a QVGA frame 0.94x as long on 2 cores: ``python
    scripts/bench_odometry_ab.py REV --method vosf --threads 2``).

    Args:
        points: (n, 3) points, m.
        centres: (k, 3) initial centres, m (not modified).
        max_iterations: most assignment/update rounds.
        tol_m: stop once no centre moves more than this, m.

    Returns:
        ``(centres, labels)``: (k, 3) final centres and (n,) int32 label of every point (its nearest final centre;
        the lowest index among equally near ones).
    """
    n, k = points.shape[0], centres.shape[0]
    px, py, pz = points[:, 0].copy(), points[:, 1].copy(), points[:, 2].copy()
    c = centres.copy()
    labels = np.zeros(n, dtype=np.int32)
    upper, lower = np.empty(n), np.empty(n)
    shift, half = np.zeros(k), np.zeros(k)
    _nearest(px, py, pz, c, labels, upper, lower, shift, half, True)
    for _ in range(max_iterations):
        # Every centre to the mean of its points, and how far it moved.
        sums = np.zeros((k, 3))
        counts = np.zeros(k)
        for i in range(n):
            lab = labels[i]
            counts[lab] += 1.0
            for j in range(3):
                sums[lab, j] += points[i, j]
        moved = 0.0
        for lab in range(k):
            shift[lab] = 0.0
            if counts[lab] > 0:
                s2 = 0.0
                for j in range(3):
                    new = sums[lab, j] / counts[lab]
                    s2 += (new - c[lab, j]) ** 2
                    c[lab, j] = new
                shift[lab] = math.sqrt(s2)
                moved = max(moved, shift[lab])
        # Nearest centres again (the last round's are the output).
        _half_gaps(c, half)
        _nearest(px, py, pz, c, labels, upper, lower, shift, half, False)
        if moved < tol_m:
            break
    return c, labels


@njit(cache=True, error_model="numpy")
def farthest_points(points: np.ndarray, centres: np.ndarray, count: int) -> np.ndarray:
    """``count`` new K-means centres picked one after the other among the points, each the point farthest from the
    given centres and the ones picked before it (the first such point on a tie).

    Args:
        points: (n >= 1, 3) points, m.
        centres: (k >= 1, 3) centres so far, m.
        count: how many to pick.

    Returns:
        (count, 3) picked points, m.
    """
    n, k = points.shape[0], centres.shape[0]
    nearest = np.full(n, np.inf)  # squared distance of every point to its nearest centre so far
    for i in range(n):
        for j in range(k):
            nearest[i] = min(nearest[i], _sq_dist(points, i, centres, j))
    out = np.empty((count, 3))
    for c in range(count):
        best = int(np.argmax(nearest))
        for a in range(3):
            out[c, a] = points[best, a]
        for i in range(n):
            nearest[i] = min(nearest[i], _sq_dist(points, i, out, c))
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _sq_dist(a: np.ndarray, i: int, b: np.ndarray, j: int) -> float:
    """Squared distance between the 3D rows ``a[i]`` and ``b[j]``, m^2."""
    dx, dy, dz = a[i, 0] - b[j, 0], a[i, 1] - b[j, 1], a[i, 2] - b[j, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, error_model="numpy")
def _half_gaps(c: np.ndarray, half: np.ndarray) -> None:
    """``half[a]``: half the distance from centre a to the nearest other centre (a point closer than that to its
    centre is nearest to it), m."""
    k = c.shape[0]
    for a in range(k):
        best = np.inf
        for b in range(k):
            if b != a:
                best = min(best, (c[a, 0] - c[b, 0]) ** 2 + (c[a, 1] - c[b, 1]) ** 2 + (c[a, 2] - c[b, 2]) ** 2)
        half[a] = 0.5 * math.sqrt(best)


@njit(cache=True, error_model="numpy")
def _nearest(px: np.ndarray, py: np.ndarray, pz: np.ndarray, c: np.ndarray, labels: np.ndarray, upper: np.ndarray,
             lower: np.ndarray, shift: np.ndarray, half: np.ndarray, full: bool) -> None:
    """Nearest centre of every point (coordinates (n,) each) into ``labels``, with the bounds ``upper``, ``lower``
    (m) of :func:`kmeans`; ``full``: search every point (the bounds are set), else update the bounds by the centres'
    ``shift`` (m) and search only where they do not settle it (``half``: :func:`_half_gaps`)."""
    n = px.shape[0]
    # A point's lower bound falls by the largest shift of the centres other than its own.
    first, second, arg = 0.0, 0.0, -1
    for j in range(shift.shape[0]):
        if shift[j] > first:
            first, second, arg = shift[j], first, j
        elif shift[j] > second:
            second = shift[j]
    drops = (first, second, arg)
    if n >= PARALLEL_MIN_WARPS:
        _nearest_par(px, py, pz, c, labels, upper, lower, shift, half, full, drops)
    else:
        for blk in range((n + BLOCK - 1) // BLOCK):
            _nearest_bounded(blk * BLOCK, min(n, (blk + 1) * BLOCK), px, py, pz, c, labels, upper, lower, shift, half,
                             full, drops)


@njit(cache=True, error_model="numpy", parallel=True)
def _nearest_par(px: np.ndarray, py: np.ndarray, pz: np.ndarray, c: np.ndarray, labels: np.ndarray,
                 upper: np.ndarray, lower: np.ndarray, shift: np.ndarray, half: np.ndarray, full: bool,
                 drops: tuple) -> None:
    n = px.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        _nearest_bounded(blk * BLOCK, min(n, (blk + 1) * BLOCK), px, py, pz, c, labels, upper, lower, shift, half,
                         full, drops)


@njit(cache=True, error_model="numpy")
def _nearest_bounded(lo: int, hi: int, px: np.ndarray, py: np.ndarray, pz: np.ndarray, c: np.ndarray,
                     labels: np.ndarray, upper: np.ndarray, lower: np.ndarray, shift: np.ndarray, half: np.ndarray,
                     full: bool, drops: tuple) -> None:
    """Points ``lo:hi`` of :func:`_nearest` (``drops``: the largest shift, the second largest, the index of the
    centre with the largest)."""
    first, second, arg = drops
    k = c.shape[0]
    cx, cy, cz = c[:, 0].copy(), c[:, 1].copy(), c[:, 2].copy()
    for i in range(lo, hi):
        x, y, z = px[i], py[i], pz[i]
        if not full:
            a = labels[i]
            upper[i] += shift[a]
            lower[i] -= second if a == arg else first
            bound = max(half[a], lower[i]) - BOUND_MARGIN_M
            if upper[i] < bound:
                continue
            upper[i] = math.sqrt((x - cx[a]) ** 2 + (y - cy[a]) ** 2 + (z - cz[a]) ** 2)
            if upper[i] < bound:
                continue
        best, best2, nearest = np.inf, np.inf, 0
        for lab in range(k):
            d = (x - cx[lab]) ** 2 + (y - cy[lab]) ** 2 + (z - cz[lab]) ** 2
            if d < best:
                best, best2, nearest = d, best, lab
            elif d < best2:
                best2 = d
        labels[i] = nearest
        upper[i] = math.sqrt(best)
        lower[i] = math.sqrt(best2)


@njit(cache=True, error_model="numpy")
def _nearest_run(px: np.ndarray, py: np.ndarray, pz: np.ndarray, centres: np.ndarray, labels: np.ndarray) -> None:
    """Nearest centre of each point of a contiguous run (:func:`assign_labels`), point by point with the nearest so
    far in registers (0.7x the time of a centre-by-centre pass over the run); the lowest index wins a tie."""
    k = centres.shape[0]
    cx, cy, cz = centres[:, 0].copy(), centres[:, 1].copy(), centres[:, 2].copy()
    for i in range(px.shape[0]):
        x, y, z = px[i], py[i], pz[i]
        best, nearest = np.inf, 0
        for lab in range(k):
            d = (x - cx[lab]) ** 2 + (y - cy[lab]) ** 2 + (z - cz[lab]) ** 2
            if d < best:
                best, nearest = d, lab
        labels[i] = nearest


@njit(cache=True, error_model="numpy")
def assign_labels(x: np.ndarray, y: np.ndarray, z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(h, w) int32 label of the nearest centre of every valid pixel's 3D point, -1 where ``z`` is 0.

    Args:
        x, y, z: (h, w) point coordinates in the optical frame, m (z = 0: invalid).
        centres: (k, 3) cluster centres, m.
    """
    out = np.empty(z.shape, dtype=np.int32)
    if z.size >= PARALLEL_MIN:
        _assign_labels_par(x, y, z, centres, out)
    else:
        for v in range(z.shape[0]):
            _assign_labels_row(x, y, z, centres, v, out)
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def _assign_labels_par(x: np.ndarray, y: np.ndarray, z: np.ndarray, centres: np.ndarray, out: np.ndarray) -> None:
    for v in prange(z.shape[0]):
        _assign_labels_row(x, y, z, centres, v, out)


@njit(cache=True, error_model="numpy")
def _assign_labels_row(x: np.ndarray, y: np.ndarray, z: np.ndarray, centres: np.ndarray, v: int,
                       out: np.ndarray) -> None:
    """Row v of :func:`assign_labels` into ``out``."""
    _nearest_run(x[v], y[v], z[v], centres, out[v])
    for u in range(z.shape[1]):
        if z[v, u] <= 0:
            out[v, u] = -1


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def label_order(labels: np.ndarray, idx: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The listed pixels grouped by cluster: ``order[offsets[l]:offsets[l + 1]]`` are the flat indices (from
    ``idx``, in its order) whose label in the flat ``labels`` is l (stable counting sort; (n,) and (k + 1,))."""
    offsets = np.zeros(k + 1, dtype=np.int64)
    for q in idx:
        offsets[labels[q] + 1] += 1
    for lab in range(k):
        offsets[lab + 1] += offsets[lab]
    fill = offsets[:k].copy()
    order = np.empty(idx.shape[0], dtype=np.int64)
    for q in idx:
        order[fill[labels[q]]] = q
        fill[labels[q]] += 1
    return order, offsets


@njit(cache=True, error_model="numpy")
def background_pixels(labels: np.ndarray, idx: np.ndarray, b: np.ndarray, moving_above: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``(pixels, scales)``: the listed flat indices whose cluster has ``b <= moving_above`` (in order) and their
    factor ``sqrt(1 - b)`` (clipped to [0, 1])."""
    keep = np.empty(idx.shape[0], dtype=np.int64)
    scales = np.empty(idx.shape[0])
    n = 0
    for q in idx:
        bq = b[labels[q]]
        if bq <= moving_above:
            keep[n] = q
            scales[n] = math.sqrt(min(max(1.0 - bq, 0.0), 1.0))
            n += 1
    return keep[:n], scales[:n]


@njit(cache=True, error_model="numpy")
def cluster_depths(labels: np.ndarray, idx: np.ndarray, depth: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(counts, sums)``: (k,) number of listed pixels and sum of their flat ``depth`` per cluster (in order)."""
    counts = np.zeros(k)
    sums = np.zeros(k)
    for q in idx:
        counts[labels[q]] += 1.0
        sums[labels[q]] += depth[q]
    return counts, sums


# ----------------------------------------------------------------------------------------------------------------
# Warping, residuals and IRLS


@njit(cache=True, error_model="numpy", inline="always")  # at the call site: unused samples are never computed
def _warp_sample(T: np.ndarray, x: float, y: float, z: float, cam: np.ndarray, pack: np.ndarray,
                 gate_m: float) -> tuple:
    """Warps the point (x, y, z) with T and samples the target pack there.

    Target values are bilinear when the 2x2 depths are all valid and span less than ``gate_m``, else from the
    nearest pixel (if valid). Returns ``(found, px, py, pz, z, i, dz/du, dz/dv, di/du, di/dv, b)`` with p the
    warped point (m); ``found`` is False (and the samples 0) outside the image or on invalid depth.
    """
    h, w = pack.shape[0], pack.shape[1]
    px = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
    py = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
    pz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
    none = (False, px, py, pz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if pz <= 1e-3:
        return none
    u = cam[0] * px / pz + cam[2]
    v = cam[1] * py / pz + cam[3]
    if not (u >= 0.0 and u <= w - 1 and v >= 0.0 and v <= h - 1):
        return none
    u0 = min(int(u), w - 2) if w > 1 else 0
    v0 = min(int(v), h - 2) if h > 1 else 0
    a, c = u - u0, v - v0
    u1, v1 = min(u0 + 1, w - 1), min(v0 + 1, h - 1)
    lo = min(min(pack[v0, u0, C_Z], pack[v0, u1, C_Z]), min(pack[v1, u0, C_Z], pack[v1, u1, C_Z]))
    hi = max(max(pack[v0, u0, C_Z], pack[v0, u1, C_Z]), max(pack[v1, u0, C_Z], pack[v1, u1, C_Z]))
    if lo > 0 and hi - lo < gate_m:
        w00, w01, w10, w11 = (1 - a) * (1 - c), a * (1 - c), (1 - a) * c, a * c
        return (True, px, py, pz, _blend(pack, v0, u0, v1, u1, C_Z, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_I, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_ZU, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_ZV, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_IU, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_IV, w00, w01, w10, w11),
                _blend(pack, v0, u0, v1, u1, C_B, w00, w01, w10, w11))
    un, vn = int(u + 0.5), int(v + 0.5)
    if pack[vn, un, C_Z] <= 0:
        return none
    return (True, px, py, pz, pack[vn, un, C_Z], pack[vn, un, C_I], pack[vn, un, C_ZU], pack[vn, un, C_ZV],
            pack[vn, un, C_IU], pack[vn, un, C_IV], pack[vn, un, C_B])


@njit(cache=True, error_model="numpy", inline="always")
def _blend(pack: np.ndarray, v0: int, u0: int, v1: int, u1: int, ch: int, w00: float, w01: float, w10: float,
           w11: float) -> float:
    """Bilinear blend of channel ``ch`` over the pixels (v0, u0), (v0, u1), (v1, u0), (v1, u1)."""
    return w00 * pack[v0, u0, ch] + w01 * pack[v0, u1, ch] + w10 * pack[v1, u0, ch] + w11 * pack[v1, u1, ch]


@njit(cache=True, error_model="numpy")
def linearize(idx: np.ndarray, scale: np.ndarray, x1: np.ndarray, y1: np.ndarray, pack1: np.ndarray,
              symmetric: bool, T: np.ndarray, cam: np.ndarray, pack2: np.ndarray, use_b: bool, use_photo: bool,
              gate_m: float, mode: int, alpha: float, kz: float, ki: float, r: np.ndarray, J: np.ndarray,
              ok: np.ndarray) -> None:
    """Warps reference pixels into the target image and linearises the residuals (1)–(2) for ``exp(delta) @ T``.

    For pixel x with point p: ``p' = T p``, ``W(x) = pi(p')``, ``r_Z = Z2(W) - p'_z`` and ``r_I = I2(W) - I1(x)``
    (sampled by :func:`_warp_sample`); the rows of ``J`` are their derivatives with respect to a twist ``delta``
    applied on the left, ``[g, p' x g]`` with ``g`` the chain of the image gradient and the projection; the image
    gradient is the target's sampled at ``W`` or, with ``symmetric``, the mean of that and the reference's at x
    (ESM-like). Both residuals (and rows) are multiplied by a pre-weight:

    * ``MODE_ROBUST`` (6): ``Z1 (1 - B^T)``, ``B^T`` the target's moving probability sampled at ``W``;
    * ``MODE_REFINE`` (18)–(19): ``scale * sqrt(K / (K + |grad|^2 + r^2))`` with ``K = kz`` (depth) or ``ki``
      (intensity), i.e. the square roots of the paper's weights normalised to 1 on smooth, aligned pixels.

    The photometric row is further multiplied by ``alpha``; without ``use_photo`` it is zero.

    Args:
        idx: (n,) flat indices of the reference pixels.
        scale: (n,) extra factor per listed pixel (``MODE_REFINE``), or empty for 1.
        x1, y1: flat reference point coordinates, m.
        pack1: (h1, w1, ``PACK``) reference pack (depth, intensity, gradients per pixel).
        symmetric: average the reference and target gradients.
        T: (4, 4) current pose of the reference frame in the target frame.
        cam: (4,) target-level intrinsics ``fx, fy, cx, cy``, pixels.
        pack2: (h, w, ``PACK``) target pack.
        use_b: sample the target's moving probability (else 0).
        use_photo: whether the photometric residual is used.
        gate_m: bilinear/nearest switch on the 2 x 2 depth span, m.
        mode: pre-weighting, see above.
        alpha: ``alpha_I``.
        kz, ki: ``K_Z`` and ``K_I`` of (18)–(19).
        r: (2, n) out: weighted residuals (geometric, photometric); 0 where not ``ok``.
        J: (2, 6, n) out: weighted Jacobian rows (residual, twist component, pixel); 0 where not ``ok``.
        ok: (n,) out: whether the pixel warped to a valid target sample (and has a non-zero weight).
    """
    f1 = pack1.reshape(-1, PACK)
    n = idx.shape[0]
    if n >= PARALLEL_MIN_WARPS:
        _linearize_par(idx, scale, x1, y1, f1, symmetric, T, cam, pack2, use_b, use_photo, gate_m, mode, alpha, kz, ki,
                       r, J, ok)
    else:
        _linearize_run(0, n, idx, scale, x1, y1, f1, symmetric, T, cam, pack2, use_b, use_photo, gate_m, mode, alpha,
                       kz, ki, r, J, ok)


@njit(cache=True, error_model="numpy", parallel=True)
def _linearize_par(idx: np.ndarray, scale: np.ndarray, x1: np.ndarray, y1: np.ndarray, f1: np.ndarray,
                   symmetric: bool, T: np.ndarray, cam: np.ndarray, pack2: np.ndarray, use_b: bool, use_photo: bool,
                   gate_m: float, mode: int, alpha: float, kz: float, ki: float, r: np.ndarray, J: np.ndarray,
                   ok: np.ndarray) -> None:
    n = idx.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        _linearize_run(blk * BLOCK, min(n, (blk + 1) * BLOCK), idx, scale, x1, y1, f1, symmetric, T, cam, pack2, use_b,
                       use_photo, gate_m, mode, alpha, kz, ki, r, J, ok)


@njit(cache=True, error_model="numpy")
def _linearize_run(lo: int, hi: int, idx: np.ndarray, scale: np.ndarray, x1: np.ndarray, y1: np.ndarray,
                   f1: np.ndarray, symmetric: bool, T: np.ndarray, cam: np.ndarray, pack2: np.ndarray, use_b: bool,
                   use_photo: bool, gate_m: float, mode: int, alpha: float, kz: float, ki: float, r: np.ndarray,
                   J: np.ndarray, ok: np.ndarray) -> None:
    """Listed pixels ``lo:hi`` of :func:`linearize` (``f1``: the (h1 * w1, ``PACK``) reference pack)."""
    for k in range(lo, hi):
        q = idx[k]
        found, px, py, pz, zs, i_s, zu, zv, iu, iv, bs = _warp_sample(T, x1[q], y1[q], f1[q, C_Z], cam, pack2, gate_m)
        rz = ri = mz = mi = 0.0
        if found:
            if symmetric:  # gradients of the mean of the two images (ESM-like)
                zu = 0.5 * (zu + f1[q, C_ZU])
                zv = 0.5 * (zv + f1[q, C_ZV])
                iu = 0.5 * (iu + f1[q, C_IU])
                iv = 0.5 * (iv + f1[q, C_IV])
            rz = zs - pz
            ri = i_s - f1[q, C_I] if use_photo else 0.0
            mz, mi = _preweights(f1, q, mode, bs if use_b else 0.0, scale[k] if scale.shape[0] > 0 else 1.0, rz, ri,
                                 alpha, kz, ki)
            if not use_photo:
                mi = 0.0
        ok[k] = found and mz > 0.0
        if ok[k]:
            _write_rows(r, J, k, mz, mi, rz, ri, zu, zv, iu, iv, cam[0], cam[1], px, py, pz)
        else:
            _clear_pixel(r, J, k)


@njit(cache=True, error_model="numpy")
def _preweights(f1: np.ndarray, q: int, mode: int, b: float, scale: float, rz: float, ri: float, alpha: float,
                kz: float, ki: float) -> tuple[float, float]:
    """Pre-weights ``(m_Z, m_I)`` of the residuals of flat reference pixel q (``f1``: (h * w, ``PACK``) pack), see
    :func:`linearize`."""
    if mode == MODE_ROBUST:
        mz = f1[q, C_Z] * (1.0 - b)
        return mz, alpha * mz
    mz = scale * math.sqrt(kz / (kz + (f1[q, C_ZU] * f1[q, C_ZU] + f1[q, C_ZV] * f1[q, C_ZV]) + rz * rz))
    mi = alpha * scale * math.sqrt(ki / (ki + (f1[q, C_IU] * f1[q, C_IU] + f1[q, C_IV] * f1[q, C_IV]) + ri * ri))
    return mz, mi


@njit(cache=True, error_model="numpy")
def _write_rows(r: np.ndarray, J: np.ndarray, k: int, mz: float, mi: float, rz: float, ri: float, zu: float,
                zv: float, iu: float, iv: float, fx: float, fy: float, px: float, py: float, pz: float) -> None:
    """Writes the weighted residuals and Jacobian rows of pixel k (gradients per pixel, warped point p)."""
    r[0, k] = mz * rz
    r[1, k] = mi * ri
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


@njit(cache=True, error_model="numpy")
def _clear_pixel(r: np.ndarray, J: np.ndarray, k: int) -> None:
    """Zeroes the residuals and Jacobian rows of pixel k."""
    for row in range(2):
        r[row, k] = 0.0
        for c in range(6):
            J[row, c, k] = 0.0


@njit(cache=True, error_model="numpy")
def _jacobian_row(J: np.ndarray, k: int, row: int, m: float, gx: float, gy: float, gz: float, px: float,
                  py: float, pz: float) -> None:
    """Writes ``m * [g, p x g]`` into ``J[row, :, k]``."""
    J[row, 0, k] = m * gx
    J[row, 1, k] = m * gy
    J[row, 2, k] = m * gz
    J[row, 3, k] = m * (py * gz - pz * gy)
    J[row, 4, k] = m * (pz * gx - px * gz)
    J[row, 5, k] = m * (px * gy - py * gx)


@njit(cache=True, error_model="numpy")
def cluster_residuals(idx: np.ndarray, labels: np.ndarray, edges: np.ndarray, zbar: np.ndarray, x1: np.ndarray,
                      y1: np.ndarray, pack1: np.ndarray, T: np.ndarray, cam: np.ndarray, pack2: np.ndarray,
                      use_b: bool, use_photo: bool, gate_m: float, alpha: float, occlusion_m: float) -> np.ndarray:
    """Per-cluster sums of the robust residuals (7)–(8) after warping the listed reference pixels with T.

    A pixel with a valid target sample (see :func:`linearize`) adds its target moving probability ``b`` to its
    cluster; one that is also not occluded (``r_Z >= -occlusion_m``) and not on a depth edge adds
    ``alpha |r_I| + min(|r_Z|, occlusion_m) / zbar``.

    Args:
        idx: (n,) flat reference indices; labels, edges: flat cluster (>= 0 at listed pixels) and edge mask.
        zbar: (k,) mean depth of each cluster, m.
        x1, y1, pack1, T, cam, pack2, use_b, use_photo, gate_m: as in :func:`linearize`.
        alpha: ``alpha_I``; occlusion_m: ``Delta Z_occ``, m.

    Returns:
        (k, 4): pixels used, their residual sum, pixels with a valid sample, their sum of ``b``.
    """
    n = idx.shape[0]
    f1 = pack1.reshape(-1, PACK)
    parts = np.zeros(((n + BLOCK - 1) // BLOCK, zbar.shape[0], 4))
    if n >= PARALLEL_MIN_WARPS:
        _cluster_residuals_par(idx, labels, edges, zbar, x1, y1, f1, T, cam, pack2, use_b, use_photo, gate_m, alpha,
                               occlusion_m, parts)
    else:
        for blk in range(parts.shape[0]):
            _cluster_residuals_block(blk, idx, labels, edges, zbar, x1, y1, f1, T, cam, pack2, use_b, use_photo,
                                     gate_m, alpha, occlusion_m, parts[blk])
    return _sum_blocks(parts)


@njit(cache=True, error_model="numpy", parallel=True)
def _cluster_residuals_par(idx: np.ndarray, labels: np.ndarray, edges: np.ndarray, zbar: np.ndarray, x1: np.ndarray,
                           y1: np.ndarray, f1: np.ndarray, T: np.ndarray, cam: np.ndarray, pack2: np.ndarray,
                           use_b: bool, use_photo: bool, gate_m: float, alpha: float, occlusion_m: float,
                           parts: np.ndarray) -> None:
    for blk in prange(parts.shape[0]):
        _cluster_residuals_block(blk, idx, labels, edges, zbar, x1, y1, f1, T, cam, pack2, use_b, use_photo, gate_m,
                                 alpha, occlusion_m, parts[blk])


@njit(cache=True, error_model="numpy")
def _cluster_residuals_block(blk: int, idx: np.ndarray, labels: np.ndarray, edges: np.ndarray, zbar: np.ndarray,
                             x1: np.ndarray, y1: np.ndarray, f1: np.ndarray, T: np.ndarray, cam: np.ndarray,
                             pack2: np.ndarray, use_b: bool, use_photo: bool, gate_m: float, alpha: float,
                             occlusion_m: float, out: np.ndarray) -> None:
    """The (k, 4) sums of :func:`cluster_residuals` over block ``blk`` of the listed pixels into ``out`` (``f1``:
    the (h1 * w1, ``PACK``) reference pack)."""
    for j in range(blk * BLOCK, min(idx.shape[0], (blk + 1) * BLOCK)):
        q = idx[j]
        lab = labels[q]
        found, px, py, pz, zs, i_s, zu, zv, iu, iv, bs = _warp_sample(T, x1[q], y1[q], f1[q, C_Z], cam, pack2, gate_m)
        if not found:
            continue
        out[lab, 2] += 1.0
        out[lab, 3] += bs if use_b else 0.0
        rz = zs - pz
        if rz >= -occlusion_m and not edges[q]:
            ri = i_s - f1[q, C_I] if use_photo else 0.0
            out[lab, 0] += 1.0
            out[lab, 1] += alpha * abs(ri) + min(abs(rz), occlusion_m) / zbar[lab]


@njit(cache=True, error_model="numpy")
def irls_cauchy(r: np.ndarray, J: np.ndarray, ok: np.ndarray, rows: int, c_factor: float, max_iterations: int,
                chi2_ratio: float, delta_tol: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Minimises ``sum F(r + J delta)`` with the Cauchy penalty (5) by iteratively reweighted least squares.

    Every iteration takes ``c = c_factor * mean |e|`` of the current residuals ``e = r + J delta`` (20), the
    weights ``1 / (1 + (e / c)^2)`` and solves the weighted normal equations for ``delta``; it stops when the
    weighted cost falls by less than ``1 - chi2_ratio`` or ``delta`` changes by less than ``delta_tol`` (max norm).

    Args:
        r: (2, n) residuals and J: (2, 6, n) Jacobian rows as written by :func:`linearize` (0 at unusable pixels,
            which then add nothing); ok: (n,) usable pixels.
        rows: residuals used per pixel: 1 (geometric only) or 2.
        c_factor: Cauchy scale relative to the mean absolute residual.
        max_iterations: most reweighted solves (at least one is made).
        chi2_ratio, delta_tol: stopping rules.

    Returns:
        ``(delta, H, s2, m)``: (6,) twist, (6, 6) weighted normal matrix of the last solve, weighted residual
        variance ``sum w e^2 / (m - 6)`` of the last solve, and the number of residuals m (0 = nothing to
        solve; delta is then 0).
    """
    n = r.shape[1]
    parts = np.zeros(((n + BLOCK - 1) // BLOCK, _N_NORMAL))
    e = np.empty((2, n))
    delta = np.zeros(6)
    H = np.zeros((6, 6))
    last_chi2 = np.inf
    s2 = 0.0
    m = rows * np.count_nonzero(ok)
    if m < 6:
        return delta, H, 0.0, 0
    for _ in range(max(1, max_iterations)):
        # Residuals at the current twist and the Cauchy scale.
        _residual_blocks(r, J, rows, delta, e, parts)
        inv_c2 = 1.0 / ((c_factor * _sum_blocks(parts)[0] / m) ** 2 + 1e-30)
        # Weighted normal equations of the full twist.
        _normal_blocks(r, J, e, rows, inv_c2, parts)
        sums = _sum_blocks(parts)
        for a in range(6):
            for b in range(6):
                H[a, b] = sums[_UPPER[a, b]]
        chi2 = sums[27]
        s2 = chi2 / max(m - 6, 1)
        damp = 1e-9 * (np.trace(H) / 6.0) + 1e-15
        new = np.linalg.solve(H + damp * np.eye(6), -sums[21:27])
        change = np.max(np.abs(new - delta))
        delta = new
        if chi2 > chi2_ratio * last_chi2 or change < delta_tol:
            break
        last_chi2 = chi2
    return delta, H, s2, m


@njit(cache=True, error_model="numpy")
def _sum_blocks(parts: np.ndarray) -> np.ndarray:
    """Sum over the first axis of the (nb, ...) block partials, blocks added in order."""
    out = parts[0].copy()
    for blk in range(1, parts.shape[0]):
        out += parts[blk]
    return out


@njit(cache=True, error_model="numpy")
def _residual_blocks(r: np.ndarray, J: np.ndarray, rows: int, delta: np.ndarray, e: np.ndarray,
                     parts: np.ndarray) -> None:
    """``e = r + J delta`` and ``parts[blk, 0]``: the sum of ``|e|`` over each block."""
    if r.shape[1] >= PARALLEL_MIN:
        _residual_blocks_par(r, J, rows, delta, e, parts)
    else:
        for blk in range(parts.shape[0]):
            _residual_block(blk, r, J, rows, delta, e, parts)


@njit(cache=True, error_model="numpy", parallel=True)
def _residual_blocks_par(r: np.ndarray, J: np.ndarray, rows: int, delta: np.ndarray, e: np.ndarray,
                         parts: np.ndarray) -> None:
    for blk in prange(parts.shape[0]):
        _residual_block(blk, r, J, rows, delta, e, parts)


@njit(cache=True, error_model="numpy")
def _residual_block(blk: int, r: np.ndarray, J: np.ndarray, rows: int, delta: np.ndarray, e: np.ndarray,
                    parts: np.ndarray) -> None:
    """Block ``blk`` of :func:`_residual_blocks`."""
    lo, hi = blk * BLOCK, min(r.shape[1], (blk + 1) * BLOCK)
    total = 0.0
    for j in range(rows):
        total += _residual_row(r[j, lo:hi], J[j, 0, lo:hi], J[j, 1, lo:hi], J[j, 2, lo:hi], J[j, 3, lo:hi],
                               J[j, 4, lo:hi], J[j, 5, lo:hi], delta, e[j, lo:hi])
    parts[blk, 0] = total


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "nsz"})
def _residual_row(r: np.ndarray, j0: np.ndarray, j1: np.ndarray, j2: np.ndarray, j3: np.ndarray, j4: np.ndarray,
                  j5: np.ndarray, delta: np.ndarray, e: np.ndarray) -> float:
    """``e = r + J delta`` for one residual row of a block (all (m,)); returns the sum of ``|e|`` (vectorised:
    any summation order)."""
    d0, d1, d2, d3, d4, d5 = delta[0], delta[1], delta[2], delta[3], delta[4], delta[5]
    total = 0.0
    for k in range(r.shape[0]):
        ek = r[k] + (j0[k] * d0 + j1[k] * d1 + j2[k] * d2 + j3[k] * d3 + j4[k] * d4 + j5[k] * d5)
        e[k] = ek
        total += abs(ek)
    return total


@njit(cache=True, error_model="numpy")
def _normal_blocks(r: np.ndarray, J: np.ndarray, e: np.ndarray, rows: int, inv_c2: float, parts: np.ndarray) -> None:
    """``parts[blk]``: the Cauchy-weighted normal equations of each block (:func:`_normal_block`)."""
    n = r.shape[1]
    if n >= PARALLEL_MIN:
        _normal_blocks_par(r, J, e, rows, inv_c2, parts)
    else:
        for blk in range(parts.shape[0]):
            _normal_block(r, J, e, rows, blk * BLOCK, min(n, (blk + 1) * BLOCK), inv_c2, parts[blk])


@njit(cache=True, error_model="numpy", parallel=True)
def _normal_blocks_par(r: np.ndarray, J: np.ndarray, e: np.ndarray, rows: int, inv_c2: float,
                       parts: np.ndarray) -> None:
    n = r.shape[1]
    for blk in prange(parts.shape[0]):
        _normal_block(r, J, e, rows, blk * BLOCK, min(n, (blk + 1) * BLOCK), inv_c2, parts[blk])


@njit(cache=True, error_model="numpy")
def _normal_block(r: np.ndarray, J: np.ndarray, e: np.ndarray, rows: int, lo: int, hi: int, inv_c2: float,
                  out: np.ndarray) -> None:
    """Sums over pixels ``lo:hi`` ((2, n) residuals r, (2, 6, n) Jacobians, (2, n) current residuals e) of
    ``w J^T J`` (21 upper-triangle entries, row-major), ``w J^T r`` (6) and ``w e^2`` (1) into ``out`` (28,), with
    ``w = 1 / (1 + e^2 / c^2)``."""
    w = np.empty(hi - lo)
    wa = np.empty(hi - lo)
    out[:] = 0.0
    for j in range(rows):
        ej = e[j, lo:hi]
        for k in range(hi - lo):
            w[k] = 1.0 / (1.0 + ej[k] * ej[k] * inv_c2)
            wa[k] = w[k] * ej[k]
        out[27] += _dot(wa, ej)
        for a in range(6):
            ja = J[j, a, lo:hi]
            for k in range(hi - lo):
                wa[k] = w[k] * ja[k]
            out[21 + a] += _dot(wa, r[j, lo:hi])
            for b in range(a, 6):
                out[_UPPER[a, b]] += _dot(wa, J[j, b, lo:hi])


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "nsz"})
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """``sum a * b`` of two (m,) arrays, vectorised (any summation order)."""
    total = 0.0
    for k in range(a.shape[0]):
        total += a[k] * b[k]
    return total


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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
    out = np.full((3, z.shape[0], z.shape[1]), np.nan, dtype=np.float32)
    near = _blend_lists(G)
    if z.size >= PARALLEL_MIN:
        _scene_flow_par(x, y, z, labels, motions, centres, near, sharpness_per_m, cutoff, out)
    else:
        for v in range(z.shape[0]):
            _scene_flow_row(v, x, y, z, labels, motions, centres, near, sharpness_per_m, cutoff, out)
    return out


@njit(cache=True, error_model="numpy")
def _blend_lists(G: np.ndarray) -> np.ndarray:
    """(k, k + 1): per cluster l, the count n of clusters blended into its flow (itself and those contiguous to it,
    ``G``) in column 0, then their indices, increasing, in columns 1..n."""
    k = G.shape[0]
    near = np.zeros((k, k + 1), dtype=np.int64)
    for lab in range(k):
        for j in range(k):
            if j == lab or G[lab, j]:
                near[lab, 0] += 1
                near[lab, near[lab, 0]] = j
    return near


@njit(cache=True, error_model="numpy", parallel=True)
def _scene_flow_par(x: np.ndarray, y: np.ndarray, z: np.ndarray, labels: np.ndarray, motions: np.ndarray,
                    centres: np.ndarray, near: np.ndarray, sharpness_per_m: float, cutoff: float,
                    out: np.ndarray) -> None:
    for v in prange(z.shape[0]):
        _scene_flow_row(v, x, y, z, labels, motions, centres, near, sharpness_per_m, cutoff, out)


@njit(cache=True, error_model="numpy")
def _scene_flow_row(v: int, x: np.ndarray, y: np.ndarray, z: np.ndarray, labels: np.ndarray, motions: np.ndarray,
                    centres: np.ndarray, near: np.ndarray, sharpness_per_m: float, cutoff: float,
                    out: np.ndarray) -> None:
    """Row v of :func:`scene_flow` into ``out`` (``near``: :func:`_blend_lists`)."""
    for u in range(z.shape[1]):
        lab = labels[v, u]
        if lab >= 0:
            out[0, v, u], out[1, v, u], out[2, v, u] = _blended_flow(x[v, u], y[v, u], z[v, u], lab, motions, centres,
                                                                     near, sharpness_per_m, cutoff)


@njit(cache=True, error_model="numpy", inline="always")
def _blended_flow(p0: float, p1: float, p2: float, lab: int, motions: np.ndarray, centres: np.ndarray,
                  near: np.ndarray, sharpness_per_m: float, cutoff: float) -> tuple[float, float, float]:
    """Flow of point p of cluster ``lab`` (see :func:`scene_flow`)."""
    d_own = math.sqrt((p0 - centres[lab, 0]) ** 2 + (p1 - centres[lab, 1]) ** 2 + (p2 - centres[lab, 2]) ** 2)
    f0 = f1 = f2 = wsum = 0.0
    for t in range(near[lab, 0]):
        j = near[lab, t + 1]
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
    return f0 / wsum, f1 / wsum, f2 / wsum
