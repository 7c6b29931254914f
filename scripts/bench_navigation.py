"""Speed of the 3D-PTG navigator: one step, and building the collision grids.

The Giraff model (4 prisms) with 3 PTGs (C, alpha, CS) of 121 paths, ref distance 4 m, collision grids at the
navigator's default cell and footprint margin (5 cm; ``--grid-m`` sets both), fed 5000 obstacle points of a room
with people and furniture at every height (about what a 1080-beam lidar plus a QQVGA depth camera give), while the
robot drives through it. Prints medians and p95 of the step time with and without the short-term memory, the 2D
navigator for comparison, and the grid build time cold (empty cache) and cached.

    python scripts/bench_navigation.py [--steps 400] [--grid-m M]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
from rich.console import Console
from rich.table import Table

import simnav  # noqa: F401  (sets up the environment like every simnav entry point)
from simnav.geometry import se2
from simnav.navigation.bands import planar_bands, robot_bands
from simnav.navigation.navigator import NavigatorConfig, ReactiveNavigator3D
from simnav.robot import load_robot


def room_points(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3) points of a 8 x 6 m room: walls, table tops, chair legs, people (world frame)."""
    n_wall, n_table, n_people = count // 2, count // 4, count - count // 2 - count // 4
    t = rng.uniform(0, 28, n_wall)
    wall_xy = np.where(t[:, None] < 8, np.column_stack([t, np.zeros_like(t)]),
                       np.where(t[:, None] < 14, np.column_stack([np.full_like(t, 8), t - 8]),
                                np.where(t[:, None] < 22, np.column_stack([30 - t, np.full_like(t, 6)]),
                                         np.column_stack([np.zeros_like(t), 28 - t]))))
    walls = np.column_stack([wall_xy - (0, 3), rng.uniform(0.02, 1.8, n_wall)])
    tables = np.column_stack([rng.uniform(5.0, 6.5, n_table), rng.uniform(1.0, 2.0, n_table),
                              rng.uniform(0.70, 0.75, n_table)])
    centres = np.array([[3.0, -1.0], [4.5, 1.5], [6.0, -2.0]])
    who = rng.integers(0, len(centres), n_people)
    angle = rng.uniform(0, 2 * np.pi, n_people)
    people = np.column_stack([centres[who] + 0.25 * np.column_stack([np.cos(angle), np.sin(angle)]),
                              rng.uniform(0.02, 1.7, n_people)])
    return np.concatenate([walls, tables, people])


def time_steps(nav: ReactiveNavigator3D, points_world: np.ndarray, steps: int) -> np.ndarray:
    """Step times (ms) while driving the robot through the room with its own commands."""
    nav.set_waypoints(np.array([[4.0, 0.0], [7.0, 0.5]]))
    T, times = se2.from_xy_yaw(0.8, 0.0, 0.0), []
    for k in range(steps):
        local = se2.transform_points(se2.inverse(T), points_world[:, :2])
        cmd = nav.step(0.05 * k, T, np.column_stack([local, points_world[:, 2]]))
        times.append(cmd.runtime_s * 1e3)
        T = T @ se2.exp([cmd.v_m_s * 0.05, 0.0, cmd.w_rad_s * 0.05])
        if cmd.state == "reached":
            nav.set_waypoints(np.array([[1.0, 0.0]]) if T[0, 2] > 4 else np.array([[7.0, 0.5]]))
    return np.array(times[5:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--grid-m", type=float, default=NavigatorConfig().grid_resolution_m,
                        help="collision grid cell and footprint margin, m (default: the navigator's)")
    args = parser.parse_args()
    grid = {"grid_resolution_m": args.grid_m, "footprint_margin_m": args.grid_m}
    robot = load_robot("giraff")
    drive = robot.drive
    points = room_points(np.random.default_rng(0), 5000)
    title = f"3D-PTG navigator, Giraff, 5000 points, {100 * args.grid_m:g} cm grids (simnav {simnav.__version__})"
    table = Table("benchmark", "median", "p95", title=title)
    with tempfile.TemporaryDirectory() as cache:
        for label in ("cold (empty cache)", "cached"):
            t0 = time.perf_counter()
            ReactiveNavigator3D(robot_bands(robot), drive.max_v_m_s, drive.max_w_rad_s, config=NavigatorConfig(**grid),
                                cache_dir=cache)
            table.add_row(f"navigator set-up, 4 bands x 3 PTGs: {label}", f"{time.perf_counter() - t0:.2f} s", "")
        for label, bands, memory in (("3D, 4 bands x 3 PTGs x 121 paths", robot_bands(robot), False),
                                     ("3D, the same + short-term memory", robot_bands(robot), True),
                                     ("2D, 1 band x 3 PTGs x 121 paths", planar_bands(robot), False)):
            nav = ReactiveNavigator3D(bands, drive.max_v_m_s, drive.max_w_rad_s, max_acc_m_s2=drive.max_acc_m_s2,
                                      max_ang_acc_rad_s2=drive.max_ang_acc_rad_s2,
                                      config=NavigatorConfig(memory=memory, **grid), cache_dir=cache)
            ms = time_steps(nav, points, args.steps)
            table.add_row(f"step: {label}", f"{np.median(ms):.2f} ms", f"{np.percentile(ms, 95):.2f} ms")
    Console().print(table)


if __name__ == "__main__":
    main()
