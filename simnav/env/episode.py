"""One episode of a policy in a navigation env, summarised (the unit of work of ``simnav batch --task rollout``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class EpisodeResult:
    """How an episode went.

    Attributes:
        seed: the ``reset`` seed.
        success: the goal was reached.
        collision: a contact ended (or happened during) the episode.
        truncated: the time limit ended it.
        steps: env steps taken.
        episode_return: sum of the rewards.
        sim_time_s: simulated time, s.
        start_distance_m: straight-line distance from start to goal, m.
        final_distance_m: distance to the goal at the end, m.
    """

    seed: int
    success: bool
    collision: bool
    truncated: bool
    steps: int
    episode_return: float
    sim_time_s: float
    start_distance_m: float
    final_distance_m: float


def rollout(env: Any, policy: Callable[[dict[str, np.ndarray]], np.ndarray], seed: int,
            max_steps: int | None = None) -> EpisodeResult:
    """Run one episode of ``policy`` in ``env`` from ``env.reset(seed=seed)``.

    Args:
        env: a Gymnasium env (with its TimeLimit, or pass ``max_steps``).
        policy: maps an observation to an action; its ``reset()`` is called first when it has one.
        seed: reset seed.
        max_steps: stop after this many steps even without a TimeLimit (counted as truncated).
    """
    obs, info = env.reset(seed=seed)
    if hasattr(policy, "reset"):
        policy.reset()
    start, total, steps, collision = float(info["distance_to_goal_m"]), 0.0, 0, False
    terminated = truncated = False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total, steps = total + float(reward), steps + 1
        collision = collision or bool(info["collision"])
        if max_steps is not None and steps >= max_steps and not terminated:
            truncated = True
    return EpisodeResult(seed=seed, success=bool(info["is_success"]), collision=collision, truncated=bool(truncated),
                         steps=steps, episode_return=total, sim_time_s=float(info["sim_time_s"]),
                         start_distance_m=start, final_distance_m=float(info["distance_to_goal_m"]))
