"""Settings of the navigation env: world, robot, people, sensors, pose source, clocks, goals and reward weights.

The defaults are the product (``simnav/OfficeNav-v0``); registered variants change only the world. Every field is
also a keyword argument of :class:`simnav.env.NavEnv` and of ``gymnasium.make``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from simnav.config import FrozenModel, check_whole_multiples
from simnav.robot.spec import RobotSpec
from simnav.world.schema import WorldSpec

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


class RewardConfig(FrozenModel):
    """Weights of the reward terms (see :class:`simnav.env.NavEnv` for the formula).

    Attributes:
        progress_per_m: reward per metre the robot comes closer to the goal (negative when it moves away).
        time_per_s: penalty per simulated second (charged every step as ``time_per_s * control_dt_s``).
        contact: penalty per new contact of the robot with anything (walls, furniture, doors, people, robots).
        success: bonus when the robot reaches the goal.
    """

    progress_per_m: float = 1.0
    time_per_s: NonNegative = 0.1
    contact: NonNegative = 10.0
    success: NonNegative = 10.0


class NavEnvConfig(FrozenModel):
    """One navigation task: a robot in a world with people, sent from a roadmap node to another one.

    Attributes:
        world: world name (``simnav worlds``), YAML path or a :class:`~simnav.world.schema.WorldSpec`.
        robot: robot name (``simnav robots``), YAML path or a :class:`~simnav.robot.spec.RobotSpec`; it needs a 2D
            lidar (and an RGB-D camera for ``sensors="lidar+depth"``).
        people: number of pedestrians (None: the world's).
        robots: number of other wandering robots (None: the world's).
        sensors: ``"lidar"`` (the robot's first 2D lidar) or ``"lidar+depth"`` (also its RGB-D camera as a QQVGA
            depth image, 160 x 120). Both fire once per control step.
        lidar_beams: beams of the lidar observation (None: the robot's lidar as specified); the scanner keeps its
            field of view and range and casts that many rays. Learned policies commonly observe 90-180 beams, which
            cost a fraction of the robot's full scan (682 beams on the Giraff) per step.
        pose_source: where the goal is measured from: ``"gt"`` (ground truth), ``"wheels"``, ``"srf"``, ``"rf2o"``
            (odometries anchored at the true start pose).
        control_dt_s: one env step, s (the rate at which actions are applied and observations made).
        physics_dt_s: MuJoCo time step, s; ``control_dt_s`` must be a whole multiple of it.
        agent_dt_s: update period of the people, other robots and doors, s (poses are interpolated in between).
        goal_min_m: the goal is at least this far from the start along the roadmap, m.
        goal_max_m: ... and at most this far, m.
        success_distance_m: the goal is reached within this distance of the base origin (ground truth), m.
        terminate_on_collision: end the episode at the first contact (else each contact is only penalised).
        reward: reward weights.
        render_size_px: (height, width) of ``render()`` images.
        render_span_m: side of the square area around the robot that the top view shows, m.
    """

    world: str | WorldSpec = "office"
    robot: str | RobotSpec = "giraff"
    people: Annotated[int, Field(ge=0, le=200)] | None = None
    robots: Annotated[int, Field(ge=0, le=20)] | None = None
    sensors: Literal["lidar", "lidar+depth"] = "lidar"
    lidar_beams: Annotated[int, Field(ge=2, le=4096)] | None = None
    pose_source: str = "gt"
    control_dt_s: Annotated[float, Field(gt=0, le=1.0)] = 0.1
    physics_dt_s: Annotated[float, Field(gt=0, le=0.02)] = 0.01
    agent_dt_s: Annotated[float, Field(gt=0, le=0.2)] = 0.1
    goal_min_m: NonNegative = 2.0
    goal_max_m: Positive = 10.0
    success_distance_m: Positive = 0.3
    terminate_on_collision: bool = True
    reward: RewardConfig = RewardConfig()
    render_size_px: tuple[Annotated[int, Field(ge=16, le=4096)], Annotated[int, Field(ge=16, le=4096)]] = (480, 480)
    render_span_m: Positive = 12.0

    @model_validator(mode="after")
    def _check(self) -> NavEnvConfig:
        if self.goal_max_m <= self.goal_min_m:
            raise ValueError(f"goal_max_m={self.goal_max_m} must exceed goal_min_m={self.goal_min_m}")
        check_whole_multiples(self, ("control_dt_s", "agent_dt_s"), "physics_dt_s")
        return self

    @property
    def depth(self) -> bool:
        """Whether the observation holds a depth image."""
        return self.sensors == "lidar+depth"
