"""Cost of watching a mission in meshcat: per visual update, and the slowdown of a whole mission at 10 Hz.

One process, one seed, one mission (default: the office with its ten people and one other robot, the Giraff,
20 simulated seconds, ground-truth pose) run in three ways, interleaved ``--repeats`` times:

- ``none``: no observer at all;
- ``record``: what every ``simnav mission`` runs (the recorder behind ``simnav view``, no viewer);
- ``live``: the recorder plus the live meshcat viewer at ``--rate`` Hz, streaming to a meshcat server in its own
  process (started once by this script; no browser connected, so the numbers are the simulation's side: building
  each frame, packing and queueing its commands).

Two measures of the slowdown, medians over the repeats:

- *loop wall*: the mission's control-loop wall time (``MissionReport.wall_time_s``) against ``record``. This is the
  number a user feels, but it needs a quiet machine: other load changes it by more than the viewer does.
- *own CPU*: within each run, the CPU time spent in the observer's ``step`` (thread time) plus the CPU time of
  pyzmq's I/O thread, divided by the rest of the process's CPU time in that run (all threads: physics, sensors,
  rendering, navigator). Both parts come from the same run, so other load on the machine hardly moves it.

It also prints the median and p95 wall and CPU time of one visual update (``step`` when it drew: frame + packing +
send) and the CPU time the meshcat server process spent per update, in parallel on another core. Target: at most
10 % slowdown at 10 Hz.

    python scripts/bench_viz.py [--world office] [--duration 20] [--repeats 3] [--rate 10]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import simnav  # noqa: F401  (chooses the GL backend before mujoco loads)

import numpy as np
from rich.console import Console
from rich.table import Table

from simnav.mission.mission import MissionSettings, mission_robot, run_mission
from simnav.robot import load_robot
from simnav.viz import MeshcatServer, mission_observers
from simnav.world import load_world

WAYS = ("none", "record", "live")
_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


class TimedObserver:
    """Wraps an observer and times its calls (wall and thread CPU); ``step`` calls are split into those that drew
    a live frame and the rest."""

    def __init__(self, observer) -> None:
        self.observer = observer
        self.viewer = next((s for s in observer.sinks if hasattr(s, "drawn")), None)
        self.update_s: list[tuple[float, float]] = []
        self.between_s: list[tuple[float, float]] = []
        self.other_cpu_s = 0.0  # start and finish

    def start(self, *args) -> None:
        c0 = time.thread_time()
        self.observer.start(*args)
        self.other_cpu_s += time.thread_time() - c0

    def step(self, frame) -> None:
        drawn = self.viewer.drawn if self.viewer is not None else 0
        t0, c0 = time.perf_counter(), time.thread_time()
        self.observer.step(frame)
        dt = (time.perf_counter() - t0, time.thread_time() - c0)
        drew = self.viewer is not None and self.viewer.drawn > drawn
        (self.update_s if drew else self.between_s).append(dt)

    def finish(self, report) -> None:
        c0 = time.thread_time()
        self.observer.finish(report)
        self.other_cpu_s += time.thread_time() - c0

    @property
    def step_cpu_s(self) -> float:
        return sum(c for _, c in self.update_s) + sum(c for _, c in self.between_s)


def cpu_of(path: Path) -> float:
    """User + system CPU time of a process or thread from its /proc stat file, s."""
    fields = path.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * _TICK_S


def zmq_threads() -> list[Path]:
    """The /proc entries of the threads pyzmq's context starts (its I/O thread and reaper)."""
    import zmq

    before = set(os.listdir("/proc/self/task"))
    zmq.Context.instance().socket(zmq.DEALER).close()
    return [Path("/proc/self/task") / tid for tid in sorted(set(os.listdir("/proc/self/task")) - before)]


ZMQ_THREADS: list[Path] = []


def zmq_threads_cpu_s() -> float:
    """CPU time of pyzmq's background threads so far, s."""
    return sum(cpu_of(task / "stat") for task in ZMQ_THREADS if task.exists())


def run_once(way: str, world, robot, settings: MissionSettings, rate_hz: float, tmp: Path,
             server: MeshcatServer) -> dict:
    """One mission: loop wall time, process CPU, the observer's own CPU and, when live, the per-update costs."""
    server_stat = Path(f"/proc/{server.process.pid}/stat")
    cpu0, zmq0, server0 = time.process_time(), zmq_threads_cpu_s(), cpu_of(server_stat)
    if way == "none":
        report = run_mission(world, robot, settings)
        return {"loop_s": report.wall_time_s, "cpu_s": time.process_time() - cpu0, "own_s": 0.0}
    with mission_observers(live=way == "live", url=server.zmq_url, html_path=None, out_dir=tmp / way,
                           rate_hz=rate_hz) as obs:
        timed = TimedObserver(obs[0])
        report = run_mission(world, robot, settings, observers=[timed])
    out = {"loop_s": report.wall_time_s, "cpu_s": time.process_time() - cpu0,
           "own_s": timed.step_cpu_s + zmq_threads_cpu_s() - zmq0, "startup_s": timed.other_cpu_s}
    if timed.viewer is not None:
        out.update(update_s=timed.update_s, between_s=timed.between_s, drawn=timed.viewer.drawn,
                   dropped=timed.viewer.dropped, server_cpu_s=cpu_of(server_stat) - server0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--world", default="office")
    parser.add_argument("--robot", default="giraff")
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds per mission")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rate", type=float, default=10.0, help="visual updates per simulated second")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    ZMQ_THREADS.extend(zmq_threads())
    world, spec = load_world(args.world), load_robot(args.robot)
    settings = MissionSettings(duration_s=args.duration, seed=args.seed)
    robot = mission_robot(spec, settings)
    console = Console()
    results: dict[str, list[dict]] = {way: [] for way in WAYS}
    with tempfile.TemporaryDirectory() as tmp, MeshcatServer() as server:
        run_once("live", world, robot, settings, args.rate, Path(tmp), server)  # warm-up: kernels, caches, PTGs
        for repeat in range(args.repeats):
            for way in WAYS:
                results[way].append(run_once(way, world, robot, settings, args.rate, Path(tmp), server))
                console.print(f"[dim]repeat {repeat + 1}/{args.repeats} {way}: loop "
                              f"{results[way][-1]['loop_s']:.2f} s[/]")
    report(console, results, args)


def report(console: Console, results: dict[str, list[dict]], args) -> None:
    def median(way: str, key: str) -> float:
        return statistics.median(r[key] for r in results[way])

    def own_share(run: dict) -> float:
        return run["own_s"] / (run["cpu_s"] - run["own_s"] - run.get("startup_s", 0.0))

    table = Table(title=f"{args.robot} in {args.world}, {args.duration:g} s simulated, seed {args.seed}, "
                        f"median of {args.repeats}")
    for column in ("observers", "loop wall (s)", "vs record", "process CPU (s)", "own CPU (s)", "own CPU share"):
        table.add_column(column, justify="left" if column == "observers" else "right")
    for way in WAYS:
        share = statistics.median(own_share(r) for r in results[way])
        table.add_row(way, f"{median(way, 'loop_s'):.2f}", f"{median(way, 'loop_s') / median('record', 'loop_s'):.3f}",
                      f"{median(way, 'cpu_s'):.2f}", f"{median(way, 'own_s'):.3f}", f"{100 * share:.1f} %")
    console.print(table)
    live = results["live"]
    updates = np.array([u for r in live for u in r["update_s"]]) * 1e3
    between = np.array([u for r in live for u in r["between_s"]]) * 1e3
    drawn = sum(r["drawn"] for r in live)
    console.print(f"one live update at {args.rate:g} Hz: wall median {np.median(updates[:, 0]):.2f} ms (p95 "
                  f"{np.percentile(updates[:, 0], 95):.2f}), CPU median {np.median(updates[:, 1]):.2f} ms (p95 "
                  f"{np.percentile(updates[:, 1], 95):.2f}); {len(updates)} updates, "
                  f"{sum(r['dropped'] for r in live)} skipped; steps in between: CPU median "
                  f"{np.median(between[:, 1]) * 1e3:.0f} us")
    console.print(f"meshcat server process: {1e3 * sum(r['server_cpu_s'] for r in live) / drawn:.2f} ms CPU per "
                  "update (in parallel, in its own process)")
    console.print(f"slowdown with the live viewer at {args.rate:g} Hz (target <= 10 %): own CPU "
                  f"{100 * statistics.median(own_share(r) for r in live):.1f} % of the mission's; loop wall "
                  f"{100 * (median('live', 'loop_s') / median('record', 'loop_s') - 1):+.1f} % against record "
                  f"(recorder alone: own CPU {100 * statistics.median(own_share(r) for r in results['record']):.2f} "
                  f"%, loop wall {100 * (median('record', 'loop_s') / median('none', 'loop_s') - 1):+.1f} % "
                  "against none)")


if __name__ == "__main__":
    main()
