"""Dynamixel hardware: the wheel-servo bridge, hardware in the loop, and a virtual Dynamixel bus.

- :class:`DynamixelBridge` drives a differential base whose wheels are X-series servos in velocity mode through the
  real ``dynamixel_sdk`` (Protocol 2.0): start-up checks, one sync write and one sync read per control period,
  wheel odometry, and the safety rules (stale commands, bad commands, bus faults, bus watchdog, torque off on exit).
- :func:`hardware_in_the_loop` gives :func:`simnav.mission.mission.run_mission` a robot whose base moves by what the
  real motors measure while the world and the sensors stay simulated.
- :class:`VirtualBus` emulates the servos byte-exactly behind a pseudo-terminal, with fault injection, so the real
  SDK runs against it without hardware (and in CI).

Raw Dynamixel units stay inside this package; everything it hands out is SI.
"""

from simnav.hardware.bridge import BridgeStats, DynamixelBridge, HardwareError, ServoInfo, WheelSample
from simnav.hardware.hil import VIRTUAL, HilRobot, hardware_in_the_loop, hardware_of
from simnav.hardware.kinematics import DiffDrive, TwistRamp, WheelOdometer
from simnav.hardware.virtual_bus import BusEmulator, RandomCorruption, ReplyFault, VirtualBus

__all__ = [
    "VIRTUAL",
    "BridgeStats",
    "BusEmulator",
    "DiffDrive",
    "DynamixelBridge",
    "HardwareError",
    "HilRobot",
    "RandomCorruption",
    "ReplyFault",
    "ServoInfo",
    "TwistRamp",
    "VirtualBus",
    "WheelOdometer",
    "WheelSample",
    "hardware_in_the_loop",
    "hardware_of",
]
