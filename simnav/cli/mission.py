"""``simnav mission``: headless navigation missions among people (registered on the main app)."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from simnav.cli.app import SetOption, _run_dir, _update_latest, app, console, err_console, user_errors


@app.command()
@user_errors
def mission(
    world: Annotated[str, typer.Option(help="World name (simnav worlds) or YAML path.")] = "office",
    robot: Annotated[str, typer.Option(help="Robot name (simnav robots) or YAML path.")] = "giraff",
    agents: Annotated[int | None, typer.Option(help="Number of people (default: the world's).", min=0)] = None,
    robots_: Annotated[int | None, typer.Option("--robots", help="Other wandering robots (default: the world's).",
                                                min=0)] = None,
    targets: Annotated[int | None, typer.Option(help="Targets to visit (default 2 unless --duration).",
                                                min=1)] = None,
    duration: Annotated[float | None, typer.Option(help="Run for this many simulated seconds instead.",
                                                   min=0.05)] = None,
    seed: Annotated[int, typer.Option(help="Seed of targets, people and sensor noise.")] = 1,
    pose_source: Annotated[str, typer.Option(help="Pose used to navigate: gt, wheels, srf, rf2o (and difodo, "
                                                  "vosf when installed).")] = "gt",
    nav: Annotated[str, typer.Option(help="3d: one prism per robot section; 2d: the whole robot as one prism.")
                   ] = "3d",
    no_memory: Annotated[bool, typer.Option("--no-memory", help="Switch the short-term memory off.")] = False,
    keep_right: Annotated[float | None, typer.Option(help="Keep this far right of the route where it goes on "
                                                          "straight, m (default 0.4; 0: on the roadmap's line).",
                                                     min=0, max=2)] = None,
    replan_after: Annotated[float | None, typer.Option(help="Plan the route again once the waypoint aimed at has "
                                                            "been behind the map's walls this long, s (default: "
                                                            "never; e.g. 3).", min=0)] = None,
    viz: Annotated[bool, typer.Option("--viz", help="Stream the mission to meshcat (prints the URL to open).")
                   ] = False,
    viz_url: Annotated[str | None, typer.Option(help="Join a running meshcat server at this ZMQ URL instead of "
                                                     "starting one (e.g. tcp://127.0.0.1:6000).")] = None,
    viz_rate: Annotated[float, typer.Option(help="Viewer updates per simulated second.", min=0.1, max=100)] = 10.0,
    html: Annotated[Path | None, typer.Option(help="Write a self-contained HTML replay of the mission here.")
                    ] = None,
    hardware: Annotated[str | None, typer.Option(help="Hardware in the loop: the Dynamixel port of the robot's "
                                                      "wheels (e.g. /dev/ttyUSB0), or 'virtual' for the emulated "
                                                      "bus.", metavar="PATH|virtual")] = None,
    out: Annotated[Path | None, typer.Option(help="Output folder (default: runs/<timestamp>-mission).")] = None,
    robot_set: SetOption = None,
    world_set: Annotated[list[str] | None, typer.Option("--world-set", metavar="KEY=VALUE",
                                                        help="Override a world field (repeatable).")] = None,
    sim_set: Annotated[list[str] | None, typer.Option(
        "--sim-set", metavar="KEY=VALUE", help="Override a simulator field, e.g. control_dt_s=0.1.")] = None,
    nav_set: Annotated[list[str] | None, typer.Option(
        "--nav-set", metavar="KEY=VALUE", help="Override a navigator option (NavigatorConfig), e.g. "
                                               "limit_to_view=true or memory_config.decay_s=10 (repeatable).")] = None,
) -> None:
    """Navigate to random roadmap targets with the 3D-PTG navigator, headless, and report how it went.

    Writes report.json, trajectory_gt.txt, trajectory_est.txt (TUM), mission.png and viz_recording.npz (for
    `simnav view`) into --out.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from simnav.config import apply_overrides, validate
    from simnav.mission.mission import MissionSettings, mission_robot, run_mission
    from simnav.mission.pose import PoseSource
    from simnav.robot import load_robot
    from simnav.sim import SimConfig
    from simnav.world import load_world

    if nav not in ("3d", "2d"):
        raise typer.BadParameter(f"--nav must be 3d or 2d, got '{nav}'")
    world_spec = load_world(world, world_set)
    robot_spec = load_robot(robot, robot_set)
    PoseSource(pose_source, robot_spec)  # one clear error for an unknown source or a missing sensor
    sim_data = apply_overrides({"pedestrians": agents, "wanderers": robots_}, sim_set, "--sim-set")
    sim_cfg = validate(SimConfig, {k: v for k, v in sim_data.items() if v is not None}, "--sim-set")
    settings = validate(MissionSettings, {"targets": targets if targets is not None or duration is not None else 2,
                                          "duration_s": duration, "seed": seed, "pose_source": pose_source,
                                          "nav": nav, "memory": not no_memory, "sim": sim_cfg.model_dump(),
                                          "navigator": apply_overrides({}, nav_set, "--nav-set"),
                                          **({} if keep_right is None else {"keep_right_m": keep_right}),
                                          **({} if replan_after is None else
                                             {"replan_after_s": replan_after or None})},
                        "simnav mission")
    out_dir = out or _run_dir("mission")
    total = float(settings.targets) if settings.duration_s is None else settings.duration_s
    unit = "targets" if settings.duration_s is None else "s sim"
    with Progress(TextColumn("[bold]mission[/] {task.description}"), BarColumn(),
                  TextColumn(f"{{task.completed:.0f}}/{{task.total:.0f}} {unit}"), TextColumn("{task.fields[info]}"),
                  TimeElapsedColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task(f"{robot_spec.name} in {world_spec.name}", total=total, info="")

        def progress(p) -> None:
            done = p.targets_done if settings.duration_s is None else p.sim_time_s
            bar.update(task, completed=done, info=f"{p.sim_time_s:.0f} s sim, {p.distance_m:.0f} m, "
                                                  f"{p.targets_reached} reached")

        with ExitStack() as stack:
            observers = _viewers(stack, viz, viz_url, viz_rate, html, out_dir)
            factory = _hardware(stack, hardware, robot_spec)
            report = run_mission(world_spec, mission_robot(robot_spec, settings), settings, out_dir, progress,
                                 observers=observers, robot_factory=factory)
    _update_latest(out_dir)
    if html is not None:
        console.print(f"replay: {html}")
    _print_report(report, out_dir)


def _viewers(stack: ExitStack, live: bool, url: str | None, rate_hz: float, html: Path | None, out_dir: Path) -> list:
    """The mission's observers: the meshcat viewer (live and/or HTML replay) and the recording for `simnav view`."""
    from simnav.viz import mission_observers

    observers = stack.enter_context(mission_observers(live=live or url is not None, url=url, html_path=html,
                                                      out_dir=out_dir, rate_hz=rate_hz))
    for obs in observers:
        if getattr(obs, "web_url", None):
            err_console.print(f"meshcat: [bold]{obs.web_url}[/]")
    return observers


def _hardware(stack: ExitStack, target: str | None, robot_spec):
    """The robot factory for hardware in the loop (None: the simulated robot)."""
    if target is None:
        return None
    from simnav.hardware import hardware_in_the_loop

    return stack.enter_context(hardware_in_the_loop(target, robot_spec))


def _print_report(report, out_dir: Path) -> None:
    table = Table(title=f"mission {out_dir}", show_header=False)
    rows = [
        ("robot / world", f"{report.robot} in {report.world}, {report.people} people, nav {report.nav}, "
                          f"pose {report.pose_source}"),
        ("targets reached", f"{report.targets_reached}/{report.targets_requested}"),
        ("distance", f"{report.distance_m:.1f} m"),
        ("duration", f"{report.duration_s:.1f} s sim ({report.real_time_factor:.1f}x real time)"),
        ("speed avg / max", f"{report.avg_speed_m_s:.2f} / {report.max_speed_m_s:.2f} m/s"),
        ("minor incidents", ", ".join(f"{k} {v}" for k, v in report.minor_incidents.items())),
        ("interventions", f"{report.interventions}"
                          + (f" ({report.replans} route re-plans)" if report.replans else "")),
        ("min clearance (static)", f"{report.min_clearance_m:.3f} m"),
        ("path length ratio", f"{report.path_length_ratio:.2f}"),
        ("navigator step median / p95", f"{report.navigator_step_ms['median']:.2f} / "
                                        f"{report.navigator_step_ms['p95']:.2f} ms"),
    ]
    if report.odometry and "rpe" in report.odometry:
        rpe = report.odometry["rpe"]
        rows.append((f"odometry {report.odometry['source']}",
                     f"RPE {rpe['trans_rmse_cm_s']:.2f} cm/s, {rpe['rot_rmse_deg_s']:.2f} deg/s; final error "
                     f"{report.odometry['final_error_m']:.2f} m"))
    for name, value in rows:
        table.add_row(name, value)
    console.print(table)
