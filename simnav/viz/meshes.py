"""Triangle meshes of everything the viewer draws: extruded polygons, boxes, cylinders, people, robots, doors.

Pure numpy (and shapely for triangulating concave polygons); nothing here talks to meshcat. Meshes share
vertices between faces and the viewer shades them flat, so a box looks like a box at an eighth of the bytes of
unshared triangles. Coordinates are metres in the frame the caller names (``world`` for the building, ``base`` for
the robot, the agent's own frame for people and robots).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from simnav.robot.spec import RobotSpec
from simnav.viz import style
from simnav.world.footprint import bounds
from simnav.world.mjcf import PEDESTRIAN_HEIGHT_M, PEDESTRIAN_RADIUS_M, WANDERER_RADIUS_M, world_solids
from simnav.world.schema import Door, WorldSpec

CYLINDER_SEGMENTS = 12
FLOOR_MARGIN_M = 1.0


@dataclass(frozen=True)
class TriMesh:
    """Triangles over shared vertices with a colour per vertex (the viewer shades each face flat).

    Attributes:
        vertices: (V, 3) float32 vertex positions, m.
        faces: (F, 3) uint32 vertex indices, counter-clockwise seen from outside.
        colors: (V, 3) float32 RGB in [0, 1].
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray

    @staticmethod
    def concat(meshes: Sequence[TriMesh]) -> TriMesh:
        """One mesh holding every triangle of ``meshes``."""
        if not meshes:
            return TriMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros((0, 3), np.float32))
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return TriMesh(np.concatenate([m.vertices for m in meshes]),
                       np.concatenate([m.faces + np.uint32(o) for m, o in zip(meshes, offsets, strict=True)]),
                       np.concatenate([m.colors for m in meshes]))


def _counter_clockwise(polygon_xy: np.ndarray) -> np.ndarray:
    x, y = polygon_xy[:, 0], polygon_xy[:, 1]
    area2 = np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)
    return polygon_xy if area2 > 0 else polygon_xy[::-1].copy()


def triangulate(polygon_xy: np.ndarray) -> np.ndarray:
    """(T, 3) counter-clockwise triangles, as vertex indices, covering a simple counter-clockwise polygon (convex
    or not)."""
    index = {(float(x), float(y)): i for i, (x, y) in enumerate(polygon_xy)}
    tris = shapely.constrained_delaunay_triangles(Polygon(polygon_xy))
    out = np.array([[index[(float(x), float(y))] for x, y in np.asarray(t.exterior.coords)[:3]] for t in tris.geoms],
                   dtype=np.int64).reshape(-1, 3)
    a, b, c = (polygon_xy[out[:, i]] for i in range(3))
    clockwise = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    out[clockwise] = out[clockwise][:, ::-1]
    return out


def prism(polygon_xy: Sequence[Sequence[float]], z_min_m: float, z_max_m: float, color: style.RGB) -> TriMesh:
    """A simple polygon (x, y, m) extruded from ``z_min_m`` to ``z_max_m``: top, bottom and side walls."""
    poly = _counter_clockwise(np.asarray(polygon_xy, dtype=np.float64).reshape(-1, 2))
    n = len(poly)
    vertices = np.vstack([np.column_stack([poly, np.full(n, z_min_m)]), np.column_stack([poly, np.full(n, z_max_m)])])
    caps = triangulate(poly)
    # side walls: two triangles per edge (bottom i, bottom j, top j, top i), normals pointing outwards
    i = np.arange(n)
    j = (i + 1) % n
    sides = np.concatenate([np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n])])
    faces = np.concatenate([caps + n, caps[:, ::-1], sides]).astype(np.uint32)
    return TriMesh(vertices.astype(np.float32), faces, np.tile(np.asarray(color, np.float32), (2 * n, 1)))


def rectangle_xy(center_xy: Sequence[float], half_xy: Sequence[float], yaw_rad: float) -> np.ndarray:
    """(4, 2) corners of a rectangle of half sizes ``half_xy`` turned by ``yaw_rad`` about its centre, m."""
    hx, hy = half_xy
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(center_xy, dtype=np.float64)


def circle_xy(center_xy: Sequence[float], radius_m: float, segments: int = CYLINDER_SEGMENTS) -> np.ndarray:
    """(segments, 2) vertices of a regular polygon inscribed in a circle, m."""
    a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    return np.column_stack([np.cos(a), np.sin(a)]) * radius_m + np.asarray(center_xy, dtype=np.float64)


def world_mesh(world: WorldSpec) -> TriMesh:
    """The building in the ``world`` frame: the floor under everything, walls and furniture in their colours."""
    x0, y0, x1, y1 = bounds(world)
    m = FLOOR_MARGIN_M
    parts = [prism([(x0 - m, y0 - m), (x1 + m, y0 - m), (x1 + m, y1 + m), (x0 - m, y1 + m)], -0.02, 0.0,
                   style.FLOOR_COLOR)]
    for solid in world_solids(world):
        (cx, cy, cz), (hx, hy, hz) = solid.center_m, solid.half_m
        outline = (rectangle_xy((cx, cy), (hx, hy), solid.yaw_rad) if solid.kind == "box"
                   else circle_xy((cx, cy), hx))
        parts.append(prism(outline, cz - hz, cz + hz, solid.color))
    return TriMesh.concat(parts)


def robot_prism_meshes(robot: RobotSpec) -> list[tuple[str, TriMesh]]:
    """Per prism of the robot (bottom first): its name and its mesh in the ``base`` frame, in its band's colour."""
    prisms = sorted(robot.prisms, key=lambda p: p.z_min_m)
    return [(p.name, prism(p.polygon, p.z_min_m, p.z_max_m, style.band_color(b))) for b, p in enumerate(prisms)]


def person_mesh() -> TriMesh:
    """A person in their own frame (x forward, z up): body, head and a nose that shows where they face."""
    body_h = PEDESTRIAN_HEIGHT_M - 0.24
    return TriMesh.concat([
        prism(circle_xy((0, 0), PEDESTRIAN_RADIUS_M - 0.02, 12), 0.0, body_h, style.PERSON_COLOR),
        prism(circle_xy((0, 0), 0.11, 10), body_h + 0.02, PEDESTRIAN_HEIGHT_M, style.PERSON_HEAD_COLOR),
        prism(rectangle_xy((0.12, 0), (0.04, 0.03), 0.0), PEDESTRIAN_HEIGHT_M - 0.14, PEDESTRIAN_HEIGHT_M - 0.08,
              style.PERSON_HEAD_COLOR),
    ])


def wanderer_mesh() -> TriMesh:
    """Another robot in its own frame: a round base and a mast behind its centre."""
    return TriMesh.concat([
        prism(circle_xy((0, 0), WANDERER_RADIUS_M), 0.01, 0.31, style.WANDERER_COLOR),
        prism(rectangle_xy((-0.1, 0), (0.05, 0.05), 0.0), 0.31, 1.01, style.WANDERER_MAST_COLOR),
    ])


def door_leaf_mesh(door: Door) -> TriMesh:
    """A door leaf in its hinge frame: it extends along +x from the hinge (rotate by the leaf's yaw)."""
    half_t = door.thickness_m / 2
    return prism([(0.0, -half_t), (door.width_m, -half_t), (door.width_m, half_t), (0.0, half_t)], 0.0,
                 door.height_m, style.DOOR_COLOR)


def target_mesh() -> TriMesh:
    """The goal marker in its own frame: a disc on the floor and a pole."""
    return TriMesh.concat([
        prism(circle_xy((0, 0), 0.25), 0.0, 0.03, style.TARGET_COLOR),
        prism(circle_xy((0, 0), 0.03, 8), 0.03, 1.8, style.TARGET_COLOR),
    ])
