"""Joint-VO-SF: visual odometry and piecewise-rigid scene flow from RGB-D in dynamic scenes (thesis §4.F).

Jaimez, Kerl, Gonzalez-Jimenez, Cremers, "Fast Odometry and Scene Flow from RGB-D Cameras based on Geometric
Clustering", ICRA 2017. Equation numbers below are the paper's ((1)–(22); the thesis numbers them 4.55–4.76).

Per frame:

1. **Geometric clustering** (§IV): K-means on the 3D points (24 clusters, seeded on a 6 x 4 image grid in the
   first frame and then from the previous frame's centres, see below), labels at every pyramid level from the same
   centres, and a graph G of spatially contiguous clusters.
2. **Robust odometry** (§V, (1)–(6)): photometric and geometric residuals of the backward warp, Cauchy M-estimator
   solved by IRLS, coarse to fine; pre-weights ``Z (1 - B^T)`` down-weight what moved at the previous frame.
3. **Background segmentation** (§VI, (7)–(15), (20)–(22)): per-cluster robust residuals after warping with the
   robust odometry, then the closed-form minimiser of the quadratic energy (data, spatial, temporal, depth prior)
   gives every cluster's probability ``b`` of moving: < 1/3 static, > 2/3 moving, in between uncertain.
4. **Odometry refinement and scene flow** (§VII, (16)–(19)): the static and uncertain clusters re-estimate the
   camera motion, every moving or uncertain cluster its own rigid motion, with the pre-weights (18)–(19).
5. **Propagation**: the segmentation is recomputed with the refined odometry and kept on the current image; the
   next frame samples it through its warp (``B^T``).

Conventions (see :mod:`simnav.geometry.se3`, :class:`simnav.sensors.readings.RGBDFrame`):

* The paper aligns frame 1 to frame 2 and clusters frame 1. Here frame 1 is the **current** frame and frame 2 the
  previous one, so the labels, segmentation and scene flow refer to the current image and the estimated transform
  ``T(xi)`` of (1)–(3) is directly the camera motion ``T_prev_curr`` (pose of the current optical frame in the
  previous one: points of the current frame are mapped into the previous frame and the previous images are
  sampled there).
* **Scene flow** (``extra["scene_flow_m"]``, (3, H, W) float32, m): for each pixel of the current image, the
  displacement in the world, from the previous frame to the current one, of the 3D point it observes, expressed in
  the current optical frame (x right, y down, z forward):
  ``s(x) = p(x) - T_curr_prev @ T_i @ p(x)`` with ``p(x)`` the pixel's point, ``T_i`` the rigid motion of its cluster
  (maps its points into the previous camera frame) and ``T_curr_prev = inv(T_prev_curr)``. It is 0 on the static
  background (``T_i = T_prev_curr``), equals ``RGBDFrame.velocity_optical * dt`` for a rigidly moving object, and is
  NaN where the current depth is invalid or no motion was measured (first frame, lost track). Near boundaries
  between contiguous clusters the motions are blended (§IV, "contiguous clusters are smoothed").
* Other extras: ``"labels"`` (H, W) int32 cluster of each pixel (-1 = invalid depth); ``"background_probability"``
  (K,) ``1 - b`` per cluster (1 when nothing was segmented); ``"moving_probability"`` (K,) ``b``;
  ``"moving_mask"`` (H, W) bool, valid pixels of the clusters labelled moving, ``"moving_clusters"`` (K,) bool
  (``b > moving_above``, or uncertain with an own motion of at least ``uncertain_moving_speed_m_s``, see
  :func:`moving_clusters`); ``"cluster_motions"``
  (K, 4, 4) ``T_curr_prev @ T_i`` (maps a point to where it was at the previous frame, current optical frame;
  identity for the background); ``"T_prev_curr_robust"`` (4, 4) the robust odometry of step 2;
  ``"cluster_residuals"`` (K,) the residuals (7) of the final segmentation (NaN: no data); ``"measured"``.

Images wider than ``max_width_px`` are processed at a downsampled pyramid level (the paper works at QVGA); the
extras are always at the input resolution.

Runtime: every per-pixel stage is a Numba kernel of :mod:`~simnav.odometry.vosf_kernels` working on one packed
array per pyramid level; loops over at least :data:`~simnav.odometry.vosf_kernels.PARALLEL_MIN` pixels (the finest
QVGA level) run on Numba's threads (``NUMBA_NUM_THREADS``), and the results do not depend on the number of threads.
``python scripts/bench_vosf_runtime.py [--threads N]`` times it.

Where this implementation departs from the paper (and why):

* Frame roles swapped (above), so outputs refer to the newest image. ``B^T`` of (6) and (14) is the previous
  frame's per-pixel segmentation sampled through the current warp (``W(x, xi)``) instead of being warped forward
  once the previous pair is solved: the same quantity, without predicting the next motion.
* Thresholds (21)–(22): the motion *scales* them, ``delta_L = (1 + 10 |xi|) delta_t``,
  ``delta_H = (2 + 10 |xi|) delta_t``, and the ceiling is ``t_M (1 + 10 |xi|)``, as the public implementation
  does (|xi| per frame, m and rad). The paper's additive ``+ 10 |xi|`` would exceed the residuals of any cluster
  (about 0.01) for an ordinary 1 cm / 0.5 degree step and mark everything static.
* The depth prior (15) weighs ``lambda_Z = 0.005`` instead of 0.15. With 0.15, ``lambda_Z (e^Zbar - e^Z_min)``
  outweighs the data term of a cluster just past ``delta_H`` (``w_D = sqrt 2``) from about 2.3 m on, so people
  walking 2-3 m ahead stayed static; counted as background they then pulled the refined odometry, and through
  ``B^T`` kept closer people static too. With the public code's thresholds (below), 0.02 labelled 62-87 % ->
  65-91 % of moving pixels moving on the simulated office sequences of ``scripts/bench_rgbd_odometry.py`` (0.0-0.2 %
  of static pixels either way) and lowered the RPE on every people sequence (robot among 3 people: 11.9 -> 0.6
  cm/s). With this implementation's thresholds, 0.02 still left people walking towards the camera static while
  they were far away (the robot among 4 people: 89.7 % labelled moving); 0.005 labels 92.7-95.4 % on the six
  people sequences (0 would give 93.4-97.3 %, with 0.6 % instead of 0.1 % of a static run's pixels labelled
  moving). The paper itself says its constants need retuning for other sensors and configurations (§VIII).
* ``t_B`` and ``t_M`` of (21) are 0.002 and 0.004, not the public code's 0.007 and 0.015 (set for real cameras'
  images). simnav's camera renders noise-free colour, and the clusters' median residual (7) on static runs is
  0.003-0.0045, so the old floor, not the median, set the thresholds: people walking 2-3 m ahead and slow walkers
  stayed static, and when a close person filled half of the view their residuals lifted the median towards the
  old ceiling, the thresholds went up with it, the person was called static and the robust odometry followed them
  (seed 001's Fig. 2F). On the simulated office sequences of ``scripts/bench_rgbd_odometry.py`` (six people
  sequences, ``lambda_Z`` 0.02): 69-91 % -> 89.7-94.6 % of moving pixels labelled moving, 0.0-0.2 % -> 0.0-0.7 % of
  static pixels, the RPE of the robot among 5 people 5.26 -> 0.31 cm/s (README). On real RGB-D data set the public
  code's ``residual_floor=0.007, residual_ceiling=0.015`` (not measured here).
* (7) averages absolute residuals, caps ``|r_Z|`` at ``Delta Z_occ`` and leaves depth-edge pixels out, as the public
  code does (edges have high residuals however well aligned).
* (18)–(19) are read as inverse variances: each residual is multiplied by ``sqrt(K / (K + |grad|^2 + r^2))``, the
  square root of the paper's weight normalised to 1 on smooth, aligned pixels (the public code also takes square
  roots), so ``alpha_I`` keeps the balance of (4). ``r`` is the residual at the current linearisation point (the
  temporal difference after warping). Pixels of uncertain clusters enter the background solve scaled by
  ``sqrt(1 - b)`` (the public code's weighting; the paper only says they are used for both).
* Warping is backward (sample the previous images at ``W(x, xi)``, bilinear, nearest pixel across depth
  discontinuities) in every stage; the Jacobians use the mean gradient of both images (ESM-like, the public
  code's "inter" images). The intensity pyramid is a plain (not depth-gated) average (see
  :func:`~simnav.odometry.vosf_kernels.downsample`).
* The motions of contiguous clusters are blended (soft labels) only in the scene-flow output; every solve uses
  hard labels.
* The robust odometry re-warps a level (at most ``max_warps_per_level`` times, the public code's 3) until the
  level's last increment is shorter than ``warp_tolerance`` = 1e-3 (m and rad together). The public code stops at
  0.04, which at 30 Hz leaves every level after the coarsest one warp; 1e-4 (this implementation's first value)
  re-warped the finest level for increments of a fraction of a millimetre. With 1e-3, on the 15 office sequences
  of the README the segmentation stays within 0.2 points of 1e-4's, the RPE within 0.03 cm/s (the hand-held run
  among 4 people 0.57 -> 0.60 cm/s; 0.64 with 0.04), and a frame of the hand-held run among 4 people takes 0.79x
  as long (``python scripts/bench_odometry_ab.py REV --method vosf --threads 2 --sequence handheld-people4``;
  0.86x on the robot among 3 people).
* K-means starts from the previous frame's centres moved by the constant-velocity prediction of the camera
  motion (``kmeans_warm_start``; a cluster left with fewer than ``min_cluster_pixels`` points is seeded again at
  the point farthest from the other centres), not from the image grid in every frame as the paper and its public
  code: the clusters then stay on the same objects from frame to frame. Seeded from the grid, a person far down a
  corridor shared a cluster with the floor and the wall around their feet in some frames and not in others, and
  was labelled static in those (the simulated hand-held office run among 1 person of
  ``scripts/bench_rgbd_odometry.py``: 85.2 -> 95.9 % of moving pixels labelled moving; README for all sequences).
* Residuals over a longer baseline (``long_baseline_frames`` = 3, an addition): each cluster's residual (7) is also
  taken against the frame 3 frames back, warped with the odometry since then composed with the current motion,
  and the larger of the two enters (10)–(12) (the thresholds follow their median, as before). A person walking at
  0.1-0.5 m/s 2 m away moves 3-17 mm between frames at 30 Hz, within a static cluster's residual from the depth
  noise and the warp; over 3 frames three times as far, while a static cluster's residual hardly grows. On the
  simulated hand-held office run among 3 people with ``--seed 10`` of ``scripts/bench_rgbd_odometry.py``, where a
  person 1.8-2 m ahead walks at 0.13-0.56 m/s inside clusters labelled static, 77.0 -> 93.0 % of moving pixels are
  labelled moving (README for every sequence). Slowly swinging door leaves are labelled moving too; their own
  frame-to-frame motions (17) are poorly constrained (a plain plane), which raises the scene flow's NRMS there.
  ``long_baseline_level`` = 1 takes the long-baseline residuals at half resolution (a quarter of the cost).
* Additions: a constant-velocity initial guess, a covariance with degeneracy detection, and motions also for
  clusters that only the final segmentation marks as moving or uncertain.
* Labels (``moving_mask``, ``moving_clusters``): the paper's moving class is ``b > 2/3``; here an uncertain cluster
  (``1/3 < b <= 2/3``) is labelled moving too when the rigid motion (17) solved for it moves its centre at least
  ``uncertain_moving_speed_m_s`` = 0.5 m/s (a slow walk) relative to the background (:func:`moving_clusters`; ``b``
  itself, the odometry and the propagation are unchanged). On the simulated office sequences most moving pixels
  left unlabelled lay in uncertain clusters: a person together with the floor or wall beside them, or a cluster
  wholly on a person held just under 2/3 by the temporal and spatial terms. On 13 people sequences of
  ``scripts/bench_rgbd_odometry.py`` 44.6-97.9 % -> 78.2-99.4 % of moving pixels labelled moving, at most 1.3 % of
  static pixels (README).
* Degeneracy is judged on the information of the final alignment at the 80 x 60 level (``degeneracy_width_px``),
  not the finest: with a plain wall filling the view, the depth noise's gradients made the finest levels look
  constrained along the wall, so the frames were not flagged, the noise decided the motion along the wall and the
  next prediction started from it (the estimate sped up to 1.4 m/s on the simulated hand-held office run with
  ``--seed 10``). At 80 x 60 the noise is averaged out and the wall's frames fall below ``degeneracy_threshold``;
  a degenerate increment keeps the translational part of the constant-velocity prediction along its unobservable
  directions (``hold_degenerate``, as DIFODO does; holding the rotation too made the hand-held runs' rotational
  error 2-2.6x as large, README).
* An alignment that starts from a prediction (the constant-velocity guess; the robust odometry for the refined
  and cluster solves) skips the 15 x 20 level (``predicted_min_level_height_px``): what is left to find is within
  the finer levels' reach, whereas in a corridor whose end is beyond the depth range the 15 x 20 image leaves the
  forward motion almost unconstrained, so that level's increment could jump several centimetres off a correct
  prediction onto a person walking ahead, and the finer levels then converged there (one such frame locked the
  odometry onto the person for the next 50 frames of a simulated hand-held sequence).

Limitation (the paper's, measured on the synthetic scenes of the tests): the robust odometry of step 2 finds the
dominant motion near its initial guess. When the camera and a close, large moving object (a quarter or more of the
image) both move from the very first pair, it can lock onto the object; the segmentation then marks the
background as moving and ``B^T`` keeps it so. Starting from rest (or from any frame where the object is already
segmented) the propagated segmentation keeps the object out.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, fields
from typing import NamedTuple

import numpy as np

from simnav.errors import ConfigError
from simnav.geometry import se3
from simnav.odometry import vosf_kernels as kern
from simnav.odometry.base import CameraOdometryEstimate
from simnav.odometry.difodo import hold_weak_translations
from simnav.odometry.rangeflow import make_config
from simnav.sensors.readings import RGBDFrame

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------------------------
# Configuration


@dataclass(frozen=True)
class VOSFConfig:
    """Joint-VO-SF options; the defaults are the paper's (§VIII) and its public implementation's but for
    ``lambda_depth``, ``residual_floor``, ``residual_ceiling`` and ``warp_tolerance`` (module notes).

    Attributes:
        cluster_grid_cols, cluster_grid_rows: K-means seeds on a cols x rows image grid; their product is the
            number of clusters N (§IV: 24 on 6 x 4).
        kmeans_level: K-means clusters the points of this pyramid level (0 = finest processing level; the public
            implementation clusters at half resolution, 120 x 160 for QVGA).
        kmeans_max_iterations: most K-means rounds.
        kmeans_tolerance_m: K-means stops once no centre moves more than this, m.
        kmeans_warm_start: K-means starts from the previous frame's centres moved by the constant-velocity
            prediction of the camera motion (False: from the image grid every frame, as the paper; module notes).
        connectivity_gap_m, connectivity_gap_px: clusters are contiguous (G_ij = 1) where neighbouring pixels of
            both are closer in 3D than ``max(gap_m, gap_px * z / f)``.
        max_width_px: finest processing width; wider images are downsampled first (the paper runs at QVGA).
        min_level_height_px: the coarsest pyramid level is at least this tall (QVGA: 5 levels, 15 x 20 last).
        predicted_min_level_height_px: an alignment that starts from a prediction (the constant-velocity prior, or
            the robust odometry for the refined and cluster solves) skips the levels shorter than this (QVGA: the
            15 x 20 one; see the module notes).
        pyramid_gate_m: depth-similarity gate of the downsampling, m.
        min_depth_m, max_depth_m: depths outside are treated as invalid, m.
        use_photometric: use the photometric residuals (2) when both frames have colour.
        photometric_weight: ``alpha_I`` of (4), (7), (17).
        cauchy_odometry, cauchy_clusters, cauchy_refinement: Cauchy ``c`` of the robust odometry, the cluster
            motions and the refined odometry, relative to the mean absolute residual (20).
        irls_max_iterations: most reweighted solves per linearisation.
        irls_chi2_ratio: IRLS stops when the weighted cost falls by less than ``1 - irls_chi2_ratio``.
        irls_delta_tolerance: IRLS stops when the twist changes by less than this (max norm; m, rad).
        max_warps_per_level: most re-warps/re-linearisations per pyramid level of the robust odometry.
        refinement_warps_per_level: the same for the refined odometry (which starts from the robust one) and the
            cluster motions (which start from the refined one).
        warp_tolerance: stop re-warping a level once the last increment's norm is below this (m, rad; the public
            code's 0.04 re-warps no level after the coarsest at 30 Hz, see the module notes).
        warp_gate_m: warped samples are bilinear where the 2 x 2 target depths span less than this, else taken
            from the nearest pixel, m.
        gradient_eps_m: regulariser of the edge-aware gradient weights, m.
        symmetric_gradients: linearise with the mean gradient of both images (ESM-like, the public code's "inter"
            images) instead of the previous image's alone.
        segmentation: run the segmentation and the per-cluster estimation (False: plain robust odometry (4) with
            ``w_R = Z``, every cluster background, scene flow NaN).
        temporal_propagation: use the previous segmentation ``B^T`` in (6) and (14).
        occlusion_threshold_m: ``Delta Z_occ`` (8); also caps the geometric residuals of (7), m.
        edge_threshold_m: pixels whose depth differs from their 4 neighbours by this much in total are left out of
            (7) (their residuals are high however well aligned), m.
        lambda_spatial, lambda_temporal, lambda_depth: ``lambda_R``, ``lambda_T``, ``lambda_Z`` of (13)–(15)
            (``lambda_Z`` 0.005, not the paper's 0.15: see the module notes).
        zmin_fraction: ``Z_Min`` of (15) is this fraction of the mean scene depth.
        residual_floor, residual_ceiling: ``t_B`` and ``t_M`` of (21), chosen for simnav's simulated camera (module
            notes; the public code's 0.007 and 0.015 were set for real cameras).
        motion_gain: growth of the thresholds with the norm of the camera motion per frame (21)–(22).
        static_below, moving_above: clusters with ``b`` below / above are static / moving; in between uncertain.
        uncertain_moving_speed_m_s: an uncertain cluster is labelled moving in ``moving_mask`` when its own rigid
            motion (17) moves its centre at least this fast relative to the background, m/s (``inf``: only the
            clusters with ``b > moving_above``, the paper's moving class; module notes).
        preweight_kz, preweight_ki: ``K_Z``, ``K_I`` of (18)–(19).
        min_cluster_pixels: fewest pixels a cluster (or the background) needs at a level to be solved there and
            to enter (7).
        soft_label_sharpness_per_m, soft_label_cutoff: blending of the motions of contiguous clusters in the
            scene flow: weight ``exp(-sharpness (d_j - d_own))``, d = distance to the cluster centres, dropped
            beyond the cutoff exponent.
        constant_velocity_prior: start each alignment from the last motion (scaled to the new interval).
        min_valid_points, min_valid_fraction: a frame with fewer valid depths (finest processing level) is not
            aligned; the prior is reported with covariance ``lost_variance * I``.
        lost_variance: variance (m^2, rad^2) reported for a predicted increment and added along the unobservable
            direction of a degenerate one.
        degeneracy_threshold: the estimate is degenerate along the directions whose eigenvalue of the background's
            information (rotations scaled by the mean depth) is below this fraction of the largest.
        degeneracy_width_px: that information is the alignment's at the pyramid level closest to this width
            (QVGA and QQVGA: 80 x 60): at the finest levels the depth noise's gradients make a plain wall filling
            the view look constrained along the wall (module notes).
        hold_degenerate: a degenerate increment keeps the constant-velocity prediction's translation along its
            unobservable directions (else the solve's noise decides it, and the next prediction starts from that).
        long_baseline_frames: each cluster's residual (7) is also taken against the frame this many frames back
            (camera motion from the odometry since then), and the larger of the two enters (10)-(12); 0 or 1: frame
            to frame only, as the paper (module notes).
        long_baseline_level: pyramid level of those long-baseline residuals (0 = finest processing level; 1: a
            quarter of the pixels and of the cost).
    """

    cluster_grid_cols: int = 6
    cluster_grid_rows: int = 4
    kmeans_level: int = 1
    kmeans_max_iterations: int = 10
    kmeans_tolerance_m: float = 0.01
    kmeans_warm_start: bool = True
    connectivity_gap_m: float = 0.05
    connectivity_gap_px: float = 2.0
    max_width_px: int = 320
    min_level_height_px: int = 15
    predicted_min_level_height_px: int = 30
    pyramid_gate_m: float = 0.1
    min_depth_m: float = 0.1
    max_depth_m: float = 10.0
    use_photometric: bool = True
    photometric_weight: float = 0.15
    cauchy_odometry: float = 0.2
    cauchy_clusters: float = 1.0
    cauchy_refinement: float = 2.0
    irls_max_iterations: int = 10
    irls_chi2_ratio: float = 0.98
    irls_delta_tolerance: float = 1e-6
    max_warps_per_level: int = 3
    refinement_warps_per_level: int = 1
    warp_tolerance: float = 1e-3
    warp_gate_m: float = 0.3
    gradient_eps_m: float = 0.005
    symmetric_gradients: bool = True
    segmentation: bool = True
    temporal_propagation: bool = True
    occlusion_threshold_m: float = 0.2
    edge_threshold_m: float = 0.3
    lambda_spatial: float = 0.5
    lambda_temporal: float = 1.5
    lambda_depth: float = 0.005
    zmin_fraction: float = 0.25
    residual_floor: float = 0.002
    residual_ceiling: float = 0.004
    motion_gain: float = 10.0
    static_below: float = 1.0 / 3.0
    moving_above: float = 2.0 / 3.0
    uncertain_moving_speed_m_s: float = 0.5
    preweight_kz: float = 1e-4
    preweight_ki: float = 0.1
    min_cluster_pixels: int = 30
    soft_label_sharpness_per_m: float = 100.0
    soft_label_cutoff: float = 6.0
    constant_velocity_prior: bool = True
    min_valid_points: int = 300
    min_valid_fraction: float = 0.05
    lost_variance: float = 1.0
    degeneracy_threshold: float = 3e-4
    degeneracy_width_px: int = 80
    hold_degenerate: bool = True
    long_baseline_frames: int = 3
    long_baseline_level: int = 0

    def __post_init__(self) -> None:
        _require(self.cluster_grid_cols >= 1 and self.cluster_grid_rows >= 1, "cluster grid must be >= 1 x 1")
        _require(self.num_clusters >= 2, "need at least 2 clusters")
        _require(self.kmeans_level >= 0 and self.kmeans_max_iterations >= 1, "bad K-means settings")
        _require(self.max_width_px >= 8 and self.min_level_height_px >= 2, "bad pyramid sizes")
        _require(self.predicted_min_level_height_px >= self.min_level_height_px,
                 "predicted_min_level_height_px must be >= min_level_height_px")
        _require(0 < self.min_depth_m < self.max_depth_m, "need 0 < min_depth_m < max_depth_m")
        _require(self.photometric_weight >= 0, "photometric_weight must be >= 0")
        _require(min(self.cauchy_odometry, self.cauchy_clusters, self.cauchy_refinement) > 0,
                 "Cauchy factors must be > 0")
        _require(min(self.irls_max_iterations, self.max_warps_per_level, self.refinement_warps_per_level) >= 1,
                 "need at least one iteration")
        _require(0 <= self.static_below <= self.moving_above <= 1, "need 0 <= static_below <= moving_above <= 1")
        _require(self.uncertain_moving_speed_m_s >= 0,
                 f"uncertain_moving_speed_m_s must be >= 0 (inf: never), got {self.uncertain_moving_speed_m_s}")
        _require(0 < self.residual_floor <= self.residual_ceiling, "need 0 < residual_floor <= residual_ceiling")
        _require(self.preweight_kz > 0 and self.preweight_ki > 0, "pre-weight constants must be > 0")
        _require(self.min_cluster_pixels >= 6, "min_cluster_pixels must be >= 6")
        _require(self.lost_variance > 0, "lost_variance must be > 0")
        _require(self.degeneracy_threshold >= 0, "degeneracy_threshold must be >= 0")
        _require(self.degeneracy_width_px >= 1, "degeneracy_width_px must be >= 1")
        _require(self.long_baseline_frames >= 0, "long_baseline_frames must be >= 0 (0: off)")
        _require(self.long_baseline_level >= 0, "long_baseline_level must be >= 0")

    @property
    def num_clusters(self) -> int:
        """Number of K-means clusters N."""
        return self.cluster_grid_cols * self.cluster_grid_rows


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def make_vosf_config(config: VOSFConfig | None = None, **overrides) -> VOSFConfig:
    """``config`` (or the defaults) with keyword overrides; an unknown name raises :class:`ConfigError` listing the
    allowed ones."""
    base = config if config is not None else VOSFConfig()
    return make_config(VOSFConfig, {**{f.name: getattr(base, f.name) for f in fields(VOSFConfig)}, **overrides},
                       "Joint-VO-SF")


# ----------------------------------------------------------------------------------------------------------------
# Frames and pyramids


@dataclass
class _Level:
    """One pyramid level of one frame (images (h, w) float64; flat = row-major ravel)."""

    depth: np.ndarray
    cam: np.ndarray  # fx, fy, cx, cy
    x: np.ndarray
    y: np.ndarray
    pack: np.ndarray  # (h, w, kern.PACK) depth, intensity, gradients, B (moving probability of the cluster)
    valid_idx: np.ndarray  # flat indices of valid depths
    labels: np.ndarray | None = None  # (h, w) int32 cluster, -1 invalid
    by_label: tuple[np.ndarray, np.ndarray] | None = None  # valid flat indices grouped by cluster, offsets
    edges: np.ndarray | None = None  # flat depth-edge mask (pixels left out of the residuals (7))

    def cluster_pixels(self, lab: int, k: int) -> np.ndarray:
        """Flat indices (increasing) of the pixels of cluster ``lab`` of ``k``."""
        if self.by_label is None:
            self.by_label = kern.label_order(self.labels.ravel(), self.valid_idx, k)
        order, offsets = self.by_label
        return order[offsets[lab]:offsets[lab + 1]]


@dataclass
class _Frame:
    """A prepared frame: processing levels (finest first), clustering and segmentation."""

    stamp_s: float
    levels: list[_Level]
    has_intensity: bool
    full_depth: np.ndarray  # input resolution, sanitised
    full_cam: np.ndarray
    mean_depth: float  # mean valid depth of the finest level, m
    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    graph: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    zbar: np.ndarray = field(default_factory=lambda: np.zeros(0))  # mean depth per cluster (finest level), m
    segmented: bool = False


class _Solve(NamedTuple):
    """Result of a coarse-to-fine alignment."""

    T: np.ndarray  # (4, 4) T_prev_curr of the solved pixels
    H: np.ndarray  # (6, 6) weighted normal matrix of the last solve
    s2: float  # weighted residual variance
    pixels: int  # pixels used by the last solve
    level: int  # level of the last solve (0 = finest)
    H_test: np.ndarray | None = None  # (6, 6) normal matrix at the degeneracy test's level (None: not solved)


def _camera(K: np.ndarray) -> np.ndarray:
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dtype=np.float64)


def _half_camera(cam: np.ndarray) -> np.ndarray:
    """Intrinsics of the 2x downsampled image (coarse pixel i is centred on fine pixels 2i, 2i + 1)."""
    return np.array([cam[0] / 2, cam[1] / 2, (cam[2] - 0.5) / 2, (cam[3] - 0.5) / 2])


def _points(depth: np.ndarray, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) x and y coordinates of the back-projected depth image, m."""
    h, w = depth.shape
    u = (np.arange(w) - cam[2]) / cam[0]
    v = (np.arange(h) - cam[3]) / cam[1]
    return depth * u[None, :], depth * v[:, None]


def _make_level(depth: np.ndarray, intensity: np.ndarray, cam: np.ndarray, eps_m: float) -> _Level:
    x, y = _points(depth, cam)
    return _Level(depth, cam, x, y, kern.level_pack(depth, intensity, eps_m), np.flatnonzero(depth.ravel() > 0))


# ----------------------------------------------------------------------------------------------------------------
# Segmentation energy


class Segmentation(NamedTuple):
    """Per-cluster result of the background segmentation.

    Attributes:
        b: (N,) probability of each cluster to be moving, in [0, 1].
        residuals: (N,) robust mean residuals delta_i (7); NaN where a cluster has no data.
        delta_low, delta_high: the thresholds delta_L, delta_H of (22).
    """

    b: np.ndarray
    residuals: np.ndarray
    delta_low: float
    delta_high: float


def segment_background(residuals: np.ndarray, mean_depth_m: np.ndarray, graph: np.ndarray,
                       b_prev: np.ndarray | None, motion_norm: float, scene_depth_m: float,
                       config: VOSFConfig) -> Segmentation:
    """Minimises the segmentation energy (9)–(15) in closed form.

    ``E(b) = sum w_D (b_i - g(delta_i))^2 + lambda_R sum_{i<j} G_ij (b_i - b_j)^2 + lambda_T sum (b_i - b^T_i)^2
    + lambda_Z sum max(0, exp(Zbar_i) - exp(Z_min)) b_i^2`` is quadratic, so ``b`` solves the linear system
    ``(W_D + lambda_R L + lambda_T I + lambda_Z D_Z) b = W_D g + lambda_T b^T`` (L the Laplacian of G), clipped
    to [0, 1]. Thresholds (21)–(22) with the camera motion scaling them (module notes):
    ``delta_t = min(t_M (1 + k |xi|), max(t_B, median delta))``, ``delta_L = (1 + k |xi|) delta_t``,
    ``delta_H = (2 + k |xi|) delta_t``, ``k = motion_gain``.

    Args:
        residuals: (N,) delta_i of (7), NaN for clusters without data (no data term).
        mean_depth_m: (N,) mean depth Zbar_i of each cluster, m (NaN or 0 for empty clusters: b = 0).
        graph: (N, N) bool contiguity G.
        b_prev: (N,) propagated segmentation b^T (NaN where unknown: no temporal term), or None (first pair).
        motion_norm: norm of the camera motion's twist over the frame interval (m and rad).
        scene_depth_m: mean depth of the scene, m (Z_min = zmin_fraction of it).
        config: the thresholds and weights.

    Returns:
        The segmentation.
    """
    cfg = config
    n = len(residuals)
    present = np.isfinite(mean_depth_m) & (mean_depth_m > 0)
    data = np.isfinite(residuals) & present
    if not np.any(data):
        return Segmentation(np.zeros(n), residuals, math.nan, math.nan)
    # Thresholds (21)-(22).
    growth = cfg.motion_gain * motion_norm
    median = float(np.median(residuals[data]))
    delta_t = min(cfg.residual_ceiling * (1.0 + growth), max(cfg.residual_floor, median))
    lo, hi = (1.0 + growth) * delta_t, (2.0 + growth) * delta_t
    # Data term (10)-(12).
    d = np.where(data, residuals, 0.0)
    g = np.clip((d - lo) / (hi - lo), 0.0, 1.0)
    w_data = np.where(data, np.sqrt(((2.0 * d - (hi + lo)) / (hi - lo)) ** 2 + 1.0), 0.0)
    # Temporal (14) and depth-prior (15) terms.
    temporal = np.zeros(n) if b_prev is None else np.where(np.isfinite(b_prev) & present, cfg.lambda_temporal, 0.0)
    bt = np.zeros(n) if b_prev is None else np.nan_to_num(b_prev)
    zbar = np.where(present, np.minimum(np.nan_to_num(mean_depth_m), 50.0), 0.0)
    z_min = cfg.zmin_fraction * scene_depth_m
    depth_prior = np.where(present, cfg.lambda_depth * np.maximum(0.0, np.exp(zbar) - math.exp(min(z_min, 50.0))), 0.0)
    # Spatial term (13): Laplacian of the graph between present clusters.
    G = np.asarray(graph, dtype=bool)
    G = (G | G.T) & present[:, None] & present[None, :]
    np.fill_diagonal(G, False)
    L = np.diag(G.sum(axis=1).astype(float)) - G.astype(float)
    A = np.diag(w_data + temporal + depth_prior + 1e-9) + cfg.lambda_spatial * L
    b = np.linalg.solve(A, w_data * g + temporal * bt)
    return Segmentation(np.where(present, np.clip(b, 0.0, 1.0), 0.0), residuals, lo, hi)


def moving_clusters(b: np.ndarray, centres_m: np.ndarray, motions: np.ndarray, dt_s: float,
                    config: VOSFConfig) -> np.ndarray:
    """Which clusters are labelled moving: ``b`` above ``moving_above``, or uncertain (above ``static_below``) with
    a rigid motion of their own that moves their centre at least ``uncertain_moving_speed_m_s``.

    Args:
        b: (N,) probability of each cluster to be moving.
        centres_m: (N, 3) cluster centres, current optical frame, m.
        motions: (N, 4, 4) ``T_curr_prev @ T_i`` of each cluster (a point's position at the previous frame, current
            optical frame; identity for the background), as ``extra["cluster_motions"]``.
        dt_s: frame interval, s (not positive: no speed test).
        config: the thresholds.

    Returns:
        (N,) bool.
    """
    moving = b > config.moving_above
    uncertain = (b > config.static_below) & ~moving
    if not (dt_s > 0 and np.any(uncertain)):
        return moving
    before = np.einsum("nij,nj->ni", motions[:, :3, :3], centres_m) + motions[:, :3, 3]
    with np.errstate(invalid="ignore"):
        fast = np.linalg.norm(centres_m - before, axis=1) >= config.uncertain_moving_speed_m_s * dt_s
    return moving | (uncertain & fast)


# ----------------------------------------------------------------------------------------------------------------
# The odometry


class JointVOSF:
    """Joint visual odometry and piecewise-rigid scene flow (§4.F) as a :class:`~simnav.odometry.base.FrameOdometry`.

    Args:
        config: options (defaults: :class:`VOSFConfig`).
        **overrides: field overrides of ``config``; an unknown name raises :class:`simnav.errors.ConfigError`.
    """

    def __init__(self, config: VOSFConfig | None = None, **overrides) -> None:
        self.config = make_vosf_config(config, **overrides)
        self._warned: set[str] = set()
        self._work: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next frame starts a new odom frame."""
        self._prev: _Frame | None = None
        self._prev_stamp_s: float | None = None
        self._T_odom_camera = np.eye(4)
        self._xi_last: np.ndarray | None = None  # last measured increment log(T_prev_curr)
        self._dt_last = 0.0
        self._history: deque[tuple[_Frame, np.ndarray]] = deque(maxlen=max(self.config.long_baseline_frames, 1))

    # -- the pipeline ------------------------------------------------------------------------------------------

    def process(self, frame: RGBDFrame) -> CameraOdometryEstimate:
        """Estimate the motion since the previous frame (see the module docs for the outputs).

        Args:
            frame: the new RGB-D (or depth-only) frame; NaN/inf/out-of-range depths are treated as invalid.

        Returns:
            The estimate; ``extra`` holds the scene flow, labels and segmentation.
        """
        t0 = time.perf_counter()
        cfg = self.config
        first = self._prev_stamp_s is None
        dt = float(frame.stamp_s - self._prev_stamp_s) if not first else 0.0
        prior = self._prior(dt)
        # 1. Sanitised pyramid of the new frame, its K-means clusters and their contiguity graph.
        cur = self._prepare(frame, self._predicted_centres(prior))
        # 2.-5. Robust odometry, segmentation, refined odometry and cluster motions against the previous frame.
        paired = cur is not None and self._prev is not None and len(cur.levels) == len(self._prev.levels)
        est = self._estimate(cur, self._prev, prior) if paired else None
        # 6. Pose, twist and covariance of the increment.
        if est is not None:
            T_inc, cov, degenerate = est["T"], est["cov"], est["degenerate"]
        else:
            T_inc = np.eye(4) if first else prior
            cov = np.zeros((6, 6)) if first else cfg.lost_variance * np.eye(6)
            degenerate = not first
        self._T_odom_camera = self._T_odom_camera @ T_inc
        xi = se3.log(T_inc)
        twist = xi / dt if dt > 0 else np.zeros(6)
        if est is not None:
            self._xi_last, self._dt_last = xi, dt
        T_base_cam = _mount(frame.T_base_sensor)
        T_odom_base = T_base_cam @ self._T_odom_camera @ se3.inverse(T_base_cam)
        extra = self._extras(frame, cur, est, dt)
        # 7. The new frame (with its segmentation, B^T of the next one) becomes the reference.
        self._prev = cur
        self._prev_stamp_s = float(frame.stamp_s)
        if cur is None:
            self._history.clear()
        else:
            self._history.append((cur, self._T_odom_camera.copy()))
        return CameraOdometryEstimate(
            stamp_s=float(frame.stamp_s), T_odom_camera=self._T_odom_camera.copy(), T_odom_base=T_odom_base,
            twist_camera=_finite(twist), covariance=_finite(0.5 * (cov + cov.T)), degenerate=bool(degenerate),
            valid_points=int(est["pixels"]) if est is not None else 0, runtime_s=time.perf_counter() - t0,
            extra=extra)

    def _estimate(self, cur: _Frame, prev: _Frame, prior: np.ndarray) -> dict | None:
        """Steps 2-5 of the module docs for one pair; None when the robust odometry found nothing to align."""
        cfg = self.config
        use_photo = cfg.use_photometric and cur.has_intensity and prev.has_intensity
        use_b = cfg.segmentation and cfg.temporal_propagation and prev.segmented
        k = cfg.num_clusters
        # 2. Robust odometry (4)-(6): every valid pixel, pre-weights Z (1 - B^T), c = 0.2 mean |r|.
        robust = self._align(cur, prev, [lv.valid_idx for lv in cur.levels], None, kern.MODE_ROBUST,
                             cfg.cauchy_odometry, prior, use_photo, use_b, predicted=self._predicting())
        if robust is None:
            return None
        T_R = robust.T
        if not cfg.segmentation:
            seg = Segmentation(np.zeros(k), np.full(k, np.nan), math.nan, math.nan)
            weak = self._weak_directions(robust, cur)
            return self._result(cur, robust, self._held(robust, prior, weak, cur), None, seg, T_R, weak)
        # 3. Background segmentation (7)-(15) with the robust odometry.
        seg = self._segment(cur, prev, T_R, use_photo, use_b)
        # 4a. Refined odometry from the static and uncertain clusters (17)-(19), c = 2 mean |r|.
        groups, scales = self._background_groups(cur, seg.b)
        refined = self._align(cur, prev, groups, scales, kern.MODE_REFINE, cfg.cauchy_refinement, T_R, use_photo,
                              False)
        final = refined if refined is not None else robust
        weak = self._weak_directions(final, cur)
        T_O = self._held(final, prior, weak, cur)  # the predicted translation along unobservable directions
        # 4b. Rigid motion of every moving or uncertain cluster (17), c = mean |r|.
        T_clusters = np.tile(T_O, (k, 1, 1))
        solved = self._cluster_motions(cur, prev, seg.b > cfg.static_below, T_O, use_photo, T_clusters)
        # 5. Segmentation again with the refined odometry: the output, and B^T of the next frame (clusters that
        #    only now turn out moving or uncertain get their motion too).
        seg = self._segment(cur, prev, T_O, use_photo, use_b)
        moving_or_uncertain = seg.b > cfg.static_below
        self._cluster_motions(cur, prev, moving_or_uncertain & ~solved, T_O, use_photo, T_clusters)
        T_clusters[~moving_or_uncertain] = T_O
        motions = se3.inverse(T_O)[None] @ T_clusters
        return self._result(cur, final, T_O, motions, seg, T_R, weak)

    def _cluster_motions(self, cur: _Frame, prev: _Frame, which: np.ndarray, T0: np.ndarray, use_photo: bool,
                         T_clusters: np.ndarray) -> np.ndarray:
        """Solves (17) for the clusters flagged in ``which`` from ``T0``, writing ``T_clusters``; returns the flags."""
        k = self.config.num_clusters
        for lab in np.flatnonzero(which):
            groups = [lv.cluster_pixels(lab, k) for lv in cur.levels]
            sol = self._align(cur, prev, groups, None, kern.MODE_REFINE, self.config.cauchy_clusters, T0, use_photo,
                              False)
            if sol is not None and np.all(np.isfinite(sol.T)):
                T_clusters[lab] = sol.T
        return which

    def _result(self, cur: _Frame, sol: _Solve, T: np.ndarray, motions: np.ndarray | None, seg: Segmentation,
                T_R: np.ndarray, weak: np.ndarray) -> dict:
        """Stores the segmentation on the current frame and packs the estimate with its covariance."""
        for lv in cur.levels:
            kern.set_moving(lv.pack, lv.labels, seg.b)
        cur.segmented = self.config.segmentation
        cov = self._covariance(sol, weak, cur)
        return {"T": T, "cov": cov, "degenerate": weak.shape[1] > 0, "pixels": sol.pixels if sol.level == 0 else 0,
                "motions": motions, "seg": seg, "T_R": T_R}

    # -- steps ---------------------------------------------------------------------------------------------------

    def _align(self, cur: _Frame, prev: _Frame, groups: list[np.ndarray], scales: list[np.ndarray] | None,
               mode: int, c_factor: float, T0: np.ndarray, use_photo: bool, use_b: bool,
               predicted: bool = True) -> _Solve | None:
        """Coarse-to-fine IRLS of one rigid motion for the listed pixels of every level (a level with fewer than
        ``min_cluster_pixels`` is skipped; from a ``predicted`` ``T0`` so are the levels shorter than
        ``predicted_min_level_height_px``); None when no level could be solved."""
        cfg = self.config
        T = np.array(T0, dtype=np.float64)
        rows = 2 if use_photo else 1
        warps = cfg.max_warps_per_level if mode == kern.MODE_ROBUST else cfg.refinement_warps_per_level
        min_height = cfg.predicted_min_level_height_px if predicted else 0
        test_level = _nearest_level(cur, cfg.degeneracy_width_px)
        last: _Solve | None = None
        H_test = None
        for lv in range(len(cur.levels) - 1, -1, -1):
            if lv > 0 and cur.levels[lv].depth.shape[0] < min_height:
                continue  # a prediction is within reach of the finer levels
            idx = groups[lv]
            n = len(idx)
            if n < cfg.min_cluster_pixels:
                continue
            ref, tgt = cur.levels[lv], prev.levels[lv]
            scale = scales[lv] if scales is not None else _NO_SCALE
            r, J, ok = self._buffers(n)
            for _ in range(warps):
                kern.linearize(idx, scale, ref.x.ravel(), ref.y.ravel(), ref.pack, cfg.symmetric_gradients, T, tgt.cam,
                               tgt.pack, use_b, use_photo, cfg.warp_gate_m, mode, cfg.photometric_weight,
                               cfg.preweight_kz, cfg.preweight_ki, r, J, ok)
                delta, H, s2, m = kern.irls_cauchy(r, J, ok, rows, c_factor, cfg.irls_max_iterations,
                                                   cfg.irls_chi2_ratio, cfg.irls_delta_tolerance)
                if m == 0 or not np.all(np.isfinite(delta)):
                    break
                T = kern.exp_compose(delta, T)
                last = _Solve(T, H, float(s2), int(np.count_nonzero(ok)), lv)
                H_test = H if lv == test_level else H_test
                if math.sqrt(float(delta @ delta)) < cfg.warp_tolerance:
                    break
        return None if last is None else last._replace(T=T, H_test=H_test)

    def _segment(self, cur: _Frame, prev: _Frame, T: np.ndarray, use_photo: bool, use_b: bool) -> Segmentation:
        """Per-cluster robust residuals (7)–(8) at the finest level after warping with ``T``, the larger of them and
        the long-baseline ones (``long_baseline_frames``), then (9)–(22)."""
        cfg = self.config
        # Robust mean residual (7) per cluster: occluded (8) and depth-edge pixels left out, geometric one capped.
        n_use, total, n_ok, b_sum = self._residual_sums(cur, 0, prev, T, use_b, use_photo).T
        with np.errstate(invalid="ignore", divide="ignore"):
            delta = np.where(n_use >= cfg.min_cluster_pixels, total / n_use, np.nan)
            b_prev = np.where(n_ok > 0, b_sum / n_ok, np.nan) if use_b else None
        # Long baseline: the same residuals against an older frame, where slow motions have grown past the noise.
        old = self._long_baseline(cur)
        if old is not None:
            old_frame, T_odom_old = old
            T_old_curr = se3.inverse(T_odom_old) @ self._T_odom_camera @ T
            lv = min(cfg.long_baseline_level, len(cur.levels) - 1)
            n_use, total, _, _ = self._residual_sums(cur, lv, old_frame, T_old_curr, False, use_photo).T
            with np.errstate(invalid="ignore", divide="ignore"):
                delta = np.fmax(delta, np.where(n_use >= cfg.min_cluster_pixels >> (2 * lv), total / n_use, np.nan))
        motion = float(np.linalg.norm(se3.log(T)))
        return segment_background(delta, cur.zbar, cur.graph, b_prev, motion, cur.mean_depth, cfg)

    def _residual_sums(self, cur: _Frame, level: int, tgt: _Frame, T: np.ndarray, use_b: bool, use_photo: bool
                       ) -> np.ndarray:
        """(N, 4) sums of :func:`~simnav.odometry.vosf_kernels.cluster_residuals` of the current frame's pixels at
        ``level`` warped with ``T`` (``T_tgt_curr``) into ``tgt``."""
        cfg = self.config
        ref = cur.levels[level]
        if ref.edges is None:
            ref.edges = kern.depth_edges(ref.depth, cfg.edge_threshold_m).ravel()
        return kern.cluster_residuals(ref.valid_idx, ref.labels.ravel(), ref.edges, np.nan_to_num(cur.zbar, nan=1.0),
                                      ref.x.ravel(), ref.y.ravel(), ref.pack, T, tgt.levels[level].cam,
                                      tgt.levels[level].pack, use_b, use_photo, cfg.warp_gate_m,
                                      cfg.photometric_weight, cfg.occlusion_threshold_m)

    def _long_baseline(self, cur: _Frame) -> tuple[_Frame, np.ndarray] | None:
        """The frame ``long_baseline_frames`` back and its ``T_odom_camera``; None when off, too early, or when its
        pyramid or colour differs from the current frame's."""
        n = self.config.long_baseline_frames
        if n < 2 or len(self._history) < n:
            return None
        old, _ = self._history[0]
        same = [lv.depth.shape for lv in old.levels] == [lv.depth.shape for lv in cur.levels] \
            and old.has_intensity == cur.has_intensity
        return self._history[0] if same else None

    def _background_groups(self, cur: _Frame, b: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Pixels of the static and uncertain clusters per level, each weighted by ``sqrt(1 - b)``."""
        groups, scales = [], []
        for lv in cur.levels:
            idx, scale = kern.background_pixels(lv.labels.ravel(), lv.valid_idx, b, self.config.moving_above)
            groups.append(idx)
            scales.append(scale)
        return groups, scales

    def _weak_directions(self, sol: _Solve, cur: _Frame) -> np.ndarray:
        """(6, m) unit twists (left perturbation, rotations scaled to displacements at the mean depth: multiply by
        :func:`_depth_scale` for the twist) along which the solve is degenerate; m = 0 when it is not."""
        H = _test_information(sol)
        S = _depth_scale(cur.mean_depth)
        evals, evecs = np.linalg.eigh(S @ H @ S)
        return evecs[:, ~(evals > self.config.degeneracy_threshold * max(evals[-1], 1e-300))]

    def _held(self, sol: _Solve, prior: np.ndarray, weak: np.ndarray, cur: _Frame) -> np.ndarray:
        """The solve's ``T`` moved onto the prediction ``prior`` by the translational part of the difference along
        the ``weak`` directions (with ``hold_degenerate``; DIFODO's :func:`hold_weak_translations` on the left twist
        from ``T`` to the prediction). The rotation stays measured: held too, it erred 2-2.6x as much."""
        if weak.shape[1] == 0 or not self.config.hold_degenerate:
            return sol.T
        step = hold_weak_translations(np.zeros(6), se3.log(prior @ se3.inverse(sol.T)), _test_information(sol),
                                      cur.mean_depth, self.config.degeneracy_threshold)
        return se3.exp(step) @ sol.T

    def _covariance(self, sol: _Solve, weak: np.ndarray, cur: _Frame) -> np.ndarray:
        """Covariance of ``log(T_prev_curr)`` (right perturbation, current optical frame); the ``weak`` directions
        get the variance of a lost track."""
        cfg = self.config
        H = 0.5 * (sol.H + sol.H.T)
        cov = sol.s2 * np.linalg.pinv(H)
        for v in (_depth_scale(cur.mean_depth) @ weak).T:
            cov = cov + cfg.lost_variance * np.outer(v, v) / float(v @ v)
        Ad = se3.adjoint(se3.inverse(sol.T))  # left twist (previous frame) -> right twist (current frame)
        return Ad @ cov @ Ad.T

    # -- frames --------------------------------------------------------------------------------------------------

    def _prepare(self, frame: RGBDFrame, warm: np.ndarray | None = None) -> _Frame | None:
        """Sanitised pyramid, clusters and graph of a frame (K-means from the (K, 3) ``warm`` centres, else from
        the image grid); None when it cannot be aligned (logged)."""
        cfg = self.config
        K = np.asarray(frame.K, dtype=np.float64)
        depth = np.asarray(frame.depth_m)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or depth.ndim != 2 \
                or min(depth.shape) < 2:
            self._warn_once("bad_frame", "Joint-VO-SF: frame with invalid K or depth shape; motion predicted")
            return None
        depth = depth.astype(np.float64)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(depth) & (depth >= cfg.min_depth_m) & (depth <= cfg.max_depth_m)
        depth = np.where(ok, depth, 0.0)
        intensity = self._intensity(frame, depth.shape)
        has_intensity = intensity is not None
        if intensity is None:
            intensity = np.zeros_like(depth)
        # Pyramid: halve until the width fits, then keep halving down to the coarsest processing level.
        cam = _camera(K)
        full_depth, full_cam = depth, cam
        while depth.shape[1] > cfg.max_width_px and min(depth.shape) >= 4:
            depth, intensity = kern.downsample(depth, intensity, cfg.pyramid_gate_m)
            cam = _half_camera(cam)
        raw = [(depth, intensity, cam)]
        while raw[-1][0].shape[0] // 2 >= cfg.min_level_height_px and raw[-1][0].shape[1] >= 4:
            d, i = kern.downsample(raw[-1][0], raw[-1][1], cfg.pyramid_gate_m)
            raw.append((d, i, _half_camera(raw[-1][2])))
        n_valid = int(np.count_nonzero(depth))
        if n_valid < max(cfg.min_valid_points, cfg.min_valid_fraction * depth.size):
            self._warn_once("few_pixels", "Joint-VO-SF: too few valid depths in a frame; motion predicted")
            return None
        levels = [_make_level(d, i, c, cfg.gradient_eps_m) for d, i, c in raw]
        cur = _Frame(float(frame.stamp_s), levels, has_intensity, full_depth, full_cam,
                     float(depth.ravel()[levels[0].valid_idx].mean()))
        self._cluster(cur, warm)
        return cur

    def _intensity(self, frame: RGBDFrame, shape: tuple[int, int]) -> np.ndarray | None:
        """Intensity in [0, 1] as float64, or None (logged once) without a usable colour image."""
        if not self.config.use_photometric:
            return None
        rgb = frame.rgb
        if rgb is None or np.shape(rgb) != (*shape, 3):
            self._warn_once("no_rgb", "Joint-VO-SF: frame without a colour image of the depth's size; the "
                                      "photometric term is off (geometric residuals only)")
            return None
        return np.nan_to_num(frame.intensity.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0)

    def _cluster(self, cur: _Frame, warm: np.ndarray | None = None) -> None:
        """K-means (§IV) on the points of ``kmeans_level`` (from the (K, 3) ``warm`` centres, else from the image
        grid), labels of every level, contiguity graph G."""
        cfg = self.config
        lv = cur.levels[min(cfg.kmeans_level, len(cur.levels) - 1)]
        idx = lv.valid_idx
        pts = np.stack([lv.x.ravel()[idx], lv.y.ravel()[idx], lv.depth.ravel()[idx]], axis=1)
        if warm is None:
            init = _seed_centres(lv, pts, cfg.cluster_grid_cols, cfg.cluster_grid_rows)
            centres, labels = kern.kmeans(pts, init, cfg.kmeans_max_iterations, cfg.kmeans_tolerance_m)
        else:
            centres, labels = self._warm_kmeans(pts, warm)
        lv.labels = np.full(lv.depth.shape, -1, dtype=np.int32)
        lv.labels.ravel()[idx] = labels
        for level in cur.levels:
            if level is not lv:
                level.labels = kern.assign_labels(level.x, level.y, level.depth, centres)
        cur.centres = centres
        cur.graph = kern.connectivity(lv.x, lv.y, lv.depth, lv.labels, cfg.num_clusters, cfg.connectivity_gap_m,
                                      cfg.connectivity_gap_px, float(lv.cam[0]))
        # Mean depth of every cluster at the finest level (Zbar of (7) and (15)).
        lv0 = cur.levels[0]
        count, total = kern.cluster_depths(lv0.labels.ravel(), lv0.valid_idx, lv0.depth.ravel(), cfg.num_clusters)
        cur.zbar = np.where(count > 0, total / np.maximum(count, 1), np.nan)

    def _warm_kmeans(self, pts: np.ndarray, warm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """K-means of the (n, 3) points from the predicted centres; a cluster left with fewer than
        ``min_cluster_pixels`` points (it left the view, or another took its points) is seeded again at the point
        farthest from every other centre, one after the other, and K-means runs once more."""
        cfg = self.config
        centres, labels = kern.kmeans(pts, np.ascontiguousarray(warm), cfg.kmeans_max_iterations,
                                      cfg.kmeans_tolerance_m)
        counts = np.bincount(labels, minlength=len(centres))
        sparse = np.flatnonzero(counts < cfg.min_cluster_pixels)
        if len(sparse) == 0 or len(pts) <= len(centres):
            return centres, labels
        others = np.ascontiguousarray(np.delete(centres, sparse, axis=0))
        centres[sparse] = kern.farthest_points(pts, others, len(sparse))
        return kern.kmeans(pts, centres, cfg.kmeans_max_iterations, cfg.kmeans_tolerance_m)

    def _predicted_centres(self, prior: np.ndarray) -> np.ndarray | None:
        """The previous frame's K-means centres in the current optical frame under the predicted camera motion
        ``prior`` (``T_prev_curr``), for the warm start; None without them (first frame, a frame that could not be
        prepared) or with ``kmeans_warm_start`` off."""
        prev = self._prev
        if not self.config.kmeans_warm_start or prev is None or len(prev.centres) != self.config.num_clusters:
            return None
        return se3.transform_points(se3.inverse(prior), prev.centres)

    # -- outputs -------------------------------------------------------------------------------------------------

    def _extras(self, frame: RGBDFrame, cur: _Frame | None, est: dict | None, dt_s: float) -> dict:
        """Scene flow, labels and segmentation at the input resolution (see the module docs); ``dt_s`` is the
        frame interval, s."""
        k = self.config.num_clusters
        shape = np.shape(frame.depth_m)[:2] if np.ndim(frame.depth_m) == 2 else (0, 0)
        if cur is None:
            return {"scene_flow_m": np.full((3, *shape), np.nan, dtype=np.float32),
                    "labels": np.full(shape, -1, dtype=np.int32), "background_probability": np.ones(k),
                    "moving_probability": np.zeros(k), "moving_mask": np.zeros(shape, dtype=bool),
                    "moving_clusters": np.zeros(k, dtype=bool), "cluster_motions": np.tile(np.eye(4), (k, 1, 1)),
                    "T_prev_curr_robust": np.eye(4),
                    "cluster_residuals": np.full(k, np.nan), "measured": False}
        lv0 = cur.levels[0]
        if cur.full_depth.shape == lv0.depth.shape:
            x, y, z, labels = lv0.x, lv0.y, lv0.depth, lv0.labels
        else:
            x, y = _points(cur.full_depth, cur.full_cam)
            z = cur.full_depth
            labels = kern.assign_labels(x, y, z, cur.centres)
        b, motions, T_R, residuals = np.zeros(k), np.tile(np.eye(4), (k, 1, 1)), np.eye(4), np.full(k, np.nan)
        flow = np.full((3, *z.shape), np.nan, dtype=np.float32)
        if est is not None:
            b, T_R, residuals = est["seg"].b, est["T_R"], est["seg"].residuals
        if est is not None and est["motions"] is not None:
            cfg, motions = self.config, est["motions"]
            flow = kern.scene_flow(x, y, z, labels, np.ascontiguousarray(motions), cur.centres, cur.graph,
                                   cfg.soft_label_sharpness_per_m, cfg.soft_label_cutoff)
        flags = moving_clusters(b, cur.centres, motions, dt_s, self.config) if est is not None else np.zeros(k, bool)
        moving = (labels >= 0) & flags[np.maximum(labels, 0)]
        return {"scene_flow_m": flow, "labels": labels, "background_probability": 1.0 - b, "moving_probability": b,
                "moving_mask": moving, "moving_clusters": flags, "cluster_motions": motions,
                "T_prev_curr_robust": T_R,
                "cluster_residuals": residuals, "measured": est is not None}

    # -- helpers -------------------------------------------------------------------------------------------------

    def _prior(self, dt: float) -> np.ndarray:
        """Constant-velocity prediction of ``T_prev_curr`` over ``dt`` (identity without history)."""
        if not self._predicting():
            return np.eye(4)
        scale = dt / self._dt_last if dt > 0 and self._dt_last > 0 else 1.0
        return se3.exp(self._xi_last * scale)

    def _predicting(self) -> bool:
        """Whether :meth:`_prior` predicts a motion (else it is the identity)."""
        return self.config.constant_velocity_prior and self._xi_last is not None

    def _buffers(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Views of length n of the reused outputs of :func:`~simnav.odometry.vosf_kernels.linearize`
        (residuals, Jacobians, ok flags): fresh multi-megabyte arrays per call cost page faults. Residuals and
        Jacobians are stored in float32 (computed and summed in float64): every IRLS iteration reads them twice,
        and at QVGA half the bytes made IRLS 0.5-0.75x as long, the solution moving by about 1e-8 of itself."""
        if self._work is None or len(self._work[2]) < n:
            self._work = (np.empty(2 * n, dtype=np.float32), np.empty(12 * n, dtype=np.float32),
                          np.empty(n, dtype=np.bool_))
        r, J, ok = self._work
        return r[:2 * n].reshape(2, n), J[:12 * n].reshape(2, 6, n), ok[:n]

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning(message)


def _seed_centres(lv: _Level, pts: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """(cols * rows, 3) initial K-means centres: the centre pixel of each image-grid cell back-projected at the
    cell's median valid depth; cells without depth take the valid point farthest from the centres so far."""
    h, w = lv.depth.shape
    ue = np.linspace(0, w, cols + 1).astype(np.int64)
    ve = np.linspace(0, h, rows + 1).astype(np.int64)
    fx, fy, cx, cy = lv.cam
    medians = kern.cell_medians(lv.depth, ue, ve)
    centres, missing = [], 0
    for r in range(rows):
        for c in range(cols):
            z = float(medians[r * cols + c])
            if math.isnan(z):
                missing += 1
                continue
            u, v = 0.5 * (ue[c] + ue[c + 1] - 1), 0.5 * (ve[r] + ve[r + 1] - 1)
            centres.append(((u - cx) / fx * z, (v - cy) / fy * z, z))
    out = np.array(centres, dtype=np.float64).reshape(-1, 3)
    if missing and len(out) == 0:
        out, missing = pts[:1].copy(), missing - 1
    return np.ascontiguousarray(np.vstack([out, kern.farthest_points(pts, np.ascontiguousarray(out), missing)]))


_NO_SCALE = np.zeros(0)  # no per-pixel factor in kern.linearize


def _depth_scale(z_m: float) -> np.ndarray:
    """(6, 6) ``diag(1, 1, 1, 1/z, 1/z, 1/z)``: twists with rotations as displacements at depth z (m)."""
    return np.diag([1.0, 1.0, 1.0, 1.0 / z_m, 1.0 / z_m, 1.0 / z_m])


def _test_information(sol: _Solve) -> np.ndarray:
    """(6, 6) information the degeneracy test reads: the solve's at the test level, else its last one's."""
    H = sol.H_test if sol.H_test is not None else sol.H
    return 0.5 * (H + H.T)


def _nearest_level(frame: _Frame, width_px: int) -> int:
    """Index of the pyramid level of ``frame`` whose width is closest to ``width_px`` (the finer one on a tie)."""
    return int(np.argmin([abs(lv.depth.shape[1] - width_px) for lv in frame.levels]))


def _mount(T: np.ndarray) -> np.ndarray:
    """The camera mount as a finite (4, 4) pose (identity if it is not one)."""
    T = np.asarray(T, dtype=np.float64)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else np.eye(4)


def _finite(a: np.ndarray) -> np.ndarray:
    """``a`` with any non-finite entry replaced by 0 (a last guard)."""
    return np.where(np.isfinite(a), a, 0.0)
