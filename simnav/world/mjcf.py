"""MJCF assembly of a world with MjSpec: static geometry, doors, pedestrians and other robots.

Static geometry is added twice, on purpose: as primitives (boxes and cylinders) in collision group
:data:`GROUP_COLLISION` that the physics and the ray-cast sensors use, and merged into one mesh per colour in
the render group :data:`GROUP_VISUAL` that cameras draw. Rendering cost on a software renderer grows with the
number of geoms, so an office of several hundred primitives renders as a handful of meshes.

Geom groups: 0 = static visual meshes and floor, 1 = moving things (people, robots, doors), 2 = the robot,
3 = static collision primitives (hidden from cameras, seen by rays). Contact bitmasks: static (1), robot (2),
moving things (4); only robot-static and robot-moving contacts are generated.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from simnav.world.schema import Door, WorldSpec

GROUP_VISUAL = 0
GROUP_MOVING = 1
GROUP_ROBOT = 2
GROUP_COLLISION = 3
CONTYPE_STATIC, CONTYPE_ROBOT, CONTYPE_MOVING = 1, 2, 4

WALL_COLOR = (0.82, 0.80, 0.76)
WOOD_COLOR = (0.62, 0.45, 0.28)
METAL_COLOR = (0.35, 0.36, 0.40)
CHAIR_COLOR = (0.15, 0.17, 0.22)
SHELF_COLOR = (0.70, 0.62, 0.50)
DOOR_COLOR = (0.55, 0.35, 0.20)
FLOOR_TEXTURE_M = 2.0  # side of the (repeating) floor texture, m
FLOOR_TEXTURE_PX = 1024
FLOOR_TILE_M = 0.5
FLOOR_JOINT_M = 0.006
CLOTH_TEXTURE_M = 0.5  # side of the (repeating) clothing textures, m
PEDESTRIAN_HEIGHT_M = 1.75
PEDESTRIAN_RADIUS_M = 0.22
WANDERER_RADIUS_M = 0.28


@dataclass(frozen=True)
class Solid:
    """A static box or upright cylinder in the world frame.

    Attributes:
        kind: ``"box"`` or ``"cylinder"``.
        center_m: (x, y, z) centre, m.
        half_m: box half extents (x, y, z) or cylinder (radius, radius, half height), m.
        yaw_rad: rotation about z.
        color: RGB in [0, 1].
    """

    kind: str
    center_m: tuple[float, float, float]
    half_m: tuple[float, float, float]
    yaw_rad: float
    color: tuple[float, float, float]


def world_solids(world: WorldSpec) -> list[Solid]:
    """Every static primitive of an explicit world (walls, furniture), in a stable order."""
    solids: list[Solid] = []
    for wall in world.walls:
        solids += _wall_solids(wall.points, wall.thickness_m, wall.height_m)
    for box in world.boxes:
        half = (box.size_m[0] / 2, box.size_m[1] / 2, box.size_m[2] / 2)
        solids.append(Solid("box", (*box.center, box.z_m + half[2]), half, math.radians(box.yaw_deg), box.color))
    for cyl in world.cylinders:
        half = (cyl.radius_m, cyl.radius_m, cyl.height_m / 2)
        solids.append(Solid("cylinder", (*cyl.center, half[2]), half, 0.0, cyl.color))
    for table in world.tables:
        solids += _table_solids(table)
    for chair in world.chairs:
        solids += _chair_solids(chair)
    for shelf in world.shelves:
        solids += _shelf_solids(shelf)
    return solids


def _wall_solids(points, thickness_m: float, height_m: float) -> list[Solid]:
    out = []
    for (x0, y0), (x1, y1) in zip(points, points[1:], strict=False):
        length = math.hypot(x1 - x0, y1 - y0)
        if length < 1e-6:
            continue
        half = (length / 2 + thickness_m / 2, thickness_m / 2, height_m / 2)
        center = ((x0 + x1) / 2, (y0 + y1) / 2, height_m / 2)
        out.append(Solid("box", center, half, math.atan2(y1 - y0, x1 - x0), WALL_COLOR))
    return out


def _local(cx: float, cy: float, yaw: float, dx: float, dy: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return cx + c * dx - s * dy, cy + s * dx + c * dy


def _table_solids(t) -> list[Solid]:
    yaw = math.radians(t.yaw_deg)
    lx, ly = t.size_m[0] / 2, t.size_m[1] / 2
    top_z = t.height_m - t.top_thickness_m / 2
    out = [Solid("box", (*t.center, top_z), (lx, ly, t.top_thickness_m / 2), yaw, WOOD_COLOR)]
    leg_half_h = (t.height_m - t.top_thickness_m) / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            xy = _local(*t.center, yaw, sx * (lx - t.leg_inset_m), sy * (ly - t.leg_inset_m))
            out.append(Solid("cylinder", (*xy, leg_half_h), (t.leg_radius_m,) * 2 + (leg_half_h,), 0.0, METAL_COLOR))
    return out


def _chair_solids(c) -> list[Solid]:
    yaw = math.radians(c.yaw_deg)
    s = c.seat_size_m / 2
    seat_t = 0.03
    out = [
        Solid("cylinder", (*c.center, 0.03), (0.28, 0.28, 0.03), 0.0, CHAIR_COLOR),  # star base
        Solid("cylinder", (*c.center, c.seat_height_m / 2), (0.03, 0.03, c.seat_height_m / 2), 0.0, METAL_COLOR),
        Solid("box", (*c.center, c.seat_height_m + seat_t), (s, s, seat_t), yaw, CHAIR_COLOR),
    ]
    back_xy = _local(*c.center, yaw, -s + 0.025, 0.0)
    back_z = c.seat_height_m + 2 * seat_t + c.back_height_m / 2
    out.append(Solid("box", (*back_xy, back_z), (0.025, s, c.back_height_m / 2), yaw, CHAIR_COLOR))
    return out


def _shelf_solids(sh) -> list[Solid]:
    yaw = math.radians(sh.yaw_deg)
    lx, ly, lz = (v / 2 for v in sh.size_m)
    t = 0.01
    out = []
    for sx in (-1, 1):  # side panels
        xy = _local(*sh.center, yaw, sx * (lx - t), 0.0)
        out.append(Solid("box", (*xy, lz), (t, ly, lz), yaw, SHELF_COLOR))
    back_xy = _local(*sh.center, yaw, 0.0, -(ly - t))
    out.append(Solid("box", (*back_xy, lz), (lx, t, lz), yaw, SHELF_COLOR))
    for k in range(sh.levels):
        z = 0.05 + k * (2 * lz - 0.07) / (sh.levels - 1)
        out.append(Solid("box", (*sh.center, z), (lx, ly, t), yaw, SHELF_COLOR))
    return out


def add_static_world(spec: mujoco.MjSpec, world: WorldSpec) -> int:
    """Add the floor and all static geometry (collision primitives + merged render meshes); returns #solids."""
    solids = world_solids(world)
    _add_floor(spec, solids)
    for k, solid in enumerate(solids):
        _add_collision_solid(spec, solid, f"static{k}")
    _add_render_meshes(spec, solids)
    return len(solids)


def _add_floor(spec: mujoco.MjSpec, solids: list[Solid], margin_m: float = 5.0) -> None:
    """A thin box under the whole world for cameras (a finite box renders much faster than an infinite plane on
    a software renderer) and an infinite plane for rays."""
    texture = floor_texture()
    tex = spec.add_texture(name="floor_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, width=texture.shape[1],
                           height=texture.shape[0], nchannel=3)
    tex.data = texture.tobytes()
    repeat = 1.0 / FLOOR_TEXTURE_M
    mat = spec.add_material(name="floor_mat", texrepeat=[repeat, repeat], texuniform=True)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
    reach = [max((abs(s.center_m[i]) + max(s.half_m[:2]) for s in solids), default=0.0) + margin_m for i in (0, 1)]
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_BOX, size=[reach[0], reach[1], 0.01],
                            pos=[0, 0, -0.01], material="floor_mat", group=GROUP_VISUAL, contype=0, conaffinity=0)
    spec.worldbody.add_geom(name="floor_rays", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05],
                            group=GROUP_COLLISION, contype=0, conaffinity=0)


@functools.lru_cache(maxsize=2)
def floor_texture(size_px: int = FLOOR_TEXTURE_PX, seed: int = 7) -> np.ndarray:
    """(size_px, size_px, 3) uint8 floor texture covering FLOOR_TEXTURE_M x FLOOR_TEXTURE_M (it repeats): grey
    FLOOR_TILE_M tiles, each a little lighter or darker, with dark joints and the mottled speckle of vinyl or
    terrazzo flooring at 1-10 cm scales (what gives a camera texture on a real office floor). Deterministic."""
    rng = np.random.default_rng(seed)
    m_per_px = FLOOR_TEXTURE_M / size_px
    tiles = round(FLOOR_TEXTURE_M / FLOOR_TILE_M)
    # tile shades, then smooth mottling (value noise at several scales, wrapping at the texture's edge)
    ij = (np.arange(size_px) * tiles) // size_px
    grey = 0.52 + rng.uniform(-0.04, 0.04, (tiles, tiles))[ij[:, None], ij[None, :]]
    for scale_m, amplitude in ((0.10, 0.05), (0.04, 0.05), (0.015, 0.04)):
        cells = max(1, round(FLOOR_TEXTURE_M / scale_m))
        coarse = rng.uniform(-amplitude, amplitude, (cells, cells))
        grey = grey + _wrapped_upsample(coarse, size_px)
    grey = grey + rng.uniform(-0.03, 0.03, (size_px, size_px))  # grain
    # joints between the tiles
    joint_px = max(1, round(FLOOR_JOINT_M / m_per_px))
    on_joint = (np.arange(size_px) % (size_px // tiles)) < joint_px
    grey[on_joint, :] = 0.30
    grey[:, on_joint] = 0.30
    rgb = np.clip(grey[..., None] * np.array([1.0, 1.0, 0.95]), 0.0, 1.0)
    out = np.ascontiguousarray((255 * rgb).astype(np.uint8))
    out.flags.writeable = False  # cached
    return out


def _wrapped_upsample(coarse: np.ndarray, size_px: int) -> np.ndarray:
    """Bilinear upsampling of a (c, c) periodic grid to (size_px, size_px), wrapping at the edges."""
    c = coarse.shape[0]
    t = np.arange(size_px) * c / size_px
    i0 = np.floor(t).astype(int) % c
    i1 = (i0 + 1) % c
    f = t - np.floor(t)
    rows = coarse[i0] * (1 - f)[:, None] + coarse[i1] * f[:, None]
    return rows[:, i0] * (1 - f)[None, :] + rows[:, i1] * f[None, :]


def _add_collision_solid(spec: mujoco.MjSpec, solid: Solid, name: str) -> None:
    g = spec.worldbody.add_geom(name=name, group=GROUP_COLLISION, contype=CONTYPE_STATIC, conaffinity=0)
    g.pos = list(solid.center_m)
    g.quat = _yaw_quat(solid.yaw_rad)
    g.rgba = [*solid.color, 1.0]
    if solid.kind == "box":
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = list(solid.half_m)
    else:
        g.type = mujoco.mjtGeom.mjGEOM_CYLINDER
        g.size = [solid.half_m[0], solid.half_m[2], 0]


def _add_render_meshes(spec: mujoco.MjSpec, solids: list[Solid]) -> None:
    by_color: dict[tuple[float, float, float], list[Solid]] = {}
    for solid in solids:
        by_color.setdefault(tuple(solid.color), []).append(solid)
    for k, (color, group) in enumerate(sorted(by_color.items())):
        verts, faces = _merged_mesh(group)
        mesh = spec.add_mesh(name=f"static_mesh{k}")
        mesh.uservert = verts.ravel().tolist()
        mesh.userface = faces.ravel().tolist()
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        spec.worldbody.add_geom(name=f"static_visual{k}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name,
                                group=GROUP_VISUAL, contype=0, conaffinity=0, rgba=[*color, 1.0])


def _merged_mesh(solids: list[Solid]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3) of all solids, one set of vertices per face (flat shading)."""
    verts, faces = [], []
    for solid in solids:
        v, f = _box_faces(solid) if solid.kind == "box" else _cylinder_faces(solid)
        faces.append(f + sum(len(x) for x in verts))
        verts.append(v)
    return np.concatenate(verts), np.concatenate(faces)


def _box_faces(solid: Solid) -> tuple[np.ndarray, np.ndarray]:
    hx, hy, hz = solid.half_m
    corners = np.array([[sx * hx, sy * hy, sz * hz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    v = np.concatenate([corners[list(q)] for q in quads])
    f = np.array([[4 * i, 4 * i + 1, 4 * i + 2] for i in range(6)] + [[4 * i, 4 * i + 2, 4 * i + 3] for i in range(6)])
    return _place(v, solid), f


def _cylinder_faces(solid: Solid, sides: int = 16) -> tuple[np.ndarray, np.ndarray]:
    r, _, hz = solid.half_m
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    v, f = [], []
    for i in range(sides):  # side quads
        j = (i + 1) % sides
        base = len(v)
        v += [[*ring[i], -hz], [*ring[j], -hz], [*ring[j], hz], [*ring[i], hz]]
        f += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    for z, flip in ((hz, False), (-hz, True)):  # caps as fans
        base = len(v)
        v += [[0, 0, z]] + [[*p, z] for p in ring]
        for i in range(sides):
            tri = [base, base + 1 + i, base + 1 + (i + 1) % sides]
            f.append(tri[::-1] if flip else tri)
    return _place(np.array(v, float), solid), np.array(f)


def _place(v: np.ndarray, solid: Solid) -> np.ndarray:
    c, s = math.cos(solid.yaw_rad), math.sin(solid.yaw_rad)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return v @ R.T + np.array(solid.center_m)


def _yaw_quat(yaw_rad: float) -> list[float]:
    return [math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)]


def add_door(spec: mujoco.MjSpec, door: Door, name: str) -> None:
    """A door leaf as a mocap body at the hinge (the leaf extends along the body's +x)."""
    body = spec.worldbody.add_body(name=name, mocap=True, pos=[*door.hinge, 0.0],
                                   quat=_yaw_quat(math.radians(door.closed_yaw_deg)))
    half = [door.width_m / 2 - 0.01, door.thickness_m / 2, door.height_m / 2]
    body.add_geom(name=f"{name}_leaf", type=mujoco.mjtGeom.mjGEOM_BOX, size=half,
                  pos=[door.width_m / 2, 0.0, door.height_m / 2], rgba=[*DOOR_COLOR, 1.0],
                  group=GROUP_MOVING, contype=CONTYPE_MOVING, conaffinity=0)


def add_pedestrian(spec: mujoco.MjSpec, name: str, shirt: tuple[float, float, float]) -> None:
    """A person as a mocap body: legs, torso and head (about 1.75 m tall, 0.22 m radius)."""
    trousers, shirt_mat = _clothing(spec, name, shirt)
    body = spec.worldbody.add_body(name=name, mocap=True, pos=[0.0, 0.0, -10.0])
    common = dict(group=GROUP_MOVING, contype=CONTYPE_MOVING, conaffinity=0)
    body.add_geom(name=f"{name}_legs", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.1, 0.15, 0.42],
                  pos=[0, 0, 0.42], material=trousers, **common)
    # shoulders across y: capsule radius + half-length = the body radius the crowd model keeps clear
    body.add_geom(name=f"{name}_torso", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.12, PEDESTRIAN_RADIUS_M - 0.12, 0],
                  pos=[0, 0, 1.15], quat=[0.7071068, 0.7071068, 0, 0], material=shirt_mat, **common)
    body.add_geom(name=f"{name}_head", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.11, 0, 0],
                  pos=[0, 0, PEDESTRIAN_HEIGHT_M - 0.11], rgba=[0.85, 0.68, 0.55, 1], **common)


def _clothing(spec: mujoco.MjSpec, name: str, shirt: tuple[float, float, float]) -> tuple[str, str]:
    """Materials of a person's trousers (denim-like mottle, shared) and shirt (a check pattern in the shirt's
    colour); the textures are added to ``spec`` once."""
    repeat = 1.0 / CLOTH_TEXTURE_M
    if spec.texture("cloth_tex") is None:
        for tex_name, pattern in (("cloth_tex", cloth_texture("check")), ("denim_tex", cloth_texture("denim"))):
            tex = spec.add_texture(name=tex_name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=pattern.shape[1],
                                   height=pattern.shape[0], nchannel=3)
            tex.data = pattern.tobytes()
        trousers = spec.add_material(name="trousers_mat", texrepeat=[repeat, repeat], texuniform=True,
                                     rgba=[0.22, 0.25, 0.42, 1.0])
        trousers.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "denim_tex"
    mat = spec.add_material(name=f"{name}_shirt_mat", texrepeat=[repeat, repeat], texuniform=True, rgba=[*shirt, 1.0])
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "cloth_tex"
    return "trousers_mat", mat.name


@functools.lru_cache(maxsize=4)
def cloth_texture(kind: str, size_px: int = 256, seed: int = 11) -> np.ndarray:
    """(size_px, size_px, 3) uint8 grey fabric pattern covering CLOTH_TEXTURE_M x CLOTH_TEXTURE_M (it repeats),
    tinted by the material's colour: ``"check"`` (a shirt: stripes of several widths across both directions, as
    a plaid) or ``"denim"`` (trousers: mottle and grain). Deterministic."""
    rng = np.random.default_rng(seed)
    t = np.arange(size_px) / size_px  # texture coordinate, 0..1 over CLOTH_TEXTURE_M
    if kind == "check":
        stripes = 0.5 + 0.5 * np.sign(np.sin(2 * np.pi * 6 * t)) * (np.sin(2 * np.pi * 2 * t) > -0.3)
        grey = 0.55 + 0.2 * (stripes[:, None] + stripes[None, :]) + rng.uniform(-0.05, 0.05, (size_px, size_px))
    else:
        grey = 0.8 + _wrapped_upsample(rng.uniform(-0.12, 0.12, (16, 16)), size_px)
        grey = grey + _wrapped_upsample(rng.uniform(-0.08, 0.08, (48, 48)), size_px)
        grey = grey + rng.uniform(-0.06, 0.06, (size_px, size_px))
    out = np.ascontiguousarray((255 * np.clip(np.repeat(grey[..., None], 3, axis=2), 0.0, 1.0)).astype(np.uint8))
    out.flags.writeable = False  # cached
    return out


def add_wanderer(spec: mujoco.MjSpec, name: str) -> None:
    """Another robot as a mocap body: a round base and a mast."""
    body = spec.worldbody.add_body(name=name, mocap=True, pos=[0.0, 0.0, -10.0])
    common = dict(group=GROUP_MOVING, contype=CONTYPE_MOVING, conaffinity=0)
    body.add_geom(name=f"{name}_base", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[WANDERER_RADIUS_M, 0.15, 0],
                  pos=[0, 0, 0.16], rgba=[0.1, 0.45, 0.7, 1], **common)
    body.add_geom(name=f"{name}_mast", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.35],
                  pos=[-0.1, 0, 0.66], rgba=[0.8, 0.8, 0.8, 1], **common)
