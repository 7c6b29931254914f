"""The observer that feeds viewers and recorders at a fixed rate of simulated time, and the null viewer.

A *sink* takes the static scene once (``show``) and then frames (``draw``): :class:`~simnav.viz.viewer.MeshcatViewer`
streams them to a meshcat server, :class:`NullViewer` drops them, :class:`~simnav.viz.recording.Recorder` keeps
them. :class:`VizObserver` is a :class:`~simnav.mission.observer.MissionObserver` that turns a mission's control
steps into frames at ``VizConfig.rate_hz`` simulated Hz, and can be driven from a
:class:`~simnav.sim.simulator.Simulator` alone (:meth:`VizObserver.attach`, :meth:`VizObserver.observe`), e.g. by a
Gymnasium env after every step. Nothing here imports meshcat.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Protocol

from simnav.sensors.readings import Reading
from simnav.viz.config import VizConfig
from simnav.viz.frame import LatestReadings, SceneInfo, VizFrame, mission_frame, sim_frame

if TYPE_CHECKING:
    from simnav.mission.mission import MissionReport
    from simnav.mission.observer import MissionFrame
    from simnav.navigation.navigator import ReactiveNavigator3D
    from simnav.robot.spec import RobotSpec
    from simnav.sim.simulator import Simulator
    from simnav.world.schema import WorldSpec

_EPS_S = 1e-9


class FrameSink(Protocol):
    """Receives the scene once, then frames."""

    web_url: str | None

    def show(self, scene: SceneInfo) -> None: ...

    def wants_points(self, time_s: float) -> bool:
        """Whether the frame at ``time_s`` should carry lidar and depth points."""
        ...

    def draw(self, frame: VizFrame) -> None: ...

    def finish(self) -> None: ...


class NullViewer:
    """A viewer that draws nothing (visualisation off): every call returns at once."""

    web_url: str | None = None

    def show(self, scene: SceneInfo) -> None:
        pass

    def wants_points(self, time_s: float) -> bool:
        return False

    def draw(self, frame: VizFrame) -> None:
        pass

    def finish(self) -> None:
        pass


class VizObserver:
    """Feeds sinks at ``config.rate_hz`` simulated Hz from a mission, or from a simulator alone.

    As a :class:`~simnav.mission.observer.MissionObserver` (``run_mission(..., observers=[obs])``) it reads the
    mission's frames. Without a mission (a Gymnasium env, a script)::

        obs = VizObserver([MeshcatViewer(connection)])
        obs.attach(sim)                  # draws the world, the robot, the people
        for _ in range(n):
            readings = sim.step(v, w)
            obs.observe(readings)        # draws at most rate_hz frames per simulated second
        obs.finish()

    Args:
        sinks: viewers and recorders, served in order (null viewers are left out: with none left, every call
            returns at once).
        config: rates and limits.
    """

    def __init__(self, sinks: Sequence[FrameSink], config: VizConfig | None = None) -> None:
        self.config = config or VizConfig()
        self.sinks = [sink for sink in sinks if not isinstance(sink, NullViewer)]  # a null viewer costs nothing
        self.web_url = next((s.web_url for s in self.sinks if getattr(s, "web_url", None)), None)
        self._readings = LatestReadings()
        self._sim: Simulator | None = None
        self._next_s = 0.0

    # -------------------------------------------------------------------------------------- MissionObserver
    def start(self, world: WorldSpec, robot: RobotSpec, sim: Simulator, navigator: ReactiveNavigator3D) -> None:
        self.attach(sim, navigator)

    def step(self, frame: MissionFrame) -> None:
        if not self.sinks:
            return
        self._readings.add(frame.readings)
        if self._due(frame.time_s):
            points = self._wants_points(frame.time_s)
            self._draw(mission_frame(self._sim, frame, self._readings if points else None, self.config))

    def finish(self, report: MissionReport | None = None) -> None:
        for sink in self.sinks:
            sink.finish()

    # --------------------------------------------------------------------------------------- simulator alone
    def attach(self, sim: Simulator, navigator: ReactiveNavigator3D | None = None) -> None:
        """Show the simulator's scene (and the navigator's PTGs); frames follow from :meth:`observe` or
        :meth:`step`. Attach again after ``sim.reset()``."""
        if not self.sinks:
            return
        self._sim, self._next_s = sim, sim.time_s
        self._readings.clear()
        scene = SceneInfo.of(sim, navigator)
        for sink in self.sinks:
            sink.show(scene)

    def observe(self, readings: Iterable[Reading] = ()) -> None:
        """Note the readings of the latest simulator step and draw a frame when one is due."""
        if not self.sinks:
            return
        self._readings.add(readings)
        if self._sim is not None and self._due(self._sim.time_s):
            points = self._wants_points(self._sim.time_s)
            self._draw(sim_frame(self._sim, self._readings if points else None, self.config))

    # --------------------------------------------------------------------------------------------- helpers
    def _due(self, time_s: float) -> bool:
        if time_s + _EPS_S < self._next_s:
            return False
        self._next_s = max(self._next_s + 1.0 / self.config.rate_hz, time_s)
        return True

    def _wants_points(self, time_s: float) -> bool:
        return any(sink.wants_points(time_s) for sink in self.sinks)

    def _draw(self, frame: VizFrame) -> None:
        for sink in self.sinks:
            sink.draw(frame)
