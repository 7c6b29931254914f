"""SRF-Odometry: planar laser odometry from symmetric range flow and multi-scan alignment (thesis §3.G).

Each beam gives the symmetric range-flow constraint (3.91 / 3.93): gradient, range and point are taken at the
mean of the two scans. Constraints are pre-weighted (3.96–3.97) and minimised with the smooth truncated parabola
(3.94, 3.95, 3.100, ``c = 4 MAD``) by IRLS; every pyramid level repeats estimate-and-warp (Algorithm 2) and
filters its solution in the eigenspace of its covariance (3.106, 3.107).

Modes (§3.G.5, §3.G.9): ``"CA"`` aligns the new scan with the previous one; ``"KA"`` with the keyscan warped
into the previous scan's frame; ``"MA"`` with both jointly (3.99). A :class:`KeyscanPolicy` decides when the
newest scan becomes the keyscan from its motion since the keyscan (§3.G.7). In mode KA the keyscan must also
share the new scan's view: when the overlap of the two (:func:`simnav.odometry.keyscan.keyscan_overlap`) falls
below ``keyscan_min_overlap``, e.g. as the robot leaves a room through a doorway, the new scan is aligned with
the previous scan instead and becomes the keyscan.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import numpy as np

from simnav.odometry.base import OdometryEstimate
from simnav.odometry.keyscan import LearnedKeyscanPolicy, available_presets, keyscan_overlap
from simnav.odometry.rangeflow import (
    MIN_ROWS,
    Alignment,
    CoarseToFine,
    LevelGeometry,
    Preweights,
    RangeFlowConfig,
    ScanFrame,
    Solution,
    irls_truncated_parabola,
    make_config,
    require,
    se2_inverse,
    warp_scan,
    weighted_constraints,
)
from simnav.odometry.rangeflow_fused import TRUNCATED_PARABOLA, LevelModel, warp_packed
from simnav.odometry.scan_odometry import RangeFlowOdometry
from simnav.sensors.presets import LIDAR2D_PRESETS
from simnav.sensors.readings import LaserScan

log = logging.getLogger(__name__)

MODES = ("CA", "KA", "MA")
"""Consecutive alignment, keyscan alignment, multi-scan alignment."""


@runtime_checkable
class KeyscanPolicy(Protocol):
    """Decides when the newest scan replaces the keyscan (§3.G.7)."""

    def needs_new_keyscan(self, translation_m: float, rotation_rad: float) -> bool:
        """Whether to take the newest scan as keyscan, given its motion from the current keyscan.

        Args:
            translation_m: distance from the keyscan pose, m.
            rotation_rad: heading change from the keyscan pose, rad (signed).
        """
        ...


@dataclass(frozen=True)
class ThresholdKeyscanPolicy:
    """Keyscan criterion with fixed translation and rotation limits.

    A simple alternative to the default, the working regions learned in simulation (§3.G.7,
    :class:`simnav.odometry.keyscan.LearnedKeyscanPolicy`); here the region is a plain box.

    Attributes:
        max_translation_m: new keyscan beyond this distance from the current one, m.
        max_rotation_rad: new keyscan beyond this heading change, rad.
    """

    max_translation_m: float = 0.3
    max_rotation_rad: float = 0.15

    def needs_new_keyscan(self, translation_m: float, rotation_rad: float) -> bool:
        """True outside the box ``|t| <= max_translation_m``, ``|rotation| <= max_rotation_rad``."""
        return translation_m > self.max_translation_m or abs(rotation_rad) > self.max_rotation_rad


@dataclass(frozen=True)
class SRFConfig(RangeFlowConfig):
    """SRF-Odometry options (shared ones: :class:`simnav.odometry.rangeflow.RangeFlowConfig`).

    Attributes:
        mode: ``"CA"`` (consecutive), ``"KA"`` (keyscan) or ``"MA"`` (multi-scan, 3.99).
        levels: pyramid levels; None = ``ceil(log2(beams) - 4.3)`` (fewer if the coarsest would have under
            ``min_level_beams``).
        max_rewarps: estimate-and-warp iterations per level (Algorithm 2).
        rewarp_tolerance: stop a level's iterations once the norm of the last solve is below this (per scan;
            metres and radians mixed, as in Algorithm 2).
        irls_max_iterations: most reweighted solves per level iteration.
        irls_min_decrease: keep reweighting while the cost falls below this fraction of the previous one.
        mad_factor: ``c = mad_factor * MAD`` of the least-squares residuals (§3.G.8).
        filter_kl: ``k_l`` of the motion filter at the coarsest level (3.107: ``0.02 e^-(l-1)``).
        filter_ke: ``k_e`` at the coarsest level (3.107: ``5e3 e^-(l-1)``).
        sensor_sigma_m: ``sigma_s`` of the pre-weights (3.96), m.
        preweight_kd: ``K_D`` (3.96).
        preweight_k2d: ``K_2D`` (3.96).
        keyscan_policy: when to take a new keyscan, from the motion since the current one (modes KA and MA).
        keyscan_min_overlap: mode KA: after aligning a new scan with the keyscan, the share of the new scan's
            view that the keyscan observed too (:func:`simnav.odometry.keyscan.keyscan_overlap`, at the estimated
            pose) must be at least this; otherwise the new scan is aligned again with the previous scan alone
            and becomes the keyscan. The motion-based working region is learned on average views; where the
            view changes faster (leaving a room through a doorway) the keyscan alignment fails while the motion
            is still inside it. 0.9 is about the 5 % quantile of the overlap on maps without doorways and a few
            scans ahead of the failures at doorways (0.5-0.7, 5 Hz). 0 disables the check. Mode MA keeps
            the previous scan's constraints in every solve (3.99) and does not use the check.
        keyscan_overlap_tolerance_m: largest range difference between a keyscan point and the new beam it
            projects onto that still counts as the same surface, m (3 sigma of very noisy scans, 0.1 m).
        keyscan_overlap_bin_deg: width of the bins of beams in which the overlap is counted, deg (wide enough
            that a surface seen closer than from the keyscan still gets a keyscan point in every bin).
        symmetric: the symmetric range flow constraint (3.83 / 3.91); False = the standard one (3.80), geometry
            of the reference scan (the NSRF variant of Table 3.14).
        preweighting: pre-weight the constraints (3.96 / 3.97); False = unit weights (Table 3.12).
        robust: minimise the smooth truncated parabola of the residuals (3.94); False = plain least squares
            (Table 3.12).
    """

    mode: str = "CA"
    levels: int | None = None
    max_rewarps: int = 8
    rewarp_tolerance: float = 0.01
    irls_max_iterations: int = 10
    irls_min_decrease: float = 0.995
    mad_factor: float = 4.0
    filter_kl: float = 0.02
    filter_ke: float = 5e3
    sensor_sigma_m: float = 0.02
    preweight_kd: float = 0.01
    preweight_k2d: float = 2e-4
    keyscan_policy: KeyscanPolicy | str = "auto"
    keyscan_min_overlap: float = 0.9
    keyscan_overlap_tolerance_m: float = 0.3
    keyscan_overlap_bin_deg: float = 2.0
    symmetric: bool = True
    preweighting: bool = True
    robust: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.mode in MODES, f"unknown SRF mode {self.mode!r}; available: {', '.join(MODES)}")
        require(self.levels is None or self.levels >= 1, "levels must be None or >= 1")
        require(self.max_rewarps >= 1, "max_rewarps must be >= 1")
        require(self.irls_max_iterations >= 0, "irls_max_iterations must be >= 0")
        require(self.mad_factor > 0, "mad_factor must be > 0")
        require(self.filter_kl >= 0 and self.filter_ke >= 0, "filter_kl and filter_ke must be >= 0")
        require(self.sensor_sigma_m > 0, "sensor_sigma_m must be > 0")
        require(0 <= self.keyscan_min_overlap <= 1, "keyscan_min_overlap must be in [0, 1]")
        require(self.keyscan_overlap_tolerance_m > 0 and self.keyscan_overlap_bin_deg > 0,
                "keyscan_overlap_tolerance_m and keyscan_overlap_bin_deg must be > 0")
        require(isinstance(self.keyscan_policy, KeyscanPolicy) or self.keyscan_policy == "auto"
                or self.keyscan_policy in available_presets(),
                "keyscan_policy must be 'auto', a lidar preset with a learned model "
                f"({', '.join(available_presets())}) or an object with a "
                "needs_new_keyscan(translation_m, rotation_rad) method")


class SRFOdometry(RangeFlowOdometry):
    """Symmetric Range Flow-based Odometry (§3.G) in mode CA, KA or MA.

    Args:
        **config: overrides of :class:`SRFConfig` fields; an unknown name or mode raises
            :class:`simnav.errors.ConfigError` listing the allowed ones.
    """

    def __init__(self, **config) -> None:
        self.config: SRFConfig = make_config(SRFConfig, config, "SRF")
        cfg = self.config
        self._ctf = CoarseToFine(cfg.filter_kl, cfg.filter_ke, cfg.max_rewarps, cfg.rewarp_tolerance)
        self._preweights = (Preweights.srf(cfg.sensor_sigma_m, cfg.preweight_kd, cfg.preweight_k2d)
                            if cfg.preweighting else Preweights.srf(1.0, 0.0, 0.0))  # 1/sqrt(1 + 0) = unit weights
        self._model = LevelModel(cfg.symmetric, self._preweights, TRUNCATED_PARABOLA,
                                 cfg.irls_max_iterations if cfg.robust else 0, cfg.mad_factor, cfg.irls_min_decrease)
        super().__init__()

    def reset(self) -> None:
        """Forget all history (scans and keyscan); the next scan starts a new odom frame."""
        super().reset()
        self._policy: KeyscanPolicy | None = None
        self._key: ScanFrame | None = None
        self._T_key_prev = np.eye(3)  # pose of the previous scan in the keyscan frame
        self._key_is_prev = True
        self._key_failed = False
        self._overlap: float | None = None  # keyscan overlap of the scan being processed (None: not checked)

    def _levels(self, beams: int) -> int:
        if self.config.levels is not None:
            return self.config.levels
        return max(1, math.ceil(math.log2(beams) - 4.3))

    def _align(self, ref: ScanFrame, new: ScanFrame, xi_prior: np.ndarray) -> Alignment:
        """Coarse-to-fine alignment of ``new`` with the previous scan and/or the warped keyscan; in mode KA with
        the previous scan when the keyscan overlaps the new scan too little."""
        # 1. References: the previous scan, the keyscan rendered from the previous scan's pose, or both.
        refs, key_w = [ref.flat], None
        self._key_failed, self._overlap = False, None
        if self.config.mode != "CA" and self._key is not None and not self._key_is_prev:
            key_w = self._warped_key(ref)
            if key_w is None:
                self._key_failed = True
            else:
                refs = [key_w] if self.config.mode == "KA" else [ref.flat, key_w]
        # 2. Estimate-and-warp through the pyramid.
        alignment = self._coarse_to_fine(refs, ref, new, xi_prior)
        if key_w is None or self.config.mode != "KA" or self.config.keyscan_min_overlap <= 0:
            return alignment
        # 3. Overlap check (KA): a keyscan that saw too little of the new view is dropped; use the previous scan.
        self._overlap = self._key_overlap(new, self._T_key_prev @ alignment.T_ref_new)
        if self._overlap >= self.config.keyscan_min_overlap:
            return alignment
        self._key_failed = True
        return self._coarse_to_fine([ref.flat], ref, new, xi_prior)

    def _key_overlap(self, new: ScanFrame, T_key_new: np.ndarray) -> float:
        """:func:`simnav.odometry.keyscan.keyscan_overlap` of the keyscan and ``new`` at full resolution, with
        ``new`` at ``T_key_new`` ((3, 3), scanner frames) in the keyscan frame; bins of
        ``keyscan_overlap_bin_deg``."""
        cfg, geom = self.config, new.geoms[0]
        step = geom.uniform_step_rad or float(np.mean(geom.spacing_rad))
        bin_beams = max(1, round(math.radians(cfg.keyscan_overlap_bin_deg) / step))
        return keyscan_overlap(self._key.pyramid[0], self._key.geoms[0], se2_inverse(T_key_new), new.pyramid[0],
                               geom, cfg.keyscan_overlap_tolerance_m, bin_beams)

    def _warped_key(self, ref: ScanFrame) -> np.ndarray | None:
        """Keyscan pyramid warped into the previous scan's frame keeping the farthest points (§3.G.5), packed on
        the previous scan's grid, or None when too little of it projects."""
        key = self._key
        if len(key.geoms) < len(ref.geoms):
            return None
        T_prev_key = se2_inverse(self._T_key_prev)
        if key.packed is ref.packed:
            warped = warp_packed(key.flat, ref.packed, T_prev_key, farthest=True)
        else:
            warped = np.concatenate([warp_scan(key.pyramid[lv], key.geoms[lv], T_prev_key, g, keep="farthest")
                                     for lv, g in enumerate(ref.geoms)])
        need = max(self.config.min_valid_points, math.ceil(self.config.min_valid_fraction * ref.beams))
        return warped if np.count_nonzero(warped[:ref.geoms[0].n]) >= need else None

    def _solve_level(self, refs: Sequence[np.ndarray], warped: np.ndarray, geom: LevelGeometry,
                     step: int) -> Solution | None:
        """Symmetric constraints (3.93) of every reference, pre-weighted (3.96–3.97), stacked (3.99) and solved
        with truncated-parabola IRLS (3.94, 3.95, 3.100)."""
        cfg = self.config
        info = geom is self._info_geom
        systems = [weighted_constraints(r_ref, warped, geom, cfg.symmetric, self._preweights, info) for r_ref in refs]
        systems = [s for s in systems if s.rows >= MIN_ROWS]
        if not systems:
            return None
        if len(systems) == 1:
            A, b = systems[0].A, systems[0].b
        else:
            A, b = np.concatenate([s.A for s in systems]), np.concatenate([s.b for s in systems])
        lever = sum(s.mean_range_m for s in systems) / len(systems)
        iterations = cfg.irls_max_iterations if cfg.robust else 0  # no reweighting: least squares
        sol = irls_truncated_parabola(A, b, iterations, cfg.mad_factor, cfg.irls_min_decrease, lever)
        # The information of stacked constraints is the sum of theirs.
        return replace(sol, information=sum(s.information for s in systems)) if info else sol

    def _after_scan(self, new: ScanFrame | None, T_prev_new: np.ndarray, measured: bool) -> dict:
        """Keyscan bookkeeping (§3.G.7): move the previous-scan pose and replace the keyscan when the policy,
        a failed keyscan warp, a too small keyscan overlap or a lost track asks for it."""
        failed, self._key_failed = self._key_failed, False
        overlap, self._overlap = self._overlap, None
        if self.config.mode == "CA":
            return {"mode": "CA"}
        if new is None or self._key is None or not measured or failed:
            updated = self._set_key(new)
        else:
            T_key_new = self._T_key_prev @ T_prev_new
            translation = math.hypot(T_key_new[0, 2], T_key_new[1, 2])
            rotation = math.atan2(T_key_new[1, 0], T_key_new[0, 0])
            if self._policy.needs_new_keyscan(translation, rotation):
                updated = self._set_key(new)
            else:
                self._T_key_prev, self._key_is_prev, updated = T_key_new, False, False
        return {"mode": self.config.mode, "new_keyscan": updated, "keyscan_overlap": overlap}

    def process(self, scan: LaserScan) -> OdometryEstimate:
        """Estimate the motion since the previous scan (see :class:`simnav.odometry.base.ScanOdometry`)."""
        if self._policy is None:
            self._policy = resolve_keyscan_policy(self.config.keyscan_policy, scan)
        return super().process(scan)

    def _set_key(self, frame: ScanFrame | None) -> bool:
        """Makes ``frame`` the keyscan (None clears it); returns whether a keyscan was set."""
        self._key, self._T_key_prev, self._key_is_prev = frame, np.eye(3), True
        return frame is not None


def resolve_keyscan_policy(policy: KeyscanPolicy | str, scan: LaserScan) -> KeyscanPolicy:
    """The policy object for a setting: itself, the learned model of a named preset, or for ``"auto"`` the
    model of the preset whose beam count and field of view are closest to ``scan``'s."""
    if not isinstance(policy, str):
        return policy
    name = policy if policy != "auto" else closest_preset(scan)
    log.info("SRF keyscan policy: learned working region of '%s'", name)
    return LearnedKeyscanPolicy.from_preset(name)


def closest_preset(scan: LaserScan) -> str:
    """The 2D lidar preset with a learned keyscan model that best matches the scan's beams and field of view."""
    beams = len(scan.angles_rad)
    span = abs(float(scan.angles_rad[-1] - scan.angles_rad[0]))
    fov = span * beams / (beams - 1) if beams > 1 else span

    def mismatch(name: str) -> float:
        p = LIDAR2D_PRESETS[name]
        return abs(beams - p.beams) / p.beams + abs(fov - math.radians(p.fov_deg)) / math.radians(p.fov_deg)

    return min(available_presets(), key=mismatch)
