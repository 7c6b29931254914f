"""Collision look-up grid of one (PTG, footprint polygon) pair, and the TP-obstacles it gives (thesis §6.C.4).

A square grid of ``resolution_m`` cells covers ``[-h, h]^2`` around the robot, ``h >= ref_distance_m + r_max``
(``r_max`` = largest vertex norm: no point beyond can be hit before the horizon; the origin is a cell corner).
Each cell holds the list of ``(k, d)``: path k and the normalised distance along it at which the footprint first
covers the cell. A TP-obstacle query is then one cell look-up per obstacle point and a running minimum per path
(MRPT's ``CPTG_DiffDrive_CollisionGridBased``).

Cell marking (``conservative=True``, MRPT's rule): the footprint is placed at every stored sample of every path; a
cell is marked when any of its four corners lies inside the placed polygon, with the distance of the sample
*before* the first such sample (contact began somewhere in between). This inflates the footprint by up to one cell
diagonal and shortens distances by up to one sample spacing (``PTGConfig.sample_step_m``), never the reverse, as
long as no footprint part is thinner than a sample step. ``conservative=False`` tests the cell centres instead
(error +-half a cell diagonal, unbiased).

Obstacles at the start ("back-away" rule, MRPT's ``COLL_BEH_BACK_AWAY`` made to work with the grid): a point whose
cell is already covered at the start of every path is not counted as a collision at distance 0 on every path.
Instead, per path, its signed penetration depth into the footprint (+ inside, - outside) at the path's first stored
sample is compared with the depth at the start. A point inside the footprint blocks (TP-obstacle 0) the paths
along which its depth does not decrease, i.e. those that dig deeper or scrape along it; a point outside (a cell
only touched by the inflated footprint) blocks the paths along which its depth increases. The remaining paths
(moving away) are limited only where the footprint covers the cell again after having left it, and are blocked if
it never leaves it. ``inside_behavior="stop"`` blocks every path instead (MRPT's ``COLL_BEH_STOP``).

Grids are cached on disk (npz) under :func:`default_cache_dir`, named by a hash of every parameter; an unreadable
or mismatching file is rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from simnav.errors import ConfigError
from simnav.navigation.ptg import PTG

log = logging.getLogger(__name__)

GRID_FORMAT_VERSION = 1
"""Bump when the grid contents or file layout change: old cache files then no longer match."""

_DEPTH_TOL_M = 1e-6  # depth changes below this count as "no change" in the back-away rule
_CHUNK_POINTS = 400_000  # lattice points tested per vectorised batch
_ARRAYS = ("cell_ptr", "cell_k", "cell_d_norm", "start_cells", "escape_limit_norm")

InsideBehavior = Literal["back_away", "stop"]


def default_cache_dir() -> Path:
    """Where grids are cached: ``$SIMNAV_CACHE_DIR/ptg`` if that variable is set, else ``~/.cache/simnav/ptg``."""
    root = os.environ.get("SIMNAV_CACHE_DIR")
    return (Path(root) if root else Path.home() / ".cache" / "simnav") / "ptg"


def points_in_polygon(points_xy: ArrayLike, polygon_xy: ArrayLike) -> np.ndarray:
    """Even-odd point-in-polygon test (points on the boundary may go either way).

    Args:
        points_xy: (..., 2) points, same frame as the polygon.
        polygon_xy: (M, 2) simple polygon vertices, either orientation.

    Returns:
        (...) bool, True inside.
    """
    p = np.asarray(points_xy, dtype=np.float64)
    return _inside(p[..., 0], p[..., 1], _as_polygon(polygon_xy))


def signed_depth(points_xy: ArrayLike, polygon_xy: ArrayLike) -> np.ndarray:
    """Signed distance from points to the polygon boundary: positive inside (penetration depth), negative outside.

    Args:
        points_xy: (..., 2) points, same frame as the polygon, m.
        polygon_xy: (M, 2) simple polygon vertices, m.

    Returns:
        (...) signed distance, m.
    """
    poly = _as_polygon(polygon_xy)
    p = np.asarray(points_xy, dtype=np.float64)
    px, py = p[..., 0], p[..., 1]
    dist = np.full(px.shape, np.inf)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
        ex, ey = bx - ax, by - ay
        L2 = ex * ex + ey * ey
        s = np.clip(((px - ax) * ex + (py - ay) * ey) / L2, 0.0, 1.0) if L2 > 0 else 0.0
        dist = np.minimum(dist, np.hypot(px - ax - s * ex, py - ay - s * ey))
    return np.where(_inside(px, py, poly), dist, -dist)


def _as_polygon(polygon_xy: ArrayLike) -> np.ndarray:
    poly = np.asarray(polygon_xy, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
        raise ConfigError(f"footprint polygon must have shape (M >= 3, 2), got {poly.shape}")
    return poly


def _inside(px: np.ndarray, py: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Crossing-number test for arrays of x and y (same shape)."""
    inside = np.zeros(np.shape(px), dtype=bool)
    for (x1, y1), (x2, y2) in zip(np.roll(poly, 1, axis=0), poly):
        if y1 == y2:
            continue  # a horizontal edge is never crossed by the horizontal ray
        crosses = (py < y1) != (py < y2)
        inside ^= crosses & (px < x1 + (py - y1) * ((x2 - x1) / (y2 - y1)))
    return inside


class CollisionGrid:
    """TP-obstacles of one footprint polygon for one PTG, from a cached look-up grid.

    Attributes:
        ptg: the :class:`~simnav.navigation.ptg.PTG`.
        polygon: (M, 2) footprint in the base frame, m.
        max_radius_m: largest vertex norm of the footprint, m.
        resolution_m: cell size, m.
        conservative: corner marking (MRPT) if True, cell centres if False.
        half_extent_m: the grid covers ``[-half_extent_m, half_extent_m]^2`` (base frame), m.
        n_side: cells per side.
        cell_ptr: (n_side^2 + 1,) CSR offsets; cell ``c = ix * n_side + iy`` owns entries ``cell_ptr[c]:cell_ptr[c+1]``.
        cell_k: (E,) int16 path index of each entry.
        cell_d_norm: (E,) float32 normalised distance at which the footprint first covers the cell on that path.
        start_cells: (Q,) cells covered at the start (handled by the back-away rule, not by their entries).
        start_row: (n_side^2,) int32 row of each cell in ``start_cells`` / ``escape_limit_norm``, -1 if not a start
            cell.
        escape_limit_norm: (Q, N) float32 TP-obstacle of each start cell for paths that move away from it: the
            distance at which the footprint covers it again (inf: never), 0 if it never leaves it.
        cache_key: hash of every parameter; names the cache file.
        cache_path: the cache file (None when caching is off).
        loaded_from_cache: whether this grid was read from disk.
        build_time_s: seconds spent building (0 if loaded).
    """

    def __init__(self, ptg: PTG, polygon_xy: ArrayLike, resolution_m: float = 0.05, conservative: bool = True,
                 cache_dir: str | Path | None = None, use_cache: bool = True) -> None:
        """Loads the grid from the cache, or builds (and caches) it.

        Args:
            ptg: the paths.
            polygon_xy: (M, 2) footprint (one prism's polygon) in the base frame, m.
            resolution_m: cell size, m.
            conservative: MRPT's corner marking (inflates by up to a cell diagonal) if True, cell centres if False.
            cache_dir: cache directory; None = :func:`default_cache_dir`.
            use_cache: read and write the cache.
        """
        if not resolution_m > 0:
            raise ConfigError(f"collision grid resolution_m must be > 0, got {resolution_m}")
        self.ptg = ptg
        self.polygon = _as_polygon(polygon_xy).copy()
        self.polygon.flags.writeable = False
        self.resolution_m = float(resolution_m)
        self.conservative = bool(conservative)
        self.max_radius_m = float(np.max(np.hypot(self.polygon[:, 0], self.polygon[:, 1])))
        # even: the origin is a cell corner, so the lattice is symmetric about the robot's axes
        self.n_side = 2 * int(math.ceil((ptg.ref_distance_m + self.max_radius_m) / self.resolution_m))
        self.half_extent_m = 0.5 * self.n_side * self.resolution_m
        self.cache_key = self._key()
        self.cache_path = (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / (
            f"grid_{ptg.config.name}_N{ptg.num_paths}_{self.cache_key[:20]}.npz") if use_cache else None
        self.loaded_from_cache = False
        self.build_time_s = 0.0
        arrays = self._load() if self.cache_path is not None else None
        if arrays is None:
            t0 = time.perf_counter()
            arrays = self._build()
            self.build_time_s = time.perf_counter() - t0
            log.info("collision grid %s (%d cells, %d entries) built in %.2f s", ptg.config.name, self.n_side**2,
                     len(arrays["cell_k"]), self.build_time_s)
            if self.cache_path is not None:
                self._save(arrays)
        else:
            self.loaded_from_cache = True
        for name in _ARRAYS:
            arrays[name].flags.writeable = False
            setattr(self, name, arrays[name])
        self.start_row = np.full(self.n_side**2, -1, dtype=np.int32)
        self.start_row[self.start_cells] = np.arange(len(self.start_cells), dtype=np.int32)
        self._escape_poses = ptg.poses[:, 1, :]  # first stored sample after the origin, (N, 3)

    def __repr__(self) -> str:
        return (f"CollisionGrid({self.ptg.config.name}, {len(self.polygon)}-gon, res={self.resolution_m} m, "
                f"{self.n_side}x{self.n_side} cells, {len(self.cell_k)} entries)")

    # ------------------------------------------------------------------ queries

    def cell_index(self, points_xy_base: ArrayLike) -> np.ndarray:
        """Flat cell index ``ix * n_side + iy`` of each point, -1 outside the grid.

        Args:
            points_xy_base: (P, 2) points in the base frame, m (extra columns, e.g. z, are ignored).

        Returns:
            (P,) int64.
        """
        p = np.asarray(points_xy_base, dtype=np.float64).reshape(-1, np.shape(points_xy_base)[-1])
        ij = np.floor((p[:, :2] + self.half_extent_m) / self.resolution_m)
        ok = np.all((ij >= 0) & (ij < self.n_side), axis=1)
        ij = np.where(ok[:, None], ij, 0).astype(np.int64)
        return np.where(ok, ij[:, 0] * self.n_side + ij[:, 1], -1)

    def entries(self, x_m: float, y_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The ``(k, d_norm)`` entries of the cell holding point (x, y), base frame (empty outside the grid)."""
        c = int(self.cell_index([[x_m, y_m]])[0])
        if c < 0:
            return np.zeros(0, dtype=np.int16), np.zeros(0, dtype=np.float32)
        sl = slice(self.cell_ptr[c], self.cell_ptr[c + 1])
        return self.cell_k[sl], self.cell_d_norm[sl]

    def tp_obstacles(self, points_xy_base: ArrayLike, inside_behavior: InsideBehavior = "back_away") -> np.ndarray:
        """Normalised collision-free distance of every path given obstacle points (TP-NavLimits, eq. 6.3).

        Args:
            points_xy_base: (P, 2) obstacle points in the base frame, m (extra columns such as z are ignored);
                points outside the grid cannot be reached before the horizon and are ignored.
            inside_behavior: ``"back_away"`` (default) or ``"stop"``, for points the footprint covers at the start
                (see the module docstring).

        Returns:
            (N,) distance along each path before the footprint hits an obstacle, normalised by
            ``ref_distance_m``, in [0, 1]; 1.0 = free up to the horizon.
        """
        tp = np.ones(self.ptg.num_paths)
        p = np.asarray(points_xy_base, dtype=np.float64)
        if p.size == 0:
            return tp
        p = p.reshape(-1, p.shape[-1])[:, :2]
        cells = self.cell_index(p)
        keep = cells >= 0
        p, cells = p[keep], cells[keep]
        rows = self.start_row[cells]
        at_start = rows >= 0
        self._gather_min(np.unique(cells[~at_start]), tp)
        if at_start.any():
            if inside_behavior == "stop":
                tp[:] = 0.0
            elif inside_behavior == "back_away":
                np.minimum(tp, self._back_away(p[at_start], rows[at_start]), out=tp)
            else:
                raise ValueError(f"inside_behavior must be 'back_away' or 'stop', got {inside_behavior!r}")
        return np.minimum(tp, 1.0)

    def _gather_min(self, cells: np.ndarray, tp: np.ndarray) -> None:
        """Running minimum of the entries of ``cells`` (unique) into ``tp`` (N,)."""
        if cells.size == 0:
            return
        first = self.cell_ptr[cells]
        count = self.cell_ptr[cells + 1] - first
        total = int(count.sum())
        if total == 0:
            return
        idx = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(total)
        np.minimum.at(tp, self.cell_k[idx], self.cell_d_norm[idx].astype(np.float64))

    def _back_away(self, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(N,) TP-obstacles of points in start cells under the back-away rule (see the module docstring)."""
        depth0 = signed_depth(p, self.polygon)  # (Ps,)
        x, y, phi = (self._escape_poses[:, i] for i in range(3))  # (N,)
        dx, dy = p[:, None, 0] - x[None], p[:, None, 1] - y[None]  # (Ps, N)
        c, s = np.cos(phi)[None], np.sin(phi)[None]
        depth1 = signed_depth(np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1), self.polygon)  # (Ps, N)
        inside = depth0 >= 0
        leaving = np.where(inside[:, None], depth1 < depth0[:, None] - _DEPTH_TOL_M,
                           depth1 <= depth0[:, None] + _DEPTH_TOL_M)
        limit = np.where(leaving, self.escape_limit_norm[rows], 0.0)
        return limit.min(axis=0)

    # ------------------------------------------------------------------ building

    def _build(self) -> dict[str, np.ndarray]:
        """Marks every cell the footprint covers along every path; see the module docstring."""
        ptg, res, ns = self.ptg, self.resolution_m, self.n_side
        offset = 0.0 if self.conservative else 0.5  # lattice = cell corners or cell centres
        nl = ns + 1 if self.conservative else ns  # lattice points per side
        W = int(math.ceil(2.0 * self.max_radius_m / res)) + 2  # window of lattice points around one pose

        def lattice_hits(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """(lattice index, pose index) of every lattice point inside the footprint placed at each pose."""
            lat, which = [], []
            B = max(1, _CHUNK_POINTS // (W * W))
            for b0 in range(0, len(poses), B):
                x, y, phi = (poses[b0:b0 + B, i][:, None, None] for i in range(3))
                i0 = np.floor((x[:, 0, 0] - self.max_radius_m + self.half_extent_m) / res - offset).astype(np.int64)
                j0 = np.floor((y[:, 0, 0] - self.max_radius_m + self.half_extent_m) / res - offset).astype(np.int64)
                gx = -self.half_extent_m + (i0[:, None] + np.arange(W) + offset) * res  # (B, W)
                gy = -self.half_extent_m + (j0[:, None] + np.arange(W) + offset) * res
                dx, dy = gx[:, :, None] - x, gy[:, None, :] - y  # (B, W, 1), (B, 1, W)
                c, s = np.cos(phi), np.sin(phi)
                b, wi, wj = np.nonzero(_inside(c * dx + s * dy, -s * dx + c * dy, self.polygon))
                li, lj = i0[b] + wi, j0[b] + wj
                ok = (li >= 0) & (li < nl) & (lj >= 0) & (lj < nl)
                lat.append(li[ok] * nl + lj[ok])
                which.append(b[ok] + b0)
            return np.concatenate(lat), np.concatenate(which)

        # Start cells: covered by the footprint at the origin (pose 0 of every path).
        start_lat, _ = lattice_hits(np.zeros((1, 3)))
        start_lat = np.unique(start_lat)
        if self.conservative:  # cells with a covered corner, and all their corners
            li, lj = start_lat // nl, start_lat % nl
            cand = np.stack([li * ns + lj, (li - 1) * ns + lj, li * ns + lj - 1, (li - 1) * ns + lj - 1], axis=1)
            cand_ok = np.stack([(li < ns) & (lj < ns), (li >= 1) & (lj < ns), (li < ns) & (lj >= 1),
                                (li >= 1) & (lj >= 1)], axis=1)
            start_cells = np.unique(cand[cand_ok])
            ci, cj = start_cells // ns, start_cells % ns
            corners = np.stack([ci * nl + cj, (ci + 1) * nl + cj, ci * nl + cj + 1, (ci + 1) * nl + cj + 1], axis=1)
        else:
            start_cells = start_lat
            corners = start_lat[:, None]
        track_lat, corner_rows = np.unique(corners, return_inverse=True)
        corner_rows = corner_rows.reshape(corners.shape)
        track_row = np.full(nl * nl, -1, dtype=np.int64)
        track_row[track_lat] = np.arange(len(track_lat))

        N = ptg.num_paths
        cells_all, k_all, d_all = [], [], []
        escape = np.zeros((len(start_cells), N), dtype=np.float32)
        for k in range(N):
            S = int(ptg.num_samples[k])
            d_norm = ptg.dist_m[k, :S] / ptg.ref_distance_m
            lat, n = lattice_hits(ptg.poses[k, :S])
            first = np.full(nl * nl, np.inf)
            np.minimum.at(first, lat, d_norm[np.maximum(n - 1, 0)])  # contact began after the previous sample
            if self.conservative:
                g = first.reshape(nl, nl)
                cell_d = np.minimum(np.minimum(g[:-1, :-1], g[1:, :-1]), np.minimum(g[:-1, 1:], g[1:, 1:])).ravel()
            else:
                cell_d = first
            hit = np.flatnonzero(np.isfinite(cell_d))
            cells_all.append(hit)
            k_all.append(np.full(hit.size, k, dtype=np.int16))
            d_all.append(cell_d[hit].astype(np.float32))
            # Coverage of the start cells along the path -> distance at which it covers them again.
            rows = track_row[lat]
            sel = rows >= 0
            cov_lat = np.zeros((len(track_lat), S), dtype=bool)
            cov_lat[rows[sel], n[sel]] = True
            cov = np.any(cov_lat[corner_rows], axis=1)  # (Q, S)
            left = ~cov
            has_left = left.any(axis=1)
            n_left = np.argmax(left, axis=1)
            again = cov & (np.arange(S)[None, :] > n_left[:, None])
            has_again = again.any(axis=1)
            escape[:, k] = np.where(has_left, np.where(has_again, d_norm[np.argmax(again, axis=1)], np.inf), 0.0)

        cells = np.concatenate(cells_all)
        order = np.argsort(cells, kind="stable")
        cell_ptr = np.zeros(ns * ns + 1, dtype=np.int32 if len(cells) < 2**31 else np.int64)
        np.cumsum(np.bincount(cells, minlength=ns * ns), out=cell_ptr[1:])
        return dict(cell_ptr=cell_ptr, cell_k=np.concatenate(k_all)[order], cell_d_norm=np.concatenate(d_all)[order],
                    start_cells=start_cells.astype(np.int64), escape_limit_norm=escape)

    # ------------------------------------------------------------------ cache

    def _key(self) -> str:
        params = dict(version=GRID_FORMAT_VERSION, ptg=self.ptg.config.path_parameters(),
                      polygon=self.polygon.tolist(), resolution_m=self.resolution_m, conservative=self.conservative)
        return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()

    def _load(self) -> dict[str, np.ndarray] | None:
        """The cached arrays, or None if there is no valid cache file (a bad one is logged and ignored)."""
        path = self.cache_path
        if path is None or not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["key"]) != self.cache_key:
                    raise ValueError("parameter hash mismatch")
                arrays = {name: z[name] for name in _ARRAYS}
            self._check(arrays)
            return arrays
        except Exception as err:  # any unreadable cache is rebuilt
            log.warning("collision grid cache %s unusable (%s): rebuilding it", path, err)
            return None

    def _check(self, a: dict[str, np.ndarray]) -> None:
        """Raises ValueError if the arrays are inconsistent with this grid."""
        ns2, E = self.n_side**2, len(a["cell_k"])
        ok = (a["cell_ptr"].shape == (ns2 + 1,) and a["cell_ptr"][0] == 0 and a["cell_ptr"][-1] == E
              and a["cell_d_norm"].shape == (E,) and a["escape_limit_norm"].shape == (len(a["start_cells"]),
                                                                                      self.ptg.num_paths)
              and np.all(np.diff(a["cell_ptr"]) >= 0) and (E == 0 or (a["cell_k"].min() >= 0
                                                                     and a["cell_k"].max() < self.ptg.num_paths))
              and (a["start_cells"].size == 0 or (a["start_cells"].min() >= 0 and a["start_cells"].max() < ns2)))
        if not ok:
            raise ValueError("inconsistent arrays")

    def _save(self, arrays: dict[str, np.ndarray]) -> None:
        """Writes the cache file atomically (write a temporary file, then rename); failures only log a warning."""
        path = self.cache_path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=path.stem, suffix=".tmp", dir=path.parent)
            try:
                with os.fdopen(fd, "wb") as f:
                    np.savez(f, key=np.array(self.cache_key), **arrays)
                os.replace(tmp, path)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
        except OSError as err:
            log.warning("cannot write collision grid cache %s (%s)", path, err)
