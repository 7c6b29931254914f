"""Where the shipped robots/ and worlds/ live, and resolving a name or a path to a YAML file."""

from __future__ import annotations

import os
from pathlib import Path

from simnav.errors import UnknownNameError

_REPO_ROOT = Path(__file__).resolve().parent.parent


def data_dir(kind: str) -> Path:
    """The folder of shipped ``kind`` files (``robots`` or ``worlds``); ``SIMNAV_DATA_DIR`` overrides the root."""
    root = Path(os.environ.get("SIMNAV_DATA_DIR", _REPO_ROOT))
    return root / kind


def available(kind: str) -> list[str]:
    """Names of the shipped ``kind`` files, sorted."""
    folder = data_dir(kind)
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def resolve(kind: str, name_or_path: str | Path) -> Path:
    """A shipped name (``giraff``) or a path to a YAML file, as a path; unknown names list what exists."""
    text = str(name_or_path)
    path = Path(text).expanduser()
    if path.suffix in (".yaml", ".yml") or os.sep in text:
        if not path.is_file():
            raise UnknownNameError(f"{kind[:-1]} file '{path}' does not exist")
        return path
    candidate = data_dir(kind) / f"{text}.yaml"
    if not candidate.is_file():
        names = ", ".join(available(kind)) or "(none found in " + str(data_dir(kind)) + ")"
        raise UnknownNameError(f"unknown {kind[:-1]} '{text}'; available: {names}")
    return candidate
