"""Random and corrupted packets through both receive paths: the emulator's (instruction packets) and the bridge's
(status packets through the real SDK). Nothing crashes, nothing hangs, nothing garbled is ever taken for data."""

from __future__ import annotations

import random
import threading
import time

import pytest
import serial

from simnav.hardware import DynamixelBridge, HardwareError, RandomCorruption
from simnav.hardware import control_table as ct
from simnav.hardware.protocol import BROADCAST_ID, HEADER, Instruction, crc16, instruction_packet
from tests.hardware.conftest import minibot, wait_until

PACKETS = 10_000
VOLATILE = set(range(ct.ADDR_REALTIME_TICK, ct.ADDR_TEMPERATURE + 1))  # present values and clocks


def contains_valid_frame(stream: bytes) -> bool:
    """Whether any header in ``stream`` starts a frame with a correct CRC."""
    k = stream.find(HEADER)
    while k >= 0:
        if k + 7 <= len(stream):
            end = k + 7 + (stream[k + 5] | stream[k + 6] << 8)
            crc_ok = end <= len(stream) and crc16(stream[k:end - 2]) == stream[end - 2] | stream[end - 1] << 8
            if end - k >= 10 and crc_ok:
                return True
        k = stream.find(HEADER, k + 1)
    return False


def corrupted_packet(rng: random.Random) -> bytes:
    """Random bytes, or a plausible instruction packet with flipped bits, lost, repeated or inserted bytes."""
    if rng.random() < 0.3:
        return rng.randbytes(rng.randint(1, 40))
    instruction = rng.choice(list(Instruction))
    packet = bytearray(instruction_packet(rng.choice([1, 2, 3, BROADCAST_ID]), instruction,
                                          rng.randbytes(rng.randint(0, 24))))
    while contains_valid_frame(bytes(packet)):  # a byte added after the CRC leaves the frame valid: go on
        k = rng.randrange(len(packet))
        action = rng.randrange(3)
        if action == 0:
            packet[k] ^= 1 << rng.randrange(8)
        elif action == 1:
            del packet[k]
        else:
            packet.insert(k, rng.randrange(256))
    return bytes(packet)


def reads(bridge: DynamixelBridge):
    try:
        return bridge.read_state()
    except HardwareError:
        return None


def open_despite_load(bridge: DynamixelBridge, attempts: int = 50) -> None:
    """Start-up with a deliberately short status timeout: a loaded machine may need a few tries."""
    for _ in range(attempts - 1):
        try:
            bridge.open()
            return
        except HardwareError:
            continue
    bridge.open()


def corrupted_stream(seed: int) -> tuple[list[bytes], int]:
    """``PACKETS`` corrupted packets without a single valid frame anywhere in their concatenation."""
    while True:
        rng = random.Random(seed)
        packets = [corrupted_packet(rng) for _ in range(PACKETS)]
        if not contains_valid_frame(b"".join(packets)):
            return packets, seed
        seed += 1


@pytest.mark.slow
def test_random_and_corrupted_instruction_packets_change_nothing(bus):
    packets, _ = corrupted_stream(seed=7)
    before = {i: bus.table(i) for i in (1, 2)}
    with serial.Serial(bus.port, timeout=0.1, write_timeout=10.0) as port:
        stop = threading.Event()
        drain = threading.Thread(target=lambda: [port.read(4096) for _ in iter(stop.is_set, True)], daemon=True)
        drain.start()  # the servos answer some of them (CRC errors): read those away
        rng = random.Random(1)
        for packet in packets:
            port.write(packet)
            if rng.random() < 0.01:
                time.sleep(0.06)  # now and then long enough for a half packet to be dropped
        stop.set()
        drain.join(timeout=2.0)
    # the emulator is alive and answers a clean ping once it has worked through the stream
    with serial.Serial(bus.port, timeout=0.5) as port:
        def answers() -> bool:
            port.reset_input_buffer()
            port.write(instruction_packet(1, Instruction.PING))
            return port.read(14)[7:8] == bytes([Instruction.STATUS])
        wait_until(answers, timeout_s=20.0, what="a ping answered after the stream")
    assert bus.get_crc_errors() > 1000
    for dxl_id in (1, 2):  # nothing written: no torque, no goal, no setting changed
        after = bus.table(dxl_id)
        assert [a for k, a in enumerate(after) if k not in VOLATILE] == \
               [b for k, b in enumerate(before[dxl_id]) if k not in VOLATILE]


@pytest.mark.slow
def test_corrupted_status_packets_never_pass_for_data(bus):
    robot = minibot("hardware.latency_timer_ms=0")  # a status timeout of about 2 ms: many timeouts to go through
    bus.set_position(1, 0x00FDFFFF)  # a stuffed status packet
    bus.set_position(2, -(2**31) + 5)
    for dxl_id in (1, 2):
        bus.set_register(dxl_id, ct.ADDR_RETURN_DELAY, 0)  # answers at once
    bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
    open_despite_load(bridge)
    try:
        truth = ((0, 0), (0x00FDFFFF, -(2**31) + 5))
        bus.set_reply_filter(RandomCorruption(probability=1.0, seed=3))
        good = bad = 0
        for _ in range(PACKETS // 2):  # two status packets per sync read, every one corrupted
            try:
                assert bridge.read_state() == truth
                good += 1
            except HardwareError as err:
                assert "Dynamixel bus" in str(err)
                bad += 1
        bus.set_reply_filter(None)
        assert bad > PACKETS // 4 and good > 0  # garbage before a header is skipped: those reads are fine
        wait_until(lambda: reads(bridge) == truth, what="a clean read")  # and the bus works as before
    finally:
        bridge.close()
    assert bus.register(1, ct.ADDR_GOAL_VELOCITY) == bus.register(2, ct.ADDR_GOAL_VELOCITY) == 0


def test_faults_at_random_never_drive_a_wheel_beyond_its_command(bus):
    robot = minibot("hardware.latency_timer_ms=20")
    limit = {1: 76, 2: 177}  # |raw goal| of (0.1 m/s, 0.5 rad/s) for the left and the right wheel
    since = time.monotonic()
    bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name)
    bus.set_reply_filter(RandomCorruption(probability=0.05, seed=11))
    faults = 0
    try:
        for _ in range(300):
            try:
                if bridge.fault is not None or not bridge.is_open:
                    bridge.reconnect()
                bridge.command(0.1, 0.5)
                bridge.cycle()
            except HardwareError:
                faults += 1
    finally:
        bus.set_reply_filter(None)
        bridge.close()
    goals = [e.detail for e in bus.bus_events(since) if e.kind == "goal"]
    assert faults > 0 and goals
    assert all(0 <= value <= limit[1] for i, value in goals if i == 1)
    assert all(-limit[2] <= value <= 0 for i, value in goals if i == 2)
