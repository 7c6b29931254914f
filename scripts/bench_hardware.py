"""Dynamixel bridge benchmarks on the virtual bus (the real dynamixel-sdk over a pty, two emulated XL430-W250).

1. Round trip of one control period -- one GroupSyncWrite of both goal velocities plus one GroupSyncRead of
   velocity and position -- through the bare SDK and through ``DynamixelBridge.cycle`` (limits, odometry),
   with the servos' factory Return Delay Time (250 x 2 us) and with 0: median, p99 and their ratios. (Timed with
   a long status timeout, so that a stall of the machine shows in the p99 rather than as a fault.)
2. Achievable control rate: back-to-back cycles per second, and the bridge's control thread at 40, 100 and 200 Hz
   (achieved rate, late cycles).
3. Time from a fault to zero velocity, in control periods (minibot: 40 Hz, 25 ms): the control thread drives at
   0.1 m/s, the fault is injected, and the emulator's log gives the time until both goal velocities are 0
   (written by the bridge, or by the servos' bus watchdog). Factory set-up: USB latency timer 16 ms as the SDK
   assumes (status timeout 34 ms) and the servos' Return Delay Time of 500 us; tuned: 1 ms (timeout 4 ms) and 0.
   A trial in which the bus fails before the fault (a loaded machine) is discarded and counted.

The emulator is a separate process on the same machine, so the figures include its scheduling; the script prints
the load average next to them.

    python scripts/bench_hardware.py [--cycles 2000] [--trials 5]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from collections.abc import Callable

from dynamixel_sdk import GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler
from rich.console import Console
from rich.table import Table

import simnav
from simnav.hardware import DynamixelBridge, HardwareError, ReplyFault, VirtualBus
from simnav.hardware import control_table as ct
from simnav.robot import load_robot

console = Console()


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


# ------------------------------------------------------------------------------------------------ round trip
PATIENT = ["hardware.latency_timer_ms=200"]
"""Round trips and rates are timed with a 402 ms status timeout: a stall of this (shared) machine then shows in the
p99 instead of ending the run; a successful round trip does not depend on the timeout."""


class PatientPort(PortHandler):
    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = 402.0


def bare_sdk_round_trips(port_name: str, cycles: int) -> list[float]:
    """Seconds per GroupSyncWrite(104, 4 B) + GroupSyncRead(128, 8 B) of ids 1 and 2 with the bare SDK."""
    port, ph = PatientPort(port_name), PacketHandler(2.0)
    port.openPort()
    writer, reader = GroupSyncWrite(port, ph, ct.ADDR_GOAL_VELOCITY, 4), GroupSyncRead(port, ph, 128, 8)
    for dxl_id in (1, 2):
        writer.addParam(dxl_id, [0, 0, 0, 0])
        reader.addParam(dxl_id)
    times = []
    for _ in range(cycles):
        t = time.perf_counter()
        writer.txPacket()
        if reader.txRxPacket() != 0:
            raise RuntimeError("a sync read failed")
        times.append(time.perf_counter() - t)
    port.closePort()
    return times


def bridge_round_trips(bridge: DynamixelBridge, cycles: int) -> list[float]:
    """Seconds per ``command`` + ``cycle`` (alternating small speeds, so goals change every period)."""
    times = []
    for k in range(cycles):
        t = time.perf_counter()
        bridge.command(0.05 * (k % 2), 0.0)
        bridge.cycle()
        times.append(time.perf_counter() - t)
    return times


def round_trip_rows(cycles: int) -> tuple[list[tuple[str, ...]], dict[int, float]]:
    robot = load_robot("minibot", PATIENT)
    rows, medians = [], {}
    for delay_us in (500, 0):
        with VirtualBus((1, 2), return_delay_us=delay_us) as bus:
            bare = bare_sdk_round_trips(bus.port, cycles)
            with DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name) as bridge:
                full = bridge_round_trips(bridge, cycles)
        medians[delay_us] = statistics.median(full)
        ratio = f"{statistics.median(full) / statistics.median(bare):.2f}x"
        for label, times in (("bare SDK", bare), ("DynamixelBridge.cycle", full)):
            rows.append((f"{label}, return delay {delay_us} us", f"{1e3 * statistics.median(times):.2f} ms",
                         f"{1e3 * percentile(times, 0.99):.2f} ms", ratio if times is full else ""))
    return rows, medians


# ---------------------------------------------------------------------------------------------- control rate
def loop_rate(rate_hz: float, seconds: float) -> tuple[float, int, int]:
    """The bridge's control thread at ``rate_hz`` for ``seconds``: (achieved Hz, cycles, late cycles)."""
    robot = load_robot("minibot", [f"hardware.control_rate_hz={rate_hz}", "hardware.watchdog_ms=200", *PATIENT])
    with VirtualBus((1, 2), return_delay_us=0) as bus:
        with DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name) as bridge:
            bridge.start()
            t0, cycles = time.monotonic(), 0
            while time.monotonic() - t0 < seconds:
                bridge.command(0.05, 0.0)
                cycles += len(bridge.wait_samples(1))
            elapsed = time.monotonic() - t0
            bridge.stop_loop()
            return cycles / elapsed, cycles, bridge.stats.overruns


# ---------------------------------------------------------------------------------------------------- faults
def time_to_zero(bus: VirtualBus, since: float) -> tuple[float, float] | None:
    """(fault time, time both goals are 0 after it) from the emulator's log, ``time.monotonic()`` seconds."""
    events = bus.bus_events(since)
    fault = next((e.t_wall_s for e in events if e.kind in ("fault", "vanished")), since)
    goals: dict[int, int] = {}
    for e in events:
        if e.kind == "goal":
            goals[e.detail[0]] = e.detail[1]
            if e.t_wall_s >= fault and goals.get(1) == 0 and goals.get(2) == 0:
                return fault, e.t_wall_s
    return None


def injectors() -> dict[str, Callable]:
    """Fault name -> f(bus, bridge) that causes it (and returns the fault time when the bus log cannot say)."""
    def stale(bus, bridge):
        bridge.command(0.1, 0.0)  # the last command; the commander falls silent
        return time.monotonic()

    def invalid(bus, bridge):
        t = time.monotonic()
        try:
            bridge.command(math.nan, 0.0)
        except HardwareError:
            pass
        return t

    return {
        "corrupted CRC": lambda bus, bridge: bus.inject(ReplyFault.CORRUPT_CRC),
        "dropped bytes": lambda bus, bridge: bus.inject(ReplyFault.DROP_BYTES, n_bytes=3),
        "missing reply": lambda bus, bridge: bus.inject(ReplyFault.NO_REPLY),
        "reply 0.5 s late": lambda bus, bridge: bus.inject(ReplyFault.DELAY, delay_s=0.5),
        "hardware error (overload)": lambda bus, bridge: bus.raise_hardware_error(2, 0x20),
        "NaN command": invalid,
        "no fresh command": stale,
        "port vanished (watchdog)": lambda bus, bridge: bus.vanish(),
    }


def open_despite_load(bridge: DynamixelBridge, attempts: int = 20) -> None:
    """Start-up (not measured here) with a short status timeout may need a few tries on a loaded machine."""
    for _ in range(attempts - 1):
        try:
            bridge.open()
            return
        except HardwareError:
            time.sleep(0.05)
    bridge.open()


SETUPS = {"factory": (16.0, 500), "tuned": (1.0, 0)}
"""USB latency timer (ms) and Return Delay Time (us): the SDK's assumption and the servos' default, and the pair
recommended for fast loops (sysfs latency_timer = 1, register 9 = 0)."""


class Spurious(Exception):
    """The bus failed before the fault was injected (a loaded machine): the trial does not count."""


def fault_trial(name: str, inject: Callable, setup: str) -> float | None:
    """Periods from the fault to zero goal velocity in one trial (None: never zero within 2 s)."""
    latency_ms, delay_us = SETUPS[setup]
    robot = load_robot("minibot", [f"hardware.latency_timer_ms={latency_ms}"])
    with VirtualBus((1, 2), return_delay_us=delay_us) as bus:
        bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
        open_despite_load(bridge)
        with bridge:
            bridge.start()
            try:
                for _ in range(10):
                    bridge.command(0.1, 0.0)
                    bridge.wait_samples(1)
            except HardwareError as err:
                raise Spurious from err
            since = time.monotonic()
            t_fault = inject(bus, bridge)
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                try:
                    if name not in ("no fresh command", "NaN command"):
                        bridge.command(0.1, 0.0)
                    bridge.wait_samples(1, timeout_s=0.2)
                except HardwareError:
                    time.sleep(0.01)
                hit = time_to_zero(bus, since)
                if hit is not None:
                    fault = t_fault if isinstance(t_fault, float) else hit[0]
                    return (hit[1] - fault) / robot.hardware.control_period_s
            return None


def fault_rows(trials: int) -> tuple[list[tuple[str, ...]], int]:
    rows, discarded = [], 0
    for name, inject in injectors().items():
        cells = [name]
        for setup in SETUPS:
            periods: list[float | None] = []
            while len(periods) < trials and discarded < 20 * trials:
                try:
                    periods.append(fault_trial(name, inject, setup))
                except Spurious:
                    discarded += 1
            done = [p for p in periods if p is not None]
            never = len(periods) - len(done)
            cells.append((f"{statistics.median(done):.2f} / {max(done):.2f}" if done else "")
                         + (f" ({never} never)" if never else ""))
        rows.append(tuple(cells))
    return rows, discarded


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=2000, help="round trips timed per configuration")
    parser.add_argument("--trials", type=int, default=5, help="trials per fault and latency timer")
    parser.add_argument("--rate-seconds", type=float, default=3.0, help="seconds per control-thread rate")
    args = parser.parse_args()
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    console.print(f"simnav {simnav.__version__}; {os.cpu_count()} CPUs, load average {load}")

    rows, medians = round_trip_rows(args.cycles)
    table = Table("sync write + sync read, 2 servos", "median", "p99", "bridge / bare SDK",
                  title=f"round trip over the virtual bus ({args.cycles} cycles each)")
    for row in rows:
        table.add_row(*row)
    table.add_row("return delay 500 us / 0 us (bridge)", f"{medians[500] / medians[0]:.2f}x", "", "")
    console.print(table)

    table = Table("control rate", "achieved", "cycles", "late cycles", title="achievable control rate")
    table.add_row("back-to-back cycles, return delay 500 us", f"{1 / medians[500]:.0f} Hz", "", "")
    table.add_row("back-to-back cycles, return delay 0", f"{1 / medians[0]:.0f} Hz", "", "")
    for rate_hz in (40.0, 100.0, 200.0):
        achieved, cycles, late = loop_rate(rate_hz, args.rate_seconds)
        table.add_row(f"control thread at {rate_hz:.0f} Hz", f"{achieved:.1f} Hz", str(cycles), str(late))
    console.print(table)

    table = Table("fault (control thread at 40 Hz, 0.1 m/s)", "factory: latency 16 ms, delay 500 us",
                  "tuned: latency 1 ms, delay 0",
                  title=f"fault to zero goal velocity, control periods of 25 ms: median / max of {args.trials}")
    rows, discarded = fault_rows(args.trials)
    for row in rows:
        table.add_row(*row)
    console.print(table)
    console.print(f"trials discarded (the bus failed before the fault was injected): {discarded}")
    console.print("load average after: " + ", ".join(f"{x:.1f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
