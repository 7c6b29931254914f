"""Top views of a mission in the seconds before one of its interventions (or at any times): who stood where.

Replays a mission from its folder (``world.yaml``, ``robot.yaml`` and ``mission.yaml``, as ``simnav mission`` and
``simnav batch`` write them; the same settings give the same run) and draws, at each chosen time, the map around
the robot: walls and furniture; the door leaves where they are; every person as a circle of their body (gold while
they pause at a goal, pink while they wait before a single-file stretch a robot is in) with their index, an arrow
of their velocity and a dashed line to the waypoint they walk to; the other robots; the robot's outline (its
largest section) at the true pose, with the route's waypoints (the one aimed at ringed) and the obstacle points
above the floor the navigator was given; in each title, the navigator's state and command. One PNG holds the
grid of views.

    python scripts/mission_snapshots.py MISSION_DIR [--intervention 1] [--before 30] [--every 3] [--span 6]
    python scripts/mission_snapshots.py MISSION_DIR --times 52 55 58 [--out views.png]

A replay that leaves the recorded ``trajectory_gt.txt`` (the mission was run by other code) is drawn with a
warning. With ``--intervention K`` (1-based, default 1) the views cover the ``--before`` seconds up to the K-th
intervention of ``report.json``, one every ``--every`` seconds. The PNG goes to
``MISSION_DIR/snapshots-<K or times>.png`` unless ``--out`` says otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
import yaml
from pydantic import ValidationError

from simnav.errors import SimnavError
from simnav.geometry import se2
from simnav.io import read_tum
from simnav.mission.mission import MissionSettings, run_mission
from simnav.navigation.bands import FLOOR_TOLERANCE_M
from simnav.robot import load_robot
from simnav.world import load_world
from simnav.world.footprint import obstacle_polygons

GRID_COLUMNS = 4


@dataclass
class View:
    """What one snapshot shows (world frame, metres)."""

    time_s: float
    T_world_base: np.ndarray
    people_xy: np.ndarray
    people_vel: np.ndarray
    people_target: np.ndarray
    people_pausing: np.ndarray
    people_waiting: np.ndarray
    robots_xy: np.ndarray
    leaves: np.ndarray
    points_xy: np.ndarray
    waypoints: np.ndarray
    target_index: int
    state: str
    v_m_s: float
    w_rad_s: float


class _Done(Exception):
    """Raised by the recorder once the last view is taken: the replay stops there."""


class Recorder:
    """A mission observer that keeps a :class:`View` at the first control step at or after each time."""

    def __init__(self, times_s: list[float]) -> None:
        self.pending = sorted(times_s)
        self.views: list[View] = []
        self.sim = None
        self.pedestrian_radius_m = 0.0
        self.robot_radius_m = 0.0

    def start(self, world, robot, sim, navigator) -> None:
        self.sim = sim
        self.pedestrian_radius_m = sim.crowd.radius_m if sim.crowd is not None else 0.0
        self.robot_radius_m = sim.wanderers.radius_m if sim.wanderers is not None else 0.0

    def step(self, frame) -> None:
        while self.pending and frame.time_s >= self.pending[0] - 1e-9:
            self.pending.pop(0)
            self.views.append(self._view(frame))
        if not self.pending:
            raise _Done

    def finish(self, report) -> None:
        pass

    def _view(self, frame) -> View:
        sim = self.sim
        crowd, wanderers = sim.crowd, sim.wanderers
        empty = np.zeros((0, 2))
        seen = np.asarray(frame.points_base).reshape(-1, 3)
        seen = seen[seen[:, 2] >= FLOOR_TOLERANCE_M]  # the floor is no obstacle to the navigator either
        points = se2.transform_points(frame.T_world_est, seen[:, :2]) if len(seen) else empty
        return View(
            time_s=frame.time_s, T_world_base=frame.T_world_base.copy(),
            people_xy=crowd.positions_xy.copy() if crowd is not None else empty,
            people_vel=crowd.velocities_xy.copy() if crowd is not None else empty,
            people_target=crowd.waypoints_xy if crowd is not None else empty,
            people_pausing=crowd.pausing.copy() if crowd is not None else np.zeros(0, dtype=bool),
            people_waiting=crowd.waiting.copy() if crowd is not None else np.zeros(0, dtype=bool),
            robots_xy=wanderers.positions_xy.copy() if wanderers is not None else empty,
            leaves=sim.doors.segments_xy() if sim.doors is not None else np.zeros((0, 2, 2)),
            points_xy=points, waypoints=np.asarray(frame.waypoints_world).copy(),
            target_index=frame.command.target_index, state=frame.command.state,
            v_m_s=frame.command.v_m_s, w_rad_s=frame.command.w_rad_s)


def replay(mission_dir: Path, times_s: list[float]) -> tuple[Recorder, object, object]:
    """Runs the mission of ``mission_dir`` until the last of ``times_s`` (simulated s); returns the recorder with
    its views, the world and the robot."""
    world = load_world(mission_dir / "world.yaml")
    robot = load_robot(mission_dir / "robot.yaml")
    settings = MissionSettings.model_validate(yaml.safe_load((mission_dir / "mission.yaml").read_text()))
    recorder = Recorder(times_s)
    try:
        run_mission(world, robot, settings, out_dir=None, observers=[recorder])
    except _Done:
        pass
    return recorder, world, robot


def divergence(mission_dir: Path, views: list[View], tolerance_m: float = 0.01) -> tuple[float, float] | None:
    """The first view's time (s) and distance (m) where the replayed robot stands more than ``tolerance_m`` from
    the recorded ``trajectory_gt.txt`` (a run made by other code), or None while they agree or nothing is
    recorded."""
    path = mission_dir / "trajectory_gt.txt"
    if not path.is_file():
        return None
    gt = read_tum(path)
    for view in views:
        k = int(np.argmin(np.abs(gt.stamps_s - view.time_s)))
        if abs(gt.stamps_s[k] - view.time_s) > 0.05:
            continue  # no recorded pose at that time
        distance = float(np.hypot(*(view.T_world_base[:2, 2] - gt.T[k][:2, 3])))
        if distance > tolerance_m:
            return view.time_s, distance
    return None


def draw(views: list[View], world, robot, span_m: float, radii: tuple[float, float], title: str, out_png: Path) -> None:
    """A grid of top views, ``span_m`` wide, centred on the robot of each view."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Polygon

    from simnav.mission.plot import polygon_patch

    cols = min(GRID_COLUMNS, len(views))
    rows = math.ceil(len(views) / cols)
    fig = Figure(figsize=(4.2 * cols, 4.4 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    statics = obstacle_polygons(world, 0.0, 2.0)
    outline = max(robot.prisms, key=lambda p: shapely.Polygon(p.polygon).area).polygon
    person_r, robot_r = radii
    for ax, v in zip(axes, views, strict=False):
        for poly in statics:
            ax.add_patch(polygon_patch(poly))
        for seg in v.leaves:  # door leaves where they stand now
            ax.plot(seg[:, 0], seg[:, 1], color="saddlebrown", lw=4, solid_capstyle="butt", zorder=6)
        if len(v.points_xy):
            ax.plot(v.points_xy[:, 0], v.points_xy[:, 1], ".", color="tab:red", ms=1.5, zorder=3)
        for i, (p, vel, tgt, pausing, waiting) in enumerate(zip(v.people_xy, v.people_vel, v.people_target,
                                                                 v.people_pausing, v.people_waiting, strict=False)):
            # pausing at a goal they reached, waiting before a single-file stretch a robot is in, walking
            colour = "gold" if pausing else "tab:pink" if waiting else "tab:orange"
            ax.add_patch(Circle(p, person_r, facecolor=colour, edgecolor="k", lw=0.5, alpha=0.8, zorder=4))
            ax.plot([p[0], tgt[0]], [p[1], tgt[1]], color="darkorange", lw=0.8, ls="--", zorder=3)
            ax.plot(*tgt, "x", color="darkorange", ms=4, zorder=3)
            ax.annotate(str(i), p, fontsize=6, ha="center", va="center", zorder=7)
            ax.arrow(p[0], p[1], vel[0], vel[1], width=0.01, head_width=0.06, color="k", zorder=5,
                     length_includes_head=True)
        for p in v.robots_xy:
            ax.add_patch(Circle(p, robot_r, facecolor="tab:purple", edgecolor="k", lw=0.5, alpha=0.8, zorder=4))
        body = se2.transform_points(v.T_world_base, np.asarray(outline, dtype=float))
        ax.add_patch(Polygon(body, closed=True, facecolor="tab:blue", edgecolor="k", alpha=0.7, zorder=5))
        x, y, yaw = v.T_world_base[0, 2], v.T_world_base[1, 2], math.atan2(v.T_world_base[1, 0], v.T_world_base[0, 0])
        ax.plot([x, x + 0.5 * math.cos(yaw)], [y, y + 0.5 * math.sin(yaw)], color="tab:blue", lw=1.5, zorder=6)
        if len(v.waypoints):
            ax.plot(v.waypoints[:, 0], v.waypoints[:, 1], "+-", color="tab:green", lw=0.7, ms=6, zorder=4)
            if 0 <= v.target_index < len(v.waypoints):
                ax.plot(*v.waypoints[v.target_index], "o", mfc="none", mec="tab:green", ms=10, mew=1.5, zorder=6)
        ax.set_xlim(x - span_m / 2, x + span_m / 2)
        ax.set_ylim(y - span_m / 2, y + span_m / 2)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        ax.set_title(f"t = {v.time_s:.1f} s, {v.state}, v {v.v_m_s:+.2f} m/s, w {v.w_rad_s:+.2f} rad/s", fontsize=8)
    for ax in axes[len(views):]:
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=90)


def _times(args: argparse.Namespace, report: dict) -> tuple[list[float], str, str]:
    """The times to show, the suffix of the PNG's name and the figure's title."""
    if args.times:
        return sorted(args.times), "t" + "-".join(f"{t:g}" for t in args.times[:3]), "chosen times"
    log = report.get("intervention_log", [])
    if not 1 <= args.intervention <= len(log):
        raise SystemExit(f"--intervention {args.intervention}: the mission has {len(log)} intervention(s) "
                         "(report.json's intervention_log); give --times instead")
    event = log[args.intervention - 1]
    t_end = float(event["time_s"])
    times = [t for t in np.arange(max(t_end - args.before, 0.0), t_end + 1e-9, args.every)]
    title = (f"intervention {args.intervention} at {t_end:.1f} s, ({event['x_m']:.2f}, {event['y_m']:.2f}) m, "
             f"target {event['target']}")
    return [float(t) for t in times], str(args.intervention), title


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mission_dir", type=Path)
    parser.add_argument("--intervention", type=int, default=1, help="1-based index in report.json's log")
    parser.add_argument("--before", type=float, default=30.0, help="seconds shown before the intervention")
    parser.add_argument("--every", type=float, default=3.0, help="seconds between two views")
    parser.add_argument("--times", type=float, nargs="+", help="simulated times to show instead, s")
    parser.add_argument("--span", type=float, default=6.0, help="width of each view, m")
    parser.add_argument("--out", type=Path, help="PNG to write")
    args = parser.parse_args()
    for name, value in (("--before", args.before), ("--every", args.every), ("--span", args.span)):
        if not (value > 0 and math.isfinite(value)):
            parser.error(f"{name} must be a positive number of {'metres' if name == '--span' else 'seconds'}, "
                         f"got {value}")
    for name in ("world.yaml", "robot.yaml", "mission.yaml", "report.json"):
        if not (args.mission_dir / name).is_file():
            raise SystemExit(f"{args.mission_dir / name}: not found (a folder written by simnav mission or batch)")
    report = json.loads((args.mission_dir / "report.json").read_text())
    times, suffix, title = _times(args, report)
    try:
        recorder, world, robot = replay(args.mission_dir, times)
    except (SimnavError, ValidationError, ValueError) as err:
        raise SystemExit(f"{args.mission_dir}: {err}") from None
    if not recorder.views:
        raise SystemExit(f"the mission ended before {times[0]:.1f} s")
    off = divergence(args.mission_dir, recorder.views)
    if off is not None:  # drawn all the same: the replay is still a run of these settings
        print(f"warning: the replay is not the recorded run: at {off[0]:.1f} s the robot stands {off[1]:.2f} m from "
              f"its pose in trajectory_gt.txt (the mission was run by other code; replay it with that version)",
              file=sys.stderr)
    out = args.out or args.mission_dir / f"snapshots-{suffix}.png"
    draw(recorder.views, world, robot, args.span, (recorder.pedestrian_radius_m, recorder.robot_radius_m),
         f"{args.mission_dir.name}: {title}", out)
    print(f"{len(recorder.views)} views -> {out}")


if __name__ == "__main__":
    main()
