"""The MJCF body of a robot: a planar base (x, y slides and a yaw hinge) carrying the robot's prisms as convex
mesh geoms, one site per lidar and one camera per RGB-D sensor.

Three velocity servos act through a site at the base origin, in the base frame: forward speed, lateral speed
(always commanded to 0: the wheels' non-holonomic constraint) and yaw rate. The control is therefore the body
command ``(v, 0, w)`` itself, constant between commands, so physics can run many steps per call.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import shapely
from shapely.geometry import Polygon

from simnav.robot.spec import Prism, RGBDSensor, RobotSpec
from simnav.sensors.presets import resolve_rgbd
from simnav.world.mjcf import CONTYPE_MOVING, CONTYPE_ROBOT, CONTYPE_STATIC, GROUP_ROBOT

ROBOT_BODY = "robot"
BASE_SITE = "robot_base"
JOINTS = ("robot_x", "robot_y", "robot_yaw")
TRACKING_TIME_CONSTANT_S = 0.02

# MuJoCo cameras look along -z with x right and y up; a sensor mount frame is x forward, y left, z up.
R_BODY_MJCAM = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def add_robot(spec: mujoco.MjSpec, robot: RobotSpec) -> None:
    """Add the robot body, its joints, actuators, prism geoms and sensor frames to ``spec``."""
    body = spec.worldbody.add_body(name=ROBOT_BODY)
    _set_inertia(body, robot)
    for name, axis, kind in zip(JOINTS, ([1, 0, 0], [0, 1, 0], [0, 0, 1]),
                                (mujoco.mjtJoint.mjJNT_SLIDE,) * 2 + (mujoco.mjtJoint.mjJNT_HINGE,), strict=True):
        body.add_joint(name=name, type=kind, axis=axis, damping=0.0)
    body.add_site(name=BASE_SITE, pos=[0, 0, 0], size=[0.01, 0, 0], group=GROUP_ROBOT)
    for k, prism in enumerate(robot.prisms):
        _add_prism(spec, body, prism, k)
    _add_actuators(spec, robot)
    for sensor in robot.sensors:
        if sensor.type in ("lidar2d", "lidar3d"):
            _add_site(body, sensor.name, sensor.mount.T_base_sensor())
        elif isinstance(sensor, RGBDSensor):
            _add_camera(body, sensor)


def _set_inertia(body, robot: RobotSpec) -> None:
    xs = [x for p in robot.prisms for x, _ in p.polygon]
    ys = [y for p in robot.prisms for _, y in p.polygon]
    lx, ly = max(xs) - min(xs), max(ys) - min(ys)
    body.explicitinertial = True
    body.mass = robot.mass_kg
    izz = robot.mass_kg * (lx**2 + ly**2) / 12
    body.inertia = [izz, izz, izz]
    body.ipos = [0.0, 0.0, robot.height_m / 3]


def _add_prism(spec: mujoco.MjSpec, body, prism: Prism, index: int) -> None:
    for k, part in enumerate(convex_parts(prism.polygon)):
        ring = np.asarray(part, float)
        verts = np.concatenate([np.column_stack([ring, np.full(len(ring), z)]) for z in (prism.z_min_m, prism.z_max_m)])
        mesh = spec.add_mesh(name=f"robot_prism{index}_{k}")
        mesh.uservert = verts.ravel().tolist()
        body.add_geom(name=f"robot_{prism.name}_{k}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name,
                      rgba=[*prism.color, 1.0], group=GROUP_ROBOT, contype=CONTYPE_ROBOT,
                      conaffinity=CONTYPE_STATIC | CONTYPE_MOVING, friction=[0.3, 0.005, 0.0001])


def convex_parts(polygon: list[tuple[float, float]]) -> list[list[tuple[float, float]]]:
    """Split a simple polygon into convex pieces (itself if convex, else constrained Delaunay triangles)."""
    poly = Polygon(polygon)
    if math.isclose(poly.convex_hull.area, poly.area, rel_tol=1e-9):
        return [list(poly.exterior.coords)[:-1]]
    triangles = shapely.constrained_delaunay_triangles(poly)
    return [list(t.exterior.coords)[:-1] for t in triangles.geoms if t.area > 1e-9]


def _add_actuators(spec: mujoco.MjSpec, robot: RobotSpec) -> None:
    xs = [x for p in robot.prisms for x, _ in p.polygon]
    ys = [y for p in robot.prisms for _, y in p.polygon]
    izz = robot.mass_kg * ((max(xs) - min(xs)) ** 2 + (max(ys) - min(ys)) ** 2) / 12
    axes = {"forward": [1, 0, 0, 0, 0, 0], "lateral": [0, 1, 0, 0, 0, 0], "yaw": [0, 0, 0, 0, 0, 1]}
    for (name, gear), inertia in zip(axes.items(), (robot.mass_kg, robot.mass_kg, izz), strict=True):
        act = spec.add_actuator(name=f"robot_{name}", target=BASE_SITE, trntype=mujoco.mjtTrn.mjTRN_SITE)
        act.gear = gear
        act.set_to_velocity(kv=inertia / TRACKING_TIME_CONSTANT_S)


def _add_site(body, name: str, T_base_sensor: np.ndarray) -> None:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, T_base_sensor[:3, :3].ravel())
    body.add_site(name=name, pos=T_base_sensor[:3, 3].tolist(), quat=quat.tolist(), size=[0.02, 0, 0],
                  group=GROUP_ROBOT)


def _add_camera(body, sensor: RGBDSensor) -> None:
    T = sensor.mount.T_base_sensor()
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (T[:3, :3] @ R_BODY_MJCAM).ravel())
    body.add_camera(name=sensor.name, pos=T[:3, 3].tolist(), quat=quat.tolist(), fovy=resolve_rgbd(sensor).fovy_deg)
