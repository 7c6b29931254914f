"""Every shipped world loads, validates and has a connected, collision-free roadmap; scene-specific checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely import affinity, ops
from shapely.geometry import Polygon, box

from simnav.robot import load_robot
from simnav.robot.spec import RobotSpec
from simnav.world import footprint as fp
from simnav.world import list_worlds, load_world
from simnav.world.schema import WorldSpec

EXPECTED = {"contour_door", "contour_door_bar", "corridor", "curved", "desks", "flat", "office", "polygonal"}
WORLDS = sorted(list_worlds())
CONTOUR = {"contour_door", "contour_door_bar"}
BASE_BAND = (0.0, 0.3)
FULL_BAND = (0.0, 2.0)


def _node_band(name: str) -> tuple[float, float]:
    """The contour scenes' doorway node lies in the robot-shaped cut-out: only the base band is free there."""
    return BASE_BAND if name in CONTOUR else FULL_BAND


@pytest.fixture(scope="module", params=WORLDS)
def world(request: pytest.FixtureRequest) -> WorldSpec:
    return load_world(request.param)


def _posed(robot: RobotSpec, x: float, y: float, yaw_deg: float) -> list[tuple[Polygon, float, float]]:
    """Each prism's polygon in the world at pose (x, y, yaw), with its z band."""
    out = []
    for prism in robot.prisms:
        poly = affinity.rotate(Polygon(prism.polygon), yaw_deg, origin=(0.0, 0.0))
        out.append((affinity.translate(poly, x, y), prism.z_min_m, prism.z_max_m))
    return out


def test_shipped_worlds() -> None:
    assert EXPECTED <= set(WORLDS)


def test_loads_as_explicit_world(world: WorldSpec) -> None:
    assert isinstance(world, WorldSpec)
    assert world.generator is None
    assert world.name in WORLDS and world.description
    assert world.walls and world.roadmap is not None and world.spawns
    assert WorldSpec.model_validate(world.model_dump()) == world


def test_roadmap_connected(world: WorldSpec) -> None:
    assert world.roadmap is not None
    n = len(world.roadmap.nodes)
    e = np.asarray(world.roadmap.edges, dtype=int).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    assert connected_components(graph, directed=False)[0] == 1


def test_nodes_and_spawns_have_clearance(world: WorldSpec) -> None:
    assert world.roadmap is not None
    band = _node_band(world.name)
    nodes = np.asarray(world.roadmap.nodes)
    assert fp.clearance_m(world, nodes, *band).min() >= 0.3
    spawns = np.array([(s.x_m, s.y_m) for s in world.spawns])
    assert fp.clearance_m(world, spawns, *band).min() >= 0.3


EDGE_CASES = [(n, BASE_BAND) for n in WORLDS] + [(n, FULL_BAND) for n in WORLDS if n not in CONTOUR]


@pytest.mark.parametrize(("name", "band"), EDGE_CASES, ids=[f"{n}-{b[1]}m" for n, b in EDGE_CASES])
def test_edges_collision_free(name: str, band: tuple[float, float]) -> None:
    """Every edge buffered by 0.3 m misses the obstacles: at the robot base's height for all worlds, up to 2 m
    except for the contour scenes, whose doorway edges pass the cut-out (free only where the robot is)."""
    world = load_world(name)
    assert world.roadmap is not None
    obstacles = fp.obstacle_union(world, *band)
    nodes = world.roadmap.nodes
    edges = world.roadmap.edges
    blocked = [(i, j) for i, j in edges if not fp.segment_is_free(obstacles, nodes[i], nodes[j], 0.3)]
    assert blocked == []


def test_nodes_inside_the_walls(world: WorldSpec) -> None:
    assert world.roadmap is not None
    xmin, ymin, xmax, ymax = fp.bounds(world)
    walls = shapely.unary_union([fp.wall_polygon(w) for w in world.walls])
    outline = shapely.unary_union([Polygon(poly.exterior) for poly in getattr(walls, "geoms", [walls])])
    for x, y in world.roadmap.nodes:
        assert xmin < x < xmax and ymin < y < ymax
        assert outline.contains(shapely.Point(x, y))


def test_agents() -> None:
    expected = {"office": (10, 1), "flat": (2, 0), "corridor": (2, 0), "curved": (3, 0), "polygonal": (3, 0),
                "contour_door": (0, 0), "contour_door_bar": (0, 0), "desks": (2, 0)}
    for name, (people, robots) in expected.items():
        agents = load_world(name).agents
        assert (agents.pedestrians, agents.robots) == (people, robots), name


# --- scene-specific -----------------------------------------------------------------------------------------


def test_office_rooms() -> None:
    world = load_world("office")
    assert 6 <= len(world.doors) <= 10
    assert world.tables and world.chairs and world.shelves
    assert load_world("office").model_dump() == world.model_dump()


def test_flat_doorways_and_passages() -> None:
    world = load_world("flat")
    assert len(world.walls) >= 5
    obstacles = fp.obstacle_union(world, *FULL_BAND)
    # doorway nodes sit in 0.8 m gaps, the hallway is 1.0 m wide
    clear = fp.distance_to(obstacles, np.asarray(world.roadmap.nodes))
    assert (np.isclose(clear, 0.4)).sum() == 4
    assert fp.clearance_m(world, np.array([[3.0, 3.5]]))[0] == pytest.approx(0.5)
    assert world.tables and len(world.chairs) >= 2 and world.shelves and len(world.boxes) >= 3


def test_corridor_is_long_and_plain() -> None:
    world = load_world("corridor")
    xmin, ymin, xmax, ymax = fp.bounds(world)
    assert xmax - xmin >= 39.0
    assert fp.clearance_m(world, np.array([[20.0, 0.0]]))[0] == pytest.approx(1.0)
    assert not any([world.boxes, world.cylinders, world.tables, world.chairs, world.shelves, world.doors])
    assert all(y == 0.0 for _, y in world.roadmap.nodes)


def test_curved_walls_are_fine_polylines() -> None:
    world = load_world("curved")
    assert max(len(w.points) for w in world.walls) >= 40
    assert len(world.cylinders) >= 1
    xmin, ymin, xmax, ymax = fp.bounds(world)
    assert 9.0 <= xmax - xmin <= 11.0 and 7.0 <= ymax - ymin <= 9.0


def test_polygonal_room_has_oblique_corners() -> None:
    world = load_world("polygonal")
    outer = max(world.walls, key=lambda w: len(w.points))
    corners = outer.points[:-1] if outer.points[0] == outer.points[-1] else outer.points
    assert 8 <= len(corners) <= 14
    pts = np.asarray(corners)
    d = np.roll(pts, -1, axis=0) - pts
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos = np.sum(d * np.roll(d, 1, axis=0), axis=1)  # between each wall and the previous one
    assert np.sum(np.abs(cos) > 0.05) >= len(corners) - 2  # (almost) no right angles
    assert len(world.walls) >= 3  # interior pieces


def _sheet_yz(world: WorldSpec, x_door: float) -> shapely.Geometry:
    """The boxes in the doorway plane, as (y, z) rectangles."""
    return shapely.unary_union([
        box(b.center[1] - b.size_m[1] / 2, b.z_m, b.center[1] + b.size_m[1] / 2, b.z_m + b.size_m[2])
        for b in world.boxes
        if abs(b.center[0] - x_door) < 0.06
    ])


def _silhouette_yz(robot: RobotSpec, y: float) -> shapely.Geometry:
    """The robot's frontal (y, z) silhouette centred on ``y``."""
    parts = []
    for p in robot.prisms:
        ys = [q[1] for q in p.polygon]
        parts.append(box(y + min(ys), p.z_min_m, y + max(ys), p.z_max_m))
    return shapely.unary_union(parts)


@pytest.mark.parametrize("name", sorted(CONTOUR))
def test_contour_door_cut_out_matches_the_giraff(name: str) -> None:
    world = load_world(name)
    giraff = load_robot("giraff")
    doorway = box(2.5, 0.0, 3.5, 2.0)
    sheet = _sheet_yz(world, 8.0)
    assert sheet.covers(box(2.5, 1.65, 3.5, 2.0))  # solid above the head
    opening = doorway.difference(sheet)
    silhouette = _silhouette_yz(giraff, 3.0)
    # the cut-out is the silhouette plus 0.06 m each side (0.03 m higher/lower where the silhouette narrows)
    assert silhouette.buffer(0.06, join_style="mitre").covers(opening.buffer(-1e-6))
    thickness = [b.size_m[0] for b in world.boxes if abs(b.center[0] - 8.0) < 0.06 and b.z_m < 2.0]
    assert all(0.01 <= t <= 0.04 for t in thickness)
    if name == "contour_door":
        assert opening.covers(silhouette)
        assert silhouette.distance(sheet) >= 0.03 - 1e-9
    else:
        assert not opening.covers(silhouette)


def _prism_gap(world: WorldSpec, robot: RobotSpec, x: float, y: float, yaw_deg: float) -> float:
    """Smallest horizontal gap (metres) between the posed robot's prisms and the obstacles in their bands."""
    posed = _posed(robot, x, y, yaw_deg)
    return min(fp.obstacle_union(world, z0, z1).distance(poly) for poly, z0, z1 in posed)


def test_giraff_drives_through_the_cut_out() -> None:
    world = load_world("contour_door")
    giraff = load_robot("giraff")
    gaps = [_prism_gap(world, giraff, x, 3.0, 0.0) for x in np.arange(6.5, 9.6, 0.05)]
    assert min(gaps) >= 0.05
    assert world.roadmap.nodes[:3] == [(3.0, 3.0), (8.0, 3.0), (10.0, 3.0)]
    assert (0, 1) in world.roadmap.edges and (1, 2) in world.roadmap.edges
    spawn = world.spawns[0]
    assert math.dist((spawn.x_m, spawn.y_m), (8.0, 3.0)) == pytest.approx(5.0, abs=0.5)
    assert spawn.yaw_deg == 0.0  # facing the doorway


def test_bar_blocks_the_giraff() -> None:
    world = load_world("contour_door_bar")
    giraff = load_robot("giraff")
    gaps = [_prism_gap(world, giraff, x, 3.0, 0.0) for x in np.arange(6.5, 9.6, 0.05)]
    assert min(gaps) == 0.0
    # the base band is the same as without the bar: a 2D planner would not see the bar
    plain = load_world("contour_door")
    assert fp.obstacle_union(world, *BASE_BAND).equals(fp.obstacle_union(plain, *BASE_BAND))


def test_rhodon_reaches_over_every_desk() -> None:
    world = load_world("desks")
    rhodon = load_robot("rhodon")
    assert 5 <= len(world.tables) <= 7
    nodes = np.asarray(world.roadmap.nodes)
    arm = next(p for p in rhodon.prisms if p.name == "arm")
    reach = max(q[0] for q in arm.polygon)
    for table in world.tables:
        assert table.height_m == pytest.approx(0.74) and table.leg_inset_m == pytest.approx(0.12)
        top = fp.rectangle(table.center, table.size_m, table.yaw_deg)
        d = fp.distance_to(top, nodes)
        k = int(np.argmin(d))
        assert 0.45 <= d[k] <= 0.55
        # face the desk: towards the nearest point of the top
        near = ops.nearest_points(top, shapely.Point(nodes[k]))[0]
        yaw = math.degrees(math.atan2(near.y - nodes[k][1], near.x - nodes[k][0]))
        assert _prism_gap(world, rhodon, *nodes[k], yaw) > 0.0
        tip = nodes[k] + reach * np.array([math.cos(math.radians(yaw)), math.sin(math.radians(yaw))])
        assert top.contains(shapely.Point(tip))
        assert arm.z_min_m > table.height_m


def test_desks_aisles_are_wide() -> None:
    world = load_world("desks")
    obstacles = fp.obstacle_union(world, *FULL_BAND)
    nodes = np.asarray(world.roadmap.nodes)
    aisle = fp.distance_to(obstacles, nodes) >= 0.6
    edges = [(i, j) for i, j in world.roadmap.edges if aisle[i] and aisle[j]]
    assert len(edges) >= 8
    assert all(fp.segment_is_free(obstacles, nodes[i], nodes[j], 0.6) for i, j in edges)
