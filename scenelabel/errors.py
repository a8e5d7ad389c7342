"""Typed exceptions. Every error a user can cause is one of these, with one clear message.

The CLI prints ``str(error)`` on one line and exits non-zero; it never shows a traceback for them.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["ScenelabelError", "InputError", "ConfigError", "TrainingError", "TrainingInterrupted", "CheckpointError"]


class ScenelabelError(Exception):
    """Base class of every error scenelabel raises on purpose."""


class InputError(ScenelabelError, ValueError):
    """A scene folder, file or query argument is missing, malformed or inconsistent.

    ``path`` names the file (or folder) and ``field`` the key or argument, when there is one.
    """

    def __init__(self, problem: str, path: str | Path | None = None, field: str | None = None):
        self.problem = problem
        self.path = None if path is None else Path(path)
        self.field = field
        where = ""
        if self.path is not None:
            where = f"{self.path}"
            if field:
                where += f" [{field}]"
            where += ": "
        elif field:
            where = f"{field}: "
        super().__init__(where + problem)


class ConfigError(ScenelabelError, ValueError):
    """An unknown preset, an unknown config key or a value out of range."""


class TrainingError(ScenelabelError, RuntimeError):
    """Training cannot go on (e.g. the loss became non-finite)."""


class TrainingInterrupted(TrainingError):
    """Training was interrupted (Ctrl-C); a checkpoint was saved first."""


class CheckpointError(ScenelabelError):
    """A checkpoint is missing, unreadable or from an incompatible version."""
