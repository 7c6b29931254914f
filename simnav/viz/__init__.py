"""Watch what the robot, its sensors and its navigator do: live in meshcat, or replayed from a recording.

- Live: :class:`MeshcatViewer` streams frames to a meshcat server that a browser shows (``simnav mission --viz``).
- Recording: every mission writes ``viz_recording.npz`` (:class:`Recorder`) for ``simnav view DIR``.
- Replay: :func:`write_replay_html` turns a recording into one self-contained HTML page (``simnav mission --html``,
  ``simnav view DIR --html``).

Drawn: the building; the robot as its prisms, one colour per height band, at its true pose; people, other robots,
door leaves; lidar returns and depth points; the navigator's estimated pose, its obstacle points coloured by
band, the fan of each PTG's paths and the chosen path, the route and its target; ground-truth and estimated trails
(colours in :mod:`simnav.viz.style`, scene tree in :mod:`simnav.viz.draw`).

Missions use :func:`mission_observers`. Anything else that steps a :class:`~simnav.sim.simulator.Simulator` (a
Gymnasium env, a script) can be watched without a navigator::

    from simnav.viz import MeshcatViewer, VizObserver, meshcat_connection

    with meshcat_connection() as connection:           # starts a server; stopped on exit
        viewer = MeshcatViewer(connection)
        print(viewer.web_url)
        observer = VizObserver([viewer])
        observer.attach(sim)                           # after every sim.reset(), too
        for _ in range(steps):
            observer.observe(sim.step(v, w))           # at most rate_hz frames per simulated second
        observer.finish()

A Gymnasium env is watched with :class:`MeshcatEnvWrapper` (``MeshcatEnvWrapper(gym.make("simnav/OfficeNav-v0"))``),
which holds such an observer, attaches it in ``reset`` and calls ``observe`` in ``step``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from simnav.viz.config import VizConfig
from simnav.viz.frame import SceneInfo, VizFrame, mission_frame, sim_frame
from simnav.viz.observer import FrameSink, NullViewer, VizObserver
from simnav.viz.recording import RECORDING_FILE, Recorder, Recording

if TYPE_CHECKING:
    from simnav.viz.env_wrapper import MeshcatEnvWrapper
    from simnav.viz.replay import HtmlReplay, replay_commands, replay_html, write_replay_html
    from simnav.viz.server import MeshcatConnection, MeshcatServer, meshcat_connection
    from simnav.viz.viewer import MeshcatViewer

_LAZY = {"MeshcatViewer": "viewer", "MeshcatConnection": "server", "MeshcatServer": "server",
         "meshcat_connection": "server", "HtmlReplay": "replay", "replay_commands": "replay",
         "replay_html": "replay", "write_replay_html": "replay", "MeshcatEnvWrapper": "env_wrapper"}
"""Names whose modules import meshcat (about 0.3 s): loaded on first use, so a mission without a viewer never
imports it."""


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"simnav.viz.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'simnav.viz' has no attribute {name!r}")


@contextlib.contextmanager
def mission_observers(*, live: bool, url: str | None, html_path: Path | None, out_dir: Path, rate_hz: float,
                      config: VizConfig | None = None) -> Iterator[list[VizObserver]]:
    """The observers a mission runs with: always the recorder, plus the live view and the HTML replay on request.

    Args:
        live: stream to meshcat; the observer's ``web_url`` is the page to open.
        url: join the meshcat server at this ZMQ URL instead of starting one (with ``live``).
        html_path: write a self-contained HTML replay here when the mission finishes.
        out_dir: the run folder; ``viz_recording.npz`` goes there.
        rate_hz: frames per simulated second (live view, recording, replay).
        config: further viewer options (its ``rate_hz`` is replaced by ``rate_hz``).

    Yields:
        One observer (a list, as ``run_mission(observers=...)`` takes them). A meshcat server started here is
        stopped when the block exits, however it exits.
    """
    base = config or VizConfig()
    config = dataclasses.replace(base, rate_hz=rate_hz, points_rate_hz=min(base.points_rate_hz, rate_hz))
    with contextlib.ExitStack() as stack:
        recorder = Recorder(out_dir, config)
        sinks: list[FrameSink] = [recorder]
        if live:
            from simnav.viz.server import meshcat_connection
            from simnav.viz.viewer import MeshcatViewer

            connection = stack.enter_context(meshcat_connection(url, config.timeout_s))
            sinks.append(MeshcatViewer(connection, config))
        if html_path is not None:
            from simnav.viz.replay import HtmlReplay

            sinks.append(HtmlReplay(recorder, html_path, config))
        yield [VizObserver(sinks, config)]


__all__ = [
    "RECORDING_FILE",
    "FrameSink",
    "HtmlReplay",
    "MeshcatConnection",
    "MeshcatEnvWrapper",
    "MeshcatServer",
    "MeshcatViewer",
    "NullViewer",
    "Recorder",
    "Recording",
    "SceneInfo",
    "VizConfig",
    "VizFrame",
    "VizObserver",
    "meshcat_connection",
    "mission_frame",
    "mission_observers",
    "replay_commands",
    "replay_html",
    "sim_frame",
    "write_replay_html",
]
