"""Checkpoints: weights + resolved config + class map + bounds + world transform, written atomically."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from ._version import __version__
from .errors import CheckpointError, InputError

__all__ = ["CHECKPOINT_NAME", "FORMAT", "FORMAT_VERSION", "save_checkpoint", "load_checkpoint"]

CHECKPOINT_NAME = "checkpoint.pt"
FORMAT = "scenelabel.checkpoint"
FORMAT_VERSION = 1


def save_checkpoint(path: str | Path, payload: dict) -> Path:
    """Write ``payload`` to ``path`` atomically (temp file in the same folder, then rename).

    A crash mid-write leaves the previous checkpoint (or none), never a partial one.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        torch.save({"format": FORMAT, "format_version": FORMAT_VERSION, "scenelabel_version": __version__, **payload}, tmp)
        os.replace(tmp, path)
    except OSError as err:
        raise InputError(f"cannot write the checkpoint: {err.strerror or err}", path=path) from None
    return path


def load_checkpoint(path: str | Path) -> dict:
    """Read a checkpoint file, or the one inside a build folder; checks format and version."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint here (expected a build folder or {CHECKPOINT_NAME})")
    try:
        data = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # torch raises many types for corrupt files
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a scenelabel checkpoint")
    if data.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {data.get('format_version')} (scenelabel "
            f"{data.get('scenelabel_version')}) is not supported by scenelabel {__version__} "
            f"(format version {FORMAT_VERSION}); rebuild the scene"
        )
    return data
