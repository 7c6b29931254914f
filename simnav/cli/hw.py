"""``simnav hw``: check a robot's Dynamixel wheel servos (or a virtual bus) and run a short motion test with live
readings (registered on the main app)."""

from __future__ import annotations

import signal
import statistics
import sys
import time
from contextlib import ExitStack
from typing import Annotated

import typer
from rich.table import Table

from simnav.cli.app import SetOption, app, console, err_console, user_errors

CHECK_CYCLES = 50
"""Zero-velocity cycles timed by the bus check."""
MOTION_STEPS = (("forward", 0.5, 0.0, 1.5), ("turn left", 0.0, 0.5, 1.5), ("stop", 0.0, 0.0, 0.75))
"""Motion test: (label, share of max v, share of max w, seconds)."""


@app.command()
@user_errors
def hw(
    port: Annotated[str | None, typer.Option(help="Serial port of the wheel servos (default: the robot's "
                                                  "hardware.port).", metavar="PATH")] = None,
    virtual: Annotated[bool, typer.Option("--virtual", help="Start a virtual Dynamixel bus (emulated servos on a "
                                                            "pseudo-terminal), print its port and check it; it then "
                                                            "serves until Ctrl-C (see --once).")] = False,
    robot: Annotated[str, typer.Option(help="Robot name (simnav robots) or YAML path; its hardware block.")
                     ] = "minibot",
    motion: Annotated[bool | None, typer.Option("--motion/--no-motion", help="Run the motion test without asking, "
                                                                             "or skip it (default: ask on a "
                                                                             "terminal).")] = None,
    once: Annotated[bool, typer.Option("--once", help="With --virtual: stop the bus after the check instead of "
                                                      "serving it.")] = False,
    reboot: Annotated[bool, typer.Option("--reboot", help="Reboot the servos first (clears a hardware error).")
                      ] = False,
    robot_set: SetOption = None,
) -> None:
    """Check the robot's Dynamixel wheels: start-up, registers, bus round trip; then an optional short motion test.

    The wheels turn during the motion test: lift the robot or clear the way.
    """
    from simnav.hardware import DynamixelBridge, hardware_of
    from simnav.hardware.bridge import reboot_servos
    from simnav.robot import load_robot

    if port is not None and virtual:
        raise typer.BadParameter("give --port or --virtual, not both")
    robot_spec = load_robot(robot, robot_set)
    hardware = hardware_of(robot_spec)
    with ExitStack() as stack:
        bus = stack.enter_context(_virtual_bus(hardware)) if virtual else None
        target = bus.port if bus is not None else (port or hardware.port)
        if bus is not None:
            console.print(f"virtual Dynamixel bus: [bold]{target}[/] (ids {hardware.left_id}, {hardware.right_id}, "
                          f"{hardware.model})", soft_wrap=True)
            console.print(f"use it with: simnav hw --port {target}  |  simnav mission --hardware {target}",
                          soft_wrap=True)
        if reboot:
            reboot_servos(hardware, target)
        with DynamixelBridge(hardware, robot_spec.drive, port=target, robot=robot_spec.name) as bridge:
            _print_check(bridge)
            if motion if motion is not None else _ask():
                _motion_test(bridge)
        if bus is not None and not once:
            _serve(target)


def _virtual_bus(hardware):
    from simnav.errors import SimnavError
    from simnav.hardware import VirtualBus

    bus = VirtualBus(hardware.ids, hardware.model)
    try:
        bus.start()
    except RuntimeError as err:
        raise SimnavError(f"cannot start the virtual Dynamixel bus: {err}") from None
    return bus


def _print_check(bridge) -> None:
    """Servo table and the round trip of one control cycle (zero velocity)."""
    times = []
    for _ in range(CHECK_CYCLES):
        t = time.perf_counter()
        bridge.command(0.0, 0.0)
        bridge.cycle()
        times.append(time.perf_counter() - t)
    statuses = bridge.read_status()
    table = Table("", *(f"{info.wheel} wheel (id {info.dxl_id})" for info in bridge.servos),
                  title=f"Dynamixel bus {bridge.port_name}")
    rows = {
        "model": [info.model for info in bridge.servos],
        "firmware": [f"v{info.firmware}" for info in bridge.servos],
        "forward is": [("negative" if info.sign < 0 else "positive")
                       + (" (drive mode reverse)" if info.drive_mode_reversed else "") for info in bridge.servos],
        "torque": ["on" if st.torque_on else "off" for st in statuses],
        "bus watchdog": [f"{st.watchdog_units * 20} ms" for st in statuses],
        "velocity limit": [f"{st.velocity_limit_rad_s:.2f} rad/s" for st in statuses],
        "supply": [f"{st.voltage_v:.1f} V" for st in statuses],
        "temperature": [f"{st.temperature_c} C" for st in statuses],
        "hardware error": ["none" if not st.hardware_error else _hardware_error(st.hardware_error)
                           for st in statuses],
    }
    for name, values in rows.items():
        table.add_row(name, *values)
    console.print(table)
    times.sort()
    median = statistics.median(times)
    p99 = times[min(len(times) - 1, round(0.99 * (len(times) - 1)))]
    console.print(f"sync write + sync read: median {median * 1e3:.2f} ms, p99 {p99 * 1e3:.2f} ms over {len(times)} "
                  f"cycles (at most {1 / median:.0f} Hz; control rate {bridge.hw.control_rate_hz:g} Hz)")


def _hardware_error(bits: int) -> str:
    from simnav.hardware.control_table import describe_hardware_error

    return f"[red]{describe_hardware_error(bits)}[/]"


def _ask() -> bool:
    if not sys.stdin.isatty():
        return False
    return typer.confirm("Run the motion test? The wheels will turn (lift the robot or clear the way)", default=False)


def _motion_test(bridge) -> None:
    """Drive a short sequence on the bridge's control thread while showing live readings."""
    from rich.live import Live

    drive = bridge.drive
    bridge.start()
    try:
        with Live(console=err_console, refresh_per_second=10, transient=True) as live:
            for label, v_share, w_share, duration_s in MOTION_STEPS:
                v, w = v_share * drive.max_v_m_s, w_share * drive.max_w_rad_s
                end = time.monotonic() + duration_s
                while time.monotonic() < end:  # a fresh command every control period
                    bridge.command(v, w)
                    bridge.wait_samples(1)
                    live.update(_live_table(label, bridge.latest))
    finally:
        bridge.stop_loop()
    last = bridge.latest
    x, y, yaw = last.pose_xyt
    console.print(f"motion test: wheel odometry x {x:.3f} m, y {y:.3f} m, yaw {yaw * 57.29578:.1f} deg after "
                  f"{last.cycle} cycles; {bridge.stats.overruns} late cycles, {bridge.stats.watchdog_rearms} "
                  "watchdog re-arms")


def _live_table(label: str, s) -> Table:
    table = Table("step", "command v / w", "goal (raw)", "wheels (rad/s)", "measured v / w", "odometry x, y, yaw",
                  title="motion test")
    table.add_row(label, f"{s.command_v_m_s:.2f} m/s / {s.command_w_rad_s:.2f} rad/s", f"{s.goal_raw}",
                  f"{s.wheel_rad_s[0]:.2f}, {s.wheel_rad_s[1]:.2f}", f"{s.v_m_s:.2f} m/s / {s.w_rad_s:.2f} rad/s",
                  f"{s.pose_xyt[0]:.2f} m, {s.pose_xyt[1]:.2f} m, {s.pose_xyt[2] * 57.29578:.0f} deg")
    return table


def _serve(port: str) -> None:
    # Ctrl-C stops the bus even when this process was started with SIGINT ignored (inherited from its parent)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    console.print(f"serving the virtual bus on [bold]{port}[/]; Ctrl-C to stop")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        console.print("virtual bus stopped")
