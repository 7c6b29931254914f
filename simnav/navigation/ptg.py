"""Parameterized Trajectory Generators (PTGs) of a differential-drive robot (thesis §6.C; MRPT's grid-based PTGs).

A PTG is a family of ``N`` paths that all start at the origin of the base frame (x forward, y left, metres) with
heading 0. Path ``k`` is selected by ``alpha_k = pi * (-1 + 2 (k + 1/2) / N)`` (cell-centred in (-pi, pi), no path
at exactly +-pi). Each path is the unicycle ``x' = v cos(phi)``, ``y' = v sin(phi)``, ``phi' = w`` driven by the
family's steering function ``(alpha, t, pose) -> (v, w)``, integrated numerically (constant-twist steps, exact for
piecewise-constant commands) and stored as samples, as MRPT's ``CPTG_DiffDrive_CollisionGridBased`` does.

Distance along a path is measured in *pseudo-metres*: ``dd = sqrt(v^2 + (w r_ref)^2) dt`` with ``r_ref`` =
``turning_radius_ref_m``, so turning in place costs distance too. TP-space distances are normalised by
``ref_distance_m``: 1.0 is the horizon. A path ends at ``d = ref_distance_m``, after turning ``max_turn_rad`` in
total or at ``max_time_s``, whichever comes first.

Families (``K = -1`` when ``backward``; ``V = v_max_mps``, ``W = w_max_radps``, ``R = V / W``):

* ``"C"`` circular arcs: ``v = K V``, ``w = K (alpha / pi) W``; radius ``R pi / |alpha|`` (alpha = 0: straight).
* ``"alpha"`` asymptotic heading (MRPT's α-A): ``D = wrap(alpha - K phi)``, ``v = K V exp(-(D / c_v)^2)``,
  ``w = K W (sigmoid(D / c_w) - 1/2)``; the heading converges to alpha, ``|w| <= W / 2``.
* ``"CS"`` arc then straight: for ``t < 0.847 sqrt(|alpha|) R / V``: ``v = V``, ``w = sgn(alpha) W min(1,
  1 - exp(-alpha^2))``; then ``(V, 0)``; both times K.
* ``"CCS"`` (lower confidence, as in MRPT): ``u = |alpha| / 2``; reverse arc ``(-V, W)`` for ``t < u R / V``,
  forward arc ``(V, W)`` until ``(u + pi / 2) R / V``, then straight ``(V, 0)``; ``w`` negated for alpha < 0;
  all times K.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from simnav.errors import ConfigError
from simnav.geometry.se2 import wrap_angle

log = logging.getLogger(__name__)

PTG_FAMILIES = ("C", "alpha", "CS", "CCS")
"""Path families: circular arcs, asymptotic heading, arc + straight, reverse arc + arc + straight."""

_NEAREST_SAMPLES = 4  # candidate samples per point in the inverse map
_CONTINUATION_STRIDE = 4  # samples considered by the inverse map's continuation (besides path ends)
_T_EPS_S = 1e-9  # phase switches are decided at t + eps so a step that lands on a switch time starts the next phase


def index_to_alpha(k: ArrayLike, num_paths: int) -> np.ndarray | float:
    """Path parameter of path index ``k``: ``alpha_k = pi (-1 + 2 (k + 0.5) / N)``.

    Args:
        k: scalar or array of path indices in [0, N).
        num_paths: N.

    Returns:
        alpha, rad, in (-pi, pi); a float for scalar input.
    """
    a = np.pi * (-1.0 + 2.0 * (np.asarray(k, dtype=np.float64) + 0.5) / num_paths)
    return float(a) if a.ndim == 0 else a


def alpha_to_index(alpha_rad: ArrayLike, num_paths: int) -> np.ndarray | int:
    """Index of the path closest to ``alpha`` (wrapped to (-pi, pi] first), clamped to [0, N - 1].

    Args:
        alpha_rad: scalar or array of angles, rad.
        num_paths: N.

    Returns:
        Path index (int for scalar input, int64 array otherwise).
    """
    a = np.asarray(wrap_angle(alpha_rad), dtype=np.float64)
    k = np.clip(np.round(0.5 * (num_paths * (1.0 + a / np.pi) - 1.0)), 0, num_paths - 1).astype(np.int64)
    return int(k) if k.ndim == 0 else k


@dataclass(frozen=True)
class PTGConfig:
    """One PTG: family, discretisation and kinematic limits.

    Attributes:
        family: one of :data:`PTG_FAMILIES`.
        backward: drive the family backwards (MRPT's ``K = -1``); meant as a lower-priority escape PTG.
        num_paths: N, number of paths (alpha values).
        ref_distance_m: horizon; TP distances are normalised by it (pseudo-metres).
        v_max_mps: robot's top linear speed, m/s (defaults = simnav's default drive, :class:`simnav.robot.spec.Drive`).
        w_max_radps: robot's top angular speed, rad/s.
        turning_radius_ref_m: ``r_ref`` of the pseudo-metre metric, m.
        alpha_cte_v_rad: ``c_v`` of the ``"alpha"`` family, rad (MRPT ``cte_a0v_deg``, default 45°).
        alpha_cte_w_rad: ``c_w`` of the ``"alpha"`` family, rad (MRPT ``cte_a0w_deg``, default 45°).
        score_priority: the navigator's preference for this PTG (MRPT ``score_priority``); not used by the paths.
        max_time_s: a path ends at this time, s.
        max_turn_rad: a path ends once its accumulated |rotation| reaches this, rad.
        dt_s: integration step, s (switch times and the end of a path are hit exactly).
        sample_step_m: a sample is stored once the robot has moved this far since the last one, m.
        sample_step_rad: ... or rotated this much, rad.
    """

    family: str = "C"
    backward: bool = False
    num_paths: int = 121
    ref_distance_m: float = 5.0
    v_max_mps: float = 0.6
    w_max_radps: float = math.radians(90.0)
    turning_radius_ref_m: float = 0.10
    alpha_cte_v_rad: float = math.radians(45.0)
    alpha_cte_w_rad: float = math.radians(45.0)
    score_priority: float = 1.0
    max_time_s: float = 100.0
    max_turn_rad: float = 1.95 * math.pi
    dt_s: float = 0.005
    sample_step_m: float = 0.015
    sample_step_rad: float = 0.015

    def __post_init__(self) -> None:
        if self.family not in PTG_FAMILIES:
            raise ConfigError(f"PTG family must be one of {PTG_FAMILIES}, got {self.family!r}")
        if self.num_paths < 2:
            raise ConfigError(f"num_paths must be >= 2, got {self.num_paths}")
        for name in ("ref_distance_m", "v_max_mps", "w_max_radps", "alpha_cte_v_rad", "alpha_cte_w_rad",
                     "max_time_s", "max_turn_rad", "dt_s", "sample_step_m", "sample_step_rad"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"PTG {name} must be > 0, got {getattr(self, name)}")
        if self.turning_radius_ref_m < 0:
            raise ConfigError(f"turning_radius_ref_m must be >= 0, got {self.turning_radius_ref_m}")

    @property
    def name(self) -> str:
        """Short description, e.g. ``"C"`` or ``"C-back"``."""
        return self.family + ("-back" if self.backward else "")

    def path_parameters(self) -> dict:
        """Every field that changes the paths (all but ``score_priority``), for cache keys."""
        params = asdict(self)
        params.pop("score_priority")
        return params


@dataclass(frozen=True)
class TPPoint:
    """A workspace point mapped into TP-space by :meth:`PTG.inverse_map_ws2tp`.

    Attributes:
        k: path index.
        alpha_rad: path parameter of ``k``, rad.
        d_norm: normalised distance along path ``k`` (> 1 beyond the horizon).
        exact: True when path ``k`` passes within the tolerance of the point at ``d_norm``; False for a best
            approximation (outside the PTG's domain, or beyond the horizon): path k, then a turn and a straight
            continuation, ``d_norm`` being the length of it all.
        error_m: distance from the point to path ``k`` (exact), or the length of the straight continuation, m.
    """

    k: int
    alpha_rad: float
    d_norm: float
    exact: bool
    error_m: float


class PTG:
    """The sampled paths of one PTG, their motion commands, and the inverse map workspace -> TP-space.

    Attributes (N paths, S = most samples of any path; rows are padded with their last sample):
        config: the :class:`PTGConfig`.
        alphas_rad: (N,) path parameters, rad.
        num_samples: (N,) samples stored per path (>= 2).
        poses: (N, S, 3) sampled poses ``(x_m, y_m, phi_rad)`` in the base frame at the start of the path;
            ``phi`` is continuous along a path (not wrapped).
        dist_m: (N, S) pseudo-metre distance of each sample, increasing from 0.
        time_s: (N, S) time of each sample, s.
        vw: (N, S, 2) command ``(v_mps, w_radps)`` applied from each sample on.
        commands: (N, 2) initial command ``(v_mps, w_radps)`` of each path (what the robot is sent).
    """

    def __init__(self, config: PTGConfig | None = None, **overrides) -> None:
        """Integrates the N paths.

        Args:
            config: the PTG; None = defaults.
            **overrides: fields of :class:`PTGConfig` replacing those of ``config``.
        """
        base = config or PTGConfig()
        self.config = PTGConfig(**{**asdict(base), **overrides}) if overrides else base
        t0 = time.perf_counter()
        self.alphas_rad = np.asarray(index_to_alpha(np.arange(self.config.num_paths), self.config.num_paths))
        self.poses, self.dist_m, self.time_s, self.num_samples = _simulate(self.config, self.alphas_rad)
        S = self.poses.shape[1]
        alpha_rep = np.broadcast_to(self.alphas_rad[:, None], (self.num_paths, S))
        v, w = _steer(self.config, alpha_rep, self.time_s, self.poses[..., 2])
        self.vw = np.stack([v, w], axis=-1)
        self.commands = self.vw[:, 0, :].copy()
        for a in (self.poses, self.dist_m, self.time_s, self.num_samples, self.vw, self.commands, self.alphas_rad):
            a.flags.writeable = False
        log.debug("PTG %s: %d paths, up to %d samples, integrated in %.3f s", self.config.name, self.num_paths, S,
                  time.perf_counter() - t0)

    def __repr__(self) -> str:
        c = self.config
        return (f"PTG({c.name}, N={c.num_paths}, ref={c.ref_distance_m} m, v={c.v_max_mps} m/s, "
                f"w={c.w_max_radps:.3f} rad/s)")

    @property
    def num_paths(self) -> int:
        """N."""
        return self.config.num_paths

    @property
    def ref_distance_m(self) -> float:
        """The normalisation distance (horizon), pseudo-metres."""
        return self.config.ref_distance_m

    @property
    def path_end_norm(self) -> np.ndarray:
        """(N,) normalised distance at the end of each path (< 1 for paths stopped by the turn or time limit)."""
        return self.dist_m[np.arange(self.num_paths), self.num_samples - 1] / self.ref_distance_m

    def index_to_alpha(self, k: ArrayLike) -> np.ndarray | float:
        """Path parameter of path ``k``, rad (see :func:`index_to_alpha`)."""
        return index_to_alpha(k, self.num_paths)

    def alpha_to_index(self, alpha_rad: ArrayLike) -> np.ndarray | int:
        """Closest path index to ``alpha_rad`` (see :func:`alpha_to_index`)."""
        return alpha_to_index(alpha_rad, self.num_paths)

    def direction_to_motion_command(self, k: int) -> tuple[float, float]:
        """Initial command of path ``k`` (MRPT ``directionToMotionCommand``).

        Returns:
            ``(v_mps, w_radps)``; within ``(v_max_mps, w_max_radps)``. The navigator scales both by its speed factor.
        """
        v, w = self.commands[int(k)]
        return float(v), float(w)

    def step_for_distance(self, k: int, d_m: float) -> int:
        """Index of the last sample of path ``k`` whose distance is <= ``d_m`` (the last sample if beyond)."""
        n = int(np.searchsorted(self.dist_m[k, : self.num_samples[k]], d_m, side="right")) - 1
        return min(max(n, 0), int(self.num_samples[k]) - 1)

    def pose_at(self, k: int, d_norm: float) -> np.ndarray:
        """Pose on path ``k`` at normalised distance ``d_norm`` (linear between samples, clamped at the ends).

        Returns:
            (3,) ``(x_m, y_m, phi_rad)`` in the base frame.
        """
        n_k = int(self.num_samples[k])
        d = self.dist_m[k, :n_k]
        q = float(d_norm) * self.ref_distance_m
        return np.array([np.interp(q, d, self.poses[k, :n_k, i]) for i in range(3)])

    @cached_property
    def _tree(self) -> tuple[cKDTree, np.ndarray, np.ndarray]:
        """KD-tree over the positions of every stored sample, with each one's (k, n)."""
        k_idx, n_idx = np.nonzero(np.arange(self.poses.shape[1])[None, :] < self.num_samples[:, None])
        return cKDTree(self.poses[k_idx, n_idx, :2]), k_idx, n_idx

    def inverse_map_ws2tp_many(self, xy_m: ArrayLike, tolerance_m: float = 0.10
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Maps workspace points (base frame) to TP-space; every point gets an answer.

        A point within ``tolerance_m`` of some path maps to the closest point of the closest path (``exact``).
        Any other point (outside the PTG's domain, or beyond the horizon) maps to the cheapest continuation: drive
        path k up to sample n, turn towards the point, then drive straight to it (backwards for backward motion),
        costed as ``d_n + max(r_ref, V / W) |turn| + |p - p_n|``, i.e. the turn costs the arc of the tightest
        turn; ``d_norm`` is that cost over ``ref_distance_m`` (> 1 beyond the horizon) and ``exact`` is False. Far
        targets thus map to the shortest "turn, then straight" path towards them.

        Args:
            xy_m: (P, 2) points in the base frame, m.
            tolerance_m: largest distance between a point and its path for an exact mapping, m.

        Returns:
            ``(k (P,) int64, d_norm (P,), exact (P,) bool, error_m (P,))``; ``error_m`` is the distance from the
            point to the path (exact) or the length of the straight continuation (not exact), m.
        """
        p = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        tree, k_all, n_all = self._tree
        _, flat = tree.query(p, k=_NEAREST_SAMPLES)  # (P, 4): samples of neighbouring paths can be the nearest
        cand_d, cand_e = self._refine_on_segments(np.repeat(p, flat.shape[1], axis=0), k_all[flat.ravel()],
                                                  n_all[flat.ravel()])
        best = np.argmin(cand_e.reshape(flat.shape), axis=1)
        pick = np.arange(len(p)) * flat.shape[1] + best
        k, d_m, err = k_all[flat.ravel()][pick], cand_d[pick], cand_e[pick]
        exact = err <= tolerance_m
        if not exact.all():
            k[~exact], d_m[~exact], err[~exact] = self.continuation(p[~exact])
        return k.astype(np.int64), d_m / self.ref_distance_m, exact, err

    def inverse_map_ws2tp(self, x_m: float, y_m: float, tolerance_m: float = 0.10) -> TPPoint:
        """Maps one workspace point (base frame) to TP-space; see :meth:`inverse_map_ws2tp_many`."""
        k, d, exact, err = self.inverse_map_ws2tp_many([[x_m, y_m]], tolerance_m)
        return TPPoint(int(k[0]), float(self.alphas_rad[k[0]]), float(d[0]), bool(exact[0]), float(err[0]))

    @cached_property
    def _continuation_samples(self) -> tuple[np.ndarray, ...]:
        """Flat (k, x, y, motion heading, d) of every 4th sample (n >= 1) and each path's last sample, in order of
        increasing d (the continuation's search stops at the first sample farther along than the best cost)."""
        N, S = self.dist_m.shape
        n = np.arange(S)[None]
        last = (self.num_samples - 1)[:, None]
        k_idx, n_idx = np.nonzero((n >= 1) & (n <= last) & (((n - 1) % _CONTINUATION_STRIDE == 0) | (n == last)))
        order = np.argsort(self.dist_m[k_idx, n_idx], kind="stable")
        k_idx, n_idx = k_idx[order], n_idx[order]
        heading = self.poses[k_idx, n_idx, 2] + np.where(self.vw[k_idx, n_idx, 0] < 0, np.pi, 0.0)
        return (k_idx, np.ascontiguousarray(self.poses[k_idx, n_idx, 0]),
                np.ascontiguousarray(self.poses[k_idx, n_idx, 1]), heading, self.dist_m[k_idx, n_idx])

    @property
    def _turn_cost_m_per_rad(self) -> float:
        """Cost of turning in the continuation: the arc length per radian of the tightest turn, ``V / W``."""
        return max(self.config.turning_radius_ref_m, self.config.v_max_mps / self.config.w_max_radps)

    def continuation(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cheapest "path k to sample n, turn in place, straight" continuation to each point (n >= 1): how a point off
        every path is mapped (by :meth:`inverse_map_ws2tp_many` and
        :meth:`~simnav.navigation.ptgspace.PTGSpace.inverse_map_many`).

        Args:
            p: (F, 2) points in the base frame, m.

        Returns:
            ``(k (F,), cost_m (F,), straight_m (F,))``.
        """
        k_idx, x, y, heading, d = self._continuation_samples
        q = np.ascontiguousarray(np.asarray(p, dtype=np.float64).reshape(-1, 2))
        best = np.empty(len(q), dtype=np.int64)
        cost, gap = np.empty(len(q)), np.empty(len(q))
        _continuation_kernel(q, x, y, heading, d, self._turn_cost_m_per_rad, best, cost, gap)
        return k_idx[best], cost, gap

    def _refine_on_segments(self, p: np.ndarray, k: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projects each point onto the two path segments around its nearest sample.

        Returns:
            ``(d_m (P,), error_m (P,))``: distance along the path of the projection, and the point's distance to it.
        """
        last = self.num_samples[k] - 1
        best_d = self.dist_m[k, n].copy()
        best_e = np.linalg.norm(p - self.poses[k, n, :2], axis=1)
        for a, b in ((np.maximum(n - 1, 0), n), (n, np.minimum(n + 1, last))):
            pa, pb = self.poses[k, a, :2], self.poses[k, b, :2]
            seg = pb - pa
            L2 = np.einsum("ij,ij->i", seg, seg)
            s = np.clip(np.einsum("ij,ij->i", p - pa, seg) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
            e = np.linalg.norm(p - (pa + s[:, None] * seg), axis=1)
            d = self.dist_m[k, a] + s * (self.dist_m[k, b] - self.dist_m[k, a])
            better = e < best_e
            best_d[better], best_e[better] = d[better], e[better]
        return best_d, best_e


def _steer(cfg: PTGConfig, alpha: np.ndarray, t: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steering function of the family: ``(v_mps, w_radps)`` for arrays of alpha, time and heading (same shape)."""
    V, W = cfg.v_max_mps, cfg.w_max_radps
    K = -1.0 if cfg.backward else 1.0
    te = t + _T_EPS_S
    if cfg.family == "C":
        v, w = np.full_like(alpha, V), alpha / np.pi * W
    elif cfg.family == "alpha":
        delta = np.asarray(wrap_angle(alpha - K * phi))
        v = V * np.exp(-((delta / cfg.alpha_cte_v_rad) ** 2))
        w = W * (1.0 / (1.0 + np.exp(-delta / cfg.alpha_cte_w_rad)) - 0.5)
    elif cfg.family == "CS":
        turning = te < _switch_times(cfg, alpha)[0]
        v = np.full_like(alpha, V)
        w = np.where(turning, np.sign(alpha) * W * np.minimum(1.0, 1.0 - np.exp(-(alpha**2))), 0.0)
    else:  # CCS
        t1, t2 = _switch_times(cfg, alpha)
        v = np.where(te < t1, -V, V)
        w = np.where(te < t2, W, 0.0) * np.where(alpha < 0, -1.0, 1.0)
    return K * v, K * w


def _switch_times(cfg: PTGConfig, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times at which the command of a piecewise family changes, s (inf where it does not)."""
    R_over_V = 1.0 / cfg.w_max_radps  # R / V with R = V / W
    if cfg.family == "CS":
        t1 = 0.847 * np.sqrt(np.abs(alpha)) * R_over_V
        return t1, np.full_like(alpha, np.inf)
    if cfg.family == "CCS":
        u = 0.5 * np.abs(alpha)
        return u * R_over_V, (u + 0.5 * np.pi) * R_over_V
    inf = np.full_like(alpha, np.inf)
    return inf, inf


def _simulate(cfg: PTGConfig, alphas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Integrates all paths at once and keeps a sample whenever a path moved or turned enough, or ended.

    Returns:
        ``poses (N, S, 3), dist_m (N, S), time_s (N, S), num_samples (N,)``, rows padded with their last sample.
    """
    N = len(alphas)
    ref, r_ref = cfg.ref_distance_m, cfg.turning_radius_ref_m
    x, y, phi, t, d, turned = (np.zeros(N) for _ in range(6))
    cap = 256
    buf = np.zeros((N, cap, 5))  # x, y, phi, t, d; sample 0 = origin
    count = np.ones(N, dtype=np.int64)
    last = np.zeros((N, 3))
    active = np.ones(N, dtype=bool)
    switches = np.stack(_switch_times(cfg, alphas), axis=1)  # (N, 2)
    piecewise = cfg.family in ("C", "CS", "CCS")  # piecewise-constant commands, integrated exactly
    max_steps = int(10 * cfg.max_time_s / cfg.dt_s) + 10
    for _ in range(max_steps):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        a = alphas[idx]
        v, w = _steer(cfg, a, t[idx], phi[idx])
        rate = np.sqrt(v**2 + (w * r_ref) ** 2)
        av, aw = np.maximum(np.abs(v), 1e-300), np.maximum(np.abs(w), 1e-300)
        if piecewise:  # exact arcs: one step per sample (until the next switch), dt is not needed
            h = np.minimum(cfg.sample_step_m / av, cfg.sample_step_rad / aw)
        else:
            h = np.full(idx.size, cfg.dt_s)
        # land exactly on the horizon, the turn limit and the time limit
        h = np.minimum(h, (ref - d[idx]) / np.maximum(rate, 1e-300))
        h = np.minimum(h, (cfg.max_turn_rad - np.abs(turned[idx])) / aw)
        h = np.minimum(h, cfg.max_time_s - t[idx])
        sw = switches[idx]
        nxt = np.min(np.where(sw > t[idx, None] + _T_EPS_S, sw, np.inf), axis=1)
        h = np.maximum(np.minimum(h, nxt - t[idx]), 0.0)
        dphi = w * h
        half = 0.5 * dphi
        chord = v * h * np.sinc(half / np.pi)  # exact arc for a constant twist
        heading = phi[idx] + half
        x[idx] += chord * np.cos(heading)
        y[idx] += chord * np.sin(heading)
        phi[idx] += dphi
        turned[idx] += dphi
        t[idx] += h
        d[idx] += rate * h
        ended = ((d[idx] >= ref * (1 - 1e-12)) | (np.abs(turned[idx]) >= cfg.max_turn_rad * (1 - 1e-12))
                 | (t[idx] >= cfg.max_time_s * (1 - 1e-12)) | (rate == 0))
        tol = 1.0 - 1e-9
        moved = np.hypot(x[idx] - last[idx, 0], y[idx] - last[idx, 1]) >= cfg.sample_step_m * tol
        rotated = np.abs(phi[idx] - last[idx, 2]) >= cfg.sample_step_rad * tol
        rec = idx[ended | moved | rotated] if not piecewise else idx
        if rec.size:
            if count[rec].max() >= cap:
                buf = np.concatenate([buf, np.zeros((N, cap, 5))], axis=1)
                cap *= 2
            buf[rec, count[rec]] = np.stack([x[rec], y[rec], phi[rec], t[rec], d[rec]], axis=1)
            count[rec] += 1
            last[rec] = np.stack([x[rec], y[rec], phi[rec]], axis=1)
        active[idx[ended]] = False
    S = int(count.max())
    buf = buf[:, :S]
    pad = np.arange(S)[None, :] >= count[:, None]
    buf[pad] = np.repeat(buf[np.arange(N), count - 1][:, None, :], S, axis=1)[pad]
    return buf[..., :3].copy(), buf[..., 4].copy(), buf[..., 3].copy(), count


@njit(cache=True, error_model="numpy")
def _continuation_kernel(p: np.ndarray, x: np.ndarray, y: np.ndarray, heading: np.ndarray, d: np.ndarray,
                         turn_cost_m_per_rad: float, best: np.ndarray, cost: np.ndarray, gap: np.ndarray) -> None:
    """For each point of p (F, 2), the sample j minimising ``d_j + turn_cost·|turn_j| + gap_j`` into (best, cost,
    gap); samples come in order of increasing d_j, so the search stops once d_j alone reaches the best cost, and
    skips the angle wherever ``d_j + gap_j`` does (the first sample wins ties)."""
    for i in range(p.shape[0]):
        px, py = p[i, 0], p[i, 1]
        best_j, best_cost, best_gap = 0, math.inf, 0.0
        for j in range(d.shape[0]):
            if d[j] >= best_cost:
                break
            dx, dy = px - x[j], py - y[j]
            g = math.sqrt(dx * dx + dy * dy)
            if d[j] + g >= best_cost:
                continue
            turn = math.atan2(dy, dx) - heading[j]
            turn = abs(turn - 2.0 * math.pi * math.floor((turn + math.pi) / (2.0 * math.pi)))
            c = d[j] + turn_cost_m_per_rad * turn + g
            if c < best_cost:
                best_j, best_cost, best_gap = j, c, g
        best[i], cost[i], gap[i] = best_j, best_cost, best_gap
