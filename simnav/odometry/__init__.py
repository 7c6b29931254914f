"""Odometry: estimates of the robot's motion from its own sensors (numpy, with numba kernels for range flow; no
simulator imports).

Planar scan odometries (:data:`SCAN_ODOMETRIES`, :func:`make_scan_odometry`) and depth / RGB-D frame odometries
(:data:`FRAME_ODOMETRIES`, :func:`make_frame_odometry`) are made by name. The numba-heavy modules load on demand:
``simnav.odometry.DIFODO``, ``DifodoConfig``, ``JointVOSF`` and ``VOSFConfig`` are imported at first access.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:
    from simnav.odometry.difodo import DIFODO, DifodoConfig
    from simnav.odometry.vosf import JointVOSF, VOSFConfig

SCAN_ODOMETRIES = {"rf2o": "simnav.odometry.rf2o:RF2O", "srf": "simnav.odometry.srf:SRFOdometry"}
"""Planar scan odometries by name: ``"module:Class"``; the class takes its config fields as keyword arguments."""

FRAME_ODOMETRIES = {"difodo": "simnav.odometry.difodo:DIFODO", "vosf": "simnav.odometry.vosf:JointVOSF"}
"""Depth / RGB-D frame odometries by name: ``"module:Class"``; the class takes its config fields as keyword
arguments (DIFODO: :class:`~simnav.odometry.difodo.DifodoConfig`, Joint-VO-SF:
:class:`~simnav.odometry.vosf.VOSFConfig`)."""

_LAZY = {"DIFODO": "simnav.odometry.difodo", "DifodoConfig": "simnav.odometry.difodo",
         "JointVOSF": "simnav.odometry.vosf", "VOSFConfig": "simnav.odometry.vosf"}


def make_scan_odometry(name: str, **config) -> ScanOdometry:
    """A scan odometry by name (``rf2o``, ``srf``), configured with keyword arguments of its config class."""
    if name not in SCAN_ODOMETRIES:
        raise UnknownNameError(f"unknown scan odometry '{name}'; available: {', '.join(sorted(SCAN_ODOMETRIES))}")
    module, cls = SCAN_ODOMETRIES[name].split(":")
    return getattr(importlib.import_module(module), cls)(**config)


def make_frame_odometry(name: str, **config) -> FrameOdometry:
    """A depth / RGB-D odometry by name, configured with keyword arguments of its config class.

    Args:
        name: ``difodo`` (depth only, :class:`~simnav.odometry.difodo.DIFODO`) or ``vosf`` (RGB-D, odometry and
            scene flow, :class:`~simnav.odometry.vosf.JointVOSF`).
        **config: fields of its config class, e.g. ``make_frame_odometry("difodo", max_rows=120)`` for QQVGA.

    Returns:
        A fresh :class:`~simnav.odometry.base.FrameOdometry`: feed frames with ``process(frame)``.

    Raises:
        UnknownNameError: ``name`` is not in :data:`FRAME_ODOMETRIES` (the message lists the available ones).
        ConfigError: an unknown field or an invalid value.
        ImportError: the method's module is not installed.
    """
    if name not in FRAME_ODOMETRIES:
        raise UnknownNameError(f"unknown frame odometry '{name}'; available: {', '.join(sorted(FRAME_ODOMETRIES))}")
    module, cls = FRAME_ODOMETRIES[name].split(":")
    return getattr(importlib.import_module(module), cls)(**config)


def __getattr__(name: str) -> Any:
    """Loads DIFODO and Joint-VO-SF (numba kernels) at first access."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = ["DIFODO", "FRAME_ODOMETRIES", "SCAN_ODOMETRIES", "CameraOdometryEstimate", "DifodoConfig",
           "FrameOdometry", "JointVOSF", "OdometryEstimate", "PlanarScan", "ScanOdometry", "VOSFConfig",
           "WheelOdometry", "laser_to_base_motion", "make_frame_odometry", "make_scan_odometry", "planar_scan"]
