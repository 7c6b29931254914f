"""The live meshcat viewer: streams frames to a meshcat server that browsers show."""

from __future__ import annotations

import logging

from simnav.errors import SimnavError
from simnav.viz.config import VizConfig
from simnav.viz.draw import FrameDrawer, scene_commands
from simnav.viz.frame import SceneInfo, VizFrame
from simnav.viz.server import MeshcatConnection

log = logging.getLogger(__name__)


class MeshcatViewer:
    """Streams a run to a meshcat server; browsers at :attr:`web_url` watch it live.

    Commands are pipelined (:class:`~simnav.viz.server.MeshcatConnection`): drawing a frame packs and queues its
    commands and returns. When the server still owes ``config.max_pending`` replies the frame is skipped (counted
    in :attr:`dropped`), so a slow browser or a stopped server never slows the simulation down.

    Args:
        connection: an open connection (see :func:`simnav.viz.server.meshcat_connection`).
        config: viewer options.
    """

    def __init__(self, connection: MeshcatConnection, config: VizConfig | None = None) -> None:
        self.connection, self.config = connection, config or VizConfig()
        self.web_url: str | None = connection.web_url
        self.drawn = 0
        self.dropped = 0
        self._drawer: FrameDrawer | None = None

    def show(self, scene: SceneInfo) -> None:
        """Draw the static scene and wait until the server has it."""
        fans = scene.paths.fans() if scene.paths is not None else []
        self.connection.send(scene_commands(scene, self.config, fans))
        self.connection.flush()
        self._drawer = FrameDrawer(scene, self.config, fans)

    def wants_points(self, time_s: float) -> bool:
        return True

    def draw(self, frame: VizFrame) -> None:
        """Queue the commands of one frame (or skip it while the server is behind)."""
        if self._drawer is None:
            raise RuntimeError("MeshcatViewer.draw before show")
        if self.connection.pending > self.config.max_pending:
            self.dropped += 1
            if self.dropped == 1:
                log.warning("meshcat server at %s is behind: skipping live frames", self.connection.zmq_url)
            return
        self.connection.send(self._drawer.commands(frame))
        self.drawn += 1

    def finish(self) -> None:
        """Wait briefly for the last frames to reach the server (a missing server is only logged)."""
        try:
            self.connection.flush(timeout_s=2.0)
        except SimnavError as err:  # the run is over; the live view is best effort
            log.warning("%s", err)
        log.info("meshcat: %d frames drawn, %d skipped", self.drawn, self.dropped)
