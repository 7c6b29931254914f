"""Simulator micro-benchmarks and the real-time factor of ``simnav record``.

Prints median wall times of: one physics step; a 2D lidar scan of 682 and 1080 rays in the office (cast on the
geoms' cross-sections, as the simulator does, and with ``mj_multiRay``, on the same scene); a depth frame
at QVGA and QQVGA (render only, and the whole reading with noise, segmentation and per-pixel motion); an RGB QVGA
render; one social-force update of 20 people; and the real-time factor of ``simnav record`` in the office with 10
people, a 10 Hz lidar and a 15 Hz QQVGA depth camera (depth only, as on a robot with a depth sensor).

    python scripts/bench_sim.py [--repeats 50] [--record-seconds 30]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # first: it chooses MUJOCO_GL before mujoco loads
import mujoco
from simnav.agents import Crowd, RoadmapGraph
from simnav.mission.record import RecordSettings, record
from simnav.robot import load_robot
from simnav.sensors.lidar import Lidar2D
from simnav.sim import SimConfig, Simulator
from simnav.world import load_world
from simnav.world.footprint import obstacle_segments


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def bench_physics(world, repeats: int) -> float:
    robot = load_robot("giraff", ["sensors=[]"])
    with Simulator(world, robot, SimConfig(pedestrians=10)) as sim:
        sim.data.ctrl[:3] = [0.3, 0.0, 0.1]
        return median_ms(lambda: mujoco.mj_step(sim.model, sim.data), repeats * 20)


def bench_lidar(world, preset: str, repeats: int) -> tuple[float, float]:
    """Median ms of one scan cast on cross-sections and with mj_multiRay (the same scene, the same rays)."""
    robot = load_robot("giraff", [f"sensors.laser_front.preset={preset}", "sensors.camera.rate_hz=0.001"])
    with Simulator(world, robot, SimConfig(pedestrians=10)) as sim:
        lidar = next(s for s in sim.sensors if isinstance(s, Lidar2D))
        rng = np.random.default_rng(0)
        planar = median_ms(lambda: lidar.capture(sim.data, 0.0, rng), repeats)
        lidar._caster.planar = False
        multiray = median_ms(lambda: lidar.capture(sim.data, 0.0, rng), repeats)
        return planar, multiray


def bench_camera(world, preset: str, rgb: bool, repeats: int) -> tuple[float, float]:
    robot = load_robot("giraff", [f"sensors.camera.preset={preset}", f"sensors.camera.rgb={str(rgb).lower()}"])
    with Simulator(world, robot, SimConfig(pedestrians=10)) as sim:
        camera = next(s for s in sim.sensors if s.name == "camera")
        render = camera._worker.submit(lambda: median_ms(lambda: camera._backend.render(sim.data, rgb), repeats))
        render_ms = render.result() if camera.backend == "gl" else float("nan")
        rng, twists = np.random.default_rng(0), sim.body_twists_world()
        return render_ms, median_ms(lambda: camera.capture(sim.data, 0.0, rng, twists), repeats)


def bench_social_force(world, repeats: int) -> float:
    crowd = Crowd(RoadmapGraph.from_spec(world.roadmap), obstacle_segments(world), 20, np.random.default_rng(0))
    for _ in range(50):
        crowd.step(0.04)
    return median_ms(lambda: crowd.step(0.04), repeats * 4)


RECORD_TARGET = ["sensors.camera.preset=kinect_qqvga", "sensors.camera.rate_hz=15", "sensors.camera.rgb=false",
                 "sensors.laser_front.rate_hz=10"]


def bench_record(world, seconds: float, overrides: list[str], cameras: bool = True) -> float:
    robot = load_robot("giraff", overrides)
    settings = RecordSettings(duration_s=seconds, seed=0, cameras=cameras,
                              sim=SimConfig(pedestrians=10, wanderers=0))
    with tempfile.TemporaryDirectory() as out:
        return record(world, robot, out, settings).real_time_factor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--record-seconds", type=float, default=30.0)
    args = parser.parse_args()
    world = load_world("office")
    rows: list[tuple[str, str]] = []
    rows.append(("physics step (office, 10 people)", f"{1e3 * bench_physics(world, args.repeats):.1f} us"))
    for preset, beams in (("hokuyo_urg04lx", 682), ("hokuyo_utm30lx", 1080)):
        planar, multiray = bench_lidar(world, preset, args.repeats)
        rows.append((f"2D lidar, {beams} rays (office): cross-sections / mj_multiRay",
                     f"{planar:.3f} / {multiray:.2f} ms ({multiray / planar:.0f}x)"))
    for preset, label in (("kinect_qvga", "QVGA 320x240"), ("kinect_qqvga", "QQVGA 160x120")):
        render, full = bench_camera(world, preset, False, args.repeats)
        rows.append((f"depth {label}: render (depth + body ids)", f"{render:.2f} ms"))
        rows.append((f"depth {label}: whole reading (noise, motion)", f"{full:.2f} ms"))
    render, full = bench_camera(world, "kinect_qvga", True, args.repeats)
    rows.append(("RGB-D QVGA 320x240: whole reading with colour", f"{full:.2f} ms"))
    rows.append(("social force update, 20 people", f"{bench_social_force(world, args.repeats):.3f} ms"))
    span = f"{args.record_seconds:.0f} s in the office, 10 people"
    rtf = bench_record(world, args.record_seconds, RECORD_TARGET)
    rows.append((f"simnav record, lidar 10 Hz + QQVGA depth 15 Hz ({span})", f"{rtf:.1f}x real time"))
    rtf = bench_record(world, args.record_seconds, RECORD_TARGET, cameras=False)
    rows.append(("  the same, depth frames rendered but not written", f"{rtf:.1f}x real time"))
    rtf = bench_record(world, args.record_seconds, [*RECORD_TARGET, "sensors.camera.rate_hz=0.01"])
    rows.append(("  the same, no depth camera", f"{rtf:.1f}x real time"))
    rtf = bench_record(world, args.record_seconds, [])
    rows.append(("simnav record default (Giraff: lidar 10 Hz, RGB-D QVGA 30 Hz)", f"{rtf:.1f}x real time"))
    table = Table("benchmark", "median", title=f"simnav {simnav.__version__}, mujoco {mujoco.__version__}")
    for row in rows:
        table.add_row(*row)
    Console().print(table)


if __name__ == "__main__":
    main()
