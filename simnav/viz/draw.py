"""The meshcat scene of a run: the static part once, then per frame what moved.

Scene tree (all under ``/meshcat``)::

    world                  floor, walls, furniture (one mesh, world frame)
    doors/d<i>             door leaves (node pose: hinge, leaf yaw)
    people/p<i>            pedestrians          robots/r<i>   other robots
    robot                  node pose: ground truth T_world_base
      prisms/<name>        the robot's prisms, one colour per height band
      scan, depth          lidar returns and depth-camera points (base frame)
    nav                    node pose: the navigator's estimate T_world_est
      pose                 axes of the estimated pose
      obstacles            obstacle points coloured by height band
      candidates/<ptg>     the fan of each PTG's paths      chosen   the chosen path (up to its free distance)
    route/line, route/target   the route being followed and its goal (world frame)
    trails/gt/c<k>, trails/est/c<k>   ground-truth and estimated trajectories (chunks of polyline)

meshcat's camera always orbits about the origin of the scene, so to follow the robot (``VizConfig.follow_robot``)
the whole ``/meshcat`` tree is shifted by minus the robot's position; without following, by minus the building's
centre. Poses below ``/meshcat`` stay world poses.
"""

from __future__ import annotations

import math

import numpy as np

from simnav.navigation.bands import FLOOR_TOLERANCE_M
from simnav.robot.spec import RobotSpec
from simnav.viz import style
from simnav.viz._meshcat import mg
from simnav.viz.commands import (
    Command,
    delete,
    line_object,
    mesh_object,
    points_object,
    pose3,
    pose_xy_yaw,
    poses_xy_yaw,
    set_object,
    set_property,
    set_transform,
    set_transforms,
)
from simnav.viz.config import VizConfig
from simnav.viz.frame import PathFan, SceneInfo, VizFrame, decimate, decimated
from simnav.viz.meshes import (
    door_leaf_mesh,
    person_mesh,
    robot_prism_meshes,
    target_mesh,
    wanderer_mesh,
    world_mesh,
)
from simnav.world.footprint import bounds

ROOT = "/meshcat"
ROBOT = f"{ROOT}/robot"
NAV = f"{ROOT}/nav"
CAMERA = "/Cameras/default/rotated/<object>"
LIGHT_HEIGHT_M = 12.0
PATH_HEIGHT_M = 0.03
TRAIL_HEIGHT_M = 0.05
DOOR_EPS_RAD = 1e-4


def person_path(i: int) -> str:
    return f"{ROOT}/people/p{i}"


def wanderer_path(i: int) -> str:
    return f"{ROOT}/robots/r{i}"


def door_path(i: int) -> str:
    return f"{ROOT}/doors/d{i}"


# ---------------------------------------------------------------------------------------------- static scene
def scene_commands(scene: SceneInfo, config: VizConfig, fans: list[PathFan] | None = None) -> list[Command]:
    """Everything that is drawn once: viewer set-up, building, doors, people, robots, the PTG fans."""
    commands = _viewer_setup(scene, config)
    # the building and the moving things' shapes (their poses come with the frames)
    commands.append(set_object(f"{ROOT}/world", mesh_object(world_mesh(scene.world))))
    for i, door in enumerate(scene.world.doors):
        commands.append(set_object(door_path(i), mesh_object(door_leaf_mesh(door))))
        commands.append(set_transform(door_path(i), pose_xy_yaw(*door.hinge, math.radians(door.closed_yaw_deg))))
    person, wanderer = mesh_object(person_mesh()), mesh_object(wanderer_mesh())
    commands += [set_object(person_path(i), person) for i in range(scene.people)]
    commands += [set_object(wanderer_path(i), wanderer) for i in range(scene.robots)]
    # the robot and what the navigator sees
    for name, mesh in robot_prism_meshes(scene.robot):
        commands.append(set_object(f"{ROBOT}/prisms/{name}", mesh_object(mesh)))
    commands.append(set_object(f"{NAV}/pose", mg.triad(0.5)))
    for fan in fans or []:
        commands.append(set_object(f"{NAV}/candidates/{fan.name}", fan_object(fan, config)))
    commands.append(set_object(f"{ROOT}/route/target", mesh_object(target_mesh())))
    commands.append(set_property(f"{ROOT}/route", "visible", False))
    return commands


def _viewer_setup(scene: SceneInfo, config: VizConfig) -> list[Command]:
    """Clear our part of the scene, hide meshcat's grid and axes, light from above, place the camera."""
    ox, oy, oz = config.camera_offset_m
    commands = [delete(ROOT), set_property("/Grid", "visible", False), set_property("/Axes", "visible", False)]
    for name, sign in (("PointLightPositiveX", 1.0), ("PointLightNegativeX", -1.0)):
        light = f"/Lights/{name}/<object>"
        commands += [set_property(light, "position", [sign * 6.0, sign * 4.0, LIGHT_HEIGHT_M]),
                     set_property(light, "distance", 0.0)]
    # the camera sits in a frame turned +90 deg about x (meshcat's y-up convention): world (x, y, z) = (x, -z, y)
    commands += [set_property(CAMERA, "position", [ox, oz, -oy]), set_property(CAMERA, "fov", config.camera_fov_deg)]
    if config.follow_robot and scene.world.spawns:
        centre = (scene.world.spawns[0].x_m, scene.world.spawns[0].y_m)
    else:
        x0, y0, x1, y1 = bounds(scene.world)
        centre = ((x0 + x1) / 2, (y0 + y1) / 2)
    commands.append(set_transform(ROOT, centre_on(*centre)))
    return commands


def centre_on(x_m: float, y_m: float) -> np.ndarray:
    """(4, 4) shift of the ``/meshcat`` tree that puts world point (x, y) at the camera's orbit centre."""
    return pose_xy_yaw(-x_m, -y_m, 0.0)


def fan_object(fan: PathFan, config: VizConfig) -> dict:
    """Every ``config.path_stride``-th path of a PTG as line segments in the ``base`` frame."""
    segments = []
    for k in range(0, len(fan.num_samples), config.path_stride):
        xy = decimate(fan.path(k), config.path_step_m)
        segments.append(np.stack([xy[:-1], xy[1:]], axis=1).reshape(-1, 2))
    xy = np.concatenate(segments)
    return line_object(np.column_stack([xy, np.full(len(xy), PATH_HEIGHT_M)]), style.CANDIDATE_COLOR, segments=True)


def chosen_path_object(fan: PathFan, k: int, free_distance: float, step_m: float,
                       keep: np.ndarray | None = None) -> dict:
    """Path ``k`` of a PTG up to its collision-free distance, in the ``base`` frame.

    Args:
        keep: ``decimated(fan.path(k), step_m)`` when the caller has it already.
    """
    keep = decimated(fan.path(k), step_m) if keep is None else keep
    end = fan.end(k, min(free_distance, 1.0))
    rows = np.append(keep[keep < end - 1], end - 1)
    xy = fan.xy[k, rows]
    return line_object(np.column_stack([xy, np.full(len(xy), 2 * PATH_HEIGHT_M)]), style.CHOSEN_COLOR)


def band_colors(points_base: np.ndarray, robot: RobotSpec) -> np.ndarray:
    """(K, 3) colour of each (K, 3) base-frame point: its height band's, or grey outside every band."""
    prisms = sorted(robot.prisms, key=lambda p: p.z_min_m)
    z_min = np.array([p.z_min_m for p in prisms])
    z_max = np.array([p.z_max_m for p in prisms])
    z = np.asarray(points_base, dtype=np.float64).reshape(-1, 3)[:, 2]
    band = np.searchsorted(z_min, z, side="right") - 1
    inside = (band >= 0) & (z >= FLOOR_TOLERANCE_M) & (z < z_max[np.clip(band, 0, None)])
    palette = np.array([style.band_color(b) for b in range(len(prisms))] + [style.UNBANDED_COLOR])
    return palette[np.where(inside, band, len(prisms))]


def route_commands(route_world: np.ndarray) -> list[Command]:
    """The route's polyline and the target marker at its last waypoint (hidden when there is no route)."""
    if len(route_world) == 0:
        return [set_property(f"{ROOT}/route", "visible", False)]
    line = np.column_stack([route_world, np.full(len(route_world), TRAIL_HEIGHT_M)])
    if len(line) == 1:
        line = np.vstack([line, line])
    x, y = route_world[-1]
    return [set_object(f"{ROOT}/route/line", line_object(line, style.ROUTE_COLOR)),
            set_transform(f"{ROOT}/route/target", pose_xy_yaw(float(x), float(y), 0.0)),
            set_property(f"{ROOT}/route", "visible", True)]


# ---------------------------------------------------------------------------------------------- live frames
class FrameDrawer:
    """Turns successive frames into the commands that update a live scene (only what changed).

    Args:
        scene: the static scene the frames belong to.
        config: viewer options.
        fans: the navigator's PTG paths (None: no chosen path is drawn).
    """

    def __init__(self, scene: SceneInfo, config: VizConfig, fans: list[PathFan] | None = None) -> None:
        self.scene, self.config = scene, config
        self._fans = {fan.name: fan for fan in fans or []}
        self._doors = np.full(len(scene.world.doors), np.nan)
        self._route = np.zeros((0, 2))
        self._chosen: tuple[str, int, float] | None = None
        self._trails: dict[str, list[np.ndarray]] = {"gt": [], "est": []}
        self._chunk = {"gt": 0, "est": 0}
        self._people = [person_path(i) for i in range(scene.people)]
        self._robots = [wanderer_path(i) for i in range(scene.robots)]
        self._paths: dict[tuple[str, int], np.ndarray] = {}  # decimated samples of each path drawn so far

    def commands(self, frame: VizFrame) -> list[Command]:
        """The commands that bring the scene to ``frame``."""
        T_robot = pose3(frame.T_world_base)
        out = [set_transform(ROBOT, T_robot)]
        # agents: every person and robot moves, doors only now and then
        out += set_transforms(self._people, poses_xy_yaw(frame.people))
        out += set_transforms(self._robots, poses_xy_yaw(frame.robots))
        out += self._door_commands(frame.door_yaws_rad)
        # sensors in the robot's frame
        size = self.config.point_size_m
        out.append(set_object(f"{ROBOT}/scan", points_object(frame.scan_base, style.SCAN_COLOR, size)))
        out.append(set_object(f"{ROBOT}/depth", points_object(frame.depth_base, style.DEPTH_COLOR, size)))
        # the navigator: its pose, obstacles, chosen path and route
        if frame.T_world_est is not None:
            out.append(set_transform(NAV, pose3(frame.T_world_est)))
            out.append(set_object(f"{NAV}/obstacles", points_object(
                frame.obstacles_base, band_colors(frame.obstacles_base, self.scene.robot), size)))
            out += self._chosen_commands(frame)
            out += self._route_commands(frame.route_world)
        # trails and camera
        out += self._trail_commands("gt", frame.T_world_base[:2, 2], style.GT_TRAIL_COLOR)
        if frame.T_world_est is not None:
            out += self._trail_commands("est", frame.T_world_est[:2, 2], style.EST_TRAIL_COLOR)
        if self.config.follow_robot:
            out.append(set_transform(ROOT, centre_on(*frame.T_world_base[:2, 2])))
        return out

    def _door_commands(self, yaws_rad: np.ndarray) -> list[Command]:
        changed = ~(np.abs(yaws_rad - self._doors) < DOOR_EPS_RAD)
        self._doors = np.array(yaws_rad, dtype=np.float64)
        doors = self.scene.world.doors
        return [set_transform(door_path(i), pose_xy_yaw(*doors[i].hinge, float(yaws_rad[i])))
                for i in np.flatnonzero(changed)]

    def _chosen_commands(self, frame: VizFrame) -> list[Command]:
        fan = self._fans.get(frame.ptg)
        key = (frame.ptg, frame.path_index, round(frame.free_distance, 2)) if fan and frame.path_index >= 0 else None
        if key == self._chosen:
            return []
        shown, self._chosen = self._chosen is not None, key
        if key is None:
            return [set_property(f"{NAV}/chosen", "visible", False)]
        step = self.config.path_step_m
        keep = self._paths.get(key[:2])
        if keep is None:
            keep = self._paths[key[:2]] = decimated(fan.path(frame.path_index), step)
        out = [set_object(f"{NAV}/chosen", chosen_path_object(fan, frame.path_index, frame.free_distance, step, keep))]
        return out if shown else [*out, set_property(f"{NAV}/chosen", "visible", True)]

    def _route_commands(self, route_world: np.ndarray) -> list[Command]:
        if np.array_equal(route_world, self._route):
            return []
        self._route = np.array(route_world, dtype=np.float64)
        return route_commands(self._route)

    def _trail_commands(self, name: str, xy: np.ndarray, color: style.RGB) -> list[Command]:
        """Extend the trail once the pose has moved ``trail_step_m``; re-send only its last chunk (a full chunk
        starts the next one)."""
        trail = self._trails[name]
        if trail and np.hypot(xy[0] - trail[-1][0], xy[1] - trail[-1][1]) < self.config.trail_step_m:
            return []
        trail.append(np.array([xy[0], xy[1], TRAIL_HEIGHT_M]))
        if len(trail) < 2:
            return []
        command = set_object(f"{ROOT}/trails/{name}/c{self._chunk[name]}", line_object(np.array(trail), color))
        if len(trail) >= self.config.trail_chunk:
            self._trails[name] = [trail[-1]]
            self._chunk[name] += 1
        return [command]
