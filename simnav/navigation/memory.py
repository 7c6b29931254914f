"""Short-term memory of nearby obstacles: one local occupancy grid per height band (thesis §6.C.5).

Depth cameras see nothing closer than about half a metre and only a narrow cone ahead; while the robot turns
or approaches an obstacle, the obstacle leaves the view. Every band keeps a robot-centred occupancy grid in the
odom frame (log-odds, 0 = unknown): cells hit by the band's points gain evidence, cells in a cone ahead of the
robot beyond the blind range that got no hit lose it, and all evidence decays towards unknown with a time
constant. Occupied cells near the robot come back as *virtual obstacles* that join the sensed points.

As §6.C.7 reports, the memory carries the pose estimate's errors into the obstacles; with a drifting odometry
it can close gaps the robot would fit through, so it can be switched off (``NavigatorConfig.memory``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

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

    def __post_init__(self) -> None:
        checks = [(self.cell_m > 0, "cell_m must be > 0"), (self.half_size_m > self.cell_m, "half_size_m > cell_m"),
                  (0.5 < self.hit_probability < 1, "hit_probability must be in (0.5, 1)"),
                  (0 < self.miss_probability < 0.5, "miss_probability must be in (0, 0.5)"),
                  (0.5 < self.occupied_probability < 1, "occupied_probability must be in (0.5, 1)"),
                  (self.decay_s > 0, "decay_s must be > 0")]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"MemoryConfig: {message}")


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class ShortTermMemory:
    """Per-band local occupancy grids in the odom frame, recentred on the robot as it moves.

    Args:
        num_bands: number of height bands.
        config: options.
    """

    def __init__(self, num_bands: int, config: MemoryConfig | None = None) -> None:
        self.config = config or MemoryConfig()
        self._n = 2 * int(math.ceil(self.config.half_size_m / self.config.cell_m))
        self._grids = np.zeros((num_bands, self._n, self._n), dtype=np.float32)
        self._origin: np.ndarray | None = None  # (2,) integer odom cell index of grid cell (0, 0)
        self._last_stamp_s: float | None = None
        self._cos_cone = math.cos(self.config.cone_half_angle_rad)

    def reset(self) -> None:
        """Forget everything."""
        self._grids[:] = 0.0
        self._origin, self._last_stamp_s = None, None

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
        cfg = self.config
        # Decay all evidence towards unknown
        if self._last_stamp_s is not None:
            self._grids *= np.float32(math.exp(-max(stamp_s - self._last_stamp_s, 0.0) / cfg.decay_s))
        self._last_stamp_s = stamp_s
        self._recentre(T_odom_base)
        # Free-space evidence in the cone ahead, then hits
        cells_odom = self._cell_centres_odom()
        rel = se2.transform_points(se2.inverse(T_odom_base), cells_odom.reshape(-1, 2)).reshape(self._n, self._n, 2)
        rng = np.hypot(rel[..., 0], rel[..., 1])
        cone = (rng > cfg.blind_range_m) & (rng < cfg.cone_range_m) & (rel[..., 0] > rng * self._cos_cone)
        emit = rng < cfg.emit_range_m
        hit_l, miss_l, limit = _logit(cfg.hit_probability), _logit(cfg.miss_probability), 2 * _logit(0.98)
        out = []
        for b, pts in enumerate(band_points_base):
            hit = np.zeros((self._n, self._n), dtype=bool)
            idx = self._indices(se2.transform_points(T_odom_base, np.asarray(pts, dtype=np.float64).reshape(-1, 2)))
            if len(idx):
                hit[idx[:, 0], idx[:, 1]] = True
            grid = self._grids[b]
            grid[cone & ~hit] += miss_l
            grid[hit] += hit_l
            np.clip(grid, -limit, limit, out=grid)
            occupied = emit & (grid > _logit(cfg.occupied_probability) + 1e-6)
            out.append(rel[occupied].astype(np.float64))
        return out

    # ------------------------------------------------------------------------------------------- grid helpers
    def _recentre(self, T_odom_base: np.ndarray) -> None:
        """Shift the grids by whole cells so that the robot stays at the centre; cells shifted in are unknown."""
        centre = np.floor(T_odom_base[:2, 2] / self.config.cell_m).astype(np.int64) - self._n // 2
        if self._origin is None:
            self._origin = centre
            return
        shift = centre - self._origin
        if np.any(np.abs(shift) >= self._n):
            self._grids[:] = 0.0
        elif np.any(shift):
            self._grids = np.roll(self._grids, (-int(shift[0]), -int(shift[1])), axis=(1, 2))
            sx, sy = int(shift[0]), int(shift[1])
            if sx > 0:
                self._grids[:, -sx:, :] = 0.0
            elif sx < 0:
                self._grids[:, :-sx, :] = 0.0
            if sy > 0:
                self._grids[:, :, -sy:] = 0.0
            elif sy < 0:
                self._grids[:, :, :-sy] = 0.0
        self._origin = centre

    def _cell_centres_odom(self) -> np.ndarray:
        """(n, n, 2) odom coordinates of every cell centre, m."""
        i = (self._origin[:, None] + np.arange(self._n)[None, :] + 0.5) * self.config.cell_m
        return np.stack(np.meshgrid(i[0], i[1], indexing="ij"), axis=-1)

    def _indices(self, xy_odom: np.ndarray) -> np.ndarray:
        """(Q, 2) grid indices of the odom points that fall inside the grid."""
        idx = np.floor(xy_odom / self.config.cell_m).astype(np.int64) - self._origin
        inside = (idx >= 0).all(axis=1) & (idx < self._n).all(axis=1)
        return idx[inside]
