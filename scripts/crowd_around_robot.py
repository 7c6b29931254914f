"""How the crowd gets past a robot standing in the office corridor, by where across the corridor it stands.

The office's 10 people walk their roadmap routes (walls and doors as the simulator poses them at the start, held
still) for ``--seconds`` per seed while a robot of the Giraff's circumradius stands at x = ``--x``; for each
offset from the corridor's centreline (y) the table gives the person-seconds that people spent within 1.3 m of
the robot walking slower than 0.2 m/s, and the longest such spell of one person. A robot near the centreline leaves
single-file gaps on both sides, or one, where people from both ways meet; at the side it leaves a lane two people
wide.

    python scripts/crowd_around_robot.py [--x 10.26] [--offsets 0,0.29,-0.29,0.45,-0.45] [--seeds 4] [--seconds 300]
"""

from __future__ import annotations

import argparse

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # noqa: F401  (sets up the environment like every simnav entry point)
from simnav.agents import Crowd
from simnav.robot import load_robot
from simnav.sim import SimConfig, Simulator
from simnav.world import load_world
from simnav.world.footprint import obstacle_segments

NEAR_M = 1.3
SLOW_M_S = 0.2
AGENT_DT_S = 0.04


def slowed_near(sim: Simulator, walls: np.ndarray, doors: np.ndarray | None, xy: np.ndarray, seed: int,
                seconds: float) -> tuple[float, float]:
    """(person-seconds slow within NEAR_M of a robot standing at ``xy``, longest spell of one person in s), among
    the (W, 2, 2) ``walls`` and the (D, 2, 2) door leaves ``doors`` (metres)."""
    robot = np.array([[xy[0], xy[1], sim.robot_radius_m]])
    crowd = Crowd(sim.roadmap, walls, sim.pedestrian_count, np.random.default_rng(seed),
                  keep_out=np.array([[xy[0], xy[1], sim.robot_radius_m + 0.5]]))
    spell, total, longest = np.zeros(crowd.count), 0.0, 0.0
    for _ in range(round(seconds / AGENT_DT_S)):
        crowd.step(AGENT_DT_S, doors, robot, np.zeros((1, 2)))
        p, v = crowd.positions_xy, crowd.velocities_xy
        slow = (np.hypot(p[:, 0] - xy[0], p[:, 1] - xy[1]) < NEAR_M) & (np.hypot(v[:, 0], v[:, 1]) < SLOW_M_S)
        spell = np.where(slow, spell + AGENT_DT_S, 0.0)
        total += float(np.sum(slow)) * AGENT_DT_S
        longest = max(longest, float(spell.max(initial=0.0)))
    return total, longest


def offsets_m(text: str) -> list[float]:
    """``--offsets``: comma-separated metres."""
    try:
        return [float(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated offsets in metres, got {text!r}") from None


def office_crowd_run(parser: argparse.ArgumentParser) -> tuple[argparse.Namespace, Simulator, np.ndarray]:
    """Parse ``parser``'s arguments with ``--seeds`` and ``--seconds`` added (checked), and set up the office with
    the Giraff: the arguments, the simulator (close it) and the (W, 2, 2) static obstacle segments (metres)."""
    parser.add_argument("--seeds", type=int, choices=range(1, 1001), metavar="1..1000", default=4)
    parser.add_argument("--seconds", type=float, default=300.0, help="simulated time per seed, s")
    args = parser.parse_args()
    if not args.seconds > 0:
        parser.error(f"--seconds must be > 0, got {args.seconds}")
    sim = Simulator(load_world("office"), load_robot("giraff"), SimConfig(), seed=0)
    return args, sim, obstacle_segments(sim.world)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--x", type=float, default=10.26, help="where along the corridor the robot stands, m")
    parser.add_argument("--offsets", type=offsets_m, default="0,0.29,-0.29,0.45,-0.45",
                        help="offsets from the centreline (y), m")
    args, sim, walls = office_crowd_run(parser)
    doors = sim.doors.segments_xy() if sim.doors else None
    table = Table(title=f"people slowed near a robot standing at x = {args.x} m in the office corridor "
                        f"({args.seeds} seeds x {args.seconds:.0f} s, {sim.pedestrian_count} people)")
    for name in ("offset (m)", f"person-s slow within {NEAR_M} m, per 100 s", "longest spell (s)"):
        table.add_column(name, justify="right")
    for offset in args.offsets:
        runs = [slowed_near(sim, walls, doors, np.array([args.x, offset]), seed, args.seconds)
                for seed in range(args.seeds)]
        per_100_s = 100.0 * sum(r[0] for r in runs) / (args.seeds * args.seconds)
        table.add_row(f"{offset:.2f}", f"{per_100_s:.1f}", f"{max(r[1] for r in runs):.1f}")
    sim.close()
    Console().print(table)


if __name__ == "__main__":
    main()
