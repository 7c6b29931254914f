"""meshcat commands, packed once into the bytes a meshcat server stores and forwards to browsers.

A :class:`Command` is what ``meshcat.Visualizer`` sends over ZMQ: its type, the scene path and the msgpack payload.
The static scene is lowered by meshcat's own classes (``meshcat.geometry``). What is sent at every live update is
built here directly in the same form (tested against meshcat): transforms are packed by hand, point clouds and lines
are lowered without meshcat's per-object UUIDs, and payloads are packed by the C ``msgpack`` package when it is
installed (ten times faster than meshcat's pure-Python packer, same bytes). Scene paths are strings such as
``/meshcat/robot``; matrices are 4x4 homogeneous poses of the node in its parent (``T_parent_node``), metres.
"""

from __future__ import annotations

import functools
import itertools
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import umsgpack

from simnav.viz import style
from simnav.viz._meshcat import MeshcatPath, js_quaternion, mg
from simnav.viz.meshes import TriMesh

_MATRIX = np.dtype([("tag", "u1"), ("value", ">f8")])
_FLOAT64 = 0xCB
_FLOAT32_ARRAY = 0x17  # meshcat's msgpack extension code of a Float32Array
_IDENTITY = [float(v) for v in np.eye(4).ravel()]
_ids = itertools.count()

try:  # the C implementation; the result is the same bytes as umsgpack's
    import msgpack as _msgpack

    def packb(data) -> bytes:
        """msgpack bytes of a lowered meshcat command."""
        return _msgpack.packb(data, default=_ext, use_bin_type=True)

    def _ext(value):
        if isinstance(value, umsgpack.Ext):
            return _msgpack.ExtType(value.type, value.data)
        raise TypeError(f"cannot pack {type(value).__name__}")
except ImportError:  # pragma: no cover - msgpack comes with most installs; meshcat's own packer is the fallback
    packb = umsgpack.packb


@dataclass(frozen=True)
class Command:
    """One packed meshcat command.

    Attributes:
        kind: ``set_object``, ``set_transform``, ``set_property``, ``set_animation`` or ``delete``.
        path: scene path, e.g. ``/meshcat/robot`` (empty for animations).
        payload: the msgpack bytes of the command.
    """

    kind: str
    path: str
    payload: bytes

    def frames(self) -> list[bytes]:
        """The ZMQ message parts a meshcat server expects."""
        return [self.kind.encode(), self.path.encode(), self.payload]


def _pack_str(text: str) -> bytes:
    raw = text.encode()
    n = len(raw)
    if n < 32:
        return bytes([0xA0 | n]) + raw
    if n < 256:
        return bytes([0xD9, n]) + raw
    return struct.pack(">BH", 0xDA, n) + raw


@functools.lru_cache(maxsize=4096)
def _lower_path(path: str) -> str:
    return MeshcatPath().append(path).lower()


@functools.lru_cache(maxsize=4096)
def _transform_prefix(path: str) -> bytes:
    """The payload of a ``set_transform`` up to its 16 matrix values."""
    return b"".join([b"\x83", _pack_str("type"), _pack_str("set_transform"), _pack_str("path"), _pack_str(path),
                     _pack_str("matrix"), b"\xdc\x00\x10"])


def set_transform(path: str, T: np.ndarray) -> Command:
    """Set the pose of a node in its parent: ``T`` is (4, 4) ``T_parent_node``."""
    return set_transforms([path], np.asarray(T, dtype=np.float64)[None])[0]


def set_transforms(paths: Sequence[str], T: np.ndarray) -> list[Command]:
    """Set the poses of many nodes at once: ``T`` is (N, 4, 4), one ``T_parent_node`` per path."""
    values = np.empty((len(paths), 16), dtype=_MATRIX)
    values["tag"] = _FLOAT64
    values["value"] = np.asarray(T, dtype=np.float64).transpose(0, 2, 1).reshape(-1, 16)  # column-major (three.js)
    lowered = [_lower_path(p) for p in paths]
    return [Command("set_transform", p, _transform_prefix(p) + row.tobytes()) for p, row in zip(lowered, values)]


def set_object(path: str, obj: mg.Object | dict) -> Command:
    """Put an object (a meshcat object, or one already lowered) at a node; it replaces what was there."""
    path = _lower_path(path)
    data = {"type": "set_object", "object": obj if isinstance(obj, dict) else obj.lower(), "path": path}
    return Command("set_object", path, packb(data))


def set_property(path: str, key: str, value) -> Command:
    """Set a property of a node's three.js object, e.g. ``visible`` or ``position``."""
    path = _lower_path(path)
    data = {"type": "set_property", "path": path, "property": key.lower(), "value": value}
    return Command("set_property", path, packb(data))


def delete(path: str) -> Command:
    """Remove a node and everything below it."""
    path = _lower_path(path)
    return Command("delete", path, packb({"type": "delete", "path": path}))


def pose3(T_world_node: np.ndarray, z_m: float = 0.0) -> np.ndarray:
    """(4, 4) pose of a (3, 3) SE(2) pose lifted to height ``z_m``."""
    T = np.eye(4)
    T[:2, :2] = T_world_node[:2, :2]
    T[:2, 3] = T_world_node[:2, 2]
    T[2, 3] = z_m
    return T


def pose_xy_yaw(x_m: float, y_m: float, yaw_rad: float, z_m: float = 0.0) -> np.ndarray:
    """(4, 4) pose from a planar position and heading."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0, x_m], [s, c, 0.0, y_m], [0.0, 0.0, 1.0, z_m], [0.0, 0.0, 0.0, 1.0]])


def poses_xy_yaw(xyyaw: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses from (N, 3) planar positions and headings (x m, y m, yaw rad)."""
    xyyaw = np.asarray(xyyaw, dtype=np.float64).reshape(-1, 3)
    c, s = np.cos(xyyaw[:, 2]), np.sin(xyyaw[:, 2])
    T = np.zeros((len(xyyaw), 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, :2, 3] = xyyaw[:, :2]
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    return T


# --------------------------------------------------------------------------------------------------- objects
def mesh_object(mesh: TriMesh, opacity: float = 1.0) -> mg.Mesh:
    """A meshcat mesh with per-vertex colours, each face shaded flat (matte)."""
    geometry = mg.TriangularMeshGeometry(mesh.vertices, mesh.faces, color=mesh.colors)
    return mg.Mesh(geometry, mg.MeshPhongMaterial(color=0xFFFFFF, vertexColors=True, opacity=opacity,
                                                   flatShading=True, shininess=5, specular=0x080808))


def points_object(points: np.ndarray, colors: np.ndarray | style.RGB, size_m: float) -> dict:
    """A point cloud, lowered as meshcat's ``PointCloud`` (:func:`set_object` takes it).

    Args:
        points: (N, 3) positions in the node's frame, m.
        colors: (N, 3) RGB per point in [0, 1], or one RGB triple for all.
        size_m: point size, m.
    """
    pts = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
    rgb = np.asarray(colors, dtype=np.float32)
    rgb = np.ascontiguousarray(np.broadcast_to(rgb, pts.shape) if rgb.ndim == 1 else rgb.reshape(-1, 3))
    material = {"type": "PointsMaterial", "color": 0xFFFFFF, "size": float(size_m), "vertexColors": 2}
    return _lowered("Points", {"position": _attribute(pts), "color": _attribute(rgb)}, material)


def line_object(points: np.ndarray, color: style.RGB, segments: bool = False) -> dict:
    """A polyline through (N, 3) points (``segments``: independent segments between rows 2i and 2i+1), m; lowered
    as meshcat's ``Line`` / ``LineSegments`` with a ``LineBasicMaterial``."""
    pts = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
    material = {"type": "LineBasicMaterial", "color": style.hex_color(color), "reflectivity": 0.5, "side": 2,
                "transparent": False, "opacity": 1.0, "linewidth": 1.0, "wireframe": False,
                "wireframeLinewidth": 1.0, "vertexColors": 0}
    return _lowered("LineSegments" if segments else "Line", {"position": _attribute(pts)}, material)


def _attribute(values: np.ndarray) -> dict:
    """A (N, 3) float32 array as a three.js buffer attribute (meshcat's ``pack_numpy_array``)."""
    return {"itemSize": 3, "type": "Float32Array", "array": umsgpack.Ext(_FLOAT32_ARRAY, values.tobytes()),
            "normalized": False}


def _lowered(kind: str, attributes: dict, material: dict) -> dict:
    """An object as meshcat's ``Object.lower`` writes it; ids only need to be unique within the message."""
    n = next(_ids)
    geometry_id, material_id, object_id = f"simnav-g{n}", f"simnav-m{n}", f"simnav-o{n}"
    return {"metadata": {"version": 4.5, "type": "Object"},
            "geometries": [{"uuid": geometry_id, "type": "BufferGeometry", "data": {"attributes": attributes}}],
            "materials": [{"uuid": material_id, **material}],
            "object": {"uuid": object_id, "type": kind, "geometry": geometry_id, "material": material_id,
                       "matrix": _IDENTITY}}


# ------------------------------------------------------------------------------------------------ animations
@dataclass
class Track:
    """One animated property of a node: keyframe times (s) and values (a list per key)."""

    name: str
    jstype: str
    times_s: list[float]
    values: list

    def lower(self) -> dict:
        return {"name": "." + self.name, "type": self.jstype,
                "keys": [{"time": t, "value": v} for t, v in zip(self.times_s, self.values, strict=True)]}


def transform_tracks(times_s: np.ndarray, T: np.ndarray) -> list[Track]:
    """Position and orientation tracks of (K, 4, 4) poses at (K,) times, s."""
    positions = [[float(v) for v in m[:3, 3]] for m in T]
    quaternions = [[float(v) for v in js_quaternion(m)] for m in T]
    times = [float(t) for t in times_s]
    return [Track("position", "vector3", times, positions), Track("quaternion", "quaternion", times, quaternions)]


def visibility_track(times_s: Sequence[float], visible: Sequence[bool]) -> Track:
    """A node shown or hidden from each time on."""
    return Track("visible", "boolean", [float(t) for t in times_s], [bool(v) for v in visible])


def set_animation(tracks: dict[str, list[Track]], play: bool = True, repetitions: int = 1) -> Command:
    """Animate nodes (path -> tracks); times are seconds. The meshcat viewer shows play/pause/scrub controls."""
    animations = [{"path": _lower_path(path), "clip": {"fps": 1.0, "name": "default",
                                                        "tracks": [t.lower() for t in node_tracks]}}
                  for path, node_tracks in tracks.items()]
    data = {"type": "set_animation", "animations": animations,
            "options": {"play": play, "repetitions": repetitions}, "path": ""}
    return Command("set_animation", "", packb(data))
