"""Metrics: accuracy of estimated trajectories against ground truth (RPE per second, ATE, drift per segment).

Pure numpy and evo (alignment); no simulator imports.
"""

from __future__ import annotations

from simnav.metrics.trajectory import (
    ALIGNMENTS,
    DEFAULT_SEGMENTS_M,
    ATEResult,
    DriftResult,
    RPEResult,
    ate,
    drift_per_segment,
    planar_trajectory,
    plot_trajectories,
    rpe_per_second,
)

__all__ = [
    "ALIGNMENTS",
    "DEFAULT_SEGMENTS_M",
    "ATEResult",
    "DriftResult",
    "RPEResult",
    "ate",
    "drift_per_segment",
    "planar_trajectory",
    "plot_trajectories",
    "rpe_per_second",
]
