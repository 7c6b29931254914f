"""Odometry: estimates of the robot's motion from its own sensors (numpy, with numba kernels for range flow; no
simulator imports)."""

from __future__ import annotations

import importlib

from simnav.errors import UnknownNameError
from simnav.odometry.base import (
    CameraOdometryEstimate,
    FrameOdometry,
    OdometryEstimate,
    PlanarScan,
    ScanOdometry,
    laser_to_base_motion,
    planar_scan,
)
from simnav.odometry.wheels import WheelOdometry

SCAN_ODOMETRIES = {"rf2o": "simnav.odometry.rf2o:RF2O", "srf": "simnav.odometry.srf:SRFOdometry"}


def make_scan_odometry(name: str, **config) -> ScanOdometry:
    """A scan odometry by name (``rf2o``, ``srf``), configured with keyword arguments of its config class."""
    if name not in SCAN_ODOMETRIES:
        raise UnknownNameError(f"unknown scan odometry '{name}'; available: {', '.join(sorted(SCAN_ODOMETRIES))}")
    module, cls = SCAN_ODOMETRIES[name].split(":")
    return getattr(importlib.import_module(module), cls)(**config)


__all__ = ["CameraOdometryEstimate", "FrameOdometry", "OdometryEstimate",
           "PlanarScan", "ScanOdometry", "WheelOdometry", "laser_to_base_motion",
           "make_scan_odometry", "planar_scan"]
