"""Simulated RGB-D camera: metric z-depth, colour, per-pixel body ids and per-pixel ground-truth motion.

Two backends give the same geometry:

* ``gl`` renders with MuJoCo's OpenGL renderer (EGL, headless). One pass in segmentation colours yields depth
  and body ids together; a second, lit pass gives colour.
* ``raycast`` casts one ray per pixel with ``mj_multiRay`` (used when EGL is unavailable); colour is the geom
  colour with Lambertian shading from the surface normals.

The camera is defined by ``fovy`` and the image size only, so K = [[f, 0, (W-1)/2], [0, f, (H-1)/2], [0, 0, 1]]
with f = (H/2)/tan(fovy/2). Depth noise follows :func:`simnav.sensors.noise.depth_noise`; pixels beyond the range
limits or seen at grazing angles are null (0).
"""

from __future__ import annotations

import logging
from concurrent.futures import Future, ThreadPoolExecutor

import mujoco
import numpy as np
from numba import njit

from simnav.geometry.camera import R_MUJOCOCAM_OPTICAL, PinholeCamera
from simnav.robot.mjcf import R_BODY_MJCAM
from simnav.robot.spec import RGBDSensor
from simnav.sensors.lidar import RayCaster
from simnav.sensors.noise import depth_noise, grazing_mask
from simnav.sensors.presets import resolve_rgbd
from simnav.sensors.readings import RGBDFrame
from simnav.world.mjcf import GROUP_ROBOT

log = logging.getLogger(__name__)
_gl_failure: str | None = None


class RGBDCamera:
    """A camera mounted on the robot (see :class:`simnav.robot.spec.RGBDSensor`).

    Args:
        spec: the sensor description.
        model: the compiled scene.
        robot_body: body id of the robot (excluded from ray casting).
        backend: ``"auto"`` (GL if EGL works, else ray casting), ``"gl"`` or ``"raycast"``.
    """

    def __init__(self, spec: RGBDSensor, model: mujoco.MjModel, robot_body: int, backend: str = "auto") -> None:
        self.name = spec.name
        self.params = resolve_rgbd(spec)
        self.period_s = 1.0 / self.params.rate_hz
        self.latency_s = self.params.latency_s
        self.pinhole = PinholeCamera.from_fovy(self.params.width, self.params.height, self.params.fovy_deg)
        T_base_body = spec.mount.T_base_sensor()
        self.T_base_sensor = T_base_body.copy()
        self.T_base_sensor[:3, :3] = T_base_body[:3, :3] @ R_BODY_MJCAM @ R_MUJOCOCAM_OPTICAL
        self._model = model
        self._cam_id = model.camera(spec.name).id
        self._rays_optical = self.pinhole.rays_optical()  # (H, W, 3) with z = 1
        # frames are made on one worker thread that owns the GL context and its own MjData copy of the state
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"simnav-{spec.name}")
        self._data = mujoco.MjData(model)
        self._backend = None
        if _use_gl(backend):
            self._backend = self._worker.submit(_GLBackend, model, self._cam_id, self.params).result()
        if self._backend is None:
            dirs = self._rays_optical / np.linalg.norm(self._rays_optical, axis=-1, keepdims=True)
            self._unit_z = dirs[..., 2]
            self._raycast_dirs_mjcam = (dirs @ R_MUJOCOCAM_OPTICAL.T).reshape(-1, 3)
            self._robot_body = robot_body

    @property
    def backend(self) -> str:
        """``"gl"`` or ``"raycast"``."""
        return "raycast" if self._backend is None else "gl"

    def capture(self, data: mujoco.MjData, stamp_s: float, rng: np.random.Generator,
                body_twists_world: np.ndarray) -> RGBDFrame:
        """Take a frame at the current state of ``data`` (blocking; see :meth:`submit`)."""
        return self.submit(data, stamp_s, rng, body_twists_world).result()

    def submit(self, data: mujoco.MjData, stamp_s: float, rng: np.random.Generator,
               body_twists_world: np.ndarray) -> Future[RGBDFrame]:
        """Snapshot the state of ``data`` now and make the frame in the background.

        Frames are made in submission order, so noise drawn from ``rng`` is the same as in sequential capture.

        Args:
            body_twists_world: (nbody, 6) linear velocity of each body's origin and its angular velocity, both in
                the world frame (m/s, rad/s); used for the per-pixel ground-truth motion.
        """
        state = (data.qpos.copy(), data.mocap_pos.copy(), data.mocap_quat.copy())
        return self._worker.submit(self._make_frame, state, stamp_s, rng, body_twists_world.copy())

    def _make_frame(self, state, stamp_s: float, rng: np.random.Generator, twists: np.ndarray) -> RGBDFrame:
        data = self._data
        data.qpos[:], data.mocap_pos[:], data.mocap_quat[:] = state
        mujoco.mj_kinematics(self._model, data)
        mujoco.mj_camlight(self._model, data)
        if self._backend is not None:
            depth, body_id, rgb = self._backend.render(data, self.params.rgb)
        else:
            depth, body_id, rgb = self._raycast(data)
        p = self.params
        # ideal depth: range limits, then surfaces seen at grazing angles are null
        ideal = np.where((depth >= p.min_range_m) & (depth <= p.max_range_m), depth, 0).astype(np.float32)
        ideal[grazing_mask(depth, self.pinhole.K, p.grazing_angle_rad)] = 0
        noisy = depth_noise(ideal, rng, p.noise_k_per_m, p.depth_quantum_m, p.dropout_prob)
        # ground truth: which body each pixel sees and how the seen point moves
        body_id = np.where(depth > 0, body_id, -1).astype(np.int32)
        velocity = self._pixel_velocity(data, depth, body_id, twists)
        return RGBDFrame(sensor=self.name, stamp_s=stamp_s, depth_m=noisy, rgb=rgb, K=self.pinhole.K,
                         T_base_sensor=self.T_base_sensor, body_id=body_id, velocity_optical=velocity)

    def T_world_optical(self, data: mujoco.MjData) -> np.ndarray:
        """(4, 4) current pose of the optical frame in the world."""
        T = np.eye(4)
        T[:3, :3] = data.cam_xmat[self._cam_id].reshape(3, 3) @ R_MUJOCOCAM_OPTICAL
        T[:3, 3] = data.cam_xpos[self._cam_id]
        return T

    def _pixel_velocity(self, data, depth, body_id, twists) -> np.ndarray:
        """(3, H, W) float32 world velocity of each observed point, expressed in the optical frame, m/s."""
        out = np.zeros((3, *body_id.shape), dtype=np.float32)
        moving_bodies = np.flatnonzero(np.any(twists != 0, axis=1))
        moving = np.isin(body_id, moving_bodies)
        if moving.any():
            T = self.T_world_optical(data)
            ids = body_id[moving]
            p_optical = self._rays_optical[moving] * depth[moving, None]
            lever = p_optical @ T[:3, :3].T + T[:3, 3] - data.xpos[ids]
            v_world = twists[ids, :3] + np.cross(twists[ids, 3:], lever)
            out[:, moving] = (v_world @ T[:3, :3]).T
        return out

    def _raycast(self, data):
        h, w = self.params.height, self.params.width
        if not hasattr(self, "_caster"):
            self._caster = _CameraRays(self._model, self._cam_id, self._raycast_dirs_mjcam, self._robot_body,
                                       self.params.max_range_m * 2)
        dist, geom, normal = self._caster.cast(data)
        depth = (dist.reshape(h, w) * self._unit_z).astype(np.float32)
        body_id = np.where(geom >= 0, self._model.geom_bodyid[np.maximum(geom, 0)], -1).reshape(h, w)
        rgb = None
        if self.params.rgb:
            rays_world = self._caster.rays_world(data)
            shade = 0.35 + 0.65 * np.abs(np.einsum("nc,nc->n", normal, rays_world))
            color = self._model.geom_rgba[np.maximum(geom, 0), :3] * shade[:, None]
            color[geom < 0] = (0.7, 0.75, 0.8)
            rgb = (np.clip(color, 0, 1) * 255).astype(np.uint8).reshape(h, w, 3)
        return depth, body_id, rgb

    def close(self) -> None:
        """Release the GL context (on its own thread) and stop the worker."""
        if self._backend is not None:
            self._worker.submit(self._backend.close).result()
            self._backend = None
        self._worker.shutdown(wait=True)


class _CameraRays(RayCaster):
    """Per-pixel rays from a MuJoCo camera frame (not a site)."""

    def __init__(self, model, cam_id, dirs_mjcam, exclude_body, max_range_m) -> None:
        self._model, self._cam, self._dirs = model, cam_id, np.ascontiguousarray(dirs_mjcam)
        self._exclude, self._max_range = exclude_body, max_range_m
        self._geomid = np.empty(len(self._dirs), dtype=np.int32)
        self._dist = np.empty(len(self._dirs), dtype=np.float64)
        self._normal = np.empty(3 * len(self._dirs), dtype=np.float64)

    def rays_world(self, data) -> np.ndarray:
        return self._dirs @ data.cam_xmat[self._cam].reshape(3, 3).T

    def cast(self, data):
        from simnav.sensors.lidar import RAY_GROUPS

        groups = RAY_GROUPS.copy()
        groups[0] = 0
        vec = self.rays_world(data).ravel()
        mujoco.mj_multiRay(self._model, data, data.cam_xpos[self._cam].copy(), vec, groups, 1, self._exclude,
                           self._geomid, self._dist, self._normal, len(self._dirs), self._max_range)
        hit = (self._geomid >= 0) & (self._dist >= 0)
        return np.where(hit, self._dist, 0.0), np.where(hit, self._geomid, -1), self._normal.reshape(-1, 3)


def _use_gl(backend: str) -> bool:
    global _gl_failure
    if backend == "raycast":
        return False
    if _gl_failure is None:
        _gl_failure = _probe_gl()
        if _gl_failure:
            log.warning("OpenGL (EGL) rendering is unavailable (%s); depth cameras fall back to ray casting",
                        _gl_failure)
    if _gl_failure and backend == "gl":
        from simnav.errors import SimnavError

        raise SimnavError(f"depth backend 'gl' requested but OpenGL (EGL) is unavailable: {_gl_failure}")
    return not _gl_failure


def _probe_gl() -> str:
    """'' if an offscreen MuJoCo render context can be made here, else the reason it cannot."""
    import os
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from mujoco.rendering.classic import gl_context

            if getattr(gl_context, "GLContext", None) is None:
                raise RuntimeError(f"no OpenGL platform (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r})")
            model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
            ctx = gl_context.GLContext(8, 8)
            ctx.make_current()
            mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value).free()
            ctx.free()
        return ""
    except Exception as err:  # any platform/driver failure means: no GL here
        hint = "" if os.environ.get("MUJOCO_GL") in ("egl", "disable") else \
            "; set MUJOCO_GL=egl before importing mujoco"
        return f"{type(err).__name__}: {err}{hint}"


def _render_context(model: mujoco.MjModel, multisample: bool) -> mujoco.MjrContext:
    """A MuJoCo render context for the current GL context; without ``multisample`` its offscreen buffer has one
    sample per pixel. Depth and segmentation are rendered without multisampling either way (the same image), but a
    multisampled buffer costs a resolve pass on every read, so only colour images, which it anti-aliases, keep it."""
    samples = model.vis.quality.offsamples
    if not multisample:
        model.vis.quality.offsamples = 0
    try:
        return mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
    finally:
        model.vis.quality.offsamples = samples


class _GLBackend:
    """Offscreen OpenGL rendering of one fixed camera."""

    def __init__(self, model: mujoco.MjModel, cam_id: int, params) -> None:
        from mujoco.rendering.classic import gl_context

        self._w, self._h = params.width, params.height
        self._ctx = gl_context.GLContext(model.vis.global_.offwidth, model.vis.global_.offheight)
        self._ctx.make_current()
        self._mjr = _render_context(model, multisample=params.rgb)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr)
        self._mjr.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._model = model
        self._scene = mujoco.MjvScene(model, maxgeom=2000)
        self._table, self._table_key = np.zeros(0, dtype=np.int32), None
        self._option = mujoco.MjvOption()
        self._option.geomgroup[GROUP_ROBOT] = 0  # the camera does not see its own robot (as the lidars)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = cam_id
        self._rect = mujoco.MjrRect(0, 0, self._w, self._h)
        self._seg = np.empty((self._h, self._w, 3), np.uint8)
        self._zbuf = np.empty((self._h, self._w), np.float32)
        near = np.float32(model.vis.map.znear * model.stat.extent)
        far = np.float32(model.vis.map.zfar * model.stat.extent)
        self._far = float(far)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        self._c, self._d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d

    def render(self, data: mujoco.MjData, with_rgb: bool):
        """Depth (H, W) float64 (0 = nothing), body ids (H, W), rgb (H, W, 3) uint8 or None; row 0 = top."""
        self._ctx.make_current()
        mujoco.mjv_updateScene(self._model, data, self._option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL,
                               self._scene)
        flags = self._scene.flags
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
                     mujoco.mjtRndFlag.mjRND_SKYBOX, mujoco.mjtRndFlag.mjRND_FOG, mujoco.mjtRndFlag.mjRND_HAZE):
            flags[flag] = 0
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        mujoco.mjr_render(self._rect, self._scene, self._mjr)
        mujoco.mjr_readPixels(self._seg, self._zbuf, self._rect, self._mjr)
        depth, body_id = _depth_and_bodies(self._zbuf, self._seg, self._body_table(), self._c, self._d,
                                           np.float32(self._far * 0.999))
        rgb = None
        if with_rgb:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
            rgb = np.empty((self._h, self._w, 3), np.uint8)
            mujoco.mjr_render(self._rect, self._scene, self._mjr)
            mujoco.mjr_readPixels(rgb, None, self._rect, self._mjr)
            rgb = np.ascontiguousarray(rgb[::-1])
        return depth, body_id, rgb

    def _body_table(self) -> np.ndarray:
        """(ngeom + 2,) int32: the body id of the scene's geom with segmentation id s at s + 1, -1 elsewhere.

        The scene holds the same geoms in the same order from frame to frame while what decides a geom's visibility
        stays (groups, colours' alpha, materials), so the table is rebuilt only when one of those, the scene's geom
        count or its last geom changes."""
        scene, model = self._scene, self._model
        last = scene.geoms[scene.ngeom - 1] if scene.ngeom else None
        visibility = hash((model.geom_group.tobytes(), model.geom_rgba[:, 3].tobytes(), model.geom_matid.tobytes(),
                           model.mat_rgba[:, 3].tobytes()))
        key = (scene.ngeom, visibility, None if last is None else (int(last.objtype), int(last.objid), int(last.segid)))
        if key != self._table_key:
            table = np.full(scene.ngeom + 2, -1, dtype=np.int32)
            geom = mujoco.mjtObj.mjOBJ_GEOM
            for g in scene.geoms[: scene.ngeom]:
                if g.segid >= 0 and g.objtype == geom:
                    table[g.segid + 1] = self._model.geom_bodyid[g.objid]
            self._table, self._table_key = table, key
        return self._table

    def close(self) -> None:
        if self._ctx is not None:
            self._ctx.make_current()
            self._mjr.free()
            self._ctx.free()
            self._ctx = None


@njit(cache=True, error_model="numpy")
def _depth_and_bodies(zbuf: np.ndarray, seg: np.ndarray, table: np.ndarray, c: np.float32, d: np.float32,
                      far: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Metric z-depth (H, W) float32 and body ids (H, W) int32, row 0 at the top, from OpenGL's (H, W) depth buffer
    and (H, W, 3) segmentation colours (row 0 at the bottom): depth = d / (zbuf + c) in float32 (~1e-7 relative
    precision in reverse-Z), body = ``table[min(colour id, len - 1)]``; depth 0 where no body is seen or the depth
    reaches ``far``."""
    h, w = zbuf.shape
    depth = np.empty((h, w), dtype=np.float32)
    body = np.empty((h, w), dtype=np.int32)
    last = table.shape[0] - 1
    for i in range(h):
        src = h - 1 - i
        for j in range(w):
            segid = np.int32(seg[src, j, 0]) | (np.int32(seg[src, j, 1]) << 8) | (np.int32(seg[src, j, 2]) << 16)
            b = table[min(segid, last)]
            z = d / (zbuf[src, j] + c)
            body[i, j] = b
            depth[i, j] = np.float32(0) if b < 0 or z >= far else z
    return depth, body
