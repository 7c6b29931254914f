"""Paired A/B throughput of the navigation env between two versions of simnav, on one core.

The machine's speed can swing by 2x within minutes, so two separate runs of ``bench_env.py`` do not compare two
versions. This script exports each git revision (``git archive``) into a temporary folder, starts one persistent
worker process per version pinned to the same core, and alternates chunks of env steps between them (random actions
from one seeded generator, resets included, after a warm-up that compiles or loads the Numba kernels). It prints
each version's median steps/s and the median of the paired speed ratios B/A, which the swings cancel out of.

    python scripts/bench_env_ab.py BASE_REV [NEW_REV] [--rounds 60] [--chunk 200] [--env simnav/OfficeNav-v0]
                                   [--env-kwargs '{"sensors": "lidar+depth"}'] [--core 1]

``NEW_REV`` defaults to the working tree (not an export: uncommitted changes count).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WORKER = """
import json, sys, time
import numpy as np
import simnav, gymnasium as gym
env = gym.make(sys.argv[1], **json.loads(sys.argv[2]))
env.reset(seed=0)
actions = iter(np.random.default_rng(0).uniform(-1, 1, (10**7, 2)).astype(np.float32))
def run(n):
    for _ in range(n):
        _, _, terminated, truncated, _ = env.step(next(actions))
        if terminated or truncated:
            env.reset()
run(400)
print("ready", simnav.__file__, flush=True)
for line in sys.stdin:
    t0 = time.perf_counter()
    run(int(line))
    print(time.perf_counter() - t0, flush=True)
"""


def export(rev: str, into: Path) -> Path:
    """The tree of git revision ``rev`` written into ``into``."""
    into.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def start_worker(tree: Path, worker: str, args: list[str], cores: str,
                 env: dict[str, str] | None = None) -> subprocess.Popen:
    """``python -c worker *args`` with simnav imported from ``tree``, pinned to ``cores`` (a taskset list), once it
    has printed ``ready`` and the path of the simnav it imported (which must lie in ``tree``)."""
    cmd = [sys.executable, "-c", worker, *args]
    if hasattr(os, "sched_setaffinity"):
        cmd = ["taskset", "-c", cores, *cmd]
    # run in the tree: ``python -c`` puts the working directory first on the import path
    proc = subprocess.Popen(cmd, cwd=tree, env=dict(os.environ, PYTHONPATH=str(tree), **(env or {})),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    ready = proc.stdout.readline().split()
    if ready[:1] != ["ready"] or not Path(ready[1]).is_relative_to(tree):
        raise SystemExit(f"the worker for {tree} did not start with its own simnav: {' '.join(ready)}")
    return proc


def alternate(workers: list[subprocess.Popen], rounds: int, request: str) -> list[list[str]]:
    """Sends ``request`` to the two workers in turn, ``rounds`` times each (who goes first alternates), and returns
    each worker's reply lines; then closes them."""
    replies: list[list[str]] = [[], []]
    for r in range(rounds):
        for j in ((0, 1) if r % 2 == 0 else (1, 0)):
            workers[j].stdin.write(f"{request}\n")
            workers[j].stdin.flush()
            replies[j].append(workers[j].stdout.readline())
    for w in workers:
        w.stdin.close()
        w.wait()
    return replies


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", help="git revision A")
    parser.add_argument("new", nargs="?", help="git revision B (default: the working tree)")
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--chunk", type=int, default=200, help="env steps per chunk")
    parser.add_argument("--env", default="simnav/OfficeNav-v0")
    parser.add_argument("--env-kwargs", default="{}", help="JSON keyword arguments of gym.make")
    parser.add_argument("--core", type=int, default=1 if (os.cpu_count() or 1) > 1 else 0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees = [export(args.base, Path(tmp) / "a"), export(args.new, Path(tmp) / "b") if args.new else ROOT]
        print(f"starting the workers (the first start in a fresh export compiles the kernels) on core {args.core}")
        workers = [start_worker(tree, WORKER, [args.env, args.env_kwargs], str(args.core)) for tree in trees]
        times = [[float(line) for line in lines] for lines in alternate(workers, args.rounds, str(args.chunk))]
    rates = [[args.chunk / t for t in ts] for ts in times]
    names = [args.base, args.new or "working tree"]
    for name, r in zip(names, rates, strict=True):
        print(f"{name}: median {statistics.median(r):.0f} steps/s (best {max(r):.0f}) over {args.rounds} chunks")
    paired = statistics.median(a / b for a, b in zip(times[0], times[1], strict=True))
    print(f"B/A speed: median of the paired ratios {paired:.3f}")


if __name__ == "__main__":
    main()
