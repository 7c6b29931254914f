"""``simnav mission``: a robot navigates to random roadmap targets among people, headless, and reports how it went.

As in §6.C.7, targets are drawn at random from the world's roadmap (not in doorways); the route to each is the
roadmap's shortest path, handed to the 3D-PTG navigator as waypoints that it follows without stopping (doorways are
passed through, lined up before them: :func:`route_waypoints`). The navigator sees every range sensor of the
robot (lidars, 3D lidars, depth cameras) and uses the pose of the chosen source (ground truth, or an odometry
anchored at the true start). A robot that has not come closer to its target for 30 s is *stuck*: that counts as
an intervention and the robot is moved to the next roadmap node of its route, as a person would. Contacts with
walls, furniture, doors and people are the minor incidents of Table 6.1.

Output folder (``--out``): ``report.json`` (schema in the README), ``trajectory_gt.txt`` and
``trajectory_est.txt`` (TUM), ``mission.png`` (top view: map, path, targets, incidents), ``navigation.csv`` (the
navigator's decision at every control step) and the settings.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Annotated, Literal, get_args, get_type_hints

import numpy as np
from pydantic import Field, field_validator, model_validator

import simnav
from simnav.config import FrozenModel, dump_yaml
from simnav.geometry import se2
from simnav.io import TumWriter, json_finite
from simnav.mission.observer import MissionFrame, MissionObserver
from simnav.mission.pose import PoseSource
from simnav.navigation.bands import planar_bands, robot_bands
from simnav.navigation.memory import MemoryConfig
from simnav.navigation.navigator import NavigatorConfig, ReactiveNavigator3D
from simnav.navigation.sensing import SensedObstacles, camera_free_space, view_sectors
from simnav.robot.interface import RobotInterface
from simnav.robot.spec import RobotSpec
from simnav.sim import SimConfig, Simulator
from simnav.sim.robot import SimRobot
from simnav.world.footprint import clearance_m, door_swing_distance_m, obstacle_union
from simnav.world.schema import WorldSpec

INCIDENT_MERGE_S = 1.0
"""Contacts with the same body closer in time than this are one incident, s."""

CLEARANCE_PERIOD_S = 0.2
"""The robot's clearance to static obstacles is measured at this period, s."""

STOPPED_M_S = 0.05
"""A contact while no point of the robot moved faster than this is one the robot did not drive into (someone walked
into it), m/s."""

NARROW_NODE_CLEARANCE_M = 0.75
"""Roadmap nodes closer than this to a static obstacle (doorways) are passed through, not skipped, m."""

NARROW_NODE_TOLERANCE_M = 0.3
"""... within this distance, m."""

SET_DOWN_CLEARANCE_M = 0.3
"""An intervention sets the robot down at a node where it stands at least this far from every person and robot, m."""

DOOR_APPROACH_TOLERANCE_M = 0.15
"""The approach waypoint before a narrow node is passed within this distance, facing the narrow node (within the
navigator's ``waypoint_heading_tolerance_rad``; it turns in place there): a robot that cut the corner into a doorway
off its axis had no path left through it, m."""

TURNING_NODE_RAD = math.radians(45.0)
"""The first place to turn after a doorway, where the route turns by more than this, is passed close by (see
:func:`route_waypoints`), rad."""

DOOR_APPROACH_M = 0.6
"""A narrow node is approached through a waypoint this far before it, towards the previous node of the route (and
left through one as far after it), so that the robot lines up with a doorway instead of cutting into it at an
angle, m (at most half the distance to that node)."""

KEEP_RIGHT_WALL_M = 0.2
"""A waypoint moved to the right of the route (``MissionSettings.keep_right_m``) keeps the robot's circumradius plus
this much from every static obstacle, m."""

STRAIGHT_NODE_RAD = math.radians(30.0)
"""Only nodes where the route turns by less than this are moved to the right of it, rad."""



NavigatorValue = bool | int | float | str | None  # a scalar navigator option of ``--nav-set``


class MissionSettings(FrozenModel):
    """What to run: how many targets (or how long), which seed, pose source, navigator model and simulator.

    ``replan_after_s``: the route to the target is planned again from where the robot stands once the waypoint the
    navigator aims at has been out of sight behind the map's walls this long, s (None, the default: never; see
    ``_MissionRunner._replan_if_off_route`` and the README: 3 s did not lower the office's interventions).
    """

    targets: Annotated[int, Field(ge=1, le=100000)] | None = 2
    duration_s: Annotated[float, Field(gt=0, le=10 * 86400)] | None = None
    seed: int = 1
    pose_source: str = "gt"
    nav: Literal["3d", "2d"] = "3d"
    stuck_timeout_s: Annotated[float, Field(gt=0)] = 30.0
    max_target_time_s: Annotated[float, Field(gt=0)] = 300.0
    memory: bool = True
    keep_right_m: Annotated[float, Field(ge=0, le=2)] = 0.4
    replan_after_s: Annotated[float, Field(gt=0)] | None = None
    navigator: dict[str, NavigatorValue | dict[str, NavigatorValue]] = {}
    sim: SimConfig = SimConfig()

    @field_validator("navigator", mode="before")
    @classmethod
    def _navigator_values(cls, value: object) -> object:
        """One error naming the option whose value is not a scalar (instead of one per type it could have had)."""
        if not isinstance(value, dict):
            return value  # pydantic's own error: expected a mapping
        for key, item in value.items():
            for sub, scalar in item.items() if isinstance(item, dict) else [(None, item)]:
                if not (scalar is None or isinstance(scalar, bool | int | float | str)):
                    name = key if sub is None else f"{key}.{sub}"
                    raise ValueError(f"{name}: expected one value (true/false, a number, a word or null), "
                                     f"got {scalar!r}")
        return value

    @model_validator(mode="after")
    def _budget(self) -> MissionSettings:
        if self.targets is None and self.duration_s is None:
            raise ValueError("give targets or duration_s")
        navigator_config(self)  # unknown or bad navigator fields fail here, naming the field
        return self


def navigator_config(settings: MissionSettings) -> NavigatorConfig:
    """The navigator options of a mission: the product defaults, the mission's memory and stuck timeout, then
    ``settings.navigator``'s overrides of scalar :class:`NavigatorConfig` fields and of the short-term memory's
    :class:`MemoryConfig` fields under ``memory_config`` (``--nav-set KEY=VALUE``,
    ``--nav-set memory_config.decay_s=10``)."""
    options = dict(settings.navigator)
    memory = options.pop("memory_config", {})
    if not isinstance(memory, dict):
        raise ValueError(f"navigator: memory_config takes fields (memory_config.decay_s=10), got {memory!r}")
    _check_fields("navigator", options, NavigatorConfig, skip=("ptgs", "memory_config"))
    _check_fields("navigator: memory_config", memory, MemoryConfig)
    nested = [k for k, v in options.items() if isinstance(v, dict)]
    if nested:
        raise ValueError(f"navigator: {', '.join(nested)} takes a value, not fields")
    _check_types("navigator", options, NavigatorConfig)
    _check_types("navigator: memory_config", memory, MemoryConfig)
    try:
        return NavigatorConfig(**{"memory": settings.memory, "stuck_timeout_s": settings.stuck_timeout_s,
                                  **options, "memory_config": MemoryConfig(**memory)})
    except ValueError as err:
        raise ValueError(f"navigator: {err}") from None


def _check_fields(what: str, options: dict, config_type: type, skip: Sequence[str] = ()) -> None:
    """One error naming every key of ``options`` that is not a field of the dataclass ``config_type``."""
    known = {f.name for f in fields(config_type) if f.name not in skip}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ValueError(f"{what}: unknown field(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")


_KINDS = {bool: "true or false", int: "a whole number", float: "a number", str: "a word", type(None): "null"}


def _check_types(what: str, options: dict, config_type: type) -> None:
    """One error naming the first option of ``options`` whose value does not have the type of its field in the
    dataclass ``config_type`` (a whole number is a number too; true/false is neither)."""
    hints = get_type_hints(config_type)
    for key, value in options.items():
        allowed = get_args(hints[key]) or (hints[key],)
        if not any(_is_kind(value, kind) for kind in allowed):
            expected = " or ".join(_KINDS.get(kind, getattr(kind, "__name__", str(kind))) for kind in allowed)
            raise ValueError(f"{what}: {key} takes {expected}, got {value!r}")


def _is_kind(value: object, kind: type) -> bool:
    if kind is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


@dataclass
class TargetRow:
    """One target of the mission."""

    index: int
    node: int
    x_m: float
    y_m: float
    start_s: float = 0.0
    reached: bool = False
    time_s: float = 0.0
    distance_m: float = 0.0
    shortest_m: float = 0.0
    path_length_ratio: float = float("nan")
    interventions: int = 0
    incidents: int = 0


@dataclass
class MissionReport:
    """Everything ``report.json`` holds (see the README for the schema)."""

    simnav_version: str
    world: str
    robot: str
    seed: int
    nav: str
    pose_source: str
    people: int
    targets_requested: int = 0
    targets_reached: int = 0
    distance_m: float = 0.0
    duration_s: float = 0.0
    avg_speed_m_s: float = 0.0
    max_speed_m_s: float = 0.0
    minor_incidents: dict = field(default_factory=lambda: {"static": 0, "door": 0, "people": 0, "robots": 0,
                                                           "total": 0, "robot_stopped": 0})
    interventions: int = 0
    replans: int = 0
    min_clearance_m: float = float("inf")
    path_length_ratio: float = float("nan")
    navigator_step_ms: dict = field(default_factory=lambda: {"median": 0.0, "p95": 0.0})
    state_time_s: dict = field(default_factory=dict)
    real_time_factor: float = 0.0
    wall_time_s: float = 0.0
    odometry: dict | None = None
    targets: list[TargetRow] = field(default_factory=list)
    incidents: list[dict] = field(default_factory=list)
    intervention_log: list[dict] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return self.targets_reached / self.targets_requested if self.targets_requested else 0.0

    def to_json(self) -> str:
        data = asdict(self)
        data["success_rate"] = self.success_rate
        return json.dumps(json_finite(data), indent=2)


@dataclass
class MissionProgress:
    """Passed to the progress callback after every control step."""

    sim_time_s: float
    targets_done: int
    targets_reached: int
    distance_m: float


def mission_robot(robot: RobotSpec, settings: MissionSettings) -> RobotSpec:
    """The robot as a mission runs it: cameras render depth only, unless the pose source needs colour."""
    if settings.pose_source == "vosf":
        return robot
    sensors = [s.model_copy(update={"rgb": False}) if s.type == "rgbd" else s for s in robot.sensors]
    return robot.model_copy(update={"sensors": sensors})


def mission_sim_config(settings: MissionSettings) -> SimConfig:
    """The simulator settings of a mission: closed loop, so readings arrive exactly at their stamps."""
    return settings.sim.model_copy(update={"lockstep": True})


RobotFactory = Callable[[Simulator], RobotInterface]
"""Makes the robot a mission commands from its simulator: :class:`SimRobot` by default; hardware-in-the-loop
wraps the simulator so the base moves by what real motors measure (see :mod:`simnav.hardware`)."""


def run_mission(world: WorldSpec, robot: RobotSpec, settings: MissionSettings, out_dir: Path | None = None,
                progress: Callable[[MissionProgress], None] | None = None,
                observers: Sequence[MissionObserver] = (), robot_factory: RobotFactory | None = None) -> MissionReport:
    """Run a mission and (with ``out_dir``) write its report, trajectories and plot.

    Args:
        observers: called before the first step, after every control step and at the end (a viewer).
        robot_factory: the robot interface to command (default: the simulated robot).

    Returns:
        The report; its ``targets`` rows list every target drawn, reached or not.
    """
    runner = _MissionRunner(world, robot, settings, out_dir, robot_factory)
    try:
        return runner.run(progress, observers)
    finally:
        runner.close()


class _MissionRunner:
    def __init__(self, world: WorldSpec, robot: RobotSpec, settings: MissionSettings, out_dir: Path | None,
                 robot_factory: RobotFactory | None = None) -> None:
        self.world, self.robot_spec, self.settings = world, robot, settings
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.pose = PoseSource(settings.pose_source, robot)
        self.sim = Simulator(world, robot, mission_sim_config(settings), seed=settings.seed)
        self.robot = (robot_factory or SimRobot)(self.sim)
        bands = robot_bands(robot) if settings.nav == "3d" else planar_bands(robot)
        nav_cfg = navigator_config(settings)
        drive = robot.drive
        self.nav = ReactiveNavigator3D(bands, drive.max_v_m_s, drive.max_w_rad_s, max_acc_m_s2=drive.max_acc_m_s2,
                                       max_ang_acc_rad_s2=drive.max_ang_acc_rad_s2, config=nav_cfg,
                                       view=view_sectors(robot), free_space_x_m=camera_free_space(robot, bands))
        self.obstacles = SensedObstacles()
        self.rng = np.random.default_rng(np.random.SeedSequence([settings.seed, 7]))
        self.report = MissionReport(simnav.__version__, world.name, robot.name, settings.seed, settings.nav,
                                    settings.pose_source, self.sim.pedestrian_count)
        nodes = self.sim.roadmap.nodes_xy
        z_max_m = max(p.z_max_m for p in robot.prisms)
        node_clearance_m = clearance_m(self.sim.world, nodes, 0.0, z_max_m)
        self._narrow = node_clearance_m < NARROW_NODE_CLEARANCE_M
        self._circumradius_m = max(math.hypot(x, y) for p in robot.prisms for x, y in p.polygon)
        self._turnable = node_clearance_m >= self._circumradius_m + self.nav.config.footprint_margin_m
        room_m = node_clearance_m - self._circumradius_m - KEEP_RIGHT_WALL_M
        self._keep_right_m = np.clip(room_m, 0.0, settings.keep_right_m)
        # nodes where the robot would stand in a door's swing: the leaf, open or moving, blocks it there, and a
        # robot waiting there keeps the door open
        in_swing = door_swing_distance_m(self.sim.world, nodes) < self._circumradius_m
        self._unfit = self._narrow | in_swing  # no place to stand: targets and set-downs avoid these nodes
        # two-node doorways approached along their axis, where the robot can turn in place clear of the doors' swing
        turn_m = self._circumradius_m + self.nav.config.footprint_margin_m
        self._axis_approach = doorway_axis_approaches(
            nodes, self.sim.roadmap.edges, self._narrow,
            lambda xy: np.minimum(clearance_m(self.sim.world, xy, 0.0, z_max_m),
                                  door_swing_distance_m(self.sim.world, xy)) - turn_m)
        self._static = [obstacle_union(self.sim.world, p.z_min_m, p.z_max_m) for p in robot.prisms]
        self._walls = wall_segments(self.sim.world)
        self._out_of_sight_since_s: float | None = None
        self._gt: list[tuple[float, np.ndarray]] = []
        self._step_times: list[float] = []
        self._nav_log: list[tuple] = []  # one row per control step (see NAV_LOG_COLUMNS)
        self._speeds: list[float] = []
        self._settle_steps = 0

    def close(self) -> None:
        self.robot.stop()
        close = getattr(self.robot, "close", None)
        if close is not None:
            close()
        self.sim.close()

    # ------------------------------------------------------------------------------------------------- loop
    def run(self, progress: Callable[[MissionProgress], None] | None,
            observers: Sequence[MissionObserver] = ()) -> MissionReport:
        for obs in observers:
            obs.start(self.world, self.robot_spec, self.sim, self.nav)
        try:
            self._loop(progress, observers)
        finally:
            for obs in observers:
                obs.finish(self.report)
        return self.report

    def _loop(self, progress: Callable[[MissionProgress], None] | None,
              observers: Sequence[MissionObserver]) -> None:
        s, started = self.settings, time.perf_counter()
        self.pose.anchor(0.0, self._true_pose())
        self._record_gt()
        next_clearance = 0.0
        route = self._new_target()
        while not self._finished():
            cmd = self._control_step()
            if observers:
                frame = self._frame(cmd)
                for obs in observers:
                    obs.step(frame)
            self._record_gt()
            if self.sim.time_s >= next_clearance:
                self._measure_clearance()
                next_clearance = self.sim.time_s + CLEARANCE_PERIOD_S
            row = self.report.targets[-1]
            if cmd.state == "reached":
                self._close_target(row, reached=True)
                route = self._new_target() if not self._finished() else route
            elif cmd.stuck:
                route = self._intervene(row, route)
            elif self.sim.time_s - self._target_start_s > s.max_target_time_s:
                self._close_target(row, reached=False)
                route = self._new_target() if not self._finished() else route
            else:
                route = self._replan_if_off_route(cmd, route)
            if progress is not None:
                progress(MissionProgress(self.sim.time_s, self._targets_done(), self.report.targets_reached,
                                         self.report.distance_m))
        self._finish(time.perf_counter() - started)

    def _finished(self) -> bool:
        s = self.settings
        if s.duration_s is not None and self.sim.time_s >= s.duration_s:
            return True
        return s.targets is not None and self._targets_done() >= s.targets

    def _targets_done(self) -> int:
        return sum(1 for r in self.report.targets if r.reached or r.time_s > 0)

    def _control_step(self):
        # Readings since the last step: odometry and obstacle points
        T_true = self._true_pose()
        readings = self.robot.poll_readings()
        for reading in readings:
            self.pose.feed(reading)
            T_at = (se2.from_se3(self.sim.T_world_base_at(reading.stamp_s)) if self.pose.is_ground_truth
                    else self.pose.T_world_base())
            self.obstacles.add(reading, T_at)
        # Navigate from the estimated pose
        now = self.robot.now_s()
        T_est = self.pose.T_world_base(T_true)
        points_base, scan_points_base = self.obstacles.split_points_base(now, T_est)
        cmd = self.nav.step(now, T_est, points_base, scan_points_base)
        self._step_times.append(cmd.runtime_s)
        self._nav_log.append((now, *se2.to_xy_yaw(T_true), cmd.v_m_s, cmd.w_rad_s, cmd.state, cmd.target_index,
                              cmd.ptg, cmd.path_index, cmd.free_distance, cmd.speed))
        self._last_step = (T_est, points_base, scan_points_base, readings)
        self.robot.send_velocity(cmd.v_m_s, cmd.w_rad_s)
        self.robot.wait_next_period()
        return cmd

    def _frame(self, cmd) -> MissionFrame:
        T_est, points_base, scan_points_base, readings = self._last_step
        return MissionFrame(self.sim.time_s, self._true_pose(), T_est, cmd, readings,
                            np.concatenate([points_base, scan_points_base]), self._route_xy)

    # ---------------------------------------------------------------------------------------------- targets
    def _new_target(self) -> list[int]:
        """Draw the next target node and hand its roadmap route to the navigator."""
        graph = self.sim.roadmap
        xy = self._true_pose()[:2, 2]
        start = graph.nearest_node(xy)
        node = self._random_target(start)
        route = graph.shortest_path(start, node)
        shortest = float(np.linalg.norm(graph.nodes_xy[route[0]] - xy)) + graph.path_length_m(route)
        target = graph.nodes_xy[node]
        self.report.targets.append(TargetRow(len(self.report.targets), int(node), float(target[0]),
                                             float(target[1]), start_s=self.sim.time_s, shortest_m=shortest))
        self.report.targets_requested += 1
        self._target_start_s, self._target_start_distance = self.sim.time_s, self.report.distance_m
        self._follow(route)
        return route

    def _random_target(self, start: int) -> int:
        """A roadmap node other than ``start`` to go to, drawn uniformly; not a narrow one nor one in a door's
        swing (a doorway is no place to stand) unless every node is."""
        candidates = np.nonzero(~self._unfit)[0]
        candidates = candidates[candidates != start]
        if len(candidates) == 0:
            return self.sim.roadmap.random_node(self.rng, exclude=start)
        return int(candidates[self.rng.integers(len(candidates))])

    def _follow(self, route: list[int], keep_stuck_timer: bool = False) -> None:
        """Hand a roadmap route to the navigator (:func:`route_waypoints`)."""
        xy, skip, near, heading, doorway = route_waypoints(self.sim.roadmap.nodes_xy, route, self._narrow,
                                                           self.nav.config.waypoint_allowed_distance_m,
                                                           self._turnable, self._keep_right_m, self._axis_approach)
        self._route_xy = xy
        self.nav.set_waypoints(xy, allow_skip=skip, allowed_distance_m=near, headings_rad=heading, give_way=doorway,
                               keep_stuck_timer=keep_stuck_timer)
        self._out_of_sight_since_s = None

    def _replan_if_off_route(self, cmd, route: list[int]) -> list[int]:
        """Off the route: the waypoint the navigator aims at has been out of sight behind the map's walls for
        ``MissionSettings.replan_after_s`` (people pushed the robot through a doorway the route passes by, and
        inside the room it followed the wall towards a waypoint in the corridor beyond it, turning on the spot in
        the corner): the route to the same goal is planned again from the nearest roadmap node in sight of the
        estimated pose. The navigator's time without progress runs on (``keep_stuck_timer``)."""
        if self.settings.replan_after_s is None:
            return route
        xy = self._last_step[0][:2, 2]
        aimed = self._route_xy[cmd.target_index] if 0 <= cmd.target_index < len(self._route_xy) else xy
        now = self.sim.time_s
        if in_sight(xy, aimed[None], self._walls)[0]:
            self._out_of_sight_since_s = None
            return route
        if self._out_of_sight_since_s is None:
            self._out_of_sight_since_s = now
        if now - self._out_of_sight_since_s < self.settings.replan_after_s:
            return route
        graph = self.sim.roadmap
        order = np.argsort(np.linalg.norm(graph.nodes_xy - xy, axis=1))
        seen = order[in_sight(xy, graph.nodes_xy[order], self._walls)]
        new = graph.shortest_path(int(seen[0]), route[-1]) if len(seen) else []
        self._out_of_sight_since_s = None
        if not new:
            return route
        self.report.replans += 1
        self._follow(new, keep_stuck_timer=True)
        return new

    def _close_target(self, row, reached: bool) -> None:
        row.reached = reached
        row.time_s = max(self.sim.time_s - self._target_start_s, 1e-9)
        row.distance_m = self.report.distance_m - self._target_start_distance
        if reached:
            self.report.targets_reached += 1
            if row.interventions == 0 and row.shortest_m > 0:
                row.path_length_ratio = row.distance_m / row.shortest_m

    def _intervene(self, row, route: list[int]) -> list[int]:
        """Stuck: move the robot to the next roadmap node of its route that is not in a doorway or a door's swing
        and that nobody stands on, and go on (counted as an intervention); a robot set down in a doorway, facing
        along the route, can touch its jambs, one set down on people touches them. When only the goal is left and
        someone stands on it, the robot is set down at the free node nearest to it and goes on from there."""
        graph = self.sim.roadmap
        xy = self._true_pose()[:2, 2]
        closest = int(np.argmin(np.linalg.norm(graph.nodes_xy[route] - xy, axis=1)))
        taken = self._taken_nodes()
        remaining = resume_route(route, closest, self._unfit, taken)
        free = np.nonzero(~self._unfit & ~taken)[0]
        if taken[remaining[0]] and len(free):
            near = free[np.argmin(np.linalg.norm(graph.nodes_xy[free] - graph.nodes_xy[remaining[0]], axis=1))]
            remaining = graph.shortest_path(int(near), route[-1])
        node = remaining[0]
        nxt = remaining[1] if len(remaining) > 1 else node
        heading = graph.nodes_xy[nxt] - graph.nodes_xy[node]
        yaw = math.atan2(heading[1], heading[0]) if np.linalg.norm(heading) > 0 else 0.0
        x, y = graph.nodes_xy[node]
        self.sim.teleport(float(x), float(y), yaw)
        self.report.interventions += 1
        row.interventions += 1
        self.report.intervention_log.append({"time_s": self.sim.time_s, "target": row.index, "x_m": float(xy[0]),
                                             "y_m": float(xy[1]), "moved_to_node": int(node)})
        self.pose.anchor(self.sim.time_s, self._true_pose())
        self.obstacles.reset()
        self._last_xy = None
        self._settle_steps = 10
        self._follow(remaining)
        return remaining

    def _taken_nodes(self) -> np.ndarray:
        """(N,) roadmap nodes where the robot, set down there, would stand within ``SET_DOWN_CLEARANCE_M`` of a
        person or another robot."""
        nodes = self.sim.roadmap.nodes_xy
        taken = np.zeros(len(nodes), dtype=bool)
        for agents in (self.sim.crowd, self.sim.wanderers):
            if agents.count:
                gap = np.linalg.norm(nodes[:, None, :] - agents.positions_xy[None, :, :], axis=2)
                taken |= np.any(gap < self._circumradius_m + agents.radius_m + SET_DOWN_CLEARANCE_M, axis=1)
        return taken

    # ----------------------------------------------------------------------------------------- measurements
    def _true_pose(self) -> np.ndarray:
        return se2.from_se3(self.sim.T_world_base)

    def _record_gt(self) -> None:
        T = self.sim.T_world_base
        if self._gt and getattr(self, "_last_xy", None) is not None:
            step = float(np.linalg.norm(T[:2, 3] - self._last_xy))
            self.report.distance_m += step
        self._last_xy = T[:2, 3].copy()
        self._gt.append((self.sim.time_s, T.copy()))
        v, _ = self.sim.base_velocity()
        if self._settle_steps > 0:  # the base is still settling after being moved by an intervention
            self._settle_steps -= 1
        else:
            self._speeds.append(abs(v))

    def _measure_clearance(self) -> None:
        """Distance from every prism of the robot (true pose) to the static obstacles in its height band."""
        from shapely import affinity
        from shapely.geometry import Polygon

        x, y, yaw = self.sim.pose_xy_yaw
        for prism, static in zip(self.robot_spec.prisms, self._static, strict=True):
            if static.is_empty:
                continue
            shape = affinity.translate(affinity.rotate(Polygon(prism.polygon), yaw, origin=(0, 0), use_radians=True),
                                       x, y)
            self.report.min_clearance_m = min(self.report.min_clearance_m, float(shape.distance(static)))

    def _finish(self, wall_s: float) -> None:
        r = self.report
        last = r.targets[-1] if r.targets else None
        if last is not None and not last.reached and last.time_s == 0:
            # the mission ended (duration) while this target was under way: it is neither reached nor requested
            r.targets.pop()
            r.targets_requested -= 1
        r.duration_s = self.sim.time_s
        r.wall_time_s = wall_s
        r.real_time_factor = self.sim.time_s / wall_s if wall_s > 0 else math.inf
        r.avg_speed_m_s = r.distance_m / r.duration_s if r.duration_s > 0 else 0.0
        r.max_speed_m_s = float(max(self._speeds, default=0.0))
        ms = np.array(self._step_times) * 1e3
        r.navigator_step_ms = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95))} if len(ms) else \
            {"median": 0.0, "p95": 0.0}
        r.state_time_s = self._state_times()
        ratios = [t.path_length_ratio for t in r.targets if math.isfinite(t.path_length_ratio)]
        r.path_length_ratio = float(np.mean(ratios)) if ratios else float("nan")
        self._count_incidents()
        if not self.pose.is_ground_truth:
            r.odometry = self._odometry_drift()
        if self.out_dir is not None:
            self._write()

    def _state_times(self) -> dict:
        """Simulated time the navigator spent in each state, s (each step counts until the next one)."""
        times: dict[str, float] = {}
        rows = self._nav_log
        for row, nxt in zip(rows, rows[1:] + [None], strict=True):
            dt = (nxt[0] if nxt is not None else self.sim.time_s) - row[0]
            times[row[6]] = times.get(row[6], 0.0) + max(dt, 0.0)
        return {state: round(t, 3) for state, t in sorted(times.items())}

    def _count_incidents(self) -> None:
        """Contacts merged per body within ``INCIDENT_MERGE_S``, sorted into static / door / people / robots."""
        r = self.report
        last_seen: dict[str, float] = {}
        for event in self.sim.contact_events:
            previous = last_seen.get(event.other)
            last_seen[event.other] = event.stamp_s
            if previous is not None and event.stamp_s - previous < INCIDENT_MERGE_S:
                continue
            kind = _incident_kind(event.kind, event.other)
            speed = self._speed_before(event.stamp_s)
            r.minor_incidents[kind] += 1
            r.minor_incidents["total"] += 1
            r.minor_incidents["robot_stopped"] += int(speed < STOPPED_M_S)
            target = _target_at(r.targets, event.stamp_s)
            if target is not None:
                target.incidents += 1
            r.incidents.append({"time_s": event.stamp_s, "kind": kind, "other": event.other,
                                "x_m": float(event.position_world[0]), "y_m": float(event.position_world[1]),
                                "robot_speed_m_s": speed})

    def _speed_before(self, stamp_s: float, window_s: float = 0.25) -> float:
        """Fastest speed of any point of the robot over ``window_s`` before ``stamp_s`` (ground truth): the base's
        speed plus its yaw rate times the robot's circumradius, m/s."""
        stamps = np.array([t for t, _ in self._gt])
        i, j = np.searchsorted(stamps, [stamp_s - window_s, stamp_s], side="right")
        i, j = max(i - 1, 0), max(j - 1, 0)
        if j <= i:
            return 0.0
        T_i, T_j = se2.from_se3(self._gt[i][1]), se2.from_se3(self._gt[j][1])
        dx, dy, dyaw = se2.log(se2.inverse(T_i) @ T_j)
        return float((math.hypot(dx, dy) + abs(dyaw) * self._circumradius_m) / (stamps[j] - stamps[i]))

    def _odometry_drift(self) -> dict:
        from simnav.io.tum import Trajectory
        from simnav.metrics import ate, rpe_per_second

        est = self.pose.estimates
        if len(est) < 3:
            return {"source": self.pose.name, "error": "too few estimates"}
        gt = Trajectory(np.array([t for t, _ in self._gt]), np.array([T for _, T in self._gt]))
        est_traj = Trajectory(np.array([t for t, _ in est]), np.array([se2.to_se3(T) for _, T in est]))
        out = {"source": self.pose.name, "sensor": self.pose.sensor, "anchors": 1 + self.report.interventions}
        try:
            out["rpe"] = rpe_per_second(est_traj, gt).as_dict()
            out["ate"] = ate(est_traj, gt).as_dict()
            final = np.linalg.norm(est[-1][1][:2, 2] - self._gt[-1][1][:2, 3])
            out["final_error_m"] = float(final)
        except ValueError as err:
            out["error"] = str(err)
        return out

    # ------------------------------------------------------------------------------------------------ files
    def _write(self) -> None:
        from simnav.mission.plot import plot_mission

        out = self.out_dir
        out.mkdir(parents=True, exist_ok=True)
        (out / "mission.yaml").write_text(dump_yaml(self.settings))
        (out / "world.yaml").write_text(dump_yaml(self.world))
        (out / "robot.yaml").write_text(dump_yaml(self.robot_spec))
        with TumWriter(out / "trajectory_gt.txt") as w:
            for t, T in self._gt:
                w.write(t, T)
        with TumWriter(out / "trajectory_est.txt") as w:
            for t, T in (self.pose.estimates if not self.pose.is_ground_truth else
                         [(t, se2.from_se3(T)) for t, T in self._gt]):
                w.write(t, se2.to_se3(T))
        (out / "report.json").write_text(self.report.to_json() + "\n")
        _write_nav_log(out / "navigation.csv", self._nav_log)
        plot_mission(self.sim.world, self.sim.roadmap, np.array([T[:2, 3] for _, T in self._gt]), self.report,
                     out / "mission.png")


NAV_LOG_COLUMNS = ("time_s", "x_m", "y_m", "yaw_rad", "v_m_s", "w_rad_s", "state", "target_index", "ptg", "path",
                   "free_distance", "speed")
"""Columns of ``navigation.csv``: one row per control step; the true pose of the base in the world, the command and
what the navigator decided (:class:`~simnav.navigation.navigator.NavCommand`)."""


def wall_segments(world: WorldSpec) -> np.ndarray:
    """(S, 2, 2) the centre lines of the world's walls, segment by segment, m."""
    segs = [np.stack([a, b]) for wall in world.walls for a, b in zip(wall.points[:-1], wall.points[1:], strict=True)]
    return np.array(segs, dtype=np.float64).reshape(-1, 2, 2)


def in_sight(xy: np.ndarray, points_xy: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(P,) whether the straight line from ``xy`` (2,) to each of the (P, 2) points crosses none of the (S, 2, 2)
    segments (m; touching counts as crossing)."""
    p = np.asarray(xy, dtype=np.float64)[None, None, :]
    q = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)[:, None, :]
    a, b = segments[None, :, 0, :], segments[None, :, 1, :]

    def cross(o, u, v):
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    d1, d2 = cross(a, b, p), cross(a, b, q)
    d3, d4 = cross(p, q, a), cross(p, q, b)
    return ~np.any((d1 * d2 <= 0.0) & (d3 * d4 <= 0.0), axis=1)


def _write_nav_log(path: Path, rows: list[tuple]) -> None:
    import csv

    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(NAV_LOG_COLUMNS)
        for row in rows:
            writer.writerow([f"{x:.6g}" if isinstance(x, float) else x for x in row])


def route_waypoints(nodes_xy: np.ndarray, route: Sequence[int], narrow: np.ndarray, free_m: float,
                    turnable: np.ndarray | None = None, keep_right_m: np.ndarray | None = None,
                    axis_approach: Mapping[tuple[int, int], np.ndarray] | None = None,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The navigator's waypoints for a roadmap route: narrow nodes (doorways) must be passed through, within
    ``NARROW_NODE_TOLERANCE_M``, lined up by an approach waypoint ``DOOR_APPROACH_M`` before them (towards the
    previous node; to be passed within ``DOOR_APPROACH_TOLERANCE_M``, facing the narrow node) and left through one as
    far after them (towards the next node, skippable); other nodes may be cut once a later waypoint is reachable and
    count as passed within ``free_m`` (the ones before and after a narrow node within ``NARROW_NODE_TOLERANCE_M``:
    passed from 1 m away, the node inside a room, the robot still in the doorway, it turned towards the room's next
    node beside the open door leaf and found no path past its tip). The first
    narrow node after one where the robot cannot turn in place (a doorway), where it can (``turnable``: the
    hallway outside the doorway) and the route turns by more than ``TURNING_NODE_RAD``, is passed within
    ``DOOR_APPROACH_TOLERANCE_M`` (the navigator then turns in place towards the next waypoint): a robot that
    counted it as passed from the doorway started turning the wrong way and met the hallway's far wall. A node
    between two wide ones where the route goes on straight (turns by less than ``STRAIGHT_NODE_RAD``) is moved
    ``keep_right_m`` to the right of the route: the robot keeps to the right of a corridor, as people do, and
    leaves them the rest of it to pass (on the centre line, where the roadmap runs, it left 0.1 m each side of
    its personal space in the office's 2.2 m corridor, and people going the other way jammed in front of it).

    Args:
        nodes_xy: (N, 2) roadmap nodes, m.
        route: node indices in order.
        narrow: (N,) which nodes are narrow.
        free_m: allowed distance of the other nodes, m.
        turnable: (N,) where the robot can turn in place (default nowhere).
        keep_right_m: (N,) how far each node may be moved to the right of the route, m (default: not moved).
        axis_approach: approach waypoints on a doorway's axis, m, keyed by (narrow node, next narrow node): a doorway
            of two narrow nodes in a row is approached from this point, ``DOOR_APPROACH_M`` before the first on
            the line through both, when it lies no further than half way to the previous node (see
            :func:`doorway_axis_approaches`); by default, and for other doorways, towards the previous node.

    Returns:
        (W, 2) waypoints (m), (W,) may be skipped, (W,) allowed distance (m), (W,) heading to pass them at (rad,
        NaN: any), (W,) doorways (the narrow nodes themselves: the navigator yields before them while someone
        stands there).
    """
    xy, skip, near, heading, doorway = [], [], [], [], []

    def add(p: np.ndarray, may_skip: bool, allowed_m: float, heading_rad: float = math.nan,
            is_doorway: bool = False) -> None:
        xy.append(p)
        skip.append(may_skip)
        near.append(allowed_m)
        heading.append(heading_rad)
        doorway.append(is_doorway)

    for i, node in enumerate(route):
        p = nodes_xy[node]
        lineup = _lineup_heading_rad(nodes_xy, route, i, narrow, turnable)
        if not narrow[node]:
            if lineup is not None:
                add(p, False, DOOR_APPROACH_TOLERANCE_M, lineup)
            else:
                after_doorway = i > 0 and narrow[route[i - 1]]  # the node inside a room (or outside it): close by
                add(_right_of_route(nodes_xy, route, i, narrow, keep_right_m), True,
                    NARROW_NODE_TOLERANCE_M if after_doorway else free_m)
            continue
        if i > 0:
            # the node before counts as passed only close by: passed from 1 m away, cutting towards the approach
            # waypoint, a robot can come to the wrong side of an open door leaf, with no path left around it
            near[-1] = min(near[-1], NARROW_NODE_TOLERANCE_M)
            q = _approach(nodes_xy, route, i, axis_approach)
            facing = math.atan2(p[1] - q[1], p[0] - q[0]) if np.linalg.norm(p - q) > 0 else math.nan
            add(q, False, DOOR_APPROACH_TOLERANCE_M, facing)
        sharp = (turnable is not None and i > 0 and turnable[node] and not turnable[route[i - 1]]
                 and abs(_route_turn_rad(nodes_xy, route, i)) > TURNING_NODE_RAD)
        if lineup is not None:
            add(p, False, DOOR_APPROACH_TOLERANCE_M, lineup, is_doorway=True)
            continue
        add(p, False, DOOR_APPROACH_TOLERANCE_M if sharp else NARROW_NODE_TOLERANCE_M, is_doorway=True)
        if i < len(route) - 1:
            add(_towards(p, nodes_xy[route[i + 1]]), True, NARROW_NODE_TOLERANCE_M)
    return (np.array(xy, dtype=np.float64).reshape(-1, 2), np.array(skip, dtype=bool), np.array(near),
            np.array(heading, dtype=np.float64), np.array(doorway, dtype=bool))


def resume_route(route: Sequence[int], closest: int, narrow: np.ndarray,
                 taken: np.ndarray | None = None) -> list[int]:
    """The rest of ``route`` after its node at position ``closest``, from the first later node that is neither
    narrow nor taken (or the goal): where an intervention sets the robot down.

    Args:
        route: node indices in order.
        closest: position in ``route`` of the node the robot is closest to.
        narrow: (N,) which nodes are narrow (doorways).
        taken: (N,) which nodes someone stands on (default none).
    """
    unfit = narrow if taken is None else narrow | taken
    start = min(closest + 1, len(route) - 1)
    while start < len(route) - 1 and unfit[route[start]]:
        start += 1
    return list(route[start:])


def _right_of_route(nodes_xy: np.ndarray, route: Sequence[int], i: int, narrow: np.ndarray,
                    keep_right_m: np.ndarray | None) -> np.ndarray:
    """The route's i-th node, moved ``keep_right_m`` to the right of the route where it goes on straight between
    two wide nodes (see :func:`route_waypoints`), m."""
    p = nodes_xy[route[i]]
    if keep_right_m is None or i == 0 or i == len(route) - 1 or keep_right_m[route[i]] <= 0.0:
        return p
    if narrow[route[i - 1]] or narrow[route[i + 1]] or abs(_route_turn_rad(nodes_xy, route, i)) >= STRAIGHT_NODE_RAD:
        return p
    along = nodes_xy[route[i + 1]] - nodes_xy[route[i - 1]]
    along = along / np.linalg.norm(along)
    return p + keep_right_m[route[i]] * np.array([along[1], -along[0]])


def _lineup_heading_rad(nodes_xy: np.ndarray, route: Sequence[int], i: int, narrow: np.ndarray,
                        turnable: np.ndarray | None) -> float | None:
    """The heading (rad) at which the route's i-th node is passed when the robot lines up there with the doorway
    that comes next, else None: the node is one where the robot can turn in place, the next is a narrow
    node where it cannot, closer than ``2 DOOR_APPROACH_M`` (the approach waypoint half way between them then lies
    where the robot cannot turn either: in the flat's 1 m hallway, 0.225 m from the wall beside the doorway) and
    the route turns there by more than ``TURNING_NODE_RAD`` (or starts there)."""
    if turnable is None or i >= len(route) - 1 or not turnable[route[i]]:
        return None
    nxt = route[i + 1]
    step = nodes_xy[nxt] - nodes_xy[route[i]]
    if not narrow[nxt] or turnable[nxt] or float(np.linalg.norm(step)) >= 2.0 * DOOR_APPROACH_M:
        return None
    if i > 0 and abs(_route_turn_rad(nodes_xy, route, i)) <= TURNING_NODE_RAD:
        return None
    return math.atan2(step[1], step[0])


def _route_turn_rad(nodes_xy: np.ndarray, route: Sequence[int], i: int) -> float:
    """The turn of the route at its i-th node (0 at either end or where two nodes coincide), rad."""
    if i == 0 or i == len(route) - 1:
        return 0.0
    a = nodes_xy[route[i]] - nodes_xy[route[i - 1]]
    b = nodes_xy[route[i + 1]] - nodes_xy[route[i]]
    if np.linalg.norm(a) == 0 or np.linalg.norm(b) == 0:
        return 0.0
    return float(se2.wrap_angle(math.atan2(b[1], b[0]) - math.atan2(a[1], a[0])))


def _approach(nodes_xy: np.ndarray, route: Sequence[int], i: int,
              axis_approach: Mapping[tuple[int, int], np.ndarray] | None) -> np.ndarray:
    """The approach waypoint before the route's i-th node, narrow (i > 0; see :func:`route_waypoints`), m."""
    p, before = nodes_xy[route[i]], nodes_xy[route[i - 1]]
    on_axis = None if axis_approach is None or i + 1 >= len(route) else axis_approach.get((route[i], route[i + 1]))
    if on_axis is not None and np.linalg.norm(on_axis - p) <= 0.5 * np.linalg.norm(before - p):
        return np.asarray(on_axis, dtype=np.float64)
    return _towards(p, before)


def doorway_axis_approaches(nodes_xy: np.ndarray, edges: Sequence[tuple[int, int]], narrow: np.ndarray,
                            room_m: Callable[[np.ndarray], np.ndarray]) -> dict[tuple[int, int], np.ndarray]:
    """For each roadmap edge (a, b) between two narrow nodes (a doorway of two nodes), in either direction, the
    point ``DOOR_APPROACH_M`` before a on the line from b through a, m, where ``room_m`` ((K, 2) points → (K,)
    m, e.g. the distance to walls and door swings less the robot's circumradius) is not negative there. Coming at
    such a doorway at an angle, towards the previous node, put the approach beside an open leaf's tip in the
    office's north-east room (0.22 m from it), where the robot, lined up, found no path past the tip."""
    pairs = [(a, b) for u, v in edges for a, b in ((u, v), (v, u)) if narrow[a] and narrow[b]]
    if not pairs:
        return {}
    points = []
    for a, b in pairs:
        axis = nodes_xy[a] - nodes_xy[b]
        points.append(nodes_xy[a] + DOOR_APPROACH_M * axis / max(float(np.linalg.norm(axis)), 1e-9))
    fits = room_m(np.array(points)) >= 0.0
    return {pair: point for pair, point, fit in zip(pairs, points, fits) if fit}


def _towards(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The point ``DOOR_APPROACH_M`` from p towards q (at most half way), m."""
    d = float(np.linalg.norm(q - p))
    return p + (q - p) * (min(DOOR_APPROACH_M, 0.5 * d) / d) if d > 0 else p.copy()


def _incident_kind(kind: str, other: str) -> str:
    if kind == "static":
        return "static"
    if kind == "door":
        return "door"
    return "robots" if other.startswith("wander") else "people"


def _target_at(rows: list[TargetRow], stamp_s: float) -> TargetRow | None:
    """The target under way at ``stamp_s`` (rows are in time order)."""
    started = [row for row in rows if row.start_s <= stamp_s]
    return started[-1] if started else None
