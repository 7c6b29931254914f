"""A crowd of pedestrians walking between roadmap nodes under the social force model.

Everything is in the world frame (x/y on the floor), SI units. Each pedestrian walks the roadmap's shortest
path to a random goal node, pauses there 0–2 s, then picks the next goal. Velocities are the exact
displacement of the last step divided by the step (``x_{k+1} = x_k + v_{k+1}·dt``), contact pushes included,
so they can serve as ground truth for scene flow.

Two rules keep the crowd moving where the force model alone locks up. Face-offs (two people meeting in a
doorway) end when one of them, the one of lower priority after 1.5 s or either after 4 s, steps back for a
moment. Anybody who makes less than 0.3 m of progress in 10 s re-plans from the nearest roadmap node in
sight to a new goal.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numba import njit

from simnav.agents.roadmap import RoadmapGraph
from simnav.agents.social_force import (
    Segments,
    SocialForceParams,
    all_pairs,
    integrate,
    resolve_overlaps_pairs,
    social_force_pairs,
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
BLOCKED_SPEED_M_S = 0.2
BLOCKING_DISTANCE_M = 1.0
BLOCKING_HALF_ANGLE_RAD = math.radians(60.0)
YIELD_AFTER_S = 1.5
FORCE_YIELD_AFTER_S = 4.0
YIELD_DURATION_S = (1.0, 2.5)
YIELD_SPEED_FACTOR = 0.5
ROBOT_PASSING_GAP_M = 0.3
OCCUPIED_MARGIN_M = 0.1  # a roadmap node closer than this to a robot's rim is taken by the robot
_NEAR_SLACK_M = 1.0  # the reach, beyond the radius and the move, that the projection keeps around a centre


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
        self._ptr, self._idx = self._build(segments, reach_m + cell_m * math.sqrt(0.5))

    def _build(self, segments: Segments, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
        nx, ny = self._shape
        gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        centers = self._origin + (np.stack([gx.ravel(), gy.ravel()], axis=1) + 0.5) * self._cell_m
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

    def pairs(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate (point index, segment index) pairs for (N, 2) points: two (P,) int arrays."""
        n = len(points)
        if self._shape == (0, 0) or n == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
        return _grid_pairs(pts, self._origin, self._cell_m, self._shape[0], self._shape[1], self._ptr, self._idx)


@njit(cache=True)
def _grid_pairs(points: np.ndarray, origin: np.ndarray, cell_m: float, nx: int, ny: int, ptr: np.ndarray,
                idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`SegmentGrid.pairs` on the grid's flat cell lists ``idx[ptr[c]:ptr[c + 1]]`` (cell c = ix·ny + iy)."""
    n = points.shape[0]
    cell = np.full(n, -1, dtype=np.int64)
    total = 0
    # each point's cell (-1 outside the grid), then its segments in cell-list order
    for i in range(n):
        ix = np.int64(math.floor((points[i, 0] - origin[0]) / cell_m))
        iy = np.int64(math.floor((points[i, 1] - origin[1]) / cell_m))
        if 0 <= ix < nx and 0 <= iy < ny:
            cell[i] = ix * ny + iy
            total += ptr[cell[i] + 1] - ptr[cell[i]]
    ped = np.empty(total, dtype=np.int64)
    seg = np.empty(total, dtype=np.int64)
    k = 0
    for i in range(n):
        if cell[i] < 0:
            continue
        for j in range(ptr[cell[i]], ptr[cell[i] + 1]):
            ped[k], seg[k] = i, idx[j]
            k += 1
    return ped, seg


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
    ) -> None:
        self._roadmap = roadmap
        self._params = params
        self._rng = rng
        self._wall_xy = np.asarray(walls_xy, dtype=float).reshape(-1, 2, 2)
        self._walls = Segments(self._wall_xy)
        self._grid_reach_m = max(wall_reach_m(params), params.radius_m + 2.0 * _NEAR_SLACK_M)
        self._grid = SegmentGrid(self._walls, self._grid_reach_m)
        # candidates found around the old centres cover the projection around the new ones up to this move
        self._max_move_m = 0.5 * (self._grid_reach_m - params.radius_m - _NEAR_SLACK_M)
        keep = np.zeros((0, 3)) if keep_out is None else np.asarray(keep_out, dtype=float).reshape(-1, 3)
        self._pos, start_nodes = self._spawn(int(count), keep)
        self._vel = np.zeros_like(self._pos)
        self._speeds = np.clip(rng.normal(speed_mean_m_s, speed_std_m_s, len(self._pos)), 0.5, 2.0)
        self._time_s = 0.0
        self._init_plans(start_nodes)
        self._yaw = self._initial_yaws()
        self._yaw_rate = np.zeros(len(self._pos))
        self._anchor_xy = self._pos.copy()
        self._anchor_t = np.zeros(len(self._pos))
        self._priority = rng.uniform(size=len(self._pos))
        self._blocked_s = np.zeros(len(self._pos))
        self._yield_s = np.zeros(len(self._pos))
        self._yield_dir = np.zeros((len(self._pos), 2))

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
        self._time_s += dt_s
        self._update_plans(dt_s, circles)
        dirs, drive_speeds = self._desired()
        segs, ped_idx, seg_idx = self._wall_pairs(self._pos, dynamic_segments)
        acc = social_force_pairs(
            self._pos, self._vel, dirs, drive_speeds, segs, ped_idx, seg_idx, circles, circle_velocities,
            self._params,
        )
        moved, _ = integrate(self._pos, self._vel, acc, self._speeds, dt_s, self._params)
        if len(moved) and np.max(np.linalg.norm(moved - self._pos, axis=1)) > self._max_move_m:
            segs, ped_idx, seg_idx = self._wall_pairs(moved, dynamic_segments)  # candidates from here
        resolved = resolve_overlaps_pairs(
            moved, self.radius_m, segs, ped_idx, seg_idx, circles, PROJECTION_SWEEPS,
            previous_xy=self._pos, check_crossing=seg_idx < len(self._walls),
        )
        self._vel = (resolved - self._pos) / dt_s
        self._pos = resolved
        self._update_yaws(dt_s)
        self._handle_blocking(dt_s, circles)
        self._handle_stuck(segs)

    def _wall_pairs(
        self, points: np.ndarray, dynamic_segments: np.ndarray | None
    ) -> tuple[Segments, np.ndarray, np.ndarray]:
        ped_idx, seg_idx = self._grid.pairs(points)
        if dynamic_segments is None or len(dynamic_segments) == 0:
            return self._walls, ped_idx, seg_idx
        dyn = np.asarray(dynamic_segments, dtype=float).reshape(-1, 2, 2)
        segs = self._walls.extended(dyn)
        dyn_ped, dyn_seg = all_pairs(len(points), len(dyn))
        return segs, np.concatenate([ped_idx, dyn_ped]), np.concatenate([seg_idx, dyn_seg + len(self._walls)])

    def _desired(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions toward the current waypoints (N, 2) and the speeds to drive at (N,)."""
        speeds = _desired_update(self._dirs, self._target, self._pos, self._yield_s, self._yield_dir, self._speeds,
                                 self._arrived, YIELD_SPEED_FACTOR)
        return self._dirs, speeds

    def _update_yaws(self, dt_s: float) -> None:
        speed = np.linalg.norm(self._vel, axis=1)
        heading = np.arctan2(self._vel[:, 1], self._vel[:, 0])
        error = wrap_angle(heading - self._yaw)
        gain = min(1.0, dt_s / YAW_TIME_CONSTANT_S) / dt_s
        rate = np.clip(error * gain, -MAX_YAW_RATE_RAD_S, MAX_YAW_RATE_RAD_S)
        rate[speed <= MOVING_SPEED_M_S] = 0.0
        self._yaw = wrap_angle(self._yaw + rate * dt_s)
        self._yaw_rate = rate

    def _init_plans(self, start_nodes: list[int]) -> None:
        n = len(self._pos)
        self._goals = np.zeros(n, dtype=np.int64)
        self._paths: list[np.ndarray] = [np.zeros((1, 2))] * n
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
        for k, path in enumerate(self._paths):
            ahead = path[min(1, len(path) - 1)] - self._pos[k]
            if np.hypot(ahead[0], ahead[1]) > 1e-6:
                yaws[k] = math.atan2(ahead[1], ahead[0])
            else:
                yaws[k] = self._rng.uniform(-math.pi, math.pi)
        return yaws

    def _plan(self, k: int, start_node: int, attempts: int = 10) -> None:
        """Send pedestrian k from ``start_node`` to a new random goal reachable from it."""
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
        self._paths[k] = self._roadmap.nodes_xy[np.asarray(path)]
        self._wp[k] = 0
        self._last_wp[k] = len(path) - 1
        self._arrived[k] = False
        self._set_target(k)

    def _set_target(self, k: int) -> None:
        self._target[k] = self._paths[k][self._wp[k]]

    def _update_plans(self, dt_s: float, circles: np.ndarray | None = None) -> None:
        self._pause_s[self._arrived] -= dt_s
        for k in np.nonzero(self._arrived & (self._pause_s <= 0.0))[0]:
            self._plan(int(k), int(self._goals[k]))
        last = self._wp == self._last_wp
        dist = np.linalg.norm(self._target - self._pos, axis=1)
        reach = np.where(last, GOAL_REACHED_M, WAYPOINT_REACHED_M) + self._occupied_by_m(circles)
        reached = ~self._arrived & (dist < reach)
        for k in np.nonzero(reached)[0]:
            self._advance(int(k))

    def _occupied_by_m(self, circles: np.ndarray | None) -> np.ndarray:
        """(N,) how much farther from its target a pedestrian counts as there: the radius of a round obstacle
        (a robot) standing on the target plus the pedestrian's, or 0. Nobody walks onto someone else's spot, so
        without this, people whose next roadmap node a robot stands on circle it for ever."""
        if circles is None or len(circles) == 0 or len(self._pos) == 0:
            return np.zeros(len(self._pos))
        c = np.ascontiguousarray(circles, dtype=float).reshape(-1, 3)
        return _occupied_extra(self._target, c, self.radius_m, OCCUPIED_MARGIN_M)

    def _advance(self, k: int) -> None:
        path = self._paths[k]
        while True:
            if self._wp[k] == len(path) - 1:
                self._arrived[k] = True
                self._pause_s[k] = self._rng.uniform(0.0, MAX_PAUSE_S)
                return
            self._wp[k] += 1
            self._set_target(k)
            last = self._wp[k] == len(path) - 1
            reach_m = GOAL_REACHED_M if last else WAYPOINT_REACHED_M
            if np.linalg.norm(self._target[k] - self._pos[k]) >= reach_m:
                return

    def _handle_blocking(self, dt_s: float, circles: np.ndarray | None = None) -> None:
        """Break face-offs (e.g. in a doorway, or with a robot): after a while the pedestrian steps aside.

        A pedestrian is blocked while it barely moves and someone stands within BLOCKING_DISTANCE_M ahead
        (±60° of its desired direction; for a round obstacle such as a robot, the distance between the rims plus
        twice the pedestrian radius). Blocked by a pedestrian for YIELD_AFTER_S, it steps back from the closest one
        ahead for 1–2.5 s if that one has a higher priority (drawn at spawn); blocked for FORCE_YIELD_AFTER_S, it
        steps back anyway. Robots outrank everyone; from one, a pedestrian steps aside towards a spot
        ROBOT_PASSING_GAP_M beside it, on the right of the way it wanted to go, and walks on past from there.
        """
        self._yield_s = np.maximum(self._yield_s - dt_s, 0.0)
        n = len(self._pos)
        c = np.zeros((0, 3)) if circles is None else np.asarray(circles, dtype=float).reshape(-1, 3)
        if n == 0 or n + len(c) < 2:
            return
        others = np.concatenate([self._pos, c[:, :2]])
        reach = np.concatenate([np.full(n, BLOCKING_DISTANCE_M), BLOCKING_DISTANCE_M + c[:, 2] - self.radius_m])
        in_way, blocker = _closest_in_way(self._pos, self._dirs, others, reach, math.cos(BLOCKING_HALF_ANGLE_RAD))
        slow = np.linalg.norm(self._vel, axis=1) < BLOCKED_SPEED_M_S
        blocked = slow & ~self._arrived & (self._yield_s <= 0.0) & in_way
        self._blocked_s = np.where(blocked, self._blocked_s + dt_s, 0.0)
        priority = np.concatenate([self._priority, np.full(len(c), np.inf)])
        outranked = self._priority < priority[blocker]
        steps_back = (self._blocked_s >= YIELD_AFTER_S) & outranked | (self._blocked_s >= FORCE_YIELD_AFTER_S)
        for k in np.nonzero(steps_back)[0]:
            away = -(others[blocker[k]] - self._pos[k])
            if blocker[k] >= n:  # a robot: head for a spot beside it, on the right of the way it wanted to go
                right = np.array([self._dirs[k, 1], -self._dirs[k, 0]])
                beside = c[blocker[k] - n, :2] + (c[blocker[k] - n, 2] + self.radius_m + ROBOT_PASSING_GAP_M) * right
                away = beside - self._pos[k]
            self._yield_dir[k] = away / max(float(np.linalg.norm(away)), 1e-9)
            self._yield_s[k] = self._rng.uniform(*YIELD_DURATION_S)
            self._blocked_s[k] = 0.0

    def _handle_stuck(self, walls: Segments) -> None:
        progressed = np.linalg.norm(self._pos - self._anchor_xy, axis=1) >= STUCK_PROGRESS_M
        reset = progressed | self._arrived
        self._anchor_xy[reset] = self._pos[reset]
        self._anchor_t[reset] = self._time_s
        for k in np.nonzero(self._time_s - self._anchor_t >= STUCK_TIME_S)[0]:
            _LOG.debug("pedestrian %d stuck at %s, re-planning", k, self._pos[k])
            self._plan(int(k), self._nearest_visible_node(self._pos[k], walls))
            self._anchor_xy[k] = self._pos[k]
            self._anchor_t[k] = self._time_s

    def _nearest_visible_node(self, xy: np.ndarray, walls: Segments, candidates: int = 8) -> int:
        """The nearest roadmap node in line of sight of ``xy`` among the closest few, else the nearest one."""
        order = np.argsort(np.linalg.norm(self._roadmap.nodes_xy - xy, axis=1))
        for node in order[:candidates]:
            if _visible(xy, self._roadmap.nodes_xy[node], walls):
                return int(node)
        return int(order[0])

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
        if len(self._walls):
            m = len(self._walls)
            _, d = self._walls.offsets(xy[None, :], np.zeros(m, dtype=np.int64), np.arange(m))
            if np.min(d) < r:
                return False
        if placed and np.min(np.linalg.norm(np.array(placed) - xy, axis=1)) < 2.0 * r:
            return False
        if len(keep_out) and np.any(np.linalg.norm(keep_out[:, :2] - xy, axis=1) < keep_out[:, 2] + r):
            return False
        return True


@njit(cache=True)
def _desired_update(dirs: np.ndarray, target: np.ndarray, pos: np.ndarray, yield_s: np.ndarray,
                    yield_dir: np.ndarray, speeds: np.ndarray, arrived: np.ndarray, yield_factor: float) -> np.ndarray:
    """Point ``dirs`` (N, 2, in place) at the targets, or along ``yield_dir`` while yielding; (N,) drive speeds.

    A pedestrian within 1 µm of its target keeps its direction; one yielding walks at ``yield_factor`` of its
    speed, one that has arrived stands (0). Positions in metres, speeds in m/s.
    """
    n = pos.shape[0]
    out = np.empty(n)
    for i in range(n):
        dx, dy = target[i, 0] - pos[i, 0], target[i, 1] - pos[i, 1]
        dist = math.sqrt(dx * dx + dy * dy)
        if dist > 1e-6:
            dirs[i, 0], dirs[i, 1] = dx / dist, dy / dist
        speed = speeds[i]
        if yield_s[i] > 0.0:
            dirs[i, 0], dirs[i, 1] = yield_dir[i, 0], yield_dir[i, 1]
            speed = yield_factor * speeds[i]
        out[i] = 0.0 if arrived[i] else speed
    return out


@njit(cache=True)
def _occupied_extra(targets: np.ndarray, circles: np.ndarray, radius_m: float, margin_m: float) -> np.ndarray:
    """(N,) the largest ``circle radius + radius_m`` over the circles (C, 3) whose rim comes within ``margin_m``
    of the pedestrian's rim about its target (N, 2), else 0 (all metres)."""
    n = targets.shape[0]
    out = np.zeros(n)
    for i in range(n):
        best = -np.inf
        for k in range(circles.shape[0]):
            dx, dy = targets[i, 0] - circles[k, 0], targets[i, 1] - circles[k, 1]
            gap = math.sqrt(dx * dx + dy * dy) - circles[k, 2] - radius_m
            best = max(best, circles[k, 2] + radius_m if gap < margin_m else 0.0)
        out[i] = best
    return out


@njit(cache=True)
def _closest_in_way(pos: np.ndarray, dirs: np.ndarray, others: np.ndarray, reach: np.ndarray,
                    cos_half_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Who stands in each pedestrian's way: (N,) whether anyone does, and (N,) the index of the closest (else 0).

    Args:
        pos: (N, 2) pedestrian centres, metres. dirs: (N, 2) unit desired directions.
        others: (K, 2) centres of the N pedestrians, then of the round obstacles, metres.
        reach: (K,) how far ahead each of ``others`` counts as in the way, metres.
        cos_half_angle: cosine of the half-angle of the cone ahead.
    """
    n, k_count = pos.shape[0], others.shape[0]
    in_way = np.zeros(n, dtype=np.bool_)
    blocker = np.zeros(n, dtype=np.int64)
    for i in range(n):
        best = np.inf
        for k in range(k_count):
            rx, ry = others[k, 0] - pos[i, 0], others[k, 1] - pos[i, 1]
            dist = math.sqrt(rx * rx + ry * ry)
            if k == i:
                dist += 1e9
            if rx * dirs[i, 0] + ry * dirs[i, 1] >= dist * cos_half_angle and dist < reach[k]:
                in_way[i] = True
                if dist < best:
                    best, blocker[i] = dist, k
    return in_way, blocker


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
