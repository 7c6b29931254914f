"""The office generator: layout, furniture, roadmap and determinism (simnav.world.generator)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely.geometry import Polygon

from simnav.world import footprint as fp
from simnav.world.generator import generate
from simnav.world.schema import Agents, Box, Door, OfficeGenerator, Roadmap, Spawn, WorldSpec


def _office(**params: object) -> WorldSpec:
    return generate(WorldSpec(name="o", description="d", generator=OfficeGenerator(**params)))


def _components(world: WorldSpec) -> int:
    assert world.roadmap is not None
    n = len(world.roadmap.nodes)
    e = np.asarray(world.roadmap.edges, dtype=int).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return int(connected_components(graph, directed=False)[0])


def _furniture(world: WorldSpec) -> int:
    kinds = (world.tables, world.chairs, world.shelves, world.boxes, world.cylinders)
    return sum(len(items) for items in kinds)


def _doorway_nodes(world: WorldSpec, corridor_width_m: float) -> list[tuple[float, float]]:
    """Roadmap nodes on a corridor wall's centreline (the doorway nodes)."""
    assert world.roadmap is not None
    return [p for p in world.roadmap.nodes if math.isclose(abs(p[1]), corridor_width_m / 2)]


def test_generated_world_is_explicit_and_keeps_the_header() -> None:
    agents = Agents(pedestrians=3, robots=2)
    spec = WorldSpec(name="o", description="d", generator=OfficeGenerator(), agents=agents)
    world = generate(spec)
    assert world.generator is None
    assert (world.name, world.description, world.agents) == ("o", "d", spec.agents)
    assert world.walls and world.roadmap is not None and world.spawns
    assert generate(world) is world  # explicit worlds pass through


@pytest.mark.parametrize("rooms", [2, 5, 8, 13])
def test_room_count_and_split(rooms: int) -> None:
    world = _office(rooms=rooms, seed=3)
    assert len(world.doors) == rooms
    north = sum(1 for d in world.doors if d.hinge[1] > 0)
    assert north == math.ceil(rooms / 2)
    assert len(_doorway_nodes(world, 2.2)) == rooms


def test_without_door_leaves_the_doorways_remain() -> None:
    world = _office(rooms=8, door_leaves=False)
    assert world.doors == []
    assert len(_doorway_nodes(world, 2.2)) == 8


def test_deterministic_per_seed() -> None:
    a = _office(seed=7, clutter_density=0.8)
    b = _office(seed=7, clutter_density=0.8)
    assert a.model_dump() == b.model_dump()


def test_different_seeds_differ() -> None:
    dumps = [_office(seed=s).model_dump() for s in range(4)]
    assert all(dumps[i] != dumps[j] for i in range(4) for j in range(i + 1, 4))
    lengths = {fp.bounds(_office(seed=s))[2] for s in range(4)}
    assert len(lengths) == 4  # room widths vary with the seed


def test_zero_clutter_gives_empty_rooms() -> None:
    world = _office(seed=1, clutter_density=0.0)
    assert _furniture(world) == 0
    assert len(world.doors) == 8


def test_clutter_density_adds_furniture() -> None:
    counts = [_furniture(_office(seed=2, clutter_density=d)) for d in (0.0, 0.3, 1.0)]
    assert counts[0] == 0 < counts[1] < counts[2]
    full = _office(seed=2, clutter_density=1.0)
    assert len(full.tables) == len(full.chairs) >= 8


def test_explicit_items_are_kept() -> None:
    extra = Box(center=(1.5, 0.0), size_m=(0.3, 0.3, 0.3))
    spec = WorldSpec(
        generator=OfficeGenerator(seed=4),
        boxes=[extra],
        spawns=[Spawn(x_m=5.0, y_m=0.0)],
        roadmap=Roadmap(nodes=[(5.0, 0.0), (6.0, 0.0)], edges=[(0, 1)]),
    )
    world = generate(spec)
    assert world.boxes[0] == extra
    assert world.spawns[0] == spec.spawns[0]
    assert world.roadmap is not None and world.roadmap.nodes[-2:] == [(5.0, 0.0), (6.0, 0.0)]
    # the generated roadmap and furniture keep clear of the explicit box
    n = len(world.roadmap.nodes) - 2
    extra_poly = fp.rectangle(extra.center, (0.3, 0.3), 0.0)
    assert fp.distance_to(extra_poly, np.array(world.roadmap.nodes[:n])).min() >= 0.5


PARAMS = [
    {"seed": s, "clutter_density": d} for s in range(5) for d in (0.0, 0.6, 1.0)
] + [
    {"seed": 1, "rooms": 2, "room_width_m": 2.0, "room_depth_m": 2.5, "door_width_m": 0.7},
    {"seed": 2, "rooms": 20, "corridor_width_m": 1.2, "clutter_density": 1.0},
    {"seed": 3, "rooms": 9, "corridor_width_m": 4.0, "door_width_m": 2.0, "clutter_density": 1.0},
    {"seed": 4, "rooms": 6, "room_width_m": 9.0, "room_depth_m": 8.0, "clutter_density": 1.0},
]


@pytest.mark.parametrize("params", PARAMS, ids=lambda p: ",".join(f"{k}={v}" for k, v in p.items()))
def test_roadmap_is_connected_and_free(params: dict[str, float]) -> None:
    world = _office(**params)
    assert world.roadmap is not None
    nodes = np.asarray(world.roadmap.nodes)
    assert _components(world) == 1
    obstacles = fp.obstacle_union(world, 0.0, 2.0)
    clearance = fp.distance_to(obstacles, nodes)
    gen = OfficeGenerator(**params)
    door_half = min(0.5, gen.door_width_m / 2) - 1e-6
    assert clearance.min() >= min(door_half, 0.3)
    doorway = set(_doorway_nodes(world, gen.corridor_width_m))
    off_doorways = [i for i, p in enumerate(world.roadmap.nodes) if p not in doorway]
    assert clearance[off_doorways].min() >= 0.5 - 1e-9
    for i, j in world.roadmap.edges:
        assert fp.segment_is_free(obstacles, nodes[i], nodes[j], 0.3), (i, j)
    # every room stays reachable: one doorway node per room survives the checks
    assert len(_doorway_nodes(world, gen.corridor_width_m)) == gen.rooms


@pytest.mark.parametrize("seed", range(6))
def test_rooms_have_one_to_three_nodes_beyond_the_inside_node(seed: int) -> None:
    gen = OfficeGenerator(seed=seed)
    world = _office(seed=seed)
    assert world.roadmap is not None
    depth_in = gen.corridor_width_m / 2 + 0.75 + 1e-6
    inner = [p for p in world.roadmap.nodes if abs(p[1]) > depth_in]
    assert gen.rooms <= len(inner) <= 3 * gen.rooms


@pytest.mark.parametrize("seed", range(8))
def test_spawns_on_corridor_facing_along_it(seed: int) -> None:
    world = _office(seed=seed, clutter_density=1.0)
    assert 2 <= len(world.spawns) <= 4
    assert world.roadmap is not None
    for s in world.spawns:
        assert (s.x_m, s.y_m) in world.roadmap.nodes
        assert s.y_m == 0.0 and s.yaw_deg in (0.0, 180.0)
    assert len({(s.x_m, s.y_m) for s in world.spawns}) == len(world.spawns)


@pytest.mark.parametrize("params", [{"seed": s, "clutter_density": 1.0} for s in range(6)]
                         + [{"seed": 0, "clutter_density": 1.0, "corridor_width_m": 2.6}])
def test_corridor_stays_wide(params: dict[str, float]) -> None:
    gen = OfficeGenerator(**params)
    world = _office(**params)
    obstacles = fp.obstacle_union(world, 0.0, 2.0)
    x_max = fp.bounds(world)[2]
    half = gen.corridor_width_m / 2 - gen.wall_thickness_m / 2 - 1e-3
    for x in np.arange(0.3, x_max - 0.3, 0.1):
        ys = np.linspace(-half, half, 201)
        free = fp.distance_to(obstacles, np.stack([np.full_like(ys, x), ys], axis=1)) > 0
        # the longest free run across the corridor at this x
        runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], free.astype(int), [0]]))))[::2]
        assert runs.max() * (ys[1] - ys[0]) >= 1.2 - 0.02, x


def test_corridor_clutter_only_above_half_density() -> None:
    for seed in range(4):
        world = _office(seed=seed, clutter_density=0.5)
        half = 1.1
        in_corridor = [b for b in world.boxes if abs(b.center[1]) < half] + [
            c for c in world.cylinders if abs(c.center[1]) < half
        ]
        assert in_corridor == []
    assert any(
        any(abs(c.center[1]) < 1.1 for c in [*w.boxes, *w.cylinders])
        for w in (_office(seed=s, clutter_density=1.0) for s in range(4))
    )


def test_doors_swing_into_their_rooms() -> None:
    world = _office(seed=5)
    for door in world.doors:
        open_yaw = math.radians(door.closed_yaw_deg + door.swing_deg)
        into_room = math.copysign(1.0, door.hinge[1])
        assert math.isclose(math.sin(open_yaw), into_room, abs_tol=1e-9)
        assert door.width_m == pytest.approx(1.0)
    assert len({d.phase_s for d in world.doors}) == len(world.doors)


def _swept_sector(door: Door) -> Polygon:
    """Floor area the leaf sweeps between closed and open."""
    yaws = np.radians(np.linspace(door.closed_yaw_deg, door.closed_yaw_deg + door.swing_deg, 19))
    hx, hy, r = door.hinge[0], door.hinge[1], door.width_m
    arc = [(hx + r * math.cos(a), hy + r * math.sin(a)) for a in yaws]
    return Polygon([door.hinge, *arc])


@pytest.mark.parametrize("seed", range(6))
def test_furniture_inside_rooms_and_clear_of_doorways(seed: int) -> None:
    world = _office(seed=seed, clutter_density=1.0)
    no_furniture = {"boxes": [], "cylinders": [], "tables": [], "chairs": [], "shelves": []}
    walls = fp.obstacle_union(world.model_copy(update=no_furniture))
    furniture = fp.obstacle_union(world.model_copy(update={"walls": []}))
    assert not furniture.intersects(walls)
    for door in world.doors:
        assert furniture.distance(_swept_sector(door)) > 0.1
        assert furniture.distance(fp.door_leaf_polygon(door)) > 0.1
