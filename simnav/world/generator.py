"""Office generator: rooms on both sides of a straight corridor, furnished from a seeded random generator.

Layout (``world`` frame, metres): the corridor runs along +x from ``x = 0`` to ``x = L`` with its centreline
on ``y = 0`` and wall centrelines at ``y = +-corridor_width_m / 2``. ``ceil(rooms / 2)`` rooms lie north (+y)
of it, the rest south; each row spans the whole corridor length, so room widths are ``room_width_m`` +-15 %
and the shorter row is stretched to the length of the longer one. Every room has one doorway (a gap in the
corridor wall) with an optional hinged leaf that swings 90 degrees into the room.

The roadmap has nodes on the corridor centreline (one in front of every doorway, gaps filled every <= 3 m),
one in every doorway, one just inside every room and 1-3 in each room's free space. Furniture is only placed
where it keeps a 0.65 m-wide-each-side path from the doorway to the room centre and the door's swing free;
afterwards every node is checked for >= 0.5 m clearance and every edge for a 0.3 m free buffer (band 0-2 m,
doors left out), and the largest connected part of the graph is kept.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely.geometry import LineString, Point, Polygon, box
from shapely.geometry.base import BaseGeometry

from simnav.world import footprint
from simnav.world.schema import (
    Box,
    Chair,
    Cylinder,
    Door,
    OfficeGenerator,
    Roadmap,
    Shelf,
    Spawn,
    Table,
    Vec2,
    Wall,
    WorldSpec,
)

NODE_CLEARANCE_M = 0.5
"""Minimum distance from a roadmap node to any obstacle (doorway nodes: half the gap if narrower)."""
EDGE_RADIUS_M = 0.3
"""Half-width of the free strip every roadmap edge needs."""
PATH_KEEPOUT_M = 0.65
"""Half-width of the furniture-free strip from a doorway to its room's centre."""
MIN_CORRIDOR_FREE_M = 1.2
"""Free corridor width that corridor clutter must leave."""
CORRIDOR_NODE_SPACING_M = 2.5
INSIDE_OFFSET_M = 0.75
"""Distance of the room-inside node from the corridor wall's centreline."""
DOOR_MARGIN_M = 0.15
"""Minimum wall length between a doorway and the room's side wall."""
ATTEMPTS = 40
"""Placement attempts per furniture item."""

DESK_SIZES_M = ((1.2, 0.6), (1.4, 0.7), (1.6, 0.8))
SHELF_SIZES_M = ((0.9, 0.35, 1.8), (0.8, 0.4, 2.0), (1.2, 0.35, 1.6))
CABINET_SIZES_M = ((0.6, 0.5, 1.1), (0.6, 0.6, 1.0), (0.8, 0.45, 0.75))
CHAIR_SEAT_M = 0.45
CHAIR_OFFSET_M = 0.2
"""Chair centre behind the desk's free edge (the seat slides partly under the top)."""


def _r(v: float) -> float:
    """Round to millimetres (tidy YAML dumps, exact comparisons)."""
    return round(float(v), 3)


def _xy(p: np.ndarray | tuple[float, float]) -> Vec2:
    return (_r(p[0]), _r(p[1]))


@dataclass
class _Room:
    """One room: wall centrelines, doorway and the interior rectangle (wall faces), world frame, metres."""

    x0: float
    x1: float
    north: bool
    y_wall: float  # corridor wall centreline
    y_back: float  # outer wall centreline
    gap: tuple[float, float] = (0.0, 0.0)
    interior: Polygon = field(default_factory=Polygon)

    @property
    def sign(self) -> float:
        """+1 for a north room (into the room is +y), -1 for a south room."""
        return 1.0 if self.north else -1.0

    @property
    def doorway(self) -> Vec2:
        return (_r(0.5 * (self.gap[0] + self.gap[1])), self.y_wall)

    @property
    def inside(self) -> Vec2:
        return (self.doorway[0], _r(self.y_wall + self.sign * INSIDE_OFFSET_M))

    @property
    def centre(self) -> Vec2:
        c = self.interior.centroid
        return (_r(c.x), _r(c.y))


@dataclass
class _Graph:
    """Roadmap under construction: nodes, their required clearance and kind, undirected edges."""

    nodes: list[Vec2] = field(default_factory=list)
    clearance: list[float] = field(default_factory=list)
    kind: list[str] = field(default_factory=list)
    edges: list[tuple[int, int]] = field(default_factory=list)

    def add(self, xy: Vec2, kind: str, clearance: float = NODE_CLEARANCE_M) -> int:
        self.nodes.append(_xy(xy))
        self.clearance.append(clearance)
        self.kind.append(kind)
        return len(self.nodes) - 1

    def link(self, i: int, j: int) -> None:
        if i != j and (i, j) not in self.edges and (j, i) not in self.edges:
            self.edges.append((i, j))

    def keepout(self, radius_m: float) -> BaseGeometry:
        """Union of the nodes and edges buffered by ``radius_m``."""
        geoms = [Point(p).buffer(radius_m) for p in self.nodes]
        geoms += [LineString([self.nodes[i], self.nodes[j]]).buffer(radius_m) for i, j in self.edges]
        return shapely.unary_union(geoms)


@dataclass
class _Items:
    """Generated obstacles, in the schema's types."""

    walls: list[Wall] = field(default_factory=list)
    boxes: list[Box] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    chairs: list[Chair] = field(default_factory=list)
    shelves: list[Shelf] = field(default_factory=list)
    doors: list[Door] = field(default_factory=list)


def generate(spec: WorldSpec) -> WorldSpec:
    """Expand a generated world into explicit geometry, roadmap and spawns.

    Args:
        spec: a world with ``generator`` set (an explicit world is returned unchanged).

    Returns:
        A copy of ``spec`` with ``generator=None``: its explicit items plus the generated walls, doors and
        furniture, the generated roadmap (explicit roadmap nodes and edges appended after it) and spawns
        (explicit spawns first). Name, description and agents are kept. Deterministic in ``generator.seed``.
    """
    if spec.generator is None:
        return spec
    gen = spec.generator
    rng = np.random.default_rng(gen.seed)
    rooms, length = _layout(gen, rng)
    items = _Items(walls=_walls(gen, rooms, length))
    if gen.door_leaves:
        items.doors = [_door(gen, room, rng) for room in rooms]
    graph, anchors = _skeleton(gen, rooms, length)
    fixed = footprint.obstacle_polygons(spec) + [footprint.wall_polygon(w) for w in items.walls]
    placed: list[Polygon] = []
    if gen.clutter_density > 0.5:
        placed += _corridor_clutter(gen, rooms, length, graph, fixed, items, rng)
    for room in rooms:
        placed += _furnish(gen, room, fixed + placed, items, rng)
    for room, anchor in zip(rooms, anchors, strict=True):
        _room_nodes(room, anchor, graph, fixed + placed, items, rng)
    graph = _prune(graph, shapely.unary_union(fixed + placed))
    spawns = _spawns(graph, rng)
    return _assemble(spec, items, _roadmap(graph), spawns)


# --- layout -------------------------------------------------------------------------------------------------


def _row_widths(gen: OfficeGenerator, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count,) room widths (wall centre to wall centre), ``room_width_m`` +-15 %."""
    return gen.room_width_m * (1.0 + rng.uniform(-0.15, 0.15, size=count))


def _layout(gen: OfficeGenerator, rng: np.random.Generator) -> tuple[list[_Room], float]:
    """Rooms of both rows with their doorways; returns the rooms and the corridor length L (metres)."""
    n_north = math.ceil(gen.rooms / 2)
    rows = [_row_widths(gen, n_north, rng), _row_widths(gen, gen.rooms - n_north, rng)]
    length = _r(max(float(w.sum()) for w in rows))
    half, t = 0.5 * gen.corridor_width_m, gen.wall_thickness_m
    rooms: list[_Room] = []
    for north, widths in zip((True, False), rows, strict=True):
        edges = np.concatenate([[0.0], np.cumsum(widths * (length / widths.sum()))])
        edges[-1] = length
        sign = 1.0 if north else -1.0
        for x0, x1 in zip(edges[:-1], edges[1:], strict=True):
            room = _Room(_r(x0), _r(x1), north, _r(sign * half), _r(sign * (half + gen.room_depth_m)))
            y_lo, y_hi = sorted((room.y_wall + sign * t / 2, room.y_back - sign * t / 2))
            room.interior = box(room.x0 + t / 2, y_lo, room.x1 - t / 2, y_hi)
            room.gap = _doorway_gap(gen, room, rng)
            rooms.append(room)
    return rooms, length


def _doorway_gap(gen: OfficeGenerator, room: _Room, rng: np.random.Generator) -> tuple[float, float]:
    """(x_start, x_end) of the room's doorway, at a random place along its corridor wall."""
    lo = room.x0 + gen.wall_thickness_m / 2 + DOOR_MARGIN_M
    hi = room.x1 - gen.wall_thickness_m / 2 - DOOR_MARGIN_M
    width = min(gen.door_width_m, hi - lo)
    start = lo + rng.uniform(0.0, 1.0) * (hi - lo - width)
    return (_r(start), _r(start + width))


def _walls(gen: OfficeGenerator, rooms: list[_Room], length: float) -> list[Wall]:
    """Outer rectangle, the two corridor walls (interrupted by the doorways) and the room partitions."""
    north = [r for r in rooms if r.north]
    south = [r for r in rooms if not r.north]
    y_n, y_s = north[0].y_back, south[0].y_back
    kw = {"thickness_m": gen.wall_thickness_m, "height_m": gen.wall_height_m}
    walls = [Wall(points=[(0.0, y_s), (length, y_s), (length, y_n), (0.0, y_n), (0.0, y_s)], **kw)]
    for row in (north, south):
        y = row[0].y_wall
        xs = [0.0] + [v for r in sorted(row, key=lambda r: r.x0) for v in r.gap] + [length]
        pieces = zip(xs[::2], xs[1::2], strict=True)
        walls += [Wall(points=[(a, y), (b, y)], **kw) for a, b in pieces if b > a]
        walls += [Wall(points=[(r.x1, r.y_wall), (r.x1, r.y_back)], **kw) for r in row[:-1]]
    return walls


def _door(gen: OfficeGenerator, room: _Room, rng: np.random.Generator) -> Door:
    """A leaf hinged at one side of the doorway, closed across it, opening 90 degrees into the room."""
    at_start = bool(rng.integers(0, 2))
    hinge = (room.gap[0] if at_start else room.gap[1], room.y_wall)
    swing = 90.0 if at_start == room.north else -90.0
    phase = rng.uniform(0.0, 26.0)
    return Door(
        hinge=hinge,
        width_m=_r(room.gap[1] - room.gap[0]),
        closed_yaw_deg=0.0 if at_start else 180.0,
        swing_deg=swing,
        height_m=min(2.0, gen.wall_height_m),
        phase_s=round(float(phase), 2),
    )


# --- roadmap skeleton ---------------------------------------------------------------------------------------


def _corridor_xs(gen: OfficeGenerator, rooms: list[_Room], length: float) -> list[float]:
    """x of the corridor centreline nodes: one within 0.4 m of every doorway's x, ends and gaps filled."""
    end = gen.wall_thickness_m / 2 + 0.8
    clusters: list[list[float]] = []
    for x in sorted(r.doorway[0] for r in rooms):
        if clusters and x - clusters[-1][0] < 0.8:
            clusters[-1].append(x)
        else:
            clusters.append([x])
    xs = [sum(c) / len(c) for c in clusters]
    if xs[0] > end + 0.8:
        xs.insert(0, end)
    if xs[-1] < length - end - 0.8:
        xs.append(length - end)
    filled = [xs[0]]
    for a, b in zip(xs[:-1], xs[1:], strict=True):
        k = math.ceil((b - a) / CORRIDOR_NODE_SPACING_M - 0.2)
        filled += [a + (b - a) * i / k for i in range(1, k + 1)] if k > 1 else [b]
    return [_r(x) for x in filled]


def _skeleton(gen: OfficeGenerator, rooms: list[_Room], length: float) -> tuple[_Graph, list[int]]:
    """Corridor chain, then per room: nearest corridor node - doorway - inside - centre.

    Returns:
        The graph and, per room, the node that its further room nodes attach to (centre, or inside if the room
        is too shallow for a separate centre node).
    """
    graph = _Graph()
    corridor = [graph.add((x, 0.0), "corridor") for x in _corridor_xs(gen, rooms, length)]
    for a, b in zip(corridor[:-1], corridor[1:], strict=True):
        graph.link(a, b)
    anchors = []
    for room in rooms:
        gap_half = 0.5 * (room.gap[1] - room.gap[0])
        door = graph.add(room.doorway, "doorway", min(NODE_CLEARANCE_M, gap_half - 1e-6))
        near = min(corridor, key=lambda i: abs(graph.nodes[i][0] - room.doorway[0]))
        inside = graph.add(room.inside, "inside")
        graph.link(near, door)
        graph.link(door, inside)
        anchors.append(inside)
        if math.dist(room.inside, room.centre) >= 0.8:
            anchors[-1] = graph.add(room.centre, "room")
            graph.link(inside, anchors[-1])
    return graph, anchors


# --- furniture ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Side:
    """A wall face of a room interior: origin, unit tangent t along the face, inward normal n = rot90(t)."""

    origin: np.ndarray
    t: np.ndarray
    length: float

    @property
    def n(self) -> np.ndarray:
        return np.array([-self.t[1], self.t[0]])

    @property
    def yaw_deg(self) -> float:
        return math.degrees(math.atan2(self.t[1], self.t[0]))

    def at(self, s: float, depth: float) -> np.ndarray:
        """World point ``s`` along the face and ``depth`` into the room."""
        return self.origin + s * self.t + depth * self.n


def _sides(interior: Polygon) -> list[_Side]:
    """The four wall faces of a rectangular interior, counter-clockwise."""
    x0, y0, x1, y1 = interior.bounds
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    sides = []
    for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
        a_, b_ = np.asarray(a), np.asarray(b)
        length = float(np.linalg.norm(b_ - a_))
        sides.append(_Side(a_, (b_ - a_) / length, length))
    return sides


def _room_keepout(room: _Room) -> BaseGeometry:
    """Doorway-to-centre path strip plus the door's swing square; furniture stays out of it."""
    path = LineString([room.doorway, room.inside, room.centre]).buffer(PATH_KEEPOUT_M)
    width = room.gap[1] - room.gap[0]
    y_far = room.y_wall + room.sign * (width + 0.15)
    swing = box(room.gap[0] - 0.15, min(room.y_wall, y_far), room.gap[1] + 0.15, max(room.y_wall, y_far))
    return shapely.unary_union([path, swing])


Register = Callable[[], None]
Maker = Callable[[_Side, float], tuple[list[Polygon], Register]]


def _place(
    maker: Maker,
    along_m: float,
    room_poly: Polygon,
    keepout: BaseGeometry,
    others: list[Polygon],
    rng: np.random.Generator,
) -> list[Polygon] | None:
    """Try random wall positions for an item; on success register it and return its footprints, else None.

    ``maker(side, s)`` builds the footprints of an item centred ``s`` metres along ``side`` and a function
    that adds the item to :class:`_Items`; ``along_m`` is the item's extent along the wall.
    """
    sides = _sides(room_poly)
    inner = room_poly.buffer(-0.005)
    for _ in range(ATTEMPTS):
        side = sides[int(rng.integers(0, 4))]
        if side.length < along_m + 0.1:
            continue
        s = float(rng.uniform(0.05 + along_m / 2, side.length - 0.05 - along_m / 2))
        polys, register = maker(side, s)
        shape = shapely.unary_union(polys)
        if not inner.contains(shape) or shape.intersects(keepout):
            continue
        if any(shape.distance(o) < 0.1 for o in others):
            continue
        register()
        return polys
    return None


def _desk_maker(items: _Items, rng: np.random.Generator) -> tuple[Maker, float]:
    """A desk against the wall with a chair at its free edge, facing the wall."""
    size = DESK_SIZES_M[int(rng.integers(0, len(DESK_SIZES_M)))]

    def make(side: _Side, s: float) -> tuple[list[Polygon], Register]:
        centre = side.at(s, 0.03 + size[1] / 2)
        table = Table(center=_xy(centre), size_m=size, yaw_deg=_r(side.yaw_deg))
        chair_xy = side.at(s, 0.03 + size[1] + CHAIR_OFFSET_M)
        chair = Chair(center=_xy(chair_xy), yaw_deg=_r(side.yaw_deg - 90.0), seat_size_m=CHAIR_SEAT_M)
        polys = footprint.table_polygons(table, 0.0, 2.0) + [
            footprint.rectangle(chair.center, (CHAIR_SEAT_M, CHAIR_SEAT_M), chair.yaw_deg)
        ]

        def register() -> None:
            items.tables.append(table)
            items.chairs.append(chair)

        return polys, register

    return make, size[0]


def _shelf_maker(items: _Items, rng: np.random.Generator) -> tuple[Maker, float]:
    """An open shelf with its back to the wall."""
    size = SHELF_SIZES_M[int(rng.integers(0, len(SHELF_SIZES_M)))]
    levels = int(rng.integers(4, 6))

    def make(side: _Side, s: float) -> tuple[list[Polygon], Register]:
        centre = _xy(side.at(s, 0.02 + size[1] / 2))
        shelf = Shelf(center=centre, size_m=size, yaw_deg=_r(side.yaw_deg), levels=levels)
        polys = [footprint.rectangle(shelf.center, size[:2], shelf.yaw_deg)]
        return polys, lambda: items.shelves.append(shelf)

    return make, size[0]


def _cabinet_maker(items: _Items, rng: np.random.Generator) -> tuple[Maker, float]:
    """A cabinet or printer: a box against the wall."""
    size = CABINET_SIZES_M[int(rng.integers(0, len(CABINET_SIZES_M)))]
    color = (0.3, 0.3, 0.32) if size[2] < 1.05 else (0.62, 0.6, 0.56)

    def make(side: _Side, s: float) -> tuple[list[Polygon], Register]:
        centre = _xy(side.at(s, 0.02 + size[1] / 2))
        item = Box(center=centre, size_m=size, yaw_deg=_r(side.yaw_deg), color=color)
        return [footprint.rectangle(item.center, size[:2], item.yaw_deg)], lambda: items.boxes.append(item)

    return make, size[0]


def _round_maker(items: _Items, rng: np.random.Generator) -> tuple[Maker, float]:
    """A bin (low, small) or a plant pot (tall, green) by the wall."""
    plant = bool(rng.integers(0, 2))
    radius, height = (0.22, 1.1) if plant else (0.15, 0.4)
    color = (0.25, 0.5, 0.25) if plant else (0.2, 0.2, 0.22)

    def make(side: _Side, s: float) -> tuple[list[Polygon], Register]:
        item = Cylinder(center=_xy(side.at(s, 0.03 + radius)), radius_m=radius, height_m=height, color=color)
        circle = Point(item.center).buffer(radius, quad_segs=footprint.CIRCLE_QUAD_SEGS)
        return [circle], lambda: items.cylinders.append(item)

    return make, 2 * radius


def _furnish(
    gen: OfficeGenerator, room: _Room, obstacles: list[Polygon], items: _Items, rng: np.random.Generator
) -> list[Polygon]:
    """Desks with chairs, shelves, maybe a cabinet and a bin/plant, all against walls; returns footprints."""
    d = gen.clutter_density
    makers = [_desk_maker] * int(rng.binomial(3, d)) + [_shelf_maker] * int(rng.binomial(2, d))
    makers += [_cabinet_maker] * int(rng.random() < 0.5 * d) + [_round_maker] * int(rng.random() < 0.6 * d)
    keepout = _room_keepout(room)
    others = [o for o in obstacles if o.intersection(room.interior).area > 1e-9]
    placed: list[Polygon] = []
    for factory in makers:
        make, along = factory(items, rng)
        polys = _place(make, along, room.interior, keepout, others + placed, rng)
        if polys is not None:
            placed += polys
    return placed


def _corridor_clutter(
    gen: OfficeGenerator,
    rooms: list[_Room],
    length: float,
    graph: _Graph,
    obstacles: list[Polygon],
    items: _Items,
    rng: np.random.Generator,
) -> list[Polygon]:
    """A few bins and cabinets by the corridor walls, keeping >= 1.2 m free and the roadmap clear."""
    t = gen.wall_thickness_m
    free = gen.corridor_width_m - t
    max_depth = min(free - MIN_CORRIDOR_FREE_M, free / 2 - NODE_CLEARANCE_M) - 0.03
    if max_depth < 0.3:
        return []
    approaches = [box(r.gap[0] - 0.6, r.y_wall - 0.6, r.gap[1] + 0.6, r.y_wall + 0.6) for r in rooms]
    keepout = shapely.unary_union([graph.keepout(NODE_CLEARANCE_M + 0.05), *approaches])
    placed: list[Polygon] = []
    spans: list[tuple[float, float]] = []
    for _ in range(int(rng.integers(1, 4))):
        for _attempt in range(ATTEMPTS):
            item, poly, (lo, hi) = _corridor_item(gen, length, max_depth, rng)
            if poly.intersects(keepout) or any(lo < b + 0.5 and hi > a - 0.5 for a, b in spans):
                continue
            if any(poly.distance(o) < 0.02 for o in obstacles):
                continue
            (items.cylinders if isinstance(item, Cylinder) else items.boxes).append(item)
            placed.append(poly)
            spans.append((lo, hi))
            break
    return placed


def _corridor_item(
    gen: OfficeGenerator, length: float, max_depth: float, rng: np.random.Generator
) -> tuple[Box | Cylinder, Polygon, tuple[float, float]]:
    """A random bin or cabinet by one corridor wall; returns it, its footprint and its x extent."""
    sign = 1.0 if rng.integers(0, 2) else -1.0
    face = sign * (gen.corridor_width_m / 2 - gen.wall_thickness_m / 2)
    x = float(rng.uniform(0.5, length - 0.5))
    if rng.random() < 0.6:
        r = min(0.18, max_depth / 2)
        centre = _xy((x, face - sign * (0.04 + r)))
        bin_ = Cylinder(center=centre, radius_m=r, height_m=0.6, color=(0.2, 0.35, 0.6))
        return bin_, Point(centre).buffer(r, quad_segs=footprint.CIRCLE_QUAD_SEGS), (x - r, x + r)
    depth = min(0.45, max_depth - 0.04)
    size = (0.8, depth, 1.0)
    item = Box(center=_xy((x, face - sign * (0.03 + depth / 2))), size_m=size, color=(0.62, 0.6, 0.56))
    return item, footprint.rectangle(item.center, size[:2], 0.0), (x - 0.4, x + 0.4)


# --- room nodes, pruning, spawns ----------------------------------------------------------------------------


def _room_nodes(
    room: _Room, anchor: int, graph: _Graph, obstacles: list[Polygon], items: _Items, rng: np.random.Generator
) -> None:
    """Add up to two nodes in the room's free space (in front of desks first), linked to ``anchor``."""
    near = [o for o in obstacles if o.distance(room.interior) < 2.0]
    local = shapely.unary_union([*near, room.interior.exterior.buffer(0.001)])
    fronts = [_desk_front(t, room) for t in items.tables if room.interior.contains(Point(t.center))]
    x0, y0, x1, y1 = room.interior.bounds
    randoms = rng.uniform((x0, y0), (x1, y1), size=(12, 2))
    candidates = [c for c in fronts if c is not None] + [(float(x), float(y)) for x, y in randoms]
    added = 0
    for cand in candidates:
        if added == 2:
            break
        cand = _xy(cand)
        if not room.interior.contains(Point(cand)) or local.distance(Point(cand)) < NODE_CLEARANCE_M + 0.05:
            continue
        if any(math.dist(cand, p) < 1.0 for p in graph.nodes):
            continue
        if not footprint.segment_is_free(local, graph.nodes[anchor], cand, EDGE_RADIUS_M + 0.05):
            continue
        graph.link(anchor, graph.add(cand, "room"))
        added += 1


def _desk_front(table: Table, room: _Room) -> Vec2 | None:
    """A point in front of the desk, beyond its chair (the desk's free edge faces into the room)."""
    yaw = math.radians(table.yaw_deg + 90.0)
    depth = table.size_m[1] / 2 + CHAIR_OFFSET_M + CHAIR_SEAT_M / 2 + NODE_CLEARANCE_M + 0.15
    p = (table.center[0] + depth * math.cos(yaw), table.center[1] + depth * math.sin(yaw))
    return p if room.interior.contains(Point(p)) else None


def _prune(graph: _Graph, obstacles: BaseGeometry) -> _Graph:
    """Drop nodes closer than their clearance to ``obstacles``, colliding edges, all but the largest part."""
    xy = np.asarray(graph.nodes)
    ok = footprint.distance_to(obstacles, xy) >= np.asarray(graph.clearance)
    edges = [
        (i, j)
        for i, j in graph.edges
        if ok[i] and ok[j] and footprint.segment_is_free(obstacles, xy[i], xy[j], EDGE_RADIUS_M)
    ]
    n = len(graph.nodes)
    rows = [i for i, _ in edges]
    cols = [j for _, j in edges]
    adjacency = coo_matrix((np.ones(len(edges)), (rows, cols)), shape=(n, n))
    _, labels = connected_components(adjacency, directed=False)
    sizes = np.bincount(labels[ok], minlength=labels.max() + 1)
    keep = ok & (labels == int(np.argmax(sizes)))
    index = {old: new for new, old in enumerate(np.flatnonzero(keep))}
    out = _Graph()
    for old in index:
        out.add(graph.nodes[old], graph.kind[old], graph.clearance[old])
    for i, j in edges:
        if i in index and j in index:
            out.link(index[i], index[j])
    return out


def _spawns(graph: _Graph, rng: np.random.Generator) -> list[Spawn]:
    """2-4 poses on distinct corridor nodes, facing along the corridor (yaw 0 or 180 degrees)."""
    corridor = [i for i, k in enumerate(graph.kind) if k == "corridor"]
    count = min(int(rng.integers(2, 5)), len(corridor))
    chosen = sorted(rng.choice(corridor, size=count, replace=False).tolist())
    yaws = rng.choice([0.0, 180.0], size=count)
    return [
        Spawn(x_m=graph.nodes[i][0], y_m=graph.nodes[i][1], yaw_deg=float(yaw))
        for i, yaw in zip(chosen, yaws, strict=True)
    ]


def _roadmap(graph: _Graph) -> Roadmap:
    """The schema roadmap of a finished graph."""
    return Roadmap(nodes=list(graph.nodes), edges=list(graph.edges))


def _assemble(spec: WorldSpec, items: _Items, roadmap: Roadmap, spawns: list[Spawn]) -> WorldSpec:
    """The explicit world: ``spec``'s own items first, then the generated ones."""
    if spec.roadmap is not None:
        offset = len(roadmap.nodes)
        roadmap = Roadmap(
            nodes=roadmap.nodes + spec.roadmap.nodes,
            edges=roadmap.edges + [(i + offset, j + offset) for i, j in spec.roadmap.edges],
        )
    return WorldSpec(
        name=spec.name,
        description=spec.description,
        generator=None,
        walls=spec.walls + items.walls,
        boxes=spec.boxes + items.boxes,
        cylinders=spec.cylinders + items.cylinders,
        tables=spec.tables + items.tables,
        chairs=spec.chairs + items.chairs,
        shelves=spec.shelves + items.shelves,
        doors=spec.doors + items.doors,
        roadmap=roadmap,
        spawns=spec.spawns + spawns,
        agents=spec.agents,
    )


__all__ = ["generate"]
