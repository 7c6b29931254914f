"""How often the crowd's robot rules act in the odometry bench's people sequences.

Two rules act only around a robot: giving up on getting past it (then routes keep clear of it for
``simnav.agents.crowd.ROBOT_AVOID_S``) and waiting before a single-file stretch it is in (``single_file_wait_s``,
off by default; ``--single-file-wait-s S`` counts the waits with it on). A sequence in which neither acts is the
same with and without them. Simulates the people and the robot of every candidate seed of
``scripts/bench_rgbd_odometry.py`` (robot and hand-held, 1-5 people) with the bench's own drive loops, without
rendering, and prints per candidate seed the give-ups and the crowd steps in which someone waited.

    python scripts/crowd_rules_in_bench_sequences.py [--seeds 0 10] [--candidates 4] [--seconds 10]
                                                   [--single-file-wait-s 20]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_rgbd_odometry as bench  # noqa: E402

from simnav.agents import crowd as crowd_module  # noqa: E402

_COUNT = [0, 0]  # give-ups, steps with someone waiting


def _counting(give_up):
    def wrapper(self, k, circle, walls):
        _COUNT[0] += 1
        return give_up(self, k, circle, walls)
    return wrapper


def _counting_waits(waiting_for_robots):
    def wrapper(self, circles):
        waiting = waiting_for_robots(self, circles)
        _COUNT[1] += int(waiting.any())
        return waiting
    return wrapper


def _waiting_for(init, wait_s: float):
    def wrapper(self, *args, **kwargs):
        kwargs["single_file_wait_s"] = wait_s
        init(self, *args, **kwargs)
    return wrapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 10], help="the bench's --seed values")
    parser.add_argument("--candidates", type=int, default=4, help="the bench's --candidates")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--single-file-wait-s", type=float, default=None,
                        help="people wait this long before a single-file stretch the robot is in (default: off)")
    args = parser.parse_args()
    crowd_module.Crowd._give_up_on_robot = _counting(crowd_module.Crowd._give_up_on_robot)
    crowd_module.Crowd._waiting_for_robots = _counting_waits(crowd_module.Crowd._waiting_for_robots)
    if args.single_file_wait_s is not None:
        crowd_module.Crowd.__init__ = _waiting_for(crowd_module.Crowd.__init__, args.single_file_wait_s)
    totals = [0, 0]
    for base in args.seeds:
        for kind, record in (("robot", bench._record_robot), ("handheld", bench._record_handheld)):
            for people in range(1, 6):
                give_ups, waits = [], []
                for seed in range(base, base + args.candidates):
                    _COUNT[:] = [0, 0]
                    record(args.seconds, seed, people, None)
                    give_ups.append(_COUNT[0])
                    waits.append(_COUNT[1])
                totals[0] += sum(give_ups)
                totals[1] += sum(waits)
                print(f"--seed {base}: {kind}-people{people}, per candidate seed: give-ups {give_ups}, "
                      f"steps with someone waiting {waits}", flush=True)
    print(f"{totals[0]} give-ups and {totals[1]} steps with someone waiting in all")


if __name__ == "__main__":
    main()
