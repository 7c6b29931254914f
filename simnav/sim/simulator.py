"""The simulator: one MuJoCo world with a robot, walking people, other robots and doors, and the robot's sensors.

Time is the simulation clock. Each :meth:`Simulator.step` advances one control period of whole physics steps;
inside it the commanded (v, w) reaches the base after the drive's latency and through its acceleration limits,
the agents move every ``agent_dt_s``, and every sensor fires on its own period. A reading is stamped with its
acquisition time and becomes available ``latency_s`` later.
"""

from __future__ import annotations

import functools
import heapq
import logging
import math
from collections import deque
from concurrent.futures import Future

import mujoco
import numpy as np
from numba import njit

from simnav.agents import Crowd, RoadmapGraph, Wanderers
from simnav.agents.doors import DoorLeaves
from simnav.errors import SimnavError
from simnav.robot.spec import Lidar2DSensor, Lidar3DSensor, RGBDSensor, RobotSpec, WheelEncoderSensor
from simnav.sensors.lidar import Lidar2D, Lidar3D
from simnav.sensors.readings import ContactEvent, Reading
from simnav.sensors.rgbd import RGBDCamera
from simnav.sensors.wheels import WheelEncoders
from simnav.sim.clearance import ContactClearance
from simnav.sim.config import SimConfig
from simnav.sim.native import FUNCTIONS, NATIVE, STATE, quiet_timers, ramp_steps, restore_timers, robot_shadow
from simnav.sim.scene import build_scene, robot_alone
from simnav.world.footprint import obstacle_segments
from simnav.world.mjcf import WANDERER_RADIUS_M
from simnav.world.schema import WorldSpec

log = logging.getLogger(__name__)
_EPS_S = 1e-9
_NEVER = 2**62  # a physics step never reached
MOTOR_PERIOD_S = 0.01  # the motor controller applies its acceleration ramp at 100 Hz
_NO_SHADOW = (0, 0, np.zeros(3), np.zeros(3), np.zeros(1))  # ramp_steps' shadow arguments without one
HISTORY_SIZE = 4096  # poses kept for T_world_base_at (stretch ends: a few seconds)


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
        # views kept for the stepping loop
        self._qpos, self._qvel, self._ctrl = self.data.qpos, self.data.qvel, self.data.ctrl
        self._mocap_pos, self._mocap_quat = self.data.mocap_pos, self.data.mocap_quat
        q0, v0 = int(self.index.qpos_adr[0]), int(self.index.dof_adr[0])
        self._qs, self._vs = slice(q0, q0 + 3), slice(v0, v0 + 3)  # the base's x, y, yaw (contiguous)
        self._base_qpos, self._base_qvel = self.data.qpos[self._qs], self.data.qvel[self._vs]  # (3,) x, y, yaw views
        self.roadmap = RoadmapGraph.from_spec(world.roadmap)
        self._walls_xy = obstacle_segments(world)
        self.robot_radius_m = _circumradius(robot)
        self._motor_substeps = max(1, round(MOTOR_PERIOD_S / self.config.physics_dt_s))
        self._dt_s, self._agent_dt_s = self.config.physics_dt_s, self.config.agent_dt_s
        self._substeps, self._agent_substeps = self.config.substeps, self.config.agent_substeps
        motor_dt = self._motor_substeps * self._dt_s
        drive = robot.drive
        self._ramp_limits = (drive.max_acc_m_s2 * motor_dt, drive.max_ang_acc_rad_s2 * motor_dt)
        self._clearance = ContactClearance(self.model, self.index.robot_body, drive.max_v_m_s)
        # the motor ramp's stretches in compiled code, most of them in a robot-only shadow (see simnav.sim.native):
        # the scene's and the shadow's addresses and views, and room for the end step and base pose of each
        # stretch of a control period
        self._native_scene = (self.model._address, self.data._address, self._ctrl, self._base_qpos) if NATIVE \
            else None
        self._shadow = robot_shadow(lambda: robot_alone(robot, self.config.physics_dt_s), self.model,
                                    self.index.qpos_adr, self.index.dof_adr)
        self._native_shadow = _NO_SHADOW if self._shadow is None else (
            self._shadow[0]._address, self._shadow[1]._address, self._shadow[1].ctrl, self._shadow[1].qpos,
            np.empty(mujoco.mj_stateSize(self._shadow[0], STATE)))
        flags = self.model.opt.disableflags
        self._contact_flags = (flags, flags | mujoco.mjtDisableBit.mjDSBL_CONTACT)  # (detecting, skipping)
        self.sensors = self._make_sensors()
        self._encoders = [s for s in self.sensors if isinstance(s, WheelEncoders)]
        self._sees_scene = [not isinstance(s, WheelEncoders) for s in self.sensors]
        self._is_camera = [isinstance(s, RGBDCamera) for s in self.sensors]
        self._capture_rank = [0 if camera else 1 for camera in self._is_camera]  # cameras first
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
        # (physics step, x, y, yaw as in qpos: T_world_base_at wraps it) after every stretch of physics steps
        self._history = PoseHistory(HISTORY_SIZE)
        self._history.append((0, *self._base_qpos.tolist()))
        self._pose_agents_at(0.0)
        mujoco.mj_forward(self.model, self.data)
        self._capture_due(0.0)  # every sensor's first reading is at t = 0

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
                               keep_out=keep_out, single_file_wait_s=agents.single_file_wait_s)
        except ValueError as err:
            raise SimnavError(f"world '{self.world.name}': {err}; try fewer people (--agents)") from None
        keep_out = np.vstack([keep_out, np.column_stack([self.crowd.positions_xy,
                                                         np.full(self.crowd.count, 0.6)])])
        self.wanderers = Wanderers(self.roadmap, self.wanderer_count, self._rng_wanderers,
                                   speed_m_s=agents.robot_speed_m_s, radius_m=WANDERER_RADIUS_M, keep_out=keep_out)
        self.doors = DoorLeaves(self.world.doors)
        people, robots = self.crowd.count, 1 + self.wanderers.count
        blockers = np.empty((robots + people, 3))
        self._agent_rows = (people, robots, blockers, np.empty((people + robots, 2)), blockers[:robots],
                            np.empty((robots, 2)))
        self._agent_time_s = 0.0
        self._posed_at: tuple[float, float] | None = None
        # the mocap rows of the people, the other robots and the doors, and their states packed in rows
        # [x, y, vx, vy, yaw, yaw rate] (doors: yaw and yaw rate only) by _keep_agent_state
        idx = self.index
        self._mocap_rows = np.concatenate([idx.pedestrian_mocap, idx.wanderer_mocap, idx.door_mocap]).astype(np.int64)
        self._movers = np.zeros((len(self._mocap_rows), 6))
        self._moving = len(idx.pedestrian_mocap) + len(idx.wanderer_mocap)  # rows that move (the rest turn)
        self._keep_agent_state()

    def _reset_drive(self) -> None:
        self._commands = deque([self._command(-math.inf, 0.0, 0.0)])
        self._v_m_s = 0.0
        self._w_rad_s = 0.0
        self.data.ctrl[:] = 0.0

    def _reset_sensors(self) -> None:
        self._next_capture_s = [0.0 for _ in self.sensors]
        self._schedule_changed()
        self._pending: list[tuple[float, int, Reading | Future]] = []
        self._pending_seq = 0
        self._pending_changed()
        self._latest: dict[str, Reading] = {}
        for s in self.sensors:
            if isinstance(s, WheelEncoders):
                s.reset()

    # ---------------------------------------------------------------------------------------------- stepping
    @property
    def time_s(self) -> float:
        """Simulation time, s (whole physics steps times the step, free of accumulated rounding)."""
        return _step_time(self._step_count, self._dt_s)

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
        v = _clamp(v_m_s, drive.max_v_m_s)
        w = _clamp(w_rad_s, drive.max_w_rad_s)
        if measured:
            self._commands.clear()
            self._commands.append(self._command(self.time_s, v, w))
            self._v_m_s, self._w_rad_s = v, w
        else:
            self._commands.append(self._command(self.time_s + drive.command_latency_s, v, w))
        return self._run_until(self._step_count + self._substeps)

    def _command(self, apply_at_s: float, v: float, w: float) -> tuple[int, int, float, float]:
        """A queued command applying at ``apply_at_s`` (s): (the physics step the stepping pauses at for it, the
        first step whose time has reached it, v m/s, w rad/s)."""
        if apply_at_s == -math.inf:
            return 0, 0, v, w
        return *self._steps_at(apply_at_s), v, w

    def _steps_at(self, t_s: float) -> tuple[int, int]:
        """The physics step the stepping pauses at for time ``t_s`` (s; the first step at or after it, up to 1e-6
        of a step), and the first step whose ``time_s`` has reached it (within _EPS_S); _NEVER for inf."""
        if t_s == math.inf:
            return _NEVER, _NEVER
        dt = self._dt_s
        pause = math.ceil(t_s / dt - 1e-6)
        k = max(pause, 0)
        while k > 0 and t_s <= _step_time(k - 1, dt) + _EPS_S:
            k -= 1
        while t_s > _step_time(k, dt) + _EPS_S:
            k += 1
        return pause, k

    def _steps_to_next_event(self, k: int, end: int) -> int:
        """Physics steps from step ``k`` until something must happen in Python: agents, a sensor, the motor, the
        period end (step ``end``)."""
        commands, nxt = self._commands, end
        # the motor controller's next acceleration update while it ramps towards the command
        _, _, v_target, w_target = commands[0]
        if v_target != self._v_m_s or w_target != self._w_rad_s:
            motor = self._motor_substeps
            nxt = min(nxt, (k // motor + 1) * motor)
            if nxt == k + 1:
                return 1  # every other event is at least a step away
        # the earliest capture (a whole step, at least the next one) and the agents' period
        agent = self._agent_substeps
        nxt = min(nxt, (k // agent + 1) * agent, max(self._next_capture_step, k + 1))
        # a command arriving after its latency
        if len(commands) > 1:
            nxt = min(nxt, max(commands[1][0], k + 1))
        return nxt - k

    def _schedule_changed(self) -> None:
        """Cache the physics step the stepping pauses at for the earliest capture, and the first step whose time
        has reached it (``_next_capture_s`` changed)."""
        self._next_capture_step, self._next_due_step = self._steps_at(min(self._next_capture_s, default=math.inf))

    def _pending_changed(self) -> None:
        """Cache the first physics step whose time has reached the earliest pending delivery."""
        self._delivery_step = self._steps_at(self._pending[0][0])[1] if self._pending else _NEVER

    def _run_until(self, end: int) -> list[Reading]:
        """Run the physics up to step ``end`` in stretches of constant controls, doing what is due after each;
        returns the readings delivered meanwhile, oldest first."""
        timers = quiet_timers()  # MuJoCo's stage timers read no clock meanwhile (a good part of a step's cost)
        try:
            return self._stretches(end)
        finally:
            self.model.opt.disableflags = self._contact_flags[0]
            restore_timers(timers)

    def _stretches(self, end: int) -> list[Reading]:
        """:meth:`_run_until`'s loop (it may leave MuJoCo's collision detection switched off)."""
        delivered: list[Reading] = []
        model, data, base_qpos, history = self.model, self.data, self._base_qpos, self._history
        dt, agent, encoders = self._dt_s, self._agent_substeps, self._encoders
        opt, clearance, flags, skipping = model.opt, self._clearance, self._contact_flags, False
        k = self._step_count
        clear_until = None  # no contact can arise before this step (None: to be checked, the agents were posed)
        while k < end:
            n = self._steps_to_next_event(k, end)
            # agents move on their own period (their state is one period ahead; poses are interpolated)
            if k % agent == 0:
                self._step_agents()
                clear_until = None
            # motor model: latency, then acceleration limits at the motor controller's rate
            self._apply_drive(k)
            # collision detection, unless the robot can touch nothing during this stretch
            if clear_until is None:
                clear_until = k + clearance.clear_steps(data, self._posed_until(k, end) - k, base_qpos,
                                                        self._base_qvel)
            if (k + n <= clear_until) != skipping:
                skipping = not skipping
                opt.disableflags = flags[skipping]
            if skipping and not encoders and self._native_scene is not None:
                # this stretch, then the motor ramping on its own meanwhile, in one compiled call
                after = k + n
                k = self._ramp_stretches(k, min(end, -(-after // agent) * agent, self._next_capture_step,
                                                clear_until), first=n)
            else:
                if encoders:
                    v0, w0 = self.base_velocity()
                mujoco.mj_step(model, data, n)
                self._step_count = k = k + n
                if encoders:
                    v1, w1 = self.base_velocity()
                    for s in encoders:
                        s.integrate((v0 + v1) / 2, (w0 + w1) / 2, n * dt)
                history.append((k, *base_qpos.tolist()))
                # the motor ramping on its own meanwhile: its stretches with fewer checks
                if skipping and not encoders:
                    k = self._ramp_stretches(k, min(end, -(-k // agent) * agent, self._next_capture_step,
                                                    clear_until))
            if data.ncon:
                self._check_contacts()
            else:
                self._active_contacts.clear()
            # sensors due now, and readings whose latency has passed
            if k >= self._next_due_step:
                self._capture_due(self.time_s)
                clear_until = None
            if k >= self._delivery_step:
                delivered += self._deliver()
        return delivered

    def _ramp_stretches(self, k: int, limit: int, first: int = 0) -> int:
        """Run the stretches of the motor's ramp from physics step ``k`` while nothing else happens: one motor
        period each, as :meth:`_stretches` runs them, up to step ``limit`` at most (the next agent step, capture or
        possible contact, which the caller bounds) and no later than a command applies (the compiled path with a
        one-step motor period: applies the next command where it is due and runs on) or a capture is due. Only for
        a robot without wheel encoders and with collision detection off. Returns the step reached.

        Readings whose latency passes meanwhile are delivered after it (the caller delivers everything due then,
        in the same order): in lockstep, where nothing else decides what is delivered, the step returns the same
        readings. Without lockstep (camera frames delivered when ready) it also stops where a reading is due.

        ``first`` > 0 (compiled path only): a stretch of that many steps with the controls as they are comes
        first, with its pose in the history, as :meth:`_stretches` runs it."""
        motor, commands, model, data = self._motor_substeps, self._commands, self.model, self.data
        limit = min(limit, self._next_due_step) if self.config.lockstep else \
            min(limit, self._next_due_step, self._delivery_step)
        _, _, v_target, w_target = commands[0]
        (dv_max, dw_max), v, w = self._ramp_limits, self._v_m_s, self._w_rad_s
        if self._native_scene is not None:  # the same stretches in one compiled call, into the history's ring
            # a single queued command can switch the target inside the call where it applies (as _apply_drive
            # would there) when the motor period is one physics step (longer: the stepping loop makes the stretch
            # there a single step, the command being an event); any other stops the stretches where it applies
            switch_at, v_next, w_next = _NEVER, 0.0, 0.0
            if motor == 1 and len(commands) == 2 and commands[1][0] == commands[1][1]:
                switch_at, _, v_next, w_next = commands[1]
            elif len(commands) > 1:
                limit = min(limit, commands[1][0], commands[1][1])
            history = self._history
            k, v, w, count, switched = ramp_steps(
                FUNCTIONS, *self._native_scene, *self._native_shadow, k, first, limit, motor, v, w, v_target,
                w_target, dv_max, dw_max, switch_at, v_next, w_next, history.steps, history.poses, history.appended)
            history.appended += count
            if switched:
                commands.popleft()
            self._v_m_s, self._w_rad_s, self._step_count = v, w, k
            return k
        if len(commands) > 1:
            limit = min(limit, commands[1][0], commands[1][1])
        ctrl, base_qpos, append, step = self._ctrl, self._base_qpos, self._history.append, mujoco.mj_step
        while k % motor == 0 and k + motor <= limit and (v_target != v or w_target != w):
            v, w = _ramped(v, v_target, dv_max), _ramped(w, w_target, dw_max)
            ctrl[0], ctrl[2] = v, w  # (ctrl[1], the lateral speed, stays 0)
            step(model, data, motor)
            k += motor
            append((k, *base_qpos.tolist()))
        self._v_m_s, self._w_rad_s, self._step_count = v, w, k
        return k

    def _posed_until(self, k: int, end: int) -> int:
        """The step after step ``k`` at which the agents may be posed next (their period, the earliest capture's
        pause) or the period ends (step ``end``); no stretch goes past it."""
        agent = self._agent_substeps
        return min(end, (k // agent + 1) * agent, max(self._next_capture_step, k + 1))

    def _apply_drive(self, k: int) -> None:
        """Commands whose latency has passed at step ``k`` take effect; the motor ramps towards the latest one."""
        commands = self._commands
        while len(commands) > 1 and commands[1][1] <= k:
            commands.popleft()
        _, _, v_target, w_target = commands[0]
        v, w = self._v_m_s, self._w_rad_s
        if k % self._motor_substeps == 0 or (v_target == v and w_target == w):
            dv_max, dw_max = self._ramp_limits
            self._v_m_s = v = _ramped(v, v_target, dv_max)
            self._w_rad_s = w = _ramped(w, w_target, dw_max)
        ctrl = self._ctrl
        ctrl[0], ctrl[1], ctrl[2] = v, 0.0, w

    def _step_agents(self) -> None:
        """Advance the people, the other robots and the doors by one agent period and pose them at the current time."""
        dt, crowd, wanderers, doors = self._agent_dt_s, self.crowd, self.wanderers, self.doors
        # blockers: circles of the robot and the other robots before this step, then of the people after it;
        # nearby: the people and the robot, then the other robots after their step (buffers of this episode, which
        # the agents read during their steps only)
        people_count, robots, blockers, nearby, circles, circle_vel = self._agent_rows
        others_xy, others_vel = wanderers.motion_arrays()[:2]
        _robot_rows(circles, circle_vel, self._base_qpos, self._base_qvel, self.robot_radius_m, others_xy, others_vel,
                    WANDERER_RADIUS_M)
        # people (an empty crowd has nothing to step), then the other robots, then the doors
        if people_count:
            crowd.step_rows(dt, doors.segments_xy() if doors else None, circles, circle_vel)
        _people_rows(nearby, blockers, crowd.motion_arrays()[0], crowd.radius_m, robots)
        if robots > 1:
            wanderers.step(dt, nearby[:people_count + 1])
        if doors:
            nearby[people_count + 1:] = wanderers.motion_arrays()[0]
            doors.update(self._agent_time_s + dt, dt, nearby, blockers)
        self._agent_time_s += dt
        self._keep_agent_state()
        self._pose_agents_at(self.time_s)

    def _keep_agent_state(self) -> None:
        """Copy the state that poses are interpolated from (the people's and other robots' positions, velocities,
        yaws and yaw rates, the doors' yaws and yaw rates) into the rows of ``_movers``."""
        _pack_movers(self._movers, *self.crowd.motion_arrays(), *self.wanderers.motion_arrays(),
                     self.doors.yaws_rad, self.doors.yaw_rates_rad_s)

    def _pose_agents_at(self, t_s: float) -> None:
        """Write agent poses into the mocap bodies at time ``t_s`` (linear motion towards the agent state)."""
        if self._posed_at == (t_s, self._agent_time_s):
            return
        self._posed_at = (t_s, self._agent_time_s)
        _pose_agents(self._mocap_pos, self._mocap_quat, self._mocap_rows, self._movers, self._moving,
                     max(self._agent_time_s - t_s, 0.0))

    # -------------------------------------------------------------------------------------------- sensors
    def _capture_due(self, t: float) -> None:
        """Take the readings due at the current time ``t`` (s) and queue them for delivery after their latency."""
        due = [k for k, next_s in enumerate(self._next_capture_s) if next_s <= t + _EPS_S]
        if not due:
            return
        if any(map(self._sees_scene.__getitem__, due)):
            self._pose_agents_at(t)
            mujoco.mj_kinematics(self.model, self.data)
            if any(map(self._is_camera.__getitem__, due)):
                mujoco.mj_camlight(self.model, self.data)
        # cameras first: their frames render in the background while the other sensors capture here (each sensor
        # has its own noise stream and nothing here changes the state, so the order does not change a reading)
        twists = None
        readings: dict[int, Reading | Future] = {}
        for k in sorted(due, key=self._capture_rank.__getitem__):
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
        self._pending_changed()

    def _deliver(self) -> list[Reading]:
        """Readings due by now, in order. Camera frames are made in the background (futures): in lockstep mode
        a due frame is waited for; otherwise delivery pauses at the first frame not finished yet."""
        out, now = [], self.time_s
        while self._pending and self._pending[0][0] <= now + _EPS_S:
            item = self._pending[0][2]
            if isinstance(item, Future) and not (self.config.lockstep or item.done()):
                break
            heapq.heappop(self._pending)
            out.append(self._receive(item))
        self._pending_changed()
        return out

    def flush(self) -> list[Reading]:
        """Wait for every reading captured so far (also those not due yet) and return them in order."""
        out = []
        while self._pending:
            out.append(self._receive(heapq.heappop(self._pending)[2]))
        self._pending_changed()
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
        self._commands = deque([self._command(-math.inf, 0.0, 0.0)])
        mujoco.mj_forward(self.model, self.data)
        self._history.append((self._step_count, *self._base_qpos.tolist()))

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
        x, y, yaw = self._base_qpos.tolist()
        return x, y, math.atan2(math.sin(yaw), math.cos(yaw))

    def T_world_base_at(self, stamp_s: float) -> np.ndarray:
        """(4, 4) ground-truth base pose at a past time ``stamp_s`` (within the last few seconds), s."""
        k = len(self._history) - 1
        while k > 0 and _step_time(self._history[k][0], self._dt_s) > stamp_s + _EPS_S:
            k -= 1
        _, x, y, yaw = self._history[k]
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        c, s = math.cos(yaw), math.sin(yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = [x, y]
        return T

    def base_velocity(self) -> tuple[float, float]:
        """Ground-truth forward speed (m/s, along base x) and yaw rate (rad/s)."""
        vx, vy, w = self._base_qvel.tolist()
        yaw = self._base_qpos[2].item()
        return vx * math.cos(yaw) + vy * math.sin(yaw), w

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
        tw[idx.door_body, 5] = self.doors.yaw_rates_rad_s
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


class PoseHistory:
    """The last ``size`` entries (physics step, x m, y m, yaw rad as in qpos) of the base's poses after each stretch
    of physics steps, in numpy rings that compiled code writes to (:func:`simnav.sim.native.ramp_steps`).

    A sequence of ``(step, x, y, yaw)`` tuples, oldest first, like a ``deque(maxlen=size)`` of them.
    """

    def __init__(self, size: int) -> None:
        self.steps = np.zeros(size, dtype=np.int64)
        self.poses = np.zeros((size, 3))
        self.appended = 0
        """How many entries were ever appended (the next goes to ring entry ``appended % size``)."""

    def append(self, entry: tuple[int, float, float, float]) -> None:
        j = self.appended % len(self.steps)
        self.steps[j] = entry[0]
        self.poses[j] = entry[1:]
        self.appended += 1

    def __len__(self) -> int:
        return min(self.appended, len(self.steps))

    def __getitem__(self, index: int) -> tuple[int, float, float, float]:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"history index {index} out of range for {n} entries")
        j = (self.appended - n + index % n) % len(self.steps)
        return (int(self.steps[j]), *self.poses[j].tolist())

    def __iter__(self):
        n, size = len(self), len(self.steps)
        order = (np.arange(self.appended - n, self.appended) % size).tolist()
        return iter(zip(self.steps[order].tolist(), *self.poses[order].T.tolist()))


@functools.lru_cache(maxsize=256)
def _step_time(k: int, dt_s: float) -> float:
    """Time of physics step ``k`` of ``dt_s`` seconds, s: ``k·dt`` rounded to the nanosecond (free of accumulated
    rounding). Cached: the stepping asks for the same few steps many times, and ``round`` is slow."""
    return round(k * dt_s, 9)


def _circumradius(robot: RobotSpec) -> float:
    return max(math.hypot(x, y) for p in robot.prisms for x, y in p.polygon)


def _clamp(x: float, limit: float) -> float:
    """``np.clip(x, -limit, limit)`` as a python float (min/max give the same for floats, without numpy's cost)."""
    if isinstance(x, float):
        return float(min(max(x, -limit), limit))
    return float(np.clip(x, -limit, limit))


def _ramped(x: float, target: float, limit: float) -> float:
    """``x`` moved towards ``target`` by at most ``limit`` (the change ``min(max(target - x, -limit), limit)``
    without the builtin calls)."""
    d = target - x
    return x + (limit if d > limit else -limit if d < -limit else d)


@njit(cache=True, error_model="numpy")
def _robot_rows(circles: np.ndarray, velocities: np.ndarray, base_q: np.ndarray, base_v: np.ndarray, radius_m: float,
                others_xy: np.ndarray, others_vel: np.ndarray, others_radius_m: float) -> None:
    """Fill the (1 + N, 3) ``circles`` ``[x, y, radius]`` (m) of the robot (base ``base_q`` x, y) and of N other
    robots at the (N, 2) ``others_xy``, and their (1 + N, 2) ``velocities`` (the robot's: ``base_v`` x, y), m/s."""
    circles[0, 0], circles[0, 1], circles[0, 2] = base_q[0], base_q[1], radius_m
    velocities[0, 0], velocities[0, 1] = base_v[0], base_v[1]
    for k in range(others_xy.shape[0]):
        circles[1 + k, 0], circles[1 + k, 1], circles[1 + k, 2] = others_xy[k, 0], others_xy[k, 1], others_radius_m
        velocities[1 + k, 0], velocities[1 + k, 1] = others_vel[k, 0], others_vel[k, 1]


@njit(cache=True, error_model="numpy")
def _people_rows(nearby: np.ndarray, blockers: np.ndarray, people_xy: np.ndarray, radius_m: float,
                 robots: int) -> None:
    """Fill ``nearby`` (P + R, 2) with the (P, 2) ``people_xy`` then the robot (``blockers[0]``), and the rows of
    ``blockers`` (R + P, 3) after its R robots with the people as circles of ``radius_m`` (all metres)."""
    people = people_xy.shape[0]
    for i in range(people):
        x, y = people_xy[i, 0], people_xy[i, 1]
        nearby[i, 0], nearby[i, 1] = x, y
        blockers[robots + i, 0], blockers[robots + i, 1], blockers[robots + i, 2] = x, y, radius_m
    nearby[people, 0], nearby[people, 1] = blockers[0, 0], blockers[0, 1]


@njit(cache=True, error_model="numpy")
def _pack_movers(out: np.ndarray, people_xy: np.ndarray, people_vel: np.ndarray, people_yaw: np.ndarray,
                 people_rate: np.ndarray, robots_xy: np.ndarray, robots_vel: np.ndarray, robots_yaw: np.ndarray,
                 robots_rate: np.ndarray, doors_yaw: np.ndarray, doors_rate: np.ndarray) -> None:
    """Rows of ``out`` (P + R + D, 6): [x, y, vx, vy, yaw, yaw rate] of the P people, then of the R other robots
    ((N, 2) positions m and velocities m/s, (N,) yaws rad and yaw rates rad/s), then [-, -, -, -, yaw, yaw rate]
    of the D doors."""
    p, r = people_xy.shape[0], robots_xy.shape[0]
    for i in range(p):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = people_xy[i, 0], people_xy[i, 1], people_vel[i, 0], \
            people_vel[i, 1]
        out[i, 4], out[i, 5] = people_yaw[i], people_rate[i]
    for i in range(r):
        out[p + i, 0], out[p + i, 1], out[p + i, 2], out[p + i, 3] = robots_xy[i, 0], robots_xy[i, 1], \
            robots_vel[i, 0], robots_vel[i, 1]
        out[p + i, 4], out[p + i, 5] = robots_yaw[i], robots_rate[i]
    for d in range(doors_yaw.shape[0]):
        out[p + r + d, 4], out[p + r + d, 5] = doors_yaw[d], doors_rate[d]


@njit(cache=True, error_model="numpy")
def _pose_agents(mocap_pos: np.ndarray, mocap_quat: np.ndarray, rows: np.ndarray, movers: np.ndarray, moving: int,
                 back_s: float) -> None:
    """Pose mocap body ``rows[k]`` ``back_s`` before the state in row k of ``movers`` (:func:`_pack_movers`): the
    first ``moving`` (people, other robots) on the floor at ``xy - vel·back_s`` (m), turned to ``yaw -
    yaw_rate·back_s`` (rad); the others (doors) only turned."""
    for k in range(rows.shape[0]):
        m = rows[k]
        if k < moving:
            mocap_pos[m, 0] = movers[k, 0] - movers[k, 2] * back_s
            mocap_pos[m, 1] = movers[k, 1] - movers[k, 3] * back_s
            mocap_pos[m, 2] = 0.0
        _set_yaw(mocap_quat, m, movers[k, 4] - movers[k, 5] * back_s)


@njit(cache=True, error_model="numpy")
def _set_yaw(mocap_quat: np.ndarray, m: int, yaw: float) -> None:
    """Mocap quaternion ``m`` (w, x, y, z): a turn by ``yaw`` (rad) about the world z axis."""
    half = yaw / 2
    mocap_quat[m, 0], mocap_quat[m, 1], mocap_quat[m, 2], mocap_quat[m, 3] = math.cos(half), 0.0, 0.0, math.sin(half)
