"""Assembling one MuJoCo model from a world, a robot and a number of moving agents."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from simnav.robot.mjcf import JOINTS, ROBOT_BODY, add_robot
from simnav.robot.spec import RGBDSensor, RobotSpec
from simnav.sensors.presets import resolve_rgbd
from simnav.world import mjcf as world_mjcf
from simnav.world.schema import WorldSpec

SHIRT_COLORS = [(0.8, 0.2, 0.2), (0.2, 0.6, 0.3), (0.9, 0.7, 0.1), (0.3, 0.3, 0.8), (0.7, 0.3, 0.7),
                (0.1, 0.6, 0.7), (0.95, 0.5, 0.2), (0.5, 0.5, 0.5)]


@dataclass(frozen=True)
class SceneIndex:
    """Ids into the compiled model.

    Attributes:
        robot_body: body id of the robot.
        qpos_adr, dof_adr: (3,) addresses of the x, y, yaw joints.
        pedestrian_mocap, wanderer_mocap, door_mocap: (N,) mocap indices.
        pedestrian_body, wanderer_body, door_body: (N,) body ids.
        body_kind: (nbody,) array of "static" | "robot" | "pedestrian" | "wanderer" | "door".
    """

    robot_body: int
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    pedestrian_mocap: np.ndarray
    wanderer_mocap: np.ndarray
    door_mocap: np.ndarray
    pedestrian_body: np.ndarray
    wanderer_body: np.ndarray
    door_body: np.ndarray
    body_kind: np.ndarray


def build_scene(
    world: WorldSpec, robot: RobotSpec, pedestrians: int, wanderers: int, physics_dt_s: float
) -> tuple[mujoco.MjModel, SceneIndex]:
    """Compile the world, the robot, ``pedestrians`` people and ``wanderers`` other robots into one model."""
    spec = mujoco.MjSpec()
    spec.modelname = f"{world.name}_{robot.name}"
    _set_options(spec, robot, physics_dt_s)
    world_mjcf.add_static_world(spec, world)
    for k, door in enumerate(world.doors):
        world_mjcf.add_door(spec, door, f"door{k}")
    for k in range(pedestrians):
        world_mjcf.add_pedestrian(spec, f"ped{k}", SHIRT_COLORS[k % len(SHIRT_COLORS)])
    for k in range(wanderers):
        world_mjcf.add_wanderer(spec, f"wanderer{k}")
    add_robot(spec, robot)
    model = spec.compile()
    return model, _index(model, pedestrians, wanderers, len(world.doors))


def robot_alone(robot: RobotSpec, physics_dt_s: float) -> mujoco.MjSpec:
    """The spec of the robot alone, with the options of :func:`build_scene` (the shadow of
    :func:`simnav.sim.native.robot_shadow` is compiled from it)."""
    spec = mujoco.MjSpec()
    spec.modelname = f"{robot.name}_alone"
    _set_options(spec, robot, physics_dt_s)
    add_robot(spec, robot)
    return spec


def _set_options(spec: mujoco.MjSpec, robot: RobotSpec, physics_dt_s: float) -> None:
    spec.option.timestep = physics_dt_s
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # sleeping on: the static geoms' poses are computed once (the actuated robot never sleeps, mocap bodies count
    # as awake, so every step is the same as without it)
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    spec.option.gravity = [0.0, 0.0, -9.81]
    spec.stat.extent = 1.0  # znear/zfar below are then in metres
    spec.visual.map.znear = 0.02
    spec.visual.map.zfar = 60.0
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.numslices = 12  # coarser tessellation of capsules, spheres and cylinders: cheaper renders
    spec.visual.quality.numstacks = 6
    cams = [resolve_rgbd(s) for s in robot.sensors if isinstance(s, RGBDSensor)]
    spec.visual.global_.offwidth = max([c.width for c in cams], default=64)
    spec.visual.global_.offheight = max([c.height for c in cams], default=64)
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    light = spec.worldbody.add_light(name="sun", pos=[0, 0, 10], dir=[0.2, 0.3, -1.0], castshadow=False)
    light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    light.diffuse = [0.5, 0.5, 0.5]


def _index(model: mujoco.MjModel, pedestrians: int, wanderers: int, doors: int) -> SceneIndex:
    def bodies(prefix: str, n: int) -> np.ndarray:
        return np.array([model.body(f"{prefix}{k}").id for k in range(n)], dtype=int)

    ped, wan, door = bodies("ped", pedestrians), bodies("wanderer", wanderers), bodies("door", doors)
    robot_body = model.body(ROBOT_BODY).id
    kind = np.full(model.nbody, "static", dtype=object)
    kind[robot_body], kind[ped], kind[wan], kind[door] = "robot", "pedestrian", "wanderer", "door"
    joints = [model.joint(j) for j in JOINTS]
    return SceneIndex(
        robot_body=robot_body,
        qpos_adr=np.array([j.qposadr[0] for j in joints]),
        dof_adr=np.array([j.dofadr[0] for j in joints]),
        pedestrian_mocap=model.body_mocapid[ped], wanderer_mocap=model.body_mocapid[wan],
        door_mocap=model.body_mocapid[door], pedestrian_body=ped, wanderer_body=wan, door_body=door,
        body_kind=kind,
    )
