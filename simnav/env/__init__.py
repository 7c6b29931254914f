"""The navigation task as a Gymnasium env, its registration, and the 3D-PTG navigator as a baseline policy.

``import simnav`` registers ``simnav/OfficeNav-v0``, ``simnav/FlatNav-v0`` and ``simnav/CorridorNav-v0``
(:mod:`simnav.env.registration`), so ``gymnasium.make("simnav/OfficeNav-v0")`` works, as does
``gymnasium.make("simnav:simnav/OfficeNav-v0")``. The classes load on first use (importing this package stays as
cheap as the registration).
"""

from __future__ import annotations

import importlib
from typing import Any

from simnav.env.registration import ENV_IDS, register_envs

_LAZY = {"NavEnv": "simnav.env.nav_env", "NavEnvConfig": "simnav.env.config", "RewardConfig": "simnav.env.config",
         "PTGPolicy": "simnav.env.policy", "rollout": "simnav.env.episode", "EpisodeResult": "simnav.env.episode"}

__all__ = ["ENV_IDS", "EpisodeResult", "NavEnv", "NavEnvConfig", "PTGPolicy", "RewardConfig", "register_envs",
           "rollout"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'simnav.env' has no attribute {name!r}")
