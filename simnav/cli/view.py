"""``simnav view DIR``: replay a finished run's recording in meshcat, or write it as a self-contained HTML page."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from simnav.cli.app import app, console, err_console, user_errors


@app.command()
@user_errors
def view(
    run_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A run folder holding viz_recording.npz (written by "
                                                                 "`simnav mission`), or that file.",
                                             show_default=False)],
    html: Annotated[Path | None, typer.Option(help="Write the replay to this HTML file (opens offline) and exit.")
                    ] = None,
    viz_url: Annotated[str | None, typer.Option(help="Show it on a running meshcat server at this ZMQ URL instead "
                                                     "of starting one (e.g. tcp://127.0.0.1:6000).")] = None,
    exit_after: Annotated[float | None, typer.Option(help="Stop serving after this many seconds (default: until "
                                                          "Ctrl-C).", min=0)] = None,
) -> None:
    """Replay a run: the robot, people, sensors and navigator as recorded, with play / pause / time controls.

    Without --html a meshcat server shows the replay at the printed URL until Ctrl-C; it is shut down on exit.
    """
    from simnav.viz import Recording, VizConfig
    from simnav.viz.replay import replay_commands, write_replay_html
    from simnav.viz.server import meshcat_connection

    recording = Recording.load(run_dir)
    config = VizConfig()
    if html is not None:
        write_replay_html(recording, html, config)
        console.print(f"replay: {html} ({recording.duration_s:.1f} s of {recording.scene.world.name})")
        return
    with meshcat_connection(viz_url, config.timeout_s) as connection:
        connection.send(replay_commands(recording, config))
        connection.flush()
        err_console.print(f"meshcat: [bold]{connection.web_url}[/] ({recording.duration_s:.1f} s replay; Ctrl-C "
                          "to stop)")
        _serve(exit_after)


def _serve(seconds: float | None) -> None:
    """Keep the server up for ``seconds`` (None: until Ctrl-C, which ends the command quietly)."""
    deadline = None if seconds is None else time.monotonic() + seconds
    try:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2 if deadline is None else min(0.2, max(deadline - time.monotonic(), 0.0)))
    except KeyboardInterrupt:
        err_console.print("stopped")
