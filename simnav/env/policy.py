"""The 3D-PTG reactive navigator as a policy of the navigation env: observation in, normalised (v, w) out.

The policy sees only what an RL policy sees (``lidar``, ``depth``, ``goal``, ``velocity``) plus the sensor
geometry that the env publishes (beam angles, mounts, ranges, intrinsics). It keeps its own odometry frame by
integrating the observed velocity over each control period: obstacle points, the short-term memory and the recovery
trail live in that frame, and the goal is re-expressed in it from every observation.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simnav.geometry import se2
from simnav.navigation.bands import planar_bands, robot_bands
from simnav.navigation.navigator import NavCommand, NavigatorConfig, ReactiveNavigator3D
from simnav.navigation.sensing import SensedObstacles, camera_free_space, view_sectors
from simnav.sensors.readings import LaserScan, RGBDFrame

NO_RETURN = 0.999
"""Normalised lidar values at or above this are no return (the env reports them as 1)."""

GOAL_SHIFT_M = 0.1
"""The navigator's target is set again when the observed goal moves this far from it in the policy's frame, m."""


class PTGPolicy:
    """The 3D-PTG navigator acting through a :class:`~simnav.env.NavEnv`'s observation/action interface.

    Args:
        env: the env (or a wrapper of it) the policy will act in; its sensor geometry and robot are read once.
        nav: ``"3d"`` (one band per robot prism) or ``"2d"`` (the robot as one prism).
        config: navigator options (default: :class:`NavigatorConfig` with the target tolerance just inside the
            env's success distance).

    Call :meth:`reset` at the start of every episode, then ``policy(obs)`` (or :meth:`act`) every step.
    """

    def __init__(self, env: Any, nav: str = "3d", config: NavigatorConfig | None = None) -> None:
        task = env.unwrapped
        robot, drive = task.robot_spec, task.robot_spec.drive
        if nav not in ("3d", "2d"):
            raise ValueError(f"nav must be '3d' or '2d', got {nav!r}")
        tolerance = 0.8 * task.config.success_distance_m
        self.config = config or NavigatorConfig(target_allowed_distance_m=tolerance)
        bands = robot_bands(robot) if nav == "3d" else planar_bands(robot)
        self.navigator = ReactiveNavigator3D(bands, drive.max_v_m_s, drive.max_w_rad_s, max_acc_m_s2=drive.max_acc_m_s2,
                                             max_ang_acc_rad_s2=drive.max_ang_acc_rad_s2, config=self.config,
                                             view=view_sectors(robot),
                                             free_space_x_m=camera_free_space(robot, bands))
        self.max_v_m_s, self.max_w_rad_s = drive.max_v_m_s, drive.max_w_rad_s
        self.control_dt_s = task.config.control_dt_s
        self._lidar = _lidar_geometry(task)
        self._camera = _camera_geometry(task) if task.camera is not None else None
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode (target, memory, odometry frame)."""
        self.navigator.reset()
        self.obstacles = SensedObstacles()
        self.T_odom_base = np.eye(3)
        self.time_s = 0.0
        self._target_odom: np.ndarray | None = None
        self._velocity: np.ndarray | None = None
        self.last_command: NavCommand | None = None

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self.act(obs)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(2,) float32 action in [-1, 1] for one (unbatched) observation of the env."""
        # Where the base is now: the motion since the previous observation
        self._integrate(np.asarray(obs["velocity"], dtype=np.float64))
        # The goal, from the base frame into the policy's odometry frame
        distance, bearing = float(obs["goal"][0]), float(obs["goal"][1])
        goal_base = np.array([[distance * math.cos(bearing), distance * math.sin(bearing)]])
        goal_odom = se2.transform_points(self.T_odom_base, goal_base)[0]
        if (self._target_odom is None or np.linalg.norm(goal_odom - self._target_odom) > GOAL_SHIFT_M
                or (self.last_command is not None and self.last_command.state == "reached")):
            self.navigator.set_target(goal_odom)
            self._target_odom = goal_odom
        # Obstacle points of this step's readings
        self.obstacles.add(self._scan(obs["lidar"]), self.T_odom_base)
        if self._camera is not None and "depth" in obs:
            self.obstacles.add(self._depth(obs["depth"]), self.T_odom_base)
        points_base, scan_points_base = self.obstacles.split_points_base(self.time_s, self.T_odom_base)
        # One navigator step, then the command as an action
        cmd = self.navigator.step(self.time_s, self.T_odom_base, points_base, scan_points_base)
        self.last_command = cmd
        return np.array([np.clip(cmd.v_m_s / self.max_v_m_s, -1, 1), np.clip(cmd.w_rad_s / self.max_w_rad_s, -1, 1)],
                        dtype=np.float32)

    def _integrate(self, velocity: np.ndarray) -> None:
        """Dead-reckon the base over the last control period from the mean of the observed (v, w) at its ends."""
        previous, self._velocity = self._velocity, velocity
        if previous is None:
            return
        v, w = (previous + velocity) / 2 * self.control_dt_s
        self.T_odom_base = self.T_odom_base @ se2.exp([v, 0.0, w])
        self.time_s += self.control_dt_s

    def _scan(self, lidar: np.ndarray) -> LaserScan:
        g = self._lidar
        ranges = np.where(lidar < NO_RETURN, lidar * g["max_range_m"], 0.0).astype(np.float32)
        return LaserScan(sensor="lidar", stamp_s=self.time_s, ranges_m=ranges, angles_rad=g["angles_rad"],
                         max_range_m=g["max_range_m"], min_range_m=g["min_range_m"], T_base_sensor=g["T_base_sensor"])

    def _depth(self, depth: np.ndarray) -> RGBDFrame:
        g = self._camera
        return RGBDFrame(sensor="depth", stamp_s=self.time_s, depth_m=depth * np.float32(g["max_range_m"]), rgb=None,
                         K=g["K"], T_base_sensor=g["T_base_sensor"])


def _lidar_geometry(task) -> dict[str, Any]:
    spec = task.robot_spec.sensors[0]
    return {"angles_rad": task.lidar.angles_rad(), "max_range_m": task.lidar.max_range_m,
            "min_range_m": task.lidar.min_range_m, "T_base_sensor": spec.mount.T_base_sensor()}


def _camera_geometry(task) -> dict[str, Any]:
    from simnav.geometry.camera import R_MUJOCOCAM_OPTICAL, PinholeCamera
    from simnav.robot.mjcf import R_BODY_MJCAM

    spec, params = task.robot_spec.sensors[1], task.camera
    T = spec.mount.T_base_sensor()
    T[:3, :3] = T[:3, :3] @ R_BODY_MJCAM @ R_MUJOCOCAM_OPTICAL  # the optical frame, as the simulated camera
    K = PinholeCamera.from_fovy(params.width, params.height, params.fovy_deg).K
    return {"max_range_m": params.max_range_m, "K": K, "T_base_sensor": T}
