"""The fused Numba steps of the crowd and the wandering robots give the numpy formulation's states.

The kernels take exponentials and angles with libm's ``exp`` and ``atan2`` inside them, where numpy's vectorised
ones differ in the last bit for a few per cent of arguments; the crowd's dynamics carry such differences up to
metres within a minute, so each step of the reference starts from the kernel's state, and one step at a time is
compared: discrete state exactly, continuous state within rounding.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.agents import Crowd, RoadmapGraph, Wanderers
from simnav.agents import crowd as crowd_module
from simnav.agents import wanderers as wanderers_module
from simnav.agents.crowd import SegmentGrid, _visible, grid_lists_reference, wrap_angle
from simnav.agents.kernels import _desired_update, closest_in_way, crowd_advance, grid_lists
from simnav.agents.social_force import (
    Segments,
    all_pairs,
    integrate,
    resolve_overlaps_pairs_reference,
    social_force_pairs_reference,
)
from tests.agents.test_crowd import DOORWAY_EDGES as EDGES
from tests.agents.test_crowd import DOORWAY_NODES as NODES
from tests.agents.test_crowd import DOORWAY_WALLS as WALLS


class ReferenceCrowd(Crowd):
    """:class:`Crowd` stepped with the numpy formulation (the kernels' reference): plans, social forces, the
    projection, yaws, face-offs and stuck pedestrians as array operations."""

    def step(self, dt_s, dynamic_segments=None, circles=None, circle_velocities=None) -> None:
        self._time_s += dt_s
        if circles is not None and len(circles):  # personal space around robots
            circles = np.asarray(circles, dtype=float).reshape(-1, 3) + [0.0, 0.0, self._params.circle_clearance_m]
        self._reference_plans(dt_s, circles)
        standing = self._standing(dt_s, np.zeros((0, 3)) if circles is None else circles)
        drive = _desired_update(self._dirs, self._target, self._pos, self._yield_s, self._yield_dir, self._speeds,
                                standing, crowd_module.YIELD_SPEED_FACTOR)
        segs, ped, seg = self._reference_pairs(self._pos, dynamic_segments)
        acc = social_force_pairs_reference(self._pos, self._vel, self._dirs, drive, segs, ped, seg, circles,
                                           circle_velocities, self._params)
        moved, _ = integrate(self._pos, self._vel, acc, self._speeds, dt_s, self._params)
        if len(moved) and np.max(np.linalg.norm(moved - self._pos, axis=1)) > 0.5:  # the move 2.25 m cover
            segs, ped, seg = self._reference_pairs(moved, dynamic_segments)
        resolved = resolve_overlaps_pairs_reference(moved, self.radius_m, segs, ped, seg, circles,
                                                    crowd_module.PROJECTION_SWEEPS, self._pos, seg < len(self._walls))
        self._vel = (resolved - self._pos) / dt_s
        self._pos = resolved
        self._reference_yaws(dt_s)
        self._reference_blocking(dt_s, circles, segs, standing)
        self._reference_stuck(segs, standing, circles)

    def _reference_pairs(self, points, dynamic_segments):
        segs = self._walls
        ped, seg = SegmentGrid(segs, 2.25).pairs(points)
        if dynamic_segments is None or len(dynamic_segments) == 0:
            return self._walls, ped, seg
        dyn = np.asarray(dynamic_segments, dtype=float).reshape(-1, 2, 2)
        dyn_ped, dyn_seg = all_pairs(len(points), len(dyn))
        return self._walls.extended(dyn), np.concatenate([ped, dyn_ped]), np.concatenate([seg, dyn_seg + len(segs)])

    def _reference_plans(self, dt_s, circles):
        self._pause_s[self._arrived] -= dt_s
        for k in np.nonzero(self._arrived & (self._pause_s <= 0.0))[0]:
            self._plan(int(k), int(self._goals[k]))
        last = self._wp == self._last_wp
        dist = np.linalg.norm(self._target - self._pos, axis=1)
        extra = np.zeros(len(self._pos))
        if circles is not None and len(circles):
            c, r = np.asarray(circles, dtype=float).reshape(-1, 3), self.radius_m
            gap = np.linalg.norm(self._target[:, None] - c[None, :, :2], axis=2) - c[:, 2] - r
            extra = np.max(np.where(gap < crowd_module.OCCUPIED_MARGIN_M, c[:, 2] + r, 0.0), axis=1)
        reach = np.where(last, crowd_module.GOAL_REACHED_M, crowd_module.WAYPOINT_REACHED_M)
        for k in np.nonzero(~self._arrived & (dist < reach + extra))[0]:
            # the robot's extra counts only when the waypoint after the target is in sight (or it is the goal)
            next_xy = self._path_xy[k, min(self._wp[k] + 1, self._last_wp[k])]
            if dist[k] >= reach[k] and not last[k] and not _visible(self._pos[k], next_xy, self._walls):
                continue
            self._advance(int(k))

    def _reference_yaws(self, dt_s):
        speed = np.linalg.norm(self._vel, axis=1)
        error = wrap_angle(np.arctan2(self._vel[:, 1], self._vel[:, 0]) - self._yaw)
        gain = min(1.0, dt_s / crowd_module.YAW_TIME_CONSTANT_S) / dt_s
        rate = np.clip(error * gain, -crowd_module.MAX_YAW_RATE_RAD_S, crowd_module.MAX_YAW_RATE_RAD_S)
        rate[speed <= crowd_module.MOVING_SPEED_M_S] = 0.0
        self._yaw = wrap_angle(self._yaw + rate * dt_s)
        self._yaw_rate = rate

    def _reference_blocking(self, dt_s, circles, walls, standing):
        self._yield_s = np.maximum(self._yield_s - dt_s, 0.0)
        n, c = len(self._pos), np.zeros((0, 3)) if circles is None else np.asarray(circles, dtype=float)
        if n == 0 or n + len(c) < 2:
            return
        others = np.concatenate([self._pos, c[:, :2]])
        reach = np.concatenate([np.full(n, 1.0), 1.0 + c[:, 2] - self.radius_m])
        in_way, blocker = closest_in_way(self._pos, self._dirs, others, reach, math.cos(math.radians(60.0)))
        slow = np.linalg.norm(self._vel, axis=1) < crowd_module.BLOCKED_SPEED_M_S
        blocked = slow & ~standing & (self._yield_s <= 0.0) & in_way
        self._blocked_s = np.where(blocked, self._blocked_s + dt_s, 0.0)
        outranked = self._priority < np.concatenate([self._priority, np.full(len(c), np.inf)])[blocker]
        for k in np.nonzero((self._blocked_s >= 1.5) & outranked | (self._blocked_s >= 4.0))[0]:
            by_robot = blocker[k] >= n
            if by_robot and self._time_s - self._robot_yield_t[k] <= crowd_module.ROBOT_GIVE_UP_S:
                # held up by a robot again soon after stepping aside: gives up, keeps clear of it for a while
                self._give_up_on_robot(int(k), c[blocker[k] - n], walls)
            else:
                self._step_back(int(k), int(blocker[k]), c)
            if by_robot:
                self._robot_yield_t[k] = self._time_s

    def _reference_stuck(self, walls, standing, circles):
        closer = (np.linalg.norm(self._anchor_xy - self._target, axis=1)
                  - np.linalg.norm(self._pos - self._target, axis=1))
        new_target = np.any(self._target != self._anchor_goal, axis=1)
        reset = (closer >= crowd_module.STUCK_PROGRESS_M) | new_target | standing
        self._anchor_xy[reset] = self._pos[reset]
        self._anchor_goal[reset] = self._target[reset]
        self._anchor_t[reset] = self._time_s
        c = np.zeros((0, 3)) if circles is None else np.asarray(circles, dtype=float)
        for k in np.nonzero(self._time_s - self._anchor_t >= crowd_module.STUCK_TIME_S)[0]:
            gaps = np.linalg.norm(c[:, :2] - self._pos[k], axis=1) - c[:, 2] - self.radius_m
            if len(c) and gaps.min() <= crowd_module.ROBOT_PASSING_GAP_M:  # pinned beside a robot: gives up on it
                self._give_up_on_robot(int(k), c[int(np.argmin(gaps))], walls)
            else:
                self._replan_stuck(int(k), walls)


def _discrete_state(crowd: Crowd) -> list[np.ndarray]:
    rng_state = crowd._rng.bit_generator.state["state"]["state"]
    return [crowd.goals, crowd.waypoints_xy, crowd._wp, crowd._arrived, np.array([rng_state % 2**62])]


def _continuous_state(crowd: Crowd) -> list[np.ndarray]:
    return [crowd.positions_xy, crowd.velocities_xy, crowd.yaws_rad, crowd.yaw_rates_rad_s, crowd._dirs,
            crowd._yield_s, crowd._blocked_s, crowd._anchor_t, crowd._pause_s]


def _continue_from(reference: Crowd | Wanderers, agents: Crowd | Wanderers) -> None:
    """``reference`` takes over every array, the time and the random generator's state of ``agents``."""
    for name, value in vars(agents).items():
        if isinstance(value, np.ndarray):
            setattr(reference, name, value.copy())
    if isinstance(agents, Crowd):
        reference._time_s = agents._time_s
    reference._rng.bit_generator.state = agents._rng.bit_generator.state


@pytest.mark.parametrize(("count", "seed", "wait_s"), [(8, 0, 0.0), (24, 1, 0.0), (24, 1, 20.0)])
def test_crowd_step_matches_the_numpy_formulation(count: int, seed: int, wait_s: float) -> None:
    roadmap = RoadmapGraph(NODES, EDGES)
    crowd, reference = (cls(roadmap, WALLS, count, np.random.default_rng(seed), single_file_wait_s=wait_s)
                        for cls in (Crowd, ReferenceCrowd))
    hinge = np.array([7.5, 2.0])
    for k in range(500):
        t = 0.1 * k
        leaf = np.array([[hinge, hinge + 0.9 * np.array([math.cos(0.4 * t), math.sin(0.4 * t)])]])
        # a robot dwelling in the doorway (face-offs, people stuck behind it), then roaming the left room
        robot = np.array([[5.0 + 0.2 * math.sin(0.1 * t), 2.0, 0.35] if t < 25.0 else
                          [2.5 + 1.5 * math.sin(0.3 * t), 2.0 + math.sin(0.2 * t), 0.3]])
        robot_vel = np.array([[0.02 * math.cos(0.1 * t), 0.0] if t < 25.0 else
                              [0.45 * math.cos(0.3 * t), 0.2 * math.cos(0.2 * t)]])
        dt = 0.6 if k % 40 == 5 else 0.3 if k % 40 == 6 else 0.1  # long steps: candidates beyond the near grid
        args = (dt, None, None, None) if k % 25 == 3 else (dt, leaf, robot, None if k % 7 == 0 else robot_vel)
        _continue_from(reference, crowd)
        crowd.step(*args)
        reference.step(*args)
        for got, expected in zip(_discrete_state(crowd), _discrete_state(reference), strict=True):
            np.testing.assert_array_equal(got, expected, err_msg=f"step {k}")
        # one step apart from the reference by the last bits of exp and atan2 (velocities: over dt)
        for got, expected in zip(_continuous_state(crowd), _continuous_state(reference), strict=True):
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12, err_msg=f"step {k}")


@pytest.mark.parametrize(("next_x", "expected_wp"), [(1.5, 1), (np.nextafter(1.5, 0.0), 2)])
def test_a_waypoint_at_the_reach_within_rounding_is_settled_with_numpy(next_x: float, expected_wp: int) -> None:
    # a pedestrian at its waypoint; the next one lies 0.5 m away (the reach) or one ulp less, the last one far
    path = np.array([[1.0, 1.0], [next_x, 1.0], [5.0, 1.0]])
    roadmap = RoadmapGraph(path, [(0, 1), (1, 2)])
    crowds = [cls(roadmap, np.zeros((0, 2, 2)), 1, np.random.default_rng(0)) for cls in (Crowd, ReferenceCrowd)]
    for c in crowds:
        c._pos = path[:1].copy()
        c._path_xy[0, :3] = path
        c._wp[0], c._last_wp[0], c._arrived[0] = 0, 2, False
        c._set_target(0)
    plans = (crowds[0]._pos, crowds[0]._target.copy(), crowds[0]._path_xy, crowds[0]._wp.copy(), crowds[0]._last_wp)
    walls = (crowds[0]._walls.start, crowds[0]._walls.delta)
    events = crowd_advance(crowds[0]._arrived.copy(), plans, np.zeros((0, 3)), crowds[0]._limits, walls)
    np.testing.assert_array_equal(events, [[0, 1]])  # the kernel leaves it to numpy's norm
    crowds[0]._update_plans(0.1, np.zeros((0, 3)))
    crowds[1]._reference_plans(0.1, None)
    assert crowds[0]._wp[0] == crowds[1]._wp[0] == expected_wp
    np.testing.assert_array_equal(crowds[0].waypoints_xy, crowds[1].waypoints_xy)


def test_grid_lists_match_numpy() -> None:
    rng = np.random.default_rng(3)
    segs = Segments(rng.uniform(0.0, 8.0, (40, 2, 2)))
    origin, cell_m, shape, reach_m = np.array([-2.5, -1.5]), 0.7, (17, 15), 2.4
    expected = grid_lists_reference(segs, origin, cell_m, shape, reach_m)
    got = grid_lists(origin, cell_m, *shape, segs.start, segs.delta, segs.inv_len2, reach_m)
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a, b)


class ReferenceWanderers(Wanderers):
    """:class:`Wanderers` stepped with the numpy formulation (bearings, blocked times and node updates)."""

    def step(self, dt_s, obstacles_xy=None) -> None:
        to_next = self._roadmap.nodes_xy[self._next] - self._pos
        points = self._pos if obstacles_xy is None else np.concatenate([obstacles_xy, self._pos])
        rel = points[None, :, :] - self._pos[:, None, :]
        heading, bearing = np.arctan2(to_next[:, 1], to_next[:, 0]), np.arctan2(rel[..., 1], rel[..., 0])
        self._yaw, self._yaw_rate, self._vel, self._pos, blocked = wanderers_module._drive(
            self._pos, self._yaw, to_next, heading, rel, bearing, self._speed_m_s, dt_s, min(2.5, 1.0 / dt_s))
        self._blocked_s = np.where(blocked, self._blocked_s + dt_s, 0.0)
        for k in np.nonzero(self._blocked_s >= wanderers_module.BLOCKED_TIMEOUT_S)[0]:
            self._prev[k], self._next[k] = self._next[k], self._prev[k]
            self._blocked_s[k] = 0.0
        dist = np.linalg.norm(self._roadmap.nodes_xy[self._next] - self._pos, axis=1)
        for k in np.nonzero(dist < wanderers_module.NODE_REACHED_M)[0]:
            self._leave_node(int(k))


def test_wanderer_step_matches_the_numpy_formulation() -> None:
    roadmap = RoadmapGraph(NODES, EDGES)
    bots, reference = (cls(roadmap, 3, np.random.default_rng(4)) for cls in (Wanderers, ReferenceWanderers))
    for k in range(1500):
        t = 0.1 * k
        people = np.array([[5.0 + 4.0 * math.sin(0.05 * t), 2.0], [2.0, 2.0 + 1.5 * math.cos(0.07 * t)]])
        obstacles = None if k % 9 == 0 else people
        _continue_from(reference, bots)
        bots.step(0.1, obstacles)
        reference.step(0.1, obstacles)
        for name in ("next_nodes", "previous_nodes"):
            np.testing.assert_array_equal(getattr(bots, name), getattr(reference, name), err_msg=f"{name}, step {k}")
        # one step apart from the reference by the last bits of atan2
        for name in ("positions_xy", "velocities_xy", "yaws_rad", "yaw_rates_rad_s"):
            np.testing.assert_allclose(getattr(bots, name), getattr(reference, name), rtol=1e-12, atol=1e-12,
                                       err_msg=f"{name}, step {k}")


@pytest.mark.parametrize(("jamb", "expected_wp"), [(False, 2), (True, 1)])
def test_a_robot_on_the_next_node_counts_as_passed_only_with_the_node_after_it_in_sight(
        jamb: bool, expected_wp: int) -> None:
    # a person in a doorway (x = 0) heading for the corridor node 1 m ahead, on which a robot stands; the node
    # after it lies down the corridor, behind the doorway's jamb when there is one
    path = np.array([[0.0, 1.5], [0.0, 0.0], [-3.0, 0.0]])
    walls = np.array([[[-2.0, 0.6], [-0.45, 0.6]], [[0.45, 0.6], [2.0, 0.6]]]) if jamb else np.zeros((0, 2, 2))
    crowd = Crowd(RoadmapGraph(path, [(0, 1), (1, 2)]), walls, 1, np.random.default_rng(0))
    crowd._pos = np.array([[0.0, 0.95]])
    crowd._path_xy[0, :3] = path
    crowd._wp[0], crowd._last_wp[0], crowd._arrived[0] = 1, 2, False
    crowd._set_target(0)
    robot = np.array([[0.0, -0.1, 0.3]])
    crowd._update_plans(0.1, robot + [0.0, 0.0, crowd._params.circle_clearance_m])
    assert crowd._wp[0] == expected_wp
