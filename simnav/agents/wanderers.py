"""Other robots: kinematic unicycles doing a random walk along roadmap edges.

World frame, x/y on the floor, SI units. Each robot drives toward its next node, turning at a limited yaw
rate and slowing down while its heading is off, and stops while something is close ahead. On reaching a node
it picks a random neighbour, not the node it came from unless that is the only one. A robot blocked for a few
seconds turns back, so two robots meeting head-on on an edge do not wait forever. Motion is semi-implicit
Euler: ``yaw_{k+1} = wrap(yaw_k + ω·dt)``, ``v_{k+1} = v·(cos yaw_{k+1}, sin yaw_{k+1})``,
``x_{k+1} = x_k + v_{k+1}·dt``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from simnav.agents.crowd import read_only_view
from simnav.agents.roadmap import RoadmapGraph

MAX_YAW_RATE_RAD_S = 1.5
HEADING_GAIN_1_S = 2.5
STOP_DISTANCE_M = 1.0
STOP_HALF_ANGLE_RAD = math.radians(45.0)
NODE_REACHED_M = 0.1
BLOCKED_TIMEOUT_S = 3.0
SPAWN_GAP_M = 0.2


class Wanderers:
    """Robots wandering along a roadmap.

    Args:
        roadmap: graph whose edges the robots follow.
        count: number of robots N.
        rng: source of all randomness (spawn nodes, next nodes).
        speed_m_s: cruising speed.
        radius_m: body radius.
        keep_out: (K, 3) circles ``[x, y, radius]`` (metres) where no robot may spawn, or None.

    Raises:
        ValueError: when no free spot is left for a robot (nodes first, then points along edges).
    """

    def __init__(
        self,
        roadmap: RoadmapGraph,
        count: int,
        rng: np.random.Generator,
        speed_m_s: float = 0.5,
        radius_m: float = 0.3,
        keep_out: np.ndarray | None = None,
    ) -> None:
        self._roadmap = roadmap
        self._nodes_xy = roadmap.nodes_xy
        self._no_obstacles = np.zeros((0, 2))
        self._rng = rng
        self._speed_m_s = speed_m_s
        self._radius_m = radius_m
        keep = np.zeros((0, 3)) if keep_out is None else np.asarray(keep_out, dtype=float).reshape(-1, 3)
        spots, prev, nxt = self._spawn(int(count), keep)
        self._pos = np.array(spots, dtype=float).reshape(-1, 2)
        self._prev = np.array(prev, dtype=np.int64)
        self._next = np.array(nxt, dtype=np.int64)
        self._yaw = np.array([self._heading_to(k) for k in range(len(spots))])
        self._vel = np.zeros_like(self._pos)
        self._yaw_rate = np.zeros(len(spots))
        self._blocked_s = np.zeros(len(spots))
        self._reached = np.zeros(len(spots), dtype=np.int64)  # _advance lists the robots at their next node here

    @property
    def count(self) -> int:
        """Number of robots N."""
        return len(self._pos)

    @property
    def radius_m(self) -> float:
        """Body radius, metres."""
        return self._radius_m

    @property
    def positions_xy(self) -> np.ndarray:
        """(N, 2) read-only centres, world frame, metres."""
        return read_only_view(self._pos)

    @property
    def yaws_rad(self) -> np.ndarray:
        """(N,) read-only headings, rad in [-π, π)."""
        return read_only_view(self._yaw)

    @property
    def velocities_xy(self) -> np.ndarray:
        """(N, 2) read-only velocities of the last step, m/s."""
        return read_only_view(self._vel)

    @property
    def yaw_rates_rad_s(self) -> np.ndarray:
        """(N,) read-only yaw rates of the last step, rad/s."""
        return read_only_view(self._yaw_rate)

    def motion_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(N, 2) positions (m), (N, 2) velocities (m/s), (N,) yaws (rad) and (N,) yaw rates (rad/s), world frame:
        the arrays themselves, not read-only views, for readers that only read them (a step replaces these
        arrays, never changes them)."""
        return self._pos, self._vel, self._yaw, self._yaw_rate

    @property
    def next_nodes(self) -> np.ndarray:
        """(N,) node each robot drives to (a copy)."""
        return self._next.copy()

    @property
    def previous_nodes(self) -> np.ndarray:
        """(N,) node each robot comes from (a copy)."""
        return self._prev.copy()

    def step(self, dt_s: float, obstacles_xy: np.ndarray | None = None) -> None:
        """Advance every robot by ``dt_s`` seconds.

        Args:
            dt_s: time step, seconds (> 0).
            obstacles_xy: (P, 2) positions (metres) of other moving things: people, the main robot. The other
                wanderers are taken into account as well.
        """
        if dt_s <= 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        if len(self._pos) == 0:
            return
        obstacles = obstacles_xy
        if obstacles is None:
            obstacles = self._no_obstacles
        elif not (type(obstacles) is np.ndarray and obstacles.dtype == np.float64 and obstacles.ndim == 2
                  and obstacles.shape[1] == 2 and obstacles.flags.c_contiguous):
            obstacles = np.ascontiguousarray(obstacles_xy, dtype=float)
            if obstacles.ndim != 2 or obstacles.shape[1] != 2:
                obstacles = obstacles.reshape(-1, 2)
        # headings, bearings, the drive and the blocked times in one pass
        self._yaw, self._yaw_rate, self._vel, self._pos, reached = _advance(
            self._pos, self._yaw, self._prev, self._next, self._blocked_s, self._nodes_xy, obstacles,
            self._speed_m_s, dt_s, min(HEADING_GAIN_1_S, 1.0 / dt_s), self._reached,
        )
        if reached:
            for k in self._reached[:reached]:
                self._leave_node(int(k))

    def _leave_node(self, k: int) -> None:
        """Robot k, at its next node, heads for a neighbour of it."""
        node = int(self._next[k])
        self._next[k] = self._pick_next(node, int(self._prev[k]))
        self._prev[k] = node

    def _pick_next(self, node: int, previous: int | None) -> int:
        options = self._roadmap.neighbors(node)
        if not options:
            return node
        forward = [n for n in options if n != previous]
        options = forward or options
        return int(options[int(self._rng.integers(len(options)))])

    def _heading_to(self, k: int) -> float:
        d = self._roadmap.nodes_xy[self._next[k]] - self._pos[k]
        if np.hypot(d[0], d[1]) < 1e-9:
            return float(self._rng.uniform(-math.pi, math.pi))
        return math.atan2(d[1], d[0])

    def _spawn(self, count: int, keep_out: np.ndarray) -> tuple[list[np.ndarray], list[int], list[int]]:
        """Spots (xy, previous node, next node): free nodes first, then random points along edges."""
        nodes_xy = self._roadmap.nodes_xy
        spots: list[np.ndarray] = []
        prev: list[int] = []
        order = self._rng.permutation(len(nodes_xy))
        degree = np.array([len(self._roadmap.neighbors(int(n))) for n in order])
        for node in np.concatenate([order[degree > 0], order[degree == 0]]):  # prefer nodes with an edge
            if len(spots) == count:
                break
            if self._free(nodes_xy[node], spots, keep_out):
                spots.append(nodes_xy[node].astype(float))
                prev.append(int(node))
        nxt = [self._pick_next(n, None) for n in prev]
        edges = self._roadmap.edges
        for _ in range(50 * count if edges else 0):
            if len(spots) == count:
                break
            i, j = edges[int(self._rng.integers(len(edges)))]
            if self._rng.uniform() < 0.5:
                i, j = j, i
            xy = nodes_xy[i] + self._rng.uniform() * (nodes_xy[j] - nodes_xy[i])
            if self._free(xy, spots, keep_out):
                spots.append(xy)
                prev.append(int(i))
                nxt.append(int(j))
        if len(spots) < count:
            raise ValueError(f"only {len(spots)} free spots on the roadmap for {count} wandering robots")
        return spots, prev, nxt

    def _free(self, xy: np.ndarray, spots: list[np.ndarray], keep_out: np.ndarray) -> bool:
        keep_gap = np.linalg.norm(keep_out[:, :2] - xy, axis=1) - keep_out[:, 2]
        if np.any(keep_gap < self._radius_m):
            return False
        too_close = 2 * self._radius_m + SPAWN_GAP_M
        return not spots or float(np.min(np.linalg.norm(np.array(spots) - xy, axis=1))) >= too_close


@njit(cache=True, error_model="numpy")
def _wrap(angle_rad: float) -> float:
    """``angle_rad`` wrapped to [-π, π) as :func:`simnav.agents.crowd.wrap_angle` does."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, error_model="numpy")
def _offsets(pos: np.ndarray, next_nodes: np.ndarray, nodes_xy: np.ndarray,
             obstacles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) offsets from the N robots to their next nodes, and (N, P, 2) to the points that may block them: the
    (P − N, 2) ``obstacles``, then the robots (metres)."""
    n, o = pos.shape[0], obstacles.shape[0]
    to_next, rel = np.empty((n, 2)), np.empty((n, o + n, 2))
    for i in range(n):
        to_next[i, 0], to_next[i, 1] = nodes_xy[next_nodes[i], 0] - pos[i, 0], nodes_xy[next_nodes[i], 1] - pos[i, 1]
        for k in range(o + n):
            px, py = (obstacles[k, 0], obstacles[k, 1]) if k < o else (pos[k - o, 0], pos[k - o, 1])
            rel[i, k, 0], rel[i, k, 1] = px - pos[i, 0], py - pos[i, 1]
    return to_next, rel


@njit(cache=True, error_model="numpy")
def _advance(pos: np.ndarray, yaw: np.ndarray, prev_nodes: np.ndarray, next_nodes: np.ndarray, blocked_s: np.ndarray,
             nodes_xy: np.ndarray, obstacles: np.ndarray, speed_m_s: float, dt_s: float, gain_1_s: float,
             reached: np.ndarray) -> tuple:
    """One step of N robots: :func:`_drive` on the directions of the :func:`_offsets` (libm's ``atan2``, within
    an ulp of numpy's ``arctan2``), then the blocked times (N,) counted and the edges of robots blocked for
    BLOCKED_TIMEOUT_S turned round, in place.

    Returns:
        New yaws (rad), yaw rates (rad/s), velocities (m/s), positions (m), and how many robots are within
        NODE_REACHED_M of their next nodes (their indices, ascending, written to ``reached`` (N,)).
    """
    n = pos.shape[0]
    to_next, rel = _offsets(pos, next_nodes, nodes_xy, obstacles)
    heading, bearing = np.empty(n), np.empty((n, rel.shape[1]))
    for i in range(n):
        heading[i] = math.atan2(to_next[i, 1], to_next[i, 0])
        for k in range(rel.shape[1]):
            bearing[i, k] = math.atan2(rel[i, k, 1], rel[i, k, 0])
    new_yaw, rate, vel, new_pos, blocked = _drive(pos, yaw, to_next, heading, rel, bearing, speed_m_s, dt_s,
                                                  gain_1_s)
    count = 0
    for i in range(n):
        blocked_s[i] = blocked_s[i] + dt_s if blocked[i] else 0.0
        if blocked_s[i] >= BLOCKED_TIMEOUT_S:
            prev_nodes[i], next_nodes[i] = next_nodes[i], prev_nodes[i]
            blocked_s[i] = 0.0
        dx, dy = nodes_xy[next_nodes[i], 0] - new_pos[i, 0], nodes_xy[next_nodes[i], 1] - new_pos[i, 1]
        if math.sqrt(dx * dx + dy * dy) < NODE_REACHED_M:
            reached[count] = i
            count += 1
    return new_yaw, rate, vel, new_pos, count


@njit(cache=True, error_model="numpy")
def _drive(pos: np.ndarray, yaw: np.ndarray, to_next: np.ndarray, heading: np.ndarray, rel: np.ndarray,
           bearing: np.ndarray, speed_m_s: float, dt_s: float,
           gain_1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One kinematic step of N robots: new yaws (rad), yaw rates (rad/s), velocities (m/s), positions (m) and
    whether each was blocked.

    Args:
        pos: (N, 2) metres. yaw: (N,) rad. to_next: (N, 2) offsets to the next nodes, metres.
        heading: (N,) their directions, rad. rel: (N, P, 2) offsets to the P points that may block, metres.
        bearing: (N, P) their directions, rad. speed_m_s: cruising speed. dt_s: step, s.
        gain_1_s: heading gain, at most 1/dt_s.
    """
    n, p = rel.shape[0], rel.shape[1]
    new_yaw, rate, vel, new_pos = np.empty(n), np.empty(n), np.empty((n, 2)), np.empty((n, 2))
    blocked = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        # turn towards the next node, slowing down while the heading is off
        dist = math.sqrt(to_next[i, 0] * to_next[i, 0] + to_next[i, 1] * to_next[i, 1])
        error = _wrap(heading[i] - yaw[i]) if dist > 1e-6 else 0.0
        turn = min(abs(error) * gain_1_s, MAX_YAW_RATE_RAD_S)
        rate[i] = (1.0 if error > 0 else -1.0 if error < 0 else 0.0) * turn  # never past the heading in one step
        speed = min(speed_m_s * max(math.cos(error), 0.0) ** 2, dist / dt_s)
        # stop while a point is close ahead (a robot does not block itself)
        for k in range(p):
            d = math.sqrt(rel[i, k, 0] * rel[i, k, 0] + rel[i, k, 1] * rel[i, k, 1])
            if d <= STOP_DISTANCE_M and d > 1e-9 and abs(_wrap(bearing[i, k] - yaw[i])) <= STOP_HALF_ANGLE_RAD:
                blocked[i] = True
        if blocked[i]:
            speed = 0.0
        # semi-implicit Euler
        new_yaw[i] = _wrap(yaw[i] + rate[i] * dt_s)
        vel[i, 0], vel[i, 1] = speed * math.cos(new_yaw[i]), speed * math.sin(new_yaw[i])
        new_pos[i, 0], new_pos[i, 1] = pos[i, 0] + vel[i, 0] * dt_s, pos[i, 1] + vel[i, 1] * dt_s
    return new_yaw, rate, vel, new_pos, blocked
