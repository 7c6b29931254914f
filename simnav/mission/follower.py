"""A simple roadmap path follower (no obstacle avoidance): a random walk along roadmap edges."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simnav.agents.roadmap import RoadmapGraph


@dataclass(frozen=True)
class FollowerConfig:
    """Gains and limits of the follower.

    Attributes:
        speed_fraction: cruise speed as a fraction of the robot's max speed.
        heading_gain: yaw-rate gain on the heading error, 1/s.
        turn_in_place_rad: above this heading error the robot turns in place.
        reach_radius_m: a node counts as reached within this distance.
    """

    speed_fraction: float = 0.7
    heading_gain: float = 1.5
    turn_in_place_rad: float = math.radians(50)
    reach_radius_m: float = 0.35


class RoadmapFollower:
    """Random walk on a roadmap: head to a neighbouring node, then to a neighbour of that one (not going back
    unless it is a dead end).

    Args:
        roadmap: the world's roadmap.
        start_xy: (2,) robot position; the walk starts at the nearest node.
        rng: chooses the next node.
        max_v_m_s, max_w_rad_s: the robot's limits.
    """

    def __init__(self, roadmap: RoadmapGraph, start_xy: np.ndarray, rng: np.random.Generator,
                 max_v_m_s: float, max_w_rad_s: float, config: FollowerConfig = FollowerConfig()) -> None:
        self._roadmap, self._rng, self._config = roadmap, rng, config
        self._max_v, self._max_w = max_v_m_s, max_w_rad_s
        self.previous: int | None = None
        self.target = roadmap.nearest_node(np.asarray(start_xy, float))
        self.nodes_reached = 0

    def command(self, x_m: float, y_m: float, yaw_rad: float) -> tuple[float, float]:
        """(v m/s, w rad/s) toward the current target node from the pose (x, y, yaw)."""
        goal = self._roadmap.nodes_xy[self.target]
        if math.hypot(goal[0] - x_m, goal[1] - y_m) < self._config.reach_radius_m:
            self._advance()
            goal = self._roadmap.nodes_xy[self.target]
        error = math.atan2(goal[1] - y_m, goal[0] - x_m) - yaw_rad
        error = math.atan2(math.sin(error), math.cos(error))
        w = float(np.clip(self._config.heading_gain * error, -self._max_w, self._max_w))
        if abs(error) > self._config.turn_in_place_rad:
            return 0.0, w
        v = self._config.speed_fraction * self._max_v * math.cos(error) ** 2
        return v, w

    def _advance(self) -> None:
        self.nodes_reached += 1
        options = self._roadmap.neighbors(self.target)
        forward = [n for n in options if n != self.previous] or options
        self.previous = self.target
        if forward:
            self.target = int(forward[self._rng.integers(len(forward))])
