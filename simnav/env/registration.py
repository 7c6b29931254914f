"""Gymnasium ids of the navigation env, registered when simnav is imported.

``simnav/OfficeNav-v0`` is the product (generated office, 10 people and a wandering robot); the variants change
only the world. Registering needs Gymnasium, whose import costs more than ``import simnav`` itself, so
``import simnav`` registers at once only when Gymnasium is already loaded, and otherwise right after Gymnasium
loads (an import hook that removes itself).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

ENTRY_POINT = "simnav.env.nav_env:NavEnv"

ENV_IDS: dict[str, dict] = {
    "simnav/OfficeNav-v0": {"kwargs": {"world": "office"}, "max_episode_steps": 600},
    "simnav/FlatNav-v0": {"kwargs": {"world": "flat"}, "max_episode_steps": 400},
    "simnav/CorridorNav-v0": {"kwargs": {"world": "corridor"}, "max_episode_steps": 400},
}
"""Registered ids: NavEnv keyword arguments and the TimeLimit (steps of ``control_dt_s``, 0.1 s by default)."""


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` with Gymnasium (ids already registered are left alone)."""
    from gymnasium.envs.registration import register, registry

    for env_id, spec in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=ENTRY_POINT, **spec)


def register_when_gymnasium_loads() -> None:
    """Register now if Gymnasium is loaded, else as soon as it is imported."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(finder, _RegisterAfterImport) for finder in sys.meta_path):
        sys.meta_path.insert(0, _RegisterAfterImport())


class _RegisterAfterImport(importlib.abc.MetaPathFinder):
    """Finds ``gymnasium`` through the other finders and registers the envs once it has executed."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_register(module) -> None:
            exec_module(module)
            register_envs()

        spec.loader.exec_module = exec_then_register
        return spec
