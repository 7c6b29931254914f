"""Sensor presets: datasheet values of common scanners and depth cameras.

A robot YAML names a preset and overrides only what differs (``preset: hokuyo_utm30lx`` + ``max_range_m: 20``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simnav.errors import UnknownNameError


@dataclass(frozen=True)
class Lidar2DPreset:
    beams: int
    fov_deg: float
    max_range_m: float
    min_range_m: float
    rate_hz: float


@dataclass(frozen=True)
class Lidar3DPreset:
    rings: int
    columns: int
    vertical_fov_deg: tuple[float, float]
    max_range_m: float
    rate_hz: float


@dataclass(frozen=True)
class RGBDPreset:
    width: int
    height: int
    fovy_deg: float
    min_range_m: float
    max_range_m: float
    rate_hz: float
    noise_k_per_m: float  # axial noise sigma_z = k * z^2 (Khoshelham & Elberink 2012: ~1.4 mm at 1 m)


LIDAR2D_PRESETS: dict[str, Lidar2DPreset] = {
    "hokuyo_urg04lx": Lidar2DPreset(beams=682, fov_deg=240.0, max_range_m=5.6, min_range_m=0.02, rate_hz=10.0),
    "hokuyo_utm30lx": Lidar2DPreset(beams=1080, fov_deg=270.0, max_range_m=30.0, min_range_m=0.1, rate_hz=40.0),
    "sick_lms200": Lidar2DPreset(beams=361, fov_deg=180.0, max_range_m=80.0, min_range_m=0.1, rate_hz=37.5),
    "lds01": Lidar2DPreset(beams=360, fov_deg=360.0, max_range_m=3.5, min_range_m=0.12, rate_hz=5.0),
}

LIDAR3D_PRESETS: dict[str, Lidar3DPreset] = {
    "vlp16": Lidar3DPreset(rings=16, columns=1800, vertical_fov_deg=(-15.0, 15.0), max_range_m=100.0, rate_hz=10.0),
    "vlp16_low": Lidar3DPreset(rings=16, columns=450, vertical_fov_deg=(-15.0, 15.0), max_range_m=100.0, rate_hz=10.0),
}

RGBD_PRESETS: dict[str, RGBDPreset] = {
    "kinect_vga": RGBDPreset(640, 480, 45.6, 0.5, 4.5, 30.0, 1.425e-3),
    "kinect_qvga": RGBDPreset(320, 240, 45.6, 0.5, 4.5, 30.0, 1.425e-3),
    "kinect_qqvga": RGBDPreset(160, 120, 45.6, 0.5, 4.5, 30.0, 1.425e-3),
    "carmine_109": RGBDPreset(320, 240, 45.0, 0.35, 3.0, 30.0, 1.2e-3),
}


def lookup(table: dict, name: str, kind: str):
    """The preset ``name`` from ``table``; an unknown name lists the available ones."""
    try:
        return table[name]
    except KeyError:
        raise UnknownNameError(f"unknown {kind} preset '{name}'; available: {', '.join(sorted(table))}") from None


@dataclass(frozen=True)
class Lidar2DParams:
    """A planar scanner with every value resolved (preset + overrides)."""

    beams: int
    fov_rad: float
    max_range_m: float
    min_range_m: float
    rate_hz: float
    noise_std_m: float
    dropout_prob: float
    latency_s: float

    def angles_rad(self) -> np.ndarray:
        """(beams,) beam angles in the sensor frame, centred on +x, counter-clockwise increasing.

        A 360-degree scanner does not repeat its first beam at the end.
        """
        full_circle = self.fov_rad >= 2 * np.pi - 1e-9
        step = self.fov_rad / (self.beams if full_circle else self.beams - 1)
        return -self.fov_rad / 2 + step * np.arange(self.beams) + (step / 2 if full_circle else 0.0)


@dataclass(frozen=True)
class Lidar3DParams:
    rings: int
    columns: int
    vertical_fov_rad: tuple[float, float]
    max_range_m: float
    rate_hz: float
    noise_std_m: float
    dropout_prob: float
    latency_s: float


@dataclass(frozen=True)
class RGBDParams:
    width: int
    height: int
    fovy_deg: float
    min_range_m: float
    max_range_m: float
    rate_hz: float
    noise_k_per_m: float
    depth_quantum_m: float
    grazing_angle_rad: float
    dropout_prob: float
    rgb: bool
    latency_s: float


def _pick(value, default):
    return default if value is None else value


def resolve_lidar2d(sensor) -> Lidar2DParams:
    """Merge a :class:`simnav.robot.spec.Lidar2DSensor` with its preset."""
    p = lookup(LIDAR2D_PRESETS, sensor.preset, "lidar2d")
    return Lidar2DParams(
        beams=_pick(sensor.beams, p.beams), fov_rad=math.radians(_pick(sensor.fov_deg, p.fov_deg)),
        max_range_m=_pick(sensor.max_range_m, p.max_range_m), min_range_m=_pick(sensor.min_range_m, p.min_range_m),
        rate_hz=_pick(sensor.rate_hz, p.rate_hz), noise_std_m=sensor.noise_std_m, dropout_prob=sensor.dropout_prob,
        latency_s=sensor.latency_s,
    )


def resolve_lidar3d(sensor) -> Lidar3DParams:
    """Merge a :class:`simnav.robot.spec.Lidar3DSensor` with its preset."""
    p = lookup(LIDAR3D_PRESETS, sensor.preset, "lidar3d")
    lo, hi = _pick(sensor.vertical_fov_deg, p.vertical_fov_deg)
    return Lidar3DParams(
        rings=_pick(sensor.rings, p.rings), columns=_pick(sensor.columns, p.columns),
        vertical_fov_rad=(math.radians(lo), math.radians(hi)), max_range_m=_pick(sensor.max_range_m, p.max_range_m),
        rate_hz=_pick(sensor.rate_hz, p.rate_hz), noise_std_m=sensor.noise_std_m, dropout_prob=sensor.dropout_prob,
        latency_s=sensor.latency_s,
    )


def resolve_rgbd(sensor) -> RGBDParams:
    """Merge a :class:`simnav.robot.spec.RGBDSensor` with its preset."""
    p = lookup(RGBD_PRESETS, sensor.preset, "rgbd")
    return RGBDParams(
        width=_pick(sensor.width, p.width), height=_pick(sensor.height, p.height),
        fovy_deg=_pick(sensor.fovy_deg, p.fovy_deg), min_range_m=_pick(sensor.min_range_m, p.min_range_m),
        max_range_m=_pick(sensor.max_range_m, p.max_range_m), rate_hz=_pick(sensor.rate_hz, p.rate_hz),
        noise_k_per_m=_pick(sensor.noise_k_per_m, p.noise_k_per_m), depth_quantum_m=sensor.depth_quantum_m,
        grazing_angle_rad=math.radians(sensor.grazing_angle_deg), dropout_prob=sensor.dropout_prob,
        rgb=sensor.rgb, latency_s=sensor.latency_s,
    )
