"""The ``simnav`` command line (typer). Heavy modules are imported inside the commands."""

from __future__ import annotations

from simnav.cli.app import app, main

__all__ = ["app", "main"]
