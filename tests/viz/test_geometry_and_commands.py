"""Meshes, colours and packed meshcat commands: closed outward-facing solids, and bytes identical to meshcat's."""

from __future__ import annotations

import numpy as np
import pytest
import umsgpack

from simnav.robot import load_robot
from simnav.viz import style
from simnav.viz._meshcat import MeshcatPath  # meshcat itself, imported without its deprecation warning
from simnav.viz.commands import mesh_object, set_object, set_property, set_transform
from simnav.viz.draw import band_colors
from simnav.viz.frame import decimate, thin
from simnav.viz.meshes import TriMesh, prism, robot_prism_meshes, world_mesh
from simnav.world import load_world
from simnav.world.footprint import bounds


def signed_volume(mesh: TriMesh) -> float:
    """Divergence theorem: positive for a closed mesh whose faces point outwards."""
    a, b, c = (mesh.vertices[mesh.faces[:, i]].astype(np.float64) for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize("polygon", [
    [(0, 0), (2, 0), (2, 2), (1, 1), (0, 2)],            # concave, counter-clockwise
    [(0, 2), (1, 1), (2, 2), (2, 0), (0, 0)],            # the same, clockwise
    [(0.26, -0.16), (0.26, 0.16), (0.16, 0.26), (-0.26, 0.26), (-0.3, 0.2), (-0.3, -0.2), (-0.26, -0.26),
     (0.16, -0.26)],                                      # the Giraff's base
])
def test_a_prism_is_a_closed_solid_of_the_polygon_times_its_height(polygon):
    from shapely.geometry import Polygon

    mesh = prism(polygon, 0.2, 0.9, (1.0, 0.0, 0.0))
    assert signed_volume(mesh) == pytest.approx(Polygon(polygon).area * 0.7, rel=1e-6)
    # closed: every edge is shared by exactly two faces, once in each direction
    edges = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    assert len({tuple(e) for e in edges.tolist()}) == len(edges)
    assert {tuple(e) for e in edges.tolist()} == {tuple(e) for e in edges[:, ::-1].tolist()}
    assert mesh.vertices[:, 2].min() == pytest.approx(0.2) and mesh.vertices[:, 2].max() == pytest.approx(0.9)


def test_the_robot_has_one_colour_per_height_band_and_points_take_their_band_colour():
    robot = load_robot("giraff")
    meshes = robot_prism_meshes(robot)
    assert [name for name, _ in meshes] == ["base", "pole", "camera_block", "head"]
    for band, (_, mesh) in enumerate(meshes):
        assert np.allclose(mesh.colors, style.band_color(band))
    points = np.array([[1.0, 0.0, 0.10], [1.0, 0.0, 0.50], [1.0, 0.0, 1.10], [1.0, 0.0, 1.5], [1.0, 0.0, 0.0],
                       [1.0, 0.0, 2.0]])
    expected = [style.band_color(0), style.band_color(1), style.band_color(2), style.band_color(3),
                style.UNBANDED_COLOR, style.UNBANDED_COLOR]
    assert np.allclose(band_colors(points, robot), expected)


def test_the_world_mesh_covers_the_building_and_stands_on_the_floor():
    world = load_world("office")
    mesh = world_mesh(world)
    x0, y0, x1, y1 = bounds(world)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    assert lo[0] <= x0 and lo[1] <= y0 and hi[0] >= x1 and hi[1] >= y1
    assert lo[2] == pytest.approx(-0.02) and hi[2] == pytest.approx(max(w.height_m for w in world.walls))
    assert signed_volume(mesh) > 0


@pytest.mark.parametrize("path", ["/meshcat/robot", "/meshcat/people/p12", "/meshcat/" + "x" * 40, "/Cameras/default"])
def test_packed_transforms_are_the_bytes_meshcat_sends(path):
    from meshcat.commands import SetTransform

    T = np.random.default_rng(3).normal(size=(4, 4))
    expected = umsgpack.packb(SetTransform(T, MeshcatPath().append(path)).lower())
    command = set_transform(path, T)
    assert command.payload == expected
    assert command.frames() == [b"set_transform", path.encode(), expected]


def test_objects_and_properties_are_lowered_by_meshcat():
    from meshcat.commands import SetObject, SetProperty

    mesh = prism([(0, 0), (1, 0), (0, 1)], 0, 1, (0.2, 0.4, 0.6))
    obj = mesh_object(mesh)
    assert set_object("/meshcat/a", obj).payload == umsgpack.packb(
        SetObject(obj, path=MeshcatPath().append("/meshcat/a")).lower())
    assert set_property("/meshcat/a", "visible", False).payload == umsgpack.packb(
        SetProperty("visible", False, MeshcatPath().append("/meshcat/a")).lower())


def test_streamed_clouds_and_lines_are_lowered_as_meshcat_lowers_them():
    from simnav.viz._meshcat import mg
    from simnav.viz.commands import line_object, packb, points_object

    def without_ids(lowered: dict) -> dict:
        ids: dict[str, int] = {}

        def walk(x):
            if isinstance(x, dict):
                return {k: ids.setdefault(v, len(ids)) if k in ("uuid", "geometry", "material") else walk(v)
                        for k, v in x.items()}
            return [walk(v) for v in x] if isinstance(x, list) else x

        return walk(lowered)

    rng = np.random.default_rng(1)
    xyz, rgb = rng.normal(size=(40, 3)), rng.uniform(size=(40, 3))
    cloud = mg.PointCloud(xyz.T.astype(np.float32), rgb.T.astype(np.float32), size=0.05).lower()
    assert without_ids(points_object(xyz, rgb, 0.05)) == without_ids(cloud)
    material = mg.LineBasicMaterial(color=style.hex_color((0.1, 0.2, 0.3)))
    line = mg.Line(mg.PointsGeometry(xyz.T.astype(np.float32)), material).lower()
    assert without_ids(line_object(xyz, (0.1, 0.2, 0.3))) == without_ids(line)
    data = {"type": "set_object", "object": cloud, "path": "/meshcat/a"}
    assert packb(data) == umsgpack.packb(data)


def test_thinning_and_decimation():
    pts = np.arange(300.0).reshape(100, 3)
    assert len(thin(pts, 40)) == 34 and np.array_equal(thin(pts, 40)[0], pts[0])  # every 3rd row
    assert len(thin(pts, 50)) == 50 and thin(pts, 200) is pts and len(thin(pts, 0)) == 0
    line = np.column_stack([np.linspace(0, 1, 101), np.zeros(101)])
    kept = decimate(line, 0.1)
    assert 10 <= len(kept) <= 12 and np.array_equal(kept[[0, -1]], line[[0, -1]])
