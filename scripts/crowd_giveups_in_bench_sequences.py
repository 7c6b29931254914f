"""How often someone gives up on getting past the robot in the odometry bench's people sequences.

The crowd changes its plans only after such a give-up (``simnav.agents.crowd.ROBOT_AVOID_S``), so a sequence with
none is the same with and without that rule. Simulates the people and the robot of every candidate seed of
``scripts/bench_rgbd_odometry.py`` (robot and hand-held, 1-5 people) with the bench's own drive loops, without
rendering, and prints the counts.

    python scripts/crowd_giveups_in_bench_sequences.py [--seeds 0 10] [--candidates 4] [--seconds 10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_rgbd_odometry as bench  # noqa: E402

from simnav.agents import crowd as crowd_module  # noqa: E402

_COUNT = [0]


def _counting(give_up):
    def wrapper(self, k, circle, walls):
        _COUNT[0] += 1
        return give_up(self, k, circle, walls)
    return wrapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 10], help="the bench's --seed values")
    parser.add_argument("--candidates", type=int, default=4, help="the bench's --candidates")
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    crowd_module.Crowd._give_up_on_robot = _counting(crowd_module.Crowd._give_up_on_robot)
    total = 0
    for base in args.seeds:
        for kind, record in (("robot", bench._record_robot), ("handheld", bench._record_handheld)):
            for people in range(1, 6):
                counts = []
                for seed in range(base, base + args.candidates):
                    _COUNT[0] = 0
                    record(args.seconds, seed, people, None)
                    counts.append(_COUNT[0])
                total += sum(counts)
                print(f"--seed {base}: {kind}-people{people}, give-ups per candidate seed: {counts}", flush=True)
    print(f"{total} give-ups in all")


if __name__ == "__main__":
    main()
