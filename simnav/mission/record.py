"""``simnav record``: drive a robot along the roadmap among people and write a dataset anyone can use.

Layout of the output folder::

    groundtruth.txt        base pose in the world at every control step (TUM)
    <laser>.clf            each 2D lidar as a CARMEN log: ROBOTLASER1 (robot pose = wheel odometry), ODOM, TRUEPOS
    <lidar3d>/<t>.npy      3D lidar sweeps, (N, 3) float32 points in the sensor frame
    wheels.txt             timestamp left_ticks right_ticks
    <camera>/              TUM RGB-D layout: rgb/, depth/ (16-bit PNG, depth x 5000), rgb.txt, depth.txt,
                           segmentation/ (body id + 1), motion/ (per-pixel world velocity, optical frame),
                           camera.yaml, groundtruth.txt (optical frame pose in the world)
    contacts.txt           contact events
    record.yaml world.yaml robot.yaml   the settings and the resolved world and robot

The same settings and seed give the same bytes.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from simnav.config import FrozenModel, dump_yaml
from simnav.io import CarmenWriter, RGBDDatasetWriter, TumWriter
from simnav.mission.follower import RoadmapFollower
from simnav.odometry.wheels import WheelOdometry
from simnav.robot.spec import RobotSpec
from simnav.sensors.readings import LaserScan, PointCloud, Reading, RGBDFrame, WheelTicks
from simnav.sim import SimConfig, Simulator
from simnav.world.schema import WorldSpec

MAX_FRAMES_IN_FLIGHT = 32


class RecordSettings(FrozenModel):
    """What to record: how long, which seed, which simulator settings."""

    duration_s: Annotated[float, Field(gt=0, le=86400)] = 30.0
    seed: int = 0
    sim: SimConfig = SimConfig()
    cameras: bool = True
    lasers: bool = True


@dataclass
class RecordSummary:
    """What a recording produced."""

    out_dir: Path
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    distance_m: float = 0.0
    nodes_reached: int = 0
    readings: dict[str, int] = field(default_factory=dict)
    contacts: int = 0

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


def record(world: WorldSpec, robot: RobotSpec, out_dir: Path, settings: RecordSettings = RecordSettings(),
           progress: Callable[[float], None] | None = None) -> RecordSummary:
    """Run the simulation for ``settings.duration_s`` and write the dataset into ``out_dir``.

    Args:
        progress: called with the simulated time (s) after every control step.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _write_configs(out_dir, world, robot, settings)
    sim = Simulator(world, robot, settings.sim.model_copy(update={"lockstep": False}), seed=settings.seed)
    follower = RoadmapFollower(sim.roadmap, np.array(sim.pose_xy_yaw[:2]),
                               np.random.default_rng(np.random.SeedSequence([settings.seed, 1])),
                               robot.drive.max_v_m_s, robot.drive.max_w_rad_s)
    summary = RecordSummary(out_dir=out_dir)
    steps = math.ceil(settings.duration_s / sim.config.control_dt_s - 1e-9)
    started = time.perf_counter()
    with sim, _Writers(out_dir, sim, settings) as writers:
        writers.ground_truth(0.0, sim.T_world_base)
        last_xy = np.array(sim.pose_xy_yaw[:2])
        for _ in range(steps):
            v, w = follower.command(*sim.pose_xy_yaw)
            for reading in sim.step(v, w):
                writers.write(reading)
                summary.readings[reading.sensor] = summary.readings.get(reading.sensor, 0) + 1
            writers.ground_truth(sim.time_s, sim.T_world_base)
            xy = np.array(sim.pose_xy_yaw[:2])
            summary.distance_m += float(np.linalg.norm(xy - last_xy))
            last_xy = xy
            if progress is not None:
                progress(sim.time_s)
        for reading in sim.flush():
            writers.write(reading)
            summary.readings[reading.sensor] = summary.readings.get(reading.sensor, 0) + 1
        writers.contacts(sim.contact_events)
    summary.wall_time_s = time.perf_counter() - started
    summary.sim_time_s = sim.time_s
    summary.nodes_reached = follower.nodes_reached
    summary.contacts = len(sim.contact_events)
    return summary


def _write_configs(out_dir: Path, world: WorldSpec, robot: RobotSpec, settings: RecordSettings) -> None:
    (out_dir / "record.yaml").write_text(dump_yaml(settings))
    (out_dir / "world.yaml").write_text(dump_yaml(world))
    (out_dir / "robot.yaml").write_text(dump_yaml(robot))


class _Writers:
    """Routes readings to the files of the dataset."""

    def __init__(self, out_dir: Path, sim: Simulator, settings: RecordSettings) -> None:
        self._out, self._sim, self._settings = out_dir, sim, settings
        self._gt = TumWriter(out_dir / "groundtruth.txt")
        self._odom = WheelOdometry()
        self._lasers: dict[str, CarmenWriter] = {}
        self._cameras: dict[str, tuple[RGBDDatasetWriter, TumWriter]] = {}
        self._wheels = open(out_dir / "wheels.txt", "w", encoding="ascii", newline="\n")  # noqa: SIM115
        self._wheels.write("# timestamp left_ticks right_ticks\n")
        # image files are encoded on one background thread (PNG/zlib release the GIL), in submission order
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="simnav-writer")
        self._in_flight = threading.BoundedSemaphore(MAX_FRAMES_IN_FLIGHT)
        self._futures: list[Future] = []

    def __enter__(self) -> _Writers:
        return self

    def __exit__(self, *exc) -> None:
        self._pool.shutdown(wait=True)
        self._raise_failed(all_done=True)
        self._gt.close()
        self._wheels.close()
        for w in self._lasers.values():
            w.close()
        for rgbd, gt in self._cameras.values():
            rgbd.close()
            gt.close()

    def ground_truth(self, stamp_s: float, T_world_base: np.ndarray) -> None:
        self._gt.write(stamp_s, T_world_base)

    def write(self, reading: Reading) -> None:
        if isinstance(reading, WheelTicks):
            self._write_wheels(reading)
        elif isinstance(reading, LaserScan) and self._settings.lasers:
            self._write_scan(reading)
        elif isinstance(reading, RGBDFrame) and self._settings.cameras:
            self._write_frame(reading)
        elif isinstance(reading, PointCloud) and self._settings.lasers:
            folder = self._out / reading.sensor
            folder.mkdir(exist_ok=True)
            np.save(folder / f"{reading.stamp_s:.6f}.npy", reading.points_sensor)

    def _write_wheels(self, ticks: WheelTicks) -> None:
        pose = self._odom.update(ticks)
        self._wheels.write(f"{ticks.stamp_s:.6f} {ticks.left_ticks} {ticks.right_ticks}\n")
        for log in self._lasers.values():
            log.write_odom(ticks.stamp_s, pose, *self._odom.twist)

    def _write_scan(self, scan: LaserScan) -> None:
        log = self._lasers.get(scan.sensor)
        if log is None:
            log = self._lasers[scan.sensor] = CarmenWriter(self._out / f"{scan.sensor}.clf")
            log.write_param("robot_name", self._sim.robot.name)
            log.write_param("world_name", self._sim.world.name)
        odom = self._odom.pose_xyt
        log.write_robotlaser(scan, None, odom, *self._odom.twist)
        T = self._sim.T_world_base_at(scan.stamp_s)
        log.write_truepos(scan.stamp_s, np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])]), odom)

    def _write_frame(self, frame: RGBDFrame) -> None:
        writers = self._cameras.get(frame.sensor)
        if writers is None:
            folder = self._out / frame.sensor
            writers = self._cameras[frame.sensor] = (RGBDDatasetWriter(folder, overwrite=True),
                                                     TumWriter(folder / "groundtruth.txt"))
        rgbd, gt = writers
        T_world_optical = self._sim.T_world_base_at(frame.stamp_s) @ frame.T_base_sensor
        self._raise_failed()
        self._in_flight.acquire()
        self._futures.append(self._pool.submit(self._write_frame_now, rgbd, gt, frame, T_world_optical))

    def _write_frame_now(self, rgbd: RGBDDatasetWriter, gt: TumWriter, frame: RGBDFrame, T: np.ndarray) -> None:
        try:
            rgbd.write_frame(frame)
            gt.write(frame.stamp_s, T)
        finally:
            self._in_flight.release()

    def _raise_failed(self, all_done: bool = False) -> None:
        """Re-raise the first error of a background write (checked before each submission and at the end)."""
        pending = []
        for future in self._futures:
            if future.done() or all_done:
                future.result()
            else:
                pending.append(future)
        self._futures = pending

    def contacts(self, events) -> None:
        lines = ["# timestamp kind other x y z depth"]
        lines += [f"{e.stamp_s:.6f} {e.kind} {e.other} {e.position_world[0]:.4f} {e.position_world[1]:.4f} "
                  f"{e.position_world[2]:.4f} {e.depth_m:.4f}" for e in events]
        (self._out / "contacts.txt").write_text("\n".join(lines) + "\n")


__all__ = ["RecordSettings", "RecordSummary", "record"]
