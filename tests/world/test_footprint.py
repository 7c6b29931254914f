"""Floor footprints of obstacles within a height band (simnav.world.footprint)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely.geometry import Point

from simnav.world import footprint as fp
from simnav.world.schema import Box, Chair, Cylinder, Door, Roadmap, Shelf, Spawn, Table, Wall, WorldSpec


def _world(**items: object) -> WorldSpec:
    """A tiny explicit world around the origin with the given items."""
    return WorldSpec(roadmap=Roadmap(nodes=[(0.0, 0.0)]), spawns=[Spawn(x_m=0.0, y_m=0.0)], **items)


@pytest.fixture
def table_world() -> WorldSpec:
    """One 1.4 x 0.7 m table, 0.74 m high, legs inset 0.12 m, centred at (2, 1)."""
    return _world(tables=[Table(center=(2.0, 1.0), size_m=(1.4, 0.7), height_m=0.74, leg_inset_m=0.12)])


def test_low_band_sees_only_the_legs(table_world: WorldSpec) -> None:
    polys = fp.obstacle_polygons(table_world, 0.0, 0.3)
    assert len(polys) == 4
    centres = sorted((round(p.centroid.x, 3), round(p.centroid.y, 3)) for p in polys)
    assert centres == [(1.42, 0.77), (1.42, 1.23), (2.58, 0.77), (2.58, 1.23)]
    assert all(p.area == pytest.approx(math.pi * 0.025**2, rel=0.05) for p in polys)
    # under the top, between the legs, there is free floor
    assert fp.clearance_m(table_world, np.array([[2.0, 1.0]]), 0.0, 0.3)[0] > 0.2


def test_band_reaching_the_top_sees_the_whole_top(table_world: WorldSpec) -> None:
    polys = fp.obstacle_polygons(table_world, 0.0, 1.0)
    assert len(polys) == 1
    assert polys[0].area == pytest.approx(1.4 * 0.7)
    assert fp.clearance_m(table_world, np.array([[2.0, 1.0]]), 0.0, 1.0)[0] == 0.0
    # a band above the table sees nothing
    assert fp.obstacle_polygons(table_world, 0.8, 2.0) == []


def test_band_edges_do_not_count_as_overlap(table_world: WorldSpec) -> None:
    # the top spans z 0.71..0.74: a band ending at its underside sees the legs, one from its top sees nothing
    assert len(fp.obstacle_polygons(table_world, 0.0, 0.71)) == 4
    assert fp.obstacle_polygons(table_world, 0.74, 1.0) == []


def test_rotated_table_legs_stay_under_the_top() -> None:
    table = Table(center=(0.0, 0.0), size_m=(1.2, 0.6), yaw_deg=30.0, leg_inset_m=0.1)
    top = fp.rectangle(table.center, table.size_m, table.yaw_deg)
    assert all(top.contains(Point(p).buffer(table.leg_radius_m)) for p in fp.table_legs(table))


def test_each_obstacle_kind_has_its_footprint() -> None:
    world = _world(
        walls=[Wall(points=[(0.0, 0.0), (4.0, 0.0)], thickness_m=0.2, height_m=2.5)],
        boxes=[Box(center=(1.0, 2.0), size_m=(1.0, 0.5, 0.8), yaw_deg=90.0)],
        cylinders=[Cylinder(center=(3.0, 2.0), radius_m=0.3, height_m=1.0)],
        chairs=[Chair(center=(1.0, 4.0), yaw_deg=45.0, seat_size_m=0.4)],
        shelves=[Shelf(center=(3.0, 4.0), size_m=(0.9, 0.3, 1.8))],
    )
    polys = fp.obstacle_polygons(world)
    assert len(polys) == 5
    wall, box, cyl, chair, shelf = polys
    assert wall.bounds == pytest.approx((0.0, -0.1, 4.0, 0.1))
    assert box.bounds == pytest.approx((0.75, 1.5, 1.25, 2.5))
    assert cyl.area == pytest.approx(math.pi * 0.09, rel=0.03)
    assert chair.area == pytest.approx(0.16)
    assert chair.bounds[2] - chair.bounds[0] == pytest.approx(0.4 * math.sqrt(2))
    assert shelf.area == pytest.approx(0.27)


def test_height_bands_filter_obstacles() -> None:
    world = _world(
        boxes=[Box(center=(0.0, 0.0), size_m=(1.0, 1.0, 0.1), z_m=0.6)],  # a board floating at 0.6-0.7 m
        cylinders=[Cylinder(center=(3.0, 0.0), radius_m=0.2, height_m=0.4)],
    )
    assert len(fp.obstacle_polygons(world, 0.0, 0.3)) == 1  # the low bin only
    assert len(fp.obstacle_polygons(world, 0.5, 0.65)) == 1  # the board only
    assert len(fp.obstacle_polygons(world, 0.0, 2.0)) == 2


def test_doors_only_on_request() -> None:
    door = Door(hinge=(1.0, 0.0), width_m=0.9, closed_yaw_deg=90.0)
    world = _world(doors=[door])
    assert fp.obstacle_polygons(world) == []
    (leaf,) = fp.obstacle_polygons(world, include_doors=True)
    assert leaf.bounds == pytest.approx((0.98, 0.0, 1.02, 0.9))


def test_closed_polyline_wall_is_a_ring() -> None:
    world = _world(walls=[Wall(points=[(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)], thickness_m=0.1)])
    (room,) = fp.obstacle_polygons(world)
    assert len(room.interiors) == 1
    assert room.area == pytest.approx(4.1 * 3.1 - 3.9 * 2.9)
    # the centre is free, 1.45 m from the nearest wall face
    assert fp.clearance_m(world, np.array([[2.0, 1.5]]))[0] == pytest.approx(1.45)


def test_segments_outline_the_union() -> None:
    world = _world(
        boxes=[Box(center=(x, 0.0), size_m=(2.0, 2.0, 1.0)) for x in (0.0, 1.0)],
    )
    segs = fp.obstacle_segments(world)
    assert segs.ndim == 3 and segs.shape[1:] == (2, 2)
    perimeter = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1).sum()
    assert perimeter == pytest.approx(2 * (3.0 + 2.0))  # one 3 x 2 outline, no inner edges
    assert fp.obstacle_segments(world, 1.5, 2.0).shape == (0, 2, 2)


def test_segments_include_holes() -> None:
    world = _world(walls=[Wall(points=[(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)], thickness_m=0.1)])
    perimeter = np.linalg.norm(np.diff(fp.obstacle_segments(world), axis=1)[:, 0], axis=1).sum()
    assert perimeter == pytest.approx(2 * (4.1 + 3.1) + 2 * (3.9 + 2.9))


def test_clearance_is_zero_inside_and_vectorised() -> None:
    world = _world(cylinders=[Cylinder(center=(0.0, 0.0), radius_m=0.5, height_m=1.0)])
    d = fp.clearance_m(world, np.array([[0.0, 0.0], [2.0, 0.0], [0.0, -1.5]]))
    assert d.shape == (3,)
    assert d[0] == 0.0
    assert d[1:] == pytest.approx([1.5, 1.0], abs=0.01)


def test_clearance_without_obstacles_is_infinite() -> None:
    assert np.isinf(fp.clearance_m(_world(), np.zeros((2, 2)))).all()


def test_segment_is_free() -> None:
    geom = shapely.box(1.0, -1.0, 2.0, 1.0)
    assert fp.segment_is_free(geom, (0.0, 2.0), (3.0, 2.0), 0.3)
    assert not fp.segment_is_free(geom, (0.0, 1.2), (3.0, 1.2), 0.3)
    assert not fp.segment_is_free(geom, (0.0, 0.0), (3.0, 0.0), 0.3)


def test_bounds_cover_all_geometry() -> None:
    world = _world(
        walls=[Wall(points=[(-1.0, 0.0), (5.0, 0.0)], thickness_m=0.2)],
        boxes=[Box(center=(0.0, 3.0), size_m=(1.0, 1.0, 0.1), z_m=2.5)],
    )
    assert fp.bounds(world) == pytest.approx((-1.0, -0.1, 5.0, 3.5))


def test_door_swing_distance_is_zero_in_the_swept_sector_and_grows_outside() -> None:
    door = Door(hinge=(0.0, 0.0), width_m=1.0, closed_yaw_deg=0.0, swing_deg=90.0)
    world = _world(doors=[door])
    d = fp.door_swing_distance_m(world, np.array([[0.5, 0.5], [0.0, -0.5], [2.0, 0.0], [-0.3, 0.4]]))
    assert d[0] == 0.0                                   # swept by the leaf
    assert d[1] == pytest.approx(0.5)                    # below the hinge, on the other side of the closed leaf
    assert d[2] == pytest.approx(1.0, abs=1e-6)          # past the leaf's tip
    assert d[3] == pytest.approx(0.3)                    # beside the open leaf
    assert np.isinf(fp.door_swing_distance_m(_world(), np.zeros((1, 2)))).all()


def test_open_leaf_distance_is_to_the_leaf_standing_at_its_full_swing() -> None:
    door = Door(hinge=(0.0, 0.0), width_m=1.0, closed_yaw_deg=0.0, swing_deg=90.0, thickness_m=0.04)
    world = _world(doors=[door])
    d = fp.open_leaf_distance_m(world, np.array([[0.3, 0.5], [0.0, 1.3], [0.5, 0.0], [-0.01, 0.5]]))
    assert d[0] == pytest.approx(0.28)                   # beside the open leaf (x = 0, 2 cm thick each side)
    assert d[1] == pytest.approx(0.3)                    # past its tip
    assert d[2] == pytest.approx(0.48)                   # across the doorway: the leaf's side at the hinge
    assert d[3] == 0.0                                   # in the leaf
    assert fp.door_leaf_polygon(door, opening=1.0).bounds == pytest.approx((-0.02, 0.0, 0.02, 1.0))
    assert np.isinf(fp.open_leaf_distance_m(_world(), np.zeros((1, 2)))).all()
