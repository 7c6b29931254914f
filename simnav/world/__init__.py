"""Worlds: the YAML schema, the office generator and the MJCF assembly (in :mod:`simnav.world.mjcf`)."""

from __future__ import annotations

from pathlib import Path

from simnav import assets
from simnav.config import load_named
from simnav.world.schema import WorldSpec


def load_world(name_or_path: str | Path, overrides: list[str] | None = None) -> WorldSpec:
    """Load and validate a world by shipped name (see :func:`list_worlds`) or YAML path.

    Generated worlds (``generator:`` set) are expanded into their explicit layout, so the result always has
    walls, furniture, a roadmap and spawns.

    Raises:
        UnknownNameError: unknown name (the message lists the available worlds).
        ConfigError: malformed YAML or an invalid field (the message names the file and the field).
    """
    spec = load_named("worlds", WorldSpec, name_or_path, overrides)
    if spec.generator is not None:
        from simnav.world.generator import generate

        spec = generate(spec)
    return spec


def list_worlds() -> list[str]:
    """Names of the shipped worlds."""
    return assets.available("worlds")


__all__ = ["WorldSpec", "list_worlds", "load_world"]
