"""One emulated X-series servo: its control table with access rules and error statuses, a first-order motor in
velocity mode, the bus watchdog, hardware errors, reboot and factory reset.

Times are the emulator's clock in seconds (see :class:`simnav.hardware.virtual_bus.VirtualBus`). Values in the
table are raw Dynamixel units.
"""

from __future__ import annotations

import math

from simnav.hardware import control_table as ct
from simnav.hardware.protocol import ALERT_BIT, ErrorCode, from_le, le_bytes

GOAL_ITEMS = (ct.ADDR_GOAL_PWM, ct.ADDR_GOAL_CURRENT, ct.ADDR_GOAL_VELOCITY, ct.ADDR_GOAL_POSITION)
"""Items that become read-only (Data Range error) while the bus watchdog is tripped."""
CLEAR_MULTI_TURN_KEY = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
TICKS_PER_RAW_S = ct.VELOCITY_UNIT_RPM / 60 * ct.TICKS_PER_REV
"""Position ticks per second for one velocity unit."""
RAW_PER_S_PER_PROFILE_UNIT = ct.PROFILE_ACC_UNIT_RPM2 / 60 / ct.VELOCITY_UNIT_RPM
"""Velocity units per second of ramp for one Profile Acceleration unit."""


def wrap_int32(value: int) -> int:
    """An integer wrapped into the int32 range, as the servo's multi-turn Present Position wraps."""
    return ((value + 2**31) % 2**32) - 2**31


class EmulatedServo:
    """An XL430/XM430-like servo.

    Args:
        dxl_id: initial ID (register 7).
        model: a key of :data:`simnav.hardware.control_table.MODELS`.
        motor_time_constant_s: time constant of the velocity response to the goal, s.
        now_s: the emulator time at power-on, s.
    """

    def __init__(self, dxl_id: int, model: str = "XL430-W250", motor_time_constant_s: float = 0.04,
                 now_s: float = 0.0) -> None:
        self.table = ct.ControlTable.for_model(model)
        self.mem = bytearray(self.table.size)
        self.tau_s = motor_time_constant_s
        self._load_defaults(eeprom=True)
        self.set(ct.ADDR_ID, dxl_id)
        self.velocity_raw = 0.0  # present velocity, velocity units
        self.ramp_raw = 0.0  # velocity trajectory (profile-limited goal), velocity units
        self.position_ticks = 0.0  # multi-turn position before the homing offset, ticks
        self.registered: tuple[int, bytes] | None = None
        self.now_s = now_s
        self.last_packet_s = now_s

    # ------------------------------------------------------------------------------------------- registers
    @property
    def dxl_id(self) -> int:
        return self.mem[ct.ADDR_ID]

    def get(self, address: int) -> int:
        """The value of the item at ``address`` (signed items decoded)."""
        item = self.table.item_at(address)
        if item is None:
            raise KeyError(f"no control-table item starts at address {address}")
        return from_le(self.mem[address:item.end], item.signed)

    def set(self, address: int, value: int) -> None:
        """Store a value without any access check (the firmware's own writes, test set-up)."""
        item = self.table.item_at(address)
        if item is None:
            raise KeyError(f"no control-table item starts at address {address}")
        self.mem[address:item.end] = le_bytes(value, item.size)

    @property
    def torque_on(self) -> bool:
        return self.mem[ct.ADDR_TORQUE_ENABLE] == 1

    @property
    def watchdog_tripped(self) -> bool:
        return self.mem[ct.ADDR_BUS_WATCHDOG] == ct.WATCHDOG_TRIPPED

    @property
    def hardware_error(self) -> int:
        return self.mem[ct.ADDR_HARDWARE_ERROR]

    def error_byte(self, code: ErrorCode | int) -> int:
        """A status packet's error byte: ``code`` plus the alert bit while a hardware error is set."""
        return int(code) | (ALERT_BIT if self.hardware_error else 0)

    def _load_defaults(self, eeprom: bool, keep: tuple[int, ...] = ()) -> None:
        kept = {address: self.get(address) for address in keep}
        for item in self.table.items:
            if eeprom or not item.eeprom:
                self.mem[item.address:item.end] = le_bytes(item.default, item.size)
        for address, value in kept.items():
            self.set(address, value)

    # ------------------------------------------------------------------------------------------ read/write
    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """READ: ``(error code, data)``; any range inside the table may be read, gaps read as 0."""
        if length <= 0:
            return ErrorCode.DATA_LENGTH, b""
        if address < 0 or address + length > len(self.mem):
            return ErrorCode.ACCESS, b""
        return ErrorCode.NONE, bytes(self.mem[address:address + length])

    def write(self, address: int, data: bytes) -> int:
        """WRITE: check every item the data covers, then store all of it or nothing. Returns the error code."""
        items, error = self._items_covering(address, len(data))
        if error:
            return error
        values = []
        for item in items:
            value = from_le(data[item.address - address:item.end - address], item.signed)
            error = self._check_value(item, value)
            if error:
                return error
            values.append((item, value))
        for item, value in values:
            self._store(item, value)
        return ErrorCode.NONE

    def _items_covering(self, address: int, length: int) -> tuple[list[ct.Item], int]:
        if length <= 0:
            return [], ErrorCode.DATA_LENGTH
        items, pos, end = [], address, address + length
        while pos < end:
            item = self.table.item_at(pos)
            if item is None:
                return [], ErrorCode.ACCESS  # a gap, or a write starting inside an item
            if item.end > end:
                return [], ErrorCode.DATA_LENGTH  # part of an item
            items.append(item)
            pos = item.end
        return items, ErrorCode.NONE

    def _check_value(self, item: ct.Item, value: int) -> int:
        if not item.writable or (item.eeprom and self.torque_on):
            return ErrorCode.ACCESS
        if item.address in GOAL_ITEMS and self.watchdog_tripped:
            return ErrorCode.DATA_RANGE
        if item.address == ct.ADDR_GOAL_VELOCITY:
            return ErrorCode.DATA_LIMIT if abs(value) > self.get(ct.ADDR_VELOCITY_LIMIT) else ErrorCode.NONE
        if item.address == ct.ADDR_TORQUE_ENABLE and value == 1 and self.hardware_error:
            return ErrorCode.RESULT_FAIL
        if item.allowed:
            return ErrorCode.NONE if value in item.allowed else ErrorCode.DATA_RANGE
        return ErrorCode.NONE if item.low <= value <= item.high else ErrorCode.DATA_RANGE

    def _store(self, item: ct.Item, value: int) -> None:
        self.set(item.address, value)
        if item.address == ct.ADDR_BUS_WATCHDOG and value > 0:
            self.last_packet_s = self.now_s  # the watchdog counts from the moment it is armed

    def reg_write(self, address: int, data: bytes) -> int:
        """REG_WRITE: check now, apply on ACTION."""
        items, error = self._items_covering(address, len(data))
        if error:
            return error
        for item in items:
            error = self._check_value(item, from_le(data[item.address - address:item.end - address], item.signed))
            if error:
                return error
        self.registered = (address, bytes(data))
        self.mem[ct.ADDR_REGISTERED] = 1
        return ErrorCode.NONE

    def action(self) -> int:
        """ACTION: apply the registered write (Result Fail when none is registered)."""
        if self.registered is None:
            return ErrorCode.RESULT_FAIL
        address, data = self.registered
        self.registered = None
        self.mem[ct.ADDR_REGISTERED] = 0
        return self.write(address, data)

    # ------------------------------------------------------------------------------------------ lifecycle
    def reboot(self) -> None:
        """REBOOT: RAM back to defaults (hardware error cleared, torque off), position back within one turn."""
        self._load_defaults(eeprom=False)
        self.registered = None
        self.velocity_raw = self.ramp_raw = 0.0
        self.position_ticks = math.fmod(self.position_ticks, ct.TICKS_PER_REV)
        self.last_packet_s = self.now_s
        self._publish()

    def factory_reset(self, option: int) -> int:
        """FACTORY_RESET: 0xFF everything, 0x01 all but the ID, 0x02 all but the ID and the baud rate."""
        keep = {0xFF: (), 0x01: (ct.ADDR_ID,), 0x02: (ct.ADDR_ID, ct.ADDR_BAUD_RATE)}.get(option)
        if keep is None:
            return ErrorCode.DATA_RANGE
        self._load_defaults(eeprom=True, keep=keep)
        self.reboot()
        return ErrorCode.NONE

    def clear_multi_turn(self, key: bytes) -> int:
        """CLEAR (multi-turn): Present Position back within one turn; only while stopped."""
        if key != CLEAR_MULTI_TURN_KEY:
            return ErrorCode.DATA_RANGE
        if abs(self.velocity_raw) >= 0.5:
            return ErrorCode.RESULT_FAIL
        self.position_ticks = math.fmod(self.position_ticks, ct.TICKS_PER_REV)
        self._publish()
        return ErrorCode.NONE

    def raise_hardware_error(self, bits: int) -> None:
        """Set bits of register 70; a bit also set in Shutdown (63) turns the torque off."""
        self.mem[ct.ADDR_HARDWARE_ERROR] |= bits & 0xFF
        if bits & self.mem[ct.ADDR_SHUTDOWN]:
            self.mem[ct.ADDR_TORQUE_ENABLE] = 0

    def set_position(self, ticks: int) -> None:
        """Place the multi-turn position (test set-up, e.g. near the int32 wrap-around)."""
        self.position_ticks = float(ticks) - self.get(ct.ADDR_HOMING_OFFSET)
        self._publish()

    # ------------------------------------------------------------------------------------------ dynamics
    def heard(self, now_s: float) -> None:
        """An instruction packet for this servo arrived (feeds the bus watchdog)."""
        self.last_packet_s = now_s

    def advance(self, now_s: float) -> None:
        """Run the motor up to ``now_s`` (the watchdog is judged separately, after the packets that arrived)."""
        dt = max(now_s - self.now_s, 0.0)
        self.now_s = now_s
        # Motor: profile-limited goal, then a first-order velocity response; position integrates velocity
        driving = self.torque_on and self.mem[ct.ADDR_OPERATING_MODE] == ct.OPERATING_MODE_VELOCITY
        goal = float(self.get(ct.ADDR_GOAL_VELOCITY)) if driving else 0.0
        acc = self.get(ct.ADDR_PROFILE_ACCELERATION) * RAW_PER_S_PER_PROFILE_UNIT
        step = acc * dt if acc > 0 else math.inf
        self.ramp_raw += max(-step, min(step, goal - self.ramp_raw))
        v0 = self.velocity_raw
        self.velocity_raw = self.ramp_raw + (v0 - self.ramp_raw) * math.exp(-dt / self.tau_s)
        self.position_ticks += (v0 + self.velocity_raw) / 2 * TICKS_PER_RAW_S * dt
        self._publish()

    def check_watchdog(self, now_s: float) -> bool:
        """Bus watchdog: no instruction packet within value x 20 ms (torque on) -> stop, register 98 = 255.
        Returns whether it tripped now."""
        units = self.mem[ct.ADDR_BUS_WATCHDOG]
        if self.torque_on and 1 <= units <= 127 and now_s - self.last_packet_s > units * ct.WATCHDOG_UNIT_S:
            self.mem[ct.ADDR_BUS_WATCHDOG] = ct.WATCHDOG_TRIPPED
            self.set(ct.ADDR_GOAL_VELOCITY, 0)
            return True
        return False

    def _publish(self) -> None:
        """Present values into the table."""
        velocity = round(self.velocity_raw)
        self.set(ct.ADDR_PRESENT_VELOCITY, velocity)
        self.set(ct.ADDR_PRESENT_POSITION, wrap_int32(round(self.position_ticks) + self.get(ct.ADDR_HOMING_OFFSET)))
        self.set(ct.ADDR_VELOCITY_TRAJECTORY, round(self.ramp_raw))
        self.set(ct.ADDR_REALTIME_TICK, int(self.now_s * 1000) % 32768)
        self.set(ct.ADDR_MOVING, int(abs(velocity) > self.get(ct.ADDR_MOVING_THRESHOLD)))
        limit = max(self.get(ct.ADDR_VELOCITY_LIMIT), 1)
        self.set(ct.ADDR_PRESENT_PWM, max(-885, min(885, round(885 * self.velocity_raw / limit))))
