"""Simulated 2D and 3D lidars: rays cast from the sensor site, then noise.

Rays see static collision geometry, people, other robots and doors, never the robot itself. A scan that stays in a
horizontal plane (a 2D lidar on a ground robot) is cast on the geoms' cross-sections
(:mod:`simnav.sensors.planar_rays`), which gives ``mj_multiRay``'s distances many times faster; any other scan, or
a scene the planar model does not cover (tilted geoms, meshes), is cast with ``mj_multiRay``. Its cutoff only
culls geoms by bounding volume; the max range is applied here explicitly.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numba import njit

from simnav.robot.spec import Lidar2DSensor, Lidar3DSensor
from simnav.sensors.noise import lidar_noise
from simnav.sensors.planar_rays import CAPSULE, SUPPORTED_TYPES, cast_planar_scan, fixed_sections
from simnav.sensors.presets import resolve_lidar2d, resolve_lidar3d
from simnav.sensors.readings import LaserScan, PointCloud
from simnav.world.mjcf import GROUP_COLLISION, GROUP_MOVING

MAX_FIXED_HEIGHTS = 16  # scan heights whose fixed sections a caster keeps
_MISSING = object()
RAY_GROUPS = np.zeros(6, dtype=np.uint8)
RAY_GROUPS[[GROUP_COLLISION, GROUP_MOVING]] = 1


class RayCaster:
    """Casts a fixed bundle of unit rays (sensor frame) from a site, returning ideal ranges (0 = no hit).

    Args:
        model: the MuJoCo model.
        site: name of the sensor site.
        dirs_sensor: (N, 3) unit ray directions in the site frame.
        exclude_body: body whose geoms the rays do not see (the robot's).
        max_range_m: hits beyond this distance count as no hit, m.
        planar: cast on cross-sections while the rays stay horizontal (None: whenever every ray has z = 0 in the
            site frame and every visible geom is a primitive the planar model covers; False: always MuJoCo).
    """

    def __init__(self, model: mujoco.MjModel, site: str, dirs_sensor: np.ndarray, exclude_body: int,
                 max_range_m: float, planar: bool | None = None) -> None:
        self._model = model
        self._site = model.site(site).id
        self._dirs = np.ascontiguousarray(dirs_sensor, dtype=np.float64)  # (N, 3)
        self._exclude = exclude_body
        self._max_range = max_range_m
        self._geomid = np.empty(len(self._dirs), dtype=np.int32)
        self._dist = np.empty(len(self._dirs), dtype=np.float64)
        self._seen = _geoms_rays_see(model, exclude_body)
        in_plane = bool(np.all(self._dirs[:, 2] == 0.0))
        covered = all(int(t) in SUPPORTED_TYPES for t in model.geom_type[self._seen])
        self.planar = in_plane and covered if planar is None else planar and in_plane and covered
        self._azimuth_sensor = np.arctan2(self._dirs[:, 1], self._dirs[:, 0])
        self._ranges = np.empty(len(self._dirs))
        self._dirs_world, self._rotation_t = np.empty_like(self._dirs), np.empty((3, 3))
        self._geoms = (model.geom_type, model.geom_size, model.geom_rbound)  # views of the model's arrays
        self._fixed_ids, self._moving_ids = _split_fixed(model, self._seen)
        self._data, self._poses, self._fixed = None, (), {}

    def cast(self, data: mujoco.MjData, copy: bool = True) -> np.ndarray:
        """(N,) distances to the first hit along each ray, metres; 0 where nothing is hit within max range.

        ``copy`` False: the caster's own buffer may be returned, valid until its next cast (for a caller that
        only reads it meanwhile)."""
        if data is not self._data:  # views of the data's site and geom poses, kept while the data is the same
            self._data, self._poses = data, (data.site_xpos, data.site_xmat, data.geom_xpos, data.geom_xmat)
            self._fixed = {}
        site_xpos, site_xmat, geom_xpos, geom_xmat = self._poses
        origin, mat = site_xpos[self._site].copy(), site_xmat[self._site]
        fixed = self._fixed_sections(origin[2], geom_xpos, geom_xmat) if self.planar else None
        if fixed is not None and cast_planar_scan(origin, mat, self._dirs, self._azimuth_sensor, fixed,
                                                  self._moving_ids, *self._geoms, geom_xpos, geom_xmat,
                                                  self._max_range, self._dirs_world, self._dist, self._geomid,
                                                  self._ranges):
            return self._ranges.copy() if copy else self._ranges
        # the transposed rotation copied contiguous first: numpy's matmul is then twice as fast (same products)
        np.copyto(self._rotation_t, mat.reshape(3, 3).T)
        dirs_world = np.matmul(self._dirs, self._rotation_t, out=self._dirs_world)
        mujoco.mj_multiRay(self._model, data, origin, dirs_world.ravel(), RAY_GROUPS, 1, self._exclude,
                           self._geomid, self._dist, None, len(self._dirs), self._max_range + 1.0)
        return _in_range(self._dist, self._geomid, self._max_range)

    def _fixed_sections(self, oz: float, geom_xpos: np.ndarray, geom_xmat: np.ndarray) -> np.ndarray | None:
        """The sections of the geoms that never move at the scan height ``oz`` (m), made once per height (a
        sensor's height takes a few values an ulp apart as the robot turns); None when one leaves the planar
        model."""
        rows = self._fixed.get(oz, _MISSING)
        if rows is _MISSING:
            if len(self._fixed) >= MAX_FIXED_HEIGHTS:
                self._fixed.clear()
            rows = self._fixed[oz] = fixed_sections(oz, self._fixed_ids, *self._geoms, geom_xpos, geom_xmat)
        return rows


def _split_fixed(model: mujoco.MjModel, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The geoms whose sections can be made once (welded to the world, not capsules, whose lying sections depend
    on the origin), and the others; the first are all of them before the first other one (geom order decides
    ties)."""
    body = model.geom_bodyid[geoms]
    fixed = (model.body_weldid[body] == 0) & (model.body_mocapid[body] < 0) & (model.geom_type[geoms] != CAPSULE)
    first_other = int(np.argmin(fixed)) if not fixed.all() else len(geoms)
    return geoms[:first_other].copy(), geoms[first_other:].copy()


@njit(cache=True, error_model="numpy")
def _in_range(dist: np.ndarray, geomid: np.ndarray, max_range_m: float) -> np.ndarray:
    """(N,) the ray distances ``dist`` (m) of the rays that hit a geom (``geomid`` >= 0) within [0, max range],
    else 0."""
    out = np.empty(dist.shape[0])
    for i in range(dist.shape[0]):
        d = dist[i]
        out[i] = d if geomid[i] >= 0 and d >= 0.0 and d <= max_range_m else 0.0
    return out


def _geoms_rays_see(model: mujoco.MjModel, exclude_body: int) -> np.ndarray:
    """Ids of the geoms ``mj_multiRay`` tests with the lidar's groups: in RAY_GROUPS, visible, not excluded."""
    alpha = model.geom_rgba[:, 3].copy()
    with_material = model.geom_matid >= 0
    alpha[with_material] = model.mat_rgba[model.geom_matid[with_material], 3]
    group = np.clip(model.geom_group, 0, len(RAY_GROUPS) - 1)
    seen = (model.geom_bodyid != exclude_body) & (alpha != 0) & (RAY_GROUPS[group] == 1)
    return np.flatnonzero(seen).astype(np.int64)


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
        ranges = lidar_noise(self._caster.cast(data, copy=False), rng, p.noise_std_m, p.dropout_prob, p.min_range_m,
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
