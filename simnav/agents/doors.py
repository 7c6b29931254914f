"""Hinged door leaves that open and close on a schedule and open early for someone waiting nearby.

World frame, x/y on the floor, SI units. The leaf is a segment from the hinge to its tip; its direction is
``yaw = closed_yaw + opening·swing`` with ``opening`` 0 (closed, across the doorway) .. 1 (open). Swings
follow a cosine ramp, so the leaf starts and stops smoothly.

Schedule, repeating: open for ``open_s``, swing closed over ``move_s``, closed for ``closed_s``, swing open
over ``move_s``. At t = 0 the leaf is ``phase_s`` seconds into that cycle (``phase_s = 0``: just opened).
Whenever a point of ``nearby_xy`` lies within ``auto_open_radius_m`` of the doorway centre, a closing or
closed leaf swings open again from where it is, and an open leaf keeps its open timer at zero, so it closes
only once nobody has been near for ``open_s``.

The leaves of a world update together (:class:`DoorLeaves`, one compiled pass); a :class:`DoorLeaf` keeps its
state in one row of their arrays, or in arrays of its own when made alone.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

if TYPE_CHECKING:
    from simnav.world.schema import Door


class DoorStage(IntEnum):
    """Stages of the door cycle, in schedule order."""

    OPEN = 0
    CLOSING = 1
    CLOSED = 2
    OPENING = 3


# columns of a leaf's parameters: hinge, doorway centre, closed yaw and swing (rad), width, thickness, auto-open
# radius, safety clearance (m), swing time (s), then the durations of the four stages in DoorStage order (s)
_HX, _HY, _CX, _CY, _CLOSED, _SWING, _WIDTH, _THICK, _RADIUS, _CLEARANCE, _MOVE, _DURATIONS = range(12)
_N_PARAMS = _DURATIONS + 4
# columns of a leaf's state: stage, time in it (s), opening, yaw (rad), yaw rate (rad/s), last update time (s)
_STAGE, _ELAPSED, _OPENING, _YAW, _YAW_RATE, _TIME = range(6)
_N_STATE = 6
_ST_OPEN, _ST_CLOSING, _ST_CLOSED, _ST_OPENING = (int(stage) for stage in DoorStage)  # stages in compiled code
# what the presence sensor says of a swing: decide it (in), free, blocked, or too close to call (out)
_DECIDE, _FREE, _BLOCKED, _UNSURE = -1, 0, 1, 2
_SURE_M = 1e-9  # clearances computed here may differ from the reference formula's by this much at most


class DoorLeaf:
    """One door leaf driven by its schedule and by people or robots waiting nearby.

    Args:
        spec: the door of the world file (:class:`simnav.world.schema.Door`).
    """

    def __init__(self, spec: Door) -> None:
        self._spec = spec
        self._hinge = np.array(spec.hinge, dtype=float)
        self._closed_yaw_rad = math.radians(spec.closed_yaw_deg)
        self._swing_rad = math.radians(spec.swing_deg)
        across = np.array([math.cos(self._closed_yaw_rad), math.sin(self._closed_yaw_rad)])
        self._center = self._hinge + 0.5 * spec.width_m * across
        durations = (spec.open_s, spec.move_s, spec.closed_s, spec.move_s)
        params = np.array([[*self._hinge, *self._center, self._closed_yaw_rad, self._swing_rad, spec.width_m,
                            spec.thickness_m, spec.auto_open_radius_m, spec.safety_clearance_m, spec.move_s,
                            *durations]])
        stage, elapsed = _stage_at(durations, spec.phase_s % sum(durations))
        opening = _opening(params[0], int(stage), elapsed)
        yaw = self._closed_yaw_rad + opening * self._swing_rad
        self._bind(params, np.array([[stage, elapsed, opening, yaw, 0.0, 0.0]]))

    def _bind(self, params: np.ndarray, state: np.ndarray) -> None:
        """Keep the parameters and state in (1, ·) rows (views into the arrays of a :class:`DoorLeaves`)."""
        self._params, self._state, self._row = params, state, state[0]

    @property
    def spec(self) -> Door:
        """The door description this leaf was built from."""
        return self._spec

    @property
    def hinge_xy(self) -> np.ndarray:
        """(2,) hinge position, metres."""
        return self._hinge.copy()

    @property
    def center_xy(self) -> np.ndarray:
        """(2,) doorway centre (hinge + width/2 along the closed direction), metres."""
        return self._center.copy()

    @property
    def opening(self) -> float:
        """0 (closed) .. 1 (open)."""
        return float(self._row[_OPENING])

    @property
    def stage(self) -> DoorStage:
        """Current stage of the cycle."""
        return DoorStage(int(self._row[_STAGE]))

    @property
    def yaw_rad(self) -> float:
        """Direction of the leaf from the hinge (world frame), rad."""
        return float(self._row[_YAW])

    @property
    def yaw_rate_rad_s(self) -> float:
        """Yaw change of the last update divided by its ``dt_s``, rad/s."""
        return float(self._row[_YAW_RATE])

    @property
    def time_s(self) -> float:
        """The ``t_s`` of the last update, seconds."""
        return float(self._row[_TIME])

    def segment_xy(self) -> np.ndarray:
        """(2, 2) leaf segment ``[hinge, tip]``, metres."""
        return np.array(self._segment())

    def _segment(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((hinge x, y), (tip x, y))``, metres, as python floats."""
        yaw, width = self.yaw_rad, self._spec.width_m
        hx, hy = float(self._hinge[0]), float(self._hinge[1])
        return (hx, hy), (hx + width * math.cos(yaw), hy + width * math.sin(yaw))

    def update(self, t_s: float, dt_s: float, nearby_xy: np.ndarray | None = None,
               blockers_xyr: np.ndarray | None = None) -> None:
        """Advance the leaf by ``dt_s`` to time ``t_s``.

        Args:
            t_s: simulated time after this update, seconds.
            dt_s: time since the previous update, seconds (>= 0).
            nearby_xy: (P, 2) positions of people and robots (metres) that may open the door, or None.
            blockers_xyr: (B, 3) circles ``[x, y, radius]`` (metres) the moving leaf must not sweep into (people,
                robots), or None.
        """
        _update([self], self._params, self._state, t_s, dt_s, nearby_xy, blockers_xyr)

    def _sweeps_into(self, opening_before: float, opening_after: float, blockers_xyr: np.ndarray) -> bool:
        """Whether moving the leaf between the two openings brings it within the safety clearance of a blocker
        and closer to it than before (the reference formula, with numpy)."""
        c = np.asarray(blockers_xyr, dtype=float).reshape(-1, 3)
        before = self._clearance_m(opening_before, c)
        after = self._clearance_m(opening_after, c)
        return bool(np.any((after < self._spec.safety_clearance_m) & (after < before)))

    def _clearance_m(self, opening: float, circles: np.ndarray) -> np.ndarray:
        """(B,) gap between the leaf at ``opening`` (its thickness included) and each circle, metres."""
        yaw = self._closed_yaw_rad + opening * self._swing_rad
        u = np.array([math.cos(yaw), math.sin(yaw)])
        rel = circles[:, :2] - self._hinge
        along = np.clip(rel @ u, 0.0, self._spec.width_m)
        dist = np.linalg.norm(rel - along[:, None] * u, axis=1)
        return dist - circles[:, 2] - 0.5 * self._spec.thickness_m


class DoorLeaves(Sequence[DoorLeaf]):
    """The door leaves of a world, updated together in one compiled pass.

    A sequence of :class:`DoorLeaf` (in ``specs`` order) whose :meth:`update` advances them all as each one's
    :meth:`DoorLeaf.update` would.

    Args:
        specs: the doors of the world file.
    """

    def __init__(self, specs: Sequence[Door]) -> None:
        self._leaves = [DoorLeaf(spec) for spec in specs]
        self._params = np.zeros((len(specs), _N_PARAMS))
        self._state = np.zeros((len(specs), _N_STATE))
        for k, leaf in enumerate(self._leaves):
            self._params[k], self._state[k] = leaf._params[0], leaf._state[0]
            leaf._bind(self._params[k:k + 1], self._state[k:k + 1])

    def __len__(self) -> int:
        return len(self._leaves)

    def __getitem__(self, k: int) -> DoorLeaf:
        return self._leaves[k]

    def __iter__(self) -> Iterator[DoorLeaf]:
        return iter(self._leaves)

    @property
    def yaws_rad(self) -> np.ndarray:
        """(D,) directions of the leaves from their hinges (world frame), rad (read-only; :meth:`update` changes it
        in place)."""
        return _read_only(self._state[:, _YAW])

    @property
    def yaw_rates_rad_s(self) -> np.ndarray:
        """(D,) yaw rates of the last update, rad/s (read-only; :meth:`update` changes it in place)."""
        return _read_only(self._state[:, _YAW_RATE])

    def update(self, t_s: float, dt_s: float, nearby_xy: np.ndarray | None = None,
               blockers_xyr: np.ndarray | None = None) -> None:
        """Advance every leaf by ``dt_s`` to time ``t_s`` (arguments as in :meth:`DoorLeaf.update`)."""
        _update(self._leaves, self._params, self._state, t_s, dt_s, nearby_xy, blockers_xyr)

    def segments_xy(self) -> np.ndarray:
        """(D, 2, 2) segments ``[hinge, tip]`` of the leaves, metres (a new array)."""
        out = np.empty((len(self._leaves), 2, 2))
        _segments(self._params, self._state, out)
        return out


def door_segments(leaves: Sequence[DoorLeaf]) -> np.ndarray:
    """(D, 2, 2) segments ``[hinge, tip]`` of the leaves, metres (shape (0, 2, 2) for none)."""
    if not leaves:
        return np.zeros((0, 2, 2))
    return np.array([leaf._segment() for leaf in leaves])


def _update(leaves: Sequence[DoorLeaf], params: np.ndarray, state: np.ndarray, t_s: float, dt_s: float,
            nearby_xy: np.ndarray | None, blockers_xyr: np.ndarray | None) -> None:
    """Advance the leaves whose (D, ·) parameters and state these are (see :func:`_update_leaves`)."""
    nearby = _points(nearby_xy, 2)
    blockers = _points(blockers_xyr, 3)
    verdicts = np.empty(len(leaves), dtype=np.int64)
    verdicts.fill(_DECIDE)
    proposals = np.empty(len(leaves))
    if not _update_leaves(params, state, t_s, dt_s, nearby, blockers, verdicts, proposals):
        return
    # swings too close to call: the reference formula decides, then those leaves update with its verdict
    for k in np.flatnonzero(verdicts == _UNSURE):
        leaf = leaves[k]
        verdicts[k] = _BLOCKED if leaf._sweeps_into(leaf.opening, float(proposals[k]), blockers) else _FREE
        _update_leaves(params[k:k + 1], state[k:k + 1], t_s, dt_s, nearby, blockers, verdicts[k:k + 1],
                       proposals[k:k + 1])


def _read_only(view: np.ndarray) -> np.ndarray:
    """``view``, made read-only."""
    view.flags.writeable = False
    return view


def _points(points: np.ndarray | None, width: int) -> np.ndarray:
    """(N, width) C-contiguous float64 copy or view of ``points`` ((0, width) for None)."""
    if points is None:
        return np.zeros((0, width))
    if (type(points) is np.ndarray and points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == width
            and points.flags.c_contiguous):
        return points
    return np.ascontiguousarray(points, dtype=float).reshape(-1, width)


def _stage_at(durations: tuple[float, float, float, float], cycle_s: float) -> tuple[DoorStage, float]:
    """The stage and the time spent in it ``cycle_s`` seconds into the cycle."""
    start = 0.0
    for stage in DoorStage:
        if cycle_s < start + durations[stage]:
            return stage, cycle_s - start
        start += durations[stage]
    return DoorStage.OPEN, 0.0


@njit(cache=True, error_model="numpy")
def _update_leaves(params: np.ndarray, state: np.ndarray, t_s: float, dt_s: float, nearby: np.ndarray,
                   blockers: np.ndarray, verdicts: np.ndarray, proposals: np.ndarray) -> int:
    """Advance each leaf of the (D, _N_PARAMS) ``params`` and (D, _N_STATE) ``state`` by ``dt_s`` to ``t_s``.

    ``nearby`` (P, 2) points may open a leaf; a swing must not sweep into the (B, 3) ``blockers`` circles (all
    metres). ``verdicts`` (D,) on a swing: _DECIDE (computed here), _FREE or _BLOCKED (given). A leaf whose swing
    is too close to call here keeps its state and gets _UNSURE, with the opening it would reach in ``proposals``.

    Returns:
        The number of leaves left _UNSURE.
    """
    unsure = 0
    for k in range(params.shape[0]):
        p, s = params[k], state[k]
        near = _any_within(nearby, p[_CX], p[_CY], p[_RADIUS])
        stage, elapsed = int(s[_STAGE]), s[_ELAPSED]
        if near:
            stage, elapsed = _hold_open(p, stage, elapsed, s[_OPENING])
        held_stage, held_elapsed = stage, elapsed
        stage, elapsed = _advance(p, stage, elapsed + dt_s, near)
        opening = _opening(p, stage, elapsed)
        # the presence sensor pauses a leaf that would sweep into someone
        if opening != s[_OPENING]:
            verdict = verdicts[k]
            if verdict == _DECIDE:
                verdict = _sweep_verdict(p, s[_OPENING], opening, blockers)
            if verdict == _UNSURE:
                verdicts[k], proposals[k] = _UNSURE, opening
                unsure += 1
                continue
            if verdict == _BLOCKED:
                stage, elapsed, opening = held_stage, held_elapsed, s[_OPENING]
        yaw = p[_CLOSED] + opening * p[_SWING]
        s[_YAW_RATE] = (yaw - s[_YAW]) / dt_s if dt_s > 0 else 0.0
        s[_STAGE], s[_ELAPSED], s[_OPENING], s[_YAW], s[_TIME] = stage, elapsed, opening, yaw, t_s
    return unsure


@njit(cache=True, error_model="numpy")
def _hold_open(p: np.ndarray, stage: int, elapsed: float, opening: float) -> tuple[int, float]:
    """Someone is near: an open leaf restarts its open time, a closing or closed one swings open from where it is."""
    if stage == _ST_OPEN:
        return stage, 0.0
    if stage == _ST_CLOSING or stage == _ST_CLOSED:
        reached = 0.0 if stage == _ST_CLOSED else opening
        cos_phase = min(max(1.0 - 2.0 * reached, -1.0), 1.0)  # inverse of the cosine ramp
        return _ST_OPENING, p[_MOVE] * math.acos(cos_phase) / math.pi
    return stage, elapsed


@njit(cache=True, error_model="numpy")
def _advance(p: np.ndarray, stage: int, elapsed: float, near: bool) -> tuple[int, float]:
    """The stage and its elapsed time (s) once the stages ``elapsed`` has outlasted are over."""
    while elapsed >= p[_DURATIONS + stage]:
        if stage == _ST_OPEN and near:
            return stage, 0.0
        elapsed -= p[_DURATIONS + stage]
        stage = (stage + 1) % 4
    return stage, elapsed


@njit(cache=True, error_model="numpy")
def _opening(p: np.ndarray, stage: int, elapsed: float) -> float:
    """Opening of the leaf ``elapsed`` seconds into ``stage`` (the cosine ramp while it swings)."""
    ramp = 0.5 * (1.0 - math.cos(math.pi * min(elapsed / p[_MOVE], 1.0)))
    if stage == _ST_CLOSING:
        return 1.0 - ramp
    if stage == _ST_OPENING:
        return ramp
    return 1.0 if stage == _ST_OPEN else 0.0


@njit(cache=True, error_model="numpy")
def _sweep_verdict(p: np.ndarray, opening_before: float, opening_after: float, blockers: np.ndarray) -> int:
    """_BLOCKED when the swing brings the leaf within the safety clearance of a (B, 3) blocker and closer to it than
    before, else _FREE; _UNSURE when a comparison lies within the rounding difference of the reference formula
    (:meth:`DoorLeaf._sweeps_into`, whose projection is a BLAS product) of flipping."""
    unsure = False
    for i in range(blockers.shape[0]):
        after = _clearance(p, opening_after, blockers[i])
        before = _clearance(p, opening_before, blockers[i])
        if after + _SURE_M < p[_CLEARANCE] and after + _SURE_M < before - _SURE_M:
            return _BLOCKED
        if not (after - _SURE_M >= p[_CLEARANCE] or after - _SURE_M >= before + _SURE_M):
            unsure = True
    return _UNSURE if unsure else _FREE


@njit(cache=True, error_model="numpy")
def _clearance(p: np.ndarray, opening: float, circle: np.ndarray) -> float:
    """Gap between the leaf at ``opening`` (its thickness included) and a circle ``[x, y, radius]``, metres."""
    yaw = p[_CLOSED] + opening * p[_SWING]
    ux, uy = math.cos(yaw), math.sin(yaw)
    rx, ry = circle[0] - p[_HX], circle[1] - p[_HY]
    along = min(max(rx * ux + ry * uy, 0.0), p[_WIDTH])
    dx, dy = rx - along * ux, ry - along * uy
    return math.sqrt(dx * dx + dy * dy) - circle[2] - 0.5 * p[_THICK]


@njit(cache=True, error_model="numpy")
def _segments(params: np.ndarray, state: np.ndarray, out: np.ndarray) -> None:
    """Write the (D, 2, 2) segments ``[hinge, tip]`` (metres) of the leaves into ``out``."""
    for k in range(params.shape[0]):
        p, yaw = params[k], state[k, _YAW]
        out[k, 0, 0], out[k, 0, 1] = p[_HX], p[_HY]
        out[k, 1, 0], out[k, 1, 1] = p[_HX] + p[_WIDTH] * math.cos(yaw), p[_HY] + p[_WIDTH] * math.sin(yaw)


@njit(cache=True, error_model="numpy")
def _any_within(points: np.ndarray, cx: float, cy: float, radius_m: float) -> bool:
    """Whether a point of (P, 2) ``points`` lies within ``radius_m`` of (cx, cy) (all metres)."""
    for k in range(points.shape[0]):
        dx, dy = points[k, 0] - cx, points[k, 1] - cy
        if math.sqrt(dx * dx + dy * dy) <= radius_m:
            return True
    return False
