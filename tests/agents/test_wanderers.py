from __future__ import annotations

import math

import numpy as np

from simnav.agents import RoadmapGraph, Wanderers

DT = 0.05


def _grid_roadmap() -> RoadmapGraph:
    nodes = np.array([(x, y) for x in (0.0, 3.0, 6.0) for y in (0.0, 3.0, 6.0)] + [(9.0, 0.0)])
    edges = [(0, 1), (1, 2), (3, 4), (4, 5), (6, 7), (7, 8)]  # along y
    edges += [(0, 3), (3, 6), (1, 4), (4, 7), (2, 5), (5, 8), (6, 9)]  # along x, plus a dead end at node 9
    return RoadmapGraph(nodes, edges)


def _distance_to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * ab)))


def test_moves_along_edges_without_backtracking() -> None:
    roadmap = _grid_roadmap()
    bots = Wanderers(roadmap, 1, np.random.default_rng(3))
    travelled, visited = 0.0, []
    prev, nxt = int(bots.previous_nodes[0]), int(bots.next_nodes[0])
    pos, yaw = bots.positions_xy.copy(), bots.yaws_rad.copy()
    for _ in range(4000):
        bots.step(DT)
        np.testing.assert_allclose(bots.positions_xy - pos, bots.velocities_xy * DT, atol=1e-12)
        dyaw = (bots.yaws_rad - yaw + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_allclose(dyaw, bots.yaw_rates_rad_s * DT, atol=1e-12)
        assert np.all(np.abs(bots.yaw_rates_rad_s) <= 1.5 + 1e-12)
        assert np.linalg.norm(bots.velocities_xy[0]) <= 0.5 + 1e-12
        travelled += np.linalg.norm(bots.positions_xy[0] - pos[0])
        pos, yaw = bots.positions_xy.copy(), bots.yaws_rad.copy()
        new_prev, new_next = int(bots.previous_nodes[0]), int(bots.next_nodes[0])
        if new_next != nxt:
            assert new_prev == nxt and new_prev in roadmap.neighbors(new_next)
            assert new_next != prev or len(roadmap.neighbors(new_prev)) == 1
            visited.append(new_prev)
            prev, nxt = new_prev, new_next
        edge_gap = _distance_to_segment(pos[0], roadmap.nodes_xy[prev], roadmap.nodes_xy[nxt])
        assert edge_gap < 0.2
    assert travelled > 0.6 * 0.5 * 4000 * DT
    assert len(set(visited)) >= 5


def test_stops_for_something_ahead_only() -> None:
    roadmap = RoadmapGraph(np.array([[0.0, 0.0], [10.0, 0.0]]), [(0, 1)])
    bots = Wanderers(roadmap, 1, np.random.default_rng(0))
    heading = np.array([math.cos(bots.yaws_rad[0]), math.sin(bots.yaws_rad[0])])
    ahead = bots.positions_xy + 0.7 * heading
    bots.step(DT, ahead)
    assert np.linalg.norm(bots.velocities_xy[0]) == 0.0
    behind = bots.positions_xy - 0.7 * heading
    side = bots.positions_xy + 0.7 * np.array([-heading[1], heading[0]])
    bots.step(DT, np.concatenate([behind, side, bots.positions_xy + 3.0 * heading]))
    assert np.linalg.norm(bots.velocities_xy[0]) > 0.4


def test_head_on_robots_do_not_wait_forever_and_are_deterministic() -> None:
    roadmap = RoadmapGraph(np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0]]), [(0, 1), (1, 2)])

    def run(seed: int) -> Wanderers:
        bots = Wanderers(roadmap, 2, np.random.default_rng(seed), keep_out=np.array([[4.0, 0.0, 0.5]]))
        for _ in range(2000):
            bots.step(DT)
            gap = np.linalg.norm(bots.positions_xy[0] - bots.positions_xy[1])
            assert gap > 2 * bots.radius_m
        return bots

    a, b = run(1), run(1)
    np.testing.assert_array_equal(a.positions_xy, b.positions_xy)
    assert set(a.positions_xy[:, 0].round(3)) != {0.0, 8.0}


def test_spawns_along_edges_when_nodes_are_taken() -> None:
    roadmap = RoadmapGraph(np.array([[0.0, 0.0], [6.0, 0.0]]), [(0, 1)])
    bots = Wanderers(roadmap, 4, np.random.default_rng(2), keep_out=np.array([[3.0, 0.0, 0.5]]))
    pos = bots.positions_xy
    gaps = np.linalg.norm(pos[:, None] - pos[None], axis=2) + np.eye(4) * 9
    assert gaps.min() >= 2 * bots.radius_m
    assert np.all(np.abs(pos[:, 1]) < 1e-12) and np.all(np.abs(pos[:, 0] - 3.0) >= 0.5 + bots.radius_m)
