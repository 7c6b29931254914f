"""Success rate of the 3D-PTG baseline policy (:class:`simnav.env.PTGPolicy`) in a navigation env.

Runs ``--episodes`` seeded episodes (reset seeds ``--seed``, ``--seed + 1``, ...) in parallel with the batch runner
(the same as ``simnav batch --task rollout``) and prints the success, collision and time-out rates with a 95 %
Wilson interval for the success rate, the mean return, and how the outcome depends on the start-goal distance.

    python scripts/eval_ptg_policy.py [--env simnav/OfficeNav-v0] [--episodes 100] [--workers 2] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # noqa: F401  (registers the env ids; chooses MUJOCO_GL before mujoco loads)
from simnav.batch import rollout_jobs, run_batch


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="simnav/OfficeNav-v0", help="Gymnasium id")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2, help="local worker processes")
    parser.add_argument("--seed", type=int, default=0, help="reset seed of the first episode")
    parser.add_argument("--ray-address", default=None, help="run on Ray instead (auto, HOST:PORT or local)")
    args = parser.parse_args()
    console = Console()
    started = time.perf_counter()
    report = run_batch(rollout_jobs(args.episodes, args.env, first_seed=args.seed), workers=args.workers,
                       ray_address=args.ray_address)
    rows, s = report.rows, report.summary
    low, high = wilson_interval(s["episodes_reached"], len(rows))
    table = Table(show_header=False, title=f"PTGPolicy in {args.env}: {len(rows)} episodes, seeds {args.seed}.."
                                           f"{args.seed + len(rows) - 1}")
    table.add_row("success rate", f"{s['success_rate']:.0%} ({s['episodes_reached']}/{len(rows)}; 95 % interval "
                                  f"{low:.0%}..{high:.0%})")
    table.add_row("collisions / time-outs", f"{s['collisions']} / {s['timeouts']}")
    table.add_row("mean return / steps", f"{s['mean_return']:.2f} / {s['mean_steps']:.0f}")
    distances = np.array([r["start_distance_m"] for r in rows])
    for lo, hi in ((0, 4), (4, 7), (7, math.inf)):
        band = [r for r, d in zip(rows, distances, strict=True) if lo <= d < hi]
        if band:
            rate = sum(r["success"] for r in band) / len(band)
            table.add_row(f"start-goal {lo}..{hi if math.isfinite(hi) else ''} m", f"{rate:.0%} of {len(band)}")
    table.add_row("wall time", f"{time.perf_counter() - started:.0f} s on {report.backend} ({report.workers} workers)")
    console.print(table)


if __name__ == "__main__":
    main()
