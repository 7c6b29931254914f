"""Hinged door leaves that open and close on a schedule and open early for someone waiting nearby.

World frame, x/y on the floor, SI units. The leaf is a segment from the hinge to its tip; its direction is
``yaw = closed_yaw + opening·swing`` with ``opening`` 0 (closed, across the doorway) .. 1 (open). Swings
follow a cosine ramp, so the leaf starts and stops smoothly.

Schedule, repeating: open for ``open_s``, swing closed over ``move_s``, closed for ``closed_s``, swing open
over ``move_s``. At t = 0 the leaf is ``phase_s`` seconds into that cycle (``phase_s = 0``: just opened).
Whenever a point of ``nearby_xy`` lies within ``auto_open_radius_m`` of the doorway centre, a closing or
closed leaf swings open again from where it is, and an open leaf keeps its open timer at zero, so it closes
only once nobody has been near for ``open_s``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
        self._hinge_xy = (float(self._hinge[0]), float(self._hinge[1]))
        self._center_xy = (float(self._center[0]), float(self._center[1]))
        self._durations = (spec.open_s, spec.move_s, spec.closed_s, spec.move_s)
        self._stage, self._elapsed_s = self._stage_at(spec.phase_s % sum(self._durations))
        self._opening = self._opening_now()
        self._yaw_rate_rad_s = 0.0
        self._time_s = 0.0

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
        return self._opening

    @property
    def stage(self) -> DoorStage:
        """Current stage of the cycle."""
        return self._stage

    @property
    def yaw_rad(self) -> float:
        """Direction of the leaf from the hinge (world frame), rad."""
        return self._closed_yaw_rad + self._opening * self._swing_rad

    @property
    def yaw_rate_rad_s(self) -> float:
        """Yaw change of the last update divided by its ``dt_s``, rad/s."""
        return self._yaw_rate_rad_s

    @property
    def time_s(self) -> float:
        """The ``t_s`` of the last update, seconds."""
        return self._time_s

    def segment_xy(self) -> np.ndarray:
        """(2, 2) leaf segment ``[hinge, tip]``, metres."""
        return np.array(self._segment())

    def _segment(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((hinge x, y), (tip x, y))``, metres, as python floats."""
        yaw, width = self.yaw_rad, self._spec.width_m
        hx, hy = self._hinge_xy
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
        yaw_before = self.yaw_rad
        near = self._someone_near(nearby_xy)
        if near:
            self._hold_open()
        held = (self._stage, self._elapsed_s)
        self._elapsed_s += dt_s
        self._advance(near)
        opening = self._opening_now()
        if opening != self._opening and self._sweeps_into(self._opening, opening, blockers_xyr):
            self._stage, self._elapsed_s = held  # the presence sensor pauses the leaf
        else:
            self._opening = opening
        self._yaw_rate_rad_s = (self.yaw_rad - yaw_before) / dt_s if dt_s > 0 else 0.0
        self._time_s = t_s

    def _someone_near(self, nearby_xy: np.ndarray | None) -> bool:
        if nearby_xy is None or len(nearby_xy) == 0:
            return False
        points = np.ascontiguousarray(nearby_xy, dtype=float).reshape(-1, 2)
        return _any_within(points, self._center_xy[0], self._center_xy[1], self._spec.auto_open_radius_m)

    def _sweeps_into(self, opening_before: float, opening_after: float, blockers_xyr: np.ndarray | None) -> bool:
        """Whether moving the leaf between the two openings brings it within the safety clearance of a blocker
        and closer to it than before."""
        if blockers_xyr is None or len(blockers_xyr) == 0:
            return False
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

    def _hold_open(self) -> None:
        if self._stage == DoorStage.OPEN:
            self._elapsed_s = 0.0
        elif self._stage in (DoorStage.CLOSING, DoorStage.CLOSED):
            reached = 0.0 if self._stage == DoorStage.CLOSED else self._opening
            self._stage = DoorStage.OPENING
            cos_phase = min(max(1.0 - 2.0 * reached, -1.0), 1.0)  # inverse of the cosine ramp
            self._elapsed_s = self._spec.move_s * math.acos(cos_phase) / math.pi

    def _advance(self, near: bool) -> None:
        while self._elapsed_s >= self._durations[self._stage]:
            if self._stage == DoorStage.OPEN and near:
                self._elapsed_s = 0.0
                return
            self._elapsed_s -= self._durations[self._stage]
            self._stage = DoorStage((self._stage + 1) % 4)

    def _stage_at(self, cycle_s: float) -> tuple[DoorStage, float]:
        start = 0.0
        for stage in DoorStage:
            if cycle_s < start + self._durations[stage]:
                return stage, cycle_s - start
            start += self._durations[stage]
        return DoorStage.OPEN, 0.0

    def _opening_now(self) -> float:
        ramp = 0.5 * (1.0 - math.cos(math.pi * min(self._elapsed_s / self._spec.move_s, 1.0)))
        if self._stage == DoorStage.CLOSING:
            return 1.0 - ramp
        if self._stage == DoorStage.OPENING:
            return ramp
        return 1.0 if self._stage == DoorStage.OPEN else 0.0


def door_segments(leaves: Sequence[DoorLeaf]) -> np.ndarray:
    """(D, 2, 2) segments ``[hinge, tip]`` of the leaves, metres (shape (0, 2, 2) for none)."""
    if not leaves:
        return np.zeros((0, 2, 2))
    return np.array([leaf._segment() for leaf in leaves])


@njit(cache=True)
def _any_within(points: np.ndarray, cx: float, cy: float, radius_m: float) -> bool:
    """Whether a point of (P, 2) ``points`` lies within ``radius_m`` of (cx, cy) (all metres)."""
    for k in range(points.shape[0]):
        dx, dy = points[k, 0] - cx, points[k, 1] - cy
        if math.sqrt(dx * dx + dy * dy) <= radius_m:
            return True
    return False
