"""``simnav hw``: the bus check and the motion test on a virtual bus; one clear error (exit 2) on bad input."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
from typer.testing import CliRunner

import simnav.cli.hw  # noqa: F401  (registers the command)
from simnav.cli.app import app
from simnav.hardware import DynamixelBridge
from tests.hardware.conftest import minibot

runner = CliRunner()
PATIENT = ["--set", "hardware.latency_timer_ms=250"]


def test_check_and_motion_test_on_a_virtual_bus():
    result = runner.invoke(app, ["hw", "--virtual", "--once", "--motion", *PATIENT])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "virtual Dynamixel bus: /dev/pts/" in out and "simnav mission --hardware /dev/pts/" in out
    assert out.count("XL430-W250") == 3 and out.count("100 ms") == 2 and out.count("7.00 rad/s") == 2
    assert "sync write + sync read: median" in out
    x_m = float(out.split("wheel odometry x ")[1].split(" m")[0])
    assert 0.1 < x_m < 0.2  # 0.11 m/s for 1.5 s, then turning in place


def test_without_a_terminal_the_motion_test_is_not_run():
    result = runner.invoke(app, ["hw", "--virtual", "--once", "--reboot", *PATIENT])
    assert result.exit_code == 0, result.output
    assert "sync write + sync read" in result.output and "motion test" not in result.output


@pytest.mark.parametrize(("args", "message"), [
    (["--port", "/dev/no-such-dynamixel"], "cannot open the Dynamixel port '/dev/no-such-dynamixel'"),
    (["--robot", "giraff", "--virtual"], "robot 'giraff' has no 'hardware' block"),
    (["--port", "/dev/ttyUSB9", "--virtual"], "give --port or --virtual, not both"),
    (["--virtual", "--set", "hardware.watchdog_ms=30"], "watchdog_ms"),
])
def test_bad_input_is_one_clear_error(args, message):
    result = runner.invoke(app, ["hw", *args])
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output


def test_the_virtual_bus_serves_another_process_until_ctrl_c():
    # started with SIGINT ignored, as a child inherits it from a parent that ignores it (what full test runs showed):
    # Ctrl-C must still stop it
    code = "import simnav.cli.hw; from simnav.cli.app import app; app()"
    proc = subprocess.Popen([sys.executable, "-c", code, "hw", "--virtual", "--no-motion", *PATIENT],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        lines = []
        for line in proc.stdout:  # ends if the command dies
            lines.append(line)
            if line.startswith("serving the virtual bus on"):
                break
        port = lines[-1].split(" on ")[1].split(";")[0].strip()
        robot = minibot()
        with DynamixelBridge(robot.hardware, robot.drive, port=port, robot=robot.name) as bridge:
            bridge.command(0.1, 0.0)
            assert bridge.cycle().goal_raw[0] > 0
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "virtual bus stopped" in out
