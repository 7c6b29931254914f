"""The virtual bus against the real dynamixel_sdk over a real pty: framing, the control table's access rules and
error statuses, instructions, the motor, the bus watchdog, hardware errors and the port vanishing."""

from __future__ import annotations

import termios

import pytest
import serial
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

from simnav.hardware import VirtualBus
from simnav.hardware import control_table as ct
from simnav.hardware.protocol import ALERT_BIT, ErrorCode, Instruction, instruction_packet
from tests.hardware.conftest import wait_until

PH = PacketHandler(2.0)


class PatientPort(PortHandler):
    """The SDK's port with a status timeout long enough for a loaded test machine."""

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = 400.0


@pytest.fixture
def port(bus):
    handler = PatientPort(bus.port)
    assert handler.openPort() and handler.setBaudRate(1_000_000)
    yield handler
    handler.closePort()


def test_ping_is_byte_exact_and_answers_the_model(bus, port):
    model, result, error = PH.ping(port, 1)
    assert (model, result, error) == (1060, COMM_SUCCESS, 0)
    assert bus.instructions()[0].raw == bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    firmware, result, _ = PH.read1ByteTxRx(port, 2, ct.ADDR_FIRMWARE)
    assert result == COMM_SUCCESS and firmware >= ct.MIN_WATCHDOG_FIRMWARE


def test_an_absent_id_stays_silent(bus):
    handler = PortHandler(bus.port)  # the SDK's own 34 ms timeout
    handler.openPort()
    try:
        assert PH.ping(handler, 7)[1] == COMM_RX_TIMEOUT
    finally:
        handler.closePort()


@pytest.mark.parametrize(("address", "size", "value", "error"), [
    (ct.ADDR_OPERATING_MODE, 1, 1, ErrorCode.ACCESS),       # EEPROM with torque on
    (ct.ADDR_PRESENT_POSITION, 4, 0, ErrorCode.ACCESS),     # read-only
    (ct.ADDR_GOAL_VELOCITY + 1, 1, 0, ErrorCode.ACCESS),    # starts inside an item
    (ct.ADDR_GOAL_VELOCITY, 2, 0, ErrorCode.DATA_LENGTH),   # part of an item
    (ct.ADDR_GOAL_VELOCITY, 4, 2000, ErrorCode.DATA_LIMIT),  # beyond the Velocity Limit (265)
    (ct.ADDR_BUS_WATCHDOG, 1, 200, ErrorCode.DATA_RANGE),   # 1..127
    (60, 1, 0, ErrorCode.ACCESS),                           # a gap in the table
])
def test_writes_follow_the_access_rules(bus, port, address, size, value, error):
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    before = bus.register(1, ct.ADDR_GOAL_VELOCITY)
    data = list((value & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))
    assert PH.writeTxRx(port, 1, address, size, data) == (COMM_SUCCESS, error)
    assert bus.register(1, ct.ADDR_GOAL_VELOCITY) == before


def test_eeprom_is_writable_with_torque_off_and_velocity_mode_moves_the_motor(bus, port):
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_OPERATING_MODE, 2) == (COMM_SUCCESS, ErrorCode.DATA_RANGE)
    for dxl_id in (1, 2):
        assert PH.write1ByteTxRx(port, dxl_id, ct.ADDR_OPERATING_MODE, 1) == (COMM_SUCCESS, 0)
        assert PH.write1ByteTxRx(port, dxl_id, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    writer = GroupSyncWrite(port, PH, ct.ADDR_GOAL_VELOCITY, 4)
    writer.addParam(1, list((100).to_bytes(4, "little", signed=True)))
    writer.addParam(2, list((-100).to_bytes(4, "little", signed=True)))
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupSyncRead(port, PH, ct.ADDR_PRESENT_VELOCITY, 8)
    reader.addParam(1)
    reader.addParam(2)

    def moved() -> bool:
        assert reader.txRxPacket() == COMM_SUCCESS
        position = reader.getData(1, ct.ADDR_PRESENT_POSITION, 4)
        return reader.getData(1, ct.ADDR_PRESENT_VELOCITY, 4) == 100 and 500 < position < 2**31

    wait_until(moved, what="servo 1 at +100 and moving")
    assert reader.getData(2, ct.ADDR_PRESENT_VELOCITY, 4) == 2**32 - 100  # -100, as the SDK returns it
    assert reader.getData(2, ct.ADDR_PRESENT_POSITION, 4) > 2**31  # negative: turning backwards


def test_parameters_containing_the_header_pattern(bus, port):
    # dynamixel-sdk 4.1.0 sends instruction packets unstuffed (txPacket drops addStuffing's result); the emulator
    # still decodes FF FF FD 00 inside the parameters (LEN tells where the packet ends)
    data, result, error = PH.readTxRx(port, 1, 0xFFFF, 0xFD)
    assert (result, error) == (COMM_SUCCESS, ErrorCode.ACCESS)
    assert bus.instructions()[-1].params == bytes.fromhex("FF FF FD 00")
    # a status packet whose data contains FF FF FD (Present Position 0x00FDFFFF) is stuffed; the SDK unstuffs it
    bus.set_position(1, 0x00FDFFFF)
    position, result, error = PH.read4ByteTxRx(port, 1, ct.ADDR_PRESENT_POSITION)
    assert (position, result, error) == (0x00FDFFFF, COMM_SUCCESS, 0)


def test_a_stuffed_instruction_is_unstuffed(bus):
    with serial.Serial(bus.port, timeout=2.0) as raw:
        raw.write(instruction_packet(1, Instruction.READ, bytes.fromhex("FF FF FD 00")))
        reply = raw.read(11)
    assert bus.instructions()[-1].params == bytes.fromhex("FF FF FD 00")
    assert reply[4] == 1 and reply[7:9] == bytes([Instruction.STATUS, ErrorCode.ACCESS])


def test_status_return_level_silences_replies(bus, port):
    quick = PortHandler(bus.port)  # the SDK's own timeout: these replies never come
    quick.openPort()
    try:
        assert PH.write1ByteTxRx(quick, 1, ct.ADDR_STATUS_RETURN_LEVEL, 1)[0] == COMM_RX_TIMEOUT  # applies at once
        assert PH.read1ByteTxRx(port, 1, ct.ADDR_STATUS_RETURN_LEVEL)[:2] == (1, COMM_SUCCESS)  # reads answered
        assert PH.write1ByteTxRx(quick, 1, ct.ADDR_LED, 1)[0] == COMM_RX_TIMEOUT  # writes not,
        assert bus.register(1, ct.ADDR_LED) == 1  # but carried out
        assert PH.write1ByteTxRx(quick, 1, ct.ADDR_STATUS_RETURN_LEVEL, 0)[0] == COMM_RX_TIMEOUT
        assert PH.read1ByteTxRx(quick, 1, ct.ADDR_LED)[1] == COMM_RX_TIMEOUT
        assert PH.ping(port, 1)[:2] == (1060, COMM_SUCCESS)  # ping always
    finally:
        quick.closePort()


def test_registered_write_waits_for_action(bus, port):
    assert PH.regWriteTxRx(port, 2, ct.ADDR_LED, 1, [1]) == (COMM_SUCCESS, 0)
    assert bus.register(2, ct.ADDR_LED) == 0 and bus.register(2, ct.ADDR_REGISTERED) == 1
    # the SDK sends ACTION without waiting for its status packet: the bus carries it out when it reads it
    assert PH.action(port, 2) == COMM_SUCCESS
    wait_until(lambda: bus.register(2, ct.ADDR_LED) == 1, what="the registered LED write applied")
    assert bus.register(2, ct.ADDR_REGISTERED) == 0
    assert PH.txRxPacket(port, [0] * 4 + [1, 3, 0, 0x7F] + [0, 0])[1:] == (COMM_SUCCESS, ErrorCode.INSTRUCTION)


def test_bus_watchdog_trips_and_clears(bus, port):
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_OPERATING_MODE, 1) == (COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    assert PH.write4ByteTxRx(port, 1, ct.ADDR_GOAL_VELOCITY, 50) == (COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_BUS_WATCHDOG, 1) == (COMM_SUCCESS, 0)  # 20 ms, then silence
    wait_until(lambda: bus.register(1, ct.ADDR_BUS_WATCHDOG) == ct.WATCHDOG_TRIPPED, what="the watchdog to trip")
    assert bus.register(1, ct.ADDR_GOAL_VELOCITY) == 0
    wait_until(lambda: bus.register(1, ct.ADDR_PRESENT_VELOCITY) == 0, what="the motor to stop")
    assert PH.write4ByteTxRx(port, 1, ct.ADDR_GOAL_VELOCITY, 50) == (COMM_SUCCESS, ErrorCode.DATA_RANGE)
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_BUS_WATCHDOG, 0) == (COMM_SUCCESS, 0)
    assert PH.write4ByteTxRx(port, 1, ct.ADDR_GOAL_VELOCITY, 50) == (COMM_SUCCESS, 0)


def test_hardware_error_alerts_stops_and_reboot_clears(bus, port):
    assert PH.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
    bus.raise_hardware_error(2, 0x20)  # overload: in Shutdown's default mask
    value, result, error = PH.read1ByteTxRx(port, 2, ct.ADDR_HARDWARE_ERROR)
    assert (value, result) == (0x20, COMM_SUCCESS) and error & ALERT_BIT
    assert bus.register(2, ct.ADDR_TORQUE_ENABLE) == 0
    assert PH.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 1)[1] == ALERT_BIT | ErrorCode.RESULT_FAIL
    assert PH.reboot(port, 2) == (COMM_SUCCESS, ALERT_BIT)  # acknowledged before restarting
    assert PH.read1ByteTxRx(port, 2, ct.ADDR_HARDWARE_ERROR) == (0, COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 2, ct.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)


def test_factory_reset_keeps_the_id_when_asked(bus, port):
    assert PH.write1ByteTxRx(port, 1, ct.ADDR_RETURN_DELAY, 0) == (COMM_SUCCESS, 0)
    assert PH.factoryReset(port, 1, 0x01) == (COMM_SUCCESS, 0)
    assert bus.register(1, ct.ADDR_RETURN_DELAY) == 250 and bus.register(1, ct.ADDR_ID) == 1


def test_the_port_vanishes_and_comes_back(tmp_path):
    with VirtualBus(ids=(1,), link=tmp_path / "ttyDXL") as bus:
        handler = PatientPort(bus.port)
        handler.openPort()
        assert PH.ping(handler, 1)[1] == COMM_SUCCESS
        bus.vanish()
        assert not (tmp_path / "ttyDXL").exists()
        with pytest.raises((serial.SerialException, OSError, termios.error)):
            for _ in range(3):
                PH.ping(handler, 1)
        handler.is_using = False
        handler.closePort()
        bus.reappear()
        handler = PatientPort(bus.port)
        handler.openPort()
        assert PH.ping(handler, 1)[:2] == (1060, COMM_SUCCESS)
        handler.closePort()
