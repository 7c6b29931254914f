"""Holonomic methods run in TP-space: Nearness Diagram (ND, the default) and Virtual Force Field (VFF) (thesis §6.C.3).

A PTG makes the robot a free-flying point of TP-space: the direction α picks one path of the family and the
distance d says how far along it. For every PTG the reactive navigator hands a holonomic method the TP-obstacles
(the free normalised distance along each of the N discretised paths, 1 = free up to the horizon) and the target's
TP coordinates; the method returns the path to take and a speed in [0, 1] (fraction of the PTG's top speed). Both
methods follow MRPT's ``CHolonomicND`` / ``CHolonomicVFF`` (notes §1.3); the deviations are listed at the class.

Direction grid (cell-centred, MRPT's ``index2alpha`` / ``alpha2index``): path k = 0..N-1 has
``α_k = -π + (k + 0.5)·2π/N``; k = 0 lies just above -π, k = N-1 just below +π, and for odd N the middle path
k = (N-1)/2 has α = 0 exactly. An angle maps back to ``k = round(½(N(1 + α/π) - 1))`` (half away from zero)
after wrapping α to (-π, π], clamped to [0, N-1]. ND's gap search runs along the array (a valley that wraps
across ±π is seen as two), as MRPT's does.

The methods import only numpy and know nothing about PTGs: all inputs are plain arrays and numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from simnav.errors import ConfigError, UnknownNameError

__all__ = [
    "METHODS",
    "Gap",
    "HolonomicInput",
    "HolonomicMethod",
    "HolonomicND",
    "HolonomicOutput",
    "HolonomicVFF",
    "NDConfig",
    "NDInfo",
    "NDSituation",
    "VFFConfig",
    "VFFInfo",
    "alpha_to_index",
    "index_to_alpha",
    "make_holonomic",
    "wrap_to_pi",
]


# ----------------------------------------------------------------------------------------------------------------
# Direction grid
# ----------------------------------------------------------------------------------------------------------------


def wrap_to_pi(alpha_rad: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) wrapped to (-π, π] (MRPT's ``wrapToPi``: -π maps to +π)."""
    wrapped = alpha_rad - 2.0 * np.pi * np.ceil((np.asarray(alpha_rad) - np.pi) / (2.0 * np.pi))
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def index_to_alpha(k: int | np.ndarray, num_paths: int) -> float | np.ndarray:
    """Direction of path(s) ``k``: ``α_k = -π + (k + 0.5)·2π/N``, rad.

    Computed as ``π·(2k + 1 - N)/N`` so that mirrored paths k and N-1-k get exactly opposite angles (symmetric
    scenes give exactly tied scores).
    """
    alpha = np.pi * (2 * np.asarray(k) + 1 - num_paths) / num_paths
    return float(alpha) if np.ndim(alpha) == 0 else alpha


def alpha_to_index(alpha_rad: float | np.ndarray, num_paths: int) -> int | np.ndarray:
    """Path index nearest to direction(s) ``alpha_rad`` (any angle; wrapped to (-π, π] first), in [0, N-1]."""
    x = 0.5 * (num_paths * (1.0 + np.asarray(wrap_to_pi(alpha_rad)) / np.pi) - 1.0)
    k = np.clip(np.floor(x + 0.5), 0, num_paths - 1).astype(int)  # C round(): halves away from zero (x >= -0.5)
    return int(k) if k.ndim == 0 else k


def _c_round(x: float) -> int:
    """C's ``round`` for x >= 0 (halves go up), unlike Python's banker's rounding."""
    return math.floor(x + 0.5)


# ----------------------------------------------------------------------------------------------------------------
# Common interface
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HolonomicInput:
    """One TP-space of one navigation step.

    Attributes:
        obstacles: (N,) TP-obstacles, the free normalised distance along each path k (index 0 = -π), >= 0;
            1 = free up to the horizon (``refDistance``). N >= 3. Stored as a read-only float64 copy.
        target_alpha_rad: TP direction of the target, rad (any angle; wrapped).
        target_dist: normalised TP distance of the target, >= 0 (may exceed 1 beyond the horizon).
        max_obstacle_dist: largest TP-obstacle value, the "free" level (MRPT passes 1).
        max_robot_speed: speed returned on a free way; the output speed is a fraction of it (MRPT passes 1).
        ref_distance_m: the PTG's ``refDistance``, m; converts ``target_slow_approaching_distance_m`` into TP units.
            1 (the default) reads that distance as TP units, as MRPT does for a method with no PTG attached.
        slow_down_near_target: slow down within the target slow-approaching distance. The navigator enables it
            only when the robot should stop at the target (MRPT: desired target speed < 0.11), not for
            pass-through waypoints.
    """

    obstacles: np.ndarray
    target_alpha_rad: float
    target_dist: float
    max_obstacle_dist: float = 1.0
    max_robot_speed: float = 1.0
    ref_distance_m: float = 1.0
    slow_down_near_target: bool = True

    def __post_init__(self) -> None:
        obs = np.array(self.obstacles, dtype=float)
        if obs.ndim != 1 or obs.size < 3:
            raise ValueError(f"obstacles must have shape (N,) with N >= 3, got {obs.shape}")
        if not (np.isfinite(obs).all() and (obs >= 0).all()):
            raise ValueError("obstacles must be finite and >= 0")
        obs.flags.writeable = False
        object.__setattr__(self, "obstacles", obs)
        if not math.isfinite(self.target_alpha_rad):
            raise ValueError(f"target_alpha_rad must be finite, got {self.target_alpha_rad}")
        if not (math.isfinite(self.target_dist) and self.target_dist >= 0):
            raise ValueError(f"target_dist must be finite and >= 0, got {self.target_dist}")
        for name in ("max_obstacle_dist", "ref_distance_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)}")
        if not (math.isfinite(self.max_robot_speed) and self.max_robot_speed >= 0):
            raise ValueError(f"max_robot_speed must be finite and >= 0, got {self.max_robot_speed}")

    @classmethod
    def toward_path(cls, obstacles: np.ndarray, target_k: int, target_dist: float, **options) -> HolonomicInput:
        """The input for a target given by its path index (as a PTG's inverse map returns it): the target
        direction is ``α_{target_k}``; ``options`` are the other fields."""
        n = np.shape(obstacles)[0] if np.ndim(obstacles) else 0
        if not 0 <= target_k < n:
            raise ValueError(f"target_k must be in [0, {n - 1}], got {target_k}")
        return cls(obstacles, index_to_alpha(int(target_k), n), target_dist, **options)

    @property
    def num_paths(self) -> int:
        """N, the number of TP directions."""
        return self.obstacles.size

    @property
    def target_k(self) -> int:
        """Index of the path nearest to the target direction."""
        return alpha_to_index(self.target_alpha_rad, self.num_paths)

    def target_nearness(self, slow_approaching_distance_m: float) -> float:
        """Speed factor min(1, d_target / (slow distance / refDistance)); 1 when slowing down is disabled."""
        if not self.slow_down_near_target:
            return 1.0
        return min(1.0, self.target_dist * self.ref_distance_m / slow_approaching_distance_m)


class NDSituation(StrEnum):
    """How ND chose its direction (MRPT's ``TSituations``)."""

    TARGET_DIRECTLY = "TARGET_DIRECTLY"
    """The paths around the target direction are free up to the target: head straight at it."""
    SMALL_GAP = "SMALL_GAP"
    """Through a narrow gap (under ``wide_gap_size_percent`` of N): its middle path."""
    WIDE_GAP = "WIDE_GAP"
    """Along a wide gap, half a wide-gap width inside its border nearest to the target."""
    NO_WAY_FOUND = "NO_WAY_FOUND"
    """No gap, or none worth taking: speed 0."""


@dataclass(frozen=True)
class Gap:
    """A valley of the TP-obstacle array that ND considered.

    Attributes:
        first_k: first path of the gap.
        last_k: last path of the gap (inclusive).
        representative_k: the path ND would take through it.
        score: ND's weighted score in [0, 1] (0 when the representative path is too close to an obstacle).
    """

    first_k: int
    last_k: int
    representative_k: int
    score: float


@dataclass(frozen=True)
class NDInfo:
    """What ND saw and decided (MRPT's ``CLogFileRecord_ND``).

    Attributes:
        situation: the decision rule that applied.
        target_k: path index of the target.
        gaps: the gaps that survived the filters, in search order, all scored.
        evaluation: score of the choice: 1 + max(0, 1 - d_target) going straight at the target, the gap's
            score through a gap, 0 when no way was found.
        risk: mean TP-obstacle around the chosen path (within the gap), the basis of the speed.
    """

    situation: NDSituation
    target_k: int
    gaps: tuple[Gap, ...]
    evaluation: float
    risk: float


@dataclass(frozen=True)
class VFFInfo:
    """The forces behind a VFF decision.

    Attributes:
        repulsive_force: (x, y) resultant of the obstacle forces, scaled by 20/N.
        attractive_force: (x, y) target force.
        obstacle_nearness: speed factor min(1, 6/|repulsive_force|).
        target_nearness: speed factor from the target distance (1 when slowing down is disabled).
    """

    repulsive_force: tuple[float, float]
    attractive_force: tuple[float, float]
    obstacle_nearness: float
    target_nearness: float


@dataclass(frozen=True)
class HolonomicOutput:
    """The motion a holonomic method asks for in one TP-space.

    Attributes:
        direction_k: the chosen path index.
        direction_alpha_rad: its direction, rad: ``α_k`` for ND; the continuous force direction for VFF.
        speed: speed in [0, max_robot_speed] (normalised: 1 = the PTG's top speed).
        situation: ND: a :class:`NDSituation` value; VFF: ``"FORCE_FIELD"``.
        info: method-specific details for logs (:class:`NDInfo` or :class:`VFFInfo`).
    """

    direction_k: int
    direction_alpha_rad: float
    speed: float
    situation: str
    info: NDInfo | VFFInfo | None = field(default=None, compare=False)


@runtime_checkable
class HolonomicMethod(Protocol):
    """A holonomic obstacle-avoidance method run in one TP-space. The navigator keeps one instance per PTG
    because methods may keep state between steps (ND's hysteresis)."""

    name: str

    def navigate(self, inp: HolonomicInput) -> HolonomicOutput:
        """The direction and speed to take given the TP-obstacles and target of ``inp``."""
        ...

    def reset(self) -> None:
        """Forget the state kept between calls (start of a new navigation)."""
        ...


def _make_config(cls: type, overrides: dict, owner: str):
    """Builds ``cls`` from keyword overrides; MRPT ini names (any case, e.g. ``TOO_CLOSE_OBSTACLE``,
    ``factorWeights``) are accepted for their fields. Unknown names raise :class:`ConfigError`."""
    allowed = {f.name for f in fields(cls)}
    resolved = {}
    for key, value in overrides.items():
        name = key if key in allowed else cls.MRPT_NAMES.get(key.lower(), key.lower())
        if name not in allowed:
            raise ConfigError(f"unknown {owner} option '{key}'; allowed: {', '.join(sorted(allowed))}")
        resolved[name] = value
    return cls(**resolved)


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


# ----------------------------------------------------------------------------------------------------------------
# Nearness Diagram
# ----------------------------------------------------------------------------------------------------------------

_GAP_THRESHOLD_RATIOS = 0.95 - 0.05 * np.arange(18)
"""Threshold ratios of the gap sweep, 0.95 down to 0.10: MRPT's loop is meant to reach 0.05 but floating-point
accumulation (0.95 - 18 x 0.05 < 0.05) stops it at 0.10; we keep what MRPT runs."""
_GAP_MIN_WIDTH_PERCENT = 0.01  # a gap spans at least ceil(1% N) sectors (end - ini)
_GAP_MIN_DEPTH_CONSIDERED = 0.6  # thresholds sweep down to min(d_target, this)
_GAP_MAX_RELATIVE_DEPTH = 0.5  # drop gaps whose depth variation exceeds this fraction of the array's
_DIRECT_SECTORS_PERCENT = 0.02  # TARGET_DIRECTLY: ±ceil(2% N) paths around the target must be free ...
_DIRECT_DIST_MARGIN = 1.05  # ... beyond 1.05 d_target ...
_DIRECT_RANGE_FRACTION = 0.95  # ... or beyond 0.95 of the max obstacle distance
_HYSTERESIS_SECTORS_PERCENT = 0.1  # factor 4 is 1 within floor(10% N) paths of the last choice
_MIN_TARGET_DIST = 0.01
_SCORE_TIE = 1e-9  # gap scores this close are tied (mirror-image gaps differ by rounding only)


@dataclass(frozen=True)
class NDConfig:
    """Nearness Diagram options; the defaults are MRPT's code defaults (``CHolonomicND::TOptions``).

    Attributes:
        wide_gap_size_percent: a gap spanning at least round(this·N) paths is wide.
        max_sector_dist_for_d2_percent: accepted for MRPT ini compatibility; MRPT's rule D2 that read it is
            disabled upstream, so it has no effect.
        risk_evaluation_sectors_percent: the risk is the mean TP-obstacle within ±round(this·N) paths of the
            choice (clipped to the gap).
        risk_evaluation_distance: full speed when the risk reaches this normalised distance; linear below.
        too_close_obstacle: a gap whose representative path is free for less than this normalised distance
            scores 0.
        target_slow_approaching_distance_m: slow down linearly within this distance of the target, m (converted
            to TP units with the input's ``ref_distance_m``).
        factor_weights: weights of the gap-score factors: mean free distance of the gap, angular nearness to the
            target, Euclidean nearness of the path to the target, hysteresis.
    """

    wide_gap_size_percent: float = 0.25
    max_sector_dist_for_d2_percent: float = 0.25
    risk_evaluation_sectors_percent: float = 0.10
    risk_evaluation_distance: float = 0.4
    too_close_obstacle: float = 0.15
    target_slow_approaching_distance_m: float = 0.60
    factor_weights: tuple[float, float, float, float] = (1.0, 0.5, 2.0, 0.4)

    MRPT_NAMES: ClassVar[dict[str, str]] = {
        "target_slow_approaching_distance": "target_slow_approaching_distance_m",
        "factorweights": "factor_weights",
    }

    def __post_init__(self) -> None:
        weights = tuple(float(w) for w in self.factor_weights)
        object.__setattr__(self, "factor_weights", weights)
        _require(len(weights) == 4 and min(weights) >= 0 and sum(weights) > 0,
                 f"ND factor_weights must be 4 weights >= 0 with a positive sum, got {weights}")
        for name in ("wide_gap_size_percent", "risk_evaluation_sectors_percent"):
            _require(0 <= getattr(self, name) <= 1, f"ND {name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("risk_evaluation_distance", "target_slow_approaching_distance_m"):
            _require(getattr(self, name) > 0, f"ND {name} must be > 0, got {getattr(self, name)}")
        _require(self.too_close_obstacle >= 0, f"ND too_close_obstacle must be >= 0, got {self.too_close_obstacle}")


@dataclass(frozen=True)
class _Gaps:
    """Gap arrays, one entry per gap: first/last path (inclusive) and max TP-obstacle / min at the borders."""

    ini: np.ndarray
    end: np.ndarray
    max_d: np.ndarray
    min_d: np.ndarray

    def take(self, idx: np.ndarray) -> _Gaps:
        return _Gaps(self.ini[idx], self.end[idx], self.max_d[idx], self.min_d[idx])


class HolonomicND:
    """Nearness Diagram navigation in TP-space (Minguez & Montano 2004, as MRPT's ``CHolonomicND``).

    1. Gaps: runs of paths above a threshold swept from the deepest obstacle-free level down towards the target
       distance, filtered (duplicates, deep ones, ones containing several others, ones inside another).
    2. TARGET_DIRECTLY when the paths within ±ceil(2% N) of the target are free beyond it (or beyond 0.95).
    3. Otherwise each gap is scored by a weighted mean of four factors and the best one is taken (SMALL_GAP:
       its middle; WIDE_GAP: half a wide width inside its border nearest to the target); none positive:
       NO_WAY_FOUND.
    4. Speed = min(mean nearby free distance / risk distance, target nearness), capped at 1.

    Ties between gaps (scores within 1e-9) go to the first in search order (the one found at the highest
    threshold, then the lowest index): of two mirror-image valleys ND takes the one at negative α.

    Deviations from MRPT: after NO_WAY_FOUND the hysteresis forgets the last choice (MRPT records path 0, a
    placeholder, and then favours gaps near -π); the NO_WAY_FOUND direction is path ``alpha_to_index(0)``
    rather than the raw angle 0; a gap's maximum includes its last path when the gap reaches the array end.

    Args:
        **config: overrides of :class:`NDConfig` fields (snake_case or MRPT ini names); an unknown name raises
            :class:`simnav.errors.ConfigError`.
    """

    name = "nd"

    def __init__(self, **config) -> None:
        self.config: NDConfig = _make_config(NDConfig, config, "ND")
        self.reset()

    def reset(self) -> None:
        """Forget the last chosen path (the hysteresis factor then scores 0 for every gap)."""
        self._last_k: int | None = None

    def navigate(self, inp: HolonomicInput) -> HolonomicOutput:
        """Choose a path and speed (see the class doc)."""
        obs, n, cfg = inp.obstacles, inp.num_paths, self.config
        target_k = inp.target_k
        target_dist = max(_MIN_TARGET_DIST, inp.target_dist)
        wide = _c_round(cfg.wide_gap_size_percent * n)
        gaps = _find_gaps(obs, inp.target_dist)
        rep = _representative_paths(gaps, target_k, n, wide)
        scores = _score_gaps(obs, gaps, rep, target_k, target_dist, inp.max_obstacle_dist, self._last_k, cfg)
        lo, hi = 0, n - 1
        if _target_directly(obs, target_k, target_dist, inp.max_obstacle_dist):
            situation, k = NDSituation.TARGET_DIRECTLY, target_k
            evaluation = 1.0 + max(0.0, (inp.max_obstacle_dist - target_dist) / inp.max_obstacle_dist)
        elif scores.size == 0 or scores.max() <= 0:
            situation, k, evaluation = NDSituation.NO_WAY_FOUND, alpha_to_index(0.0, n), 0.0
        else:
            best = int(np.flatnonzero(scores >= scores.max() - _SCORE_TIE)[0])  # the first of tied gaps
            lo, hi, k, evaluation = int(gaps.ini[best]), int(gaps.end[best]), int(rep[best]), float(scores[best])
            situation = NDSituation.SMALL_GAP if hi - lo < wide else NDSituation.WIDE_GAP
        risk = _risk(obs, k, lo, hi, _c_round(cfg.risk_evaluation_sectors_percent * n))
        if situation is NDSituation.NO_WAY_FOUND:
            speed = 0.0
        else:
            risk_factor = min(1.0, risk / cfg.risk_evaluation_distance)
            speed = inp.max_robot_speed * min(risk_factor, inp.target_nearness(cfg.target_slow_approaching_distance_m))
        self._last_k = None if situation is NDSituation.NO_WAY_FOUND else k
        info = NDInfo(situation, target_k, _gap_records(gaps, rep, scores), evaluation, risk)
        return HolonomicOutput(k, index_to_alpha(k, n), speed, situation.value, info)


def _find_gaps(obs: np.ndarray, target_dist: float) -> _Gaps:
    """The gaps that survive MRPT's filters, in search order (threshold ratio 0.95 first, then by index)."""
    n = obs.size
    interior = obs[1:-1]  # MRPT leaves out the two end paths when measuring the array's range
    top, bottom = float(interior.max()), float(interior.min())
    candidates = _candidate_gaps(obs, top, target_dist, math.ceil(_GAP_MIN_WIDTH_PERCENT * n))
    keep = _filter_gaps(candidates, top - bottom)
    return candidates.take(np.flatnonzero(keep))


def _candidate_gaps(obs: np.ndarray, top: float, target_dist: float, min_width: int) -> _Gaps:
    """Every run of paths with obs >= threshold, for each threshold of the sweep, of width (end - ini) >=
    ``min_width``; exact repeats (the same run at several thresholds) are kept once, at their first place."""
    n = obs.size
    floor_d = min(target_dist, _GAP_MIN_DEPTH_CONSIDERED)
    thresholds = _GAP_THRESHOLD_RATIOS * top + (1.0 - _GAP_THRESHOLD_RATIOS) * floor_d
    above = np.zeros((thresholds.size, n + 2), dtype=np.int8)
    above[:, 1:-1] = obs[None, :] >= thresholds[:, None]
    edges = np.diff(above, axis=1)
    _, ini = np.nonzero(edges == 1)  # row-major: threshold first, then index
    _, end = np.nonzero(edges == -1)
    end = end - 1
    wide_enough = end - ini >= min_width
    ini, end = ini[wide_enough], end[wide_enough]
    _, first = np.unique(ini * (n + 1) + end, return_index=True)
    order = np.sort(first)
    ini, end = ini[order], end[order]
    return _Gaps(ini, end, _run_max(obs, ini, end), np.minimum(obs[ini], obs[end]))


def _run_max(obs: np.ndarray, ini: np.ndarray, end: np.ndarray) -> np.ndarray:
    """max(obs[ini[i] : end[i] + 1]) for every i, in one ``reduceat``."""
    if ini.size == 0:
        return np.empty(0)
    bounds = np.empty(2 * ini.size, dtype=np.intp)
    bounds[0::2], bounds[1::2] = ini, end + 1
    return np.maximum.reduceat(np.append(obs, 0.0), bounds)[0::2]


def _filter_gaps(gaps: _Gaps, array_depth: float) -> np.ndarray:
    """MRPT's four filters, applied in order; returns the keep mask.

    1. A gap sharing its first or last path with an earlier surviving gap goes.
    2. A gap whose depth variation (max - min at the borders) exceeds half the array's goes.
    3. A gap that contains more than one surviving gap goes (in order, counting those still alive).
    4. A gap inside a surviving gap goes (what is left: the maximal gaps).
    """
    ini, end = gaps.ini, gaps.end
    g = ini.size
    alive = np.ones(g, dtype=bool)
    shares = (ini[:, None] == ini[None, :]) | (end[:, None] == end[None, :])
    for i in range(g):
        if alive[i]:
            alive[i + 1:] &= ~shares[i, i + 1:]
    alive &= gaps.max_d - gaps.min_d <= _GAP_MAX_RELATIVE_DEPTH * array_depth
    contains = (ini[None, :] >= ini[:, None]) & (end[None, :] <= end[:, None])  # [i, j]: j inside i
    np.fill_diagonal(contains, False)
    for i in np.flatnonzero((contains & alive[None, :]).sum(axis=1) > 1):  # inner counts only fall
        if alive[i] and np.count_nonzero(contains[i] & alive) > 1:
            alive[i] = False
    return alive & ~(contains & alive[:, None]).any(axis=0)


def _representative_paths(gaps: _Gaps, target_k: int, n: int, wide: int) -> np.ndarray:
    """Path taken through each gap: the middle of a narrow gap; for a wide one, ``wide // 2`` paths inside the
    border nearest (circularly) to the target, the last border on a tie."""
    ini, end = gaps.ini, gaps.end
    middle = np.floor(0.5 * ini + 0.5 * end + 0.5).astype(int)
    to_ini, to_end = _circular_diff(ini, target_k, n), _circular_diff(end, target_k, n)
    near_border = np.where(to_ini < to_end, ini + wide // 2, end - wide // 2)
    rep = np.where(end - ini < wide, middle, near_border)
    return np.clip(rep, 0, n - 1)


def _circular_diff(k: np.ndarray | int, target_k: int, n: int) -> np.ndarray:
    """Number of paths between k and target_k around the circle."""
    d = np.abs(np.asarray(k) - target_k)
    return np.where(d > 0.5 * n, n - d, d)


def _target_directly(obs: np.ndarray, target_k: int, target_dist: float, max_obs: float) -> bool:
    """MRPT's rule D1: the target path is not near the array ends and the ±ceil(2% N) paths around it are free
    for at least min(1.05 d_target, 0.95 max_obs)."""
    n = obs.size
    m = math.ceil(_DIRECT_SECTORS_PERCENT * n)
    if not m < target_k < n - m:
        return False
    needed = min(_DIRECT_DIST_MARGIN * target_dist, _DIRECT_RANGE_FRACTION * max_obs)
    return bool((obs[target_k - m:target_k + m + 1] >= needed).all())


def _score_gaps(obs: np.ndarray, gaps: _Gaps, rep: np.ndarray, target_k: int, target_dist: float, max_obs: float,
                last_k: int | None, cfg: NDConfig) -> np.ndarray:
    """Weighted mean of MRPT's four factors for every gap, 0 where the representative path is too close.

    f1: mean free distance over the gap (min(d_t, mean)/d_t for a gap pointing at a target inside the horizon);
    f2: exp(-(Δpaths / (N/4))²), Δ circular; f3: 1 - min(1, dist(target, [origin, representative point]) /
    max_obs) with the point at min(obs, max_obs, 0.95 d_t); f4: 1 within floor(10% N) paths of the last choice.
    """
    n = obs.size
    cumsum = np.concatenate(([0.0], np.cumsum(obs)))
    mean = (cumsum[gaps.end + 1] - cumsum[gaps.ini]) / (gaps.end - gaps.ini + 1)
    at_target = (np.abs(rep - target_k) <= 1) & (target_dist < 1)
    f1 = np.where(at_target, np.minimum(target_dist, mean) / target_dist, mean)
    f2 = np.exp(-np.square(_circular_diff(rep, target_k, n) / (0.25 * n)))
    reach = np.minimum(np.minimum(obs[rep], max_obs), 0.95 * target_dist)
    f3 = 1.0 - np.minimum(max_obs, _distance_to_segments(target_k, target_dist, rep, reach, n)) / max_obs
    if last_k is None:
        f4 = np.zeros(rep.size)
    else:
        f4 = (np.abs(rep - last_k) <= int(_HYSTERESIS_SECTORS_PERCENT * n)).astype(float)
    w = cfg.factor_weights
    score = (w[0] * f1 + w[1] * f2 + w[2] * f3 + w[3] * f4) / sum(w)
    return np.where(obs[rep] < cfg.too_close_obstacle, 0.0, score)


def _distance_to_segments(target_k: int, target_dist: float, rep: np.ndarray, reach: np.ndarray,
                          n: int) -> np.ndarray:
    """Distance in TP-space from the target (placed on its path's direction) to each segment from the origin to
    ``reach[i]`` along path ``rep[i]``."""
    alpha_t = index_to_alpha(target_k, n)
    px, py = target_dist * math.cos(alpha_t), target_dist * math.sin(alpha_t)
    alpha = index_to_alpha(rep, n)
    ux, uy = np.cos(alpha), np.sin(alpha)
    along = np.clip(px * ux + py * uy, 0.0, reach)  # projection onto the unit direction, clamped to the segment
    return np.hypot(px - along * ux, py - along * uy)


def _risk(obs: np.ndarray, k: int, lo: int, hi: int, half_width: int) -> float:
    """Mean TP-obstacle over paths k ± half_width, clipped to [lo, hi]."""
    first = max(lo, k - half_width if half_width < k else 0)
    last = min(hi, k + half_width)
    return float(obs[first:last + 1].mean())


def _gap_records(gaps: _Gaps, rep: np.ndarray, scores: np.ndarray) -> tuple[Gap, ...]:
    return tuple(Gap(int(a), int(b), int(r), float(s)) for a, b, r, s in zip(gaps.ini, gaps.end, rep, scores))


# ----------------------------------------------------------------------------------------------------------------
# Virtual Force Field
# ----------------------------------------------------------------------------------------------------------------

_VFF_OBSTACLE_GAIN = 20.0  # the repulsive resultant is scaled by this / N
_VFF_NEARNESS_GAIN = 6.0  # obstacle nearness = min(1, this / |repulsive resultant|)
_VFF_MAX_REPULSION = 1e6  # per-path force cap (1/obs for obs -> 0)


@dataclass(frozen=True)
class VFFConfig:
    """Virtual Force Field options; the defaults are MRPT's (``CHolonomicVFF::TOptions``).

    Attributes:
        target_slow_approaching_distance_m: slow down linearly within this distance of the target, m (converted
            to TP units with the input's ``ref_distance_m``).
        target_attractive_force: magnitude of the target force (dimensionless; compare with the repulsive
            resultant, 20/N x sum of 1/obs).
    """

    target_slow_approaching_distance_m: float = 0.10
    target_attractive_force: float = 20.0

    MRPT_NAMES: ClassVar[dict[str, str]] = {
        "target_slow_approaching_distance": "target_slow_approaching_distance_m",
    }

    def __post_init__(self) -> None:
        _require(self.target_slow_approaching_distance_m > 0,
                 f"VFF target_slow_approaching_distance_m must be > 0, got {self.target_slow_approaching_distance_m}")
        _require(self.target_attractive_force >= 0,
                 f"VFF target_attractive_force must be >= 0, got {self.target_attractive_force}")


class HolonomicVFF:
    """Virtual Force Field in TP-space (Borenstein & Koren 1989, as MRPT's ``CHolonomicVFF``).

    Every path k pushes with ``-(cos α_k, sin α_k)·min(1e6, 1/obs_k)``; the resultant is scaled by 20/N. The
    target pulls with ``target_attractive_force`` along its direction. The robot heads along the total force
    (α = 0 if it is zero) at speed ``min(obstacle nearness, target nearness)`` with obstacle nearness
    ``min(1, 6/|repulsion|)``.

    Uniformly near obstacles cancel out and do not slow VFF down; the navigator's safety ramp on the chosen
    path's free distance (notes §1.4 d) is what stops the robot then. Like any potential field it can head
    straight into an obstacle that sits symmetrically across the target direction.

    Deviation from MRPT: with slowing down disabled MRPT leaves the speed unset (0, an upstream bug); here it is
    the obstacle nearness.

    Args:
        **config: overrides of :class:`VFFConfig` fields (snake_case or MRPT ini names); an unknown name raises
            :class:`simnav.errors.ConfigError`.
    """

    name = "vff"

    def __init__(self, **config) -> None:
        self.config: VFFConfig = _make_config(VFFConfig, config, "VFF")

    def reset(self) -> None:
        """VFF keeps no state."""

    def navigate(self, inp: HolonomicInput) -> HolonomicOutput:
        """Choose a direction and speed (see the class doc)."""
        n, cfg = inp.num_paths, self.config
        cos_k, sin_k = _unit_directions(n)
        with np.errstate(divide="ignore"):
            push = np.minimum(_VFF_MAX_REPULSION, 1.0 / inp.obstacles)
        scale = -_VFF_OBSTACLE_GAIN / n
        rx, ry = scale * float(cos_k @ push), scale * float(sin_k @ push)
        repulsion = math.hypot(rx, ry)
        obstacle_nearness = 1.0 if repulsion == 0 else min(1.0, _VFF_NEARNESS_GAIN / repulsion)
        ax = cfg.target_attractive_force * math.cos(inp.target_alpha_rad)
        ay = cfg.target_attractive_force * math.sin(inp.target_alpha_rad)
        fx, fy = rx + ax, ry + ay
        alpha = 0.0 if fx == 0 and fy == 0 else math.atan2(fy, fx)
        target_nearness = inp.target_nearness(cfg.target_slow_approaching_distance_m)
        speed = inp.max_robot_speed * min(obstacle_nearness, target_nearness)
        info = VFFInfo((rx, ry), (ax, ay), obstacle_nearness, target_nearness)
        return HolonomicOutput(alpha_to_index(alpha, n), alpha, speed, "FORCE_FIELD", info)


_UNIT_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _unit_directions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(cos α_k, sin α_k) of the N paths, cached per N."""
    if n not in _UNIT_CACHE:
        alpha = index_to_alpha(np.arange(n), n)
        _UNIT_CACHE[n] = (np.cos(alpha), np.sin(alpha))
    return _UNIT_CACHE[n]


# ----------------------------------------------------------------------------------------------------------------
# Factory
# ----------------------------------------------------------------------------------------------------------------

METHODS: dict[str, type] = {"nd": HolonomicND, "vff": HolonomicVFF}
"""Holonomic methods by name; ``"nd"`` is the default (the thesis' choice, §6.C.6)."""


def make_holonomic(name: str = "nd", **config) -> HolonomicMethod:
    """A new holonomic method by name.

    Args:
        name: ``"nd"`` (Nearness Diagram, default) or ``"vff"`` (Virtual Force Field); case-insensitive.
        **config: overrides of the method's config fields (:class:`NDConfig`, :class:`VFFConfig`).

    Raises:
        UnknownNameError: ``name`` is no method (the message lists the available ones).
        ConfigError: an option is unknown or invalid.
    """
    cls = METHODS.get(name.lower()) if isinstance(name, str) else None
    if cls is None:
        raise UnknownNameError(f"unknown holonomic method '{name}'; available: {', '.join(METHODS)}")
    return cls(**config)
