"""Scan-to-scan bookkeeping shared by the range-flow odometries RF2O (§3.F) and SRF-Odometry (§3.G).

:class:`RangeFlowOdometry` turns each :class:`simnav.sensors.readings.LaserScan` into an upright, reordered scan
and its range pyramid, aligns it with its reference through the subclass's :meth:`RangeFlowOdometry._align`
(one compiled call per scan, :mod:`simnav.odometry.rangeflow_fused`, when both scans share a beam geometry), and
accumulates the base pose, twist and covariance. The kernels live in :mod:`simnav.odometry.rangeflow`.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numba import njit

from simnav.odometry.base import OdometryEstimate, PlanarScan, planar_scan
from simnav.odometry.rangeflow import (
    MIN_ROWS,
    Alignment,
    BeamLayout,
    CoarseToFine,
    LevelGeometry,
    LevelSolver,
    RangeFlowConfig,
    ScanFrame,
    _f64,
    beam_layout,
    coarse_to_fine,
    degeneracy_ratio,
    pyramid_geometry,
    se2_adjoint,
    se2_exp,
    se2_inverse,
    se2_log,
    weakest_direction,
)
from simnav.odometry.rangeflow_fused import (
    LevelModel,
    PackedGeometry,
    build_packed_pyramid,
    coarse_to_fine_packed,
    pack_geometry,
)
from simnav.sensors.readings import LaserScan


class RangeFlowOdometry(ABC):
    """Scan-to-scan bookkeeping shared by the range-flow odometries.

    Subclasses set ``config``, implement :meth:`_levels` and :meth:`_align`, and may override
    :meth:`_after_scan`. Each call to :meth:`process` prepares the scan, aligns it (or predicts with constant
    velocity when the scan or its reference has too few valid beams, or the alignment fails), accumulates the
    base pose and reports twist, covariance and degeneracy. Nothing raises on bad data and no output is NaN.
    """

    config: RangeFlowConfig
    _model: LevelModel
    """The level solver of the one-call coarse-to-fine path."""
    _ctf: CoarseToFine
    """Coarse-to-fine loop parameters."""
    _solve_level: LevelSolver
    """The level solver of the Python coarse-to-fine loop (scans on different grids)."""

    def __init__(self) -> None:
        self._upright_cache: tuple[np.ndarray, np.ndarray, np.ndarray, PlanarScan] | None = None
        self._layout_key: np.ndarray | None = None
        self._layout_angles: np.ndarray | None = None
        self._layout: BeamLayout | None = None
        self._geoms: tuple[LevelGeometry, ...] = ()
        self._packed: PackedGeometry | None = None
        self._info_cache: tuple[tuple[LevelGeometry, ...] | None, int] = (None, -1)
        self._info_geom: LevelGeometry | None = None
        self._info_level = -1
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next scan starts a new odom frame."""
        self._ref: ScanFrame | None = None
        self._last_stamp_s: float | None = None
        self._T_odom_base = np.eye(3)
        self._xi_last = np.zeros(3)  # last laser increment, per scan
        self._twist_laser: np.ndarray | None = None  # last laser twist, per second

    # -- hooks ----------------------------------------------------------------------------------------------

    @abstractmethod
    def _levels(self, beams: int) -> int:
        """Number of pyramid levels for a scan with ``beams`` beams."""

    @abstractmethod
    def _align(self, ref: ScanFrame, new: ScanFrame, xi_prior: np.ndarray) -> Alignment:
        """Motion from ``ref`` to ``new`` (both valid)."""

    def _coarse_to_fine(self, references: Sequence[np.ndarray], ref: ScanFrame, new: ScanFrame,
                        xi_prior: np.ndarray) -> Alignment:
        """Coarse-to-fine alignment of ``new`` with packed (N,) reference pyramids on ``ref``'s grid: one kernel
        call (:func:`simnav.odometry.rangeflow_fused.coarse_to_fine_packed` with ``self._model``) when ``new``
        shares that grid, else the Python loop with ``self._solve_level``."""
        if new.packed is ref.packed:
            stacked = references[0][None, :] if len(references) == 1 else np.stack(references)
            return coarse_to_fine_packed(stacked, new.flat, ref.packed, self._model, xi_prior, self._ctf,
                                         self._info_level)
        return coarse_to_fine([ref.packed.split(r) for r in references], ref.geoms, new, self._solve_level,
                              xi_prior, self._ctf)

    def _after_scan(self, new: ScanFrame | None, T_prev_new: np.ndarray, measured: bool) -> dict:
        """Called after each scan with the (valid) frame or None and the laser increment; returns extras."""
        return {}

    # -- pipeline -------------------------------------------------------------------------------------------

    def process(self, scan: LaserScan) -> OdometryEstimate:
        """Estimate the motion since the previous scan.

        Args:
            scan: the new scan (any mount; NaN/inf/out-of-range beams are treated as invalid).

        Returns:
            The estimate; see :class:`simnav.odometry.base.OdometryEstimate`.
        """
        t0 = time.perf_counter()
        # 1. Upright scan, layout and pyramid.
        ps = self._upright(scan)
        frame = self._frame(ps)
        dt = ps.stamp_s - self._last_stamp_s if self._last_stamp_s is not None else 0.0
        xi_prior = self._prior(dt)
        # 2. Align with the reference, or predict.
        ref, first = self._ref, self._last_stamp_s is None
        alignment, cov_laser, degenerate, rows = None, None, True, 0
        if frame is not None and ref is not None:
            self._info_level = self._information_level(ref.geoms)
            self._info_geom = ref.geoms[self._info_level]
            alignment = self._align(ref, frame, xi_prior)
        if (alignment is not None and alignment.solution is not None and np.all(np.isfinite(alignment.T_ref_new))
                and self._plausible(alignment.T_ref_new, dt)):
            T_inc = alignment.T_ref_new
            cov_laser, degenerate = self._covariance(alignment)
            rows = alignment.solution.rows
        else:
            T_inc = np.eye(3) if first else se2_exp(xi_prior)
        measured = cov_laser is not None
        # 3. Base increment, pose, twist and covariance.
        T_base_laser = ps.T_base_laser
        T_inc_base = T_base_laser @ T_inc @ se2_inverse(T_base_laser)  # laser_to_base_motion, fast path
        self._T_odom_base = self._T_odom_base @ T_inc_base
        if measured:
            Ad = se2_adjoint(T_base_laser)
            cov = Ad @ cov_laser @ Ad.T
        else:
            cov = np.zeros((3, 3)) if first else self.config.lost_variance * np.eye(3)
        twist = se2_log(T_inc_base) / dt if dt > 0 else np.zeros(3)
        # 4. Remember the motion, the reference and the stamp.
        xi_inc = se2_log(T_inc)
        if not first:
            self._xi_last = xi_inc
            self._twist_laser = xi_inc / dt if dt > 0 else self._twist_laser
        extra = self._after_scan(frame, T_inc, measured)
        self._ref = frame
        self._last_stamp_s = ps.stamp_s
        extra.update(measured=measured, levels=len(frame.geoms) if frame is not None else 0)
        return OdometryEstimate(
            stamp_s=ps.stamp_s, T_odom_base=self._T_odom_base.copy(), twist_base=_finite(twist),
            covariance=_finite(0.5 * (cov + cov.T)), degenerate=bool(degenerate and not first),
            valid_points=int(rows), runtime_s=time.perf_counter() - t0, extra=extra)

    def _plausible(self, T_inc: np.ndarray, dt: float) -> bool:
        """Whether an increment over ``dt`` stays within the configured speed limits."""
        if dt <= 0:
            return True
        xi = se2_log(T_inc)
        return (math.hypot(xi[0], xi[1]) <= self.config.max_speed_m_s * dt
                and abs(xi[2]) <= self.config.max_yaw_rate_rad_s * dt)

    def _information_level(self, geoms: tuple[LevelGeometry, ...]) -> int:
        """Index of the level whose beam spacing is closest to ``degeneracy_spacing_deg`` (level solvers attach the
        geometric information there)."""
        if self._info_cache[0] is not geoms:
            target = math.radians(self.config.degeneracy_spacing_deg)
            best = min(range(len(geoms)), key=lambda lv: abs(float(np.median(geoms[lv].spacing_rad)) - target))
            self._info_cache = (geoms, best)
        return self._info_cache[1]

    def _covariance(self, alignment: Alignment) -> tuple[np.ndarray, bool]:
        """Laser-frame covariance of an alignment and its degeneracy flag.

        The covariance is the finest solve's; when the geometric information (attached at the level chosen by
        :meth:`_information_level`) is degenerate, ``lost_variance`` is added along its weakest direction.
        """
        cov = alignment.solution.covariance
        sol = next((s for s in alignment.level_solutions if s is not None and s.information is not None), None)
        if sol is None or degeneracy_ratio(sol.information, sol.lever_m) >= self.config.degeneracy_threshold:
            return cov, False
        v = weakest_direction(sol.information, sol.lever_m)
        return cov + self.config.lost_variance * np.outer(v, v), True

    def _upright(self, scan: LaserScan) -> PlanarScan:
        """:func:`simnav.odometry.base.planar_scan` of ``scan``; the beam order, upright angles and mount it
        derives from the scanner's angles and mount are computed once per scanner."""
        cached = self._upright_cache
        if cached is None or not (np.array_equal(scan.angles_rad, cached[0])
                                  and np.array_equal(scan.T_base_sensor, cached[1])):
            # planar_scan of beam numbers 1..N tells where each upright beam comes from.
            numbers = np.arange(1.0, len(scan.angles_rad) + 1.0)
            probe = planar_scan(replace(scan, ranges_m=numbers, min_range_m=0.0, max_range_m=np.inf))
            order = probe.ranges_m.astype(np.int64) - 1
            cached = self._upright_cache = (np.array(scan.angles_rad, copy=True),
                                            np.array(scan.T_base_sensor, copy=True), order, probe)
        _, _, order, probe = cached
        ranges = _upright_ranges(_f64(scan.ranges_m), order, float(scan.min_range_m), float(scan.max_range_m))
        return PlanarScan(scan.stamp_s, ranges, probe.angles_rad, probe.T_base_laser, scan.max_range_m)

    def _frame(self, ps: PlanarScan) -> ScanFrame | None:
        """Layout, geometry and pyramid of a scan; None when it has too few valid beams."""
        layout, geoms = self._geometry(ps.angles_rad)
        ranges = ps.ranges_m[layout.take]
        valid = int(np.count_nonzero(ranges > 0))
        need = max(self.config.min_valid_points, math.ceil(self.config.min_valid_fraction * len(ps.ranges_m)))
        if valid < need or not geoms:
            return None
        packed = self._packed
        flat = build_packed_pyramid(ranges, packed, self.config.pyramid_gate_m, self.config.smooth_finest)
        return ScanFrame(ps.stamp_s, packed.split(flat), geoms, valid, len(ranges), ps.T_base_laser, packed, flat)

    def _geometry(self, angles_rad: np.ndarray) -> tuple[BeamLayout, tuple[LevelGeometry, ...]]:
        """Cached beam layout and pyramid geometry for an angle vector."""
        if self._layout_key is None or not (angles_rad is self._layout_angles
                                            or np.array_equal(angles_rad, self._layout_key)):
            layout = beam_layout(angles_rad)
            geoms = ()
            if len(layout.angles_rad) >= max(self.config.min_level_beams, MIN_ROWS):
                geoms = pyramid_geometry(layout, self._levels(len(layout.angles_rad)), self.config.min_level_beams)
            self._layout_key, self._layout, self._geoms = np.array(angles_rad, copy=True), layout, geoms
            self._packed = pack_geometry(geoms) if geoms else None
        self._layout_angles = angles_rad  # the cached upright angles come back as the same array
        return self._layout, self._geoms

    def _prior(self, dt: float) -> np.ndarray:
        """Constant-velocity prediction of the laser increment over ``dt`` seconds (per-scan twist)."""
        if self._twist_laser is not None and dt > 0:
            return self._twist_laser * dt
        return self._xi_last.copy()


@njit(cache=True, error_model="numpy")
def _upright_ranges(ranges: np.ndarray, order: np.ndarray, min_range_m: float, max_range_m: float) -> np.ndarray:
    """(N,) ``ranges[order]`` with NaN, inf and out-of-range beams set to 0, as :func:`planar_scan` returns them."""
    out = np.empty(len(order))
    for k in range(len(order)):
        r = ranges[order[k]]
        ok = np.isfinite(r) and r > 0 and r >= min_range_m and r <= max_range_m
        out[k] = r if ok else 0.0
    return out


def _finite(a: np.ndarray) -> np.ndarray:
    """``a`` with any non-finite entry replaced by 0 (a last guard; the pipeline should not produce any)."""
    return np.where(np.isfinite(a), a, 0.0)
