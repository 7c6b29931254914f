"""Simulated 2D and 3D lidars: rays cast with ``mj_multiRay`` from the sensor site, then noise.

``mj_multiRay``'s cutoff only culls geoms by bounding volume; the max range is applied here explicitly.
Rays see static collision geometry, people, other robots and doors, never the robot itself.
"""

from __future__ import annotations

import mujoco
import numpy as np

from simnav.robot.spec import Lidar2DSensor, Lidar3DSensor
from simnav.sensors.noise import lidar_noise
from simnav.sensors.presets import resolve_lidar2d, resolve_lidar3d
from simnav.sensors.readings import LaserScan, PointCloud
from simnav.world.mjcf import GROUP_COLLISION, GROUP_MOVING

RAY_GROUPS = np.zeros(6, dtype=np.uint8)
RAY_GROUPS[[GROUP_COLLISION, GROUP_MOVING]] = 1


class RayCaster:
    """Casts a fixed bundle of unit rays (sensor frame) from a site, returning ideal ranges (0 = no hit)."""

    def __init__(self, model: mujoco.MjModel, site: str, dirs_sensor: np.ndarray, exclude_body: int,
                 max_range_m: float) -> None:
        self._model = model
        self._site = model.site(site).id
        self._dirs = np.ascontiguousarray(dirs_sensor, dtype=np.float64)  # (N, 3)
        self._exclude = exclude_body
        self._max_range = max_range_m
        self._geomid = np.empty(len(self._dirs), dtype=np.int32)
        self._dist = np.empty(len(self._dirs), dtype=np.float64)

    def cast(self, data: mujoco.MjData) -> np.ndarray:
        """(N,) distances to the first hit along each ray, metres; 0 where nothing is hit within max range."""
        origin = data.site_xpos[self._site].copy()
        vec = (self._dirs @ data.site_xmat[self._site].reshape(3, 3).T).ravel()
        mujoco.mj_multiRay(self._model, data, origin, vec, RAY_GROUPS, 1, self._exclude, self._geomid,
                           self._dist, None, len(self._dirs), self._max_range + 1.0)
        hit = (self._geomid >= 0) & (self._dist >= 0) & (self._dist <= self._max_range)
        return np.where(hit, self._dist, 0.0)


class Lidar2D:
    """A planar scanner at a robot site. See :class:`simnav.robot.spec.Lidar2DSensor` for the parameters."""

    def __init__(self, spec: Lidar2DSensor, model: mujoco.MjModel, robot_body: int) -> None:
        self.name = spec.name
        self.params = resolve_lidar2d(spec)
        self.period_s = 1.0 / self.params.rate_hz
        self.latency_s = self.params.latency_s
        self.T_base_sensor = spec.mount.T_base_sensor()
        self._angles = self.params.angles_rad()
        dirs = np.column_stack([np.cos(self._angles), np.sin(self._angles), np.zeros_like(self._angles)])
        self._caster = RayCaster(model, spec.name, dirs, robot_body, self.params.max_range_m)

    def capture(self, data: mujoco.MjData, stamp_s: float, rng: np.random.Generator) -> LaserScan:
        p = self.params
        ranges = lidar_noise(self._caster.cast(data), rng, p.noise_std_m, p.dropout_prob, p.min_range_m,
                             p.max_range_m)
        return LaserScan(sensor=self.name, stamp_s=stamp_s, ranges_m=ranges, angles_rad=self._angles.copy(),
                         max_range_m=p.max_range_m, min_range_m=p.min_range_m, T_base_sensor=self.T_base_sensor)


class Lidar3D:
    """A spinning multi-beam lidar (all columns captured at one instant)."""

    def __init__(self, spec: Lidar3DSensor, model: mujoco.MjModel, robot_body: int) -> None:
        self.name = spec.name
        self.params = resolve_lidar3d(spec)
        self.period_s = 1.0 / self.params.rate_hz
        self.latency_s = self.params.latency_s
        self.T_base_sensor = spec.mount.T_base_sensor()
        lo, hi = self.params.vertical_fov_rad
        elevation = np.linspace(lo, hi, self.params.rings)
        azimuth = np.linspace(-np.pi, np.pi, self.params.columns, endpoint=False)
        el, az = np.meshgrid(elevation, azimuth, indexing="ij")
        self._dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
        self._caster = RayCaster(model, spec.name, self._dirs.reshape(-1, 3), robot_body, self.params.max_range_m)

    def capture(self, data: mujoco.MjData, stamp_s: float, rng: np.random.Generator) -> PointCloud:
        p = self.params
        ranges = lidar_noise(self._caster.cast(data), rng, p.noise_std_m, p.dropout_prob, 0.05, p.max_range_m)
        image = ranges.reshape(p.rings, p.columns)
        ok = ranges > 0
        points = (self._dirs.reshape(-1, 3)[ok] * ranges[ok, None]).astype(np.float32)
        return PointCloud(sensor=self.name, stamp_s=stamp_s, points_sensor=points, ranges_m=image,
                          T_base_sensor=self.T_base_sensor)
