"""The Dynamixel X-series (430 family) control table, model numbers and raw units.

Addresses, sizes, access and defaults follow the ROBOTIS e-manual of the XL430-W250 and XM430-W210 (the model
files bundled with dynamixel-sdk 4.x carry the same addresses). Raw Dynamixel units live only in
:mod:`simnav.hardware`; everything outside it is SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

# Units
VELOCITY_UNIT_RPM = 0.229
"""One Goal/Present Velocity unit, rev/min (e-manual; the SDK's model files use 0.0239691 rad/s, 0.05 % less)."""
VELOCITY_UNIT_RAD_S = VELOCITY_UNIT_RPM * 2 * math.pi / 60
"""One velocity unit, rad/s (0.0239808)."""
TICKS_PER_REV = 4096
"""Present Position ticks per revolution (0.088 deg per tick)."""
PROFILE_ACC_UNIT_RPM2 = 214.577
"""One Profile Acceleration unit, rev/min^2."""
WATCHDOG_UNIT_S = 0.020
"""One Bus Watchdog unit, s."""
RETURN_DELAY_UNIT_S = 2e-6
"""One Return Delay Time unit, s."""
MIN_WATCHDOG_FIRMWARE = 38
"""The Bus Watchdog needs firmware v38 or later."""

# Addresses used by the bridge
ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY = 9
ADDR_DRIVE_MODE = 10
ADDR_OPERATING_MODE = 11
ADDR_HOMING_OFFSET = 20
ADDR_MOVING_THRESHOLD = 24
ADDR_VELOCITY_LIMIT = 44
ADDR_SHUTDOWN = 63
ADDR_TORQUE_ENABLE = 64
ADDR_LED = 65
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_REGISTERED = 69
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
ADDR_GOAL_PWM = 100
ADDR_GOAL_CURRENT = 102
ADDR_GOAL_VELOCITY = 104
ADDR_PROFILE_ACCELERATION = 108
ADDR_GOAL_POSITION = 116
ADDR_REALTIME_TICK = 120
ADDR_MOVING = 122
ADDR_MOVING_STATUS = 123
ADDR_PRESENT_PWM = 124
ADDR_PRESENT_LOAD = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
ADDR_VELOCITY_TRAJECTORY = 136
ADDR_POSITION_TRAJECTORY = 140
ADDR_INPUT_VOLTAGE = 144
ADDR_TEMPERATURE = 146

OPERATING_MODE_VELOCITY = 1
DRIVE_MODE_REVERSE_BIT = 0x01
WATCHDOG_TRIPPED = 0xFF
"""Register 98 reads 255 (-1) after the bus watchdog stopped the motor."""

HARDWARE_ERROR_BITS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}
"""Register 70 (Hardware Error Status) bits."""


def describe_hardware_error(bits: int) -> str:
    """Readable list of the set bits of register 70, e.g. ``'overload, overheating'``."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if bits & bit]
    return ", ".join(names) if names else f"unknown (0x{bits:02x})"


MODELS = {
    "XL430-W250": 1060,
    "XM430-W210": 1030,
    "XM430-W350": 1020,
    "XH430-W210": 1010,
    "XH430-W350": 1000,
    "XC430-W150": 1070,
    "XC430-W240": 1080,
}
"""X-series 430 servos with velocity mode and this control table: name -> Model Number (register 0)."""
MODEL_NAMES = {number: name for name, number in MODELS.items()}


@dataclass(frozen=True)
class Item:
    """One control-table item: address, size in bytes, access and the range a write must respect."""

    address: int
    size: int
    name: str
    writable: bool = True
    eeprom: bool = False
    default: int = 0
    low: int = 0
    high: int = 0
    signed: bool = False
    allowed: tuple[int, ...] = ()

    @property
    def end(self) -> int:
        return self.address + self.size


def _items(model: str) -> list[Item]:
    """The control table of ``model`` (XM servos add current items; defaults differ slightly)."""
    xm = model.startswith(("XM", "XH"))
    eeprom = [
        Item(0, 2, "Model Number", writable=False, eeprom=True, default=MODELS[model]),
        Item(2, 4, "Model Information", writable=False, eeprom=True),
        Item(6, 1, "Firmware Version", writable=False, eeprom=True, default=46),
        Item(7, 1, "ID", eeprom=True, default=1, high=252),
        Item(8, 1, "Baud Rate", eeprom=True, default=1, high=7),
        Item(9, 1, "Return Delay Time", eeprom=True, default=250, high=254),
        Item(10, 1, "Drive Mode", eeprom=True, high=13),
        Item(11, 1, "Operating Mode", eeprom=True, default=3, allowed=(0, 1, 3, 4, 5, 16) if xm else (1, 3, 4, 16)),
        Item(12, 1, "Secondary(Shadow) ID", eeprom=True, default=255, high=255),
        Item(13, 1, "Protocol Type", eeprom=True, default=2, allowed=(1, 2)),
        Item(20, 4, "Homing Offset", eeprom=True, low=-1044479, high=1044479, signed=True),
        Item(24, 4, "Moving Threshold", eeprom=True, default=10, high=1023),
        Item(31, 1, "Temperature Limit", eeprom=True, default=80 if xm else 72, high=100),
        Item(32, 2, "Max Voltage Limit", eeprom=True, default=160 if xm else 140, low=95 if xm else 60,
             high=160 if xm else 140),
        Item(34, 2, "Min Voltage Limit", eeprom=True, default=95 if xm else 60, low=95 if xm else 60,
             high=160 if xm else 140),
        Item(36, 2, "PWM Limit", eeprom=True, default=885, high=885),
    ]
    if xm:
        eeprom.append(Item(38, 2, "Current Limit", eeprom=True, default=1193, high=1193))
    eeprom += [
        Item(44, 4, "Velocity Limit", eeprom=True, default=330 if xm else 265, high=1023),
        Item(48, 4, "Max Position Limit", eeprom=True, default=4095, high=4095),
        Item(52, 4, "Min Position Limit", eeprom=True, high=4095),
        Item(63, 1, "Shutdown", eeprom=True, default=0x34, high=0x3D),
    ]
    ram = [
        Item(64, 1, "Torque Enable", high=1),
        Item(65, 1, "LED", high=1),
        Item(68, 1, "Status Return Level", default=2, high=2),
        Item(69, 1, "Registered Instruction", writable=False),
        Item(70, 1, "Hardware Error Status", writable=False),
        Item(76, 2, "Velocity I Gain", default=1920 if xm else 1000, high=16383),
        Item(78, 2, "Velocity P Gain", default=100, high=16383),
        Item(80, 2, "Position D Gain", default=0 if xm else 4000, high=16383),
        Item(82, 2, "Position I Gain", high=16383),
        Item(84, 2, "Position P Gain", default=800 if xm else 640, high=16383),
        Item(88, 2, "Feedforward 2nd Gain", high=16383),
        Item(90, 2, "Feedforward 1st Gain", high=16383),
        Item(98, 1, "Bus Watchdog", high=127),
        Item(100, 2, "Goal PWM", low=-885, high=885, signed=True),
    ]
    if xm:
        ram.append(Item(102, 2, "Goal Current", low=-1193, high=1193, signed=True))
    ram += [
        Item(104, 4, "Goal Velocity", low=-1023, high=1023, signed=True),
        Item(108, 4, "Profile Acceleration", high=32767),
        Item(112, 4, "Profile Velocity", high=32767),
        Item(116, 4, "Goal Position", low=0, high=4095),
        Item(120, 2, "Realtime Tick", writable=False),
        Item(122, 1, "Moving", writable=False),
        Item(123, 1, "Moving Status", writable=False),
        Item(124, 2, "Present PWM", writable=False, signed=True),
        Item(126, 2, "Present Current" if xm else "Present Load", writable=False, signed=True),
        Item(128, 4, "Present Velocity", writable=False, signed=True),
        Item(132, 4, "Present Position", writable=False, signed=True),
        Item(136, 4, "Velocity Trajectory", writable=False, signed=True),
        Item(140, 4, "Position Trajectory", writable=False, signed=True),
        Item(144, 2, "Present Input Voltage", writable=False, default=120),
        Item(146, 1, "Present Temperature", writable=False, default=30),
    ]
    return eeprom + ram


@dataclass(frozen=True)
class ControlTable:
    """The items of one model, indexed by address; ``size`` is the readable extent in bytes.

    The emulator covers addresses 0-146; the indirect address/data areas (168-251) are not emulated.
    """

    model: str
    items: tuple[Item, ...]

    @classmethod
    def for_model(cls, model: str) -> ControlTable:
        if model not in MODELS:
            raise ValueError(f"unknown Dynamixel model '{model}'; known: {sorted(MODELS)}")
        return cls(model, tuple(_items(model)))

    @property
    def size(self) -> int:
        return max(item.end for item in self.items)

    def item_at(self, address: int) -> Item | None:
        """The item starting at ``address`` (None inside an item or in a gap)."""
        return self._by_address.get(address)

    @cached_property
    def _by_address(self) -> dict[int, Item]:
        return {item.address: item for item in self.items}
