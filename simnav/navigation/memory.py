"""Short-term memory of nearby obstacles: one local occupancy grid per height band (thesis §6.C.5).

Depth cameras see nothing closer than about half a metre and only a narrow cone ahead; while the robot turns
or approaches an obstacle, the obstacle leaves the view. Every band keeps a robot-centred occupancy grid in the
odom frame (log-odds, 0 = unknown): cells hit by the band's points gain evidence, cells in a cone ahead of the
robot beyond the blind range that got no hit lose it, and all evidence decays towards unknown with a time
constant. Occupied cells near the robot come back as *virtual obstacles* that join the sensed points.

The cone is the depth camera's view, and a camera pitched down sees all of a band's height only over part of it:
the Giraff's camera (1.12 m up, 30 deg down, 45.6 deg vertical field of view) sees the floor from 0.885 m ahead of
the base origin and the top of its pole band (1.02 m) only up to 0.84 m, and nothing above 1.12 m. ``free_x_m``
(per band, the range of forward distances where the band's whole height is in view,
:func:`simnav.navigation.sensing.camera_free_space`) limits the cone band by band
(``MemoryConfig.whole_band_view``, off by default), so that a low box the robot has come closer to than the camera
sees keeps its evidence until it decays instead of being seen free within a few steps.

Points of a level 2D lidar (given apart, *scan points*) are ends of rays in the lidar's plane, so the space before
them was seen free: a cell whose evidence came only from scan points also loses it when it lies closer to the base
than the nearest scan point of its band in the same direction (``ray_bin_rad`` wide) by ``ray_margin_m`` (rays are
taken to start at the base origin). A person who walks around the robot then leaves no ring of remembered
obstacles behind for the seconds of the decay; a cell any other sensor hit (a low box below the scan plane, a bar
above it) keeps its evidence until it decays.

:class:`ScanHistory` keeps where a level lidar saw free space over the last seconds, not decaying: yielding at a
doorway backs the robot into it when it lies off the robot's own trail (``NavigatorConfig.give_way_seen_free_s``).

As §6.C.7 reports, the memory carries the pose estimate's errors into the obstacles; with a drifting odometry
it can close gaps the robot would fit through, so it can be switched off (``NavigatorConfig.memory``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from simnav.geometry import se2


@dataclass(frozen=True)
class MemoryConfig:
    """Short-term memory options (defaults from MRPT's ReactiveNav3D demo, ``[STM_CONFIG]``).

    Attributes:
        cell_m: cell size, m.
        half_size_m: the grid spans ``±half_size_m`` around the robot, m.
        hit_probability: occupancy update of a cell hit by a point (0.5..1).
        miss_probability: occupancy update of a cell seen free (0..0.5).
        occupied_probability: cells above this become virtual obstacles.
        decay_s: time constant of the decay of all evidence towards unknown, s.
        blind_range_m: no free-space evidence closer than this (the depth camera's near blind zone), m.
        cone_half_angle_rad: half angle of the cone ahead where cells without hits are seen free, rad.
        cone_range_m: reach of that cone, m.
        emit_range_m: occupied cells closer than this to the base origin become virtual obstacles, m.
        ray_bin_rad: angular width of the directions in which the nearest scan point is looked up, rad.
        ray_margin_m: a cell counts as seen free by the scan only this much closer than that point, m.
        whole_band_view: the cone counts a band's cells as seen free only where the camera sees the band's whole
            height (the navigator's ``free_space_x_m``); off (the default, as MRPT): everywhere in the cone. On,
            low obstacles closer than the floor the camera sees are remembered until they decay, and so are the
            people the camera saw there (README: more turning among people).
        blind_decay_s: time constant of the decay of cells outside every sensor's field of view (the ``view``
            sectors given to the memory), s; None: ``decay_s`` everywhere. A jamb that leaves the lidar's view
            behind the robot is then remembered for longer than one that stays in view.
    """

    cell_m: float = 0.04
    half_size_m: float = 1.2
    hit_probability: float = 0.8
    miss_probability: float = 0.4
    occupied_probability: float = 0.8
    decay_s: float = 3.0
    blind_range_m: float = 0.5
    cone_half_angle_rad: float = math.pi / 6 - 0.05
    cone_range_m: float = 1.2
    emit_range_m: float = 0.7
    ray_bin_rad: float = math.radians(2.0)
    ray_margin_m: float = 0.1
    whole_band_view: bool = False
    blind_decay_s: float | None = None

    def __post_init__(self) -> None:
        checks = [(self.cell_m > 0, "cell_m must be > 0"), (self.half_size_m > self.cell_m, "half_size_m > cell_m"),
                  (0.5 < self.hit_probability < 1, "hit_probability must be in (0.5, 1)"),
                  (0 < self.miss_probability < 0.5, "miss_probability must be in (0, 0.5)"),
                  (0.5 < self.occupied_probability < 1, "occupied_probability must be in (0.5, 1)"),
                  (self.decay_s > 0, "decay_s must be > 0"),
                  (self.blind_decay_s is None or self.blind_decay_s > 0, "blind_decay_s must be > 0 (or None)"),
                  (0 < self.ray_bin_rad <= math.pi / 4, "ray_bin_rad must be in (0, pi/4]"),
                  (self.ray_margin_m >= 0, "ray_margin_m must be >= 0")]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"MemoryConfig: {message}")


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class ShortTermMemory:
    """Per-band local occupancy grids in the odom frame, following the robot as it moves.

    The grids are toroidal: odom cell ``(i, j)`` lives in slot ``(i mod n, j mod n)``, so following the robot
    moves no data; a slot whose odom cell changed is cleared when the window reaches it. One update is a single
    Numba pass over the window (~0.05 ms for 4 bands of 60 × 60 cells).

    Args:
        num_bands: number of height bands.
        config: options.
        free_x_m: (num_bands, 2) per band, the interval [near, far] of forward distance in the base frame (x, m)
            inside which the cone's cells count as seen free (beside ``blind_range_m`` < range < ``cone_range_m``
            and the cone's angle); an empty interval (near > far): never. None: every band everywhere in the cone.
        view: the sensors' horizontal fields of view in the base frame (:class:`simnav.navigation.sensing.
            ViewSector`); cells outside all of them decay with ``blind_decay_s``. None: everything is in view.
    """

    def __init__(self, num_bands: int, config: MemoryConfig | None = None,
                 free_x_m: np.ndarray | None = None, view: Sequence | None = None) -> None:
        self.config = config or MemoryConfig()
        if free_x_m is None:
            free_x_m = np.tile([-math.inf, math.inf], (num_bands, 1))
        self._free_x_m = np.array(free_x_m, dtype=np.float64)
        if self._free_x_m.shape != (num_bands, 2) or np.isnan(self._free_x_m).any():
            raise ValueError(f"ShortTermMemory: free_x_m must be ({num_bands}, 2) without NaN, "
                             f"got shape {self._free_x_m.shape}")
        self._n = 2 * int(math.ceil(self.config.half_size_m / self.config.cell_m))
        self._grids = np.zeros((num_bands, self._n, self._n), dtype=np.float32)
        self._keys = np.full((self._n, self._n, 2), _NO_CELL, dtype=np.int64)  # odom cell held by each slot
        self._hit_step = np.zeros((num_bands, self._n, self._n), dtype=np.int64)
        self._scan_only = np.zeros((num_bands, self._n, self._n), dtype=np.bool_)  # evidence from scan points only
        self._step = 0
        self._last_stamp_s: float | None = None
        cfg = self.config
        sectors = [] if view is None or cfg.blind_decay_s is None else view
        self._view = np.array([[v.x_m, v.y_m, v.yaw_rad, v.half_angle_rad, v.range_m] for v in sectors],
                              dtype=np.float64).reshape(-1, 5)
        self._params = np.array([cfg.cell_m, cfg.blind_range_m, cfg.cone_range_m, math.cos(cfg.cone_half_angle_rad),
                                 cfg.emit_range_m, _logit(cfg.hit_probability), _logit(cfg.miss_probability),
                                 2 * _logit(0.98), _logit(cfg.occupied_probability) + 1e-6,
                                 cfg.ray_bin_rad, cfg.ray_margin_m])

    def reset(self) -> None:
        """Forget everything."""
        self._grids[:] = 0.0
        self._keys[:] = _NO_CELL
        self._scan_only[:] = False
        self._last_stamp_s = None

    def update(self, stamp_s: float, T_odom_base: np.ndarray,
               band_points_base: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Add one step's obstacles and return the remembered ones.

        Args:
            stamp_s: time of the observation, s.
            T_odom_base: (3, 3) SE(2) pose of the base in the odom frame.
            band_points_base: per band, (P_i, 2) obstacle (x, y) in the base frame, m.

        Returns:
            Per band, (Q_i, 2) virtual obstacles in the base frame, m: centres of occupied cells within
            ``emit_range_m``.
        """
        pts = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in band_points_base]
        ptr = np.zeros(len(pts) + 1, dtype=np.int64)
        np.cumsum([len(p) for p in pts], out=ptr[1:])
        xy = np.concatenate(pts) if len(pts) else np.zeros((0, 2))
        out, out_ptr = self.update_flat(stamp_s, T_odom_base, xy, ptr)
        return [out[out_ptr[b]:out_ptr[b + 1]] for b in range(len(pts))]

    def update_flat(self, stamp_s: float, T_odom_base: np.ndarray, xy: np.ndarray, ptr: np.ndarray,
                    scan_xy: np.ndarray | None = None,
                    scan_ptr: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`update` on flat arrays: band b's points are ``xy[ptr[b]:ptr[b + 1]]`` (base frame, m), its scan
        points (a level 2D lidar's, not also in ``xy``) ``scan_xy[scan_ptr[b]:scan_ptr[b + 1]]``; returns the
        virtual obstacles the same way, (Q, 2) and (B + 1,)."""
        if scan_xy is None or scan_ptr is None:
            scan_xy, scan_ptr = np.zeros((0, 2)), np.zeros(len(ptr), dtype=np.int64)
        decay = blind_decay = 1.0
        if self._last_stamp_s is not None:
            dt = max(stamp_s - self._last_stamp_s, 0.0)
            decay = math.exp(-dt / self.config.decay_s)
            blind_decay = math.exp(-dt / (self.config.blind_decay_s or self.config.decay_s))
        self._last_stamp_s = stamp_s
        self._step += 1
        return _update_kernel(self._grids, self._keys, self._hit_step, self._scan_only, self._step,
                              np.ascontiguousarray(T_odom_base, dtype=np.float64),
                              np.ascontiguousarray(xy, dtype=np.float64), np.asarray(ptr, dtype=np.int64),
                              np.ascontiguousarray(scan_xy, dtype=np.float64), np.asarray(scan_ptr, dtype=np.int64),
                              np.float32(decay), np.float32(blind_decay), self._view, self._params,
                              self._free_x_m)


_NO_CELL = np.iinfo(np.int64).min
"""Key of a slot that holds no odom cell yet."""


@njit(cache=True, error_model="numpy")
def _update_kernel(grids: np.ndarray, keys: np.ndarray, hit_step: np.ndarray, scan_only: np.ndarray, step: int,
                   T: np.ndarray, xy: np.ndarray, ptr: np.ndarray, scan_xy: np.ndarray, scan_ptr: np.ndarray,
                   decay: np.float32, blind_decay: np.float32, view: np.ndarray, params: np.ndarray,
                   free_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One memory update: decay (``blind_decay`` outside the (V, 5) ``view`` sectors, when there are any), window
    follows the robot, hits, free space (the cone, within each band's (B, 2) ``free_x`` forward interval), virtual
    obstacles (flat per band)."""
    cell, blind, cone_range, cos_cone, emit_range = params[0], params[1], params[2], params[3], params[4]
    hit_l, miss_l, limit, occupied = np.float32(params[5]), np.float32(params[6]), np.float32(params[7]), params[8]
    ray_bin, ray_margin = params[9], params[10]
    n_bands, n = grids.shape[0], grids.shape[1]
    c, s, tx, ty = T[0, 0], T[1, 0], T[0, 2], T[1, 2]
    ox, oy = int(math.floor(tx / cell)) - n // 2, int(math.floor(ty / cell)) - n // 2  # odom cell of window (0, 0)
    # Hits: scan points first (their cells' evidence is the scan's, and the nearest per direction bounds the free
    # space), then the other points (whose cells' evidence is not only the scan's)
    n_dirs = int(math.ceil(2.0 * math.pi / ray_bin))
    nearest = np.full((n_bands, n_dirs), -1.0)  # -1: no scan point in that direction
    for source in range(2):  # 0: scan points, 1: the other points
        pts, pts_ptr = (scan_xy, scan_ptr) if source == 0 else (xy, ptr)
        for b in range(n_bands):
            for k in range(pts_ptr[b], pts_ptr[b + 1]):
                px, py = pts[k, 0], pts[k, 1]
                i = int(math.floor((c * px - s * py + tx) / cell)) - ox
                j = int(math.floor((s * px + c * py + ty) / cell)) - oy
                if 0 <= i < n and 0 <= j < n:
                    hit_step[b, (ox + i) % n, (oy + j) % n] = step
                    scan_only[b, (ox + i) % n, (oy + j) % n] = source == 0
                if source == 0:
                    q = min(int((math.atan2(py, px) + math.pi) / ray_bin), n_dirs - 1)
                    r = math.hypot(px, py)
                    if nearest[b, q] < 0 or r < nearest[b, q]:
                        nearest[b, q] = r
    # Window pass: recycle slots of cells that left, decay, free-space cone, hits, clip, emit occupied cells
    out = np.empty((n_bands, n * n, 2))
    count = np.zeros(n_bands, dtype=np.int64)
    for a in range(n):
        for d in range(n):
            gi, gj = ox + a, oy + d
            si, sj = gi % n, gj % n
            fresh = keys[si, sj, 0] != gi or keys[si, sj, 1] != gj
            if fresh:
                keys[si, sj, 0], keys[si, sj, 1] = gi, gj
            # cell centre in the base frame
            ex, ey = (gi + 0.5) * cell - tx, (gj + 0.5) * cell - ty
            rx, ry = c * ex + s * ey, -s * ex + c * ey
            rng = math.hypot(rx, ry)
            in_cone = blind < rng < cone_range and rx > rng * cos_cone
            emit = rng < emit_range
            cell_decay = decay if view.shape[0] == 0 or _in_view(view, rx, ry) else blind_decay
            q = -1  # direction of the cell, found when a band needs it
            for b in range(n_bands):
                if fresh and hit_step[b, si, sj] != step:
                    scan_only[b, si, sj] = False  # a cell new to the window: no evidence yet
                g = np.float32(0.0) if fresh else grids[b, si, sj] * cell_decay
                if hit_step[b, si, sj] == step:
                    g += hit_l
                elif in_cone and free_x[b, 0] <= rx <= free_x[b, 1]:
                    g += miss_l
                elif scan_only[b, si, sj]:
                    if q < 0:
                        q = min(int((math.atan2(ry, rx) + math.pi) / ray_bin), n_dirs - 1)
                    if rng < nearest[b, q] - ray_margin:
                        g += miss_l
                g = min(max(g, -limit), limit)
                grids[b, si, sj] = g
                if emit and g > occupied:
                    out[b, count[b], 0], out[b, count[b], 1] = rx, ry
                    count[b] += 1
    # Pack per band
    out_ptr = np.zeros(n_bands + 1, dtype=np.int64)
    for b in range(n_bands):
        out_ptr[b + 1] = out_ptr[b] + count[b]
    flat = np.empty((out_ptr[-1], 2))
    for b in range(n_bands):
        flat[out_ptr[b]:out_ptr[b + 1]] = out[b, :count[b]]
    return flat, out_ptr


@njit(cache=True, error_model="numpy", inline="always")
def _in_view(view: np.ndarray, x: float, y: float) -> bool:
    """Whether base-frame point (x, y) lies in one of the (V, 5) sectors ``(x, y, yaw, half_angle, range)``: the
    test of :meth:`simnav.navigation.sensing.ViewSector.contains`, per cell inside the kernel."""
    for v in range(view.shape[0]):
        dx, dy = x - view[v, 0], y - view[v, 1]
        if math.hypot(dx, dy) > view[v, 4]:
            continue
        if view[v, 3] >= math.pi:
            return True
        off = abs((math.atan2(dy, dx) - view[v, 2] + math.pi) % (2.0 * math.pi) - math.pi)
        if off <= view[v, 3]:
            return True
    return False


class ScanHistory:
    """Where a level 2D lidar saw free space over the last seconds, to back into space no sensor sees now.

    Keeps, for the scans of the last ``keep_s`` seconds taken at least ``step_m`` or ``step_rad`` apart in pose,
    the range of the nearest scan point per bearing bin (``bin_rad`` wide) from the lidar's position ``origin_xy``
    in the base frame. A point counts as seen free when the newest kept scan with a return in the bearings of the
    disk of radius ``clearance_m`` around the point saw every return in those bearings at least ``clearance_m``
    beyond the point: no scan point in the disk, nor in the cone behind it up to ``clearance_m`` further (a ray
    may pass a door jamb closely). Walls and furniture in the lidar's plane stay where a scan saw them, so the
    space before them stays free of them however old the scan; people and door leaves may have moved in since,
    and obstacles above or below the scan plane are not seen.

    Args:
        origin_xy: (2,) the lidar's position in the base frame, m.
        keep_s: how long scans are kept, s.
        bin_rad: width of a bearing bin, rad.
        clearance_m: radius of the disk around a point that must be seen free, m (> 0).
        step_m, step_rad: a scan is kept only this far in position or heading from the last kept one (m, rad).
    """

    def __init__(self, origin_xy: Sequence[float] = (0.0, 0.0), keep_s: float = 20.0,
                 bin_rad: float = math.radians(1.0), clearance_m: float = 0.1, step_m: float = 0.05,
                 step_rad: float = math.radians(5.0)) -> None:
        if not (keep_s > 0 and 0 < bin_rad <= math.pi / 4 and clearance_m > 0 and min(step_m, step_rad) >= 0):
            raise ValueError(f"ScanHistory: need keep_s > 0, bin_rad in (0, pi/4], clearance_m > 0 and step_m, "
                             f"step_rad >= 0; got keep_s={keep_s}, bin_rad={bin_rad}, clearance_m={clearance_m}, "
                             f"step_m={step_m}, step_rad={step_rad}")
        self.origin_xy = np.asarray(origin_xy, dtype=np.float64).reshape(2)
        self.keep_s, self.bin_rad, self.clearance_m = float(keep_s), float(bin_rad), float(clearance_m)
        self.step_m, self.step_rad = float(step_m), float(step_rad)
        self._bins = int(math.ceil(2 * math.pi / self.bin_rad))
        self._stamps: deque[float] = deque()
        self._poses: deque[np.ndarray] = deque()  # (3, 3) T_odom_lidar
        self._ranges: deque[list[np.ndarray]] = deque()  # nearest return per bin (inf: none), as a range-min table

    def reset(self) -> None:
        """Forget every scan."""
        for kept in (self._stamps, self._poses, self._ranges):
            kept.clear()

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp_s: float, T_odom_base: np.ndarray, scan_xy_base: np.ndarray) -> None:
        """Keep one scan: (S, 2) its points in the base frame at ``T_odom_base`` (3, 3), m."""
        T_odom_lidar = np.array(T_odom_base, dtype=np.float64) @ se2.from_xy_yaw(*self.origin_xy, 0.0)
        while self._stamps and self._stamps[0] < stamp_s - self.keep_s:
            for kept in (self._stamps, self._poses, self._ranges):
                kept.popleft()
        if self._poses:
            last = self._poses[-1]
            moved = math.hypot(*(T_odom_lidar[:2, 2] - last[:2, 2]))
            turned = abs(se2.wrap_angle(math.atan2(T_odom_lidar[1, 0], T_odom_lidar[0, 0])
                                        - math.atan2(last[1, 0], last[0, 0])))
            if moved < self.step_m and turned < self.step_rad:
                return
        d = np.asarray(scan_xy_base, dtype=np.float64).reshape(-1, 2) - self.origin_xy
        ranges = np.full(self._bins, np.inf)
        np.minimum.at(ranges, self._bin(np.arctan2(d[:, 1], d[:, 0])), np.hypot(d[:, 0], d[:, 1]))
        self._stamps.append(float(stamp_s))
        self._poses.append(T_odom_lidar)
        self._ranges.append(_range_min_table(np.tile(ranges, 3)))  # three times round: windows wrap

    def seen_free(self, points_odom: np.ndarray) -> np.ndarray:
        """(P,) bool: whether each of the (P, 2) points (odom frame, m) was seen free (see the class docstring)."""
        pts = np.asarray(points_odom, dtype=np.float64).reshape(-1, 2)
        free, decided = np.zeros(len(pts), dtype=bool), np.zeros(len(pts), dtype=bool)
        for T_odom_lidar, table in zip(reversed(self._poses), reversed(self._ranges), strict=True):
            d = se2.transform_points(se2.inverse(T_odom_lidar), pts[~decided])
            r = np.hypot(d[:, 0], d[:, 1])
            # the bearings of the disk around each point: at least the bin's neighbours, at most all round
            half = np.arcsin(np.minimum(self.clearance_m / np.maximum(r, 1e-9), 1.0))
            width = np.maximum(np.ceil(half / self.bin_rad).astype(np.int64), 1)
            width[r <= self.clearance_m] = self._bins
            width = np.minimum(width, (self._bins - 1) // 2)
            centre = self._bin(np.arctan2(d[:, 1], d[:, 0])) + self._bins
            seen = _range_min(table, centre - width, centre + width)
            new = np.isfinite(seen)
            rows = np.flatnonzero(~decided)[new]
            free[rows] = r[new] + self.clearance_m < seen[new]
            decided[rows] = True
            if decided.all():
                break
        return free

    def _bin(self, bearing_rad: np.ndarray) -> np.ndarray:
        return (np.floor((bearing_rad + math.pi) / self.bin_rad).astype(np.int64)) % self._bins


def _range_min_table(values: np.ndarray) -> list[np.ndarray]:
    """Sparse table for range minima: level j holds the minima of the windows of 2**j values."""
    table = [values]
    while 2 ** len(table) <= len(values):
        half = 2 ** (len(table) - 1)
        table.append(np.minimum(table[-1][:-half], table[-1][half:]))
    return table


def _range_min(table: list[np.ndarray], lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(Q,) the minima of the values ``lo[q]..hi[q]`` (inclusive) of a :func:`_range_min_table`."""
    if len(lo) == 0:
        return np.zeros(0)
    level = np.floor(np.log2(hi - lo + 1)).astype(np.int64)
    out = np.empty(len(lo))
    for j in np.unique(level):
        rows = level == j
        out[rows] = np.minimum(table[j][lo[rows]], table[j][hi[rows] - 2**j + 1])
    return out
