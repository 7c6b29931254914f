"""How often someone gives up on getting past the robot in the odometry bench's people sequences.

The crowd changes its plans only after such a give-up (``simnav.agents.crowd.ROBOT_AVOID_S``), so a sequence with
none is the same with and without that rule. Simulates the people and the robot of every candidate seed of
``scripts/bench_rgbd_odometry.py`` (robot and hand-held, 1-5 people) without rendering and prints the counts.

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


def _robot(seconds: float, seed: int, people: int) -> None:
    robot, sim = bench._simulator(people, seed, ["sensors.camera.rate_hz=0.001"])
    with sim:
        follower = bench._follower(sim, robot, seed)
        while sim.time_s < seconds - 1e-9:
            sim.step(*follower.command(*sim.pose_xy_yaw))


def _handheld(seconds: float, seed: int, people: int) -> None:
    overrides = ["drive.max_v_m_s=0.5", "drive.max_w_deg_s=45", "sensors.camera.rate_hz=0.001"]
    robot, sim = bench._simulator(people, seed, overrides, physics_dt_s=1 / 300, control_dt_s=1 / bench.FRAME_RATE_HZ)
    with sim:
        follower = bench._follower(sim, robot, seed)
        for _ in range(int(seconds * bench.FRAME_RATE_HZ) + 1):
            sim.step(*follower.command(*sim.pose_xy_yaw))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 10], help="the bench's --seed values")
    parser.add_argument("--candidates", type=int, default=4, help="the bench's --candidates")
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    crowd_module.Crowd._give_up_on_robot = _counting(crowd_module.Crowd._give_up_on_robot)
    total = 0
    for base in args.seeds:
        for kind, record in (("robot", _robot), ("handheld", _handheld)):
            for people in range(1, 6):
                counts = []
                for seed in range(base, base + args.candidates):
                    _COUNT[0] = 0
                    record(args.seconds, seed, people)
                    counts.append(_COUNT[0])
                total += sum(counts)
                print(f"--seed {base}: {kind}-people{people}, give-ups per candidate seed: {counts}", flush=True)
    print(f"{total} give-ups in all")


if __name__ == "__main__":
    main()
