"""Robot description (YAML schema): a stack of prisms, a differential drive, sensor mounts and servo ids.

The robot's volume is a stack of prisms consecutive in height (thesis §6.C): each prism is a polygon in the base
frame (x forward, y left, metres) extruded over a height band ``z_min_m..z_max_m``. Sensors are mounted at
``T_base_sensor`` given as ``xyz_m`` + ``rpy_deg`` (roll, pitch, yaw about fixed x, y, z axes).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from simnav.config import FrozenModel

Vec2 = tuple[float, float]
MOUNT_TOLERANCE_M = 0.05
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


class Prism(FrozenModel):
    """One height band of the robot: a simple polygon (base frame) extruded from z_min_m to z_max_m."""

    name: str
    z_min_m: NonNegative
    z_max_m: Positive
    polygon: list[Vec2] = Field(min_length=3)
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)

    @model_validator(mode="after")
    def _check(self) -> Prism:
        if self.z_max_m <= self.z_min_m:
            raise ValueError(f"prism '{self.name}': z_max_m={self.z_max_m} must exceed z_min_m={self.z_min_m}")
        from shapely.geometry import Polygon

        if not Polygon(self.polygon).is_valid or Polygon(self.polygon).area <= 0:
            raise ValueError(f"prism '{self.name}': polygon must be simple (no self-crossing) with area > 0")
        return self


class Drive(FrozenModel):
    """Differential drive kinematics and limits."""

    wheel_radius_m: Positive = 0.05
    wheel_separation_m: Positive = 0.4
    max_v_m_s: Positive = 0.6
    max_w_deg_s: Positive = 90.0
    max_acc_m_s2: Positive = 1.0
    max_ang_acc_deg_s2: Positive = 180.0
    command_latency_s: NonNegative = 0.05
    ticks_per_rev: Annotated[int, Field(ge=1)] = 4096
    slip_std: Annotated[float, Field(ge=0, le=0.5)] = 0.01

    @property
    def max_w_rad_s(self) -> float:
        return math.radians(self.max_w_deg_s)

    @property
    def max_ang_acc_rad_s2(self) -> float:
        return math.radians(self.max_ang_acc_deg_s2)


class Mount(FrozenModel):
    """Sensor mount pose in the base frame."""

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def T_base_sensor(self) -> np.ndarray:
        """(4, 4) pose of the sensor frame in the base frame (R = Rz(yaw) Ry(pitch) Rx(roll))."""
        r, p, y = (math.radians(a) for a in self.rpy_deg)
        cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
        T = np.eye(4)
        T[:3, :3] = [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
        T[:3, 3] = self.xyz_m
        return T


class _SensorBase(FrozenModel):
    name: str
    mount: Mount = Mount()
    rate_hz: Positive | None = None
    latency_s: NonNegative = 0.0


class Lidar2DSensor(_SensorBase):
    """A planar scanner; unset fields come from ``preset`` (see simnav.sensors.presets)."""

    type: Literal["lidar2d"]
    preset: str = "hokuyo_urg04lx"
    beams: Annotated[int, Field(ge=2)] | None = None
    fov_deg: Annotated[float, Field(gt=0, le=360)] | None = None
    max_range_m: Positive | None = None
    min_range_m: NonNegative | None = None
    noise_std_m: NonNegative = 0.01
    dropout_prob: Annotated[float, Field(ge=0, le=1)] = 0.0


class Lidar3DSensor(_SensorBase):
    """A spinning multi-beam lidar (rings x columns)."""

    type: Literal["lidar3d"]
    preset: str = "vlp16"
    rings: Annotated[int, Field(ge=1)] | None = None
    columns: Annotated[int, Field(ge=2)] | None = None
    vertical_fov_deg: tuple[float, float] | None = None
    max_range_m: Positive | None = None
    noise_std_m: NonNegative = 0.01
    dropout_prob: Annotated[float, Field(ge=0, le=1)] = 0.0


class RGBDSensor(_SensorBase):
    """A pinhole RGB-D camera; the mount gives the optical frame (z forward, x right, y down) via rpy of the
    camera body frame (x forward, y left, z up) -- see simnav.sensors.rgbd."""

    type: Literal["rgbd"]
    preset: str = "kinect_qvga"
    width: Annotated[int, Field(ge=8, le=1920)] | None = None
    height: Annotated[int, Field(ge=8, le=1080)] | None = None
    fovy_deg: Annotated[float, Field(gt=1, lt=170)] | None = None
    min_range_m: NonNegative | None = None
    max_range_m: Positive | None = None
    noise_k_per_m: NonNegative | None = None
    depth_quantum_m: NonNegative = 0.001
    grazing_angle_deg: Annotated[float, Field(gt=0, le=90)] = 80.0
    dropout_prob: Annotated[float, Field(ge=0, le=1)] = 0.0
    rgb: bool = True


class WheelEncoderSensor(_SensorBase):
    """Wheel encoders of the differential drive (resolution and slip from ``drive``)."""

    type: Literal["wheels"]


SensorSpec = Annotated[
    Lidar2DSensor | Lidar3DSensor | RGBDSensor | WheelEncoderSensor, Field(discriminator="type")
]


DynamixelModel = Literal["XL430-W250", "XM430-W210", "XM430-W350", "XH430-W210", "XH430-W350", "XC430-W150",
                         "XC430-W240"]
"""X-series 430 servos with velocity mode (one control table; see simnav.hardware.control_table)."""
BaudRate = Literal[9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000]
"""Rates both the X-series Baud Rate register and dynamixel-sdk's PortHandler support, bit/s."""


class Hardware(FrozenModel):
    """Dynamixel wheel servos of the differential base (used only by simnav.hardware).

    Wheel radius and separation, the (v, w) limits and the acceleration limits come from ``drive``; this block holds
    what belongs to the servos and their bus. Each control period the bridge sends one goal velocity per wheel and
    reads back velocities and positions; no fresh command for two control periods stops the wheels, and the
    servos' own bus watchdog (``watchdog_ms``) stops them if the host goes silent.

    Fields: ``port`` (serial device), ``baud_rate`` (bit/s), ``model`` (checked at start-up), ``left_id`` /
    ``right_id``, ``reverse_left`` / ``reverse_right`` (the servo is mounted mirrored: its positive rotation drives
    the robot backwards; a servo's own Drive Mode reverse bit is taken into account on top), ``max_wheel_speed_rad_s``
    (written to Velocity Limit; commands are scaled into it keeping their curvature), ``control_rate_hz``,
    ``watchdog_ms`` (multiple of 20 ms, more than two control periods), ``latency_timer_ms`` (the USB adapter's;
    status timeout = 2 x this + 2 ms), ``reconnect_attempts`` / ``reconnect_interval_s`` (after a fault; 0: off).
    """

    port: str = Field("/dev/ttyUSB0", min_length=1)
    baud_rate: BaudRate = 1_000_000
    model: DynamixelModel = "XL430-W250"
    left_id: Annotated[int, Field(ge=0, le=252)] = 1
    right_id: Annotated[int, Field(ge=0, le=252)] = 2
    reverse_left: bool = False
    reverse_right: bool = True
    max_wheel_speed_rad_s: Annotated[float, Field(gt=0, le=24.5)] = 6.35
    control_rate_hz: Annotated[float, Field(gt=0, le=500)] = 40.0
    watchdog_ms: Annotated[int, Field(ge=20, le=2540, multiple_of=20)] = 100
    latency_timer_ms: Annotated[float, Field(ge=0, le=255)] = 16.0
    reconnect_attempts: Annotated[int, Field(ge=0, le=100)] = 0
    reconnect_interval_s: Annotated[float, Field(gt=0, le=60)] = 0.5

    @model_validator(mode="after")
    def _check(self) -> Hardware:
        if self.left_id == self.right_id:
            raise ValueError(f"left_id and right_id must differ, both are {self.left_id}")
        period_ms = 1000.0 / self.control_rate_hz
        if self.watchdog_ms <= 2 * period_ms:
            raise ValueError(f"watchdog_ms={self.watchdog_ms} must exceed two control periods "
                             f"(2 x {period_ms:g} ms at control_rate_hz={self.control_rate_hz:g}), or a healthy "
                             "loop would trip it")
        return self

    @property
    def ids(self) -> tuple[int, int]:
        """Servo IDs of the left and right wheel."""
        return self.left_id, self.right_id

    @property
    def control_period_s(self) -> float:
        return 1.0 / self.control_rate_hz


class RobotSpec(FrozenModel):
    """A robot: prisms, drive, sensors, hardware (see module docstring)."""

    name: str = "unnamed"
    description: str = ""
    prisms: list[Prism] = Field(min_length=1)
    drive: Drive = Drive()
    sensors: list[SensorSpec] = Field(default_factory=list)
    hardware: Hardware | None = None
    mass_kg: Positive = 20.0

    @model_validator(mode="after")
    def _check(self) -> RobotSpec:
        names = [s.name for s in self.sensors]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"sensor names must be unique, repeated: {sorted(dup)}")
        bands = sorted((p.z_min_m, p.z_max_m, p.name) for p in self.prisms)
        for (_, z1a, na), (z0b, _, nb) in zip(bands, bands[1:], strict=False):
            if z0b < z1a - 1e-9:
                raise ValueError(f"prisms '{na}' and '{nb}' overlap in height ({z1a} > {z0b})")
        for k, sensor in enumerate(self.sensors):
            if sensor.type != "wheels" and not self.contains(sensor.mount.xyz_m, MOUNT_TOLERANCE_M):
                raise ValueError(
                    f"sensors[{k}] '{sensor.name}': mount.xyz_m={list(sensor.mount.xyz_m)} lies outside the robot "
                    f"(more than {MOUNT_TOLERANCE_M} m from every prism)"
                )
        return self

    def contains(self, xyz_m: tuple[float, float, float], tolerance_m: float = 0.0) -> bool:
        """Whether a base-frame point lies inside (or within ``tolerance_m`` of) one of the prisms."""
        from shapely.geometry import Point, Polygon

        x, y, z = xyz_m
        for p in self.prisms:
            if p.z_min_m - tolerance_m <= z <= p.z_max_m + tolerance_m:
                if Polygon(p.polygon).distance(Point(x, y)) <= tolerance_m:
                    return True
        return False

    @property
    def height_m(self) -> float:
        return max(p.z_max_m for p in self.prisms)

    def sensor(self, name: str):
        for s in self.sensors:
            if s.name == name:
                return s
        from simnav.errors import UnknownNameError

        names = [s.name for s in self.sensors]
        raise UnknownNameError(f"robot '{self.name}' has no sensor '{name}'; available: {names}")
