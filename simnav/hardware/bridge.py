"""The Dynamixel bridge: a differential base whose wheels are X-series servos in velocity mode, driven through the
real ``dynamixel_sdk`` (Protocol 2.0).

Start-up (:meth:`DynamixelBridge.open`): open the port, ping every ID and check the model and firmware, torque
off, velocity mode, velocity limit (EEPROM written only when it differs), arm the bus watchdog, zero goal, torque
on. Each control period (:meth:`DynamixelBridge.cycle`): the command through the freshness gate, the acceleration
ramp and the wheel-speed clamp; one GroupSyncWrite of both goal velocities; one GroupSyncRead of present velocity
and position; wheel odometry. :meth:`DynamixelBridge.start` runs the cycles on a thread at the control rate.

Safety: no fresh command for ``stale_after_cycles`` periods (default two) -> zero; a NaN/inf/out-of-range command ->
zero and an error; a timeout, a corrupt status packet, a hardware error or a vanished port -> zero where still
possible and a :class:`HardwareError` (latched until :meth:`reconnect`; optionally reconnected automatically);
torque off on :meth:`close`. The servos' bus watchdog stops them on its own if the host falls silent.
"""

from __future__ import annotations

import logging
import math
import termios
import threading
import time
from collections import deque
from dataclasses import dataclass

import serial
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

from simnav.errors import SimnavError
from simnav.hardware import control_table as ct
from simnav.hardware.kinematics import (
    DiffDrive,
    TwistRamp,
    WheelOdometer,
    clamp_wheels,
    rad_s_to_raw,
    raw_to_rad_s,
    to_int32,
)
from simnav.hardware.protocol import ALERT_BIT, le_bytes
from simnav.robot.spec import Drive, Hardware

log = logging.getLogger(__name__)

COMMAND_MARGIN = 1.01
"""Commands up to 1 % beyond the drive limits are accepted (and clamped); further out they are errors."""
WATCHDOG_SUSPECT = 0.8
"""After a bus silence of this share of the watchdog time, the bridge checks whether it tripped before writing."""
PORT_ERRORS = (serial.SerialException, OSError, termios.error)
"""What pyserial raises when the port vanishes (unplugged adapter, closed pty)."""
SDK_ERRORS = (IndexError, ValueError, TypeError, KeyError)
"""What the SDK's packet handling can raise on a status packet that passed its CRC check but is malformed."""
READ_ADDRESS, READ_LENGTH = ct.ADDR_PRESENT_VELOCITY, 8  # Present Velocity (4) + Present Position (4)


class HardwareError(SimnavError):
    """A fault of the Dynamixel bus or a servo; the motors were commanded to zero where still possible."""


class _BusFault(Exception):
    """A failed transaction inside the bridge (turned into a latched :class:`HardwareError`)."""


@dataclass(frozen=True)
class ServoInfo:
    """What start-up found on the bus for one wheel."""

    wheel: str
    dxl_id: int
    model_number: int
    model: str
    firmware: int
    drive_mode_reversed: bool
    sign: int
    """+1 or -1: servo velocity/position units times this are forward wheel rotation."""


@dataclass(frozen=True)
class ServoStatus:
    """Health registers of one servo, in SI units."""

    wheel: str
    dxl_id: int
    torque_on: bool
    hardware_error: int
    watchdog_units: int
    velocity_limit_rad_s: float
    voltage_v: float
    temperature_c: int


@dataclass(frozen=True)
class WheelSample:
    """One control period's exchange with the servos.

    ``stamp_s`` is the bridge's clock (seconds since start-up, wall time times the time scale). Wheel values are
    (left, right) and forward-positive; raw values are the servos' own units and directions.
    """

    cycle: int
    stamp_s: float
    command_v_m_s: float
    command_w_rad_s: float
    goal_raw: tuple[int, int]
    velocity_raw: tuple[int, int]
    position_raw: tuple[int, int]
    wheel_rad_s: tuple[float, float]
    wheel_ticks: tuple[int, int]
    v_m_s: float
    w_rad_s: float
    pose_xyt: tuple[float, float, float]
    stale: bool


@dataclass
class BridgeStats:
    """Counters since start-up."""

    cycles: int = 0
    faults: int = 0
    stale_stops: int = 0
    watchdog_rearms: int = 0
    reconnects: int = 0
    overruns: int = 0


class _Port(PortHandler):
    """The SDK's port with two changes:

    - the adapter's latency timer is configurable (the SDK assumes 16 ms): the status timeout is
      ``bytes x byte time + 2 x latency + 2 ms``;
    - a status packet that arrived in time is not lost to a stall of this process: the SDK's receive loop checks
      the clock after an empty read, so a stall between the two would read as a timeout although the bytes are
      waiting. Once the time is up, one more read is granted if bytes are waiting.
    """

    def __init__(self, port_name: str, latency_timer_ms: float) -> None:
        super().__init__(port_name)
        self.latency_timer_ms = latency_timer_ms
        self._grace = True

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_timer_ms + 2.0
        self._grace = True

    def isPacketTimeout(self):  # noqa: N802 (SDK name)
        if self._grace and self.getTimeSinceStart() > self.packet_timeout and self.getBytesAvailable() > 0:
            self._grace = False
            return False
        return super().isPacketTimeout()


class DynamixelBridge:
    """Two wheel servos of a differential base behind one serial port.

    Args:
        hardware: the robot's ``hardware`` block (port, IDs, limits, rates).
        drive: the robot's ``drive`` block (wheel radius and separation, v/w and acceleration limits).
        port: serial port to use instead of ``hardware.port`` (e.g. a virtual bus).
        robot: robot name, for messages.
        time_scale: the servos' clock runs this much faster than the wall clock (a virtual bus only).
        stale_after_cycles: control periods without a fresh command after which the wheels are stopped.

    Use as a context manager (open on enter; zero, torque off and close on exit, also on Ctrl-C)::

        with DynamixelBridge(robot.hardware, robot.drive) as bridge:
            bridge.command(0.1, 0.0)
            sample = bridge.cycle()
    """

    def __init__(self, hardware: Hardware, drive: Drive, *, port: str | None = None, robot: str = "robot",
                 time_scale: float = 1.0, stale_after_cycles: int = 2) -> None:
        self.hw = hardware
        self.drive = drive
        self.port_name = port or hardware.port
        self.robot = robot
        self.time_scale = time_scale
        self.stale_after_cycles = stale_after_cycles
        self.kinematics = DiffDrive(drive.wheel_radius_m, drive.wheel_separation_m)
        self.period_s = hardware.control_period_s
        self.limit_raw = min(rad_s_to_raw(hardware.max_wheel_speed_rad_s), 1023)
        self.max_wheel_rad_s = raw_to_rad_s(self.limit_raw)
        self.servos: list[ServoInfo] = []
        self.stats = BridgeStats()
        self._wheels = (("left", hardware.left_id), ("right", hardware.right_id))
        self._port: _Port | None = None
        self._ph = PacketHandler(2.0)
        self._gsw: GroupSyncWrite | None = None
        self._gsr: GroupSyncRead | None = None
        self._bus_lock = threading.RLock()
        self._cmd_lock = threading.Lock()
        self._command = (0.0, 0.0)
        self._fresh = False
        self._missed = stale_after_cycles  # no command yet: stopped
        self._ramp = TwistRamp(drive.max_acc_m_s2, drive.max_ang_acc_rad_s2)
        self._odometer: WheelOdometer | None = None
        self._fault: HardwareError | None = None
        self._t0 = time.monotonic()
        self._last_tx = time.monotonic()
        self._last_goals = (0, 0)
        self._cycle = 0
        # loop thread
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._samples: deque[WheelSample] = deque(maxlen=4096)
        self._cond = threading.Condition()
        self.latest: WheelSample | None = None

    # ------------------------------------------------------------------------------------------- start-up
    def __enter__(self) -> DynamixelBridge:
        if not self.is_open:
            self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._port is not None

    @property
    def fault(self) -> HardwareError | None:
        """The latched fault (None while healthy)."""
        return self._fault

    @property
    def wheel_ticks(self) -> tuple[int, int]:
        """Cumulative forward ticks of the (left, right) wheel since start-up (4096 per revolution)."""
        return self._odometer.ticks if self._odometer is not None else (0, 0)

    def now_s(self) -> float:
        """The bridge's clock: seconds since construction, wall time times the time scale."""
        return (time.monotonic() - self._t0) * self.time_scale

    def open(self) -> list[ServoInfo]:
        """Open the port and run the start-up sequence; returns what was found.

        Raises:
            HardwareError: the port cannot be opened, a servo does not answer, has the wrong model, old firmware,
                a hardware error, or refuses a register write (the port is closed again).
        """
        with self._bus_lock:
            self._close_port(torque_off=False)  # opening twice starts afresh
            self._open_port()
            try:
                self.servos = [self._start_servo(wheel, dxl_id) for wheel, dxl_id in self._wheels]
                self._make_groups()
                self._odometer = WheelOdometer(self.kinematics, (self.servos[0].sign, self.servos[1].sign))
                self._odometer.update(*self._read_state()[1])
            except (_BusFault, *SDK_ERRORS) as err:
                self._close_port(torque_off=True)
                raise HardwareError(f"{self._where()}: start-up failed: {err}") from None
            except PORT_ERRORS as err:
                self._close_port(torque_off=False)
                raise HardwareError(f"{self._where()}: the port failed during start-up ({err})") from None
        self._fault = None
        self._ramp.reset()
        log.info("%s: %s", self._where(), ", ".join(f"{s.wheel} id {s.dxl_id} {s.model} fw {s.firmware}"
                                                   for s in self.servos))
        return self.servos

    def _where(self) -> str:
        return f"Dynamixel bus '{self.port_name}' of robot '{self.robot}'"

    def _open_port(self) -> None:
        port = _Port(self.port_name, self.hw.latency_timer_ms)
        try:
            port.openPort()
            ok = port.setBaudRate(self.hw.baud_rate)
        except PORT_ERRORS as err:
            raise HardwareError(f"cannot open the Dynamixel port '{self.port_name}' of robot '{self.robot}': {err}. "
                                "Check the device path (ls /dev/ttyUSB* /dev/serial/by-id/), the cable, and that "
                                "you may use it (group dialout)") from None
        if not ok:
            port.closePort()
            raise HardwareError(f"{self._where()}: baud rate {self.hw.baud_rate} not supported by the port")
        self._port = port
        self._last_tx = time.monotonic()

    def _start_servo(self, wheel: str, dxl_id: int) -> ServoInfo:
        """Ping, check, configure and enable one servo."""
        # Identify: ping (model), firmware, hardware error
        name = f"servo {dxl_id} ({wheel} wheel)"
        model, result, error = self._ph.ping(self._port, dxl_id)
        if result != COMM_SUCCESS:
            raise _BusFault(f"{name} does not answer a ping at {self.hw.baud_rate} bit/s "
                            f"({self._ph.getTxRxResult(result)}); check the ID, the baud rate and the power")
        expected = ct.MODELS[self.hw.model]
        if model != expected:
            found = ct.MODEL_NAMES.get(model, "an unknown model")
            raise _BusFault(f"{name} is {found} (model number {model}), the robot's hardware.model is "
                            f"{self.hw.model} ({expected})")
        self._check_status(dxl_id, "ping", error)
        firmware = self._read(dxl_id, name, ct.ADDR_FIRMWARE, 1, "Firmware Version")
        if firmware < ct.MIN_WATCHDOG_FIRMWARE:
            raise _BusFault(f"{name} has firmware v{firmware}; the bus watchdog needs v{ct.MIN_WATCHDOG_FIRMWARE} "
                            "or later (update it with Dynamixel Wizard)")
        # Configure with torque off: velocity mode and velocity limit (EEPROM written only when it differs)
        self._write(dxl_id, name, ct.ADDR_TORQUE_ENABLE, 1, 0, "Torque Enable")
        reversed_mode = bool(self._read(dxl_id, name, ct.ADDR_DRIVE_MODE, 1, "Drive Mode")
                             & ct.DRIVE_MODE_REVERSE_BIT)
        if self._read(dxl_id, name, ct.ADDR_OPERATING_MODE, 1, "Operating Mode") != ct.OPERATING_MODE_VELOCITY:
            self._write(dxl_id, name, ct.ADDR_OPERATING_MODE, 1, ct.OPERATING_MODE_VELOCITY, "Operating Mode")
        if self._read(dxl_id, name, ct.ADDR_VELOCITY_LIMIT, 4, "Velocity Limit") != self.limit_raw:
            self._write(dxl_id, name, ct.ADDR_VELOCITY_LIMIT, 4, self.limit_raw, "Velocity Limit")
        # Arm the bus watchdog (clearing a trip first), zero goal, torque on
        self._write(dxl_id, name, ct.ADDR_BUS_WATCHDOG, 1, 0, "Bus Watchdog")
        self._write(dxl_id, name, ct.ADDR_BUS_WATCHDOG, 1, self._watchdog_units(), "Bus Watchdog")
        self._write(dxl_id, name, ct.ADDR_GOAL_VELOCITY, 4, 0, "Goal Velocity")
        self._write(dxl_id, name, ct.ADDR_TORQUE_ENABLE, 1, 1, "Torque Enable")
        mounted = -1 if (self.hw.reverse_left if wheel == "left" else self.hw.reverse_right) else 1
        return ServoInfo(wheel, dxl_id, model, ct.MODEL_NAMES[model], firmware, reversed_mode,
                         mounted * (-1 if reversed_mode else 1))

    def _watchdog_units(self) -> int:
        return round(self.hw.watchdog_ms / 1000 / ct.WATCHDOG_UNIT_S)

    def _make_groups(self) -> None:
        self._gsw = GroupSyncWrite(self._port, self._ph, ct.ADDR_GOAL_VELOCITY, 4)
        self._gsr = GroupSyncRead(self._port, self._ph, READ_ADDRESS, READ_LENGTH)
        for _, dxl_id in self._wheels:
            self._gsw.addParam(dxl_id, list(le_bytes(0, 4)))
            self._gsr.addParam(dxl_id)

    # ------------------------------------------------------------------------------------ register access
    def _read(self, dxl_id: int, name: str, address: int, size: int, what: str) -> int:
        read = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[size]
        value, result, error = read(self._port, dxl_id, address)
        self._last_tx = time.monotonic()
        if result != COMM_SUCCESS:
            raise _BusFault(f"{name}: reading {what} ({address}) failed: {self._ph.getTxRxResult(result)}")
        self._check_status(dxl_id, f"reading {what} ({address})", error)
        return value

    def _write(self, dxl_id: int, name: str, address: int, size: int, value: int, what: str) -> None:
        write = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[size]
        result, error = write(self._port, dxl_id, address, value & ((1 << (8 * size)) - 1))
        self._last_tx = time.monotonic()
        if result != COMM_SUCCESS:
            raise _BusFault(f"{name}: writing {what} ({address}) = {value} failed: "
                            f"{self._ph.getTxRxResult(result)}")
        self._check_status(dxl_id, f"writing {what} ({address}) = {value}", error)

    def _check_status(self, dxl_id: int, doing: str, error: int) -> None:
        """Raise for an error byte: the alert bit means a hardware error (register 70 says which)."""
        name = self._name(dxl_id)
        if error & ALERT_BIT:
            bits, result, _ = self._ph.read1ByteTxRx(self._port, dxl_id, ct.ADDR_HARDWARE_ERROR)
            what = ct.describe_hardware_error(bits) if result == COMM_SUCCESS else "unreadable"
            raise _BusFault(f"{name} reports a hardware error ({what}); it turned its torque off. Remove the cause, "
                            "then power-cycle or reboot it (simnav hw --reboot)")
        if error:
            raise _BusFault(f"{name}: {doing}: {self._ph.getRxPacketError(error)} (error {error})")

    def _name(self, dxl_id: int) -> str:
        wheel = next(w for w, i in self._wheels if i == dxl_id)
        return f"servo {dxl_id} ({wheel} wheel)"

    # ---------------------------------------------------------------------------------------- commanding
    def command(self, v_m_s: float, w_rad_s: float) -> None:
        """Set the (v, w) command (m/s, rad/s) that the next control periods send.

        Raises:
            HardwareError: a NaN, infinite or out-of-range command (the wheels are stopped at once), or a latched
                fault.
        """
        v, w = float(v_m_s), float(w_rad_s)
        max_v, max_w = self.drive.max_v_m_s * COMMAND_MARGIN, self.drive.max_w_rad_s * COMMAND_MARGIN
        if not (math.isfinite(v) and math.isfinite(w) and abs(v) <= max_v and abs(w) <= max_w):
            self.stop_now()
            raise HardwareError(f"robot '{self.robot}': invalid velocity command v={v_m_s!r} m/s, w={w_rad_s!r} "
                                f"rad/s; expected finite values with |v| <= {self.drive.max_v_m_s:g} m/s and |w| <= "
                                f"{self.drive.max_w_rad_s:.3g} rad/s (drive limits); the wheels were stopped")
        self._raise_fault()
        with self._cmd_lock:
            self._command = (v, w)
            self._fresh = True

    def stop_now(self) -> None:
        """Zero command and zero goal velocities on the bus at once (best effort, never raises)."""
        with self._cmd_lock:
            self._command, self._fresh, self._missed = (0.0, 0.0), False, self.stale_after_cycles
        self._ramp.reset()
        with self._bus_lock:
            self._zero_goals()

    def _zero_goals(self) -> bool:
        """One GroupSyncWrite of zero goals; False when the bus is gone."""
        if self._port is None or self._gsw is None:
            return False
        self._port.is_using = False  # a transaction cut short (Ctrl-C) must not block the stop
        try:
            self._sync_write((0, 0))
            return True
        except (_BusFault, *PORT_ERRORS, *SDK_ERRORS) as err:
            self._port.is_using = False
            log.error("%s: could not command zero velocity: %s", self._where(), err)
            return False

    def _raise_fault(self) -> None:
        if self._fault is not None:
            raise HardwareError(str(self._fault))

    # -------------------------------------------------------------------------------------- control period
    def cycle(self) -> WheelSample:
        """One control period: one GroupSyncWrite of goal velocities, one GroupSyncRead of velocity and position.

        Raises:
            HardwareError: a fault now or before (latched until :meth:`reconnect`); the wheels were stopped where
                the bus still allowed it.
        """
        self._raise_fault()
        with self._bus_lock:
            if self._port is None:
                raise HardwareError(f"{self._where()}: the bridge is not open")
            # Command: freshness gate, acceleration ramp, wheel-speed clamp, raw units
            command, stale = self._next_command()
            goals = self._goals(command, stale)
            try:
                # Bus watchdog: after a silence that may have tripped it, check and re-arm before writing
                self._rearm_watchdog_if_tripped()
                # One GroupSyncWrite of goal velocities, one GroupSyncRead of present velocity and position
                self._sync_write(goals)
                velocity, position = self._read_state()
            except (_BusFault, *PORT_ERRORS) as err:
                raise self._latch(err) from None
            except SDK_ERRORS as err:  # a status packet the SDK could not take apart
                raise self._latch(_BusFault(f"malformed status packet ({type(err).__name__}: {err})")) from None
            # Wheel odometry from positions (wrap-around handled)
            return self._sample(command, goals, velocity, position, stale)

    def _next_command(self) -> tuple[tuple[float, float], bool]:
        with self._cmd_lock:
            if self._fresh:
                self._fresh, self._missed = False, 0
            else:
                self._missed += 1
            stale = self._missed >= self.stale_after_cycles
            if stale and self._missed == self.stale_after_cycles and self._command != (0.0, 0.0):
                self.stats.stale_stops += 1
                log.warning("%s: no fresh command for %d control periods: stopping the wheels", self._where(),
                            self._missed)
            return ((0.0, 0.0) if stale else self._command), stale

    def _goals(self, command: tuple[float, float], stale: bool) -> tuple[int, int]:
        """Raw goal velocities for a (v, w) command: scaled into the wheel-speed limit keeping its curvature,
        ramped (a stale stop is immediate), signed per servo."""
        if stale:
            self._ramp.reset()
            v, w = 0.0, 0.0
        else:
            target = self.kinematics.twist(*clamp_wheels(*self.kinematics.wheel_speeds(*command),
                                                         self.max_wheel_rad_s))
            v, w = self._ramp.step(*target, self.period_s)
        left, right = clamp_wheels(*self.kinematics.wheel_speeds(v, w), self.max_wheel_rad_s)
        raw = [max(-self.limit_raw, min(self.limit_raw, s.sign * rad_s_to_raw(speed)))
               for s, speed in zip(self.servos, (left, right))]
        return raw[0], raw[1]

    def _rearm_watchdog_if_tripped(self) -> None:
        silence_s = (time.monotonic() - self._last_tx) * self.time_scale
        if silence_s < WATCHDOG_SUSPECT * self.hw.watchdog_ms / 1000:
            return
        for _, dxl_id in self._wheels:
            name = self._name(dxl_id)
            if self._read(dxl_id, name, ct.ADDR_BUS_WATCHDOG, 1, "Bus Watchdog") == ct.WATCHDOG_TRIPPED:
                self.stats.watchdog_rearms += 1
                moving = any(self._last_goals)
                log.log(logging.WARNING if moving else logging.INFO, "%s: %s: the bus watchdog %s after %.0f ms "
                        "without a packet; re-arming", self._where(), name,
                        "stopped it" if moving else "tripped (wheels at rest)", silence_s * 1000)
                self._write(dxl_id, name, ct.ADDR_BUS_WATCHDOG, 1, 0, "Bus Watchdog")
                self._write(dxl_id, name, ct.ADDR_BUS_WATCHDOG, 1, self._watchdog_units(), "Bus Watchdog")

    def _sync_write(self, goals: tuple[int, int]) -> None:
        self._last_goals = goals
        for (_, dxl_id), goal in zip(self._wheels, goals):
            self._gsw.changeParam(dxl_id, list(le_bytes(goal, 4)))
        result = self._gsw.txPacket()
        self._last_tx = time.monotonic()
        if result != COMM_SUCCESS:
            raise _BusFault(f"sync write of goal velocities failed: {self._ph.getTxRxResult(result)}")

    def _read_state(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """GroupSyncRead of Present Velocity and Position: ((vel left, right), (pos left, right)), raw int32.

        The status packets are received one by one with the SDK's ``readRx`` (what ``GroupSyncRead.rxPacket``
        does) so that each servo's error byte -- the hardware-error alert -- is seen, not dropped.
        """
        try:
            result = self._gsr.txPacket()
            self._last_tx = time.monotonic()
            if result != COMM_SUCCESS:
                raise _BusFault(f"sync read failed to send: {self._ph.getTxRxResult(result)}")
            data = [self._receive(dxl_id) for _, dxl_id in self._wheels]
        finally:
            self._port.is_using = False
        velocity = tuple(to_int32(int.from_bytes(bytes(d[0:4]), "little")) for d in data)
        position = tuple(to_int32(int.from_bytes(bytes(d[4:8]), "little")) for d in data)
        return velocity, position

    def _receive(self, dxl_id: int) -> list[int]:
        data, result, error = self._ph.readRx(self._port, dxl_id, READ_LENGTH)
        name = self._name(dxl_id)
        if result != COMM_SUCCESS:
            raise _BusFault(f"{name}: no valid status packet for the sync read of velocity and position "
                            f"({self._ph.getTxRxResult(result)})")
        self._port.is_using = False
        self._check_status(dxl_id, "sync read", error)
        if len(data) != READ_LENGTH:
            raise _BusFault(f"{name}: sync read returned {len(data)} bytes, expected {READ_LENGTH}")
        return data

    def _sample(self, command, goals, velocity, position, stale) -> WheelSample:
        self._cycle += 1
        self.stats.cycles += 1
        pose = self._odometer.update(*position)
        wheel = tuple(s.sign * raw_to_rad_s(v) for s, v in zip(self.servos, velocity))
        v_m_s, w_rad_s = self.kinematics.twist(*wheel)
        return WheelSample(self._cycle, self.now_s(), command[0], command[1], goals, velocity, position, wheel,
                           self._odometer.ticks, v_m_s, w_rad_s, pose, stale)

    def _latch(self, err: Exception) -> HardwareError:
        """A fault: stop the wheels where the bus still allows it, latch and return the error to raise."""
        self._port.is_using = False
        gone = isinstance(err, PORT_ERRORS)
        zeroed = False if gone else self._zero_goals()
        self.stats.faults += 1
        cause = f"the port failed ({err}); it may have been unplugged" if gone else str(err)
        after = ("the wheels were commanded to zero" if zeroed else
                 f"zero velocity could not be sent; the servos' bus watchdog stops them within "
                 f"{self.hw.watchdog_ms} ms")
        self._fault = HardwareError(f"{self._where()}: {cause}; {after}")
        log.error("%s", self._fault)
        return self._fault

    def read_state(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """One GroupSyncRead of Present Velocity and Present Position, writing nothing: ``((velocity left, right),
        (position left, right))`` in raw int32 units. A diagnostic probe: a bus fault raises :class:`HardwareError`
        but is not latched and stops nothing (:meth:`cycle` is the control path).
        """
        with self._bus_lock:
            if self._port is None:
                raise HardwareError(f"{self._where()}: the bridge is not open")
            try:
                return self._read_state()
            except (_BusFault, *PORT_ERRORS, *SDK_ERRORS) as err:
                self._port.is_using = False
                raise HardwareError(f"{self._where()}: {err}") from None

    def read_status(self) -> list[ServoStatus]:
        """Read each servo's health registers (between cycles; raises :class:`HardwareError` on a bus fault)."""
        out = []
        with self._bus_lock:
            if self._port is None:
                raise HardwareError(f"{self._where()}: the bridge is not open")
            try:
                for info in self.servos:
                    name, i = self._name(info.dxl_id), info.dxl_id
                    out.append(ServoStatus(
                        info.wheel, i,
                        torque_on=self._read(i, name, ct.ADDR_TORQUE_ENABLE, 1, "Torque Enable") == 1,
                        hardware_error=self._read(i, name, ct.ADDR_HARDWARE_ERROR, 1, "Hardware Error Status"),
                        watchdog_units=self._read(i, name, ct.ADDR_BUS_WATCHDOG, 1, "Bus Watchdog"),
                        velocity_limit_rad_s=raw_to_rad_s(self._read(i, name, ct.ADDR_VELOCITY_LIMIT, 4,
                                                                     "Velocity Limit")),
                        voltage_v=self._read(i, name, ct.ADDR_INPUT_VOLTAGE, 2, "Present Input Voltage") / 10,
                        temperature_c=self._read(i, name, ct.ADDR_TEMPERATURE, 1, "Present Temperature")))
            except (_BusFault, *PORT_ERRORS, *SDK_ERRORS) as err:
                raise self._latch(_BusFault(str(err)) if isinstance(err, SDK_ERRORS) else err) from None
        return out

    # ----------------------------------------------------------------------------------------- reconnect
    def reconnect(self) -> list[ServoInfo]:
        """Close the port and run the start-up sequence again; clears the latched fault. Odometry continues
        (motion during the outage is not counted)."""
        with self._bus_lock:
            self._close_port(torque_off=False)
            odometer = self._odometer
            servos = self.open()
            if odometer is not None:
                odometer.signs = (servos[0].sign, servos[1].sign)
                odometer.rebase()
                odometer.update(*self._read_state()[1])
                self._odometer = odometer
        with self._cmd_lock:
            self._command, self._fresh, self._missed = (0.0, 0.0), False, self.stale_after_cycles
        self.stats.reconnects += 1
        log.warning("%s: reconnected", self._where())
        return servos

    # ----------------------------------------------------------------------------------------------- close
    def close(self) -> None:
        """Stop the loop, zero the wheels, torque off, close the port. Safe to call twice; never raises."""
        self.stop_loop()
        with self._bus_lock:
            self._close_port(torque_off=True)

    def _close_port(self, torque_off: bool) -> None:
        port = self._port
        if port is None:
            return
        try:
            if torque_off:
                self._zero_goals()
                self._torque_off(port)
        finally:
            self._port, self._gsw, self._gsr = None, None, None
            try:
                port.closePort()
            except PORT_ERRORS:
                pass

    def _torque_off(self, port: _Port) -> None:
        for _, dxl_id in self._wheels:
            port.is_using = False
            try:
                result, _ = self._ph.write1ByteTxRx(port, dxl_id, ct.ADDR_TORQUE_ENABLE, 0)
            except (*PORT_ERRORS, *SDK_ERRORS) as err:
                port.is_using = False
                log.error("%s: torque off failed (%s)", self._where(), err)
                return
            if result != COMM_SUCCESS:
                log.error("%s: %s: torque off failed: %s", self._where(), self._name(dxl_id),
                          self._ph.getTxRxResult(result))

    # ------------------------------------------------------------------------------------------ loop thread
    def start(self) -> None:
        """Run :meth:`cycle` on a thread at the control rate; read results with :meth:`wait_samples`."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="dynamixel-bridge", daemon=True)
        self._thread.start()

    def stop_loop(self) -> None:
        """Stop the loop thread (the wheels keep their last goal until :meth:`close` or a new cycle)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0 + 4 * self.hw.latency_timer_ms / 1000)
            self._thread = None
        with self._cond:
            self._cond.notify_all()

    @property
    def wall_period_s(self) -> float:
        """Control period on the wall clock, s."""
        return self.period_s / self.time_scale

    def _loop(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            # Pace: deadline-based; a late cycle starts the next period now (an overrun)
            deadline += self.wall_period_s
            sample = self._loop_cycle()
            if sample is None:
                break
            with self._cond:
                self._samples.append(sample)
                self.latest = sample
                self._cond.notify_all()
            now = time.monotonic()
            if now > deadline:
                self.stats.overruns += 1
                deadline = now
            self._stop.wait(deadline - now)

    def _loop_cycle(self) -> WheelSample | None:
        """One cycle for the loop thread; None ends the loop (a fault that reconnecting did not clear)."""
        try:
            return self.cycle_or_recover(self._stop)
        except HardwareError:
            with self._cond:
                self._cond.notify_all()
            return None

    def cycle_or_recover(self, stop: threading.Event | None = None) -> WheelSample:
        """:meth:`cycle`; after a fault, up to ``hardware.reconnect_attempts`` reconnects (``reconnect_interval_s``
        apart) and a new cycle.

        Raises:
            HardwareError: the fault, when reconnecting is off or failed (or ``stop`` was set meanwhile).
        """
        try:
            return self.cycle()
        except HardwareError as fault:
            first = fault
        for attempt in range(1, self.hw.reconnect_attempts + 1):
            wait_s = self.hw.reconnect_interval_s / self.time_scale
            if stop is None:
                time.sleep(wait_s)
            elif stop.wait(wait_s):
                break
            try:
                self.reconnect()
                return self.cycle()
            except HardwareError as err:
                log.warning("%s: reconnect attempt %d/%d failed: %s", self._where(), attempt,
                            self.hw.reconnect_attempts, err)
                self._fault = self._fault or first
        raise HardwareError(str(first))

    def wait_samples(self, n: int, timeout_s: float | None = None) -> list[WheelSample]:
        """Block until the loop has made at least ``n`` samples since the last call; return them all, oldest first.

        Raises:
            HardwareError: the loop stopped on a fault, or no sample came within ``timeout_s`` (default: ``n``
                periods plus the reconnect budget plus 2 s).
        """
        if timeout_s is None:
            timeout_s = (n * self.wall_period_s + 2.0 + self.hw.reconnect_attempts
                         * (self.hw.reconnect_interval_s / self.time_scale + 1.0))
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while len(self._samples) < n:
                if self._fault is not None and not self._loop_alive():
                    raise HardwareError(str(self._fault))
                if not self._loop_alive():
                    raise HardwareError(f"{self._where()}: the control loop is not running")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise HardwareError(f"{self._where()}: no control cycle completed within {timeout_s:.2f} s")
                self._cond.wait(min(left, 0.1))
            out = list(self._samples)
            self._samples.clear()
        return out

    def drain(self) -> None:
        """Forget the samples made so far."""
        with self._cond:
            self._samples.clear()

    def _loop_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()


def reboot_servos(hardware: Hardware, port: str | None = None, settle_s: float = 1.0) -> None:
    """Send REBOOT to both wheel servos (clears a hardware error; the torque is off afterwards), then wait
    ``settle_s`` seconds for them to come back.

    Raises:
        HardwareError: the port cannot be opened or a servo does not acknowledge.
    """
    name = port or hardware.port
    handler, ph = _Port(name, hardware.latency_timer_ms), PacketHandler(2.0)
    try:
        handler.openPort()
        handler.setBaudRate(hardware.baud_rate)
    except PORT_ERRORS as err:
        raise HardwareError(f"cannot open the Dynamixel port '{name}': {err}") from None
    try:
        for dxl_id in hardware.ids:
            result, _ = ph.reboot(handler, dxl_id)
            if result != COMM_SUCCESS:
                raise HardwareError(f"Dynamixel bus '{name}': servo {dxl_id} did not acknowledge the reboot "
                                    f"({ph.getTxRxResult(result)})")
    finally:
        handler.closePort()
    time.sleep(settle_s)
