"""How long the office's people stand held up in its doorways, with no robot about.

The office's 10 people walk their roadmap routes among its walls and its doors (which swing on their schedule and
open for someone within reach, as in the simulator) for ``--seconds`` per seed; the table gives the
person-seconds that people on their way (not pausing at a goal) spent within ``NEAR_M`` of a doorway's node
(a roadmap node with less than ``NARROW_NODE_CLEARANCE_M`` of clearance) walking slower than 0.2 m/s, per 100 s,
the longest such spell of one person, and the share of the time people spent on their way walking slower than
that anywhere. A person pressed against a door jamb or an open leaf shows up as a long spell.

    python scripts/crowd_doorways.py [--seeds 4] [--seconds 300]
"""

from __future__ import annotations

import argparse

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # noqa: F401  (sets up the environment like every simnav entry point)
from crowd_around_robot import AGENT_DT_S, SLOW_M_S, office_crowd_run
from simnav.agents import Crowd
from simnav.agents.doors import DoorLeaves
from simnav.mission.mission import NARROW_NODE_CLEARANCE_M
from simnav.sim import Simulator
from simnav.world.footprint import clearance_m

NEAR_M = 1.0


def held_in_doorways(sim: Simulator, walls: np.ndarray, doorways_xy: np.ndarray, seed: int,
                     seconds: float) -> tuple[float, float, float, float]:
    """(person-seconds slow within NEAR_M of the (K, 2) ``doorways_xy``, longest spell of one person in s,
    person-seconds slow anywhere, person-seconds on the way) among the (W, 2, 2) ``walls`` and the world's doors
    (metres)."""
    crowd = Crowd(sim.roadmap, walls, sim.pedestrian_count, np.random.default_rng(seed))
    doors = DoorLeaves(sim.world.doors)
    spell, held_s, longest, slow_s, walking_s = np.zeros(crowd.count), 0.0, 0.0, 0.0, 0.0
    for k in range(round(seconds / AGENT_DT_S)):
        crowd.step(AGENT_DT_S, doors.segments_xy() if doors else None)
        p, v = crowd.positions_xy, crowd.velocities_xy
        if doors:
            people = np.column_stack([p, np.full(len(p), crowd.radius_m)])
            doors.update((k + 1) * AGENT_DT_S, AGENT_DT_S, p, people)
        walking = ~crowd.pausing
        slow = walking & (np.hypot(v[:, 0], v[:, 1]) < SLOW_M_S)
        near = np.min(np.linalg.norm(p[:, None] - doorways_xy[None], axis=2), axis=1) < NEAR_M
        spell = np.where(slow & near, spell + AGENT_DT_S, 0.0)
        held_s += float(np.sum(slow & near)) * AGENT_DT_S
        slow_s += float(np.sum(slow)) * AGENT_DT_S
        walking_s += float(np.sum(walking)) * AGENT_DT_S
        longest = max(longest, float(spell.max(initial=0.0)))
    return held_s, longest, slow_s, walking_s


def main() -> None:
    args, sim, walls = office_crowd_run(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    nodes = sim.roadmap.nodes_xy
    doorways = nodes[clearance_m(sim.world, nodes) < NARROW_NODE_CLEARANCE_M]
    table = Table(title=f"people held up in the office's {len(doorways)} doorway nodes, no robot "
                        f"({sim.pedestrian_count} people, {args.seconds:.0f} s per seed)")
    for name in ("seed", f"person-s slow within {NEAR_M} m of a doorway, per 100 s", "longest spell (s)",
                 "slow while on the way"):
        table.add_column(name, justify="right")
    runs = [held_in_doorways(sim, walls, doorways, seed, args.seconds) for seed in range(args.seeds)]
    sim.close()
    for seed, (held, longest, slow, walking) in enumerate(runs):
        table.add_row(str(seed), f"{100.0 * held / args.seconds:.1f}", f"{longest:.1f}", f"{slow / walking:.1%}")
    held, slow, walking = (sum(r[i] for r in runs) for i in (0, 2, 3))
    table.add_row("all", f"{100.0 * held / (args.seeds * args.seconds):.1f}", f"{max(r[1] for r in runs):.1f}",
                  f"{slow / walking:.1%}")
    Console().print(table)


if __name__ == "__main__":
    main()
