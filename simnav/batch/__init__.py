"""Many seeded missions or env rollouts in parallel: local worker processes, or Ray tasks on a cluster.

    from simnav.batch import mission_jobs, run_batch
    report = run_batch(mission_jobs(8, settings=MissionSettings(targets=2)), workers=2)
    report = run_batch(mission_jobs(8), ray_address="auto")        # the same rows, on a Ray cluster

``simnav batch`` is the command line of :func:`run_batch`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from simnav.batch.jobs import TIMING_FIELDS, Job, MissionJob, RolloutJob, run_job
from simnav.batch.report import BatchReport
from simnav.batch.runner import run_batch
from simnav.mission.mission import MissionSettings


def mission_jobs(count: int, world: str = "office", robot: str = "giraff", settings: MissionSettings | None = None,
                 first_seed: int | None = None, out_dir: Path | None = None, world_set: tuple[str, ...] = (),
                 robot_set: tuple[str, ...] = ()) -> list[MissionJob]:
    """``count`` missions with seeds ``first_seed``, ``first_seed + 1``, ... (default: the settings' seed).

    With ``out_dir``, mission ``k`` writes its report folder to ``out_dir/mission-<seed>``.
    """
    settings = settings or MissionSettings()
    start = settings.seed if first_seed is None else first_seed
    jobs = []
    for seed in range(start, start + count):
        folder = str(Path(out_dir) / f"mission-{seed}") if out_dir is not None else None
        jobs.append(MissionJob(world, robot, settings.model_copy(update={"seed": seed}), tuple(world_set),
                               tuple(robot_set), folder))
    return jobs


def rollout_jobs(count: int, env_id: str = "simnav/OfficeNav-v0", first_seed: int = 0,
                 env_kwargs: dict[str, Any] | None = None, policy: str = "ptg") -> list[RolloutJob]:
    """``count`` episodes of ``policy`` in ``env_id`` with reset seeds ``first_seed``, ``first_seed + 1``, ..."""
    kwargs = tuple(sorted((env_kwargs or {}).items()))
    return [RolloutJob(env_id, seed, kwargs, policy) for seed in range(first_seed, first_seed + count)]


__all__ = ["TIMING_FIELDS", "BatchReport", "Job", "MissionJob", "RolloutJob", "mission_jobs", "rollout_jobs",
           "run_batch", "run_job"]
