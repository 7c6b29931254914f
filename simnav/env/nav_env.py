"""The navigation task as a Gymnasium environment: reach a goal among people with a lidar (and a depth camera).

Every episode puts the robot on a roadmap node of the world (facing one of 8 headings) and draws a goal node
``goal_min_m``..``goal_max_m`` away along the roadmap; people, other robots and doors move as in ``simnav mission``.
One step applies a normalised (v, w) command for ``control_dt_s`` of MuJoCo physics and returns what the sensors
saw at its end.

**Observation** (``spaces.Dict``, every entry float32, fresh arrays each call):

====================  ================  ===================================================================
key                   shape             meaning
====================  ================  ===================================================================
``lidar``             (B,)              ranges / max range of the robot's 2D lidar, in [0, 1]; no return: 1
``depth`` (optional)  (120, 160)        QQVGA z-depth / max range of the RGB-D camera, in [0, 1]; invalid: 0
``goal``              (2,)              distance (m) and bearing (rad, counter-clockwise from the base's x
                                        axis) of the goal in the base frame, from the pose source
``velocity``          (2,)              measured forward speed (m/s) and yaw rate (rad/s) of the base
====================  ================  ===================================================================

**Action**: ``Box(-1, 1, (2,), float32)``: (v, w) as fractions of the robot's top speed and yaw rate.

**Reward** (each term is also in ``info`` as ``reward_<term>``)::

    reward = progress_per_m * (d_prev - d)          # progress: metres gained towards the goal (ground truth)
           - time_per_s * control_dt_s              # time
           - contact * new_contacts                 # contacts begun this step (walls, furniture, doors, people)
           + success * reached                      # bonus on reaching the goal (d <= success_distance_m)

**Episode end**: ``terminated`` on reaching the goal, or at the first contact when ``terminate_on_collision``;
``truncated`` only through the ``TimeLimit`` that ``gymnasium.make`` adds (``max_episode_steps``).

**Info**: the reward terms, ``distance_to_goal_m``, ``is_success``, ``collision`` (a contact began this step),
``contacts`` (contacts so far), ``sim_time_s``.
"""

from __future__ import annotations

import functools
import logging
import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numba import njit

from simnav.agents import RoadmapGraph
from simnav.config import validate
from simnav.env.config import NavEnvConfig
from simnav.errors import SimnavError
from simnav.geometry import se2
from simnav.robot.spec import Lidar2DSensor, RGBDSensor, RobotSpec, WheelEncoderSensor
from simnav.sensors.presets import RGBD_PRESETS, resolve_lidar2d, resolve_rgbd
from simnav.sensors.readings import LaserScan, RGBDFrame
from simnav.world.schema import Spawn, WorldSpec

log = logging.getLogger(__name__)

HEADINGS = 8
"""Start headings per roadmap node (every 45 degrees)."""

START_CLEARANCE_M = 0.1
"""Start and goal nodes keep at least the robot's circumradius plus this from static obstacles and from the disc
that every door leaf sweeps, m."""

DEPTH_PRESET = "kinect_qqvga"


class NavEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """Reach a goal among people (see the module docstring for spaces, reward and episode end).

    Args:
        render_mode: None or ``"rgb_array"`` (a top view that follows the robot, the goal as a green disc; with
            depth, the robot camera's view inset at the top-left).
        config: the task (default :class:`NavEnvConfig`).
        **overrides: fields of :class:`NavEnvConfig` (``world="flat"``, ``people=4``, ...).

    Attributes:
        config: the validated settings.
        robot_spec: the robot as the env runs it: its 2D lidar first, then the QQVGA depth camera (with depth),
            then its wheel encoders (pose source ``wheels``), all firing once per control step.
        lidar: the lidar's resolved parameters (beams, field of view, ranges; ``angles_rad()`` for the beams).
        camera: the depth camera's resolved parameters, or None.
        world_spec: the world, with one spawn per (roadmap node, heading).
        roadmap: its roadmap graph (world frame, m).

    Raises:
        SimnavError: an invalid setting, a robot without the sensors asked for, or a world without goals in range.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, config: NavEnvConfig | None = None, **overrides: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise SimnavError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if config is None or overrides:
            base = dict(config) if config is not None else {}
            config = validate(NavEnvConfig, {**base, **overrides}, "NavEnv")
        self.config = cfg = config
        self.render_mode = render_mode
        self.metadata = {**NavEnv.metadata, "render_fps": max(1, round(1.0 / cfg.control_dt_s))}
        self.robot_spec = _task_robot(cfg)
        self.lidar = resolve_lidar2d(self.robot_spec.sensors[0])
        self.camera = resolve_rgbd(self.robot_spec.sensors[1]) if cfg.depth else None
        self._lidar_name = self.robot_spec.sensors[0].name
        self._camera_name = self.robot_spec.sensors[1].name if cfg.depth else None
        self.world_spec, self.roadmap, self._starts, self._goals_from = _task_world(cfg, self.robot_spec)
        _check_pose_source(cfg.pose_source, self.robot_spec)
        drive = self.robot_spec.drive
        self.max_v_m_s, self.max_w_rad_s = drive.max_v_m_s, drive.max_w_rad_s
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observation_space = self._observation_space()
        self._sim = None
        self._scale_of = (math.nan, np.float32(math.nan))  # (a max range, np.float32(1 / it)) for the lidar
        self.last_readings: list = []
        """The sensor readings of the latest step (a viewer draws them)."""
        self._view = None

    # --------------------------------------------------------------------------------------------- spaces
    def _observation_space(self) -> spaces.Dict:
        from simnav.world.footprint import bounds

        x0, y0, x1, y1 = bounds(self.world_spec)
        self._max_goal_m = max_goal_m = float(math.ceil(math.hypot(x1 - x0, y1 - y0)))
        entries = {"lidar": spaces.Box(0.0, 1.0, shape=(self.lidar.beams,), dtype=np.float32)}
        if self.camera is not None:
            entries["depth"] = spaces.Box(0.0, 1.0, shape=(self.camera.height, self.camera.width), dtype=np.float32)
        entries["goal"] = spaces.Box(np.array([0.0, -math.pi], dtype=np.float32),
                                     np.array([max_goal_m, math.pi], dtype=np.float32), dtype=np.float32)
        limits = np.array([self.max_v_m_s, self.max_w_rad_s], dtype=np.float32)
        entries["velocity"] = spaces.Box(-limits, limits, dtype=np.float32)
        return spaces.Dict(entries)

    # ---------------------------------------------------------------------------------------------- reset
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode: a new start, goal, crowd and sensor noise, all drawn from ``self.np_random``.

        Args:
            seed: reseeds ``np_random`` (Gymnasium rules: None continues the current stream).
            options: ``{"goal_xy": (x, y)}`` sets the goal (world frame, m) instead of drawing it.

        Returns:
            The first observation and an info dict: ``distance_to_goal_m``, ``goal_xy`` (2,) and ``start_xy_yaw``
            (3,) in the world frame (m, rad; ground truth, for analysis).
        """
        super().reset(seed=seed)
        options = dict(options or {})
        goal_xy = options.pop("goal_xy", None)
        if options:
            raise SimnavError(f"unknown reset options {sorted(options)}; expected: goal_xy")
        # The draw: simulator seed, start (node and heading), goal node within the route-length range
        sim_seed = int(self.np_random.integers(2**31 - 1))
        k = int(self.np_random.integers(len(self._starts)))
        goals = self._goals_from[self._starts[k] // HEADINGS]
        goal = goals[int(self.np_random.integers(len(goals)))]
        self._goal_xy = (np.asarray(goal_xy, dtype=np.float64).reshape(2) if goal_xy is not None
                         else self.roadmap.nodes_xy[goal].copy())
        self._goal_x, self._goal_y = self._goal_xy.tolist()
        # The world as it is at t = 0, with the robot at the start
        sim = self._simulator(sim_seed)
        sim.reset(seed=sim_seed, spawn=self._starts[k])
        readings = sim.flush()  # the readings taken at t = 0
        self.last_readings = readings
        self._pose = _make_pose_source(self.config.pose_source, self.robot_spec)
        if self._pose is not None:
            self._pose.anchor(0.0, se2.from_se3(sim.T_world_base))
            for reading in readings:
                self._pose.feed(reading)
        pose = sim.pose_xy_yaw
        self._distance_m = self._distance_from(pose)
        self._contacts_seen = 0
        info = {"distance_to_goal_m": self._distance_m, "goal_xy": self._goal_xy.copy(),
                "start_xy_yaw": np.array(pose)}
        return self._observe(pose), info

    def _simulator(self, seed: int):
        """The simulator, built on the first reset (so that making the env, e.g. in a vector env's parent
        process, creates no MuJoCo model and no GL context)."""
        if self._sim is None:
            from simnav.sim import SimConfig, Simulator

            cfg = self.config
            sim_cfg = SimConfig(physics_dt_s=cfg.physics_dt_s, control_dt_s=cfg.control_dt_s,
                                agent_dt_s=cfg.agent_dt_s, pedestrians=cfg.people, wanderers=cfg.robots)
            self._sim = Simulator(self.world_spec, self.robot_spec, sim_cfg, seed=seed)
        return self._sim

    # ----------------------------------------------------------------------------------------------- step
    @property
    def simulator(self):
        """The :class:`~simnav.sim.simulator.Simulator` behind the env (None before the first :meth:`reset`)."""
        return self._sim

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Apply ``action`` (2,) in [-1, 1] (clipped) for one control period.

        Raises:
            SimnavError: called before :meth:`reset`, or an action that is not 2 finite numbers.
        """
        sim = self._sim
        if sim is None:
            raise SimnavError("call reset() before step()")
        if type(action) is np.ndarray and action.shape == (2,) and action.dtype.char in "fd":
            v, w = action.tolist()  # the float64 values np.asarray(action, np.float64) holds, as Python floats
        else:
            a = np.asarray(action, dtype=np.float64).reshape(-1)
            v, w = a.tolist() if a.shape == (2,) else (math.nan, math.nan)
        if not (math.isfinite(v) and math.isfinite(w)):
            raise SimnavError(f"action must be 2 finite numbers in [-1, 1] (v, w), got {action!r}")
        # Command and simulate one control period
        v, w = min(max(v, -1.0), 1.0), min(max(w, -1.0), 1.0)
        readings = sim.step(v * self.max_v_m_s, w * self.max_w_rad_s)
        self.last_readings = readings
        if self._pose is not None:
            for reading in readings:
                self._pose.feed(reading)
        # Outcome: progress, contacts begun this step, goal reached
        pose = sim.pose_xy_yaw
        distance = math.hypot(self._goal_x - pose[0], self._goal_y - pose[1])
        contacts = len(sim.contact_events)
        new_contacts = contacts - self._contacts_seen
        self._contacts_seen = contacts
        progress_w, time_term, contact_w, success_w, success_m, terminate_on_collision = self._reward_weights
        reached = distance <= success_m
        # the terms of _reward_terms, and their sum as sum() adds them (from 0, in this order)
        progress, contact, success = progress_w * (self._distance_m - distance), contact_w * new_contacts, \
            success_w if reached else 0.0
        self._distance_m = distance
        terminated = reached or (new_contacts > 0 and terminate_on_collision)
        info = {"reward_progress": progress, "reward_time": time_term, "reward_contact": contact,
                "reward_success": success, "distance_to_goal_m": distance, "is_success": reached,
                "collision": new_contacts > 0, "contacts": contacts, "sim_time_s": sim.time_s}
        return self._observe(pose), 0.0 + progress + time_term + contact + success, terminated, False, info

    def _reward_terms(self, progress_m: float, new_contacts: int, reached: bool) -> dict[str, float]:
        r = self.config.reward
        return {"reward_progress": r.progress_per_m * progress_m,
                "reward_time": -r.time_per_s * self.config.control_dt_s,
                "reward_contact": -r.contact * new_contacts,
                "reward_success": r.success if reached else 0.0}

    @functools.cached_property
    def _reward_weights(self) -> tuple[float, float, float, float, float, bool]:
        """The factors :meth:`_reward_terms` applies (progress, the time term itself, contact, success) and the
        success distance and termination rule, read once from the (frozen) config."""
        cfg = self.config
        r = cfg.reward
        return (r.progress_per_m, -r.time_per_s * cfg.control_dt_s, -r.contact, r.success, cfg.success_distance_m,
                cfg.terminate_on_collision)

    def _distance_from(self, pose_xy_yaw: tuple[float, float, float]) -> float:
        """Distance (m) from the ground-truth ``pose_xy_yaw`` of the base to the goal."""
        x, y, _ = pose_xy_yaw
        return math.hypot(self._goal_x - x, self._goal_y - y)

    # -------------------------------------------------------------------------------------------- observe
    def _observe(self, pose_xy_yaw: tuple[float, float, float]) -> dict[str, np.ndarray]:
        """The observation now; ``pose_xy_yaw`` is the simulator's ground-truth pose now."""
        sim = self._sim
        obs = {"lidar": self._lidar_obs(sim.latest(self._lidar_name))}
        if self.camera is not None:
            obs["depth"] = self._depth_obs(sim.latest(self._camera_name))
        obs["goal"] = self._goal_obs(pose_xy_yaw)
        v, w = sim.base_velocity()
        max_v, max_w = self.max_v_m_s, self.max_w_rad_s
        obs["velocity"] = np.array([min(max(v, -max_v), max_v), min(max(w, -max_w), max_w)], dtype=np.float32)
        return obs

    def _lidar_obs(self, scan: LaserScan | None) -> np.ndarray:
        if scan is None:  # nothing delivered yet (a latency longer than the control period)
            return np.ones(self.lidar.beams, dtype=np.float32)
        ranges = scan.ranges_m
        if type(ranges) is not np.ndarray or ranges.dtype != np.float32:
            ranges = np.asarray(ranges, dtype=np.float32)
        if scan.max_range_m != self._scale_of[0]:
            self._scale_of = (scan.max_range_m, np.float32(1.0 / scan.max_range_m))
        return _scaled_ranges(ranges, self._scale_of[1])

    def _depth_obs(self, frame: RGBDFrame | None) -> np.ndarray:
        if frame is None:
            return np.zeros((self.camera.height, self.camera.width), dtype=np.float32)
        out = np.asarray(frame.depth_m, dtype=np.float32) * np.float32(1.0 / self.camera.max_range_m)
        return np.clip(out, 0.0, 1.0, out=out)

    def _goal_obs(self, pose_xy_yaw: tuple[float, float, float]) -> np.ndarray:
        """Distance (m) and bearing (rad) of the goal in the base frame, from the pose source (ground truth:
        ``pose_xy_yaw``)."""
        if self._pose is None:
            x, y, yaw = pose_xy_yaw
        else:
            T = self._pose.T_world_base()
            x, y, yaw = float(T[0, 2]), float(T[1, 2]), math.atan2(T[1, 0], T[0, 0])
        dx, dy = self._goal_x - x, self._goal_y - y
        c, s = math.cos(yaw), math.sin(yaw)
        distance = min(math.hypot(dx, dy), self._max_goal_m)
        return np.array([distance, math.atan2(-s * dx + c * dy, c * dx + s * dy)], dtype=np.float32)

    # ------------------------------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """(H, W, 3) uint8 top view (``render_size_px``) in ``"rgb_array"`` mode; None without a render mode."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; make the env with render_mode='rgb_array'")
            return None
        if self._sim is None:
            raise SimnavError("call reset() before render()")
        if self._view is None:
            from simnav.env.render import TopView

            camera = self.robot_spec.sensors[1].name if self.camera is not None else None
            size = (self.camera.height, self.camera.width) if self.camera is not None else (0, 0)
            self._view = TopView(self._sim.model, self.config.render_size_px, self.config.render_span_m,
                                 camera, size)
        x, y, _ = self._sim.pose_xy_yaw
        return self._view.render(self._sim.data, np.array([x, y]), self._goal_xy)

    def close(self) -> None:
        """Release the simulator and the renderers (safe to call twice)."""
        if self._view is not None:
            self._view.close()
            self._view = None
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    # ------------------------------------------------------------------------------------------- pickling
    def __getstate__(self) -> dict[str, Any]:
        """Only the settings travel (vector envs, Ray): the copy builds its own simulator on reset."""
        return {"config": self.config, "render_mode": self.render_mode}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(render_mode=state["render_mode"], config=state["config"])


# ---------------------------------------------------------------------------------------------- set-up helpers
def _task_robot(cfg: NavEnvConfig) -> RobotSpec:
    """The robot as the env runs it: its first 2D lidar (then its RGB-D camera as a QQVGA depth camera, then its
    wheel encoders when the pose source needs them), every sensor firing once per control step."""
    from simnav.robot import load_robot

    robot = load_robot(cfg.robot) if isinstance(cfg.robot, str) else cfg.robot
    rate_hz = 1.0 / cfg.control_dt_s
    lidar = next((s for s in robot.sensors if isinstance(s, Lidar2DSensor)), None)
    if lidar is None:
        raise SimnavError(f"robot '{robot.name}' has no 2D lidar (type: lidar2d); the env observes one")
    update: dict[str, Any] = {"rate_hz": rate_hz}
    if cfg.lidar_beams is not None:
        update["beams"] = cfg.lidar_beams
    sensors: list = [lidar.model_copy(update=update)]
    if cfg.depth:
        camera = next((s for s in robot.sensors if isinstance(s, RGBDSensor)), None)
        if camera is None:
            raise SimnavError(f"sensors='lidar+depth': robot '{robot.name}' has no RGB-D camera (type: rgbd)")
        qqvga = RGBD_PRESETS[DEPTH_PRESET]
        sensors.append(camera.model_copy(update={"preset": DEPTH_PRESET, "width": qqvga.width,
                                                 "height": qqvga.height, "rgb": cfg.pose_source == "vosf",
                                                 "rate_hz": rate_hz}))
    if cfg.pose_source == "wheels":
        wheels = next((s for s in robot.sensors if isinstance(s, WheelEncoderSensor)), None)
        if wheels is None:
            raise SimnavError(f"pose_source='wheels': robot '{robot.name}' has no wheel encoders (type: wheels)")
        sensors.append(wheels)
    return robot.model_copy(update={"sensors": sensors})


def _task_world(cfg: NavEnvConfig, robot: RobotSpec) -> tuple[WorldSpec, RoadmapGraph, list[int], list[list[int]]]:
    """The world with one spawn per (roadmap node, heading), its roadmap, the spawn indices to draw starts from,
    and per roadmap node the goal nodes ``goal_min_m``..``goal_max_m`` away along the roadmap."""
    from simnav.world import load_world

    world = load_world(cfg.world) if isinstance(cfg.world, str) else cfg.world
    if world.generator is not None:
        from simnav.world.generator import generate

        world = generate(world)
    if world.roadmap is None:
        raise SimnavError(f"world '{world.name}' has no roadmap to draw starts and goals from")
    graph = RoadmapGraph.from_spec(world.roadmap)
    nodes = graph.nodes_xy
    radius = max(math.hypot(x, y) for p in robot.prisms for x, y in p.polygon)
    height = max(p.z_max_m for p in robot.prisms)
    free = _free_nodes(world, nodes, radius + START_CLEARANCE_M, height)
    goals_from: list[list[int]] = [[] for _ in range(len(nodes))]
    for i in free:
        for j in free:
            path = graph.shortest_path(int(i), int(j)) if i != j else []
            if path and cfg.goal_min_m <= graph.path_length_m(path) <= cfg.goal_max_m:
                goals_from[i].append(int(j))
    starts = [int(i) for i in free if goals_from[i]]
    if not starts:
        raise SimnavError(f"world '{world.name}': no two roadmap nodes with {radius + START_CLEARANCE_M:.2f} m "
                          f"clearance lie {cfg.goal_min_m}..{cfg.goal_max_m} m apart along the roadmap; change "
                          f"goal_min_m/goal_max_m")
    spawns = [Spawn(x_m=float(nodes[i][0]), y_m=float(nodes[i][1]), yaw_deg=360.0 * h / HEADINGS)
              for i in range(len(nodes)) for h in range(HEADINGS)]
    spawn_indices = [i * HEADINGS + h for i in starts for h in range(HEADINGS)]
    return world.model_copy(update={"spawns": spawns}), graph, spawn_indices, goals_from


def _free_nodes(world: WorldSpec, nodes_xy: np.ndarray, clearance_m: float, height_m: float) -> np.ndarray:
    """Indices of the roadmap nodes ``clearance_m`` away from static obstacles and from every door's swing."""
    from simnav.world.footprint import clearance_m as static_clearance_m

    ok = static_clearance_m(world, nodes_xy, 0.0, height_m) >= clearance_m
    for door in world.doors:
        ok &= np.hypot(*(nodes_xy - np.asarray(door.hinge)).T) >= door.width_m + clearance_m
    return np.flatnonzero(ok)


def _check_pose_source(name: str, robot: RobotSpec) -> None:
    from simnav.mission.pose import PoseSource

    PoseSource(name, robot)  # one clear error for an unknown source or a missing sensor


def _make_pose_source(name: str, robot: RobotSpec):
    if name == "gt":
        return None
    from simnav.mission.pose import PoseSource

    return PoseSource(name, robot)


@njit(cache=True, error_model="numpy")
def _scaled_ranges(ranges_m: np.ndarray, scale: np.float32) -> np.ndarray:
    """(B,) float32 ``ranges_m · scale`` capped at 1, and 1 where a range is invalid (<= 0)."""
    out = np.empty(ranges_m.shape[0], dtype=np.float32)
    for i in range(ranges_m.shape[0]):
        scaled = ranges_m[i] * scale
        out[i] = 1.0 if ranges_m[i] <= 0 or scaled > 1.0 else scaled
    return out
