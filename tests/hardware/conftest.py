"""Fixtures of the hardware tests: one virtual Dynamixel bus (a process behind a pty) per test module, reset to
factory state for every test, and the minibot's bridge on it.

The machine running the tests may be loaded: unless a test is about them, status timeouts are generous (latency
timer 250 ms) and the bus watchdog is 1 s, so that a stalled test or emulator process is not taken for a fault.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from simnav.hardware import DynamixelBridge, VirtualBus
from simnav.robot import load_robot
from simnav.robot.spec import RobotSpec

PATIENT = ["hardware.latency_timer_ms=250", "hardware.watchdog_ms=1000"]
WATCHDOG_100_MS = "hardware.watchdog_ms=100"  # the minibot's own


def minibot(*overrides: str) -> RobotSpec:
    """The minibot with patient status timeouts and watchdog (and any further overrides)."""
    return load_robot("minibot", [*PATIENT, *overrides])


def wait_until(predicate: Callable[[], bool], timeout_s: float = 5.0, what: str = "condition") -> None:
    """Poll ``predicate`` until it holds; fail (never hang) after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.01)


@pytest.fixture(scope="module")
def module_bus():
    with VirtualBus(ids=(1, 2)) as bus:
        yield bus


@pytest.fixture
def bus(module_bus):
    module_bus.reset()
    return module_bus


@pytest.fixture
def robot() -> RobotSpec:
    return minibot()


@pytest.fixture
def make_bridge(bus):
    """``make_bridge(robot=None, **kwargs)``: an open bridge on the bus, closed after the test."""
    made = []

    def make(robot: RobotSpec | None = None, **kwargs) -> DynamixelBridge:
        robot = robot or minibot()
        bridge = DynamixelBridge(robot.hardware, robot.drive, port=bus.port, robot=robot.name, **kwargs)
        made.append(bridge)
        bridge.open()
        return bridge

    yield make
    for bridge in made:
        bridge.close()
