"""One path family across every height band: the PTG, one collision grid per band, TP-NavLimits by eq. 6.4.

For speed at run time each collision grid is expanded once into a dense table, one row of N path distances per
cell (uint8, rounded down to 1/255 of the horizon, so never optimistic): the TP-NavLimits of a band are then the
column minimum over the rows of its occupied cells. The inverse map of points within the horizon is looked up in
a table of nearest path samples built once; points beyond it use MRPT's end-point extrapolation.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simnav.navigation.bands import Band
from simnav.navigation.collision_grid import CollisionGrid
from simnav.navigation.ptg import PTG, PTGConfig

FAMILIES = {"C": ("C", False), "alpha": ("alpha", False), "CS": ("CS", False), "CCS": ("CCS", False),
            "C-backward": ("C", True)}
"""Names accepted in ``NavigatorConfig.ptgs``: family and whether it drives backwards."""

_FREE = 255
_LOOKUP_RESOLUTION_M = 0.05
_EXACT_TOLERANCE_M = 0.10


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
        self._dense = [_dense_table(grid) for grid in self.grids]
        self._lookup = _InverseLookup(self.ptg)
        last = self.ptg.num_samples - 1
        self._ends = self.ptg.poses[np.arange(num_paths), last, :2]
        self._end_dist = self.ptg.dist_m[np.arange(num_paths), last]

    @property
    def num_paths(self) -> int:
        return self.ptg.num_paths

    # ----------------------------------------------------------------------------------------- TP-obstacles
    def prepare(self, band_xy: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per band: the unique grid cells of the points ahead, and the points the sections cover at the start.

        Every PTG of a navigator shares the band polygons and the grid geometry, so this is done once per step
        and passed to :meth:`tp_limits` of each PTG.

        Args:
            band_xy: per band, (P_i, 2) obstacle points in the base frame, m.
        """
        out = []
        for grid, pts in zip(self.grids, band_xy, strict=True):
            cells = grid.cell_index(pts) if len(pts) else np.zeros(0, dtype=np.int64)
            in_grid = cells >= 0
            at_start = in_grid & (grid.start_row[np.maximum(cells, 0)] >= 0)
            out.append((np.unique(cells[in_grid & ~at_start]), np.asarray(pts)[at_start]))
        return out

    def shares_grid_geometry(self, other: PTGSpace) -> bool:
        """Whether :meth:`prepare` of ``other`` is valid for this PTG."""
        return all(a.n_side == b.n_side and a.half_extent_m == b.half_extent_m and a.resolution_m == b.resolution_m
                   and np.array_equal(a.start_cells, b.start_cells) for a, b in zip(self.grids, other.grids,
                                                                                     strict=True))

    def tp_limits(self, prepared: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """(N,) normalised collision-free distance per path: the minimum over the bands (eq. 6.4).

        Args:
            prepared: the output of :meth:`prepare` for this step's points.
        """
        limits = np.full(self.num_paths, _FREE, dtype=np.uint8)
        inside = np.ones(self.num_paths)
        for grid, dense, (cells, start_pts) in zip(self.grids, self._dense, prepared, strict=True):
            if len(cells):
                np.minimum(limits, dense[cells].min(axis=0), out=limits)
            if len(start_pts):
                # points the section covers at the start: the grid's back-away rule
                np.minimum(inside, grid.tp_obstacles(start_pts), out=inside)
        return np.minimum(limits.astype(np.float64) / _FREE, inside)

    # ----------------------------------------------------------------------------------------- inverse map
    def inverse_map(self, x_m: float, y_m: float) -> tuple[int, float, bool]:
        """(k, normalised distance, exact) of one base-frame point."""
        k, d, exact = self.inverse_map_many(np.array([[x_m, y_m]]))
        return int(k[0]), float(d[0]), bool(exact[0])

    def inverse_map_many(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(k (P,), normalised distance (P,), exact (P,)) of (P, 2) base-frame points; every point gets an answer.

        Within the horizon: the PTG's inverse map (from a table at 5 cm). Beyond it: the path whose end is
        cheapest to reach plus the straight line from there (``d > 1``, not exact).
        """
        p = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        k, d, exact = self._lookup(p)
        far = ~self._lookup.covers(p)
        if far.any():
            gap = np.linalg.norm(p[far, None, :] - self._ends[None], axis=-1)  # (F, N)
            total = self._end_dist[None] + gap
            best = np.argmin(total, axis=1)
            k[far], d[far], exact[far] = best, total[np.arange(len(best)), best] / self.ptg.ref_distance_m, False
        return k, d, exact

    # ------------------------------------------------------------------------------------------ path queries
    def command(self, k: int) -> tuple[float, float]:
        """(v m/s, w rad/s) of path k at full speed."""
        return self.ptg.direction_to_motion_command(k)

    def closest_approach(self, k: int, d_norm: float, target_xy: np.ndarray) -> float:
        """Smallest distance from the target to path k up to ``d_norm``, m."""
        n = self.ptg.step_for_distance(k, max(d_norm, 0.0) * self.ptg.ref_distance_m)
        xy = self.ptg.poses[k, : n + 1, :2]
        return float(np.min(np.hypot(xy[:, 0] - target_xy[0], xy[:, 1] - target_xy[1])))


def _dense_table(grid: CollisionGrid) -> np.ndarray:
    """(cells, N) uint8 first-contact distance per cell and path, rounded down; 255 = free; start cells free."""
    n_cells, n_paths = grid.n_side**2, grid.ptg.num_paths
    table = np.full(n_cells * n_paths, _FREE, dtype=np.uint8)
    counts = np.diff(grid.cell_ptr)
    cell_of_entry = np.repeat(np.arange(n_cells), counts)
    quantised = np.floor(np.clip(grid.cell_d_norm, 0.0, 1.0) * _FREE).astype(np.uint8)
    np.minimum.at(table, cell_of_entry * n_paths + grid.cell_k.astype(np.int64), quantised)
    table = table.reshape(n_cells, n_paths)
    table[grid.start_cells] = _FREE
    return table


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
