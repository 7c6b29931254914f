"""Where the navigator thinks the robot is: ground truth or an odometry started at the true initial pose."""

from __future__ import annotations

import numpy as np

from simnav.errors import UnknownNameError
from simnav.geometry import se2
from simnav.odometry import WheelOdometry, make_scan_odometry
from simnav.odometry.base import FrameOdometry
from simnav.robot.spec import RobotSpec
from simnav.sensors.readings import LaserScan, Reading, RGBDFrame, WheelTicks

SCAN_SOURCES = ("srf", "rf2o")
FRAME_SOURCES = {"difodo": "simnav.odometry.difodo:DIFODO", "vosf": "simnav.odometry.vosf:JointVOSF"}
POSE_SOURCES = ("gt", "wheels", *SCAN_SOURCES, *FRAME_SOURCES)


def available_pose_sources() -> list[str]:
    """Pose sources whose implementation is installed."""
    import importlib.util

    out = ["gt", "wheels", *SCAN_SOURCES]
    for name, target in FRAME_SOURCES.items():
        if importlib.util.find_spec(target.split(":")[0]) is not None:
            out.append(name)
    return out


class PoseSource:
    """Tracks ``T_world_base`` from ground truth or from one odometry.

    The odometry's odom frame is anchored at the true pose given to :meth:`anchor` (the start, and again after
    every intervention that moves the robot), so that the estimate is comparable with the world frame.

    Args:
        name: one of :func:`available_pose_sources`.
        robot: the robot (to pick the sensor an odometry runs on).
    """

    def __init__(self, name: str, robot: RobotSpec) -> None:
        if name not in available_pose_sources():
            raise UnknownNameError(f"unknown pose source '{name}'; available: {', '.join(available_pose_sources())}")
        self.name = name
        self.sensor = _odometry_sensor(name, robot)
        self._T_world_odom = np.eye(3)
        self._T_odom_base = np.eye(3)
        self._odometry = None
        self.estimates: list[tuple[float, np.ndarray]] = []

    @property
    def is_ground_truth(self) -> bool:
        return self.name == "gt"

    def anchor(self, stamp_s: float, T_world_base_true: np.ndarray) -> None:
        """Restart the odometry with its odom frame at the (3, 3) true pose."""
        self._T_world_odom = np.asarray(T_world_base_true, dtype=np.float64)
        self._T_odom_base = np.eye(3)
        self._odometry = None if self.is_ground_truth else _make_odometry(self.name)
        if self.estimates and stamp_s <= self.estimates[-1][0]:
            self.estimates.pop()
        self.estimates.append((stamp_s, self._T_world_odom.copy()))

    def feed(self, reading: Reading) -> None:
        """Give the odometry a reading (ignored for ground truth and for other sensors)."""
        if self._odometry is None or reading.sensor != self.sensor:
            return
        if isinstance(reading, WheelTicks):
            xyt = self._odometry.update(reading)
            self._T_odom_base = se2.from_xy_yaw(*xyt)
        elif isinstance(reading, LaserScan):
            self._T_odom_base = self._odometry.process(reading).T_odom_base
        elif isinstance(reading, RGBDFrame):
            self._T_odom_base = se2.from_se3(self._odometry.process(reading).T_odom_base)
        else:
            return
        if self.estimates and reading.stamp_s <= self.estimates[-1][0]:
            self.estimates.pop()  # same instant as the anchor (or an earlier reading): keep the newest
        self.estimates.append((reading.stamp_s, self.T_world_base()))

    def T_world_base(self, T_world_base_true: np.ndarray | None = None) -> np.ndarray:
        """(3, 3) the pose estimate; for ground truth, the true pose passed in."""
        if self.is_ground_truth:
            if T_world_base_true is None:
                raise ValueError("the ground-truth pose source needs the true pose")
            return np.asarray(T_world_base_true, dtype=np.float64)
        return self._T_world_odom @ self._T_odom_base


def _odometry_sensor(name: str, robot: RobotSpec) -> str | None:
    """The robot sensor an odometry runs on: wheels, the first 2D lidar, or the first RGB-D camera."""
    if name == "gt":
        return None
    kind = {"wheels": "wheels", "srf": "lidar2d", "rf2o": "lidar2d"}.get(name, "rgbd")
    for sensor in robot.sensors:
        if sensor.type == kind:
            return sensor.name
    raise UnknownNameError(f"pose source '{name}' needs a '{kind}' sensor; robot '{robot.name}' has: "
                           f"{', '.join(s.name + ' (' + s.type + ')' for s in robot.sensors) or 'none'}")


def _make_odometry(name: str):
    if name == "wheels":
        return WheelOdometry()
    if name in SCAN_SOURCES:
        return make_scan_odometry(name)
    module, cls = FRAME_SOURCES[name].split(":")
    import importlib

    odometry: FrameOdometry = getattr(importlib.import_module(module), cls)()
    return odometry
