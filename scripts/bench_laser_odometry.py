"""Planar laser odometry side by side: SRF (CA, KA, MA), RF2O, small_gicp GICP, KISS-ICP and Open3D ICP.

Every method runs in this process on the same simulated scans: a robot with a Hokuyo UTM-30LX (1080 rays, 270
degrees, sigma = 1 cm) follows the roadmap at up to 0.5 m/s and 45 deg/s in the curved, office and polygonal
worlds and in the polygonal world with 3, 5 and 7 wandering robots. Scans are recorded at 10 Hz and evaluated at
5 Hz and 2 Hz. For each run the script prints the RPE per second (cm/s, deg/s), the drift over 10 m segments and
the runtime per scan (median, p95). small_gicp (GICP) and Open3D (point-to-plane ICP) register consecutive scans
lifted into three parallel planes (see LIFT_Z_M); KISS-ICP keeps its own map.

    python scripts/bench_laser_odometry.py [--minutes 10] [--worlds curved office polygonal dynamic3 ...]
                                           [--methods srf-ca rf2o small_gicp ...] [--rates 5 2]

Sequences are simulated once and cached under runs/bench_laser_cache/. The peers come with `pip install -e
".[peers]"`; a missing peer is reported and skipped.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

import simnav  # first: it chooses MUJOCO_GL before mujoco loads
from simnav.geometry import se2
from simnav.io import Trajectory
from simnav.metrics import drift_per_segment, rpe_per_second
from simnav.mission.follower import RoadmapFollower
from simnav.odometry import laser_to_base_motion, make_scan_odometry, planar_scan
from simnav.robot import load_robot
from simnav.sensors.readings import LaserScan
from simnav.sim import SimConfig, Simulator
from simnav.world import load_world

CACHE = Path("runs/bench_laser_cache")
SCAN_RATE_HZ = 10.0
ROBOT = [
    "drive.max_v_m_s=0.5", "drive.max_w_deg_s=45",
    "sensors=[{name: laser, type: lidar2d, preset: hokuyo_utm30lx, rate_hz: 10, noise_std_m: 0.01,"
    " mount: {xyz_m: [0.2, 0.0, 0.3]}}]",
]
WORLDS = {"curved": ("curved", 0), "office": ("office", 0), "polygonal": ("polygonal", 0),
          "dynamic3": ("polygonal", 3), "dynamic5": ("polygonal", 5), "dynamic7": ("polygonal", 7)}
HELD_OPEN = {"office-static": "office"}
"""Extra worlds with every door held open: static, like the thesis' maps A-C (reproduce_srf_tables.py)."""


@dataclass
class Sequence:
    """Scans (N, beams) with their stamps, the ground-truth base poses at those stamps, and the scanner."""

    name: str
    stamps_s: np.ndarray
    ranges_m: np.ndarray
    gt_xy_yaw: np.ndarray
    angles_rad: np.ndarray
    T_base_sensor: np.ndarray
    max_range_m: float
    min_range_m: float

    def scan(self, k: int) -> LaserScan:
        return LaserScan("laser", float(self.stamps_s[k]), self.ranges_m[k], self.angles_rad, self.max_range_m,
                         self.min_range_m, self.T_base_sensor)

    def every(self, step: int) -> Sequence:
        return Sequence(self.name, self.stamps_s[::step], self.ranges_m[::step], self.gt_xy_yaw[::step],
                        self.angles_rad, self.T_base_sensor, self.max_range_m, self.min_range_m)


def simulate(name: str, seconds: float, seed: int = 0) -> Sequence:
    """Record (or load from the cache) ``seconds`` of scans in a benchmark world."""
    world_name, wanderers = WORLDS[name] if name in WORLDS else (HELD_OPEN[name], 0)
    path = CACHE / f"{name}-{seconds:.0f}s-seed{seed}-v5.npz"
    if path.is_file():
        d = np.load(path)
        return Sequence(name, d["stamps_s"], d["ranges_m"], d["gt_xy_yaw"], d["angles_rad"], d["T_base_sensor"],
                        float(d["max_range_m"]), float(d["min_range_m"]))
    robot = load_robot("giraff", ROBOT)
    config = SimConfig(pedestrians=0, wanderers=wanderers)
    stamps, ranges, poses = [], [], []
    world = load_world(world_name)
    if name in HELD_OPEN:
        world = world.model_copy(update={"doors": [d.model_copy(update={"open_s": 1e9, "phase_s": 0.0})
                                                   for d in world.doors]})
    with Simulator(world, robot, config, seed=seed) as sim:
        follower = RoadmapFollower(sim.roadmap, np.array(sim.pose_xy_yaw[:2]), np.random.default_rng(seed),
                                   robot.drive.max_v_m_s, robot.drive.max_w_rad_s)
        scan = sim.capture_now("laser")
        for _ in range(math.ceil(seconds / sim.config.control_dt_s)):
            v, w = follower.command(*sim.pose_xy_yaw)
            for reading in sim.step(v if clear_ahead(sim, scan) else 0.0, w):
                T = sim.T_world_base_at(reading.stamp_s)
                stamps.append(reading.stamp_s)
                ranges.append(reading.ranges_m)
                poses.append((T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])))
                scan = reading
    seq = Sequence(name, np.array(stamps), np.array(ranges), np.array(poses), scan.angles_rad, scan.T_base_sensor,
                   scan.max_range_m, scan.min_range_m)
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, stamps_s=seq.stamps_s, ranges_m=seq.ranges_m, gt_xy_yaw=seq.gt_xy_yaw, angles_rad=seq.angles_rad,
             T_base_sensor=seq.T_base_sensor, max_range_m=seq.max_range_m, min_range_m=seq.min_range_m)
    return seq


def clear_ahead(sim: Simulator, scan: LaserScan, distance_m: float = 1.0, stop_range_m: float = 0.6,
                half_angle_rad: float = math.radians(40)) -> bool:
    """Whether the robot may drive on: no wandering robot within ``distance_m`` ahead of the base and no laser return
    within ``stop_range_m`` ahead of the scanner (a closing door, a robot). The roadmap follower has no obstacle
    avoidance, so it waits instead of pushing into things, which would corrupt the ground truth of the run."""
    x, y, yaw = sim.pose_xy_yaw
    offsets = sim.wanderers.positions_xy - (x, y)
    distance = np.hypot(offsets[:, 0], offsets[:, 1])
    bearing = np.arctan2(offsets[:, 1], offsets[:, 0]) - yaw
    ahead = np.abs(np.arctan2(np.sin(bearing), np.cos(bearing))) < half_angle_rad
    front = (np.abs(scan.angles_rad) < half_angle_rad) & scan.valid
    blocked = bool(np.any(np.asarray(scan.ranges_m)[front] < stop_range_m))
    return not np.any(ahead & (distance < distance_m)) and not blocked


# ------------------------------------------------------------------------------------------------ methods
class _PairwisePeer:
    """Consecutive-scan registration with a peer library: T_prev_curr of the scanner, composed into a pose."""

    def __init__(self, register: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> None:
        self._register = register
        self._prev: np.ndarray | None = None
        self._delta = np.eye(4)
        self.T_odom_base = np.eye(3)

    def process(self, scan: LaserScan) -> np.ndarray:
        upright = planar_scan(scan)
        ok = upright.ranges_m > 0
        r, a = upright.ranges_m[ok], upright.angles_rad[ok]
        points = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))])
        if self._prev is not None:
            self._delta = self._register(self._prev, points, self._delta)
            T_prev_curr = se2.from_se3(self._delta)
            self.T_odom_base = self.T_odom_base @ laser_to_base_motion(T_prev_curr, upright.T_base_laser)
        self._prev = points
        return self.T_odom_base


# Planar scans become three copies 0.2 m apart in z, so that walls are vertical planes: without it, the normals and
# covariances the peers estimate from neighbours all point along z and plane-based registration breaks down.
LIFT_Z_M = (-0.2, 0.0, 0.2)


def _lift(points: np.ndarray) -> np.ndarray:
    """(3N, 3) the (N, 3) z = 0 points repeated at the heights of ``LIFT_Z_M``."""
    return np.concatenate([points + (0.0, 0.0, z) for z in LIFT_Z_M])


def _small_gicp() -> _PairwisePeer:
    """small_gicp GICP on lifted scans (of its ICP, PLANE_ICP and GICP this is by far the most accurate here)."""
    import small_gicp

    def register(target, source, init):
        result = small_gicp.align(_lift(target), _lift(source), init_T_target_source=init, registration_type="GICP",
                                  downsampling_resolution=0.05, max_correspondence_distance=0.5, num_threads=1,
                                  max_iterations=50, rotation_epsilon=1e-5, translation_epsilon=1e-5)
        return result.T_target_source

    return _PairwisePeer(register)


def _open3d() -> _PairwisePeer:
    """Open3D point-to-plane ICP on lifted scans, normals from 20 neighbours within 0.3 m."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(relative_fitness=1e-8, relative_rmse=1e-8, max_iteration=50)

    def cloud(points: np.ndarray):
        c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(points)))
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.3, max_nn=20))
        return c

    def register(target, source, init):
        result = reg.registration_icp(cloud(source), cloud(target), 0.5, init,
                                      reg.TransformationEstimationPointToPlane(), criteria)
        return np.asarray(result.transformation)

    return _PairwisePeer(register)


class _KissICP:
    """KISS-ICP fed the scans as z = 0 point clouds (deskew off, voxel 0.1 m: smaller voxels or lifted scans were no
    better on these runs), its pose mapped to the base."""

    def __init__(self) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        config = KISSConfig()
        config.data.max_range, config.data.min_range, config.data.deskew = 30.0, 0.1, False
        config.mapping.voxel_size = 0.1
        self._odometry = KissICP(config)
        self.T_odom_base = np.eye(3)

    def process(self, scan: LaserScan) -> np.ndarray:
        upright = planar_scan(scan)
        ok = upright.ranges_m > 0
        r, a = upright.ranges_m[ok], upright.angles_rad[ok]
        self._odometry.register_frame(np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))]),
                                      np.array([]))
        T_odom_laser = se2.from_se3(self._odometry.last_pose)
        T_base_laser = upright.T_base_laser
        self.T_odom_base = T_base_laser @ T_odom_laser @ se2.inverse(T_base_laser)
        return self.T_odom_base


class _Ours:
    def __init__(self, name: str, **config) -> None:
        self._odometry = make_scan_odometry(name, **config)

    def process(self, scan: LaserScan) -> np.ndarray:
        return self._odometry.process(scan).T_odom_base


METHODS: dict[str, Callable[[], object]] = {
    "srf-ca": lambda: _Ours("srf", mode="CA"),
    "srf-ka": lambda: _Ours("srf", mode="KA"),
    "srf-ma": lambda: _Ours("srf", mode="MA"),
    "rf2o": lambda: _Ours("rf2o"),
    "small_gicp": _small_gicp,
    "kiss_icp": _KissICP,
    "open3d": _open3d,
}


# --------------------------------------------------------------------------------------------- evaluation
@dataclass
class Row:
    rpe_cm_s: float
    rpe_deg_s: float
    drift_pct: float
    runtime_ms: tuple[float, float]


def run(method: str, seq: Sequence) -> Row:
    """Run one method over a sequence and score it against the ground truth."""
    odometry = METHODS[method]()
    poses, times = [], []
    for k in range(len(seq.stamps_s)):
        scan = seq.scan(k)
        t0 = time.perf_counter()
        T = odometry.process(scan)
        times.append(time.perf_counter() - t0)
        poses.append(se2.to_se3(T))
    est = Trajectory(seq.stamps_s, np.array(poses))
    gt = Trajectory(seq.stamps_s, np.array([se2.to_se3(se2.from_xy_yaw(*p)) for p in seq.gt_xy_yaw]))
    rpe = rpe_per_second(est, gt)
    drift = drift_per_segment(est, gt, lengths_m=(10.0,))
    ms = np.array(times[1:]) * 1e3
    return Row(rpe.trans_rmse_cm_s, rpe.rot_rmse_deg_s, drift[10.0].translation_pct if 10.0 in drift else float("nan"),
               (float(np.median(ms)), float(np.percentile(ms, 95))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--worlds", nargs="+", default=list(WORLDS), choices=list(WORLDS))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--rates", nargs="+", type=float, default=[5.0, 2.0])
    args = parser.parse_args()
    console = Console()
    title = f"planar laser odometry, UTM-30LX, {args.minutes:g} min per world (simnav {simnav.__version__})"
    table = Table("world", "rate", "method", "RPE cm/s", "RPE deg/s", "drift % (10 m)", "ms median", "ms p95",
                  title=title)
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("simulating", total=len(args.worlds) * (1 + len(args.rates) * len(args.methods)))
        for name in args.worlds:
            full = simulate(name, args.minutes * 60)
            bar.advance(task)
            for rate in args.rates:
                seq = full.every(round(SCAN_RATE_HZ / rate))
                for method in args.methods:
                    bar.update(task, description=f"{name} {rate:g} Hz {method}")
                    try:
                        row = run(method, seq)
                    except ImportError as err:
                        console.print(f"[yellow]{method}: not installed ({err}); skipped")
                        bar.advance(task)
                        continue
                    table.add_row(name, f"{rate:g} Hz", method, f"{row.rpe_cm_s:.2f}", f"{row.rpe_deg_s:.3f}",
                                  f"{row.drift_pct:.2f}", f"{row.runtime_ms[0]:.2f}", f"{row.runtime_ms[1]:.2f}")
                    bar.advance(task)
    console.print(table)


if __name__ == "__main__":
    main()
