"""Robots: the prism/drive/sensor description, its loader, and the robot interface shared by sim and hardware.

Nothing here imports MuJoCo; the MJCF body of a robot is built in :mod:`simnav.robot.mjcf`.
"""

from __future__ import annotations

from pathlib import Path

from simnav import assets
from simnav.config import load_named
from simnav.robot.interface import RobotInterface
from simnav.robot.spec import RobotSpec


def load_robot(name_or_path: str | Path, overrides: list[str] | None = None) -> RobotSpec:
    """Load and validate a robot by shipped name (see :func:`list_robots`) or YAML path.

    Args:
        name_or_path: e.g. ``"giraff"`` or ``"my_robots/bot.yaml"``.
        overrides: dotted ``key=value`` strings applied before validation (``drive.max_v_m_s=0.4``).

    Raises:
        UnknownNameError: unknown name (the message lists the available robots).
        ConfigError: malformed YAML or an invalid field (the message names the file and the field).
    """
    return load_named("robots", RobotSpec, name_or_path, overrides)


def list_robots() -> list[str]:
    """Names of the shipped robots."""
    return assets.available("robots")


__all__ = ["RobotInterface", "RobotSpec", "list_robots", "load_robot"]
