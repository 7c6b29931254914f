"""A crowd of pedestrians walking between roadmap nodes under the social force model.

Everything is in the world frame (x/y on the floor), SI units. Each pedestrian walks the roadmap's shortest
path to a random goal node, pauses there 0–2 s, then picks the next goal. Velocities are the exact
displacement of the last step divided by the step (``x_{k+1} = x_k + v_{k+1}·dt``), contact pushes included,
so they can serve as ground truth for scene flow.

Two rules keep the crowd moving where the force model alone locks up. Face-offs (two people meeting in a
doorway) end when one of them, the one of lower priority after 1.5 s or either after 4 s, steps back for a
moment. Anybody who comes less than 0.3 m closer to their next waypoint in 10 s re-plans from the nearest
roadmap node in sight to a new goal, preferring one whose route turns back (two people or a person and a robot
facing each other in a hallway too narrow to pass otherwise wait for ever); so does anybody blocked by a robot
again soon after stepping aside for it, or stuck with a robot's rim within ``ROBOT_PASSING_GAP_M`` (pinned beside
it, between it and a wall or a post, out of the way ahead that face-offs look at: people coming out of a doorway
stood in its mouth beside a robot yielding there, and the robot waited for them), and for ``ROBOT_AVOID_S`` after
giving up on a robot they pick only goals whose route keeps clear of where it stood (else they kept coming back to
it: in a flat, every room but the one they turned back into lies past the robot in the hallway). People keep
``circle_clearance_m`` of personal space from a robot (the round obstacles).

People can also wait before a single-file stretch that a robot is in (``single_file_wait_s`` > 0; off by default,
as it did not lower the flat's interventions, see the README): someone about to leave
a roadmap node with room to pass a robot (at least ``SINGLE_FILE_CLEARANCE_M`` from every wall) for one without
(a doorway, a flat's 1 m hallway) stands where they are, at least ``SINGLE_FILE_MARGIN_M`` before it, while a
robot is on their route through the stretch, up to the next node with room; after waiting that long they go
anyway (and do not wait again for ``SINGLE_FILE_COOLDOWN_S``). Without the rule they walk into the hallway
towards a robot coming along it, and neither can pass.
"""

from __future__ import annotations

import functools
import logging
import math

import numpy as np

from simnav.agents.kernels import crowd_advance, crowd_move, crowd_plan_events, grid_lists, grid_pairs
from simnav.agents.roadmap import RoadmapGraph
from simnav.agents.social_force import (
    NEAR_SLACK_M,
    Segments,
    SocialForceParams,
    all_pairs,
    circle_arrays,
    kernel_params,
    wall_reach_m,
)

_LOG = logging.getLogger(__name__)

SPAWN_JITTER_M = 0.3
SPAWN_CLEARANCE_M = 0.05
WAYPOINT_REACHED_M = 0.5
GOAL_REACHED_M = 0.3
MAX_PAUSE_S = 2.0
STUCK_PROGRESS_M = 0.3
STUCK_TIME_S = 10.0
YAW_TIME_CONSTANT_S = 0.25
MAX_YAW_RATE_RAD_S = 4.0
MOVING_SPEED_M_S = 0.1
PROJECTION_SWEEPS = 40
STEP_ALLOWANCE_M = 0.3  # the largest move of a step for which the near grid lists the walls to project out of
BLOCKED_SPEED_M_S = 0.2
BLOCKING_DISTANCE_M = 1.0
BLOCKING_HALF_ANGLE_RAD = math.radians(60.0)
YIELD_AFTER_S = 1.5
FORCE_YIELD_AFTER_S = 4.0
YIELD_DURATION_S = (1.0, 2.5)
YIELD_SPEED_FACTOR = 0.5
ROBOT_PASSING_GAP_M = 0.3
REPLAN_ATTEMPTS = 4
ROBOT_GIVE_UP_S = 8.0
ROBOT_AVOID_S = 20.0  # after giving up on getting past a robot, routes keep clear of where it stood this long
REPLAN_AHEAD_HALF_ANGLE_RAD = math.radians(60.0)
OCCUPIED_MARGIN_M = 0.1  # a roadmap node closer than this to a robot's rim is taken by the robot
SINGLE_FILE_CLEARANCE_M = 0.75  # a roadmap node closer than this to a wall lies in a single-file stretch
SINGLE_FILE_MARGIN_M = 1.0  # people wait for a robot at least this far before a single-file stretch's first node
SINGLE_FILE_COOLDOWN_S = 10.0  # after waiting that long, no waiting again for this long
# the rules as the kernels take them (simnav.agents.kernels.crowd_react)
_TURNING = (YAW_TIME_CONSTANT_S, MAX_YAW_RATE_RAD_S, MOVING_SPEED_M_S)
_BLOCKING = (BLOCKING_DISTANCE_M, math.cos(BLOCKING_HALF_ANGLE_RAD), BLOCKED_SPEED_M_S, YIELD_AFTER_S,
             FORCE_YIELD_AFTER_S)
_STUCK = (STUCK_PROGRESS_M, STUCK_TIME_S)


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-π, π)."""
    return (np.asarray(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


class SegmentGrid:
    """Uniform grid listing, per cell, the segments that may lie within ``reach_m`` of a point in the cell.

    Args:
        segments: prepared wall segments (world frame, metres).
        reach_m: query radius, metres.
        cell_m: cell size, metres.
    """

    def __init__(self, segments: Segments, reach_m: float, cell_m: float = 1.0) -> None:
        self._cell_m = cell_m
        if len(segments) == 0:
            self._origin = np.zeros(2)
            self._shape = (0, 0)
            self._ptr = np.zeros(1, dtype=np.int64)
            self._idx = np.zeros(0, dtype=np.int64)
            return
        ends = np.concatenate([segments.start, segments.start + segments.delta])
        self._origin = ends.min(axis=0) - reach_m
        extent = ends.max(axis=0) + reach_m - self._origin
        self._shape = tuple(int(k) for k in np.maximum(np.ceil(extent / cell_m), 1).astype(int))
        self._ptr, self._idx = grid_lists(self._origin, cell_m, *self._shape, segments.start, segments.delta,
                                          segments.inv_len2, reach_m + cell_m * math.sqrt(0.5))

    @property
    def arrays(self) -> tuple[np.ndarray, float, int, int, np.ndarray, np.ndarray]:
        """The grid as :func:`~simnav.agents.kernels.grid_pairs` takes it: (origin (2,) m, cell size m, nx, ny,
        cell pointers, segment indices)."""
        return self._origin, self._cell_m, self._shape[0], self._shape[1], self._ptr, self._idx

    def pairs(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate (point index, segment index) pairs for (N, 2) points: two (P,) int arrays."""
        pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
        return grid_pairs(pts, *self.arrays)


def grid_lists_reference(segments: Segments, origin: np.ndarray, cell_m: float, shape: tuple[int, int],
                         reach_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~simnav.agents.kernels.grid_lists` written with numpy array operations (the reference of the kernel)."""
    nx, ny = shape
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    centers = origin + (np.stack([gx.ravel(), gy.ravel()], axis=1) + 0.5) * cell_m
    m = len(segments)
    chunk = max(1, 2_000_000 // m)
    counts, lists = [], []
    for lo in range(0, len(centers), chunk):
        c = centers[lo : lo + chunk]
        ped, seg = all_pairs(len(c), m)
        _, d = segments.offsets(c, ped, seg)
        near = (d <= reach_m).reshape(len(c), m)
        counts.append(near.sum(axis=1))
        lists.append(np.nonzero(near)[1])
    ptr = np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int64)
    return ptr, np.concatenate(lists).astype(np.int64)


@functools.lru_cache(maxsize=16)
def _shared_grid(walls: bytes, reach_m: float, cell_m: float) -> SegmentGrid:
    """The :class:`SegmentGrid` of the (M, 2, 2) float64 wall segments ``walls`` (as bytes), built once for all
    the crowds in those walls (an env makes one per episode)."""
    return SegmentGrid(Segments(np.frombuffer(walls).reshape(-1, 2, 2)), reach_m, cell_m)


class Crowd:
    """Pedestrians walking between roadmap nodes (social force model, hard non-overlap constraints).

    Args:
        roadmap: the graph the pedestrians walk on.
        walls_xy: (M, 2, 2) static wall segments, world frame, metres.
        count: number of pedestrians N.
        rng: source of all randomness (spawn, speeds, goals, pauses).
        params: social force parameters (``radius_m`` is the body radius).
        speed_mean_m_s: mean desired speed; speeds ~ N(mean, std) clipped to [0.5, 2.0] m/s.
        speed_std_m_s: standard deviation of the desired speed.
        keep_out: (K, 3) circles ``[x, y, radius]`` (metres) where nobody may spawn, e.g. around the robot.
        single_file_wait_s: longest wait before a single-file stretch a robot is in, seconds (0, the default:
            nobody waits; see the module docstring).

    Raises:
        ValueError: when a pedestrian cannot be placed near any roadmap node or edge.
    """

    def __init__(
        self,
        roadmap: RoadmapGraph,
        walls_xy: np.ndarray,
        count: int,
        rng: np.random.Generator,
        params: SocialForceParams = SocialForceParams(),
        speed_mean_m_s: float = 1.34,
        speed_std_m_s: float = 0.26,
        keep_out: np.ndarray | None = None,
        single_file_wait_s: float = 0.0,
    ) -> None:
        if not single_file_wait_s >= 0.0:
            raise ValueError(f"single_file_wait_s must be >= 0 s, got {single_file_wait_s}")
        self._roadmap = roadmap
        self._params = params
        self._rng = rng
        self._wall_xy = np.asarray(walls_xy, dtype=float).reshape(-1, 2, 2)
        self._walls = Segments(self._wall_xy)
        self._kernel_params = kernel_params(params)
        self._rules = (YIELD_SPEED_FACTOR, params.wall_look_ahead_m > 0.0, params.max_speed_factor, params.radius_m,
                       PROJECTION_SWEEPS, NEAR_SLACK_M, _TURNING, _BLOCKING, _STUCK)
        self._limits = (GOAL_REACHED_M, WAYPOINT_REACHED_M, params.radius_m, OCCUPIED_MARGIN_M)
        self._circle_pad = np.array([0.0, 0.0, params.circle_clearance_m])  # added to the circles (read only)
        self._circle_pad.flags.writeable = False
        self._init_grids()
        self._single_file_wait_s = float(single_file_wait_s)
        # the roadmap nodes with room to pass a robot (looked at only by the single-file rule)
        self._roomy = (_wall_clearances_m(roadmap.nodes_xy, self._walls) >= SINGLE_FILE_CLEARANCE_M
                       if self._single_file_wait_s > 0.0 else np.ones(roadmap.node_count, dtype=bool))
        keep = np.zeros((0, 3)) if keep_out is None else np.asarray(keep_out, dtype=float).reshape(-1, 3)
        self._pos, start_nodes = self._spawn(int(count), keep)
        self._vel = np.zeros_like(self._pos)
        self._speeds = np.clip(rng.normal(speed_mean_m_s, speed_std_m_s, len(self._pos)), 0.5, 2.0)
        self._time_s = 0.0
        self._avoid = np.zeros((len(self._pos), 3))  # [x, y, radius] each keeps their routes clear of, m
        self._avoid_until_s = np.full(len(self._pos), -math.inf)  # ... until this time, s
        self._init_plans(start_nodes)
        self._yaw = self._initial_yaws()
        self._yaw_rate = np.zeros(len(self._pos))
        self._anchor_xy = self._pos.copy()
        self._anchor_t = np.zeros(len(self._pos))
        self._anchor_goal = self._target.copy()
        self._robot_yield_t = np.full(len(self._pos), -math.inf)  # when each last stepped aside for a robot, s
        self._priority = rng.uniform(size=len(self._pos))
        self._blocked_s = np.zeros(len(self._pos))
        self._yield_s = np.zeros(len(self._pos))
        self._yield_dir = np.zeros((len(self._pos), 2))
        self._waited_s = np.zeros(len(self._pos))  # how long each has waited before a single-file stretch, s
        self._wait_again_s = np.full(len(self._pos), -math.inf)  # ... and when they may wait again, s
        self._waiting = np.zeros(len(self._pos), dtype=bool)

    @property
    def count(self) -> int:
        """Number of pedestrians N."""
        return len(self._pos)

    @property
    def radius_m(self) -> float:
        """Body radius of every pedestrian, metres."""
        return self._params.radius_m

    @property
    def positions_xy(self) -> np.ndarray:
        """(N, 2) read-only centres, world frame, metres."""
        return read_only_view(self._pos)

    @property
    def velocities_xy(self) -> np.ndarray:
        """(N, 2) read-only velocities over the last step, world frame, m/s."""
        return read_only_view(self._vel)

    @property
    def yaws_rad(self) -> np.ndarray:
        """(N,) read-only headings (world frame, from +x), rad in [-π, π)."""
        return read_only_view(self._yaw)

    @property
    def yaw_rates_rad_s(self) -> np.ndarray:
        """(N,) read-only yaw rates over the last step, rad/s (``yaw_{k+1} = wrap(yaw_k + rate·dt)``)."""
        return read_only_view(self._yaw_rate)

    def motion_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(N, 2) positions (m), (N, 2) velocities (m/s), (N,) yaws (rad) and (N,) yaw rates (rad/s), world frame:
        the arrays themselves, not read-only views, for readers that only read them (a step replaces these
        arrays, never changes them)."""
        return self._pos, self._vel, self._yaw, self._yaw_rate

    @property
    def goals(self) -> np.ndarray:
        """(N,) goal node indices (a copy)."""
        return self._goals.copy()

    @property
    def desired_speeds_m_s(self) -> np.ndarray:
        """(N,) read-only desired walking speeds, m/s."""
        return read_only_view(self._speeds)

    @property
    def waypoints_xy(self) -> np.ndarray:
        """(N, 2) current waypoints, metres (a copy)."""
        return self._target.copy()

    @property
    def pausing(self) -> np.ndarray:
        """(N,) read-only: who stands at the goal they reached, before setting out for the next."""
        return read_only_view(self._arrived)

    @property
    def waiting(self) -> np.ndarray:
        """(N,) read-only: who waited, over the last step, before a single-file stretch a robot is in."""
        return read_only_view(self._waiting)

    @property
    def time_s(self) -> float:
        """Simulated time since construction, seconds."""
        return self._time_s

    def step(
        self,
        dt_s: float,
        dynamic_segments: np.ndarray | None = None,
        circles: np.ndarray | None = None,
        circle_velocities: np.ndarray | None = None,
    ) -> None:
        """Advance every pedestrian by ``dt_s`` seconds.

        Args:
            dt_s: time step, seconds (> 0).
            dynamic_segments: (D, 2, 2) moving wall segments this step (e.g. door leaves), metres, or None.
            circles: (C, 3) round obstacles ``[x, y, radius]`` (e.g. the robot), metres, or None.
            circle_velocities: (C, 2) velocities of the circles, m/s, or None.
        """
        if dt_s <= 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        circ, circ_vel = circle_arrays(circles, circle_velocities)
        self._step(dt_s, dynamic_segments, circ, circ_vel, circles is not None)

    def step_rows(self, dt_s: float, dynamic_segments: np.ndarray | None, circles: np.ndarray,
                  circle_velocities: np.ndarray) -> None:
        """:meth:`step` for a caller whose arrays are already as the kernels take them: ``dt_s`` > 0, C-contiguous
        float64 (D, 2, 2) segments (or None), (C, 3) circles and (C, 2) velocities (the simulator, every agent
        period), without the checks and conversions."""
        self._step(dt_s, dynamic_segments, circles, circle_velocities, True)

    def _step(self, dt_s: float, dynamic_segments: np.ndarray | None, circ: np.ndarray, circ_vel: np.ndarray,
              has_circles: bool) -> None:
        """:meth:`step` from the kernels' circle arrays (``has_circles`` False: there were none)."""
        self._time_s += dt_s
        if len(circ) and self._circle_pad[2] > 0:  # personal space around robots
            circ = circ + self._circle_pad
        self._update_plans(dt_s, circ)
        standing = self._standing(dt_s, circ)
        dyn = self._moving_segments(dynamic_segments)
        events = self._move(dt_s, dyn, circ, circ_vel, has_circles, standing)
        if len(events):
            self._unblock(events, circ, self._walls if len(dyn) == 0 else self._extended)

    def _unblock(self, events: np.ndarray, circles: np.ndarray, walls: Segments) -> None:
        """Those blocked step back, those stuck head elsewhere: (E, 2) events [pedestrian, blocker, or −1 for
        stuck] of :func:`~simnav.agents.kernels.crowd_move`, with the (C, 3) ``circles`` and this step's
        ``walls``. Blocked by a robot again within ``ROBOT_GIVE_UP_S`` of stepping aside for one, a pedestrian
        gives up getting past (:meth:`_give_up_on_robot`)."""
        n = len(self._pos)
        for k, blocker in events:
            robot_again = blocker >= n and self._time_s - self._robot_yield_t[k] <= ROBOT_GIVE_UP_S
            if blocker >= 0 and not robot_again:
                self._step_back(int(k), int(blocker), circles)
            elif robot_again:
                self._give_up_on_robot(int(k), circles[blocker - n], walls)
            elif (beside := self._robot_beside(int(k), circles)) is not None:
                self._give_up_on_robot(int(k), circles[beside], walls)
            else:
                self._replan_stuck(int(k), walls)
            if blocker >= n:
                self._robot_yield_t[k] = self._time_s

    def _moving_segments(self, dynamic_segments: np.ndarray | None) -> np.ndarray:
        """The (D, 2, 2) moving segments (metres), contiguous, with room for them after the walls (kept while D
        stays; :func:`~simnav.agents.kernels.crowd_move` fills it)."""
        if dynamic_segments is None:
            return self._no_segments
        dyn = dynamic_segments
        if not (type(dyn) is np.ndarray and dyn.dtype == np.float64 and dyn.ndim == 3 and dyn.shape[1:] == (2, 2)
                and dyn.flags.c_contiguous):
            dyn = np.ascontiguousarray(dynamic_segments, dtype=float).reshape(-1, 2, 2)
        if len(dyn) and len(self._extended) != len(self._walls) + len(dyn):
            self._extended = self._walls.extended(dyn)
            self._extended_args = (*self._extended.arrays, len(self._walls))
        return dyn

    def _move(self, dt_s: float, dyn: np.ndarray, circ: np.ndarray, circ_vel: np.ndarray,
              has_circles: bool, standing: np.ndarray) -> np.ndarray:
        """Social forces, the semi-implicit Euler step, the non-overlap projection, then yaws, face-offs and stuck
        pedestrians, in one kernel call: new positions, velocities, yaws and yaw rates; returns the (E, 2) events
        [pedestrian, blocker, or −1 for stuck] left to :meth:`_unblock`.

        ``dyn``: (D, 2, 2) moving segments; ``has_circles`` False: ``circ`` is (0, 3); ``standing`` (N,) bool: who
        stands this step (pausing at a goal or waiting, :meth:`_standing`).
        """
        walls = self._walls_args if len(dyn) == 0 else self._extended_args
        self._pos, self._vel, self._yaw, self._yaw_rate, events = crowd_move(
            (self._pos, self._vel, self._yaw),
            (self._dirs, self._target, self._yield_s, self._yield_dir, self._speeds, standing),
            (self._blocked_s, self._priority, self._anchor_xy, self._anchor_t, self._anchor_goal),
            (self._near_cells, walls, self._fallback, dyn, circ, circ_vel, has_circles),
            self._kernel_params, self._rules, self._time_s, dt_s,
        )
        return events

    def _init_grids(self) -> None:
        """The candidate walls: a near grid for the forces and the projection after moves up to
        STEP_ALLOWANCE_M; beyond, a grid whose candidates around the old centres cover the projection around the
        new ones for moves up to ``max_move_m`` (larger moves: candidates around the new centres)."""
        params, walls = self._params, self._wall_xy.tobytes()
        reach_m = max(wall_reach_m(params), params.radius_m + 2.0 * NEAR_SLACK_M)
        max_move_m = 0.5 * (reach_m - params.radius_m - NEAR_SLACK_M)
        near_reach_m = max(wall_reach_m(params), params.radius_m + NEAR_SLACK_M + 2.0 * STEP_ALLOWANCE_M)
        self._near_cells = _shared_grid(walls, near_reach_m, 0.5).arrays
        self._fallback = (near_reach_m, max_move_m, _shared_grid(walls, reach_m, 1.0).arrays)
        self._walls_args = (*self._walls.arrays, len(self._walls))
        self._extended, self._extended_args = self._walls, self._walls_args  # walls + moving segments (D > 0)
        self._no_segments = np.zeros((0, 2, 2))

    def _init_plans(self, start_nodes: list[int]) -> None:
        n = len(self._pos)
        self._goals = np.zeros(n, dtype=np.int64)
        self._path_xy = np.zeros((n, self._roadmap.node_count, 2))  # path k: the first _last_wp[k] + 1 nodes
        self._path_nodes = np.zeros((n, self._roadmap.node_count), dtype=np.int64)  # ... their node indices
        self._wp = np.zeros(n, dtype=np.int64)
        self._last_wp = np.zeros(n, dtype=np.int64)
        self._target = self._pos.copy()
        self._arrived = np.zeros(n, dtype=bool)
        self._pause_s = np.zeros(n)
        self._dirs = np.tile([1.0, 0.0], (n, 1))
        for k, node in enumerate(start_nodes):
            self._plan(k, node)

    def _initial_yaws(self) -> np.ndarray:
        yaws = np.empty(len(self._pos))
        for k in range(len(self._pos)):
            ahead = self._path_xy[k, min(1, self._last_wp[k])] - self._pos[k]
            if np.hypot(ahead[0], ahead[1]) > 1e-6:
                yaws[k] = math.atan2(ahead[1], ahead[0])
            else:
                yaws[k] = self._rng.uniform(-math.pi, math.pi)
        return yaws

    def _plan(self, k: int, start_node: int, attempts: int = 10) -> None:
        """Send pedestrian k from ``start_node`` to a new random goal reachable from it (while k avoids a robot,
        one whose route keeps clear of it, if any: :meth:`_give_up_on_robot`)."""
        avoid = self._avoiding(k)
        if avoid is not None:
            goal, path = self._goal_clear_of(start_node, avoid)
        else:
            path = [start_node]
            goal = start_node
            for _ in range(attempts):
                goal = self._roadmap.random_node(self._rng, exclude=start_node)
                path = self._roadmap.shortest_path(start_node, goal)
                if path:
                    break
        if not path:
            goal, path = start_node, [start_node]
        self._goals[k] = goal
        self._path_xy[k, : len(path)] = self._roadmap.nodes_xy[np.asarray(path)]
        self._path_nodes[k, : len(path)] = path
        self._wp[k] = 0
        self._last_wp[k] = len(path) - 1
        self._arrived[k] = False
        self._set_target(k)

    def _goal_clear_of(self, start_node: int, avoid: np.ndarray) -> tuple[int, list[int]]:
        """A random goal other than ``start_node`` whose route from it keeps out of the circle ``avoid`` ``[x, y,
        radius]`` (m) and that route; ``start_node`` and ``[]`` when there is none."""
        nodes_xy = self._roadmap.nodes_xy
        options = []
        for goal in range(self._roadmap.node_count):
            path = self._roadmap.shortest_path(start_node, goal) if goal != start_node else []
            if path and _keeps_clear(nodes_xy[np.asarray(path)], avoid):
                options.append((goal, path))
        if not options:
            return start_node, []
        return options[int(self._rng.integers(len(options)))]

    def _set_target(self, k: int) -> None:
        self._target[k] = self._path_xy[k, self._wp[k]]

    def _standing(self, dt_s: float, circles: np.ndarray) -> np.ndarray:
        """(N,) bool: who stands this step: those pausing at a goal, and those waiting before a single-file
        stretch that one of the (C, 3) ``circles`` (robots, m) is in (see the module docstring; the waits run
        up here)."""
        waiting = self._waiting_for_robots(circles)
        self._waited_s = np.where(waiting, self._waited_s + dt_s, 0.0)
        done = self._waited_s > self._single_file_wait_s
        if np.any(done):
            self._wait_again_s[done] = self._time_s + SINGLE_FILE_COOLDOWN_S
            self._waited_s[done] = 0.0
            waiting &= ~done
        self._waiting = waiting
        return self._arrived | waiting if np.any(waiting) else self._arrived

    def _waiting_for_robots(self, circles: np.ndarray) -> np.ndarray:
        """(N,) bool: who would wait now before a single-file stretch one of the (C, 3) ``circles`` is in."""
        n = len(self._pos)
        waiting = np.zeros(n, dtype=bool)
        if self._single_file_wait_s <= 0.0 or len(circles) == 0 or n == 0:
            return waiting
        rows, wp = np.arange(n), self._wp
        before = self._path_nodes[rows, np.maximum(wp - 1, 0)]
        ahead = self._path_nodes[rows, wp]
        gap = self._target - self._pos
        about_to_enter = ((wp >= 1) & ~self._arrived & self._roomy[before] & ~self._roomy[ahead]
                          & (self._time_s >= self._wait_again_s)
                          & (np.einsum("ij,ij->i", gap, gap) >= SINGLE_FILE_MARGIN_M**2))
        reach = circles[:, 2] + self.radius_m
        for k in np.nonzero(about_to_enter)[0]:
            stretch = self._single_file_stretch(int(k))
            waiting[k] = any(not _keeps_clear(stretch, np.array([c[0], c[1], r])) for c, r in zip(circles, reach))
        return waiting

    def _single_file_stretch(self, k: int) -> np.ndarray:
        """(P, 2) the nodes of pedestrian k's route from their waypoint up to, not including, the next node with
        room to pass a robot (or to their goal), metres."""
        end, last = int(self._wp[k]), int(self._last_wp[k])
        while end < last and not self._roomy[self._path_nodes[k, end + 1]]:
            end += 1
        return self._path_xy[k, self._wp[k] : end + 1]

    def _update_plans(self, dt_s: float, circles: np.ndarray) -> None:
        """Pauses run down and new goals; waypoints reached, counting a robot (in (C, 3) ``circles``) standing on
        the target as there."""
        plans = (self._pos, self._target, self._path_xy, self._wp, self._last_wp)
        walls = (self._walls.start, self._walls.delta)
        due, events = crowd_plan_events(self._pause_s, self._arrived, dt_s, plans, circles, self._limits, walls)
        if len(due):
            for k in due:
                self._plan(int(k), int(self._goals[k]))
            events = crowd_advance(self._arrived, plans, circles, self._limits, walls)
        if len(events):
            self._settle(events)

    def _settle(self, events: np.ndarray) -> None:
        """Pauses for those who arrived, and the waypoints the kernel left to numpy's norm: (E, 2) events
        [pedestrian, kind] of :func:`~simnav.agents.kernels.crowd_advance`."""
        for k, unsettled in events:
            if unsettled:
                last = self._wp[k] == self._last_wp[k]
                if np.linalg.norm(self._target[k] - self._pos[k]) < (GOAL_REACHED_M if last else WAYPOINT_REACHED_M):
                    self._advance(int(k))
            else:
                self._pause_s[k] = self._rng.uniform(0.0, MAX_PAUSE_S)

    def _advance(self, k: int) -> None:
        """Pedestrian k takes the next waypoints until one is out of reach, or arrives (see
        :func:`~simnav.agents.kernels.crowd_advance`, which measures the distances in the common case)."""
        while True:
            if self._wp[k] == self._last_wp[k]:
                self._arrived[k] = True
                self._pause_s[k] = self._rng.uniform(0.0, MAX_PAUSE_S)
                return
            self._wp[k] += 1
            self._set_target(k)
            last = self._wp[k] == self._last_wp[k]
            reach_m = GOAL_REACHED_M if last else WAYPOINT_REACHED_M
            if np.linalg.norm(self._target[k] - self._pos[k]) >= reach_m:
                return

    def _step_back(self, k: int, blocker: int, circles: np.ndarray) -> None:
        """Pedestrian k, blocked by ``blocker`` (a pedestrian, or N + the index of a round obstacle in (C, 3)
        ``circles``), yields for 1–2.5 s: back from a pedestrian; from a robot, towards a
        spot ROBOT_PASSING_GAP_M beside it, on the right of the way it wanted to go."""
        n = len(self._pos)
        if blocker < n:
            away = -(self._pos[blocker] - self._pos[k])
        else:
            right = np.array([self._dirs[k, 1], -self._dirs[k, 0]])
            beside = circles[blocker - n, :2] + (circles[blocker - n, 2] + self.radius_m + ROBOT_PASSING_GAP_M) * right
            away = beside - self._pos[k]
        self._yield_dir[k] = away / max(float(np.linalg.norm(away)), 1e-9)
        self._yield_s[k] = self._rng.uniform(*YIELD_DURATION_S)
        self._blocked_s[k] = 0.0

    def _give_up_on_robot(self, k: int, circle: np.ndarray, walls: Segments) -> None:
        """Pedestrian k gives up getting past the robot ``circle`` ``[x, y, radius]`` (m): for ``ROBOT_AVOID_S``
        their routes keep ``ROBOT_PASSING_GAP_M`` clear of where it stands now, and they head elsewhere as if
        stuck."""
        self._avoid[k] = (circle[0], circle[1], circle[2] + self.radius_m + ROBOT_PASSING_GAP_M)
        self._avoid_until_s[k] = self._time_s + ROBOT_AVOID_S
        self._replan_stuck(k, walls)

    def _robot_beside(self, k: int, circles: np.ndarray) -> int | None:
        """The index of the nearest of the (C, 3) ``circles`` (robots, personal space included) whose rim is within
        ``ROBOT_PASSING_GAP_M`` of stuck pedestrian k's, or None: someone pinned beside a robot (between it and a
        wall or a post, out of the way ahead that face-offs look at) gives up on getting past it."""
        if len(circles) == 0:
            return None
        gaps = np.hypot(*(circles[:, :2] - self._pos[k]).T) - circles[:, 2] - self.radius_m
        nearest = int(np.argmin(gaps))
        return nearest if gaps[nearest] <= ROBOT_PASSING_GAP_M else None

    def _replan_stuck(self, k: int, walls: Segments) -> None:
        """Pedestrian k, stuck, heads for a new goal from the nearest roadmap node in sight (``walls``): of up to
        ``REPLAN_ATTEMPTS`` random goals the first whose route does not lead on the way k was stuck (within
        ``REPLAN_AHEAD_HALF_ANGLE_RAD`` of it), else the last one: someone who cannot get past a robot in a
        hallway turns back."""
        _LOG.debug("pedestrian %d stuck at %s, re-planning", k, self._pos[k])
        start, stuck_dir = self._nearest_visible_node(self._pos[k], walls, self._avoiding(k)), self._dirs[k].copy()
        for _ in range(REPLAN_ATTEMPTS):
            self._plan(k, start)
            if not self._route_leads(k, stuck_dir):
                break
        self._anchor_xy[k] = self._pos[k]
        self._anchor_t[k] = self._time_s
        self._anchor_goal[k] = self._target[k]

    def _route_leads(self, k: int, direction: np.ndarray) -> bool:
        """Whether pedestrian k's route first heads (to its first node more than WAYPOINT_REACHED_M away) within
        ``REPLAN_AHEAD_HALF_ANGLE_RAD`` of the unit ``direction``."""
        for node_xy in self._path_xy[k, : self._last_wp[k] + 1]:
            ahead = node_xy - self._pos[k]
            dist = float(np.hypot(ahead[0], ahead[1]))
            if dist > WAYPOINT_REACHED_M:
                return float(ahead @ direction) >= dist * math.cos(REPLAN_AHEAD_HALF_ANGLE_RAD)
        return False

    def _nearest_visible_node(self, xy: np.ndarray, walls: Segments, avoid: np.ndarray | None = None,
                              candidates: int = 8) -> int:
        """The nearest roadmap node in line of sight of ``xy`` among the closest few (and, given an ``avoid``
        circle ``[x, y, radius]``, one outside it whose way from ``xy`` comes no closer to its centre, if any),
        else the nearest one."""
        nodes_xy = self._roadmap.nodes_xy
        order = np.argsort(np.linalg.norm(nodes_xy - xy, axis=1))
        seen = [int(node) for node in order[:candidates] if _visible(xy, nodes_xy[node], walls)]
        if avoid is not None:
            here = min(float(avoid[2]), float(np.linalg.norm(xy - avoid[:2])) - 1e-6)
            away = [node for node in seen if _keeps_clear(nodes_xy[node][None], avoid)
                    and _keeps_clear(np.stack([xy, nodes_xy[node]]), np.array([avoid[0], avoid[1], here]))]
            seen = away or seen
        return seen[0] if seen else int(order[0])

    def _avoiding(self, k: int) -> np.ndarray | None:
        """The circle ``[x, y, radius]`` pedestrian k's routes keep clear of now (see :meth:`_give_up_on_robot`),
        or None."""
        return self._avoid[k] if self._time_s < self._avoid_until_s[k] else None

    def _spawn(self, count: int, keep_out: np.ndarray) -> tuple[np.ndarray, list[int]]:
        placed: list[np.ndarray] = []
        nodes: list[int] = []
        for k in range(count):
            found = self._spawn_one(placed, keep_out, attempts=max(200, 20 * self._roadmap.node_count))
            if found is None:
                raise ValueError(
                    f"cannot place pedestrian {k} of {count} near any roadmap node or edge (walls, keep-out "
                    f"zones or other pedestrians within {self._params.radius_m + SPAWN_CLEARANCE_M:.2f} m "
                    "everywhere)"
                )
            placed.append(found[0])
            nodes.append(found[1])
        return (np.array(placed) if placed else np.zeros((0, 2))), nodes

    def _spawn_one(
        self, placed: list[np.ndarray], keep_out: np.ndarray, attempts: int
    ) -> tuple[np.ndarray, int] | None:
        """A free spot near a random node, else (all nodes crowded) near a random point of an edge."""
        r = self._params.radius_m + SPAWN_CLEARANCE_M
        nodes_xy, edges = self._roadmap.nodes_xy, self._roadmap.edges
        for attempt in range(2 * attempts if edges else attempts):
            if attempt < attempts:
                node = self._roadmap.random_node(self._rng)
                anchor = nodes_xy[node]
            else:
                i, j = edges[int(self._rng.integers(len(edges)))]
                along = self._rng.uniform()
                anchor = nodes_xy[i] + along * (nodes_xy[j] - nodes_xy[i])
                node = i if along < 0.5 else j  # the edge leads back to it through free space
            angle = self._rng.uniform(-math.pi, math.pi)
            jitter = SPAWN_JITTER_M * math.sqrt(self._rng.uniform())
            xy = anchor + jitter * np.array([math.cos(angle), math.sin(angle)])
            if self._free(xy, r, placed, keep_out) and _visible(anchor, xy, self._walls):
                return xy, node
        return None

    def _free(self, xy: np.ndarray, r: float, placed: list[np.ndarray], keep_out: np.ndarray) -> bool:
        if _wall_clearances_m(xy[None, :], self._walls)[0] < r:
            return False
        if placed and np.min(np.linalg.norm(np.array(placed) - xy, axis=1)) < 2.0 * r:
            return False
        if len(keep_out) and np.any(np.linalg.norm(keep_out[:, :2] - xy, axis=1) < keep_out[:, 2] + r):
            return False
        return True


def _keeps_clear(polyline_xy: np.ndarray, circle: np.ndarray) -> bool:
    """Whether the (P, 2) polyline (m) stays outside the circle ``[x, y, radius]``."""
    centre, radius = circle[:2], float(circle[2])
    if len(polyline_xy) == 1:
        return float(np.linalg.norm(polyline_xy[0] - centre)) >= radius
    a, ab = polyline_xy[:-1], np.diff(polyline_xy, axis=0)
    t = np.clip(np.einsum("ij,ij->i", centre - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0)
    return bool(np.all(np.linalg.norm(a + t[:, None] * ab - centre, axis=1) >= radius))


def _wall_clearances_m(points_xy: np.ndarray, walls: Segments) -> np.ndarray:
    """(K,) distance from each of the (K, 2) points (m) to the nearest wall segment, metres (inf without walls)."""
    if len(walls) == 0:
        return np.full(len(points_xy), math.inf)
    ped, seg = all_pairs(len(points_xy), len(walls))
    _, dist = walls.offsets(np.asarray(points_xy, dtype=float), ped, seg)
    return dist.reshape(len(points_xy), len(walls)).min(axis=1)


def _visible(p: np.ndarray, q: np.ndarray, walls: Segments) -> bool:
    """True when the straight segment p→q touches no wall segment."""
    if len(walls) == 0:
        return True
    a, ab = walls.start, walls.delta
    move = np.asarray(q, float) - np.asarray(p, float)
    d1 = ab[:, 0] * (p[1] - a[:, 1]) - ab[:, 1] * (p[0] - a[:, 0])
    d2 = ab[:, 0] * (q[1] - a[:, 1]) - ab[:, 1] * (q[0] - a[:, 0])
    d3 = move[0] * (a[:, 1] - p[1]) - move[1] * (a[:, 0] - p[0])
    b = a + ab
    d4 = move[0] * (b[:, 1] - p[1]) - move[1] * (b[:, 0] - p[0])
    return not bool(np.any((d1 * d2 <= 0.0) & (d3 * d4 <= 0.0) & ~((d1 == 0.0) & (d2 == 0.0))))


def read_only_view(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array`` (the owner replaces, never mutates, the arrays it hands out this way)."""
    view = array.view()
    view.flags.writeable = False
    return view
