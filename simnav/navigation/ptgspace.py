"""One path family across every height band: the PTG, one collision grid per band, TP-NavLimits by eq. 6.4.

For speed at run time each collision grid is recast once into a compact table: per cell, the path distances over
the range of paths that reach it (uint8, rounded down to 1/255 of the horizon, so never optimistic; ~5-10 paths a
cell), the bands' cells side by side. The TP-NavLimits are then the running minimum over the occupied cells of
every band. The occupied cells are found once per step for all PTGs, in one Numba pass over the points that
deduplicates them with a one-byte stamp per cell (no sort), and the navigator reduces the tables of all its PTGs,
merged so that a cell's runs lie side by side, in a second pass over the cells (:meth:`PTGSpace.tp_limits_all`,
kernels in :mod:`simnav.navigation.binning`): ~0.1 ms a step for 5000 points where the numpy formulation took
~1.3 ms, with the same limits to the bit. The inverse map of points within the horizon is looked up in a table
of nearest path samples built once; points beyond it use MRPT's end-point extrapolation (Numba kernels too).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from simnav.navigation.bands import Band
from simnav.navigation.binning import NOTHING, START, mark_cells, ranges_min
from simnav.navigation.collision_grid import CollisionGrid
from simnav.navigation.ptg import PTG, PTGConfig

FAMILIES = {"C": ("C", False), "alpha": ("alpha", False), "CS": ("CS", False), "CCS": ("CCS", False),
            "C-backward": ("C", True)}
"""Names accepted in ``NavigatorConfig.ptgs``: family and whether it drives backwards."""

_FREE = 255
_LOOKUP_RESOLUTION_M = 0.05
_EXACT_TOLERANCE_M = 0.10


@dataclass(frozen=True)
class PreparedObstacles:
    """One step's obstacle points in the grid geometry that the PTGs of a navigator share (:meth:`PTGSpace.prepare`).

    Attributes:
        cells: (M,) distinct occupied cells outside the start cells, as indices into the bands' grids side by side
            (cell c of band b is ``cell_offset[b] + c``); valid for every PTG that shares the grid geometry.
        start_xy: per band, (S_b, 2) the points in the band's start cells (handled by the back-away rule); empty
            list when there are none.
    """

    cells: np.ndarray
    start_xy: list[np.ndarray]


class PTGSpace:
    """A PTG shared by all bands (they share the kinematics) and one collision grid per band polygon.

    Args:
        name: a key of :data:`FAMILIES`.
        bands: the robot's bands.
        max_v_m_s, max_w_rad_s: the robot's speed limits.
        num_paths: paths of the PTG.
        ref_distance_m: horizon, m.
        resolution_m: cell size of the collision grids, m.
        cache_dir: where grids are cached (None = the default).
    """

    def __init__(self, name: str, bands: Sequence[Band], max_v_m_s: float, max_w_rad_s: float, num_paths: int,
                 ref_distance_m: float, resolution_m: float, cache_dir: str | None = None) -> None:
        if name not in FAMILIES:
            raise ValueError(f"unknown PTG '{name}'; available: {', '.join(FAMILIES)}")
        family, backward = FAMILIES[name]
        self.name, self.backward = name, backward
        self.ptg = PTG(PTGConfig(family=family, backward=backward, num_paths=num_paths, ref_distance_m=ref_distance_m,
                                 v_max_mps=max_v_m_s, w_max_radps=max_w_rad_s))
        # cell-centre marking: a point is an obstacle of a path where the section covers its cell's centre, which is
        # off by at most half a cell diagonal; the navigator grows the sections by a margin at least that large
        self.grids = [CollisionGrid(self.ptg, band.polygon, resolution_m=resolution_m, conservative=False,
                                    cache_dir=cache_dir) for band in bands]
        self._ranges = _range_table(self.grids)  # the input of _CellTable
        self._joint: _CellTable | None = None  # of tp_limits_all, when this PTG comes first
        self._lookup = _InverseLookup(self.ptg)
        last = self.ptg.num_samples - 1
        self._ends = self.ptg.poses[np.arange(num_paths), last, :2]
        self._end_dist = self.ptg.dist_m[np.arange(num_paths), last]

    @property
    def num_paths(self) -> int:
        return self.ptg.num_paths

    @cached_property
    def _cells(self) -> _CellTable:
        """This PTG's cell table, for :meth:`prepare` and :meth:`tp_limits` (no cell is skipped as free: other
        PTGs use the cells that :meth:`prepare` finds)."""
        return _CellTable([self], skip_free=False)

    # ----------------------------------------------------------------------------------------- TP-obstacles
    def prepare(self, band_xy: Sequence[np.ndarray]) -> PreparedObstacles:
        """The distinct grid cells of the points ahead, and per band the points the sections cover at the start.

        Every PTG of a navigator shares the band polygons and the grid geometry, so this is done once per step
        and passed to :meth:`tp_limits` of each PTG.

        Args:
            band_xy: per band, (P_i, 2) obstacle points in the base frame, m (extra columns are ignored).
        """
        parts = [np.asarray(pts, dtype=np.float64) for pts in band_xy]
        parts = [p.reshape(len(p), -1)[:, :2] if p.size else np.zeros((0, 2)) for p in parts]
        if len(parts) != len(self.grids):
            raise ValueError(f"expected points of {len(self.grids)} bands, got {len(parts)}")
        ptr = np.zeros(len(parts) + 1, dtype=np.int64)
        np.cumsum([len(p) for p in parts], out=ptr[1:])
        return self.prepare_flat(np.concatenate(parts) if parts else np.zeros((0, 2)), ptr)

    def prepare_flat(self, xy: np.ndarray, ptr: np.ndarray) -> PreparedObstacles:
        """:meth:`prepare` of the bands' points as one array: band b owns ``xy[ptr[b]:ptr[b + 1]]``.

        Args:
            xy: (K, 2) obstacle points in the base frame, m.
            ptr: (B + 1,) band offsets.
        """
        table = self._cells
        xy = np.ascontiguousarray(xy, dtype=np.float64)
        cells, start, start_ptr = mark_cells(xy, np.asarray(ptr, dtype=np.int64), table.n_side, table.half_extent,
                                             table.resolution_m, table.cell_offset, table.mark, table.next_stamp())
        return PreparedObstacles(cells, _start_points(xy, start, start_ptr, len(self.grids)))

    def shares_grid_geometry(self, other: PTGSpace) -> bool:
        """Whether :meth:`prepare` of ``other`` is valid for this PTG."""
        return all(a.n_side == b.n_side and a.half_extent_m == b.half_extent_m and a.resolution_m == b.resolution_m
                   and np.array_equal(a.start_cells, b.start_cells) for a, b in zip(self.grids, other.grids,
                                                                                     strict=True))

    def tp_limits(self, prepared: PreparedObstacles) -> np.ndarray:
        """(N,) normalised collision-free distance per path: the minimum over the bands (eq. 6.4).

        Args:
            prepared: the output of :meth:`prepare` (of this PTG or one that shares its grid geometry).
        """
        limits = np.full((1, self.num_paths), _FREE, dtype=np.uint8)
        ranges_min(self._cells.records, self._cells.data, prepared.cells, limits)
        tp = limits[0].astype(np.float64) / _FREE
        self._start_limits(prepared.start_xy, tp)
        return tp

    @staticmethod
    def tp_limits_all(spaces: Sequence[PTGSpace], xy: np.ndarray, ptr: np.ndarray) -> list[np.ndarray]:
        """``[space.tp_limits(spaces[0].prepare_flat(xy, ptr)) for space in spaces]``, faster.

        The spaces must share the grid geometry (:meth:`shares_grid_geometry`). Their tables are merged once (kept
        by ``spaces[0]``): an occupied cell then costs one record and one contiguous run of path distances for all
        the PTGs, and cells that no path of any PTG reaches cost one byte.

        Args:
            spaces: the PTGs.
            xy: (K, 2) obstacle points in the base frame, m; band b owns ``xy[ptr[b]:ptr[b + 1]]``.
            ptr: (B + 1,) band offsets.

        Returns:
            Per PTG, (N,) normalised collision-free distance per path.
        """
        first = spaces[0]
        table = first._joint
        if table is None or len(table.spaces) != len(spaces) or any(a is not b for a, b in zip(table.spaces, spaces)):
            table = first._joint = _CellTable(spaces)
        xy = np.ascontiguousarray(xy, dtype=np.float64)
        limits = np.full((len(spaces), first.num_paths), _FREE, dtype=np.uint8)
        cells, start, start_ptr = mark_cells(xy, np.asarray(ptr, dtype=np.int64), table.n_side, table.half_extent,
                                             table.resolution_m, table.cell_offset, table.mark, table.next_stamp())
        ranges_min(table.records, table.data, cells, limits)
        tp = limits.astype(np.float64) / _FREE
        start_xy = _start_points(xy, start, start_ptr, len(first.grids))
        out = [tp[i] for i in range(len(spaces))]
        for space, row in zip(spaces, out, strict=True):
            space._start_limits(start_xy, row)
        return out

    def _start_limits(self, start_xy: Sequence[np.ndarray], tp: np.ndarray) -> None:
        """Points the sections cover at the start: the grids' back-away rule, into ``tp`` (N,)."""
        for grid, pts in zip(self.grids, start_xy):
            if len(pts):
                np.minimum(tp, grid.tp_obstacles(pts), out=tp)

    # ----------------------------------------------------------------------------------------- inverse map
    def inverse_map(self, x_m: float, y_m: float) -> tuple[int, float, bool]:
        """(k, normalised distance, exact) of one base-frame point."""
        k, d, exact = self.inverse_map_many(np.array([[x_m, y_m]], dtype=np.float64))
        return int(k[0]), float(d[0]), bool(exact[0])

    def inverse_map_many(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(k (P,), normalised distance (P,), exact (P,)) of (P, 2) base-frame points; every point gets an answer.

        Within the horizon: the PTG's inverse map (from a table at 5 cm); a point off every path there (behind a
        forward-only family, inside its tightest turn) gets the PTG's cheapest "path, turn, straight" continuation
        (not exact; its nearest sample would say "distance 0" of a point behind the robot). Beyond the horizon:
        the path whose end is cheapest to reach plus the straight line from there (``d > 1``, not exact).
        """
        p = np.ascontiguousarray(np.asarray(xy_m, dtype=np.float64).reshape(-1, 2))
        k = np.empty(len(p), dtype=np.int64)
        d = np.empty(len(p), dtype=np.float64)
        exact = np.empty(len(p), dtype=np.bool_)
        lk = self._lookup
        _inverse_map_kernel(p, _LOOKUP_RESOLUTION_M, lk.mid, lk.n, lk.half_m, lk.k, lk.d, lk.exact, self._ends,
                            self._end_dist, self.ptg.ref_distance_m, k, d, exact)
        off = np.nonzero(~exact & (d <= 1.0))[0]
        if len(off):
            k_off, cost_m, _ = self.ptg.continuation(p[off])
            k[off], d[off] = k_off, cost_m / self.ptg.ref_distance_m
        return k, d, exact

    # ------------------------------------------------------------------------------------------ path queries
    def command(self, k: int) -> tuple[float, float]:
        """(v m/s, w rad/s) of path k at full speed."""
        return self.ptg.direction_to_motion_command(k)

    def closest_approach(self, k: int, d_norm: float, target_xy: np.ndarray) -> float:
        """Smallest distance from the target to path k up to ``d_norm``, m."""
        ptg = self.ptg
        return _closest_approach(ptg.dist_m, ptg.poses, int(ptg.num_samples[k]), int(k),
                                 max(d_norm, 0.0) * ptg.ref_distance_m, float(target_xy[0]), float(target_xy[1]))


@njit(cache=True, error_model="numpy")
def _inverse_map_kernel(p: np.ndarray, resolution_m: float, mid: int, n: int, half_m: float, table_k: np.ndarray,
                        table_d: np.ndarray, table_exact: np.ndarray, ends: np.ndarray, end_dist: np.ndarray,
                        ref_distance_m: float, k: np.ndarray, d: np.ndarray, exact: np.ndarray) -> None:
    """:meth:`PTGSpace.inverse_map_many` into (k, d, exact): the table within the horizon (its nearest cell
    centre), beyond it the path end with the least path length + straight gap (the first one on ties, as
    ``np.argmin``). The same float operations as the numpy formulation (norm = sqrt(dx² + dy²))."""
    for i in range(p.shape[0]):
        x, y = p[i, 0], p[i, 1]
        if math.hypot(x, y) < half_m:
            ix = min(max(int(np.rint(x / resolution_m)) + mid, 0), n - 1)
            iy = min(max(int(np.rint(y / resolution_m)) + mid, 0), n - 1)
            cell = ix * n + iy
            k[i], d[i], exact[i] = table_k[cell], table_d[cell], table_exact[cell]
            continue
        best, best_total = 0, math.inf
        for j in range(ends.shape[0]):
            dx, dy = x - ends[j, 0], y - ends[j, 1]
            total = end_dist[j] + math.sqrt(dx * dx + dy * dy)
            if math.isnan(total):  # np.argmin: the first NaN wins
                best, best_total = j, total
                break
            if total < best_total:
                best, best_total = j, total
        k[i], d[i], exact[i] = best, best_total / ref_distance_m, False


@njit(cache=True, error_model="numpy")
def _closest_approach(dist_m: np.ndarray, poses: np.ndarray, num_samples: int, k: int, d_m: float, tx: float,
                      ty: float) -> float:
    """min over the samples of path k up to distance ``d_m`` (as :meth:`PTG.step_for_distance`: the last sample
    with distance <= d_m, at least the first) of their distance to (tx, ty), m."""
    lo, hi = 0, num_samples  # np.searchsorted(dist_m[k, :num_samples], d_m, side="right")
    while lo < hi:
        half = (lo + hi) // 2
        if dist_m[k, half] <= d_m:
            lo = half + 1
        else:
            hi = half
    last = min(max(lo - 1, 0), num_samples - 1)
    best = math.inf
    for i in range(last + 1):
        gap = math.hypot(poses[k, i, 0] - tx, poses[k, i, 1] - ty)
        if gap < best or math.isnan(gap):
            best = gap
            if math.isnan(gap):
                break
    return best


def _start_points(xy: np.ndarray, start: np.ndarray, start_ptr: np.ndarray, n_bands: int) -> list[np.ndarray]:
    """Per band, the points of ``xy`` indexed by ``start[start_ptr[b]:start_ptr[b + 1]]`` ([] when none)."""
    if len(start) == 0:
        return []
    return [xy[start[start_ptr[b]:start_ptr[b + 1]]] for b in range(n_bands)]


class _CellTable:
    """The path-distance ranges of several PTGs (sharing the grid geometry) per cell.

    Global cell c: the bands' grids side by side, ``cell_offset[band] + ix * n_side + iy``. ``records[c]`` (int32)
    is ``[data offset, (first path << 16) | count for each PTG, padding]``, padded to a power of two (one cache
    line holds whole records); the PTGs' runs of path distances of the cell follow one another in ``data``
    (uint8). ``mark[c]`` (uint8, 124 KB for the Giraff's 4 bands: it stays in cache) is ``START`` for the
    start cells (the back-away rule handles their points), ``NOTHING`` for cells that no path reaches before
    the horizon (with ``skip_free``), otherwise the stamp (1..253) of the last pass that met the cell
    (:meth:`next_stamp`): cells are deduplicated without a sort, and free cells cost one byte.
    """

    def __init__(self, spaces: Sequence[PTGSpace], skip_free: bool = True) -> None:
        grids = spaces[0].grids
        self.spaces = list(spaces)
        self.n_side = np.array([grid.n_side for grid in grids], dtype=np.int64)
        self.half_extent = np.array([grid.half_extent_m for grid in grids], dtype=np.float64)
        self.resolution_m = float(grids[0].resolution_m)
        sizes = self.n_side**2
        self.cell_offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        n_cells, n_ptgs = int(sizes.sum()), len(spaces)
        if max(space.num_paths for space in spaces) >= 2**15:
            raise ValueError("too many paths for the cell table (at most 32767)")
        counts = np.stack([np.diff(space._ranges[0][:, 0]) for space in spaces])  # (P, cells)
        total = counts.sum(axis=0)
        offset = np.zeros(n_cells + 1, dtype=np.int64)
        np.cumsum(total, out=offset[1:])
        if offset[-1] >= 2**31:
            raise ValueError("collision grids too large for the int32 cell table")
        self.records = np.zeros((n_cells, 1 << int(math.ceil(math.log2(1 + n_ptgs)))), dtype=np.int32)
        self.records[:, 0] = offset[:-1]
        self.data = np.empty(int(offset[-1]), dtype=np.uint8)
        data_base = np.concatenate([[0], np.cumsum([len(space._ranges[1]) for space in spaces])]).astype(np.int64)
        _merge_runs(np.stack([space._ranges[0] for space in spaces]),
                    np.concatenate([space._ranges[1] for space in spaces]), data_base, self.records, self.data)
        start = np.concatenate([grid.start_row for grid in grids]) >= 0
        self._mark0 = np.where(start, START, np.where((total == 0) & skip_free, NOTHING, 0)).astype(np.uint8)
        self.mark = self._mark0.copy()
        self._stamp = 0

    def next_stamp(self) -> int:
        """A stamp that no cell holds (the marks are reset when the stamps run out, every 253 passes)."""
        self._stamp += 1
        if self._stamp == NOTHING:
            self.mark[:] = self._mark0
            self._stamp = 1
        return self._stamp


@njit(cache=True, error_model="numpy")
def _merge_runs(rows: np.ndarray, data: np.ndarray, data_base: np.ndarray, records: np.ndarray,
                out: np.ndarray) -> None:
    """Per cell, the PTGs' runs side by side from ``out[records[c, 0]]``, and their (first << 16) | count.

    Args:
        rows: (P, cells + 1, 2) each PTG's :func:`_range_table` rows; data: their data, concatenated, starting at
            ``data_base[p]``.
        records: (cells, R) with column 0 (the cell's offset into ``out``) set; columns 1..P are written.
        out: the merged runs.
    """
    for c in range(records.shape[0]):
        at = records[c, 0]
        for p in range(rows.shape[0]):
            start, count = data_base[p] + rows[p, c, 0], rows[p, c + 1, 0] - rows[p, c, 0]
            records[c, 1 + p] = (rows[p, c, 1] << 16) | count
            for j in range(count):
                out[at + j] = data[start + j]
            at += count


def _range_table(grids: Sequence[CollisionGrid]) -> tuple[np.ndarray, np.ndarray]:
    """The grids' first-contact distances, per cell over the range of paths that reach it before the horizon.

    The per-PTG input of :class:`_CellTable`.

    Distances are uint8, rounded down to 1/255 of the horizon (never optimistic); 255 = free. Cell c (global, the
    grids side by side) holds paths ``lo = rows[c, 1]`` to ``lo + rows[c + 1, 0] - rows[c, 0] - 1`` at
    ``data[rows[c, 0]:rows[c + 1, 0]]`` (255 between paths that miss it); free cells and start cells hold none.
    About 5-10 paths a cell on average, so the ~350 KB per PTG stay in cache where a dense (cells, N) table
    (~15 MB) would not.

    Returns:
        rows ((cells + 1, 2) int32: data offset, first path), data (uint8).
    """
    widths, firsts, datas, base = [], [], [], 0
    for grid in grids:
        n_cells = grid.n_side**2
        cell = np.repeat(np.arange(n_cells), np.diff(grid.cell_ptr))  # ascending (CSR order)
        quantised = np.floor(np.clip(grid.cell_d_norm, 0.0, 1.0) * _FREE).astype(np.uint8)
        keep = (quantised < _FREE) & (grid.start_row[cell] < 0)  # free entries change no minimum
        cell, k, quantised = cell[keep], grid.cell_k[keep].astype(np.int64), quantised[keep]
        width, first = np.zeros(n_cells, dtype=np.int64), np.zeros(n_cells, dtype=np.int64)
        if len(cell):
            starts = np.flatnonzero(np.diff(cell, prepend=-1))
            owner = np.cumsum(np.diff(cell, prepend=-1) != 0) - 1  # entry -> index into starts
            lo, hi = np.minimum.reduceat(k, starts), np.maximum.reduceat(k, starts)
            width[cell[starts]], first[cell[starts]] = hi - lo + 1, lo
            offset = np.concatenate([[0], np.cumsum(hi - lo + 1)[:-1]])
            data = np.full(int((hi - lo + 1).sum()), _FREE, dtype=np.uint8)
            np.minimum.at(data, offset[owner] + k - lo[owner], quantised)
            datas.append(data)
            base += len(data)
        widths.append(width)
        firsts.append(first)
    width = np.concatenate(widths)
    rows = np.zeros((len(width) + 1, 2), dtype=np.int64)
    np.cumsum(width, out=rows[1:, 0])
    rows[:-1, 1] = np.concatenate(firsts)
    if base >= np.iinfo(np.int32).max:
        raise ValueError("collision grids too large for the int32 row table")
    data = np.concatenate(datas) if datas else np.zeros(0, dtype=np.uint8)
    return rows.astype(np.int32), data


class _InverseLookup:
    """The inverse map tabulated on a square grid over the horizon: the nearest path sample of each cell centre.

    A cell centre within ``_EXACT_TOLERANCE_M`` of its nearest sample is exact (MRPT's ``tolerance_dist``).
    """

    def __init__(self, ptg: PTG) -> None:
        from scipy.spatial import cKDTree

        self.half_m = ptg.ref_distance_m
        self.mid = int(np.ceil(self.half_m / _LOOKUP_RESOLUTION_M))
        self.n = 2 * self.mid + 1  # a cell centred on the origin and on each axis
        centres = (np.arange(self.n) - self.mid) * _LOOKUP_RESOLUTION_M
        gx, gy = np.meshgrid(centres, centres, indexing="ij")
        k_all, n_all = np.nonzero(np.arange(ptg.poses.shape[1])[None, :] < ptg.num_samples[:, None])
        dist, flat = cKDTree(ptg.poses[k_all, n_all, :2]).query(np.column_stack([gx.ravel(), gy.ravel()]))
        self.k = k_all[flat].astype(np.int64)
        self.d = ptg.dist_m[self.k, n_all[flat]] / ptg.ref_distance_m
        self.exact = dist <= _EXACT_TOLERANCE_M

    def covers(self, p: np.ndarray) -> np.ndarray:
        return np.hypot(p[:, 0], p[:, 1]) < self.half_m

    def __call__(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ij = np.clip(np.rint(p / _LOOKUP_RESOLUTION_M).astype(np.int64) + self.mid, 0, self.n - 1)
        flat = ij[:, 0] * self.n + ij[:, 1]
        return self.k[flat].copy(), self.d[flat].copy(), self.exact[flat].copy()
