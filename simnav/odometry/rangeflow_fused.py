"""One compiled call per scan for the range-flow pipeline: pyramid, keyscan warp and the coarse-to-fine loop.

:func:`simnav.odometry.rangeflow.coarse_to_fine` drives the level kernels from Python: about thirty kernel calls
per 1080-beam scan in SRF's mode MA, each paying Python and argument-unboxing costs comparable to its work on
the coarse levels. Here the geometry of every pyramid level is packed into flat arrays once per scanner
(:class:`PackedGeometry`), the pyramid of a scan is one flat array (level ``l`` at ``offsets[l]:offsets[l+1]``),
and the whole estimate-and-warp loop of Algorithm 2 runs in a single kernel that calls the same per-level kernels
as the Python loop, in the same order, so both give the same numbers (tested). The Python loop stays the general
path: it also aligns scans whose beam geometries differ.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from simnav.odometry.rangeflow import (
    Alignment,
    CoarseToFine,
    LevelGeometry,
    Preweights,
    Solution,
    _coarse_to_fine_kernel,
    _f64,
    _pyramid_kernel,
    _warp_levels_kernel,
    se2_exp,
)

CAUCHY, TRUNCATED_PARABOLA = 0, 1
"""Robust kernels of :class:`LevelModel`."""


@dataclass(frozen=True)
class PackedGeometry:
    """The :class:`LevelGeometry` of every pyramid level in flat arrays (finest level first).

    Level ``l`` occupies ``offsets[l]:offsets[l + 1]`` of the per-beam arrays, ``seg_offsets`` of the segment
    arrays and ``index_offsets`` of the grid-index knots; neighbour, segment and window indices are local to the
    level. ``windows`` (N, 5) holds each level's smoothing window into its source: the raw scan for level 0
    (``raw_beams`` = outside), the next finer level for the others (its beam count = outside).
    """

    geoms: tuple[LevelGeometry, ...]
    offsets: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    spacing: np.ndarray
    gap_next: np.ndarray
    prev: np.ndarray
    next: np.ndarray
    has_prev: np.ndarray
    has_next: np.ndarray
    windows: np.ndarray
    seg_offsets: np.ndarray
    seg_a: np.ndarray
    seg_b: np.ndarray
    index_offsets: np.ndarray
    index_angles: np.ndarray
    index_values: np.ndarray
    a0: np.ndarray
    step: np.ndarray
    circular: bool

    @property
    def levels(self) -> int:
        """Number of pyramid levels."""
        return len(self.geoms)

    @property
    def beams(self) -> int:
        """Beams of all levels together (length of a packed pyramid)."""
        return int(self.offsets[-1])

    def split(self, flat: np.ndarray) -> list[np.ndarray]:
        """Per-level views ``[(n_0,), (n_1,), ...]`` of a packed (N,) pyramid."""
        return [flat[self.offsets[lv]:self.offsets[lv + 1]] for lv in range(self.levels)]


def pack_geometry(geoms: Sequence[LevelGeometry]) -> PackedGeometry:
    """Packs the levels of :func:`simnav.odometry.rangeflow.pyramid_geometry` (finest first) into flat arrays."""
    def cat(name: str, dtype: type) -> np.ndarray:
        return np.ascontiguousarray(np.concatenate([getattr(g, name) for g in geoms]), dtype=dtype)

    def offsets(sizes: list[int]) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    windows = [geoms[0].window] + [g.parent_window for g in geoms[1:]]
    return PackedGeometry(
        tuple(geoms), offsets([g.n for g in geoms]), cat("cos", np.float64), cat("sin", np.float64),
        cat("spacing_rad", np.float64), cat("gap_next", np.float64), cat("prev", np.int64), cat("next", np.int64),
        cat("has_prev", np.bool_), cat("has_next", np.bool_),
        np.ascontiguousarray(np.concatenate(windows), dtype=np.int64), offsets([len(g.seg_a) for g in geoms]),
        cat("seg_a", np.int64), cat("seg_b", np.int64), offsets([len(g.index_angles) for g in geoms]),
        cat("index_angles", np.float64), cat("index_values", np.float64),
        np.array([g.angles_rad[0] for g in geoms]), np.array([g.uniform_step_rad for g in geoms]),
        bool(geoms[0].circular))


# ----------------------------------------------------------------------------------------------------------------
# Pyramid and warping of all levels


def build_packed_pyramid(ranges_m: np.ndarray, packed: PackedGeometry, gate_m: float,
                         smooth_finest: bool) -> np.ndarray:
    """:func:`simnav.odometry.rangeflow.build_pyramid` into one (N,) array (see :class:`PackedGeometry`)."""
    out = np.empty(packed.beams)
    _pyramid_kernel(_f64(ranges_m), packed.windows, packed.offsets, float(gate_m), bool(smooth_finest), out)
    return out


def warp_packed(flat: np.ndarray, packed: PackedGeometry, T_dst_src: np.ndarray, farthest: bool) -> np.ndarray:
    """:func:`simnav.odometry.rangeflow.warp_scan` of every level of a packed pyramid onto the same grid.

    Args:
        flat: (N,) packed source ranges, 0 = invalid.
        packed: geometry of source and target.
        T_dst_src: (3, 3) pose of the source scanner frame in the target scanner frame.
        farthest: keep the farthest range per beam (keyscans) instead of the closest.

    Returns:
        (N,) packed warped ranges, 0 where nothing projects.
    """
    out = np.empty(packed.beams)
    g = packed
    _warp_levels_kernel(_f64(flat), g.offsets, g.cos, g.sin, g.seg_offsets, g.seg_a, g.seg_b, g.index_offsets,
                        g.index_angles, g.index_values, g.a0, g.step, g.circular, _f64(T_dst_src), bool(farthest), out)
    return out


# ----------------------------------------------------------------------------------------------------------------
# Coarse-to-fine loop


@dataclass(frozen=True)
class LevelModel:
    """How one pyramid level is solved (the level solvers of RF2O and SRF).

    Attributes:
        symmetric: constraint geometry at the mean of both scans (3.91) or on the reference (3.64).
        preweights: pre-weight model (3.71 / 3.96).
        robust: :data:`CAUCHY` (RF2O: ``iterations`` reweighted solves, width ``param`` x mean |r|) or
            :data:`TRUNCATED_PARABOLA` (SRF: at most ``iterations`` solves, ``c = param`` x MAD, stop once the
            cost falls by less than ``1 - min_decrease``).
        iterations, param, min_decrease: as above.
    """

    symmetric: bool
    preweights: Preweights
    robust: int
    iterations: int
    param: float
    min_decrease: float = 1.0


def coarse_to_fine_packed(references: np.ndarray, new_flat: np.ndarray, packed: PackedGeometry,
                          model: LevelModel, xi_prior: np.ndarray, params: CoarseToFine,
                          info_level: int) -> Alignment:
    """:func:`simnav.odometry.rangeflow.coarse_to_fine` with the level solver of ``model``, in one kernel call.

    Each level stacks the pre-weighted constraints of every reference with at least ``MIN_ROWS`` rows (3.99);
    a level where none has enough ends the loop, as a level solver returning None does.

    Args:
        references: (R, N) packed reference pyramids on the grid of ``packed`` (previous scan, warped keyscan).
        new_flat: (N,) packed pyramid of the new scan on the same grid.
        packed: the shared geometry.
        model: the level solver.
        xi_prior: (3,) predicted motion twist from the references to the new scan.
        params: loop parameters.
        info_level: level whose solutions carry the geometric information (-1: none).

    Returns:
        The alignment (level solutions finest first).
    """
    g, pw = packed, model.preweights
    T, solved, xi, cov, H, rows, lever, lam, V, info = _coarse_to_fine_kernel(
        np.ascontiguousarray(references, dtype=np.float64), _f64(new_flat), g.offsets, g.cos, g.sin, g.spacing,
        g.gap_next, g.prev, g.next, g.has_prev, g.has_next, g.seg_offsets, g.seg_a, g.seg_b, g.index_offsets,
        g.index_angles, g.index_values, g.a0, g.step, g.circular, se2_exp(_f64(xi_prior)), float(params.k_l),
        float(params.k_e), int(params.max_rewarps), float(params.rewarp_tolerance), bool(model.symmetric),
        *pw.args, int(model.robust), int(model.iterations), float(model.param), float(model.min_decrease),
        int(info_level))
    per_level = [Solution(xi[lv], cov[lv], H[lv], int(rows[lv]), float(lever[lv]), (lam[lv], V[lv]),
                          info if lv == info_level else None) if solved[lv] else None for lv in range(g.levels)]
    finest = next((s for s in per_level if s is not None), None)
    return Alignment(T, finest, tuple(per_level))
