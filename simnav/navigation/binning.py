"""Numba kernels of the navigator's per-step obstacle handling: points into bands, bands' points into grid cells.

One step gets thousands of obstacle points (a lidar plus a depth camera). Written with numpy, sorting them into
the height bands, finding their collision-grid cells, deduplicating the cells (``np.unique``, a sort), the column
minimum over the cells' rows of dense (cells, N) TP-distance tables and the speed regulation's obstacle distance
took a dozen array passes and temporaries per band and PTG, ~1.5 ms a step for 5000 points; these kernels take
~0.15 ms together.

* :func:`sort_points`: the finite points above the floor and inside the grids' extent, into every band whose
  height interval holds them, as one flat (K, 2) array with band offsets (the points of a band keep their order).
* :func:`mark_cells`: the distinct grid cells of the bands' points (a one-byte mark per cell tells the cells
  already met in this pass: no sort) and the points in start cells (those go through the grid's back-away rule).
* :func:`ranges_min`: running minimum over cells of their path-distance runs (uint8), for every PTG at once (the
  tables are built in :mod:`simnav.navigation.ptgspace`).
* :func:`effective_obstacle_distance`: the navigator's obstacle distance for the speed regulation.
* :func:`points_near`: the points near a spot (the navigator's blocked-goal check looks at no other).
* :func:`merge_bands`: two flat band sets as one (sensed points, then the short-term memory's virtual ones).

Every kernel does the same floating-point operations as the numpy formulation it replaces, so bands, cells, minima
and distances are identical to the bit. ``@njit(cache=True)``: compiled on first use, then loaded from
``__pycache__``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _keep(x: float, y: float, z: float, floor_m: float, max_xy_m: float) -> bool:
    """A finite point above the floor with |x|, |y| <= max_xy_m."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return False
    return z >= floor_m and abs(x) <= max_xy_m and abs(y) <= max_xy_m


@njit(cache=True, error_model="numpy")
def sort_points(points: np.ndarray, z_min: np.ndarray, z_max: np.ndarray, floor_m: float,
                max_xy_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(xy (K, 2), ptr (B + 1,)): the kept points of band b are ``xy[ptr[b]:ptr[b + 1]]``, in input order.

    Args:
        points: (P, 3) float64 points in the base frame, m.
        z_min, z_max: (B,) height interval ``[z_min, z_max)`` of each band, m (a point may fall in several).
        floor_m: points below this height are dropped, m.
        max_xy_m: points with |x| or |y| beyond this are dropped, m.
    """
    n_bands = z_min.shape[0]
    # The heights between consecutive band limits: a point's slot is the number of limits <= z (0 for NaN).
    limits = np.sort(np.concatenate((z_min, z_max)))
    slot_band = np.full(limits.shape[0] + 1, n_bands, dtype=np.int64)  # n_bands: no band
    for b in range(n_bands):
        lo, hi = np.searchsorted(limits, z_min[b], side="right"), np.searchsorted(limits, z_max[b], side="left")
        for j in range(lo, hi + 1):  # the slots of z >= z_min[b] and z < z_max[b]
            if slot_band[j] != n_bands:
                return _sort_points_overlapping(points, z_min, z_max, floor_m, max_xy_m)
            slot_band[j] = b
    # One band (or none) per point: its band, then the points scattered band by band.
    code = np.empty(points.shape[0], dtype=np.int64)
    counts = np.zeros(n_bands + 1, dtype=np.int64)
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        slot = 0
        for e in range(limits.shape[0]):
            slot += z >= limits[e]
        b = slot_band[slot] if _keep(x, y, z, floor_m, max_xy_m) else n_bands
        code[i] = b
        counts[b] += 1
    ptr = np.zeros(n_bands + 1, dtype=np.int64)
    for b in range(n_bands):
        ptr[b + 1] = ptr[b] + counts[b]
    xy = np.empty((ptr[n_bands], 2), dtype=np.float64)
    fill = ptr[:n_bands].copy()
    for i in range(points.shape[0]):
        b = code[i]
        if b < n_bands:
            xy[fill[b], 0] = points[i, 0]
            xy[fill[b], 1] = points[i, 1]
            fill[b] += 1
    return xy, ptr


@njit(cache=True, error_model="numpy")
def _sort_points_overlapping(points: np.ndarray, z_min: np.ndarray, z_max: np.ndarray, floor_m: float,
                             max_xy_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sort_points` for bands whose height intervals overlap (a point may go to several)."""
    n_bands = z_min.shape[0]
    ptr = np.zeros(n_bands + 1, dtype=np.int64)
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if _keep(x, y, z, floor_m, max_xy_m):
            for b in range(n_bands):
                if z >= z_min[b] and z < z_max[b]:
                    ptr[b + 1] += 1
    for b in range(n_bands):
        ptr[b + 1] += ptr[b]
    xy = np.empty((ptr[n_bands], 2), dtype=np.float64)
    fill = ptr[:n_bands].copy()
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if _keep(x, y, z, floor_m, max_xy_m):
            for b in range(n_bands):
                if z >= z_min[b] and z < z_max[b]:
                    xy[fill[b], 0] = x
                    xy[fill[b], 1] = y
                    fill[b] += 1
    return xy, ptr


@njit(cache=True, error_model="numpy")
def _cell(x: float, y: float, n_side: int, half_extent_m: float, resolution_m: float) -> int:
    """Cell ``ix * n_side + iy`` of a point, ``(ix, iy) = floor((p + half_extent) / resolution)`` as
    :meth:`CollisionGrid.cell_index`; -1 outside the grid (NaN too)."""
    fx = math.floor((x + half_extent_m) / resolution_m)
    fy = math.floor((y + half_extent_m) / resolution_m)
    if fx >= 0 and fx < n_side and fy >= 0 and fy < n_side:
        return int(fx) * n_side + int(fy)
    return -1


START, NOTHING = 255, 254
"""Cell marks (uint8) of :func:`mark_cells`: a start cell, a cell without path distances; stamps are 1..253."""


@njit(cache=True, error_model="numpy")
def mark_cells(xy: np.ndarray, ptr: np.ndarray, n_side: np.ndarray, half_extent_m: np.ndarray,
               resolution_m: float, cell_offset: np.ndarray, mark: np.ndarray,
               stamp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct grid cells with path distances of the bands' points, and the points in start cells.

    Args:
        xy: (K, 2) points, m; band b owns ``xy[ptr[b]:ptr[b + 1]]``.
        ptr: (B + 1,) band offsets.
        n_side, half_extent_m: (B,) grid geometry of each band.
        resolution_m: cell size (every band), m.
        cell_offset: (B,) first global cell of each band (the bands' grids side by side).
        mark: (cells,) uint8 marks: :data:`START`, :data:`NOTHING` (cells that no path reaches: skipped), else
            never ``stamp`` on entry; the cells met are set to ``stamp``.
        stamp: this pass's mark, 1..253.

    Returns:
        cells (M,) distinct global cells (in order of first point), start (S,) indices into ``xy`` of the points
        in start cells, start_ptr (B + 1,) band offsets into those.
    """
    n_bands = n_side.shape[0]
    cells = np.empty(xy.shape[0], dtype=np.int64)
    start = np.empty(xy.shape[0], dtype=np.int64)
    start_ptr = np.zeros(n_bands + 1, dtype=np.int64)
    n_cells, n_start = 0, 0
    for b in range(n_bands):
        for i in range(ptr[b], ptr[b + 1]):
            c = _cell(xy[i, 0], xy[i, 1], n_side[b], half_extent_m[b], resolution_m)
            if c < 0:
                continue
            c += cell_offset[b]
            m = mark[c]
            if m == stamp or m == NOTHING:
                continue
            if m == START:
                start[n_start] = i
                n_start += 1
            else:
                mark[c] = stamp
                cells[n_cells] = c
                n_cells += 1
        start_ptr[b + 1] = n_start
    return cells[:n_cells], start[:n_start], start_ptr


@njit(cache=True, error_model="numpy")
def ranges_min(records: np.ndarray, data: np.ndarray, cells: np.ndarray, out: np.ndarray) -> None:
    """Running minimum into ``out`` (P, N) uint8 of the PTGs' path-distance runs of ``cells``.

    Record of cell c: ``[offset, (first path << 16) | count per PTG, ...]``; PTG p's run covers paths
    ``first..first + count - 1`` and follows the runs of PTGs 0..p-1 from ``data[offset]``.
    """
    for c in cells:
        at = records[c, 0]
        for p in range(out.shape[0]):
            packed = records[c, 1 + p]
            first, count = packed >> 16, packed & 0xFFFF
            row = out[p]
            for j in range(count):
                v = data[at + j]
                if v < row[first + j]:
                    row[first + j] = v
            at += count


@njit(cache=True, error_model="numpy")
def effective_obstacle_distance(xy: np.ndarray, lo_x: float, lo_y: float, hi_x: float, hi_y: float,
                                lateral_weight: float, upper: float) -> float:
    """min(upper, min over the points of (gap to the box [lo, hi]) / (direction weight)), m.

    The weight is ``lateral_weight + (1 - lateral_weight) * clip(x / max(|p|, 1e-9), 0, 1)``: 1 straight ahead,
    ``lateral_weight`` to the side and behind (the navigator's ``_obstacle_speed_factor``). A point whose gap along
    x or y alone exceeds the best so far (the weight is at most 1) is skipped before the two ``hypot``.
    """
    best = upper
    for i in range(xy.shape[0]):
        x, y = xy[i, 0], xy[i, 1]
        gx = max(max(lo_x - x, x - hi_x), 0.0)
        gy = max(max(lo_y - y, y - hi_y), 0.0)
        if max(gx, gy) > best * (1.0 + 1e-9):  # its value is at least its gap: cannot win
            continue
        gap = math.hypot(gx, gy)
        frontal = min(max(x / max(math.hypot(x, y), 1e-9), 0.0), 1.0)
        value = gap / (lateral_weight + (1.0 - lateral_weight) * frontal)
        if value < best:
            best = value
    return best


@njit(cache=True, error_model="numpy")
def points_near(xy: np.ndarray, ptr: np.ndarray, cx: float, cy: float,
                radius_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(xy (K', 2), ptr (B + 1,)): the points of each band b within ``radius_m[b]`` of (cx, cy), in order."""
    n_bands = ptr.shape[0] - 1
    out = np.empty((xy.shape[0], 2), dtype=np.float64)
    out_ptr = np.zeros(n_bands + 1, dtype=np.int64)
    n = 0
    for b in range(n_bands):
        r2 = radius_m[b] * radius_m[b]
        for i in range(ptr[b], ptr[b + 1]):
            dx, dy = xy[i, 0] - cx, xy[i, 1] - cy
            if dx * dx + dy * dy <= r2:
                out[n, 0] = xy[i, 0]
                out[n, 1] = xy[i, 1]
                n += 1
        out_ptr[b + 1] = n
    return out[:n].copy(), out_ptr


@njit(cache=True, error_model="numpy")
def merge_bands(xy: np.ndarray, ptr: np.ndarray, extra_xy: np.ndarray,
                extra_ptr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(xy (K + E, 2), ptr (B + 1,)): per band, its points of ``xy`` followed by its points of ``extra_xy``."""
    n_bands = ptr.shape[0] - 1
    out = np.empty((xy.shape[0] + extra_xy.shape[0], 2), dtype=np.float64)
    out_ptr = np.zeros(n_bands + 1, dtype=np.int64)
    n = 0
    for b in range(n_bands):
        for src, lo, hi in ((xy, ptr[b], ptr[b + 1]), (extra_xy, extra_ptr[b], extra_ptr[b + 1])):
            for i in range(lo, hi):
                out[n, 0] = src[i, 0]
                out[n, 1] = src[i, 1]
                n += 1
        out_ptr[b + 1] = n
    return out, out_ptr
