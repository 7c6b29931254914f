"""Hardware in the loop: the world and the sensors stay simulated; the robot's base moves by what the real wheel
motors measure.

:func:`hardware_in_the_loop` opens the bus (a real port, or a virtual bus it starts), runs the bridge's start-up and
control loop, and yields a robot factory for :func:`simnav.mission.mission.run_mission`. The robot it makes sends
the navigator's (v, w) to the motors; each control period it runs the bridge's cycles paced to real time, turns the
measured wheel velocities into (v, w), advances the simulator with them and hands over the simulated readings, with
the wheel-encoder readings replaced by the servos' own positions.

The bridge cycles in the mission's own thread: a bridge thread would compete with the simulation for the
interpreter lock and could miss its status packets. A mission that stalls (or dies) stops sending packets, and the
servos' bus watchdog stops the wheels; the next cycle re-arms it.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import replace
from typing import TYPE_CHECKING

from simnav.errors import SimnavError
from simnav.hardware import control_table as ct
from simnav.hardware.bridge import DynamixelBridge, HardwareError, WheelSample
from simnav.robot.spec import Hardware, RobotSpec
from simnav.sensors.readings import Reading, WheelTicks

if TYPE_CHECKING:
    from simnav.sim.simulator import Simulator

log = logging.getLogger(__name__)
VIRTUAL = "virtual"
"""The ``target`` that starts a virtual bus instead of opening a port."""


def hardware_of(robot: RobotSpec) -> Hardware:
    """The robot's ``hardware`` block, or one clear error naming the robot and the missing field."""
    if robot.hardware is None:
        raise SimnavError(f"robot '{robot.name}' has no 'hardware' block: hardware in the loop needs hardware.port, "
                          "hardware.left_id, hardware.right_id, ... (see robots/minibot.yaml)")
    return robot.hardware


@contextmanager
def hardware_in_the_loop(target: str, robot: RobotSpec, *,
                         time_scale: float = 1.0) -> Iterator[Callable[[Simulator], HilRobot]]:
    """Open the robot's Dynamixel wheels and yield a factory of hardware-in-the-loop robots.

    Args:
        target: a serial port path (e.g. ``/dev/ttyUSB0``) or ``"virtual"`` (a virtual bus with the robot's IDs
            and model, started here and stopped on exit).
        robot: the robot; its ``hardware`` block configures the bridge, its ``drive`` the kinematics and limits.
        time_scale: virtual bus only: run the servos' clock, the control loop and hence the simulation this many
            times faster than real time (for tests and CI; the motors' dynamics and the watchdog scale along).

    Yields:
        ``factory(sim) -> HilRobot``; the simulator's ``control_dt_s`` must be a whole multiple of the bridge's
        period ``1 / hardware.control_rate_hz``.

    On exit -- also on an exception or Ctrl-C -- the wheels get zero velocity, torque off, the port is closed and
    the virtual bus stopped.

    Raises:
        SimnavError: no ``hardware`` block, a port that cannot be opened, a failed start-up, a time scale with a
            real port.
    """
    hardware = hardware_of(robot)
    if time_scale != 1.0 and target != VIRTUAL:
        raise SimnavError(f"time_scale={time_scale} applies to the virtual bus only; real motors run in real time")
    if time_scale <= 0:
        raise SimnavError(f"time_scale must be > 0, got {time_scale}")
    with ExitStack() as stack:
        port = stack.enter_context(_virtual_port(hardware, time_scale)) if target == VIRTUAL else target
        bridge = DynamixelBridge(hardware, robot.drive, port=port, robot=robot.name, time_scale=time_scale)
        stack.enter_context(bridge)
        yield lambda sim: _make_robot(bridge, sim)


@contextmanager
def _virtual_port(hardware: Hardware, time_scale: float) -> Iterator[str]:
    from simnav.hardware.virtual_bus import VirtualBus

    bus = VirtualBus(hardware.ids, hardware.model, time_scale=time_scale)
    try:
        bus.start()
    except RuntimeError as err:
        raise SimnavError(f"cannot start the virtual Dynamixel bus: {err}") from None
    try:
        yield bus.port
    finally:
        bus.stop()


def _make_robot(bridge: DynamixelBridge, sim: Simulator) -> HilRobot:
    """The hardware-in-the-loop robot for ``sim``, after checking that the two clocks fit together."""
    dt_s, period_s = sim.config.control_dt_s, bridge.period_s
    ratio = dt_s / period_s
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6:
        raise SimnavError(f"hardware in the loop: the simulator's control period control_dt_s={dt_s:g} s must be a "
                          f"whole multiple of the bridge period 1/hardware.control_rate_hz = {period_s:g} s (robot "
                          f"'{bridge.robot}'); change --sim-set control_dt_s or hardware.control_rate_hz")
    return HilRobot(sim, bridge, round(ratio))


class HilRobot:
    """The robot interface on real wheels in a simulated world (see the module docstring).

    Args:
        sim: the simulator whose robot base follows the motors.
        bridge: an open bridge; this robot runs its cycles (its control thread is stopped).
        cycles_per_step: bridge periods per simulator control period.
    """

    def __init__(self, sim: Simulator, bridge: DynamixelBridge, cycles_per_step: int) -> None:
        bridge.stop_loop()
        self.sim = sim
        self.bridge = bridge
        self.cycles_per_step = cycles_per_step
        bridge.stale_after_cycles = 2 * cycles_per_step  # two of this robot's control periods
        self._origin = bridge.wheel_ticks
        self._ticks: list[tuple[float, int, int]] = [(sim.time_s, 0, 0)]  # (sim time, left, right) since start
        self._inbox: list[Reading] = []
        self._late_cycles = 0
        self._deadline: float | None = None

    @property
    def control_period_s(self) -> float:
        return self.sim.config.control_dt_s

    @property
    def wheel_ticks(self) -> tuple[int, int]:
        """The servos' forward ticks (left, right) since this robot was made (4096 per revolution)."""
        ticks = self.bridge.wheel_ticks
        return ticks[0] - self._origin[0], ticks[1] - self._origin[1]

    def now_s(self) -> float:
        return self.sim.time_s

    def send_velocity(self, v_m_s: float, w_rad_s: float) -> None:
        """Command the motors (clamped, acceleration-limited; NaN/inf/out of range stop them and raise)."""
        self.bridge.command(v_m_s, w_rad_s)

    def poll_readings(self) -> list[Reading]:
        out, self._inbox = self._inbox, []
        return out

    def wait_next_period(self) -> None:
        """Run the bridge's cycles of one control period, each at its time (real time times the time scale), then
        advance the simulator with the measured base velocity.

        Raises:
            HardwareError: a bus or servo fault (the wheels were stopped where possible).
        """
        samples = [self._paced_cycle() for _ in range(self.cycles_per_step)]
        # Measured base velocity over the period, then the simulator's step with it
        v_m_s = sum(s.v_m_s for s in samples) / len(samples)
        w_rad_s = sum(s.w_rad_s for s in samples) / len(samples)
        self._record_ticks(samples)
        readings = self.sim.step(v_m_s, w_rad_s, measured=True)
        # Wheel encoders: the servos' positions in place of the simulated ones
        self._inbox += [self._motor_ticks(r) if isinstance(r, WheelTicks) else r for r in readings]

    def _paced_cycle(self) -> WheelSample:
        """Sleep until the next cycle is due, then run it; a cycle later than one period restarts the clock."""
        now, period = time.monotonic(), self.bridge.wall_period_s
        self._deadline = now if self._deadline is None else self._deadline + period
        if now > self._deadline + period:
            self._late_cycles += 1
            if self._late_cycles in (1, 10, 100) or self._late_cycles % 1000 == 0:
                log.warning("hardware in the loop: %d control cycles late (the simulation or the host is slower "
                            "than real time)", self._late_cycles)
            self._deadline = now
        time.sleep(max(0.0, self._deadline - now))
        return self.bridge.cycle_or_recover()

    def _record_ticks(self, samples: list[WheelSample]) -> None:
        """Spread the period's samples evenly over the simulator's next control period."""
        t0, dt = self.sim.time_s, self.sim.config.control_dt_s
        for j, s in enumerate(samples, start=1):
            left, right = s.wheel_ticks[0] - self._origin[0], s.wheel_ticks[1] - self._origin[1]
            self._ticks.append((round(t0 + dt * j / len(samples), 9), left, right))
        del self._ticks[:-4096]

    def _motor_ticks(self, reading: WheelTicks) -> WheelTicks:
        """The reading with the servos' cumulative forward ticks at its stamp (linear between samples)."""
        stamps = [t for t, _, _ in self._ticks]
        k = bisect.bisect_right(stamps, reading.stamp_s)
        if k == 0:
            _, left, right = self._ticks[0]
        elif k == len(stamps):
            _, left, right = self._ticks[-1]
        else:
            (ta, la, ra), (tb, lb, rb) = self._ticks[k - 1], self._ticks[k]
            s = (reading.stamp_s - ta) / (tb - ta) if tb > ta else 1.0
            left, right = round(la + s * (lb - la)), round(ra + s * (rb - ra))
        return replace(reading, left_ticks=int(left), right_ticks=int(right), ticks_per_rev=ct.TICKS_PER_REV)

    def stop(self) -> None:
        """Command zero velocity (never raises: after a fault the bridge has stopped the wheels already)."""
        try:
            self.bridge.command(0.0, 0.0)
        except HardwareError as err:
            log.debug("stop after a fault: %s", err)

    def close(self) -> None:
        """Stop; the bus itself is closed by :func:`hardware_in_the_loop`."""
        self.stop()
