"""The bridge with the real dynamixel_sdk over a pty against the virtual bus: start-up sequence and registers, (v, w)
to raw goals and signs, odometry across the position wrap-around, and the safety rules -- every injected fault ends
with zero goals at the next write and a clear error, never a hang; torque off on exit."""

from __future__ import annotations

import math
import time

import pytest

from simnav.hardware import DynamixelBridge, HardwareError, ReplyFault, VirtualBus
from simnav.hardware import control_table as ct
from simnav.hardware.bridge import reboot_servos
from simnav.hardware.protocol import Instruction
from tests.hardware.conftest import WATCHDOG_100_MS, minibot, wait_until

UNIT_RAD_S = 0.229 * 2 * math.pi / 60
R, HALF = 0.033, 0.08


def expected_raw(v: float, w: float, right_sign: int = -1) -> tuple[int, int]:
    """Minibot's raw goals: left forward-positive, right mirrored (negative forward) unless ``right_sign`` = 1."""
    return round((v - w * HALF) / R / UNIT_RAD_S), right_sign * round((v + w * HALF) / R / UNIT_RAD_S)


def drive(bridge, v: float, w: float, cycles: int, period_s: float = 0.0):
    samples = []
    for _ in range(cycles):
        bridge.command(v, w)
        samples.append(bridge.cycle())
        time.sleep(period_s)
    return samples


def goal(bus, dxl_id: int) -> int:
    return bus.register(dxl_id, ct.ADDR_GOAL_VELOCITY)


# ----------------------------------------------------------------------------------------------------- start-up
def test_start_up_sequence_and_registers(bus, make_bridge):
    bridge = make_bridge(minibot(WATCHDOG_100_MS))
    steps = [(p.dxl_id, p.instruction, p.params.hex(" ")) for p in bus.instructions()]
    per_servo = lambda i: [  # noqa: E731
        (i, Instruction.PING, ""),
        (i, Instruction.READ, "06 00 01 00"),                   # firmware
        (i, Instruction.WRITE, "40 00 00"),                     # torque off
        (i, Instruction.READ, "0a 00 01 00"),                   # drive mode
        (i, Instruction.READ, "0b 00 01 00"),                   # operating mode ...
        (i, Instruction.WRITE, "0b 00 01"),                     # ... velocity
        (i, Instruction.READ, "2c 00 04 00"),                   # velocity limit ...
        (i, Instruction.WRITE, "2c 00 24 01 00 00"),            # ... 292 = 7.0 rad/s
        (i, Instruction.WRITE, "62 00 00"),                     # bus watchdog cleared ...
        (i, Instruction.WRITE, "62 00 05"),                     # ... and armed: 5 x 20 ms
        (i, Instruction.WRITE, "68 00 00 00 00 00"),            # zero goal
        (i, Instruction.WRITE, "40 00 01"),                     # torque on
    ]
    assert steps == [*per_servo(1), *per_servo(2), (0xFE, Instruction.SYNC_READ, "80 00 08 00 01 02")]
    for dxl_id in (1, 2):
        assert bus.register(dxl_id, ct.ADDR_TORQUE_ENABLE) == 1
        assert bus.register(dxl_id, ct.ADDR_OPERATING_MODE) == ct.OPERATING_MODE_VELOCITY
        assert bus.register(dxl_id, ct.ADDR_VELOCITY_LIMIT) == 292
        assert bus.register(dxl_id, ct.ADDR_BUS_WATCHDOG) == 5
    assert [(s.wheel, s.dxl_id, s.model, s.sign) for s in bridge.servos] == \
        [("left", 1, "XL430-W250", 1), ("right", 2, "XL430-W250", -1)]


def test_a_configured_servo_gets_no_eeprom_writes(bus, make_bridge):
    make_bridge().close()
    since = time.monotonic()
    make_bridge()
    writes = {p.params[0] for p in bus.instructions(since) if p.instruction == Instruction.WRITE}
    assert ct.ADDR_OPERATING_MODE not in writes and ct.ADDR_VELOCITY_LIMIT not in writes


@pytest.mark.parametrize(("setup", "robot_overrides", "message"), [
    (lambda bus: bus.set_register(1, ct.ADDR_MODEL_NUMBER, 1030), (),
     "servo 1 (left wheel) is XM430-W210 (model number 1030), the robot's hardware.model is XL430-W250"),
    (lambda bus: None, ("hardware.right_id=3",), "servo 3 (right wheel) does not answer a ping"),
    (lambda bus: bus.set_register(2, ct.ADDR_FIRMWARE, 36), (), "servo 2 (right wheel) has firmware v36"),
    (lambda bus: bus.raise_hardware_error(1, 0x04), (), "servo 1 (left wheel) reports a hardware error (overheating)"),
])
def test_start_up_failures_are_one_clear_error(bus, setup, robot_overrides, message):
    setup(bus)
    robot = minibot(*robot_overrides)
    bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
    with pytest.raises(HardwareError, match="start-up failed") as err:
        bridge.open()
    assert message in str(err.value) and bus.port in str(err.value) and "minibot" in str(err.value)
    assert not bridge.is_open
    assert bus.register(1, ct.ADDR_TORQUE_ENABLE) == 0  # whatever was enabled is off again


def test_a_bad_port_is_one_clear_error(robot):
    bridge = DynamixelBridge(robot.hardware, robot.drive, port="/dev/no-such-dynamixel", robot=robot.name)
    with pytest.raises(HardwareError, match="cannot open the Dynamixel port '/dev/no-such-dynamixel' of robot "
                                            "'minibot'"):
        bridge.open()


# ---------------------------------------------------------------------------------------------- commanding
def test_a_command_gives_the_right_raw_goals_and_signs(bus, make_bridge):
    bridge = make_bridge()
    first = drive(bridge, 0.1, 0.5, 1)[0]
    assert first.goal_raw == expected_raw(0.025, 0.025 * 2 * math.pi)  # one period of acceleration: 1 m/s^2, 2 pi
    last = drive(bridge, 0.1, 0.5, 8)[-1]
    assert last.goal_raw == expected_raw(0.1, 0.5)
    assert (goal(bus, 1), goal(bus, 2)) == expected_raw(0.1, 0.5)
    assert last.goal_raw[0] > 0 and last.goal_raw[1] < 0  # forward: the mirrored right servo turns backwards
    spin = drive(bridge, 0.0, -1.0, 12)[-1]  # turning right: left wheel forward, right wheel backward
    assert spin.goal_raw == expected_raw(0.0, -1.0) and spin.goal_raw[0] > 0 and spin.goal_raw[1] > 0


def test_the_drive_mode_reverse_bit_is_respected(bus, make_bridge):
    bus.set_register(2, ct.ADDR_DRIVE_MODE, ct.DRIVE_MODE_REVERSE_BIT)  # set up like a TurtleBot3
    bridge = make_bridge()
    assert bridge.servos[1].drive_mode_reversed and bridge.servos[1].sign == 1
    assert drive(bridge, 0.1, 0.0, 8)[-1].goal_raw == expected_raw(0.1, 0.0, right_sign=1)


def test_wheel_speeds_are_clamped_keeping_the_curvature(make_bridge):
    bridge = make_bridge()
    sample = drive(bridge, 0.22, 2.79, 30)[-1]  # both at the drive limits: the right wheel would need 13 rad/s
    left, right = sample.goal_raw[0], -sample.goal_raw[1]
    assert right == 292  # Velocity Limit
    assert left / right == pytest.approx((0.22 - 2.79 * HALF) / (0.22 + 2.79 * HALF), abs=0.01)


def test_measured_velocities_and_odometry_across_the_wrap_around(bus, make_bridge):
    bus.set_position(1, 2**31 - 2500)
    bus.set_position(2, -(2**31) + 2500)  # mirrored: forward motion counts down through the wrap
    bridge = make_bridge()
    samples = drive(bridge, 0.2, 0.0, 20, period_s=bridge.period_s)
    while samples[-1].position_raw[0] > 0 and len(samples) < 2000:  # until both counters have wrapped
        samples += drive(bridge, 0.2, 0.0, 1, period_s=bridge.period_s)
    samples += drive(bridge, 0.2, 0.0, 10, period_s=bridge.period_s)
    wrapped = [s.position_raw for s in samples]
    assert wrapped[0][0] > 0 > wrapped[-1][0] and wrapped[0][1] < 0 < wrapped[-1][1]
    ticks = [s.wheel_ticks for s in samples]
    steps = [b[k] - a[k] for a, b in zip(ticks, ticks[1:]) for k in (0, 1)]
    assert min(steps) >= 0 and max(steps) < 1000  # forward all along, no jump at the wrap
    assert samples[-1].v_m_s == pytest.approx(0.2, abs=0.01) and samples[-1].w_rad_s == pytest.approx(0, abs=0.05)
    x, y, yaw = samples[-1].pose_xyt
    travelled = sum(ticks[-1]) / 2 / 4096 * 2 * math.pi * R
    assert ticks[-1][0] > 2500 and x == pytest.approx(travelled, rel=0.02) and abs(y) < 0.02 and abs(yaw) < 0.05


# ------------------------------------------------------------------------------------------------- safety
def test_no_fresh_command_for_two_periods_stops_the_wheels(bus, make_bridge):
    bridge = make_bridge()
    bridge.command(0.1, 0.0)
    samples = [bridge.cycle() for _ in range(3)]
    assert [s.stale for s in samples] == [False, False, True]
    assert samples[1].goal_raw[0] > 0 and samples[2].goal_raw == (0, 0)
    assert goal(bus, 1) == 0 and bridge.stats.stale_stops == 1
    assert drive(bridge, 0.1, 0.0, 1)[0].goal_raw[0] > 0  # a fresh command drives again


def test_the_control_thread_stops_the_wheels_without_fresh_commands(make_bridge):
    bridge = make_bridge()
    bridge.start()
    bridge.command(0.1, 0.0)
    samples = []
    while len(samples) < 8:
        samples += bridge.wait_samples(1)
    bridge.stop_loop()
    fresh = next(k for k, s in enumerate(samples) if s.command_v_m_s > 0)
    assert not samples[fresh + 1].stale and samples[fresh + 1].goal_raw[0] > 0
    assert all(s.stale and s.goal_raw == (0, 0) for s in samples[fresh + 2:])


@pytest.mark.parametrize(("v", "w"), [(math.nan, 0.0), (0.0, math.inf), (0.5, 0.0), (0.0, -6.0)])
def test_a_bad_command_stops_the_wheels_with_an_error(bus, make_bridge, v, w):
    bridge = make_bridge()
    assert drive(bridge, 0.1, 0.5, 6)[-1].goal_raw[0] != 0
    with pytest.raises(HardwareError, match=r"invalid velocity command v=.* expected finite values"):
        bridge.command(v, w)
    wait_until(lambda: (goal(bus, 1), goal(bus, 2)) == (0, 0), what="zero goals")  # a write gets no reply
    assert bridge.fault is None and drive(bridge, 0.1, 0.0, 1)[0].goal_raw[0] > 0  # not latched


def sync_writes(bus, t_s: float) -> list:
    return [p for p in bus.instructions(t_s) if p.instruction == Instruction.SYNC_WRITE]


def first_goals_after(bus, t_s: float) -> list[tuple[int, int]]:
    return [e.detail for e in bus.bus_events(t_s) if e.kind == "goal"][:2]


@pytest.mark.parametrize(("fault", "message"), [
    (ReplyFault.CORRUPT_CRC, "Incorrect status packet"),
    (ReplyFault.DROP_BYTES, "Incorrect status packet"),
    (ReplyFault.NO_REPLY, "There is no status packet"),
    (ReplyFault.DELAY, "There is no status packet"),
])
def test_every_reply_fault_stops_the_wheels_at_the_next_write(bus, make_bridge, fault, message):
    bridge = make_bridge()
    drive(bridge, 0.1, 0.5, 6)
    since = time.monotonic()
    bus.inject(fault, delay_s=1.5)  # longer than the status timeout (2 x 250 + 2 ms)
    with pytest.raises(HardwareError, match="sync read") as err:
        drive(bridge, 0.1, 0.5, 1)
    assert message in str(err.value) and "the wheels were commanded to zero" in str(err.value)
    wait_until(lambda: len(sync_writes(bus, since)) == 2, what="the write after the fault")
    writes = sync_writes(bus, since)  # the cycle's own, then the first write after the fault: zeros
    assert writes[1].params == bytes.fromhex("68 00 04 00 01 00 00 00 00 02 00 00 00 00")
    assert first_goals_after(bus, since) == [(1, 0), (2, 0)] and (goal(bus, 1), goal(bus, 2)) == (0, 0)
    with pytest.raises(HardwareError, match="sync read"):  # latched
        bridge.cycle()
    bridge.close()
    assert bus.register(1, ct.ADDR_TORQUE_ENABLE) == bus.register(2, ct.ADDR_TORQUE_ENABLE) == 0


def test_a_short_reply_delay_is_not_a_fault(bus, make_bridge):
    bridge = make_bridge()
    bus.inject(ReplyFault.DELAY, delay_s=0.05)
    assert drive(bridge, 0.1, 0.0, 3)[-1].goal_raw[0] > 0 and bridge.fault is None


def test_a_hardware_error_stops_the_wheels_with_its_cause(bus, make_bridge):
    bridge = make_bridge()
    drive(bridge, 0.1, 0.0, 6)
    bus.raise_hardware_error(2, 0x20)
    with pytest.raises(HardwareError, match=r"servo 2 \(right wheel\) reports a hardware error \(overload\)"):
        drive(bridge, 0.1, 0.0, 1)
    wait_until(lambda: (goal(bus, 1), goal(bus, 2)) == (0, 0), what="zero goals")
    assert bus.register(2, ct.ADDR_TORQUE_ENABLE) == 0
    bridge.close()
    reboot_servos(bridge.hw, bus.port, settle_s=0.0)
    assert bus.register(2, ct.ADDR_HARDWARE_ERROR) == 0


def test_a_vanished_port_is_an_error_and_the_watchdog_stops_the_wheels(tmp_path):
    robot = minibot(WATCHDOG_100_MS)
    with VirtualBus(robot.hardware.ids, link=tmp_path / "ttyDXL") as bus:
        bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
        with bridge:
            drive(bridge, 0.1, 0.0, 6)
            bus.vanish()
            with pytest.raises(HardwareError, match="may have been unplugged") as err:
                drive(bridge, 0.1, 0.0, 2)
            assert "bus watchdog stops them within 100 ms" in str(err.value)
            wait_until(lambda: all(bus.register(i, ct.ADDR_BUS_WATCHDOG) == ct.WATCHDOG_TRIPPED for i in (1, 2)),
                       what="the bus watchdogs to trip")
            wait_until(lambda: bus.register(1, ct.ADDR_PRESENT_VELOCITY) == 0, what="the wheels to stop")
        assert not bridge.is_open  # closing a vanished port neither hangs nor raises


def test_the_bridge_reconnects_when_the_port_comes_back(tmp_path):
    robot = minibot("hardware.reconnect_attempts=40", "hardware.reconnect_interval_s=0.05")
    with VirtualBus(robot.hardware.ids, link=tmp_path / "ttyDXL") as bus:
        with DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name) as bridge:
            bridge.start()
            bus.vanish()
            time.sleep(0.2)
            bus.reappear()
            wait_until(lambda: bridge.stats.reconnects >= 1, what="a reconnect")
            while bridge.wait_samples(1)[-1].stale:  # after a reconnect, only a fresh command moves the wheels
                bridge.command(0.1, 0.0)
            assert bus.register(1, ct.ADDR_TORQUE_ENABLE) == 1 and bridge.fault is None


def test_a_tripped_watchdog_is_re_armed(bus, make_bridge):
    bridge = make_bridge(minibot(WATCHDOG_100_MS))
    wait_until(lambda: bus.register(2, ct.ADDR_BUS_WATCHDOG) == ct.WATCHDOG_TRIPPED, what="the watchdog to trip")
    assert drive(bridge, 0.1, 0.0, 3)[-1].goal_raw[0] > 0
    assert bridge.stats.watchdog_rearms == 2 and bus.register(2, ct.ADDR_BUS_WATCHDOG) == 5 and goal(bus, 1) > 0


def test_torque_off_on_exit_also_on_ctrl_c(bus, robot):
    bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
    with pytest.raises(KeyboardInterrupt), bridge:
        drive(bridge, 0.1, 0.0, 6)
        assert bus.register(1, ct.ADDR_TORQUE_ENABLE) == 1 and goal(bus, 1) > 0
        raise KeyboardInterrupt
    for dxl_id in (1, 2):
        assert bus.register(dxl_id, ct.ADDR_TORQUE_ENABLE) == 0 and goal(bus, dxl_id) == 0
    bridge.close()  # twice is fine
