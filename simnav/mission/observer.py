"""What a mission shows to whoever watches it (a viewer, a recorder): one :class:`MissionFrame` per control step.

An observer is anything with ``start``, ``step`` and ``finish``; the mission calls them in that order and never
depends on what they do. A viewer reads the people, other robots and doors from the simulator it gets in ``start``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from simnav.navigation.navigator import NavCommand
from simnav.sensors.readings import Reading

if TYPE_CHECKING:
    from simnav.mission.mission import MissionReport
    from simnav.navigation.navigator import ReactiveNavigator3D
    from simnav.robot.spec import RobotSpec
    from simnav.sim.simulator import Simulator
    from simnav.world.schema import WorldSpec


@dataclass(frozen=True)
class MissionFrame:
    """The state of a mission after one control step.

    Attributes:
        time_s: simulation time at the end of the step, s.
        T_world_base: (3, 3) ground-truth SE(2) pose of the base.
        T_world_est: (3, 3) pose the navigator used (the pose source's estimate, in the world frame).
        command: the navigator's decision (velocity, state, chosen PTG and path index).
        readings: the sensor readings consumed in this step, oldest first (stamps in simulation time).
        points_base: (P, 3) obstacle points the navigator saw, in the base frame at ``T_world_est``, m.
        waypoints_world: (M, 2) the route being followed (last row: the target), m.
    """

    time_s: float
    T_world_base: np.ndarray
    T_world_est: np.ndarray
    command: NavCommand
    readings: list[Reading]
    points_base: np.ndarray
    waypoints_world: np.ndarray


@runtime_checkable
class MissionObserver(Protocol):
    """Watches a mission; see the module docstring."""

    def start(self, world: WorldSpec, robot: RobotSpec, sim: Simulator, navigator: ReactiveNavigator3D) -> None:
        """Called once before the first step."""
        ...

    def step(self, frame: MissionFrame) -> None:
        """Called after every control step."""
        ...

    def finish(self, report: MissionReport) -> None:
        """Called once at the end (also when the mission stops on an error; ``report`` is then partial)."""
        ...
