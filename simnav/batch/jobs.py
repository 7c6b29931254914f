"""The units of work of a batch: a seeded mission or a seeded env episode, each a pure function of its job.

A job is a small frozen, picklable value; :func:`run_job` turns it into one result row (a flat dict of numbers),
in whatever process or Ray worker it runs. The same job gives the same row everywhere except for the wall-clock
fields listed in :data:`TIMING_FIELDS`.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from simnav.mission.mission import MissionSettings

TIMING_FIELDS = ("wall_time_s", "real_time_factor", "navigator_step_ms_median")
"""Row fields that measure the machine, not the run (left out when backends are compared)."""


@dataclass(frozen=True)
class MissionJob:
    """One ``simnav mission``.

    Attributes:
        world: world name or YAML path.
        robot: robot name or YAML path.
        settings: targets or duration, seed, pose source, navigator and simulator settings.
        world_set: dotted overrides of world fields (``--world-set``).
        robot_set: dotted overrides of robot fields (``--set``).
        out_dir: where the mission writes its report folder (None: nowhere).
    """

    world: str
    robot: str
    settings: MissionSettings
    world_set: tuple[str, ...] = ()
    robot_set: tuple[str, ...] = ()
    out_dir: str | None = None

    @property
    def seed(self) -> int:
        return self.settings.seed


@dataclass(frozen=True)
class RolloutJob:
    """One episode of a policy in a registered navigation env.

    Attributes:
        env_id: Gymnasium id (``simnav/OfficeNav-v0``, ...).
        seed: ``reset`` seed of the episode.
        env_kwargs: keyword arguments of ``gymnasium.make`` as (name, value) pairs.
        policy: ``"ptg"`` (:class:`simnav.env.PTGPolicy`) or ``"random"`` (uniform actions from the seed).
    """

    env_id: str
    seed: int
    env_kwargs: tuple[tuple[str, Any], ...] = field(default=())
    policy: Literal["ptg", "random"] = "ptg"


Job = MissionJob | RolloutJob


def run_job(job: Job) -> dict[str, Any]:
    """Run one job here and return its result row (see :func:`mission_row`, :func:`rollout_row`)."""
    import simnav  # noqa: F401  (sets the GL backend in a fresh worker before mujoco loads)

    if isinstance(job, MissionJob):
        return _run_mission(job)
    return _run_rollout(job)


# ---------------------------------------------------------------------------------------------------- missions
def _run_mission(job: MissionJob) -> dict[str, Any]:
    from simnav.mission.mission import mission_robot, run_mission

    world, robot = _world(job.world, job.world_set), _robot(job.robot, job.robot_set)
    out_dir = Path(job.out_dir) if job.out_dir is not None else None
    report = run_mission(world, mission_robot(robot, job.settings), job.settings, out_dir)
    return mission_row(report)


def mission_row(report) -> dict[str, Any]:
    """The row of a :class:`~simnav.mission.mission.MissionReport`: targets, distance, incidents, clearance."""
    incidents = report.minor_incidents
    return {
        "seed": report.seed,
        "success": report.targets_requested > 0 and report.targets_reached == report.targets_requested,
        "targets_reached": report.targets_reached,
        "targets_requested": report.targets_requested,
        "distance_m": report.distance_m,
        "duration_s": report.duration_s,
        "incidents": incidents["total"],
        "incidents_static": incidents["static"],
        "incidents_door": incidents["door"],
        "incidents_people": incidents["people"],
        "incidents_robots": incidents["robots"],
        "interventions": report.interventions,
        "min_clearance_m": report.min_clearance_m if math.isfinite(report.min_clearance_m) else None,
        "path_length_ratio": report.path_length_ratio if math.isfinite(report.path_length_ratio) else None,
        "navigator_step_ms_median": report.navigator_step_ms["median"],
        "real_time_factor": report.real_time_factor,
        "wall_time_s": report.wall_time_s,
    }


@functools.lru_cache(maxsize=8)
def _world(name: str, overrides: tuple[str, ...]):
    from simnav.world import load_world

    return load_world(name, list(overrides))


@functools.lru_cache(maxsize=8)
def _robot(name: str, overrides: tuple[str, ...]):
    from simnav.robot import load_robot

    return load_robot(name, list(overrides))


# ---------------------------------------------------------------------------------------------------- rollouts
def _run_rollout(job: RolloutJob) -> dict[str, Any]:
    from simnav.env.episode import rollout

    env, policy = _env_and_policy(job.env_id, job.env_kwargs, job.policy)
    started = time.perf_counter()
    if job.policy == "random":
        env.action_space.seed(job.seed)
    result = rollout(env, policy, job.seed)
    return rollout_row(result, time.perf_counter() - started)


def rollout_row(result, wall_time_s: float) -> dict[str, Any]:
    """The row of an :class:`~simnav.env.episode.EpisodeResult`."""
    return {
        "seed": result.seed,
        "success": result.success,
        "collision": result.collision,
        "truncated": result.truncated,
        "steps": result.steps,
        "episode_return": result.episode_return,
        "sim_time_s": result.sim_time_s,
        "start_distance_m": result.start_distance_m,
        "final_distance_m": result.final_distance_m,
        "wall_time_s": wall_time_s,
    }


@functools.lru_cache(maxsize=2)
def _env_and_policy(env_id: str, env_kwargs: tuple[tuple[str, Any], ...], policy: str):
    """One env and policy per worker process, reused by its episodes (every episode is reset from its seed)."""
    import gymnasium as gym

    import simnav.env  # noqa: F401  (registers the ids)

    env = gym.make(env_id, **dict(env_kwargs))
    if policy == "ptg":
        from simnav.env.policy import PTGPolicy

        return env, PTGPolicy(env)
    return env, _RandomPolicy(env)


class _RandomPolicy:
    def __init__(self, env) -> None:
        self._space = env.action_space

    def __call__(self, obs):
        return self._space.sample()
