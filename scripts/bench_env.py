"""Throughput of the navigation env and of batch missions, compared with the targets of the env.

Every configuration runs in this process on the same seeds: random actions from one seeded generator, an episode
reset whenever one ends (resets are part of the time). Prints the median steps/s over ``--repeats`` runs of
``--steps`` steps of:

* a single env: the default ``simnav/OfficeNav-v0`` (the office's 10 people and its robot, the 682-beam lidar),
  with depth, and lighter settings (no people, with and without depth; the corridor without people and a 90-beam
  lidar);
* ``SyncVectorEnv`` and ``AsyncVectorEnv`` (spawn) of 2 default envs (env-steps/s, i.e. both envs' steps);
* batch missions (``simnav batch``: the default office mission for ``--mission-seconds`` simulated seconds each)
  on 1 and on 2 local workers, ``--batch-rounds`` times in turn after one short warm-up batch (the first mission on
  a machine builds the navigator's collision grids and Numba's caches on disk, which would slow the first timed
  batch down): simulated seconds per wall second, and the median of the rounds' 1 -> 2 workers ratios.

Targets: >= 3000 steps/s lidar only in one process, >= 200 steps/s with depth, >= 1.8x from 1 to 2 workers.

The single envs run pinned to one core (``--core``, default the last; ``--core -1``: wherever the scheduler puts the
process), as one env is one thread: on this 2-core machine the scheduler otherwise moves it between the cores
whenever other work wakes up, and single runs then dip by up to 40 %. The vector envs and the batch run on all
cores. The speed of a shared machine also swings within minutes, so ``--runs N`` measures the single envs N times,
round after round (a fresh env each time), and prints the median and the range of the N medians, and how many
meet the target.

    python scripts/bench_env.py [--steps 400] [--repeats 5] [--runs 1] [--core C] [--missions 4]
                                [--mission-seconds 20] [--batch-rounds 3]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import resource
import statistics
import time

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # noqa: F401  (first: it chooses MUJOCO_GL before mujoco loads)
import gymnasium as gym
from simnav.batch import mission_jobs, run_batch
from simnav.mission.mission import MissionSettings

ENV = "simnav/OfficeNav-v0"
SEED = 0
TARGET_LIDAR, TARGET_DEPTH, TARGET_SCALING = 3000.0, 200.0, 1.8

SINGLE = [
    ("OfficeNav-v0 default (10 people + 1 robot, 682 beams), lidar", ENV, {}),
    ("OfficeNav-v0 default, lidar + QQVGA depth", ENV, {"sensors": "lidar+depth"}),
    ("OfficeNav-v0 without people or robots, lidar", ENV, {"people": 0, "robots": 0}),
    ("OfficeNav-v0 without people or robots, lidar + depth", ENV, {"people": 0, "robots": 0, "sensors": "lidar+depth"}),
    ("CorridorNav-v0 without people, 90-beam lidar", "simnav/CorridorNav-v0", {"people": 0, "lidar_beams": 90}),
]


def steps_per_second(step_batch, steps: int, repeats: int, per_call: int = 1) -> float:
    """Median env-steps/s of ``repeats`` runs of ``steps`` calls (after one warm-up run)."""
    step_batch(steps // 4)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step_batch(steps)
        rates.append(steps * per_call / (time.perf_counter() - t0))
    return statistics.median(rates)


def bench_single(env_id: str, kwargs: dict, steps: int, repeats: int) -> float:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=SEED)
    actions = np.random.default_rng(SEED).uniform(-1, 1, (steps, 2)).astype(np.float32)

    def run(n: int) -> None:
        for a in actions[:n]:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()

    rate = steps_per_second(run, steps, repeats)
    env.close()
    return rate


def bench_vector(mode: str, steps: int, repeats: int, num_envs: int = 2) -> float:
    vector_kwargs = {"context": "spawn"} if mode == "async" else {}
    envs = gym.make_vec(ENV, num_envs=num_envs, vectorization_mode=mode, vector_kwargs=vector_kwargs)
    envs.reset(seed=SEED)
    actions = np.random.default_rng(SEED).uniform(-1, 1, (steps, num_envs, 2)).astype(np.float32)

    def run(n: int) -> None:
        for a in actions[:n]:
            envs.step(a)  # sub-envs reset themselves (next-step autoreset)

    rate = steps_per_second(run, steps, repeats, per_call=num_envs)
    envs.close()
    return rate


def _pinned_default_env(core: int, steps: int, repeats: int) -> float:
    with pinned(core):
        return bench_single(ENV, {}, steps, repeats)


def bench_two_at_once(steps: int, repeats: int) -> tuple[float, list[float]]:
    """Steps/s of the default env alone on core 1, then in two processes at once, pinned to cores 0 and 1: what
    each core still gives when both are busy, the ceiling of any two-worker speed-up on this machine."""
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        alone = pool.apply(_pinned_default_env, (1, steps, repeats))
        return alone, pool.starmap(_pinned_default_env, [(0, steps, repeats), (1, steps, repeats)])


def bench_batch(workers: int, missions: int, seconds: float) -> tuple[float, float, float]:
    """(simulated seconds per wall second, wall time, cores the workers got) of ``missions`` office missions of
    ``seconds`` each; the cores are the workers' CPU time over the wall time (below ``workers`` when the machine is
    shared)."""
    jobs = mission_jobs(missions, settings=MissionSettings(targets=None, duration_s=seconds), first_seed=1)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    report = run_batch(jobs, workers=workers)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return report.summary["sim_time_s"] / wall, wall, cpu / wall


def verdict(value: float, target: float) -> str:
    return f"[green]meets {target:g}[/]" if value >= target else f"[red]misses {target:g}[/]"


@contextlib.contextmanager
def pinned(core: int):
    """This process on ``core`` only (no change for -1 or where affinity cannot be set), restored afterwards."""
    if core < 0 or not hasattr(os, "sched_setaffinity"):
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {core})
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def spread(values: list[float]) -> str:
    """'median' of one value, 'median (min-max)' of several."""
    med = statistics.median(values)
    return f"{med:.0f}" if len(values) == 1 else f"{med:.0f} ({min(values):.0f}-{max(values):.0f})"


def verdict_runs(values: list[float], target: float) -> str:
    """The verdict on the median run, with how many runs met the target when there are several."""
    out = verdict(statistics.median(values), target)
    return out if len(values) == 1 else f"{out} ({sum(v >= target for v in values)}/{len(values)} runs)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=400, help="steps per timed run")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per configuration (median)")
    parser.add_argument("--runs", type=int, default=1, help="rounds of the single-env configurations")
    parser.add_argument("--core", type=int, default=(os.cpu_count() or 1) - 1,
                        help="core the single envs run on (-1: not pinned)")
    parser.add_argument("--missions", type=int, default=4, help="missions per batch run (0: no batch runs)")
    parser.add_argument("--mission-seconds", type=float, default=20.0, help="simulated seconds per mission")
    parser.add_argument("--batch-rounds", type=int, default=3, help="rounds of the 1- and 2-worker batches")
    args = parser.parse_args()
    console = Console()
    load = os.getloadavg()
    console.print(f"{os.cpu_count()} CPUs, load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} "
                  f"(1 / 5 / 15 min) before the runs; MUJOCO_GL={os.environ.get('MUJOCO_GL')}")

    runs = max(1, args.runs)
    what = f"median of {args.repeats} x {args.steps} steps" + (f"; median and range of {runs} runs" if runs > 1 else "")
    where = f"core {args.core}" if args.core >= 0 else "not pinned"
    table = Table("configuration", "steps/s", "vs target", title=f"env steps/s ({what}, seed {SEED}; single envs: "
                                                                   f"{where})")
    rates_single: dict[str, list[float]] = {name: [] for name, _, _ in SINGLE}
    with pinned(args.core):
        for _ in range(runs):
            for name, env_id, kwargs in SINGLE:
                rates_single[name].append(bench_single(env_id, kwargs, args.steps, args.repeats))
    for name, _, _ in SINGLE:
        target = TARGET_DEPTH if "depth" in name else TARGET_LIDAR
        table.add_row(name, spread(rates_single[name]), verdict_runs(rates_single[name], target))
    for mode, label in (("sync", "SyncVectorEnv"), ("async", "AsyncVectorEnv (spawn)")):
        rate = bench_vector(mode, args.steps, args.repeats)
        table.add_row(f"{label} x 2, OfficeNav-v0 default, lidar", f"{rate:.0f}", "")
    console.print(table)

    if args.missions < 1:
        return finish(console)
    bench_batch(2, 2, 1.0)  # warm-up: collision grids and compiled kernels cached on disk
    rounds = max(1, args.batch_rounds)
    batch = Table("round", "workers", "simulated s / wall s", "wall time (s)", "cores used",
                  title=f"batch missions: {args.missions} office missions of {args.mission_seconds:g} s simulated "
                        f"(default mission: 10 people, lidar + depth camera)")
    ratios = []
    for r in range(rounds):
        rates, cores = {}, {}
        for workers in (1, 2):
            rates[workers], wall, cores[workers] = bench_batch(workers, args.missions, args.mission_seconds)
            batch.add_row(str(r + 1), str(workers), f"{rates[workers]:.2f}", f"{wall:.1f}", f"{cores[workers]:.2f}")
        ratios.append(rates[2] / rates[1])
    console.print(batch)
    ratio = statistics.median(ratios)
    console.print(f"1 -> 2 workers: {ratio:.2f}x, median of {rounds} rounds ({verdict(ratio, TARGET_SCALING)}; "
                  f"rounds: {', '.join(f'{x:.2f}' for x in ratios)}); the cores column is the workers' CPU time over "
                  "the wall time")
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) >= 2:
        alone, both = bench_two_at_once(args.steps, args.repeats)
        console.print(f"ceiling: the default env alone on core 1 made {alone:.0f} steps/s; two copies at once on "
                      f"cores 0 and 1 made {both[0]:.0f} and {both[1]:.0f}, so two busy cores give at most "
                      f"{sum(both) / alone:.2f}x one")
    finish(console)


def finish(console: Console) -> None:
    load = os.getloadavg()
    console.print(f"load average after the runs: {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f}")


if __name__ == "__main__":
    main()
