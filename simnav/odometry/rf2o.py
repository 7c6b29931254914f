"""RF2O: planar laser odometry from range flow (thesis §3.F).

Every beam gives the range-flow constraint (3.64) on the scanner motion; the constraints are pre-weighted (3.71)
and minimised with the Cauchy M-estimator (3.66–3.68) by IRLS, in a coarse-to-fine pyramid with warping
(3.73–3.75), and each level's solution is filtered in the eigenspace of its covariance (3.77, 3.78). Kernels
live in :mod:`simnav.odometry.rangeflow`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from simnav.odometry.rangeflow import (
    MIN_ROWS,
    Alignment,
    CoarseToFine,
    LevelGeometry,
    Preweights,
    RangeFlowConfig,
    ScanFrame,
    Solution,
    irls_cauchy,
    make_config,
    require,
    weighted_constraints,
)
from simnav.odometry.rangeflow_fused import CAUCHY, LevelModel
from simnav.odometry.scan_odometry import RangeFlowOdometry


@dataclass(frozen=True)
class RF2OConfig(RangeFlowConfig):
    """RF2O options (shared ones: :class:`simnav.odometry.rangeflow.RangeFlowConfig`).

    Attributes:
        levels: coarse-to-fine pyramid levels (fewer if the coarsest would have under ``min_level_beams``).
        irls_iterations: reweighted solves per level after the first least-squares solve.
        cauchy_k_ratio: Cauchy width ``k`` (3.67) as a multiple of the mean absolute (pre-weighted) residual of
            the level's first least-squares solve, then fixed for its IRLS (0.1 mirrors the factor 10 of the
            reference implementation, which writes the weight as ``1 / (1 + (10 r / mean)²)``).
        filter_kl: ``k_l`` of the motion filter at the coarsest level (3.78: ``0.05 e^-(l-1)``).
        filter_ke: ``k_e`` of the motion filter at the coarsest level (3.78: ``15e3 e^-(l-1)``).
        preweight_eps_m2: ``epsilon`` of the pre-weights (3.71), m² (derivatives are per beam, ``Δt`` = 1 scan).
        preweight_kd: ``K_d`` of the pre-weights (3.71).
        inter_geometry: evaluate range, point and gradient of (3.64) at the mean of the two scans (as the
            published implementation does); False evaluates them on the previous scan.
    """

    levels: int = 5
    irls_iterations: int = 5
    cauchy_k_ratio: float = 0.1
    filter_kl: float = 0.05
    filter_ke: float = 15e3
    preweight_eps_m2: float = 1e-6
    preweight_kd: float = 0.2
    inter_geometry: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.levels >= 1, "levels must be >= 1")
        require(self.irls_iterations >= 0, "irls_iterations must be >= 0")
        require(self.cauchy_k_ratio > 0, "cauchy_k_ratio must be > 0")
        require(self.filter_kl >= 0 and self.filter_ke >= 0, "filter_kl and filter_ke must be >= 0")
        require(self.preweight_eps_m2 > 0, "preweight_eps_m2 must be > 0")


class RF2O(RangeFlowOdometry):
    """Range Flow-based 2D Odometry (§3.F): aligns each scan with the previous one.

    Args:
        **config: overrides of :class:`RF2OConfig` fields; an unknown name raises
            :class:`simnav.errors.ConfigError` listing the allowed ones.
    """

    def __init__(self, **config) -> None:
        self.config: RF2OConfig = make_config(RF2OConfig, config, "RF2O")
        self._ctf = CoarseToFine(self.config.filter_kl, self.config.filter_ke, max_rewarps=1)
        self._preweights = Preweights.rf2o(self.config.preweight_eps_m2, self.config.preweight_kd)
        self._model = LevelModel(self.config.inter_geometry, self._preweights, CAUCHY, self.config.irls_iterations,
                                 self.config.cauchy_k_ratio)
        super().__init__()

    def _levels(self, beams: int) -> int:
        return self.config.levels

    def _align(self, ref: ScanFrame, new: ScanFrame, xi_prior: np.ndarray) -> Alignment:
        return self._coarse_to_fine([ref.flat], ref, new, xi_prior)

    def _solve_level(self, refs: Sequence[np.ndarray], warped: np.ndarray, geom: LevelGeometry,
                     step: int) -> Solution | None:
        """Pre-weighted constraints (3.64, 3.71–3.72) of one level, solved with Cauchy IRLS (3.66–3.68)."""
        cfg = self.config
        system = weighted_constraints(refs[0], warped, geom, cfg.inter_geometry, self._preweights,
                                      information=geom is self._info_geom)
        if system.rows < MIN_ROWS:
            return None
        sol = irls_cauchy(system.A, system.b, cfg.irls_iterations, cfg.cauchy_k_ratio, system.mean_range_m)
        return sol if system.information is None else replace(sol, information=system.information)
