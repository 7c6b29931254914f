"""``simnav`` commands: worlds, robots, record, version.

Every user error (bad YAML, unknown name, invalid value) ends as one red line naming the file, field or value,
and exit code 2; no traceback.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

import simnav
from simnav.errors import SimnavError

app = typer.Typer(name="simnav", help="Simulation-in-the-loop range-sensing navigation.", no_args_is_help=True,
                  add_completion=False, pretty_exceptions_enable=False)
console = Console()
err_console = Console(stderr=True)

SetOption = Annotated[list[str] | None, typer.Option("--set", help="Override a field: KEY=VALUE (repeatable).",
                                                     metavar="KEY=VALUE")]


def user_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn :class:`SimnavError` into one clear message and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except SimnavError as err:
            err_console.print(f"[bold red]error:[/] {escape(str(err))}", highlight=False, markup=True, soft_wrap=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            err_console.print("[yellow]interrupted[/]")
            raise typer.Exit(130) from None

    return wrapper


@app.callback()
def _root(verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log progress details.")] = False) -> None:
    from rich.logging import RichHandler

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s",
                        handlers=[RichHandler(console=err_console, show_path=False)])


@app.command()
def version() -> None:
    """Print the simnav, MuJoCo and Python versions."""
    import mujoco

    console.print(f"simnav {simnav.__version__} (mujoco {mujoco.__version__}, python {sys.version.split()[0]})")


@app.command()
@user_errors
def worlds() -> None:
    """List the shipped worlds with their size, roadmap and agents."""
    from simnav.world import list_worlds, load_world
    from simnav.world.footprint import bounds

    table = Table("world", "size (m)", "walls", "furniture", "doors", "roadmap", "people", "robots",
                  title="worlds/")
    for name in list_worlds():
        w = load_world(name)
        x0, y0, x1, y1 = bounds(w)
        furniture = len(w.tables) + len(w.chairs) + len(w.shelves) + len(w.boxes) + len(w.cylinders)
        table.add_row(name, f"{x1 - x0:.1f} x {y1 - y0:.1f}", str(len(w.walls)), str(furniture), str(len(w.doors)),
                      str(len(w.roadmap.nodes)), str(w.agents.pedestrians), str(w.agents.robots))
    console.print(table)


@app.command()
@user_errors
def robots() -> None:
    """List the shipped robots with their prisms, drive limits and sensors."""
    from simnav.robot import list_robots, load_robot

    table = Table("robot", "height (m)", "prisms", "max v (m/s)", "max w (deg/s)", "sensors", title="robots/")
    for name in list_robots():
        r = load_robot(name)
        sensors = ", ".join(getattr(s, "preset", s.type) for s in r.sensors)
        table.add_row(name, f"{r.height_m:.2f}", str(len(r.prisms)), f"{r.drive.max_v_m_s:.2f}",
                      f"{r.drive.max_w_deg_s:.0f}", sensors)
    console.print(table)


@app.command()
@user_errors
def record(
    world: Annotated[str, typer.Option(help="World name (simnav worlds) or YAML path.")] = "office",
    robot: Annotated[str, typer.Option(help="Robot name (simnav robots) or YAML path.")] = "giraff",
    duration: Annotated[float, typer.Option(help="Simulated seconds to record.", min=0.05)] = 30.0,
    agents: Annotated[int | None, typer.Option(help="Number of people (default: the world's).", min=0)] = None,
    robots_: Annotated[int | None, typer.Option("--robots", help="Other wandering robots (default: the world's).",
                                                min=0)] = None,
    seed: Annotated[int, typer.Option(help="Seed of agents, route and sensor noise.")] = 0,
    out: Annotated[Path | None, typer.Option(help="Output folder (default: runs/<timestamp>-record).")] = None,
    no_cameras: Annotated[bool, typer.Option("--no-cameras", help="Skip RGB-D frames.")] = False,
    robot_set: SetOption = None,
    world_set: Annotated[list[str] | None, typer.Option("--world-set", metavar="KEY=VALUE",
                                                        help="Override a world field (repeatable).")] = None,
    sim_set: Annotated[list[str] | None, typer.Option(
        "--sim-set", metavar="KEY=VALUE", help="Override a simulator field, e.g. physics_dt_s=0.002.")] = None,
) -> None:
    """Drive a robot along the roadmap among people and write a dataset (TUM, CARMEN, TUM RGB-D).

    Robot fields are overridden with --set, e.g. --set sensors.camera.rate_hz=15.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from simnav.config import apply_overrides, validate
    from simnav.mission.record import RecordSettings
    from simnav.mission.record import record as run_record
    from simnav.robot import load_robot
    from simnav.sim import SimConfig
    from simnav.world import load_world

    world_spec = load_world(world, world_set)
    robot_spec = load_robot(robot, robot_set)
    sim_data = apply_overrides({"pedestrians": agents, "wanderers": robots_}, sim_set, "--sim-set")
    sim_cfg = validate(SimConfig, {k: v for k, v in sim_data.items() if v is not None}, "--sim-set")
    settings = RecordSettings(duration_s=duration, seed=seed, sim=sim_cfg, cameras=not no_cameras)
    out_dir = out or _run_dir("record")
    with Progress(TextColumn("[bold]record[/] {task.description}"), BarColumn(),
                  TextColumn("{task.completed:.1f}/{task.total:.1f} s sim"), TimeRemainingColumn(),
                  console=err_console, transient=True) as bar:
        task = bar.add_task(f"{robot_spec.name} in {world_spec.name}", total=duration)
        summary = run_record(world_spec, robot_spec, out_dir, settings,
                             progress=lambda t: bar.update(task, completed=t))
    _update_latest(out_dir)
    _print_record_summary(summary)


def _print_record_summary(summary) -> None:
    table = Table(title=f"recorded {summary.out_dir}", show_header=False)
    table.add_row("simulated time", f"{summary.sim_time_s:.1f} s")
    table.add_row("wall time", f"{summary.wall_time_s:.1f} s")
    table.add_row("real-time factor", f"{summary.real_time_factor:.1f}x")
    table.add_row("distance driven", f"{summary.distance_m:.1f} m")
    table.add_row("roadmap nodes reached", str(summary.nodes_reached))
    table.add_row("contacts", str(summary.contacts))
    for sensor, count in sorted(summary.readings.items()):
        table.add_row(f"readings: {sensor}", str(count))
    console.print(table)


def _run_dir(kind: str) -> Path:
    return Path("runs") / f"{datetime.now().strftime('%Y%m%d-%H%M%S')}-{kind}"


def _update_latest(out_dir: Path) -> None:
    """Point ``runs/latest`` at the run folder when it lives in runs/."""
    out_dir = out_dir.resolve()
    runs = out_dir.parent
    if runs.name != "runs":
        return
    latest = runs / "latest"
    if latest.is_symlink() or not latest.exists():
        latest.unlink(missing_ok=True)
        latest.symlink_to(out_dir.name)


def main() -> None:
    """Entry point of the ``simnav`` script."""
    app()


# Commands defined in other modules register themselves on `app` when imported.
from simnav.cli import batch as _batch_commands  # noqa: E402, F401
from simnav.cli import hw as _hw_commands  # noqa: E402, F401
from simnav.cli import mission as _mission_commands  # noqa: E402, F401
from simnav.cli import odometry as _odometry_commands  # noqa: E402, F401
from simnav.cli import view as _view_commands  # noqa: E402, F401
