"""The dependency rule: geometry, odometry and navigation import nothing from mujoco, meshcat or dynamixel_sdk."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

PURE = ["simnav.geometry", "simnav.odometry", "simnav.navigation", "simnav.sensors.readings", "simnav.robot",
        "simnav.metrics", "simnav.agents", "simnav.io"]


def test_pure_packages_do_not_load_the_simulator():
    present = [name for name in PURE if importlib.util.find_spec(name) is not None]
    assert "simnav.geometry" in present and "simnav.odometry" in present
    code = (
        "import sys, importlib\n"
        f"for name in {present!r}: importlib.import_module(name)\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('mujoco', 'meshcat', 'dynamixel_sdk'))\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
