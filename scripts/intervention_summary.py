"""What the robot did before each intervention of a mission batch (or of one mission folder).

For every intervention in ``DIR/mission-*/report.json`` (a batch), ``DIR/seed-*/report.json`` (a long run of
``scripts/reproduce_nav_experiments.py``) or ``DIR/report.json``, the navigator's states over the ``--window``
seconds before it (from ``navigation.csv``), the path length driven and the total turning (sum of the absolute
heading changes) in that window: a robot turning back and forth in place turns hundreds of degrees while driving
almost nothing, a waiting one neither. The last line counts each kind: *turning* (more than ``--turned``),
*boxed in* (otherwise, mostly waiting, recovering or blocked), *driving* (the rest). The line after it sums up the
whole missions: path driven, total turning and the time spent turning on the spot (commanded speed under
``ON_THE_SPOT_M_S`` and yaw rate over ``ON_THE_SPOT_RAD_S``). Each intervention's distance to the nearest door leaf
standing fully open (from the mission's ``world.yaml``) is listed too, and those within ``--leaf`` of one counted:
in a doorway, beside the open leaf, the robot has little room to turn.

    python scripts/intervention_summary.py DIR [--window 30] [--turned 400] [--leaf 0.6]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from simnav.world import load_world
from simnav.world.footprint import open_leaf_distance_m

ON_THE_SPOT_M_S = 0.05
ON_THE_SPOT_RAD_S = 0.2
SET_DOWN_JUMP_M = 0.5  # a longer step between two rows is an intervention setting the robot down elsewhere


def mission_dirs(root: Path) -> list[Path]:
    """Mission folders under ``root`` (itself when it holds a report), by seed."""
    if (root / "report.json").is_file():
        return [root]
    dirs = [d for d in [*root.glob("mission-*"), *root.glob("seed-*")] if (d / "report.json").is_file()]
    return sorted(dirs, key=lambda d: int(d.name.split("-")[-1]) if d.name.split("-")[-1].isdigit() else 0)


def window_summary(rows: list[dict], t_s: float, window_s: float) -> tuple[Counter, float, float]:
    """States (count of control steps), path length (m) and total turning (deg) in ``[t_s - window_s, t_s)``."""
    w = [r for r in rows if t_s - window_s <= float(r["time_s"]) < t_s]
    return Counter(r["state"] for r in w), *path_and_turning(w)


def path_and_turning(rows: list[dict]) -> tuple[float, float]:
    """Path length (m, without the jumps of interventions) and total turning (deg, the sum of the absolute heading
    changes) over ``rows``."""
    steps = (math.hypot(float(b["x_m"]) - float(a["x_m"]), float(b["y_m"]) - float(a["y_m"]))
             for a, b in zip(rows, rows[1:], strict=False))
    path_m = sum(d for d in steps if d < SET_DOWN_JUMP_M)
    turned = sum(abs((float(b["yaw_rad"]) - float(a["yaw_rad"]) + math.pi) % (2 * math.pi) - math.pi)
                 for a, b in zip(rows, rows[1:], strict=False))
    return path_m, math.degrees(turned)


def whole_run(rows: list[dict]) -> tuple[float, float, float]:
    """Path length (m), total turning (deg) and time turning on the spot (s) over a whole mission."""
    path_m, turned_deg = path_and_turning(rows)
    spot_s = sum(float(b["time_s"]) - float(a["time_s"]) for a, b in zip(rows, rows[1:], strict=False)
                 if abs(float(a["v_m_s"])) < ON_THE_SPOT_M_S and abs(float(a["w_rad_s"])) > ON_THE_SPOT_RAD_S)
    return path_m, turned_deg, spot_s


def kind(states: Counter, turned_deg: float, turned_limit_deg: float) -> str:
    """What the robot mostly did before an intervention: ``turning``, ``boxed in`` or ``driving``."""
    if turned_deg > turned_limit_deg:
        return "turning"
    n = max(sum(states.values()), 1)
    held = sum(states[s] for s in ("waiting", "recovering", "blocked"))
    return "boxed in" if held / n >= 0.5 else "driving"


def leaf_distances_m(mission_dir: Path, report: dict, events: list[dict]) -> np.ndarray:
    """(E,) distance (m) of each intervention's position to the nearest door leaf standing open, in the mission's
    world (its ``world.yaml``, else the shipped world of the report's name); +inf without doors, NaN when the
    folder names no world."""
    saved = mission_dir / "world.yaml"
    if not events or not (saved.is_file() or "world" in report):
        return np.full(len(events), np.nan)
    world = load_world(saved if saved.is_file() else report["world"])
    return open_leaf_distance_m(world, np.array([[e["x_m"], e["y_m"]] for e in events], dtype=float))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dir", type=Path, help="a simnav batch --out folder, or one mission's folder")
    parser.add_argument("--window", type=float, default=30.0, help="seconds before each intervention")
    parser.add_argument("--turned", type=float, default=400.0, help="count interventions with more turning, deg")
    parser.add_argument("--leaf", type=float, default=0.6,
                        help="count interventions closer than this to a door leaf standing open, m")
    args = parser.parse_args()
    console = Console()
    dirs = mission_dirs(args.dir)
    if not dirs:
        console.print(f"[red]{args.dir}: no report.json in it or in its mission-*/ or seed-*/ folders")
        raise SystemExit(2)
    table = Table("mission", "time (s)", "x, y (m)", "states in the window (share of steps)", "path (m)",
                  "turned (deg)", "open leaf (m)", title=f"the {args.window:.0f} s before each intervention")
    kinds: Counter = Counter()
    by_leaf = 0
    totals = [0.0, 0.0, 0.0]
    for d in dirs:
        report = json.loads((d / "report.json").read_text())
        nav_csv = d / "navigation.csv"
        rows = list(csv.DictReader(nav_csv.open())) if nav_csv.is_file() else []
        totals = [a + b for a, b in zip(totals, whole_run(rows), strict=True)]
        events = report.get("intervention_log", [])
        for event, leaf_m in zip(events, leaf_distances_m(d, report, events), strict=True):
            states, path_m, turned = window_summary(rows, event["time_s"], args.window)
            n = max(sum(states.values()), 1)
            shares = ", ".join(f"{k} {v / n:.0%}" for k, v in states.most_common())
            table.add_row(d.name, f"{event['time_s']:.0f}", f"{event['x_m']:.1f}, {event['y_m']:.1f}", shares,
                          f"{path_m:.2f}", f"{turned:.0f}", "-" if np.isnan(leaf_m) else f"{leaf_m:.2f}")
            kinds[kind(states, turned, args.turned)] += 1
            by_leaf += int(leaf_m < args.leaf)
    console.print(table)
    console.print(f"{sum(kinds.values())} interventions in {len(dirs)} missions: {kinds['turning']} turning (more "
                  f"than {args.turned:.0f} deg in the window), {kinds['boxed in']} boxed in, {kinds['driving']} "
                  f"driving; {by_leaf} within {args.leaf:g} m of a door leaf standing open")
    console.print(f"whole missions: {totals[0]:.1f} m driven, {totals[1] / 360.0:.0f} full turns, {totals[2]:.0f} s "
                  "turning on the spot")


if __name__ == "__main__":
    main()
