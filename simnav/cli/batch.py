"""``simnav batch``: many seeded missions (or env rollouts) in parallel, locally or on Ray (registered on the app)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from simnav.cli.app import SetOption, _run_dir, _update_latest, app, console, err_console, user_errors

ROW_LIMIT = 50
"""Per-job rows printed (all of them are in batch.json and rows.csv)."""


@app.command()
@user_errors
def batch(
    missions: Annotated[int, typer.Option("--missions", "-n", help="Number of missions (or episodes), seeds "
                                                                  "--seed, --seed + 1, ...", min=1)] = 4,
    workers: Annotated[int | None, typer.Option(help="Local worker processes (default: one per CPU); with Ray, "
                                                     "tasks in flight at most (default: the cluster's CPUs).",
                                                min=1)] = None,
    ray_address: Annotated[str | None, typer.Option(help="Run on Ray: 'auto' (the cluster this machine is in), "
                                                         "HOST:PORT (its head) or 'local' (a private instance); "
                                                         "needs the ray extra.", metavar="auto|HOST:PORT|local")
                           ] = None,
    task: Annotated[str, typer.Option(help="mission: simnav mission runs; rollout: env episodes of a policy.")
                    ] = "mission",
    world: Annotated[str, typer.Option(help="World name or YAML path (missions).")] = "office",
    robot: Annotated[str, typer.Option(help="Robot name or YAML path (missions).")] = "giraff",
    targets: Annotated[int | None, typer.Option(help="Targets per mission (default 2 unless --duration).", min=1)
                       ] = None,
    duration: Annotated[float | None, typer.Option(help="Simulated seconds per mission instead.", min=0.05)] = None,
    agents: Annotated[int | None, typer.Option(help="Number of people (default: the world's).", min=0)] = None,
    pose_source: Annotated[str, typer.Option(help="Pose the navigator uses: gt, wheels, srf, rf2o, ...")] = "gt",
    nav: Annotated[str, typer.Option(help="3d or 2d navigator (missions).")] = "3d",
    keep_right: Annotated[float | None, typer.Option(help="Keep this far right of the route where it goes on "
                                                          "straight, m (missions; default 0.4).", min=0, max=2)
                          ] = None,
    replan_after: Annotated[float | None, typer.Option(help="Plan the route again once the waypoint aimed at has "
                                                            "been behind the map's walls this long, s (missions; "
                                                            "default: never; e.g. 3).", min=0)] = None,
    env: Annotated[str, typer.Option(help="Gymnasium id of the env (rollouts).")] = "simnav/OfficeNav-v0",
    policy: Annotated[str, typer.Option(help="Policy of the rollouts: ptg (the 3D-PTG navigator) or random.")
                      ] = "ptg",
    seed: Annotated[int, typer.Option(help="Seed of the first mission.")] = 1,
    out: Annotated[Path | None, typer.Option(help="Output folder (default: runs/<timestamp>-batch).")] = None,
    robot_set: SetOption = None,
    world_set: Annotated[list[str] | None, typer.Option("--world-set", metavar="KEY=VALUE",
                                                        help="Override a world field (repeatable).")] = None,
    sim_set: Annotated[list[str] | None, typer.Option("--sim-set", metavar="KEY=VALUE",
                                                      help="Override a simulator field (repeatable).")] = None,
    nav_set: Annotated[list[str] | None, typer.Option(
        "--nav-set", metavar="KEY=VALUE", help="Override a navigator option (NavigatorConfig), e.g. "
                                               "limit_to_view=true or memory_config.decay_s=10 (repeatable).")] = None,
) -> None:
    """Run many seeded missions (or env rollouts) in parallel and report them together.

    Writes batch.json (summary and one row per mission), rows.csv and, for missions, every mission's report folder
    (mission-<seed>/) into --out. The same seeds give the same rows locally and on Ray.
    """
    _batch(missions, workers, ray_address, task, world, robot, targets, duration, agents, pose_source, nav, env,
           policy, seed, out, robot_set, world_set, sim_set, nav_set, keep_right, replan_after)


def _batch(missions, workers, ray_address, task, world, robot, targets, duration, agents, pose_source, nav, env,
           policy, seed, out, robot_set, world_set, sim_set, nav_set=None, keep_right=None,
           replan_after=None) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from simnav.batch import run_batch

    if task not in ("mission", "rollout"):
        raise typer.BadParameter(f"--task must be mission or rollout, got '{task}'")
    out_dir = out or _run_dir("batch")
    jobs = (_mission_jobs(missions, world, robot, targets, duration, agents, pose_source, nav, seed, out_dir,
                          robot_set, world_set, sim_set, nav_set, keep_right, replan_after) if task == "mission"
            else _rollout_jobs(missions, env, policy, seed))
    where = f"on Ray ({ray_address})" if ray_address else f"on {workers or 'all'} local workers"
    with Progress(TextColumn(f"[bold]batch[/] {len(jobs)} {task}s {where}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), TimeElapsedColumn(), console=err_console, transient=True) as bar:
        bar_task = bar.add_task(task, total=len(jobs), info="")
        reached = [0]

        def progress(done: int, total: int, row: dict) -> None:
            reached[0] += int(bool(row["success"]))
            bar.update(bar_task, completed=done, info=f"{reached[0]}/{done} successful")

        report = run_batch(jobs, workers=workers, ray_address=ray_address, progress=progress)
    report.write(out_dir)
    _update_latest(out_dir)
    _print_report(report, out_dir)


def _mission_jobs(count, world, robot, targets, duration, agents, pose_source, nav, seed, out_dir, robot_set,
                  world_set, sim_set, nav_set=None, keep_right=None, replan_after=None):
    """Validated jobs: every user error (unknown world, robot or pose source, bad field) before any worker starts."""
    from simnav.batch import mission_jobs
    from simnav.config import apply_overrides, validate
    from simnav.mission.mission import MissionSettings
    from simnav.mission.pose import PoseSource
    from simnav.robot import load_robot
    from simnav.sim import SimConfig
    from simnav.world import load_world

    if nav not in ("3d", "2d"):
        raise typer.BadParameter(f"--nav must be 3d or 2d, got '{nav}'")
    load_world(world, world_set)
    PoseSource(pose_source, load_robot(robot, robot_set))
    sim_data = apply_overrides({"pedestrians": agents}, sim_set, "--sim-set")
    sim_cfg = validate(SimConfig, {k: v for k, v in sim_data.items() if v is not None}, "--sim-set")
    settings = validate(MissionSettings, {"targets": targets if targets is not None or duration is not None else 2,
                                          "duration_s": duration, "seed": seed, "pose_source": pose_source,
                                          "nav": nav, "sim": sim_cfg.model_dump(),
                                          "navigator": apply_overrides({}, nav_set, "--nav-set"),
                                          **({} if keep_right is None else {"keep_right_m": keep_right}),
                                          **({} if replan_after is None else
                                             {"replan_after_s": replan_after or None})},
                        "simnav batch")
    return mission_jobs(count, world, robot, settings, out_dir=out_dir, world_set=tuple(world_set or ()),
                        robot_set=tuple(robot_set or ()))


def _rollout_jobs(count, env_id, policy, seed):
    import gymnasium as gym

    import simnav.env  # noqa: F401  (registers the ids)
    from simnav.batch import rollout_jobs
    from simnav.errors import UnknownNameError

    if policy not in ("ptg", "random"):
        raise typer.BadParameter(f"--policy must be ptg or random, got '{policy}'")
    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("simnav/"))
        raise UnknownNameError(f"unknown env '{env_id}'; available: {', '.join(ours)}")
    return rollout_jobs(count, env_id, first_seed=seed, policy=policy)


def _print_report(report, out_dir: Path) -> None:
    s = report.summary
    summary = Table(title=f"batch {out_dir}", show_header=False)
    rows = [("jobs", f"{s['jobs']} {report.task}s, {report.backend}, {report.workers} workers"),
            ("wall time", f"{report.wall_time_s:.1f} s ({s['sim_time_per_wall_s']:.1f} s simulated per second)")]
    if report.task == "mission":
        rows += [("targets reached", f"{s['targets_reached']}/{s['targets_requested']} ({s['success_rate']:.0%}); "
                                     f"missions with all reached {s['missions_all_reached']}/{s['jobs']}"),
                 ("minor incidents", f"{s['incidents']} (static {s['incidents_static']}, door {s['incidents_door']}, "
                                     f"people {s['incidents_people']}, robots {s['incidents_robots']})"),
                 ("interventions", str(s["interventions"])),
                 ("distance", f"{s['distance_m']:.1f} m in {s['sim_time_s']:.0f} s simulated")]
    else:
        rows += [("goal reached", f"{s['episodes_reached']}/{s['jobs']} ({s['success_rate']:.0%})"),
                 ("collisions / time-outs", f"{s['collisions']} / {s['timeouts']}"),
                 ("mean return / steps", f"{s['mean_return']:.2f} / {s['mean_steps']:.0f}")]
    for name, value in rows:
        summary.add_row(name, value)
    console.print(summary)
    console.print(_rows_table(report))


def _rows_table(report) -> Table:
    if report.task == "mission":
        columns = ("seed", "targets", "distance (m)", "sim (s)", "incidents", "interventions", "wall (s)")
        cells = [(r["seed"], f"{r['targets_reached']}/{r['targets_requested']}", f"{r['distance_m']:.1f}",
                  f"{r['duration_s']:.1f}", r["incidents"], r["interventions"], f"{r['wall_time_s']:.1f}")
                 for r in report.rows]
    else:
        columns = ("seed", "success", "collision", "steps", "return", "final distance (m)", "wall (s)")
        cells = [(r["seed"], "yes" if r["success"] else "no", "yes" if r["collision"] else "no", r["steps"],
                  f"{r['episode_return']:.2f}", f"{r['final_distance_m']:.2f}", f"{r['wall_time_s']:.1f}")
                 for r in report.rows]
    table = Table(*columns, title=f"per {report.task}" + (f" (first {ROW_LIMIT})" if len(cells) > ROW_LIMIT else ""))
    for row in cells[:ROW_LIMIT]:
        table.add_row(*(str(c) for c in row))
    return table
