"""Odometry: estimates of the robot's motion from its own sensors. Pure numpy; no simulator imports."""

from simnav.odometry.wheels import WheelOdometry

__all__ = ["WheelOdometry"]
