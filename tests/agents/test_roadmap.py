from __future__ import annotations

import numpy as np
import pytest

from simnav.agents.roadmap import RoadmapGraph
from simnav.world.schema import Roadmap


@pytest.fixture
def graph() -> RoadmapGraph:
    # 0 --- 1 --- 2          4 (isolated)
    #  \         /
    #   `-- 3 --'   (the detour 0-3-2 is longer than 0-1-2)
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, -3.0], [10.0, 10.0]])
    return RoadmapGraph(nodes, [(0, 1), (1, 2), (0, 3), (3, 2), (1, 0)])


def test_shortest_path_prefers_short_route(graph: RoadmapGraph) -> None:
    assert graph.shortest_path(0, 2) == [0, 1, 2]
    assert graph.shortest_path(2, 0) == [2, 1, 0]
    assert graph.shortest_path(3, 1) in ([3, 0, 1], [3, 2, 1])
    assert graph.path_length_m([0, 1, 2]) == pytest.approx(2.0)


def test_shortest_path_to_itself_and_unreachable(graph: RoadmapGraph) -> None:
    assert graph.shortest_path(2, 2) == [2]
    assert graph.shortest_path(0, 4) == []
    assert graph.shortest_path(4, 1) == []


def test_neighbors_nearest_and_edges(graph: RoadmapGraph) -> None:
    assert sorted(graph.neighbors(0)) == [1, 3]
    assert graph.neighbors(4) == []
    assert graph.nearest_node([1.9, 0.3]) == 2
    assert len(graph.edges) == 4  # the duplicate (1, 0) is dropped
    assert graph.nodes_xy.shape == (5, 2)


def test_random_node_excludes_and_is_seeded(graph: RoadmapGraph) -> None:
    draws = [graph.random_node(np.random.default_rng(7), exclude=2) for _ in range(3)]
    assert len(set(draws)) == 1
    rng = np.random.default_rng(0)
    picks = {graph.random_node(rng, exclude=2) for _ in range(200)}
    assert picks == {0, 1, 3, 4}


def test_from_spec_and_bad_edges() -> None:
    graph = RoadmapGraph.from_spec(Roadmap(nodes=[(0, 0), (3, 4)], edges=[(0, 1)]))
    assert graph.path_length_m(graph.shortest_path(0, 1)) == pytest.approx(5.0)
    with pytest.raises(ValueError):
        RoadmapGraph(np.zeros((2, 2)), [(0, 2)])
    with pytest.raises(ValueError):
        RoadmapGraph(np.zeros((0, 2)), [])
