"""The navigation experiments of thesis §6.C.7 in simulation, printed beside what the thesis reports.

1. ``contour_door`` ("Testing the limits of the reactive navigator"): the Giraff starts about 5 m in front of a
   doorway closed by a sheet with the robot's own silhouette cut out (``worlds/contour_door.yaml``, 6 cm of room
   per side), at seeded poses spread across the room's width and heading, and is sent to a target 2 m beyond the
   doorway; max speed 0.3 m/s, short-term memory (STM) off, no people. 3D and 2D navigator, without and with the
   blocking bar (``worlds/contour_door_bar.yaml``). Per run: *pass* (reached the target), *stop* (did not cross,
   ended in front of the doorway without touching it, standing still or waiting/blocked/stuck), *hit* (did not
   cross, ended pressed against the contour), *other*, and *grazes* (contacts with the sheet, bar or door frame).
   Besides the product defaults, the 3D navigator also runs with fine collision grids (2 cm cells, sections grown
   by 2 cm instead of 5 / 5 cm), and fine with the STM on. Thesis: 20/20 passes, 20/20 stops with the bar, about
   half of the passes touch the cloth; a 2D navigator cannot pass.
2. ``desks`` ("Navigation with an outstretched robotic arm"): the Rhodon (arm 0.40 m beyond its base at 0.80-0.95 m)
   visits the desk nodes of ``worlds/desks.yaml`` in a seeded random order (the same for 3D and 2D, every desk
   once per round); each desk node is 0.5 m from a desk edge, where the arm of a robot facing the desk lies 0.2 m
   over the top. A visit follows the roadmap route through the aisle node in front of the desk (so the robot
   arrives facing it) and needs the goal within 0.1 m; it fails when the navigator reports stuck or after
   ``--desk-timeout``. Per visit: reached, and how far the arm reaches over the desk top. Thesis: 3D visits the
   desks with no incident; 2D cannot.
3. ``--long KM``: office and flat missions with the normal mission runner (random roadmap targets, 10 people,
   ground-truth pose, STM on), KM km in all, split as in the thesis (13.5 : 5.01 km); the flat at 0.4 m/s as in
   §6.C.7. Each world's share runs as continuous missions of at most ``--long-chunk-km`` (0.5 km) on consecutive
   seeds, in parallel over ``--jobs``. The navigator has the product defaults; ``--long-nav-set KEY=VALUE`` changes
   an option for both worlds, ``--flat-nav-set KEY=VALUE`` for the flat only (e.g. its 0.8 m doorways with
   ``grid_resolution_m=0.02`` and ``footprint_margin_m=0.02``). With ``--out`` a rerun reuses every mission whose
   ``report.json`` is there with the same world, people, seed and distance, run by the same package code and
   navigator options (a hash of the sources and the options in ``code.txt``). Printed beside Tables 6.1 and 6.2.

The scenarios drive the mission runner (:class:`simnav.mission.mission._MissionRunner`) one route at a time: a
subclass gives it the start pose (as the world's spawn), the route and the end conditions; the control step,
sensing, pose source (ground truth) and contact bookkeeping are the runner's own.

    python scripts/reproduce_nav_experiments.py [--runs 20] [--seed 0] [--timeout 90] [--variants ...]
        [--desk-visits 14] [--only door|desks|none] [--long KM [--long-chunk-km 0.5] [--long-nav-set KEY=VALUE]
        [--flat-nav-set KEY=VALUE] [--long-replan-after S] [--long-worlds office,flat]] [--jobs N] [--out DIR]
        [--verbose]

With ``--out DIR``: ``DIR/nav_experiments.md`` (every table, per-run and per-visit rows included),
``DIR/contour_door*_<nav>_<config>.png`` (every run's path), ``DIR/desks_<nav>.png`` and ``DIR/long_<world>/seed-<N>/``
(the mission runner's report.json, trajectories and plot).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

import simnav  # (before anything that imports mujoco: it chooses the GL backend)
from simnav.mission.mission import (
    INCIDENT_MERGE_S,
    NARROW_NODE_TOLERANCE_M,
    MissionSettings,
    _MissionRunner,
    mission_robot,
)
from simnav.assets import data_dir
from simnav.config import apply_overrides, validate
from simnav.errors import ConfigError
from simnav.navigation.memory import MemoryConfig
from simnav.robot import load_robot
from simnav.robot.spec import RobotSpec
from simnav.sim import SimConfig
from simnav.world import load_world
from simnav.world.footprint import obstacle_union, rectangle
from simnav.world.schema import Spawn, WorldSpec

console = Console(width=200) if not Console().is_terminal else Console()

# ------------------------------------------------------------------------------------------ contour door
DOOR_XY = np.array([8.0, 3.0])
"""Centre of the contoured doorway (worlds/contour_door*.yaml), m."""
BEYOND_NODE = 2
"""Roadmap node of contour_door*.yaml 2 m beyond the doorway: the target."""
DOOR_SPEED_M_S = 0.3
"""Max speed of the contour-door test (§6.C.7)."""
NAV_CONFIGS = {"default": {}, "fine": {"grid_resolution_m": 0.02, "footprint_margin_m": 0.02},
               "fine+STM": {"grid_resolution_m": 0.02, "footprint_margin_m": 0.02, "memory": True},
               "fine+STM30": {"grid_resolution_m": 0.02, "footprint_margin_m": 0.02, "memory": True,
                              "memory_config": MemoryConfig(decay_s=30.0)}}
"""Navigator options of the contour-door runs: the product defaults (5 cm collision grids, sections grown by 5 cm,
STM off as in the thesis); a fine variant (2 cm grids, 2 cm margin) that leaves room in the 6 cm per side of the
cut-out; the fine variant with the short-term memory on; and the same with the memory's evidence decaying over
30 s instead of 3 s (not in the default ``--variants``)."""
DOOR_STILL_EXIT_S = 10.0
"""A contour-door run ends once the robot has stood still this long, s."""
FRONT_OF_DOOR_M = 2.0
"""A robot that did not cross and ends within this distance of the doorway centre is 'in front of the door', m."""
STILL_SPEED_M_S = 0.02
"""Below this mean speed over the last ``STILL_WINDOW_S`` the robot counts as standing still, m/s."""
STILL_WINDOW_S = 5.0
TOUCH_M = 0.005
"""A robot ending closer than this to a static obstacle is touching it ('hit' when it did not cross), m."""
CONTOUR_BOX = (7.85, 8.15, 2.4, 3.6)
"""Contacts inside this (x0, x1, y0, y1) box are contacts with the contour (sheet, bar, door frame), m."""

# -------------------------------------------------------------------------------------------------- desks
DESK_NODE_MAX_M = 0.6
"""Roadmap nodes within this distance of a desk top are the desk nodes (0.5 m in worlds/desks.yaml), m."""
DESK_TOLERANCE_M = 0.1
"""Goal tolerance of a desk visit, m: with the navigator's 0.3 m a robot 0.3 m short of the node, its arm 0.1 m
short of the desk, would count as there."""
ARM_OVER_MIN_M = 0.05
"""A visit counts as 'arm over the desk' when the arm reaches at least this far over the desk top, m."""

# ---------------------------------------------------------------------------------------- long missions
THESIS_LONG = {  # Tables 6.1 and 6.2
    "office": {"km": 13.5, "hours": 11.85, "avg": 0.316, "max": 0.7, "incidents": 20, "interventions": 4},
    "flat": {"km": 5.01, "hours": 8.78, "avg": 0.159, "max": 0.4, "incidents": 11, "interventions": 1},
}
FLAT_SPEED_M_S = 0.4


# ================================================================================================ runner
@dataclass
class Segment:
    """What happened while the robot drove one route."""

    reached: bool
    end: str  # reached | stuck | still | timeout
    state: str  # the navigator's last state
    duration_s: float
    distance_m: float
    final_xy_yaw: tuple[float, float, float]
    still: bool  # mean speed over the last STILL_WINDOW_S below STILL_SPEED_M_S
    states_s: dict[str, float]  # time spent in each navigator state
    contacts: list[dict]  # merged contact events (as the mission report's incidents)
    min_clearance_m: float  # smallest distance from any prism to static obstacles during the segment
    final_clearance_m: float  # the same at the end


class ScenarioRunner(_MissionRunner):
    """The mission runner driving given routes from a given start, with no interventions.

    The start pose is the world's only spawn; :meth:`drive` hands a roadmap route to the navigator (doorway nodes
    passed through, as the runner does) and steps the runner's own control loop until the navigator reports the
    goal reached, reports stuck (no progress for ``stuck_timeout_s``) or ``timeout_s`` passes.
    """

    def __init__(self, world: WorldSpec, robot: RobotSpec, settings: MissionSettings,
                 nav_options: dict | None = None) -> None:
        super().__init__(world, robot, settings, None)
        if nav_options:  # the same navigator with other options (goal tolerance, grid resolution, margin)
            from simnav.navigation.navigator import ReactiveNavigator3D

            old = self.nav
            self.nav = ReactiveNavigator3D(old.bands, old.max_v_m_s, old.max_w_rad_s, max_acc_m_s2=old._acc[0],
                                           max_ang_acc_rad_s2=old._acc[1], config=replace(old.config, **nav_options),
                                           view=old.view, free_space_x_m=old.free_space_x_m)
        self.pose.anchor(0.0, self._true_pose())
        self._record_gt()
        self._next_clearance = 0.0
        self._contacts_seen = 0
        self._last_seen: dict[str, float] = {}

    def drive(self, route: list[int], timeout_s: float, still_exit_s: float | None = None,
              pass_through: Sequence[int] = ()) -> Segment:
        """Follow ``route``; also end (``still``) once the robot has not moved for ``still_exit_s``.

        Doorway nodes are passed through as the runner does (but without its approach waypoints: the scenarios
        hand the route's nodes as they are); so are the nodes in ``pass_through`` (an approach node, so that the
        robot arrives at the goal facing the way from it)."""
        t0, d0 = self.sim.time_s, self.report.distance_m
        self.report.min_clearance_m = math.inf
        fixed = self._narrow[route] | np.isin(route, list(pass_through))
        self.nav.set_waypoints(self.sim.roadmap.nodes_xy[route], allow_skip=~fixed,
                               allowed_distance_m=np.where(fixed, NARROW_NODE_TOLERANCE_M,
                                                           self.nav.config.waypoint_allowed_distance_m))
        states: dict[str, float] = {}
        dt = self.sim.config.control_dt_s
        cmd, steps = None, 0
        while True:
            cmd = self._control_step()
            self._record_gt()
            states[cmd.state] = states.get(cmd.state, 0.0) + dt
            if self.sim.time_s >= self._next_clearance:
                self._measure_clearance()
                self._next_clearance = self.sim.time_s + 0.2
            steps += 1
            if (still_exit_s is not None and steps % 20 == 0 and self.sim.time_s - t0 > still_exit_s
                    and self._still_for(still_exit_s)):
                end = "still"
                break
            if cmd.state == "reached":
                end = "reached"
                break
            if cmd.stuck:
                end = "stuck"
                break
            if self.sim.time_s - t0 >= timeout_s:
                end = "timeout"
                break
        window = [s for (t, _), s in zip(self._gt, self._speeds, strict=True) if t >= self.sim.time_s - STILL_WINDOW_S]
        lowest, self.report.min_clearance_m = self.report.min_clearance_m, math.inf
        self._measure_clearance()
        final_clearance, self.report.min_clearance_m = self.report.min_clearance_m, min(lowest,
                                                                                         self.report.min_clearance_m)
        return Segment(reached=end == "reached", end=end, state=cmd.state, duration_s=self.sim.time_s - t0,
                       distance_m=self.report.distance_m - d0, final_xy_yaw=self.sim.pose_xy_yaw,
                       still=bool(np.mean(window) < STILL_SPEED_M_S), states_s=states,
                       contacts=self._new_contacts(), min_clearance_m=self.report.min_clearance_m,
                       final_clearance_m=final_clearance)

    def _still_for(self, window_s: float) -> bool:
        """Whether the base moved less than 5 cm and turned less than 5 degrees over the last ``window_s``."""
        k = len(self._gt) - 1
        now = self._gt[k][0]
        T1 = self._gt[k][1]
        turned = 0.0
        while k > 0 and self._gt[k - 1][0] >= now - window_s:
            a, b = self._gt[k - 1][1], self._gt[k][1]
            turned += abs(math.atan2(a[1, 0] * b[0, 0] - a[0, 0] * b[1, 0], a[0, 0] * b[0, 0] + a[1, 0] * b[1, 0]))
            k -= 1
            if turned > math.radians(5.0) or np.linalg.norm(self._gt[k][1][:2, 3] - T1[:2, 3]) > 0.05:
                return False
        return True

    def _new_contacts(self) -> list[dict]:
        """Contact events since the last call, merged per body within INCIDENT_MERGE_S as the runner does."""
        out = []
        events = self.sim.contact_events
        for event in events[self._contacts_seen:]:
            previous = self._last_seen.get(event.other)
            self._last_seen[event.other] = event.stamp_s
            if previous is not None and event.stamp_s - previous < INCIDENT_MERGE_S:
                continue
            kind = event.kind if event.kind in ("static", "door") else "people"
            out.append({"time_s": event.stamp_s, "kind": kind, "other": event.other,
                        "x_m": float(event.position_world[0]), "y_m": float(event.position_world[1]),
                        "depth_m": float(event.depth_m)})
        self._contacts_seen = len(events)
        return out

    def path_xy(self) -> np.ndarray:
        return np.array([T[:2, 3] for _, T in self._gt])


def with_spawn(world: WorldSpec, x_m: float, y_m: float, yaw_rad: float) -> WorldSpec:
    return world.model_copy(update={"spawns": [Spawn(x_m=x_m, y_m=y_m, yaw_deg=math.degrees(yaw_rad))]})


def with_max_speed(robot: RobotSpec, max_v_m_s: float) -> RobotSpec:
    return robot.model_copy(update={"drive": robot.drive.model_copy(update={"max_v_m_s": max_v_m_s})})


# ========================================================================================= contour door
@dataclass
class DoorJob:
    world: str
    nav: str
    config: str  # key of NAV_CONFIGS
    run: int
    start: tuple[float, float, float]  # x, y, yaw (rad)
    seed: int
    timeout_s: float


@dataclass
class DoorResult:
    job: DoorJob
    outcome: str  # pass | stop | hit | other
    segment: Segment
    crossed: bool
    door_distance_m: float
    grazes: int  # merged contacts with the contour
    other_contacts: int  # merged static contacts elsewhere
    path_xy: np.ndarray = field(repr=False)
    wall_s: float = 0.0


def door_starts(count: int, seed: int, world: WorldSpec, robot: RobotSpec) -> list[tuple[float, float, float]]:
    """Start poses about 5 m in front of the doorway: y stratified across the room, x jittered, heading +-90 deg."""
    from shapely import affinity
    from shapely.geometry import Polygon

    rng = np.random.default_rng(np.random.SeedSequence([seed, 5]))
    static = [obstacle_union(world, p.z_min_m, p.z_max_m) for p in robot.prisms]
    strata = rng.permutation(count)
    starts = []
    for i in range(count):
        for _ in range(1000):
            y = 1.2 + (strata[i] + rng.uniform()) * (4.8 - 1.2) / count
            x = DOOR_XY[0] - 5.0 + rng.uniform(-0.3, 0.3)
            yaw = rng.uniform(-math.pi / 2, math.pi / 2)
            clear = all(affinity.translate(affinity.rotate(Polygon(p.polygon), yaw, origin=(0, 0), use_radians=True),
                                           x, y).distance(s) > 0.15 for p, s in zip(robot.prisms, static, strict=True))
            if clear:
                break
        starts.append((float(x), float(y), float(yaw)))
    return starts


def run_door(job: DoorJob) -> DoorResult:
    started = time.perf_counter()
    world = with_spawn(load_world(job.world), *job.start)
    settings = MissionSettings(targets=1, seed=job.seed, nav=job.nav, memory=False, keep_right_m=0.0,
                               sim=SimConfig(pedestrians=0, wanderers=0))  # on the roadmap's line, as measured
    robot = mission_robot(with_max_speed(load_robot("giraff"), DOOR_SPEED_M_S), settings)
    runner = ScenarioRunner(world, robot, settings, NAV_CONFIGS[job.config])
    try:
        graph = runner.sim.roadmap
        route = graph.shortest_path(graph.nearest_node(job.start[:2]), BEYOND_NODE)
        seg = runner.drive(route, job.timeout_s, DOOR_STILL_EXIT_S)
        path = runner.path_xy()
    finally:
        runner.close()
    x, y, _ = seg.final_xy_yaw
    crossed = bool(x > DOOR_XY[0])
    door_distance = float(np.hypot(x - DOOR_XY[0], y - DOOR_XY[1]))
    if seg.reached:
        outcome = "pass"
    elif not crossed and seg.final_clearance_m < TOUCH_M:
        outcome = "hit"
    elif not crossed and door_distance < FRONT_OF_DOOR_M and (seg.still or seg.end in ("stuck", "still")
                                                              or seg.state in ("waiting", "blocked")):
        outcome = "stop"
    else:
        outcome = "other"
    x0, x1, y0, y1 = CONTOUR_BOX
    static = [c for c in seg.contacts if c["kind"] in ("static", "door")]
    at_contour = [c for c in static if x0 <= c["x_m"] <= x1 and y0 <= c["y_m"] <= y1]
    return DoorResult(job, outcome, seg, crossed, door_distance, len(at_contour), len(static) - len(at_contour),
                      path[::4], time.perf_counter() - started)


# ================================================================================================ desks
@dataclass
class DeskVisit:
    order: int
    desk: int
    node: int
    reached: bool
    end: str
    state: str
    time_s: float
    arm_over_m: float  # how far the arm reaches over the desk top at the end of the visit (< 0: short of it)
    base_gap_m: float  # distance from the base prism to the desk top at the end
    contacts: list[dict]


@dataclass
class DeskResult:
    nav: str
    visits: list[DeskVisit]
    distance_m: float
    duration_s: float
    min_clearance_m: float
    path_xy: np.ndarray = field(repr=False)
    wall_s: float = 0.0


def desk_nodes(world: WorldSpec) -> dict[int, int]:
    """Roadmap node -> desk (table) index, for the nodes next to a desk."""
    nodes = np.asarray(world.roadmap.nodes, dtype=float)
    tops = [rectangle(t.center, t.size_m, t.yaw_deg) for t in world.tables]
    from shapely.geometry import Point

    out = {}
    for i, xy in enumerate(nodes):
        d = [top.distance(Point(xy)) for top in tops]
        if min(d) <= DESK_NODE_MAX_M:
            out[i] = int(np.argmin(d))
    return out


def desk_order(world: WorldSpec, visits: int, seed: int) -> list[int]:
    """Desk nodes in a seeded random order: every desk once per round, never the same desk twice in a row."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 6]))
    nodes = sorted(desk_nodes(world))
    order: list[int] = []
    while len(order) < visits:
        batch = list(rng.permutation(nodes))
        if order and batch[0] == order[-1]:
            batch.append(batch.pop(0))
        order += [int(n) for n in batch]
    return order[:visits]


def arm_over_desk(robot: RobotSpec, pose: tuple[float, float, float], desk) -> tuple[float, float]:
    """(how far the arm prism reaches over the desk top, gap from the base prism to the desk top), m."""
    from shapely import affinity
    from shapely.geometry import Point, Polygon

    x, y, yaw = pose
    top = rectangle(desk.center, desk.size_m, desk.yaw_deg)

    def placed(prism):
        return affinity.translate(affinity.rotate(Polygon(prism.polygon), yaw, origin=(0, 0), use_radians=True), x, y)

    arm = placed(next(p for p in robot.prisms if p.name == "arm"))
    base = placed(next(p for p in robot.prisms if p.name == "base"))
    verts = np.asarray(arm.exterior.coords)
    depth = max((top.exterior.distance(Point(v)) if top.contains(Point(v)) else -top.distance(Point(v)))
                for v in verts)
    return float(depth), float(base.distance(top))


def run_desks(nav: str, visits: int, seed: int, people: int, timeout_s: float, tolerance_m: float | None,
              approach: bool = True, on_visit: Callable[[int], None] | None = None) -> DeskResult:
    started = time.perf_counter()
    world = load_world("desks")
    settings = MissionSettings(targets=1, seed=seed, nav=nav, memory=True, keep_right_m=0.0,  # as measured
                               sim=SimConfig(pedestrians=people, wanderers=0))
    robot = mission_robot(load_robot("rhodon"), settings)
    desks = desk_nodes(world)
    aisle = np.array([i for i in range(len(world.roadmap.nodes)) if i not in desks])
    options = {"target_allowed_distance_m": tolerance_m} if tolerance_m is not None else None
    runner = ScenarioRunner(world, robot, settings, options)
    out: list[DeskVisit] = []
    try:
        graph = runner.sim.roadmap
        for k, node in enumerate(desk_order(world, visits, seed)):
            # route from the nearest aisle node (a robot at or short of a desk first backs out into the aisle)
            xy = np.array(runner.sim.pose_xy_yaw[:2])
            start = int(aisle[np.argmin(np.linalg.norm(graph.nodes_xy[aisle] - xy, axis=1))])
            route = graph.shortest_path(start, node)
            # the aisle node in front of the desk is passed through: the robot arrives facing the desk
            seg = runner.drive(route, timeout_s, pass_through=route[-2:-1] if approach else ())
            desk = world.tables[desks[node]]
            over, gap = arm_over_desk(robot, seg.final_xy_yaw, desk)
            out.append(DeskVisit(k, desks[node], node, seg.reached, seg.end, seg.state, seg.duration_s, over, gap,
                                 seg.contacts))
            if on_visit is not None:
                on_visit(k + 1)
        result = DeskResult(nav, out, runner.report.distance_m, runner.sim.time_s, runner.report.min_clearance_m,
                            runner.path_xy()[::4])
    finally:
        runner.close()
    result.wall_s = time.perf_counter() - started
    return result


# ======================================================================================= long missions
class DistanceRunner(_MissionRunner):
    """The mission runner, ending once the robot has driven ``distance_m``."""

    def __init__(self, *args, distance_m: float, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.distance_budget_m = distance_m

    def _finished(self) -> bool:
        return self.report.distance_m >= self.distance_budget_m or super()._finished()


@dataclass(frozen=True)
class LongJob:
    """One continuous mission of a long run: ``km`` km in ``world`` among ``people`` people."""

    world: str
    km: float
    people: int
    seed: int
    out_dir: Path | None = None
    navigator: tuple[tuple[str, object], ...] = ()  # navigator options (``MissionSettings.navigator``), sorted
    replan_after_s: float | None = None  # ``MissionSettings.replan_after_s``


def long_jobs(km: float, people: dict[str, int], seed: int, chunk_km: float, out: Path | None,
              navigator: dict[str, dict] | None = None, worlds: Sequence[str] = ("office", "flat"),
              replan_after_s: float | None = None) -> list[LongJob]:
    """KM km split between the office and the flat as Tables 6.1 : 6.2, each share in continuous missions of at most
    ``chunk_km`` km on consecutive seeds; the office's first. ``navigator`` maps a world to its navigator options;
    ``worlds`` keeps only those worlds' jobs (the same jobs as in the whole run)."""
    total = sum(t["km"] for t in THESIS_LONG.values())
    jobs = []
    for name in [w for w in ("office", "flat") if w in worlds]:
        share = km * THESIS_LONG[name]["km"] / total
        n = max(1, math.ceil(share / chunk_km - 1e-9))
        options = tuple(sorted((navigator or {}).get(name, {}).items()))
        jobs += [LongJob(name, share / n, people[name], seed + k,
                         out / f"long_{name}" / f"seed-{seed + k}" if out is not None else None, options,
                         replan_after_s)
                 for k in range(n)]
    return jobs


def run_long(job: LongJob) -> dict:
    """Run one long mission (or reuse its ``report.json`` when the folder holds one of the same job); the report as a
    dict (the schema of ``report.json``)."""
    done = _finished_long(job)
    if done is not None:
        return done
    if job.out_dir is not None:
        job.out_dir.mkdir(parents=True, exist_ok=True)
        (job.out_dir / "code.txt").write_text(_job_stamp(job))
    world = load_world(job.world)
    robot = load_robot("giraff")
    if job.world == "flat":
        robot = with_max_speed(robot, FLAT_SPEED_M_S)
    settings = MissionSettings(targets=100000, seed=job.seed, sim=SimConfig(pedestrians=job.people),
                               navigator=dict(job.navigator), replan_after_s=job.replan_after_s)
    runner = DistanceRunner(world, mission_robot(robot, settings), settings, job.out_dir, distance_m=job.km * 1000.0)
    try:
        report = runner.run(None)
    finally:
        runner.close()
    return json.loads(report.to_json())


def _finished_long(job: LongJob) -> dict | None:
    """The report of an earlier run of this job in ``job.out_dir``, if it finished with the same settings and the
    same code."""
    if job.out_dir is None or not (job.out_dir / "report.json").is_file():
        return None
    code = job.out_dir / "code.txt"
    if not code.is_file() or code.read_text() != _job_stamp(job):
        return None
    data = json.loads((job.out_dir / "report.json").read_text())
    same = (data.get("world"), data.get("people"), data.get("seed")) == (job.world, job.people, job.seed)
    return data if same and data.get("distance_m", 0.0) >= job.km * 1000.0 else None


def _job_stamp(job: LongJob) -> str:
    """What a long mission's folder records of the code and the navigator options that ran it (``code.txt``)."""
    replan = f"replan_after_s={job.replan_after_s}\n" if job.replan_after_s is not None else ""
    options = json.dumps(dict(job.navigator), sort_keys=True) + "\n" if job.navigator else ""
    return code_fingerprint() + "\n" + options + replan


def code_fingerprint() -> str:
    """SHA-1 over the simnav package's sources and the shipped worlds and robots: a mission is reused only by the
    code that ran it."""
    digest = hashlib.sha1()
    for root in (Path(simnav.__file__).parent, data_dir("worlds"), data_dir("robots")):
        for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".yaml") and p.is_file()):
            digest.update(f"{root.name}/{path.relative_to(root)}".encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


# ============================================================================================ execution
def _progress() -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[info]}"), TimeElapsedColumn(), console=console)


def run_jobs(fn, jobs: list, workers: int, label: str) -> list:
    """Run ``fn`` over ``jobs`` (in ``workers`` processes when > 1) with a progress bar; results in job order."""
    results: list = [None] * len(jobs)
    with _progress() as bar:
        task = bar.add_task(label, total=len(jobs), info="")
        if workers <= 1:
            for i, job in enumerate(jobs):
                results[i] = fn(job)
                bar.update(task, advance=1, info=_info(results[i]))
        else:
            with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
                futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
                for future in as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update(task, advance=1, info=_info(results[futures[future]]))
    return results


def _info(result) -> str:
    if isinstance(result, DoorResult):
        return (f"{_variant(result.job.nav, result.job.config)} {result.job.world} run {result.job.run + 1}: "
                f"{result.outcome}")
    if isinstance(result, DeskResult):
        return f"{result.nav}: {sum(v.reached for v in result.visits)}/{len(result.visits)} desks"
    if isinstance(result, dict):
        return (f"{result['world']} seed {result['seed']}: {result['distance_m']:.0f} m, "
                f"{result['interventions']} interventions")
    return ""


# ================================================================================================ tables
def md_table(table: Table) -> str:
    """A rich table as markdown."""
    head = [str(c.header) for c in table.columns]
    cells = [list(c._cells) for c in table.columns]
    lines = [f"### {table.title}" if table.title else "", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for r in range(len(cells[0]) if cells else 0):
        lines.append("| " + " | ".join(str(col[r]) for col in cells) + " |")
    if table.caption:
        lines += ["", str(table.caption)]
    return "\n".join(lines) + "\n"


THESIS_DOOR = {("3d", "contour_door"): "20/20 pass, ~50 % touch the cloth", ("3d", "contour_door_bar"): "20/20 stop",
               ("2d", "contour_door"): "cannot pass", ("2d", "contour_door_bar"): "cannot pass"}
DOOR_VARIANTS = ("3d:default", "2d:default", "3d:fine", "3d:fine+STM")
"""navigator:NAV_CONFIGS key of the contour-door runs, in table order."""
OUTCOMES = ("pass", "stop", "hit", "other")


def _variant(nav: str, config: str) -> str:
    return nav.upper() if config == "default" else f"{nav.upper()} {config}"


def door_tables(results: list[DoorResult], variants: list[tuple[str, str]], runs: int,
                timeout_s: float) -> list[Table]:
    fine = NAV_CONFIGS["fine"]
    summary = Table("navigator", "world", *OUTCOMES, "runs with grazes", "grazes", "other contacts",
                    "time to pass (s)", "min clearance (m)", "thesis (3D / 2D)",
                    title=f"contour door: Giraff at {DOOR_SPEED_M_S} m/s, no people, {runs} starts ~5 m in front of "
                          f"the door, limit {timeout_s:.0f} s",
                    caption="pass: target beyond the door reached; stop: not crossed, ended within "
                            f"{FRONT_OF_DOOR_M} m of the doorway, not touching, standing still or waiting/blocked/"
                            "stuck; hit: not crossed, ended pressed against the contour; grazes: contacts (merged "
                            "within 1 s) with the sheet/bar/door frame; min clearance: median over runs of the "
                            "smallest distance from any prism to static obstacles. Navigators: product defaults "
                            "(collision grids at 0.05 m, sections grown by 0.05 m, STM off as in the thesis); 'fine': "
                            f"grids at {fine['grid_resolution_m']} m, sections grown by {fine['footprint_margin_m']} "
                            "m; '+STM': short-term memory on")
    per_run = Table("navigator", "world", "run", "start x, y, yaw", "outcome", "end", "last state", "time (s)",
                    "final x, y", "grazes", "min / final clearance (m)", title="contour door: every run")
    for world in ("contour_door", "contour_door_bar"):
        for nav, config in variants:
            rows = [r for r in results if (r.job.world, r.job.nav, r.job.config) == (world, nav, config)]
            if not rows:
                continue
            count = {k: sum(r.outcome == k for r in rows) for k in OUTCOMES}
            pass_times = [r.segment.duration_s for r in rows if r.outcome == "pass"]
            clear = [r.segment.min_clearance_m for r in rows]
            summary.add_row(_variant(nav, config), world, *(f"{count[k]}/{len(rows)}" for k in OUTCOMES),
                            f"{sum(r.grazes > 0 for r in rows)}/{len(rows)}", str(sum(r.grazes for r in rows)),
                            str(sum(r.other_contacts for r in rows)),
                            f"{np.median(pass_times):.1f}" if pass_times else "-", f"{np.median(clear):.3f}",
                            THESIS_DOOR[nav, world])
            for r in rows:
                s, (fx, fy, _) = r.segment, r.segment.final_xy_yaw
                x, y, yaw = r.job.start
                per_run.add_row(_variant(nav, config), world, str(r.job.run + 1),
                                f"{x:.2f}, {y:.2f}, {math.degrees(yaw):+.0f}", r.outcome, s.end, s.state,
                                f"{s.duration_s:.1f}", f"{fx:.2f}, {fy:.2f}", str(r.grazes),
                                f"{s.min_clearance_m:.3f} / {s.final_clearance_m:.3f}")
    return [summary, per_run]


def desk_tables(results: list[DeskResult], world: WorldSpec, tolerance: float, approach: bool) -> list[Table]:
    summary = Table("navigator", "desk visits reached", "arm over the desk", "failed (stuck / timeout)",
                    "distance (m)", "time (s)", "contacts static / people", "min clearance (m)", "thesis",
                    title=f"desks: Rhodon (arm 0.40 m beyond the base), desk nodes 0.5 m from the desk edge, goal "
                          f"tolerance {tolerance:.2f} m" + (", through the aisle node in front" if approach else ""),
                    caption=f"arm over the desk: the arm prism reaches at least {ARM_OVER_MIN_M} m over the desk "
                            "top at the end of the visit")
    per_desk = Table("navigator", *[f"desk {k}" for k in range(len(world.tables))],
                     title="desks: reached (arm over) / visits, per desk")
    visits = Table("navigator", "#", "desk", "reached", "end", "last state", "time (s)", "arm over (m)",
                   "base gap (m)", "contacts", title="desks: every visit")
    thesis = {"3d": "visits the 7 desks, no incidents", "2d": "cannot (the arm over the desk is a collision)"}
    for r in results:
        reached = sum(v.reached for v in r.visits)
        over = sum(v.reached and v.arm_over_m >= ARM_OVER_MIN_M for v in r.visits)
        stuck = sum(v.end == "stuck" for v in r.visits)
        timeout = sum(v.end == "timeout" for v in r.visits)
        contacts = [c for v in r.visits for c in v.contacts]
        static = sum(c["kind"] in ("static", "door") for c in contacts)
        summary.add_row(r.nav.upper(), f"{reached}/{len(r.visits)}", f"{over}/{len(r.visits)}",
                        f"{stuck} / {timeout}", f"{r.distance_m:.0f}", f"{r.duration_s:.0f}",
                        f"{static} / {len(contacts) - static}", f"{r.min_clearance_m:.3f}", thesis[r.nav])
        cells = []
        for k in range(len(world.tables)):
            mine = [v for v in r.visits if v.desk == k]
            over = sum(v.reached and v.arm_over_m >= ARM_OVER_MIN_M for v in mine)
            cells.append(f"{sum(v.reached for v in mine)} ({over}) / {len(mine)}")
        per_desk.add_row(r.nav.upper(), *cells)
        for v in r.visits:
            visits.add_row(r.nav.upper(), str(v.order + 1), str(v.desk), "yes" if v.reached else "no", v.end, v.state,
                           f"{v.time_s:.1f}", f"{v.arm_over_m:+.2f}", f"{v.base_gap_m:.2f}", str(len(v.contacts)))
    return [summary, per_desk, visits]


def long_table(reports: list[dict]) -> Table:
    """Per world, the long missions' sums beside the thesis' row."""
    table = Table("world", "missions", "people", "distance (km)", "duration (h)", "avg speed (m/s)",
                  "max speed (m/s)", "targets reached", "minor incidents (static/door/people/robots)",
                  "of which robot stopped", "interventions", "interventions per km",
                  title="long missions beside Tables 6.1 / 6.2 (thesis rows: the real Giraff)",
                  caption="each world's share of the distance in continuous missions on consecutive seeds")
    for world in ("office", "flat"):
        rows = [r for r in reports if r["world"] == world]
        if not rows:
            continue
        km = sum(r["distance_m"] for r in rows) / 1000
        hours = sum(r["duration_s"] for r in rows) / 3600
        kinds = ("total", "static", "door", "people", "robots", "robot_stopped")
        i = {k: sum(r["minor_incidents"].get(k, 0) for r in rows) for k in kinds}
        interventions = sum(r["interventions"] for r in rows)
        table.add_row(f"{world} (simnav)", str(len(rows)), str(rows[0]["people"]), f"{km:.3f}", f"{hours:.2f}",
                      f"{km / hours / 3.6:.3f}", f"{max(r['max_speed_m_s'] for r in rows):.2f}",
                      f"{sum(r['targets_reached'] for r in rows)}/{sum(r['targets_requested'] for r in rows)}",
                      f"{i['total']} ({i['static']}/{i['door']}/{i['people']}/{i['robots']})", str(i["robot_stopped"]),
                      str(interventions), f"{interventions / km:.1f}")
        t = THESIS_LONG[world]
        table.add_row(f"{world} (thesis)", "-", "-", f"{t['km']:.2f}", f"{t['hours']:.2f}", f"{t['avg']:.3f}",
                      f"{t['max']:.2f}", "-", str(t["incidents"]), "-", str(t["interventions"]),
                      f"{t['interventions'] / t['km']:.1f}")
    return table


def long_runs_table(reports: list[dict]) -> Table:
    """One row per long mission."""
    table = Table("world", "seed", "distance (m)", "sim (s)", "targets", "incidents", "interventions", "wall (s)",
                  title="long missions: every mission")
    for r in reports:
        table.add_row(r["world"], str(r["seed"]), f"{r['distance_m']:.0f}", f"{r['duration_s']:.0f}",
                      f"{r['targets_reached']}/{r['targets_requested']}", str(r["minor_incidents"]["total"]),
                      str(r["interventions"]), f"{r['wall_time_s']:.0f}")
    return table


# ================================================================================================ plots
def plot_runs(world: WorldSpec, paths: list[tuple[np.ndarray, str, list[dict]]], title: str, out_png: Path,
              zoom: tuple[float, float, float, float] | None = None) -> None:
    """Every run's path over the map (colour by outcome), contacts as crosses; optional zoomed second panel."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from simnav.mission.plot import polygon_patch
    from simnav.world.footprint import obstacle_polygons

    colours = {"pass": "tab:green", "stop": "tab:blue", "hit": "tab:red", "other": "tab:orange"}
    fig = Figure(figsize=(14 if zoom else 9, 6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2 if zoom else 1, squeeze=False)[0]
    for ax in axes:
        for poly in obstacle_polygons(world, 0.0, 2.0):
            ax.add_patch(polygon_patch(poly))
        for path, outcome, contacts in paths:
            ax.plot(path[:, 0], path[:, 1], color=colours.get(outcome, "tab:gray"), lw=0.8, alpha=0.8)
            ax.plot(*path[0], "o", color=colours.get(outcome, "tab:gray"), ms=3)
            ax.plot(*path[-1], "s", color=colours.get(outcome, "tab:gray"), ms=3)
            for c in contacts:
                ax.plot(c["x_m"], c["y_m"], "x", color="k", ms=6)
        ax.set_aspect("equal")
        ax.set(xlabel="x (m)", ylabel="y (m)")
    if zoom:
        axes[1].set(xlim=zoom[:2], ylim=zoom[2:], title="zoom")
    axes[0].set_title(title, fontsize=9)
    handles = [axes[0].plot([], [], color=c, label=k)[0] for k, c in colours.items()]
    axes[0].legend(handles=handles, loc="upper left", fontsize="small")
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)


# ================================================================================================= main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="contour-door runs per navigator and world")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=90.0, help="contour-door run limit, simulated s")
    parser.add_argument("--variants", default=",".join(DOOR_VARIANTS),
                        help=f"contour-door navigators, nav:config with config in {', '.join(NAV_CONFIGS)}")
    parser.add_argument("--desk-visits", type=int, default=14, help="desk targets per navigator (7 desks)")
    parser.add_argument("--desk-timeout", type=float, default=150.0, help="limit per desk visit, simulated s")
    parser.add_argument("--desk-people", type=int, default=0, help="people walking in the desks lab")
    parser.add_argument("--desk-tolerance", type=float, default=DESK_TOLERANCE_M,
                        help="goal tolerance of the desk visits, m (the navigator's default is 0.3)")
    parser.add_argument("--no-desk-approach", dest="desk_approach", action="store_false",
                        help="let the navigator cut past the aisle node in front of each desk")
    parser.add_argument("--only", choices=("door", "desks", "none"), default=None,
                        help="run only one of the two scenario experiments ('none': only --long)")
    parser.add_argument("--long", type=float, default=None, metavar="KM",
                        help="also run office + flat missions of KM km in all (split 13.5 : 5.01 as the thesis)")
    parser.add_argument("--long-people", default="10", metavar="N[,N_FLAT]",
                        help="people in the office and the flat (one number for both)")
    parser.add_argument("--long-chunk-km", type=float, default=0.5, metavar="KM",
                        help="longest continuous long mission; each world's share is split into missions of at most "
                             "this distance on consecutive seeds, run in parallel with --jobs")
    parser.add_argument("--long-nav-set", action="append", default=[], metavar="KEY=VALUE",
                        help="a navigator option for the long missions (as `simnav mission --nav-set`); repeatable")
    parser.add_argument("--flat-nav-set", action="append", default=[], metavar="KEY=VALUE",
                        help="a navigator option for the flat's long missions only, after --long-nav-set, e.g. "
                             "grid_resolution_m=0.02; repeatable")
    parser.add_argument("--long-replan-after", type=float, default=None, metavar="S",
                        help="re-plan a long mission's route once the waypoint aimed at has been behind the map's "
                             "walls S seconds (as `simnav mission --replan-after`; default: never)")
    parser.add_argument("--long-worlds", default="office,flat", metavar="office,flat",
                        help="run only these worlds' share of the long missions (as in a whole run)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--out", type=Path, default=None, help="folder for markdown tables and plots")
    parser.add_argument("--verbose", action="store_true", help="also print the per-run and per-visit tables")
    args = parser.parse_args()
    navigator = long_navigator(parser, args.long_nav_set, args.flat_nav_set)  # a bad option fails before any run
    long_worlds = [w.strip() for w in args.long_worlds.split(",") if w.strip()]
    if not long_worlds or any(w not in THESIS_LONG for w in long_worlds):
        parser.error(f"--long-worlds: expected a comma-separated list of {', '.join(THESIS_LONG)}, "
                     f"got {args.long_worlds!r}")
    started = time.perf_counter()
    tables: list[Table] = []
    out = args.out
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)

    if args.only in (None, "door"):
        t0 = time.perf_counter()
        worlds = ("contour_door", "contour_door_bar")
        variants = [tuple(v.split(":")) for v in args.variants.split(",")]
        unknown = [v for v in variants if len(v) != 2 or v[0] not in ("3d", "2d") or v[1] not in NAV_CONFIGS]
        if unknown:
            parser.error(f"--variants: unknown {unknown}")
        starts = door_starts(args.runs, args.seed, load_world(worlds[0]), load_robot("giraff"))
        jobs = [DoorJob(w, nav, config, i, s, args.seed * 1000 + i, args.timeout) for w in worlds
                for nav, config in variants for i, s in enumerate(starts)]
        results = run_jobs(run_door, jobs, args.jobs, "contour door")
        door = door_tables(results, variants, args.runs, args.timeout)
        for t in door if args.verbose else door[:1]:
            console.print(t)
        tables += door
        console.print(f"contour door: {time.perf_counter() - t0:.0f} s wall")
        if out is not None:
            for w in worlds:
                for nav, config in variants:
                    rows = [r for r in results if (r.job.world, r.job.nav, r.job.config) == (w, nav, config)]
                    count = {k: sum(r.outcome == k for r in rows) for k in OUTCOMES}
                    plot_runs(load_world(w), [(r.path_xy, r.outcome, r.segment.contacts) for r in rows],
                              f"{w}, {_variant(nav, config)}: " + ", ".join(f"{v} {k}" for k, v in count.items()),
                              out / f"{w}_{nav}_{config.replace('+', '_')}.png", zoom=(6.0, 10.5, 1.0, 5.0))

    if args.only in (None, "desks"):
        t0 = time.perf_counter()
        world = load_world("desks")
        with _progress() as bar:
            tasks = {nav: bar.add_task(f"desks {nav.upper()}", total=args.desk_visits, info="") for nav in ("3d", "2d")}
            common = (args.desk_visits, args.seed, args.desk_people, args.desk_timeout, args.desk_tolerance,
                      args.desk_approach)
            if args.jobs <= 1:
                desk_results = [run_desks(nav, *common, lambda k, nav=nav: bar.update(tasks[nav], completed=k))
                                for nav in ("3d", "2d")]
            else:
                with ProcessPoolExecutor(2, mp_context=get_context("spawn")) as pool:
                    futures = {nav: pool.submit(run_desks, nav, *common) for nav in ("3d", "2d")}
                    desk_results = []
                    for nav, future in futures.items():
                        desk_results.append(future.result())
                        bar.update(tasks[nav], completed=args.desk_visits)
        desk = desk_tables(desk_results, world, args.desk_tolerance, args.desk_approach)
        for t in desk if args.verbose else desk[:2]:
            console.print(t)
        tables += desk
        console.print(f"desks: {time.perf_counter() - t0:.0f} s wall")
        if out is not None:
            for r in desk_results:
                contacts = [c for v in r.visits for c in v.contacts]
                ok = sum(v.reached for v in r.visits)
                plot_runs(world, [(r.path_xy, "pass", contacts)], f"desks, Rhodon, {r.nav.upper()}: {ok}/"
                          f"{len(r.visits)} desk visits reached", out / f"desks_{r.nav}.png")

    if args.long is not None:
        people = [int(n) for n in args.long_people.split(",")]
        people = dict(zip(("office", "flat"), people if len(people) == 2 else people * 2, strict=True))
        t0 = time.perf_counter()
        jobs = long_jobs(args.long, people, args.seed, args.long_chunk_km, out, navigator, long_worlds,
                         args.long_replan_after or None)
        reports = run_jobs(run_long, jobs, args.jobs, "long missions")
        long = [long_table(reports), long_runs_table(reports)]
        for t in long if args.verbose else long[:1]:
            console.print(t)
        tables += long
        console.print(f"long missions: {time.perf_counter() - t0:.0f} s wall")

    console.print(f"total wall time {time.perf_counter() - started:.0f} s")
    if out is not None:
        text = "# simnav: navigation experiments of thesis §6.C.7\n\n" + "\n".join(md_table(t) for t in tables)
        (out / "nav_experiments.md").write_text(text)
        console.print(f"wrote {out / 'nav_experiments.md'}")


def long_navigator(parser: argparse.ArgumentParser, common: list[str], flat: list[str]) -> dict[str, dict]:
    """The long missions' navigator options per world from ``--long-nav-set`` and ``--flat-nav-set``; a bad one ends
    the script with one error naming it."""
    try:
        options = {"office": apply_overrides({}, common, "--long-nav-set")}
        options["flat"] = apply_overrides(options["office"], flat, "--flat-nav-set")
        for name, navigator in options.items():
            validate(MissionSettings, {"targets": 1, "navigator": navigator}, f"long missions in the {name}")
    except ConfigError as err:
        parser.error(str(err))
    return options


if __name__ == "__main__":
    main()
