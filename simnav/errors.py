"""Exceptions raised by simnav. Every user-facing error is a :class:`SimnavError`."""

from __future__ import annotations


class SimnavError(Exception):
    """Base class of all errors simnav raises on purpose (bad input, unknown names, ...)."""


class ConfigError(SimnavError, ValueError):
    """A YAML file or a config value is invalid.

    The message names the file, the field and what was expected.
    """


class UnknownNameError(SimnavError, KeyError):
    """A robot, world, sensor preset, ... name that does not exist; the message lists the available ones."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""
