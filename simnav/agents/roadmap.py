"""Roadmap graph: nodes in free space (world frame, x/y on the floor, metres) joined by undirected edges.

Pedestrians and wandering robots move along this graph. Shortest paths use Dijkstra on Euclidean edge lengths.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

if TYPE_CHECKING:
    from simnav.world.schema import Roadmap

_MIN_EDGE_LENGTH_M = 1e-9  # keeps zero-length edges (duplicate nodes) as edges in the sparse graph


class RoadmapGraph:
    """Undirected graph with nodes at 2D positions.

    Args:
        nodes_xy: (K, 2) node positions in the world frame, metres.
        edges: pairs (i, j) of node indices, 0 <= i, j < K, i != j. Duplicates are ignored.

    Raises:
        ValueError: on an empty or malformed node array, or an edge outside 0..K-1 or from a node to itself.
    """

    def __init__(self, nodes_xy: np.ndarray, edges: Sequence[tuple[int, int]]) -> None:
        nodes = np.array(nodes_xy, dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 2 or nodes.shape[0] == 0:
            raise ValueError(f"nodes_xy must have shape (K, 2) with K >= 1, got {nodes.shape}")
        self._nodes = nodes
        self._nodes.flags.writeable = False
        self._edges = _unique_edges(edges, len(nodes))
        self._neighbors: list[list[int]] = [[] for _ in range(len(nodes))]
        for i, j in self._edges:
            self._neighbors[i].append(j)
            self._neighbors[j].append(i)
        self._graph = self._build_graph()
        self._predecessors: dict[int, np.ndarray] = {}

    @classmethod
    def from_spec(cls, roadmap: Roadmap) -> RoadmapGraph:
        """Build the graph of a world's ``roadmap`` section (:class:`simnav.world.schema.Roadmap`)."""
        return cls(np.asarray(roadmap.nodes, dtype=float), list(roadmap.edges))

    @property
    def nodes_xy(self) -> np.ndarray:
        """(K, 2) read-only node positions, world frame, metres."""
        return self._nodes

    @property
    def edges(self) -> list[tuple[int, int]]:
        """Unique undirected edges as (i, j) with i < j, in first-seen order."""
        return list(self._edges)

    @property
    def node_count(self) -> int:
        """Number of nodes K."""
        return len(self._nodes)

    def neighbors(self, i: int) -> list[int]:
        """Indices of the nodes joined to node ``i`` by an edge."""
        return list(self._neighbors[i])

    def nearest_node(self, xy: np.ndarray | Sequence[float]) -> int:
        """Index of the node closest (Euclidean) to the point ``xy`` (2,), metres."""
        d2 = np.sum((self._nodes - np.asarray(xy, dtype=float).reshape(1, 2)) ** 2, axis=1)
        return int(np.argmin(d2))

    def shortest_path(self, i: int, j: int) -> list[int]:
        """Shortest path (sum of Euclidean edge lengths) from node ``i`` to node ``j``.

        Returns:
            The node indices from ``i`` to ``j`` inclusive (``[i]`` when i == j); ``[]`` when ``j`` is
            unreachable.
        """
        if i == j:
            return [int(i)]
        pred = self._predecessor_row(int(i))
        if pred[j] < 0:
            return []
        path = [int(j)]
        while path[-1] != i:
            path.append(int(pred[path[-1]]))
        return path[::-1]

    def random_node(self, rng: np.random.Generator, exclude: int | None = None) -> int:
        """A uniformly drawn node index, different from ``exclude`` when the graph has another node."""
        k = len(self._nodes)
        if exclude is None or k == 1 or not 0 <= exclude < k:
            return int(rng.integers(k))
        node = int(rng.integers(k - 1))
        return node + 1 if node >= exclude else node

    def path_length_m(self, path: Sequence[int]) -> float:
        """Sum of the Euclidean lengths along ``path`` (node indices), metres; 0 for fewer than two nodes."""
        if len(path) < 2:
            return 0.0
        pts = self._nodes[np.asarray(path, dtype=int)]
        return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))

    def _build_graph(self) -> csr_matrix:
        k = len(self._nodes)
        if not self._edges:
            return csr_matrix((k, k))
        ij = np.asarray(self._edges, dtype=int)
        lengths = np.linalg.norm(self._nodes[ij[:, 0]] - self._nodes[ij[:, 1]], axis=1)
        lengths = np.maximum(lengths, _MIN_EDGE_LENGTH_M)
        rows = np.concatenate([ij[:, 0], ij[:, 1]])
        cols = np.concatenate([ij[:, 1], ij[:, 0]])
        return csr_matrix((np.concatenate([lengths, lengths]), (rows, cols)), shape=(k, k))

    def _predecessor_row(self, source: int) -> np.ndarray:
        row = self._predecessors.get(source)
        if row is None:
            _, row = dijkstra(self._graph, directed=False, indices=source, return_predecessors=True)
            self._predecessors[source] = row
        return row


def _unique_edges(edges: Sequence[tuple[int, int]], node_count: int) -> list[tuple[int, int]]:
    seen: set[tuple[int, int]] = set()
    unique: list[tuple[int, int]] = []
    for k, (i, j) in enumerate(edges):
        i, j = int(i), int(j)
        if not (0 <= i < node_count and 0 <= j < node_count) or i == j:
            raise ValueError(f"edge {k} = ({i}, {j}) must join two different nodes in 0..{node_count - 1}")
        key = (min(i, j), max(i, j))
        if key not in seen:
            seen.add(key)
            unique.append(key)
    return unique
