"""Depth and RGB-D odometry side by side in the simulated office, plus Joint-VO-SF's scene flow and segmentation.

Every method runs in this process on the same frames: DIFODO at QVGA and QQVGA (``max_rows`` 240 / 120; depth
only), Joint-VO-SF (RGB-D, :mod:`simnav.odometry.vosf`, when installed), Open3D RGB-D odometry with the hybrid
(photometric + geometric) term (tensor pipeline; ``--methods open3d-rgbd-legacy`` adds the legacy one, about twice
as slow here), Open3D point-to-plane ICP, and small_gicp GICP and VGICP on the back-projected depth (settings
below, at METHODS). The peers register consecutive frames, each starting from the previous increment (the
constant-velocity prior our methods use too), and keep that prior when a registration fails ("lost"); every method
runs on one thread. Per method and sequence the script prints the RPE per second (cm/s, deg/s, pairs 1 s apart), the
ATE (SE(3)-aligned, cm) of the camera's optical frame and the runtime per frame (median, p95; the first frame is
left out, and each method first runs 3 untimed frames once per process so that loading kernels is not timed).

Sequences (office world, giraff robot with its kinect_qvga camera: 320 x 240, 30 Hz, 0.5-4.5 m, noise 1.4 mm at 1 m,
mounted at 1.12 m and pitched 30 deg down), simulated once and cached as TUM RGB-D folders under
runs/bench_rgbd_cache/ (what `simnav record` writes for a camera, plus sequence.yaml):

* ``robot-static``: the camera on the robot, which follows the roadmap (0.7 m/s, 60 deg/s), no people.
* ``robot-people<N>`` (N = 1..5): the same among N walking people. People spawn anywhere on the floor, so for each
  of these the seeds ``--seed`` .. ``--seed + --candidates - 1`` are simulated and the one whose frames show the most
  people is kept (the sequence table says which). The robot has no obstacle avoidance and does not wait for anyone;
  the people (social force model) avoid it.
* ``handheld-static`` / ``handheld-people<N>``: hand-held-like 6-DoF motion. The robot drives the roadmap at up to
  0.5 m/s and 45 deg/s, and before every frame the camera is moved on it (its MuJoCo camera pose, ``model.cam_pos``
  / ``cam_quat``, relative to the robot body): 1.15-1.35 m high, 10-20 cm in front of the head, swaying sideways,
  yawing +-15 deg, pitching 20 +- 10 deg down and rolling +-8 deg, at 0.2-0.4 Hz. Frames are taken with
  ``Simulator.capture_now`` at 30 Hz (physics step 1/300 s, control period 1/30 s); the ground truth is the rendered
  camera pose (``data.cam_xpos`` / ``cam_xmat``).

Per sequence the script reports the % of valid depth pixels and the % of valid pixels that see a person or a
wandering robot (body kinds ``pedestrian`` / ``wanderer`` from the segmentation; mean and worst frame), as seed 001's
Table II. For Joint-VO-SF it also scores, on every consecutive frame pair of a sequence with people, the scene flow
against the simulator's per-pixel velocity (``RGBDFrame.velocity_optical`` times the frame interval; the world
motion of each observed point, which is what Joint-VO-SF's flow is): MAX-V (largest true displacement of the pair),
NRMS-V (RMS of the error vector over the pixels with a depth and a flow estimate, divided by MAX-V) and AAE (mean 3D
angle between estimated and true displacement over the moving pixels; a zero estimate, i.e. a pixel labelled static,
counts as 90 deg), as in thesis Table 4.1, averaged over pairs with at least 200 moving pixels; and the
segmentation: % of moving pixels (true speed >= 0.1 m/s) labelled moving and % of static pixels (true speed 0)
labelled moving, over all frames (compare seed 001's Table I; on a static sequence only the latter), and the
median over the clusters of the residuals (7) the segmentation compares with its thresholds t_B, t_M (median and
10th-90th percentile over the pairs).

    python scripts/bench_rgbd_odometry.py [--seconds 10] [--sequences robot-static robot-people3 ...]
                                          [--methods difodo-qvga vosf open3d-rgbd ...] [--seed 0] [--candidates 4]
                                          [--per-frame DIR] [--vosf-set KEY=VALUE ...]
                                          [--difodo-set KEY=VALUE ...]

``--vosf-set`` runs Joint-VO-SF with fields of its config changed, e.g. the public code's segmentation thresholds
``--vosf-set residual_floor=0.007 residual_ceiling=0.015``; ``--difodo-set`` does the same for DIFODO (both
resolutions).
``--per-frame DIR`` writes the error of every frame-to-frame increment per sequence and method
(``DIR/<sequence>_<method>.csv``: true and estimated speed, translational and rotational error, degeneracy flag),
to find the frames where a method goes wrong; for Joint-VO-SF on a sequence with people also its segmentation per
frame (``DIR/<sequence>_vosf_segmentation.csv``: moving and static pixels, those labelled moving, and the median
depth and true speed of the moving pixels left unlabelled).

Defaults: robot-static, robot-people3, robot-people5 and handheld-static, 10 s each (301 frames): about 8 minutes
on a shared 2-core machine, simulation included (about 1.5 minutes of it; later runs read the cache).

The peers come with `pip install -e ".[peers]"`; a missing one is reported and skipped.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one thread per method (Open3D reads OMP_NUM_THREADS when it loads)

import argparse  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, field, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.progress import Progress  # noqa: E402
from rich.table import Table  # noqa: E402

import simnav  # noqa: E402  (first: it chooses MUJOCO_GL before mujoco loads)
from simnav.config import apply_overrides  # noqa: E402
from simnav.errors import ConfigError  # noqa: E402
from simnav.geometry import se3  # noqa: E402
from simnav.geometry.camera import R_BODY_OPTICAL, R_MUJOCOCAM_OPTICAL  # noqa: E402
from simnav.io import RGBDDataset, RGBDDatasetWriter, Trajectory, TumWriter  # noqa: E402
from simnav.metrics import ate, rpe_per_second  # noqa: E402
from simnav.odometry import make_frame_odometry  # noqa: E402
from simnav.sensors.readings import RGBDFrame  # noqa: E402

CACHE = Path("runs/bench_rgbd_cache")
CACHE_VERSION = 4
CAMERA = "camera"
FRAME_RATE_HZ = 30.0
DYNAMIC_KINDS = ("pedestrian", "wanderer")
MOVING_SPEED_M_S = 0.1  # a pixel is moving (segmentation ground truth) from this true speed on
MIN_MOVING_PIXELS = 200  # fewest moving pixels of a pair scored for scene flow
DEFAULT_SEQUENCES = ["robot-static", "robot-people3", "robot-people5", "handheld-static"]
ALL_SEQUENCES = ["robot-static", *(f"robot-people{n}" for n in range(1, 6)), "handheld-static",
                 *(f"handheld-people{n}" for n in range(1, 6))]


# ------------------------------------------------------------------------------------------------- sequences
@dataclass
class Sequence:
    """Frames of one cached sequence in memory, their ground truth and the statistics of seed 001's Table II."""

    name: str
    info: dict
    frames: list[RGBDFrame]
    T_world_camera: np.ndarray  # (N, 4, 4) optical-frame ground truth at the frame stamps
    motion: list[tuple[np.ndarray, np.ndarray]]  # per frame: moving pixel indices, their (M, 3) velocity (m/s)
    valid_pct: float = 0.0
    dynamic_pct: float = 0.0
    dynamic_max_pct: float = 0.0

    @property
    def stamps_s(self) -> np.ndarray:
        return np.array([f.stamp_s for f in self.frames])

    def velocity(self, k: int) -> np.ndarray:
        """(3, H, W) true velocity of each pixel's point in frame k (optical frame, m/s)."""
        h, w = self.frames[k].depth_m.shape
        out = np.zeros((3, h * w), dtype=np.float32)
        idx, vel = self.motion[k]
        out[:, idx] = vel.T
        return out.reshape(3, h, w)


def _parse(name: str) -> tuple[str, int]:
    """('robot' | 'handheld', people) of a sequence name."""
    kind, _, rest = name.partition("-")
    return kind, 0 if rest == "static" else int(rest.removeprefix("people"))


def sequence_folder(name: str, seconds: float, seed: int, candidates: int) -> Path:
    _, people = _parse(name)
    tried = f"-of{candidates}" if people else ""
    return CACHE / f"{name}-{seconds:g}s-seed{seed}{tried}-v{CACHE_VERSION}"


def simulate(name: str, seconds: float, seed: int, candidates: int, progress: Callable[[str], None]) -> Path:
    """The cached TUM RGB-D folder of a sequence, simulated now if needed.

    With people, the seeds ``seed`` .. ``seed + candidates - 1`` are first simulated without writing anything and
    scored by the mean fraction of pixels that see a person; the best one is then simulated again (the simulator is
    deterministic) and written.
    """
    folder = sequence_folder(name, seconds, seed, candidates)
    if (folder / "sequence.yaml").is_file():
        return folder
    kind, people = _parse(name)
    record = _record_robot if kind == "robot" else _record_handheld
    seeds, scores = (list(range(seed, seed + candidates)) if people else [seed]), []
    for s in seeds if len(seeds) > 1 else []:
        progress(f"{name}: scoring seed {s}")
        fractions: list[float] = []
        record(seconds, s, people, lambda sim, frame, T, out=fractions: out.append(_dynamic(sim, frame).mean()))
        scores.append(float(np.mean(fractions)))
    best = seeds[int(np.argmax(scores))] if scores else seed
    progress(f"{name}: simulating seed {best}")
    tmp = CACHE / f".tmp-{folder.name}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    with RGBDDatasetWriter(tmp) as rgbd, TumWriter(tmp / "groundtruth.txt") as gt:
        def write(sim, frame: RGBDFrame, T_world_camera: np.ndarray) -> None:
            rgbd.write_frame(frame)
            gt.write(frame.stamp_s, T_world_camera)

        info = record(seconds, best, people, write)
    info.update(name=name, seconds=seconds, candidate_seeds=seeds, candidate_dynamic_pct=[100 * x for x in scores])
    (tmp / "sequence.yaml").write_text(yaml.safe_dump(info, sort_keys=False))
    shutil.rmtree(folder, ignore_errors=True)
    tmp.rename(folder)
    return folder


def _dynamic(sim, frame: RGBDFrame) -> np.ndarray:
    """(H, W) bool: the pixels that see a person or a wandering robot."""
    kinds = np.append(sim.index.body_kind, "none")  # body id -1 (nothing) picks the last entry
    return np.isin(kinds[frame.body_id], DYNAMIC_KINDS)


def _simulator(people: int, seed: int, robot_overrides: list[str], **sim_fields):
    from simnav.robot import load_robot
    from simnav.sim import SimConfig, Simulator
    from simnav.world import load_world

    robot = load_robot("giraff", robot_overrides)
    sim = Simulator(load_world("office"), robot, SimConfig(pedestrians=people, wanderers=0, **sim_fields), seed=seed)
    return robot, sim


def _follower(sim, robot, seed: int):
    from simnav.mission.follower import RoadmapFollower

    return RoadmapFollower(sim.roadmap, np.array(sim.pose_xy_yaw[:2]),
                           np.random.default_rng(np.random.SeedSequence([seed, 1])), robot.drive.max_v_m_s,
                           robot.drive.max_w_rad_s)


def _info(sim, kind: str, people: int, seed: int, frames: int) -> dict:
    dynamic = np.flatnonzero(np.isin(sim.index.body_kind, DYNAMIC_KINDS))
    return {"kind": kind, "people": people, "seed": seed, "frames": frames, "world": sim.world.name,
            "robot": sim.robot.name, "dynamic_body_ids": [int(b) for b in dynamic]}


Sink = Callable[[object, RGBDFrame, np.ndarray], None]  # (simulator, frame, T_world_camera)


def _record_robot(seconds: float, seed: int, people: int, sink: Sink | None) -> dict:
    """The camera on the robot following the roadmap (frames from the camera's own 30 Hz schedule); with no
    ``sink``, the same run with the camera off (the people and the robot move as when it renders)."""
    robot, sim = _simulator(people, seed, [] if sink else ["sensors.camera.rate_hz=0.001"])
    frames = 0
    with sim:
        follower = _follower(sim, robot, seed)

        def take(readings) -> int:
            n = 0
            for r in readings:
                if sink and isinstance(r, RGBDFrame) and r.sensor == CAMERA and r.stamp_s <= seconds + 1e-9:
                    sink(sim, r, sim.T_world_base_at(r.stamp_s) @ r.T_base_sensor)
                    n += 1
            return n

        while sim.time_s < seconds - 1e-9:
            v, w = follower.command(*sim.pose_xy_yaw)
            frames += take(sim.step(v, w))
        frames += take(sim.flush())
        return _info(sim, "robot", people, seed, frames)


def handheld_mount(t_s: float) -> np.ndarray:
    """(4, 4) pose of the optical frame in the robot base frame at time t: a hand-held-like 6-DoF wobble."""
    tau = 2 * math.pi * t_s
    xyz = [0.15 + 0.05 * math.sin(0.3 * tau), 0.05 * math.sin(0.23 * tau + 0.5), 1.25 + 0.1 * math.sin(0.4 * tau)]
    roll = math.radians(8.0) * math.sin(0.35 * tau + 1.0)
    pitch = math.radians(20.0 + 10.0 * math.sin(0.27 * tau))  # positive: looking down
    yaw = math.radians(15.0) * math.sin(0.2 * tau + 2.0)
    return se3.from_rpy(roll, pitch, yaw, xyz) @ se3.from_rotation_translation(R_BODY_OPTICAL)


def _record_handheld(seconds: float, seed: int, people: int, sink: Sink | None) -> dict:
    """A free camera: the robot drives the roadmap and the camera is moved on it before every frame; with no
    ``sink``, the same run without the frames."""
    import mujoco

    overrides = ["drive.max_v_m_s=0.5", "drive.max_w_deg_s=45", "sensors.camera.rate_hz=0.001"]
    robot, sim = _simulator(people, seed, overrides, physics_dt_s=1 / 300, control_dt_s=1 / FRAME_RATE_HZ)
    cam = sim.model.camera(CAMERA).id
    frames = 0
    with sim:
        sim.flush()  # the scheduled frame of t = 0 is rendered before the camera is moved
        follower = _follower(sim, robot, seed)
        for _ in range(int(math.floor(seconds * FRAME_RATE_HZ + 1e-6)) + 1):
            if sink is None:
                sim.step(*follower.command(*sim.pose_xy_yaw))
                continue
            T = handheld_mount(sim.time_s)
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, (T[:3, :3] @ R_MUJOCOCAM_OPTICAL.T).ravel())
            sim.model.cam_pos[cam], sim.model.cam_quat[cam] = T[:3, 3], quat
            frame = sim.capture_now(CAMERA)
            T_world_camera = np.eye(4)
            T_world_camera[:3, :3] = sim.data.cam_xmat[cam].reshape(3, 3) @ R_MUJOCOCAM_OPTICAL
            T_world_camera[:3, 3] = sim.data.cam_xpos[cam]
            sink(sim, frame, T_world_camera)
            frames += 1
            v, w = follower.command(*sim.pose_xy_yaw)
            sim.step(v, w)
        return _info(sim, "handheld", people, seed, frames)


def load(folder: Path) -> Sequence:
    """Reads a cached sequence into memory (depth, colour; segmentation and motion reduced to what is scored)."""
    info = yaml.safe_load((folder / "sequence.yaml").read_text())
    dataset = RGBDDataset(folder)
    gt = dataset.groundtruth
    frames, motion, valid, dynamic = [], [], [], []
    for frame in dataset:
        ok = np.isfinite(frame.depth_m) & (frame.depth_m > 0)
        valid.append(ok.mean())
        dyn = np.isin(frame.body_id, info["dynamic_body_ids"]) & ok if frame.body_id is not None else ok & False
        dynamic.append(dyn.sum() / max(ok.sum(), 1))
        vel = frame.velocity_optical.reshape(3, -1) if frame.velocity_optical is not None else np.zeros((3, 0))
        idx = np.flatnonzero(np.any(vel != 0, axis=0)).astype(np.int32)
        motion.append((idx, np.ascontiguousarray(vel[:, idx].T)))
        frames.append(replace(frame, body_id=None, velocity_optical=None))
    stamps = np.array([f.stamp_s for f in frames])
    index = {round(t * 1e6): k for k, t in enumerate(gt.stamps_s)}
    T_gt = np.stack([gt.T[index[round(t * 1e6)]] for t in stamps])
    return Sequence(folder.name, info, frames, T_gt, motion, 100 * float(np.mean(valid)),
                    100 * float(np.mean(dynamic)), 100 * float(np.max(dynamic)))


# --------------------------------------------------------------------------------------------------- methods
class _Ours:
    """A simnav frame odometry; the last estimate is kept for the scene flow evaluation."""

    def __init__(self, name: str, **config) -> None:
        self.odometry = make_frame_odometry(name, **config)
        self.last = None
        self.failures = 0  # frames after the first that were not aligned (the prior was kept)

    def process(self, frame: RGBDFrame) -> np.ndarray:
        first = self.last is None
        self.last = self.odometry.process(frame)
        self.failures += not first and not self.last.extra.get("measured", True)
        return self.last.T_odom_camera


class _Pairwise:
    """Consecutive-frame registration with a peer: ``register(prev, cur, init)`` returns T_prev_curr or None."""

    def __init__(self, prepare: Callable[[RGBDFrame], object],
                 register: Callable[[object, object, np.ndarray], np.ndarray | None]) -> None:
        self._prepare, self._register = prepare, register
        self._prev = None
        self._delta = np.eye(4)
        self.T_odom_camera = np.eye(4)
        self.failures = 0

    def process(self, frame: RGBDFrame) -> np.ndarray:
        cur = self._prepare(frame)
        if self._prev is not None:
            delta = self._register(self._prev, cur, self._delta)
            if delta is None or not np.all(np.isfinite(delta)):
                self.failures += 1
            else:
                self._delta = np.asarray(delta, dtype=np.float64)
            self.T_odom_camera = self.T_odom_camera @ self._delta
        self._prev = cur
        return self.T_odom_camera


def _points(frame: RGBDFrame) -> np.ndarray:
    """(N, 3) float64 points of the valid depth pixels, optical frame, m."""
    depth = np.asarray(frame.depth_m, dtype=np.float64)
    h, w = depth.shape
    K = frame.K
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u]
    return np.column_stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])


# Peer settings: the most accurate of a small grid (voxel 0.02-0.05 m, 10-20 neighbours, pixel strides) on 2 s of
# robot-static and handheld-static (seed 0) that keeps each within about 100 ms per frame on this 2-core machine.
# Coarser voxels make the clouds' registration stick to zero motion along the floor, which fills half of the robot
# camera's view.
ICP_VOXEL_M = 0.03
GICP_VOXEL_M = 0.025
VGICP_VOXEL_M = 0.05  # Gaussian voxel map of VGICP's target (its clouds are downsampled at GICP_VOXEL_M)
NEIGHBOURS = 20
MAX_CORRESPONDENCE_M = 0.1
DEPTH_MAX_M = 4.5


def _open3d_rgbd() -> _Pairwise:
    """Open3D RGB-D odometry (tensor pipeline, ``Method.Hybrid``: photometric + geometric terms, colour as float
    RGB in [0, 1]), iterations (20, 10, 5) coarse to fine, depths up to DEPTH_MAX_M."""
    import open3d as o3d

    odo = o3d.t.pipelines.odometry
    criteria = [odo.OdometryConvergenceCriteria(n) for n in (20, 10, 5)]

    def prepare(frame: RGBDFrame):
        depth = np.where(np.isfinite(frame.depth_m), frame.depth_m, 0).astype(np.float32)[..., None]
        color = np.ascontiguousarray(frame.rgb, dtype=np.float32) / np.float32(255.0)
        image = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(o3d.core.Tensor(color)),
                                         o3d.t.geometry.Image(o3d.core.Tensor(depth)))
        return image, o3d.core.Tensor(np.asarray(frame.K, dtype=np.float64))

    def register(prev, cur, init):
        result = odo.rgbd_odometry_multi_scale(cur[0], prev[0], cur[1], o3d.core.Tensor(init), 1.0, DEPTH_MAX_M,
                                               criteria, odo.Method.Hybrid)
        return result.transformation.numpy() if result.fitness > 0 else None

    return _Pairwise(prepare, register)


def _open3d_rgbd_legacy() -> _Pairwise:
    """Open3D RGB-D odometry (legacy pipeline), ``RGBDOdometryJacobianFromHybridTerm``, default iterations (20, 10,
    5) and depth_diff_max 0.03 m, depths up to DEPTH_MAX_M; about twice as slow as the tensor pipeline here."""
    import open3d as o3d

    odo = o3d.pipelines.odometry
    option = odo.OdometryOption(depth_max=DEPTH_MAX_M)
    jacobian = odo.RGBDOdometryJacobianFromHybridTerm()

    def prepare(frame: RGBDFrame):
        h, w = frame.depth_m.shape
        K = frame.K
        depth = np.where(np.isfinite(frame.depth_m), frame.depth_m, 0).astype(np.float32)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(frame.rgb)), o3d.geometry.Image(depth), depth_scale=1.0,
            depth_trunc=DEPTH_MAX_M, convert_rgb_to_intensity=True)
        return rgbd, o3d.camera.PinholeCameraIntrinsic(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])

    def register(prev, cur, init):
        ok, T, _ = odo.compute_rgbd_odometry(cur[0], prev[0], cur[1], init, jacobian, option)
        return np.asarray(T) if ok else None

    return _Pairwise(prepare, register)


def _open3d_icp() -> _Pairwise:
    """Open3D point-to-plane ICP on the back-projected depth (voxels of ICP_VOXEL_M, normals from up to 20
    neighbours within 0.1 m, correspondences within MAX_CORRESPONDENCE_M, up to 30 iterations)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=30)

    def prepare(frame: RGBDFrame):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_points(frame))).voxel_down_sample(ICP_VOXEL_M)
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=NEIGHBOURS))
        return cloud

    def register(prev, cur, init):
        if len(cur.points) < 10 or len(prev.points) < 10:
            return None
        result = reg.registration_icp(cur, prev, MAX_CORRESPONDENCE_M, init,
                                      reg.TransformationEstimationPointToPlane(), criteria)
        return np.asarray(result.transformation) if result.fitness > 0 else None

    return _Pairwise(prepare, register)


def _small_gicp(kind: str) -> _Pairwise:
    """small_gicp GICP (target k-d tree) or VGICP (target Gaussian voxel map of VGICP_VOXEL_M) on the back-projected
    depth downsampled to GICP_VOXEL_M, covariances from NEIGHBOURS neighbours, correspondences within
    MAX_CORRESPONDENCE_M, up to 30 iterations."""
    import small_gicp

    def prepare(frame: RGBDFrame):
        cloud, tree = small_gicp.preprocess_points(_points(frame), downsampling_resolution=GICP_VOXEL_M,
                                                   num_neighbors=NEIGHBOURS, num_threads=1)
        target = tree
        if kind == "VGICP":
            target = small_gicp.GaussianVoxelMap(VGICP_VOXEL_M)
            target.insert(cloud)
        return cloud, target

    def register(prev, cur, init):
        if cur[0].size() < 10 or prev[0].size() < 10:
            return None
        if kind == "VGICP":
            result = small_gicp.align(prev[1], cur[0], init, max_correspondence_distance=MAX_CORRESPONDENCE_M,
                                      num_threads=1, max_iterations=30)
        else:
            result = small_gicp.align(prev[0], cur[0], prev[1], init, registration_type="GICP",
                                      max_correspondence_distance=MAX_CORRESPONDENCE_M, num_threads=1,
                                      max_iterations=30)
        return result.T_target_source if result.converged else None

    return _Pairwise(prepare, register)


METHODS: dict[str, Callable[[], object]] = {
    "difodo-qvga": lambda: _Ours("difodo", max_rows=240),
    "difodo-qqvga": lambda: _Ours("difodo", max_rows=120),
    "vosf": lambda: _Ours("vosf"),
    "open3d-rgbd": _open3d_rgbd,
    "open3d-icp": _open3d_icp,
    "gicp": lambda: _small_gicp("GICP"),
    "vgicp": lambda: _small_gicp("VGICP"),
    "open3d-rgbd-legacy": _open3d_rgbd_legacy,
}
DEFAULT_METHODS = [m for m in METHODS if m != "open3d-rgbd-legacy"]


# ------------------------------------------------------------------------------------------------ evaluation
@dataclass
class FlowScore:
    """Joint-VO-SF's scene flow and segmentation on one sequence."""

    pairs: int = 0
    max_v_m: list[float] = field(default_factory=list)
    nrms: list[float] = field(default_factory=list)
    aae_deg: list[float] = field(default_factory=list)
    moving: int = 0
    moving_labelled: int = 0
    static: int = 0
    static_labelled: int = 0
    median_residual: list[float] = field(default_factory=list)  # per pair: the clusters' median residual (7)
    rows: list[str] = field(default_factory=list)  # per frame with moving pixels: a CSV row (SEGMENTATION_HEADER)

    def add(self, seq: Sequence, k: int, extra: dict) -> None:
        """Scores the flow and segmentation of frame k (estimated against frame k - 1)."""
        if k == 0 or not extra.get("measured", False):
            return
        frame = seq.frames[k]
        dt = frame.stamp_s - seq.frames[k - 1].stamp_s
        truth = seq.velocity(k).reshape(3, -1).astype(np.float64) * dt
        speed = np.linalg.norm(truth, axis=0) / dt
        depth_ok = (np.isfinite(frame.depth_m) & (frame.depth_m > 0)).ravel()
        moving_true, static_true = depth_ok & (speed >= MOVING_SPEED_M_S), depth_ok & (speed == 0)
        labelled = np.asarray(extra["moving_mask"], dtype=bool).ravel()
        residuals = np.asarray(extra["cluster_residuals"], dtype=np.float64)
        if np.isfinite(residuals).any():
            self.median_residual.append(float(np.nanmedian(residuals)))
        self.moving += int(moving_true.sum())
        self.moving_labelled += int((moving_true & labelled).sum())
        self.static += int(static_true.sum())
        self.static_labelled += int((static_true & labelled).sum())
        if moving_true.any():
            self.rows.append(_segmentation_row(k, frame, speed, moving_true, static_true, labelled))
        flow = np.asarray(extra["scene_flow_m"], dtype=np.float64).reshape(3, -1)
        scored = depth_ok & np.all(np.isfinite(flow), axis=0)
        movers = scored & moving_true
        if movers.sum() < MIN_MOVING_PIXELS:
            return
        max_v = float(np.max(np.linalg.norm(truth[:, scored], axis=0)))
        error = flow[:, scored] - truth[:, scored]
        self.max_v_m.append(max_v)
        self.nrms.append(float(np.sqrt(np.mean(np.sum(error**2, axis=0)))) / max_v)
        a, b = flow[:, movers], truth[:, movers]
        cos = np.sum(a * b, axis=0) / np.maximum(np.linalg.norm(a, axis=0) * np.linalg.norm(b, axis=0), 1e-12)
        self.aae_deg.append(float(np.degrees(np.mean(np.arccos(np.clip(cos, -1.0, 1.0))))))
        self.pairs += 1


SEGMENTATION_HEADER = ("frame,moving_px,moving_labelled_px,static_px,static_labelled_px,"
                       "missed_median_depth_m,missed_median_speed_m_s")


def _segmentation_row(k: int, frame: RGBDFrame, speed: np.ndarray, moving: np.ndarray, static: np.ndarray,
                      labelled: np.ndarray) -> str:
    """One frame's segmentation as a CSV row: counts of moving and static pixels and of those labelled moving, and
    the median depth (m) and true speed (m/s) of the moving pixels left unlabelled (empty when none)."""
    missed = moving & ~labelled
    depth = np.ravel(frame.depth_m)[missed]
    where = f"{np.median(depth):.2f},{np.median(speed[missed]):.2f}" if missed.any() else ","
    return f"{k},{moving.sum()},{(moving & labelled).sum()},{static.sum()},{(static & labelled).sum()},{where}"


@dataclass
class Row:
    rpe_cm_s: float
    rpe_deg_s: float
    ate_cm: float
    runtime_ms: tuple[float, float]
    failures: int
    flow: FlowScore | None = None


_WARM: set[str] = set()


def run(method: str, seq: Sequence, per_frame: Path | None = None) -> Row:
    """Runs one method over a sequence and scores it against the ground truth.

    The first time a method runs in this process, a throw-away instance first processes 3 frames (loading compiled
    kernels and libraries is not timed). With ``per_frame``, the error of every frame-to-frame increment is written
    there as CSV (:func:`write_per_frame`).
    """
    if method not in _WARM:
        warm = METHODS[method]()
        for frame in seq.frames[:3]:
            warm.process(frame)
        _WARM.add(method)
    odometry = METHODS[method]()
    flow = FlowScore() if method == "vosf" else None  # static runs: its false positives
    poses, times, degenerate = [], [], []
    for k, frame in enumerate(seq.frames):
        t0 = time.perf_counter()
        T = odometry.process(frame)
        times.append(time.perf_counter() - t0)
        poses.append(seq.T_world_camera[0] @ T)  # the estimate starts at the true first pose
        degenerate.append(bool(odometry.last.degenerate) if isinstance(odometry, _Ours) else False)
        if flow is not None:
            flow.add(seq, k, odometry.last.extra)
    if per_frame is not None:
        write_per_frame(per_frame, seq, np.array(poses), degenerate)
        if flow is not None and flow.rows:
            seg_csv = per_frame.with_name(per_frame.stem + "_segmentation.csv")
            seg_csv.write_text("\n".join([SEGMENTATION_HEADER, *flow.rows]) + "\n")
    est, gt = Trajectory(seq.stamps_s, np.array(poses)), Trajectory(seq.stamps_s, seq.T_world_camera)
    rpe = rpe_per_second(est, gt)
    ms = np.array(times[1:]) * 1e3
    return Row(rpe.trans_rmse_cm_s, rpe.rot_rmse_deg_s, 100 * ate(est, gt, "se3").rmse_m,
               (float(np.median(ms)), float(np.percentile(ms, 95))), odometry.failures, flow)


def write_per_frame(path: Path, seq: Sequence, T_world_camera: np.ndarray, degenerate: list[bool]) -> None:
    """CSV of every frame-to-frame increment of an estimate against the ground truth: frame, stamp_s, true and
    estimated speed (norm of the translation over the interval, m/s), translational and rotational error of the
    increment (m/s, deg/s; the true increment's inverse times the estimated one), and the method's degeneracy flag
    (simnav's methods; False for the peers). ``T_world_camera``: (N, 4, 4) estimated poses."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["frame,stamp_s,true_speed_m_s,est_speed_m_s,trans_error_m_s,rot_error_deg_s,degenerate"]
    for k in range(1, len(seq.frames)):
        dt = float(seq.stamps_s[k] - seq.stamps_s[k - 1]) or 1.0
        true = se3.inverse(seq.T_world_camera[k - 1]) @ seq.T_world_camera[k]
        est = se3.inverse(T_world_camera[k - 1]) @ T_world_camera[k]
        err = se3.inverse(true) @ est
        angle = math.degrees(np.linalg.norm(se3.so3_log(err[:3, :3])))
        lines.append(f"{k},{seq.stamps_s[k]:.6f},{np.linalg.norm(true[:3, 3]) / dt:.4f},"
                     f"{np.linalg.norm(est[:3, 3]) / dt:.4f},{np.linalg.norm(err[:3, 3]) / dt:.4f},{angle / dt:.4f},"
                     f"{int(degenerate[k])}")
    path.write_text("\n".join(lines) + "\n")


def _spread(values: list[float]) -> str:
    """'median (10th-90th percentile)' of per-pair values, or '-'."""
    if not values:
        return "-"
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return f"{p50:.4f} ({p10:.4f}-{p90:.4f})"


def _motion_stats(seq: Sequence) -> tuple[float, float, float]:
    """Path length (m), mean speed (cm/s) and mean turn rate (deg/s) of the camera."""
    T = seq.T_world_camera
    steps = [se3.inverse(a) @ b for a, b in zip(T[:-1], T[1:])]
    length = float(sum(np.linalg.norm(s[:3, 3]) for s in steps))
    angle = float(sum(np.linalg.norm(se3.so3_log(s[:3, :3])) for s in steps))
    duration = float(seq.stamps_s[-1] - seq.stamps_s[0]) or 1.0
    return length, 100 * length / duration, math.degrees(angle) / duration


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per sequence (30 Hz)")
    parser.add_argument("--sequences", nargs="+", default=DEFAULT_SEQUENCES, choices=ALL_SEQUENCES)
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS, choices=list(METHODS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--candidates", type=int, default=4, help="seeds tried per sequence with people")
    parser.add_argument("--per-frame", type=Path, metavar="DIR",
                        help="write DIR/<sequence>_<method>.csv: the error of every frame-to-frame increment "
                             "(and DIR/<sequence>_vosf_segmentation.csv: Joint-VO-SF's segmentation per frame)")
    parser.add_argument("--vosf-set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="Joint-VO-SF config fields, e.g. residual_floor=0.007 residual_ceiling=0.015")
    parser.add_argument("--difodo-set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="DIFODO config fields (both resolutions), e.g. hold_degenerate_levels=false")
    args = parser.parse_args()
    try:
        vosf_config = apply_overrides({}, args.vosf_set, "--vosf-set")
        make_frame_odometry("vosf", **vosf_config)
        difodo_config = apply_overrides({}, args.difodo_set, "--difodo-set")
        make_frame_odometry("difodo", **difodo_config)
    except ConfigError as err:
        parser.error(str(err))
    METHODS["vosf"] = lambda: _Ours("vosf", **vosf_config)
    METHODS["difodo-qvga"] = lambda: _Ours("difodo", **{"max_rows": 240, **difodo_config})
    METHODS["difodo-qqvga"] = lambda: _Ours("difodo", **{"max_rows": 120, **difodo_config})
    console = Console()
    if not console.is_terminal:
        console = Console(width=150)
    seq_table = Table("sequence", "seed", "frames", "path m", "cm/s", "deg/s", "valid px %", "dynamic px %",
                      "dynamic max %", title=f"sequences: office, giraff, kinect_qvga 320x240 @ 30 Hz "
                      f"(simnav {simnav.__version__})")
    odo_table = Table("sequence", "method", "RPE cm/s", "RPE deg/s", "ATE cm", "ms median", "ms p95", "lost",
                      title="odometry of the camera optical frame (RPE per second, pairs 1 s apart; ATE SE(3)-aligned)",
                      caption="lost: frames whose registration failed (the previous increment was kept). Targets of "
                      "issue 4: DIFODO <= 15 ms per QVGA frame, Joint-VO-SF <= 40 ms; DIFODO's RPE no worse than "
                      "Open3D ICP's on static runs; Joint-VO-SF's at most half DIFODO's on dynamic runs")
    flow_table = Table("sequence", "pairs", "MAX-V cm", "NRMS-V", "AAE deg", "moving px labelled moving %",
                       "static px labelled moving %", "median residual (7)",
                       title="Joint-VO-SF scene flow (thesis Table 4.1) and "
                       f"segmentation (seed 001 Table I); moving = true speed >= {MOVING_SPEED_M_S:g} m/s",
                       caption=f"flow over pairs with >= {MIN_MOVING_PIXELS} moving pixels; targets of issue 4: "
                       ">= 90 % of moving pixels labelled moving, <= 5 % of static pixels")
    missing: dict[str, str] = {}
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("", total=len(args.sequences) * (1 + len(args.methods)))
        for name in args.sequences:
            folder = simulate(name, args.seconds, args.seed, args.candidates,
                              lambda text: bar.update(task, description=text))
            bar.update(task, description=f"loading {name}")
            seq = load(folder)
            length, speed, turn = _motion_stats(seq)
            seq_table.add_row(name, str(seq.info["seed"]), str(len(seq.frames)), f"{length:.1f}", f"{speed:.1f}",
                              f"{turn:.1f}", f"{seq.valid_pct:.1f}", f"{seq.dynamic_pct:.1f}",
                              f"{seq.dynamic_max_pct:.1f}")
            bar.advance(task)
            for method in args.methods:
                bar.update(task, description=f"{name}: {method}")
                if method in missing:
                    bar.advance(task)
                    continue
                try:
                    csv = args.per_frame / f"{name}_{method}.csv" if args.per_frame else None
                    row = run(method, seq, csv)
                except ImportError as err:
                    missing[method] = str(err)
                    console.print(f"[yellow]{method}: not installed ({err}); skipped")
                    bar.advance(task)
                    continue
                odo_table.add_row(name, method, f"{row.rpe_cm_s:.2f}", f"{row.rpe_deg_s:.3f}", f"{row.ate_cm:.2f}",
                                  f"{row.runtime_ms[0]:.1f}", f"{row.runtime_ms[1]:.1f}", str(row.failures))
                if row.flow is not None:
                    f = row.flow
                    pct = (lambda a, b: f"{100 * a / b:.1f}" if b else "-")
                    flow_table.add_row(name, str(f.pairs), f"{100 * np.mean(f.max_v_m):.2f}" if f.pairs else "-",
                                       f"{np.mean(f.nrms):.3f}" if f.pairs else "-",
                                       f"{np.mean(f.aae_deg):.1f}" if f.pairs else "-",
                                       pct(f.moving_labelled, f.moving), pct(f.static_labelled, f.static),
                                       _spread(f.median_residual))
                bar.advance(task)
            odo_table.add_section()
    console.print(f"[dim]{args.seconds:g} s per sequence, seed {args.seed}, {args.candidates} candidate seeds with "
                  f"people; cache {CACHE}/[/]" + (f"\n[dim]Joint-VO-SF with {vosf_config}[/]" if vosf_config else "")
                  + (f"\n[dim]DIFODO with {difodo_config}[/]" if difodo_config else ""))
    console.print(seq_table)
    console.print(odo_table)
    if flow_table.row_count:
        console.print(flow_table)


if __name__ == "__main__":
    main()
