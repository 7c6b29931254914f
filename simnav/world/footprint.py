"""Floor footprints of a world's static obstacles within a height band.

Every obstacle of a :class:`~simnav.world.schema.WorldSpec` occupies a vertical extent ``z_lo..z_hi``; it is
seen in a height band ``z_min_m..z_max_m`` when the two intervals overlap (touching is not overlapping). The
footprint is its projection onto the floor, a shapely polygon in the ``world`` frame (x, y, metres). Tables
are the reason for the band: below the underside of the top only the legs are there, a band that reaches the
top sees the whole top rectangle. The pedestrian model, the roadmap checks and the tests use these functions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import LinearRing, LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from simnav.world.schema import Box, Chair, Cylinder, Door, Shelf, Table, Vec2, Wall, WorldSpec

CIRCLE_QUAD_SEGS = 8
"""Segments per quarter circle for cylinders and table legs."""


def _overlaps(z_lo: float, z_hi: float, z_min_m: float, z_max_m: float) -> bool:
    """Whether the open intervals ``(z_lo, z_hi)`` and ``(z_min_m, z_max_m)`` intersect."""
    return z_lo < z_max_m and z_hi > z_min_m


def rectangle(center: Vec2, size_xy: Sequence[float], yaw_deg: float) -> Polygon:
    """A ``size_xy`` (metres) rectangle centred at ``center``, its first side turned by ``yaw_deg``."""
    hx, hy = 0.5 * size_xy[0], 0.5 * size_xy[1]
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    return Polygon([(center[0] + c * x - s * y, center[1] + s * x + c * y) for x, y in corners])


def wall_polygon(wall: Wall) -> Polygon:
    """The wall's polyline buffered by half its thickness (flat ends, mitred corners, closed = ring)."""
    pts = [tuple(p) for p in wall.points]
    half = 0.5 * wall.thickness_m
    if len(pts) >= 4 and pts[0] == pts[-1]:
        return LinearRing(pts).buffer(half, join_style="mitre", mitre_limit=4.0)
    return LineString(pts).buffer(half, cap_style="flat", join_style="mitre", mitre_limit=4.0)


def table_legs(table: Table) -> list[Vec2]:
    """World (x, y) of the four leg centres: the top's corners moved ``leg_inset_m`` inwards on both axes."""
    hx = 0.5 * table.size_m[0] - table.leg_inset_m
    hy = 0.5 * table.size_m[1] - table.leg_inset_m
    c, s = math.cos(math.radians(table.yaw_deg)), math.sin(math.radians(table.yaw_deg))
    cx, cy = table.center
    return [(cx + c * x - s * y, cy + s * x + c * y) for x, y in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy))]


def table_polygons(table: Table, z_min_m: float, z_max_m: float) -> list[Polygon]:
    """Top rectangle if the band reaches the top (``height - top_thickness..height``), else leg discs."""
    underside = table.height_m - table.top_thickness_m
    if _overlaps(underside, table.height_m, z_min_m, z_max_m):
        return [rectangle(table.center, table.size_m, table.yaw_deg)]
    if _overlaps(0.0, underside, z_min_m, z_max_m):
        return [Point(p).buffer(table.leg_radius_m, quad_segs=CIRCLE_QUAD_SEGS) for p in table_legs(table)]
    return []


def door_leaf_polygon(door: Door, opening: float = 0.0) -> Polygon:
    """The leaf at ``opening`` (0: closed, along ``closed_yaw_deg``; 1: fully open, ``swing_deg`` further):
    ``width_m`` from the hinge, ``thickness_m`` across."""
    yaw_deg = door.closed_yaw_deg + opening * door.swing_deg
    yaw, half = math.radians(yaw_deg), 0.5 * door.width_m
    mid = (door.hinge[0] + half * math.cos(yaw), door.hinge[1] + half * math.sin(yaw))
    return rectangle(mid, (door.width_m, door.thickness_m), yaw_deg)


def door_swing_polygon(door: Door, arc_points: int = 16) -> Polygon:
    """The area the leaf sweeps between closed and fully open: a circular sector of radius ``width_m`` about the
    hinge, from ``closed_yaw_deg`` through ``swing_deg``."""
    start, sweep = math.radians(door.closed_yaw_deg), math.radians(door.swing_deg)
    arc = [(door.hinge[0] + door.width_m * math.cos(start + sweep * k / arc_points),
            door.hinge[1] + door.width_m * math.sin(start + sweep * k / arc_points)) for k in range(arc_points + 1)]
    return Polygon([tuple(door.hinge), *arc])


def open_leaf_distance_m(spec: WorldSpec, xy: np.ndarray) -> np.ndarray:
    """(N,) distance (metres) from each (N, 2) world point to the nearest door leaf standing fully open (+inf in a
    world without doors)."""
    return distance_to(shapely.unary_union([door_leaf_polygon(d, opening=1.0) for d in spec.doors]), xy)


def door_swing_distance_m(spec: WorldSpec, xy: np.ndarray) -> np.ndarray:
    """(N,) distance (metres) from each (N, 2) world point to the nearest area a door leaf sweeps (0 inside;
    +inf in a world without doors)."""
    return distance_to(shapely.unary_union([door_swing_polygon(d) for d in spec.doors]), xy)


def _box_polygon(box: Box, z_min_m: float, z_max_m: float) -> list[Polygon]:
    if not _overlaps(box.z_m, box.z_m + box.size_m[2], z_min_m, z_max_m):
        return []
    return [rectangle(box.center, box.size_m[:2], box.yaw_deg)]


def _cylinder_polygon(cyl: Cylinder, z_min_m: float, z_max_m: float) -> list[Polygon]:
    if not _overlaps(0.0, cyl.height_m, z_min_m, z_max_m):
        return []
    return [Point(cyl.center).buffer(cyl.radius_m, quad_segs=CIRCLE_QUAD_SEGS)]


def _chair_polygon(chair: Chair, z_min_m: float, z_max_m: float) -> list[Polygon]:
    # Legs, seat and backrest are all simplified to the seat square, whatever the band.
    if not _overlaps(0.0, chair.seat_height_m + chair.back_height_m, z_min_m, z_max_m):
        return []
    return [rectangle(chair.center, (chair.seat_size_m, chair.seat_size_m), chair.yaw_deg)]


def _shelf_polygon(shelf: Shelf, z_min_m: float, z_max_m: float) -> list[Polygon]:
    if not _overlaps(0.0, shelf.size_m[2], z_min_m, z_max_m):
        return []
    return [rectangle(shelf.center, shelf.size_m[:2], shelf.yaw_deg)]


def obstacle_polygons(
    spec: WorldSpec, z_min_m: float = 0.0, z_max_m: float = 2.0, include_doors: bool = False
) -> list[Polygon]:
    """Floor footprints of every static obstacle seen in the height band ``z_min_m..z_max_m``.

    Args:
        spec: the world (explicit geometry; a generated world must be expanded first).
        z_min_m: bottom of the band (metres above the floor).
        z_max_m: top of the band.
        include_doors: add the closed door leaves (doors move, so they are left out by default).

    Returns:
        Polygons in the world frame (x, y, metres), one per wall / box / cylinder / chair / shelf / door and
        one per table top or table leg; they may overlap.
    """
    polys: list[Polygon] = []
    for wall in spec.walls:
        if _overlaps(0.0, wall.height_m, z_min_m, z_max_m):
            polys.append(wall_polygon(wall))
    for box in spec.boxes:
        polys += _box_polygon(box, z_min_m, z_max_m)
    for cyl in spec.cylinders:
        polys += _cylinder_polygon(cyl, z_min_m, z_max_m)
    for table in spec.tables:
        polys += table_polygons(table, z_min_m, z_max_m)
    for chair in spec.chairs:
        polys += _chair_polygon(chair, z_min_m, z_max_m)
    for shelf in spec.shelves:
        polys += _shelf_polygon(shelf, z_min_m, z_max_m)
    if include_doors:
        polys += [door_leaf_polygon(d) for d in spec.doors if _overlaps(0.0, d.height_m, z_min_m, z_max_m)]
    return polys


def obstacle_union(
    spec: WorldSpec, z_min_m: float = 0.0, z_max_m: float = 2.0, include_doors: bool = False
) -> BaseGeometry:
    """Union of :func:`obstacle_polygons` (a Polygon, MultiPolygon or empty geometry)."""
    return shapely.unary_union(obstacle_polygons(spec, z_min_m, z_max_m, include_doors))


def _rings(geom: BaseGeometry) -> list[np.ndarray]:
    """Exterior and interior rings of every polygon in ``geom``, each an (K, 2) closed point array."""
    rings: list[np.ndarray] = []
    for poly in getattr(geom, "geoms", [geom]):
        if poly.is_empty or not isinstance(poly, Polygon):
            continue
        rings.append(np.asarray(poly.exterior.coords)[:, :2])
        rings += [np.asarray(r.coords)[:, :2] for r in poly.interiors]
    return rings


def obstacle_segments(spec: WorldSpec, z_min_m: float = 0.0, z_max_m: float = 2.0) -> np.ndarray:
    """Outline edges of the union of the obstacle footprints in the band (doors left out).

    Returns:
        (M, 2, 2) array of segments ``[[x0, y0], [x1, y1]]`` in the world frame, metres; (0, 2, 2) if empty.
    """
    segs = [np.stack([r[:-1], r[1:]], axis=1) for r in _rings(obstacle_union(spec, z_min_m, z_max_m))]
    return np.concatenate(segs, axis=0) if segs else np.zeros((0, 2, 2))


def distance_to(geom: BaseGeometry, xy: np.ndarray) -> np.ndarray:
    """(N,) distance (metres) from each (N, 2) point to ``geom``; 0 inside; +inf if ``geom`` is empty."""
    pts = np.atleast_2d(np.asarray(xy, dtype=float))
    if geom.is_empty:
        return np.full(len(pts), np.inf)
    return shapely.distance(geom, shapely.points(pts))


def clearance_m(spec: WorldSpec, xy: np.ndarray, z_min_m: float = 0.0, z_max_m: float = 2.0) -> np.ndarray:
    """(N,) distance from each (N, 2) world point to the nearest obstacle footprint in the band (0 if inside).

    Doors are left out. A world without obstacles gives +inf.
    """
    return distance_to(obstacle_union(spec, z_min_m, z_max_m), xy)


def segment_is_free(geom: BaseGeometry, a: Vec2, b: Vec2, radius_m: float) -> bool:
    """Whether the segment ``a``-``b`` buffered by ``radius_m`` misses ``geom`` (touching counts as a hit)."""
    if geom.is_empty:
        return True
    line = LineString([a, b]) if tuple(a) != tuple(b) else Point(a)
    return bool(line.distance(geom) > radius_m)


def bounds(spec: WorldSpec) -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)``, metres: all obstacles (any height), doors, roadmap nodes, spawns."""
    geoms: list[BaseGeometry] = list(obstacle_polygons(spec, -math.inf, math.inf, include_doors=True))
    if spec.roadmap is not None:
        geoms += [Point(p) for p in spec.roadmap.nodes]
    geoms += [Point(s.x_m, s.y_m) for s in spec.spawns]
    if not geoms:
        return (0.0, 0.0, 0.0, 0.0)
    xmin, ymin, xmax, ymax = shapely.unary_union(geoms).bounds
    return (float(xmin), float(ymin), float(xmax), float(ymax))


__all__ = [
    "bounds",
    "clearance_m",
    "distance_to",
    "door_leaf_polygon",
    "obstacle_polygons",
    "obstacle_segments",
    "obstacle_union",
    "rectangle",
    "segment_is_free",
    "table_legs",
    "table_polygons",
    "wall_polygon",
]
