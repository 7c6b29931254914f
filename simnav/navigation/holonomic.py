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

The methods import only numpy and numba and know nothing about PTGs: all inputs are plain arrays and numbers.

Runtime: the navigator runs a method once per PTG and step, within a 1 ms step budget. ND's gap search, filters,
scoring and risk run in one Numba kernel (``@njit(cache=True)``: compiled on first use, then loaded from
``__pycache__``), ~0.006 ms a call for N = 121 against 0.2-0.3 ms written with numpy; its results are bit-identical
to the numpy formulation (same operations in the same order; ``exp`` and ``cos``/``sin`` come from numpy-built tables,
the risk mean from numpy's pairwise summation). ``NDInfo.gaps`` is built on first access. VFF stays in numpy (its
two dot products are BLAS's, whose summation order a kernel would not reproduce) with the scalar work in Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from enum import StrEnum
from functools import cached_property
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numba import njit

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


def _path_alpha(k: int, num_paths: int) -> float:
    """:func:`index_to_alpha` of one path, in plain floats (the same operations, so the same bits)."""
    return math.pi * (2 * k + 1 - num_paths) / num_paths


def _path_index(alpha_rad: float, num_paths: int) -> int:
    """:func:`alpha_to_index` of one angle, in plain floats (the same operations, so the same index)."""
    wrapped = alpha_rad - 2.0 * math.pi * math.ceil((alpha_rad - math.pi) / (2.0 * math.pi))
    k = math.floor(0.5 * (num_paths * (1.0 + wrapped / math.pi) - 1.0) + 0.5)
    return min(max(k, 0), num_paths - 1)


@njit(cache=True, error_model="numpy")
def _obstacles_valid(obs: np.ndarray) -> bool:
    """All TP-obstacles finite and >= 0 (NaN fails), in one pass."""
    for v in obs:
        if not 0.0 <= v < math.inf:
            return False
    return True


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
        obs = np.array(self.obstacles, dtype=np.float64, order="C")  # a copy (the caller may reuse its array)
        if obs.ndim != 1 or obs.size < 3:
            raise ValueError(f"obstacles must have shape (N,) with N >= 3, got {obs.shape}")
        if not _obstacles_valid(obs):
            raise ValueError("obstacles must be finite and >= 0")
        obs.flags.writeable = False
        object.__setattr__(self, "obstacles", obs)
        if not math.isfinite(self.target_alpha_rad):
            raise ValueError(f"target_alpha_rad must be finite, got {self.target_alpha_rad}")
        if not (math.isfinite(self.target_dist) and self.target_dist >= 0):
            raise ValueError(f"target_dist must be finite and >= 0, got {self.target_dist}")
        if not (math.isfinite(self.max_obstacle_dist) and self.max_obstacle_dist > 0):
            raise ValueError(f"max_obstacle_dist must be finite and > 0, got {self.max_obstacle_dist}")
        if not (math.isfinite(self.ref_distance_m) and self.ref_distance_m > 0):
            raise ValueError(f"ref_distance_m must be finite and > 0, got {self.ref_distance_m}")
        if not (math.isfinite(self.max_robot_speed) and self.max_robot_speed >= 0):
            raise ValueError(f"max_robot_speed must be finite and >= 0, got {self.max_robot_speed}")

    @classmethod
    def toward_path(cls, obstacles: np.ndarray, target_k: int, target_dist: float, **options) -> HolonomicInput:
        """The input for a target given by its path index (as a PTG's inverse map returns it): the target
        direction is ``α_{target_k}``; ``options`` are the other fields."""
        if isinstance(obstacles, np.ndarray):
            n = obstacles.shape[0] if obstacles.ndim else 0
        else:
            n = np.shape(obstacles)[0] if np.ndim(obstacles) else 0
        if not 0 <= target_k < n:
            raise ValueError(f"target_k must be in [0, {n - 1}], got {target_k}")
        return cls(obstacles, _path_alpha(int(target_k), n), target_dist, **options)

    @property
    def num_paths(self) -> int:
        """N, the number of TP directions."""
        return self.obstacles.size

    @cached_property
    def target_k(self) -> int:
        """Index of the path nearest to the target direction."""
        return _path_index(float(self.target_alpha_rad), self.obstacles.size)

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


class _LazyNDInfo(NDInfo):
    """The :class:`NDInfo` that :meth:`HolonomicND.navigate` returns: ``gaps`` may be given as the kernel's (g, 4)
    array of (first_k, last_k, representative_k, score) rows, turned into :class:`Gap` records on first access
    (the navigator never reads them). Compares and hashes as an :class:`NDInfo` with the same fields."""

    def __init__(self, situation: NDSituation, target_k: int, gaps: np.ndarray | tuple[Gap, ...], evaluation: float,
                 risk: float) -> None:
        attrs = self.__dict__  # frozen: set the fields directly
        attrs["situation"], attrs["target_k"] = situation, target_k
        attrs["evaluation"], attrs["risk"] = evaluation, risk
        attrs["_gap_table" if isinstance(gaps, np.ndarray) else "_gaps"] = gaps

    @property
    def gaps(self) -> tuple[Gap, ...]:  # type: ignore[override]
        attrs = self.__dict__
        if "_gaps" not in attrs:
            attrs["_gaps"] = tuple(Gap(int(a), int(b), int(r), s) for a, b, r, s in attrs["_gap_table"].tolist())
        return attrs["_gaps"]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, NDInfo):
            return NotImplemented
        return ((self.situation, self.target_k, self.gaps, self.evaluation, self.risk)
                == (other.situation, other.target_k, other.gaps, other.evaluation, other.risk))

    __hash__ = NDInfo.__hash__

    def __repr__(self) -> str:
        return "NDInfo" + super().__repr__().removeprefix(type(self).__qualname__)


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

_GAP_THRESHOLD_COUNT = 18  # threshold ratios of the gap sweep: 0.95 - 0.05 t, t = 0..17 (see _nd_gaps)
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
        crowded_floor_ratio: the gap sweep goes down to ``min(d_target, 0.6, this · deepest)``, ``deepest`` the
            largest TP-obstacle but the end paths'; None: MRPT's ``min(d_target, 0.6)``. With MRPT's floor, when
            no path but the end ones is free that far (0.6 is 2.4 m at a 4 m reference distance: people all
            around), every threshold lies above the free paths, and ND finds no gap (the robot stops and waits) or
            only the one across the seam at alpha = +-pi (which turns the robot in place; as it turns, the seam
            turns with it, and it spins). On the office missions (seeds 1-32) 0.5 cut the time spent turning on the spot
            by 19 % and the missions' duration by 8 %, with as many interventions; in the contour-door experiment
            with the bar (2 cm grids, short-term memory) the robot pressed against the bar 7 times in 20 instead
            of 2, so MRPT's floor stays the default; the navigator runs ND again with 0.5 only where MRPT's finds no
            way (:attr:`simnav.navigation.navigator.NavigatorConfig.nd_fallback_floor_ratio`).
    """

    wide_gap_size_percent: float = 0.25
    max_sector_dist_for_d2_percent: float = 0.25
    risk_evaluation_sectors_percent: float = 0.10
    risk_evaluation_distance: float = 0.4
    too_close_obstacle: float = 0.15
    target_slow_approaching_distance_m: float = 0.60
    factor_weights: tuple[float, float, float, float] = (1.0, 0.5, 2.0, 0.4)
    crowded_floor_ratio: float | None = None

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
        _require(self.crowded_floor_ratio is None or 0 < self.crowded_floor_ratio <= 1,
                 f"ND crowded_floor_ratio must be None or in (0, 1], got {self.crowded_floor_ratio}")


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

    Deviations from MRPT: the gap sweep's floor where nothing is free down to MRPT's (``crowded_floor_ratio``);
    after NO_WAY_FOUND the hysteresis forgets the last choice (MRPT records path 0, a placeholder, and then
    favours gaps near -π); the NO_WAY_FOUND direction is path ``alpha_to_index(0)`` rather than the raw angle 0;
    a gap's maximum includes its last path when the gap reaches the array end.

    Steps 1-3 and the risk of step 4 run in the compiled :func:`_nd_kernel`; the returned ``info`` builds its
    :class:`Gap` records on first access.

    Args:
        **config: overrides of :class:`NDConfig` fields (snake_case or MRPT ini names); an unknown name raises
            :class:`simnav.errors.ConfigError`.
    """

    name = "nd"

    def __init__(self, **config) -> None:
        self.config: NDConfig = _make_config(NDConfig, config, "ND")
        self._params_config: NDConfig | None = None  # the config that _params was built from
        self._params = np.empty(0)
        self.reset()

    def reset(self) -> None:
        """Forget the last chosen path (the hysteresis factor then scores 0 for every gap)."""
        self._last_k: int | None = None

    def navigate(self, inp: HolonomicInput) -> HolonomicOutput:
        """Choose a path and speed (see the class doc)."""
        cfg = self.config
        if cfg is not self._params_config:  # the kernel's view of the config, rebuilt if it was replaced
            w = cfg.factor_weights
            floor_ratio = math.inf if cfg.crowded_floor_ratio is None else cfg.crowded_floor_ratio
            self._params = np.array([cfg.wide_gap_size_percent, cfg.risk_evaluation_sectors_percent,
                                     cfg.too_close_obstacle, *w, sum(w), floor_ratio])
            self._params_config = cfg
        obs = inp.obstacles
        n = obs.size
        target_k = inp.target_k
        last_k = self._last_k
        gap_table = np.empty((n, 4))
        code, k, evaluation, risk, g = _nd_kernel(obs, target_k, inp.target_dist, inp.max_obstacle_dist,
                                                  -1 if last_k is None else last_k, self._params, _direction_tables(n),
                                                  gap_table)
        if code == _ND_NO_WAY_FOUND:
            speed = 0.0
            self._last_k = None
        else:
            risk_factor = min(1.0, risk / cfg.risk_evaluation_distance)
            speed = inp.max_robot_speed * min(risk_factor, inp.target_nearness(cfg.target_slow_approaching_distance_m))
            self._last_k = k
        situation = _ND_SITUATIONS[code]
        info = _LazyNDInfo(situation, target_k, gap_table[:g], evaluation, risk)
        return HolonomicOutput(k, _path_alpha(k, n), speed, _ND_SITUATION_NAMES[code], info)


_ND_SITUATIONS = (NDSituation.TARGET_DIRECTLY, NDSituation.SMALL_GAP, NDSituation.WIDE_GAP, NDSituation.NO_WAY_FOUND)
"""The situations by the kernel's code."""
_ND_SITUATION_NAMES = tuple(s.value for s in _ND_SITUATIONS)
_ND_TARGET_DIRECTLY, _ND_SMALL_GAP, _ND_WIDE_GAP, _ND_NO_WAY_FOUND = range(4)

_DIRECTION_TABLES: dict[int, np.ndarray] = {}


def _direction_tables(n: int) -> np.ndarray:
    """(3, N) per-N tables, cached: cos α_k, sin α_k and ND's angular factor ``exp(-(d / (N/4))²)`` for a circular
    distance of d paths, all computed with numpy (whose ``exp`` may differ from libm's by an ulp)."""
    tables = _DIRECTION_TABLES.get(n)
    if tables is None:
        k = np.arange(n)
        alpha = index_to_alpha(k, n)
        tables = np.ascontiguousarray(np.stack([np.cos(alpha), np.sin(alpha), np.exp(-np.square(k / (0.25 * n)))]))
        tables.flags.writeable = False
        _DIRECTION_TABLES[n] = tables
    return tables


@njit(cache=True, error_model="numpy")
def _nd_kernel(obs: np.ndarray, target_k: int, target_dist: float, max_obs: float, last_k: int, params: np.ndarray,
               tables: np.ndarray, gaps: np.ndarray) -> tuple[int, int, float, float, int]:
    """Compiled ND decision (steps 1-3 of :class:`HolonomicND` and the risk).

    Args:
        obs: (N,) TP-obstacles.
        target_k: path of the target.
        target_dist: normalised target distance, as given (the gap sweep reads it unclamped).
        max_obs: the "free" level.
        last_k: the last chosen path, -1 for none.
        params: wide-gap percent, risk-sectors percent, too-close distance, the 4 factor weights, their sum, the
            crowded floor ratio (inf: MRPT's floor).
        tables: :func:`_direction_tables` of N.
        gaps: (N, 4) output: its first g rows get (first_k, last_k, representative_k, score) of the surviving
            gaps in search order.

    Returns:
        ``(situation code, chosen path, evaluation, risk, g)``.
    """
    n = obs.size
    wide = int(math.floor(params[0] * n + 0.5))
    td = max(_MIN_TARGET_DIST, target_dist)
    scratch = np.empty(5 * n, np.int64)
    g = _nd_gaps(obs, target_dist, params[8], scratch)
    ini, end = scratch[:n], scratch[n:2 * n]
    # Scores: weighted mean of the four factors (see _nd_score)
    cumsum = np.empty(n + 1)  # as numpy's: cumsum[i + 1] = cumsum[i] + obs[i], cumsum[1] = obs[0]
    cumsum[0], cumsum[1] = 0.0, obs[0]
    for i in range(1, n):
        cumsum[i + 1] = cumsum[i] + obs[i]
    alpha_t = math.pi * (2 * target_k + 1 - n) / n
    px, py = td * math.cos(alpha_t), td * math.sin(alpha_t)
    hysteresis = int(_HYSTERESIS_SECTORS_PERCENT * n)
    best_score = -math.inf
    for i in range(g):
        a, b = ini[i], end[i]
        if b - a < wide:  # narrow: its middle path
            rep = int(math.floor(0.5 * a + 0.5 * b + 0.5))
        elif _circular_distance(a, target_k, n) < _circular_distance(b, target_k, n):  # wide: near the target's side
            rep = a + wide // 2
        else:
            rep = b - wide // 2
        rep = min(max(rep, 0), n - 1)
        score = _nd_score(obs, a, b, rep, cumsum, target_k, td, px, py, max_obs, last_k, hysteresis, params, tables)
        gaps[i, 0], gaps[i, 1], gaps[i, 2], gaps[i, 3] = a, b, rep, score
        best_score = max(best_score, score)
    # Decision
    lo, hi = 0, n - 1
    if _target_directly(obs, target_k, td, max_obs):
        code, k = _ND_TARGET_DIRECTLY, target_k
        evaluation = 1.0 + max(0.0, (max_obs - td) / max_obs)
    elif g == 0 or best_score <= 0:
        code, k, evaluation = _ND_NO_WAY_FOUND, min(max(int(math.floor(0.5 * (n * 1.0 - 1.0) + 0.5)), 0), n - 1), 0.0
    else:
        best = 0
        while gaps[best, 3] < best_score - _SCORE_TIE:  # the first of tied gaps
            best += 1
        lo, hi, k, evaluation = ini[best], end[best], int(gaps[best, 2]), gaps[best, 3]
        code = _ND_SMALL_GAP if hi - lo < wide else _ND_WIDE_GAP
    # Risk: mean TP-obstacle over k ± round(risk% N), clipped to [lo, hi]
    half = int(math.floor(params[1] * n + 0.5))
    first = max(lo, k - half if half < k else 0)
    last = min(hi, k + half)
    risk = _pairwise_sum(obs, first, last + 1 - first) / (last + 1 - first)
    return code, k, evaluation, risk, g


@njit(cache=True, error_model="numpy")
def _nd_gaps(obs: np.ndarray, target_dist: float, floor_ratio: float, scratch: np.ndarray) -> int:
    """The gaps that survive MRPT's filters, in search order (threshold ratio 0.95 first, then by index): writes
    their first and last paths into ``scratch[:N]`` and ``scratch[N:2N]`` and returns their number; ``scratch`` is
    (5N,) int64, the rest work space.

    Candidates are the runs of paths with obs >= threshold, of width (last - first) >= ceil(1% N), for each
    threshold ``r·top + (1 - r)·min(d_target, 0.6, floor_ratio·top)`` of the sweep (MRPT: ``floor_ratio`` = inf),
    ``top`` the largest TP-obstacle but the two end paths' and ``r = 0.95 - 0.05 t``, t = 0..17 (0.95 down to
    0.10: MRPT's loop is meant to reach 0.05 but floating-point accumulation, 0.95 - 18 x 0.05 < 0.05, stops it
    at 0.10; we keep what MRPT runs). MRPT's four filters, in order:

    1. A gap sharing its first or last path with an earlier surviving gap goes. (A gap's fate here depends only
       on the earlier survivors, so it is decided as the gap is found; exact repeats go this way too.)
    2. A gap whose depth variation (max - min at the borders) exceeds half the array's (top - bottom) goes.
    3. A gap that contains more than one surviving gap goes (in order, counting those still alive).
    4. A gap inside a surviving gap goes (what is left: the maximal gaps).
    """
    n = obs.size
    ini, end = scratch[:n], scratch[n:2 * n]
    top = bottom = obs[1]  # MRPT leaves out the two end paths when measuring the array's range
    for i in range(2, n - 1):
        top = max(top, obs[i])
        bottom = min(bottom, obs[i])
    floor_d = min(target_dist, _GAP_MIN_DEPTH_CONSIDERED)
    if floor_ratio * top < floor_d:  # crowded: nothing but the end paths is free down to MRPT's floor
        floor_d = floor_ratio * top
    min_width = math.ceil(_GAP_MIN_WIDTH_PERCENT * n)
    depth_limit = _GAP_MAX_RELATIVE_DEPTH * (top - bottom)
    taken = scratch[2 * n:3 * n]  # bit 0: an earlier survivor starts at the path, bit 1: one ends there
    taken[:] = 0
    starts, ends = scratch[3 * n:4 * n], scratch[4 * n:]  # the runs of one threshold (at most ceil(N/2))
    g = 0
    for t in range(_GAP_THRESHOLD_COUNT):
        ratio = 0.95 - 0.05 * t
        threshold = ratio * top + (1.0 - ratio) * floor_d
        runs = closed = 0
        inside = False
        for i in range(n):  # the run boundaries, free of data-dependent branches
            above = obs[i] >= threshold
            starts[runs] = i
            ends[closed] = i - 1
            runs += above > inside
            closed += inside > above
            inside = above
        if inside:
            ends[closed] = n - 1
        for r in range(runs):
            i, j = starts[r], ends[r]
            if j - i >= min_width and taken[i] & 1 == 0 and taken[j] & 2 == 0:  # filter 1
                taken[i] |= 1
                taken[j] |= 2
                peak = obs[i]
                for q in range(i + 1, j + 1):
                    peak = max(peak, obs[q])
                if peak - min(obs[i], obs[j]) <= depth_limit:  # filter 2
                    ini[g], end[g] = i, j
                    g += 1
    alive = taken  # reused: 1 = alive
    alive[:g] = 1
    for i in range(g):  # filter 3
        nested = 0
        for j in range(g):
            if j != i and alive[j] and ini[j] >= ini[i] and end[j] <= end[i]:
                nested += 1
        alive[i] = nested <= 1
    m = 0
    for j in range(g):  # filter 4; the kept indices go to starts
        if alive[j]:
            outer = False
            for i in range(g):
                if i != j and alive[i] and ini[j] >= ini[i] and end[j] <= end[i]:
                    outer = True
                    break
            if not outer:
                starts[m] = j
                m += 1
    for r in range(m):
        ini[r], end[r] = ini[starts[r]], end[starts[r]]
    return m


@njit(cache=True, error_model="numpy", inline="always")
def _circular_distance(k: int, target_k: int, n: int) -> int:
    """Number of paths between k and target_k around the circle."""
    d = abs(k - target_k)
    return n - d if d > 0.5 * n else d


@njit(cache=True, error_model="numpy", inline="always")
def _nd_score(obs: np.ndarray, a: int, b: int, rep: int, cumsum: np.ndarray, target_k: int, td: float, px: float,
              py: float, max_obs: float, last_k: int, hysteresis: int, params: np.ndarray,
              tables: np.ndarray) -> float:
    """Weighted mean of MRPT's four factors for the gap [a, b] taken along path ``rep``, 0 when that path is too
    close to an obstacle.

    f1: mean free distance over the gap (min(d_t, mean)/d_t for a gap pointing at a target inside the horizon);
    f2: exp(-(Δpaths / (N/4))²), Δ circular; f3: 1 - min(1, dist(target, [origin, representative point]) /
    max_obs) with the point at min(obs, max_obs, 0.95 d_t), the target (px, py) on its path's direction;
    f4: 1 within floor(10% N) paths of the last choice.
    """
    if obs[rep] < params[2]:
        return 0.0
    mean = (cumsum[b + 1] - cumsum[a]) / (b - a + 1)
    f1 = min(td, mean) / td if abs(rep - target_k) <= 1 and td < 1 else mean
    f2 = tables[2, _circular_distance(rep, target_k, obs.size)]
    reach = min(min(obs[rep], max_obs), 0.95 * td)
    ux, uy = tables[0, rep], tables[1, rep]
    along = min(max(px * ux + py * uy, 0.0), reach)  # projection onto the path, clamped to the segment
    f3 = 1.0 - min(max_obs, math.hypot(px - along * ux, py - along * uy)) / max_obs
    f4 = 1.0 if last_k >= 0 and abs(rep - last_k) <= hysteresis else 0.0
    return (params[3] * f1 + params[4] * f2 + params[5] * f3 + params[6] * f4) / params[7]


@njit(cache=True, error_model="numpy")
def _target_directly(obs: np.ndarray, target_k: int, td: float, max_obs: float) -> bool:
    """MRPT's rule D1: the target path is not near the array ends and the ±ceil(2% N) paths around it are free
    for at least min(1.05 d_target, 0.95 max_obs)."""
    n = obs.size
    m = math.ceil(_DIRECT_SECTORS_PERCENT * n)
    if not m < target_k < n - m:
        return False
    needed = min(_DIRECT_DIST_MARGIN * td, _DIRECT_RANGE_FRACTION * max_obs)
    for i in range(target_k - m, target_k + m + 1):
        if obs[i] < needed:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _pairwise_sum(a: np.ndarray, start: int, count: int) -> float:
    """sum(a[start : start + count]) exactly as numpy adds it (``np.add.reduce``'s pairwise summation: 8
    accumulators over blocks of up to 128, halves beyond), so that the risk is ``np.mean``'s to the bit."""
    if count < 8:
        total = 0.0
        for i in range(start, start + count):
            total += a[i]
        return total
    if count <= 128:
        r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
        r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
        i = start + 8
        stop = start + count - count % 8
        while i < stop:
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < start + count:
            total += a[i]
            i += 1
        return total
    half = count // 2
    half -= half % 8
    return _pairwise_sum(a, start, half) + _pairwise_sum(a, start + half, count - half)


# ----------------------------------------------------------------------------------------------------------------
# Virtual Force Field
# ----------------------------------------------------------------------------------------------------------------

_VFF_OBSTACLE_GAIN = 20.0  # the repulsive resultant is scaled by this / N
_VFF_NEARNESS_GAIN = 6.0  # obstacle nearness = min(1, this / |repulsive resultant|)
_VFF_MAX_REPULSION = 1e6  # per-path force cap (1/obs for obs -> 0)
_VFF_MIN_OBSTACLE = 1.0 / _VFF_MAX_REPULSION  # 1/this == 1e6 exactly, and 1/obs <= 1e6 for obs >= this


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
        push = 1.0 / np.maximum(inp.obstacles, _VFF_MIN_OBSTACLE)  # min(1e6, 1/obs) to the bit, without 1/0
        scale = -_VFF_OBSTACLE_GAIN / n
        rx, ry = scale * float(cos_k.dot(push)), scale * float(sin_k.dot(push))
        repulsion = math.hypot(rx, ry)
        obstacle_nearness = 1.0 if repulsion == 0 else min(1.0, _VFF_NEARNESS_GAIN / repulsion)
        ax = cfg.target_attractive_force * math.cos(inp.target_alpha_rad)
        ay = cfg.target_attractive_force * math.sin(inp.target_alpha_rad)
        fx, fy = rx + ax, ry + ay
        alpha = 0.0 if fx == 0 and fy == 0 else math.atan2(fy, fx)
        target_nearness = inp.target_nearness(cfg.target_slow_approaching_distance_m)
        speed = inp.max_robot_speed * min(obstacle_nearness, target_nearness)
        info = VFFInfo((rx, ry), (ax, ay), obstacle_nearness, target_nearness)
        return HolonomicOutput(_path_index(alpha, n), alpha, speed, "FORCE_FIELD", info)


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
