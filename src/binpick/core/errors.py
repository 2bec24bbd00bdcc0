"""Errors meant for people: each carries one line that says what is wrong and how to fix it.

The CLI prints ``str(error)`` of any :class:`BinpickError` without a traceback, so the message
must stand on its own (name the bad parameter, file or id, and what would be accepted).
"""

from __future__ import annotations


class BinpickError(Exception):
    """Base class of every error caused by user input or the machine's set-up."""


class ConfigError(BinpickError, ValueError):
    """A parameter or config value is outside what is allowed."""


class UnknownEnvError(BinpickError, KeyError):
    """An environment id that binpick does not provide."""

    def __str__(self) -> str:  # KeyError would wrap the message in quotes
        return str(self.args[0]) if self.args else ""


class RenderingUnavailableError(BinpickError, RuntimeError):
    """MuJoCo could not open an OpenGL context (headless machine without EGL/OSMesa)."""


class InputFileError(BinpickError):
    """A file binpick was asked to read is missing, not decodable, damaged, or not what it claims to be."""


class OutputPathError(BinpickError):
    """binpick cannot write where it was asked to (a file where a folder must be, no permission, ...)."""


class WorkerError(BinpickError, RuntimeError):
    """A training worker process stopped with an error; the run keeps its last checkpoint."""
