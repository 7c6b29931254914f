"""The simulator: one MuJoCo world with a robot, walking people, other robots and doors, and the robot's sensors.

Time is the simulation clock. Each :meth:`Simulator.step` advances one control period of whole physics steps;
inside it the commanded (v, w) reaches the base after the drive's latency and through its acceleration limits,
the agents move every ``agent_dt_s``, and every sensor fires on its own period. A reading is stamped with its
acquisition time and becomes available ``latency_s`` later.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections import deque
from concurrent.futures import Future

import mujoco
import numpy as np

from simnav.agents import Crowd, DoorLeaf, RoadmapGraph, Wanderers
from simnav.agents.doors import door_segments
from simnav.errors import SimnavError
from simnav.robot.spec import Lidar2DSensor, Lidar3DSensor, RGBDSensor, RobotSpec, WheelEncoderSensor
from simnav.sensors.lidar import Lidar2D, Lidar3D
from simnav.sensors.readings import ContactEvent, Reading
from simnav.sensors.rgbd import RGBDCamera
from simnav.sensors.wheels import WheelEncoders
from simnav.sim.config import SimConfig
from simnav.sim.scene import build_scene
from simnav.world.footprint import obstacle_segments
from simnav.world.mjcf import WANDERER_RADIUS_M
from simnav.world.schema import WorldSpec

log = logging.getLogger(__name__)
_EPS_S = 1e-9
MOTOR_PERIOD_S = 0.01  # the motor controller applies its acceleration ramp at 100 Hz


class Simulator:
    """A robot in a world with agents.

    Args:
        world: an explicit world (see :func:`simnav.world.load_world`).
        robot: the robot (see :func:`simnav.robot.load_robot`).
        config: clocks, agent counts, rendering backend.
        seed: seed of every random process (agents, sensor noise); the same seed gives identical runs.
    """

    def __init__(self, world: WorldSpec, robot: RobotSpec, config: SimConfig | None = None, seed: int = 0) -> None:
        if world.roadmap is None or not world.spawns:
            raise SimnavError(f"world '{world.name}' has no roadmap or spawns; load it with simnav.world.load_world")
        self.world, self.robot = world, robot
        self.config = config or SimConfig()
        self.pedestrian_count = world.agents.pedestrians if self.config.pedestrians is None else self.config.pedestrians
        self.wanderer_count = world.agents.robots if self.config.wanderers is None else self.config.wanderers
        self.model, self.index = build_scene(world, robot, self.pedestrian_count, self.wanderer_count,
                                             self.config.physics_dt_s)
        self.data = mujoco.MjData(self.model)
        self._qpos, self._ctrl = self.data.qpos, self.data.ctrl  # views kept for the stepping loop
        q0, v0 = int(self.index.qpos_adr[0]), int(self.index.dof_adr[0])
        self._qs, self._vs = slice(q0, q0 + 3), slice(v0, v0 + 3)  # the base's x, y, yaw (contiguous)
        self.roadmap = RoadmapGraph.from_spec(world.roadmap)
        self._walls_xy = obstacle_segments(world)
        self.robot_radius_m = _circumradius(robot)
        self._motor_substeps = max(1, round(MOTOR_PERIOD_S / self.config.physics_dt_s))
        self._dt_s, self._agent_substeps = self.config.physics_dt_s, self.config.agent_substeps
        motor_dt = self._motor_substeps * self._dt_s
        drive = robot.drive
        self._ramp_limits = (drive.max_acc_m_s2 * motor_dt, drive.max_ang_acc_rad_s2 * motor_dt)
        self.sensors = self._make_sensors()
        self._encoders = [s for s in self.sensors if isinstance(s, WheelEncoders)]
        self.reset(seed)

    # ------------------------------------------------------------------------------------------------ set-up
    def _make_sensors(self) -> list:
        sensors: list = []
        for spec in self.robot.sensors:
            if isinstance(spec, Lidar2DSensor):
                sensors.append(Lidar2D(spec, self.model, self.index.robot_body))
            elif isinstance(spec, Lidar3DSensor):
                sensors.append(Lidar3D(spec, self.model, self.index.robot_body))
            elif isinstance(spec, RGBDSensor):
                sensors.append(RGBDCamera(spec, self.model, self.index.robot_body, self.config.depth_backend))
            elif isinstance(spec, WheelEncoderSensor):
                sensors.append(WheelEncoders(spec, self.robot.drive))
        return sensors

    def reset(self, seed: int | None = None, spawn: int | None = None) -> None:
        """Put the robot at a spawn pose, respawn the agents and restart all clocks.

        Args:
            seed: new seed (None keeps the constructor's seed sequence going).
            spawn: index into the world's spawns (default: config.spawn, else 0).
        """
        if seed is not None:
            self._seed_seq = np.random.SeedSequence(seed)
        streams = self._seed_seq.spawn(2 + len(self.sensors))
        self._rng_crowd, self._rng_wanderers = (np.random.default_rng(s) for s in streams[:2])
        self._rng_sensors = [np.random.default_rng(s) for s in streams[2:]]
        mujoco.mj_resetData(self.model, self.data)
        self._place_robot(spawn)
        self._reset_agents()
        self._reset_drive()
        self._reset_sensors()
        self._active_contacts: set[int] = set()
        self.contact_events: list[ContactEvent] = []
        self._step_count = 0
        self._history: deque[tuple[float, float, float, float]] = deque(maxlen=4096)
        self._history.append((0.0, *self.pose_xy_yaw))
        self._pose_agents_at(0.0)
        mujoco.mj_forward(self.model, self.data)
        self._capture_due()  # every sensor's first reading is at t = 0

    def _place_robot(self, spawn: int | None) -> None:
        k = spawn if spawn is not None else (self.config.spawn or 0)
        if not 0 <= k < len(self.world.spawns):
            raise SimnavError(f"spawn index {k} out of range: world '{self.world.name}' has "
                              f"{len(self.world.spawns)} spawns")
        s = self.world.spawns[k]
        self.data.qpos[self._qs] = [s.x_m, s.y_m, s.yaw_rad]

    def _reset_agents(self) -> None:
        x, y, _ = self.data.qpos[self._qs].tolist()
        keep_out = np.array([[x, y, self.robot_radius_m + 0.5]])
        agents = self.world.agents
        try:
            self.crowd = Crowd(self.roadmap, self._walls_xy, self.pedestrian_count, self._rng_crowd,
                               speed_mean_m_s=agents.speed_mean_m_s, speed_std_m_s=agents.speed_std_m_s,
                               keep_out=keep_out)
        except ValueError as err:
            raise SimnavError(f"world '{self.world.name}': {err}; try fewer people (--agents)") from None
        keep_out = np.vstack([keep_out, np.column_stack([self.crowd.positions_xy,
                                                         np.full(self.crowd.count, 0.6)])])
        self.wanderers = Wanderers(self.roadmap, self.wanderer_count, self._rng_wanderers,
                                   speed_m_s=agents.robot_speed_m_s, radius_m=WANDERER_RADIUS_M, keep_out=keep_out)
        self.doors = [DoorLeaf(d) for d in self.world.doors]
        self._agent_time_s = 0.0
        self._posed_at: tuple[float, float] | None = None

    def _reset_drive(self) -> None:
        self._commands: deque[tuple[float, float, float]] = deque([(-math.inf, 0.0, 0.0)])  # (apply at s, v, w)
        self._v_m_s = 0.0
        self._w_rad_s = 0.0
        self.data.ctrl[:] = 0.0

    def _reset_sensors(self) -> None:
        self._next_capture_s = [0.0 for _ in self.sensors]
        self._schedule_changed()
        self._pending: list[tuple[float, int, Reading | Future]] = []
        self._pending_seq = 0
        self._latest: dict[str, Reading] = {}
        for s in self.sensors:
            if isinstance(s, WheelEncoders):
                s.reset()

    # ---------------------------------------------------------------------------------------------- stepping
    @property
    def time_s(self) -> float:
        """Simulation time, s (whole physics steps times the step, free of accumulated rounding)."""
        return round(self._step_count * self._dt_s, 9)

    def step(self, v_m_s: float, w_rad_s: float, *, measured: bool = False) -> list[Reading]:
        """Command (v, w) and advance one control period.

        Args:
            v_m_s: forward speed command, m/s (clamped to the drive's limit).
            w_rad_s: yaw rate command, rad/s, counter-clockwise (clamped).
            measured: (v, w) is what real motors measured (hardware in the loop): the base takes it at once,
                without the simulated motor's latency and acceleration ramp.

        Returns:
            The readings that became available during this period, oldest first.

        Raises:
            SimnavError: a NaN or infinite command.
        """
        if not (math.isfinite(v_m_s) and math.isfinite(w_rad_s)):
            raise SimnavError(f"velocity command must be finite, got v={v_m_s}, w={w_rad_s}")
        drive = self.robot.drive
        v = float(np.clip(v_m_s, -drive.max_v_m_s, drive.max_v_m_s))
        w = float(np.clip(w_rad_s, -drive.max_w_rad_s, drive.max_w_rad_s))
        if measured:
            self._commands.clear()
            self._commands.append((self.time_s, v, w))
            self._v_m_s, self._w_rad_s = v, w
        else:
            self._commands.append((self.time_s + drive.command_latency_s, v, w))
        delivered: list[Reading] = []
        end = self._step_count + self.config.substeps
        while self._step_count < end:
            delivered += self._advance(self._steps_to_next_event(end))
        return delivered

    def _steps_to_next_event(self, end: int) -> int:
        """Physics steps until something must happen in Python: agents, a sensor, the motor, the period end."""
        k, agent = self._step_count, self._agent_substeps
        # the earliest capture (a whole step, at least the next one), the agents' period and the period end
        nxt = min(end, (k // agent + 1) * agent, max(self._next_capture_step, k + 1))
        # a command arriving after its latency
        if len(self._commands) > 1:
            nxt = min(nxt, max(math.ceil(self._commands[1][0] / self._dt_s - 1e-6), k + 1))
        # the motor controller's next acceleration update while it ramps towards the command
        if self._ramping():
            nxt = min(nxt, (k // self._motor_substeps + 1) * self._motor_substeps)
        return nxt - k

    def _schedule_changed(self) -> None:
        """Cache the earliest capture time and its physics step (``_next_capture_s`` changed)."""
        self._next_due_s = min(self._next_capture_s, default=math.inf)
        steps = [math.ceil(t / self._dt_s - 1e-6) for t in self._next_capture_s]
        self._next_capture_step = min(steps, default=2**62)

    def _advance(self, n: int) -> list[Reading]:
        """Run ``n`` physics steps with constant controls, then do what is due at the new time."""
        k = self._step_count
        # agents move on their own period (their state is one period ahead; poses are interpolated)
        if k % self._agent_substeps == 0:
            self._step_agents()
        # motor model: latency, then acceleration limits at the motor controller's rate
        self._apply_drive(round(k * self._dt_s, 9))
        encoders = self._encoders
        if encoders:
            v0, w0 = self.base_velocity()
        mujoco.mj_step(self.model, self.data, nstep=n)
        self._step_count = k = k + n
        t = round(k * self._dt_s, 9)
        if encoders:
            v1, w1 = self.base_velocity()
            for s in encoders:
                s.integrate((v0 + v1) / 2, (w0 + w1) / 2, n * self._dt_s)
        x, y, yaw = self._qpos[self._qs].tolist()
        self._history.append((t, x, y, math.atan2(math.sin(yaw), math.cos(yaw))))
        if self.data.ncon:
            self._check_contacts()
        else:
            self._active_contacts.clear()
        # sensors due now, and readings whose latency has passed
        if self._next_due_s <= t + _EPS_S:
            self._capture_due()
        if self._pending and self._pending[0][0] <= t + _EPS_S:
            return self._deliver()
        return []

    def _ramping(self) -> bool:
        _, v_target, w_target = self._commands[0]
        return v_target != self._v_m_s or w_target != self._w_rad_s

    def _apply_drive(self, now: float) -> None:
        """Commands whose latency has passed at ``now`` (s) take effect; the motor ramps towards the latest one."""
        commands = self._commands
        while len(commands) > 1 and commands[1][0] <= now + _EPS_S:
            commands.popleft()
        _, v_target, w_target = commands[0]
        v, w = self._v_m_s, self._w_rad_s
        if self._step_count % self._motor_substeps == 0 or (v_target == v and w_target == w):
            dv_max, dw_max = self._ramp_limits
            # python floats: min/max is np.clip without its per-call overhead
            self._v_m_s = v = v + min(max(v_target - v, -dv_max), dv_max)
            self._w_rad_s = w = w + min(max(w_target - w, -dw_max), dw_max)
        ctrl = self._ctrl
        ctrl[0], ctrl[1], ctrl[2] = v, 0.0, w

    def _step_agents(self) -> None:
        dt = self.config.agent_dt_s
        robot_xy = self.data.qpos[self._qs][:2].copy()
        robot_vel = self.data.qvel[self._vs][:2].copy()
        wanderers = self.wanderers
        circles = np.vstack([[*robot_xy, self.robot_radius_m],
                             np.column_stack([wanderers.positions_xy, np.full(wanderers.count, WANDERER_RADIUS_M)])])
        # people (an empty crowd has nothing to step), then the other robots, then the doors
        if self.crowd.count:
            circle_vel = np.vstack([robot_vel, wanderers.velocities_xy])
            doors = door_segments(self.doors) if self.doors else None
            self.crowd.step(dt, dynamic_segments=doors, circles=circles, circle_velocities=circle_vel)
        people = self.crowd.positions_xy
        others = np.vstack([people, robot_xy[None]])
        if wanderers.count:
            wanderers.step(dt, others)
        if self.doors:
            nearby = np.vstack([others, wanderers.positions_xy])
            blockers = np.vstack([circles, np.column_stack([people, np.full(len(people), self.crowd.radius_m)])])
            for door in self.doors:
                door.update(self._agent_time_s + dt, dt, nearby, blockers)
        self._agent_time_s += dt
        self._pose_agents_at(self.time_s)

    def _pose_agents_at(self, t_s: float) -> None:
        """Write agent poses into the mocap bodies at time ``t_s`` (linear motion towards the agent state)."""
        if self._posed_at == (t_s, self._agent_time_s):
            return
        self._posed_at = (t_s, self._agent_time_s)
        back = max(self._agent_time_s - t_s, 0.0)
        d, idx = self.data, self.index
        for mocap, agents in ((idx.pedestrian_mocap, self.crowd), (idx.wanderer_mocap, self.wanderers)):
            if len(mocap):
                xy = agents.positions_xy - agents.velocities_xy * back
                d.mocap_pos[mocap, :2] = xy
                d.mocap_pos[mocap, 2] = 0.0
                d.mocap_quat[mocap] = _yaw_quats(agents.yaws_rad - agents.yaw_rates_rad_s * back)
        if len(idx.door_mocap):
            yaws = np.array([door.yaw_rad - door.yaw_rate_rad_s * back for door in self.doors])
            d.mocap_quat[idx.door_mocap] = _yaw_quats(yaws)

    # -------------------------------------------------------------------------------------------- sensors
    def _capture_due(self) -> None:
        t = self.time_s
        due = [k for k, next_s in enumerate(self._next_capture_s) if next_s <= t + _EPS_S]
        if not due:
            return
        if any(not isinstance(self.sensors[k], WheelEncoders) for k in due):
            self._pose_agents_at(t)
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_camlight(self.model, self.data)
        # cameras first: their frames render in the background while the other sensors capture here (each sensor
        # has its own noise stream and nothing here changes the state, so the order does not change a reading)
        twists = None
        readings: dict[int, Reading | Future] = {}
        for k in sorted(due, key=lambda k: not isinstance(self.sensors[k], RGBDCamera)):
            sensor, rng = self.sensors[k], self._rng_sensors[k]
            if isinstance(sensor, WheelEncoders):
                readings[k] = sensor.capture(t, rng)
            elif isinstance(sensor, RGBDCamera):
                twists = self.body_twists_world() if twists is None else twists
                readings[k] = sensor.submit(self.data, t, rng, twists)
            else:
                readings[k] = sensor.capture(self.data, t, rng)
        # queued in sensor order (ties in delivery time keep it)
        for k in due:
            sensor = self.sensors[k]
            self._next_capture_s[k] += sensor.period_s
            heapq.heappush(self._pending, (round(t + sensor.latency_s, 9), self._pending_seq, readings[k]))
            self._pending_seq += 1
        self._schedule_changed()

    def _deliver(self) -> list[Reading]:
        """Readings due by now, in order. Camera frames are made in the background (futures): in lockstep mode
        a due frame is waited for; otherwise delivery pauses at the first frame not finished yet."""
        out = []
        while self._pending and self._pending[0][0] <= self.time_s + _EPS_S:
            item = self._pending[0][2]
            if isinstance(item, Future) and not (self.config.lockstep or item.done()):
                break
            heapq.heappop(self._pending)
            out.append(self._receive(item))
        return out

    def flush(self) -> list[Reading]:
        """Wait for every reading captured so far (also those not due yet) and return them in order."""
        out = []
        while self._pending:
            out.append(self._receive(heapq.heappop(self._pending)[2]))
        return out

    def _receive(self, item: Reading | Future) -> Reading:
        reading = item.result() if isinstance(item, Future) else item
        self._latest[reading.sensor] = reading
        return reading

    def teleport(self, x_m: float, y_m: float, yaw_rad: float) -> None:
        """Put the robot at a pose (world frame) at rest, without advancing time (for sampling sensor views)."""
        self.data.qpos[self._qs] = [x_m, y_m, yaw_rad]
        self.data.qvel[self._vs] = 0.0
        self._v_m_s = self._w_rad_s = 0.0
        self._commands = deque([(-math.inf, 0.0, 0.0)])
        mujoco.mj_forward(self.model, self.data)
        self._history.append((self.time_s, *self.pose_xy_yaw))

    def capture_now(self, sensor: str) -> Reading:
        """Take a reading of ``sensor`` at the current time, outside its schedule (its noise stream advances)."""
        names = [s.name for s in self.sensors]
        if sensor not in names:
            raise SimnavError(f"robot '{self.robot.name}' has no sensor '{sensor}'; available: {names}")
        k = names.index(sensor)
        s, rng, t = self.sensors[k], self._rng_sensors[k], self.time_s
        self._pose_agents_at(t)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        if isinstance(s, WheelEncoders):
            return s.capture(t, rng)
        if isinstance(s, RGBDCamera):
            return s.capture(self.data, t, rng, self.body_twists_world())
        return s.capture(self.data, t, rng)

    def latest(self, sensor: str) -> Reading | None:
        """The most recent delivered reading of ``sensor`` (None before its first one)."""
        return self._latest.get(sensor)

    # ------------------------------------------------------------------------------------------- contacts
    def _check_contacts(self) -> None:
        d = self.data
        if d.ncon == 0:
            self._active_contacts.clear()
            return
        geoms = d.contact.geom[: d.ncon]
        bodies = self.model.geom_bodyid[geoms]
        robot = self.index.robot_body
        now: set[int] = set()
        for k in np.flatnonzero((bodies == robot).any(axis=1)):
            other = int(bodies[k, 1] if bodies[k, 0] == robot else bodies[k, 0])
            if other in now:
                continue
            now.add(other)
            if other not in self._active_contacts:
                self.contact_events.append(self._contact_event(other, k))
        self._active_contacts = now

    def _contact_event(self, other: int, k: int) -> ContactEvent:
        kind = self.index.body_kind[other]
        kind = {"static": "static", "door": "door"}.get(kind, "agent")
        name = "world" if other == 0 else self.model.body(other).name
        contact = self.data.contact[k]
        event = ContactEvent(stamp_s=self.time_s, kind=kind, other=name, position_world=contact.pos.copy(),
                             depth_m=max(0.0, -float(contact.dist)))
        log.info("contact with %s (%s) at t=%.2f s", name, kind, event.stamp_s)
        return event

    # --------------------------------------------------------------------------------------- ground truth
    @property
    def T_world_base(self) -> np.ndarray:
        """(4, 4) ground-truth pose of the robot base in the world."""
        x, y, yaw = self.data.qpos[self._qs].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = [x, y]
        return T

    @property
    def pose_xy_yaw(self) -> tuple[float, float, float]:
        """Ground-truth planar pose (x m, y m, yaw rad in (-pi, pi])."""
        x, y, yaw = self.data.qpos[self._qs].tolist()
        return float(x), float(y), float(math.atan2(math.sin(yaw), math.cos(yaw)))

    def T_world_base_at(self, stamp_s: float) -> np.ndarray:
        """(4, 4) ground-truth base pose at a past time ``stamp_s`` (within the last few seconds), s."""
        k = len(self._history) - 1
        while k > 0 and self._history[k][0] > stamp_s + _EPS_S:
            k -= 1
        _, x, y, yaw = self._history[k]
        c, s = math.cos(yaw), math.sin(yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = [x, y]
        return T

    def base_velocity(self) -> tuple[float, float]:
        """Ground-truth forward speed (m/s, along base x) and yaw rate (rad/s)."""
        vx, vy, w = self.data.qvel[self._vs].tolist()
        yaw = float(self.data.qpos[self._qs.start + 2])
        return float(vx * math.cos(yaw) + vy * math.sin(yaw)), float(w)

    def body_twists_world(self) -> np.ndarray:
        """(nbody, 6): world linear velocity of each body's origin and its angular velocity (m/s, rad/s).

        Mocap bodies (people, other robots, doors) get the velocities of the agent models, which MuJoCo does
        not know; static bodies are 0.
        """
        tw = np.zeros((self.model.nbody, 6))
        idx = self.index
        tw[idx.pedestrian_body, :2] = self.crowd.velocities_xy
        tw[idx.pedestrian_body, 5] = self.crowd.yaw_rates_rad_s
        tw[idx.wanderer_body, :2] = self.wanderers.velocities_xy
        tw[idx.wanderer_body, 5] = self.wanderers.yaw_rates_rad_s
        tw[idx.door_body, 5] = [door.yaw_rate_rad_s for door in self.doors]
        tw[idx.robot_body, :2] = self.data.qvel[self._vs][:2]
        tw[idx.robot_body, 5] = self.data.qvel[self._vs][2]
        return tw

    def close(self) -> None:
        """Release rendering contexts."""
        for s in self.sensors:
            if isinstance(s, RGBDCamera):
                s.close()

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _circumradius(robot: RobotSpec) -> float:
    return max(math.hypot(x, y) for p in robot.prisms for x, y in p.polygon)


def _yaw_quats(yaw: np.ndarray) -> np.ndarray:
    yaw = np.asarray(yaw, dtype=float)
    q = np.zeros((*yaw.shape, 4))
    q[..., 0], q[..., 3] = np.cos(yaw / 2), np.sin(yaw / 2)
    return q
