"""Checkpoints: weights + training state + a JSON record (config, class map, bounds, world
transform, cameras...), written atomically and read without running pickled code.

A checkpoint file (format 2) is a ``torch.save`` of a dict that holds only tensors, plain
containers and primitives: the state dicts of the field, its density grid, the optional
coarse field and the optimizer, the step, the elapsed seconds, the random generator's state,
and one JSON string (``"json"``: ``{"meta": ..., "history": ...}``). It is read with
``torch.load(..., weights_only=True)``, torch's restricted unpickler, which builds tensors and
plain data only: a file that asks for anything else is refused, nothing of it runs.

Format 1 (scenelabel before this format) was one pickled dict read with ``weights_only=False``;
``scenelabel upgrade-checkpoint PATH`` (:func:`upgrade_checkpoint`) converts such a file in place,
once the user has said they trust it.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scenelabel._version import __version__
from scenelabel.errors import CheckpointError, InputError

__all__ = [
    "CHECKPOINT_NAME",
    "FORMAT",
    "FORMAT_VERSION",
    "UPGRADE_COMMAND",
    "Checkpoint",
    "save_checkpoint",
    "load_checkpoint",
    "upgrade_checkpoint",
]

CHECKPOINT_NAME = "checkpoint.pt"
FORMAT = "scenelabel.checkpoint"
FORMAT_VERSION = 2
UPGRADE_COMMAND = "scenelabel upgrade-checkpoint"
"""The command that converts a format-1 (pickled) checkpoint: ``scenelabel upgrade-checkpoint PATH``."""

#: The training state's entries (the layout of :meth:`scenelabel.train.trainer.Trainer.state_dict`).
STATE_KEYS = ("model", "occupancy", "coarse_model", "optimizer", "step", "elapsed", "history", "generator", "budget_anchor", "rollbacks")
_HEADER_KEYS = ("format", "format_version", "scenelabel_version")


@dataclass
class Checkpoint:
    """One checkpoint: the field's tensors, the training state, and ``meta``, a JSON-able record
    of everything else (``config`` as :func:`scenelabel.config.config_to_dict`, ``class_map``,
    ``frame``, ``aabb_world``, ``aabb_internal``, ``warp``, ``train_cameras``, ``train_views``, ...;
    see :func:`scenelabel.train.pipeline.prepare_training`). ``meta`` goes through JSON: dict keys
    come back as strings, tuples as lists, numpy values as lists and numbers."""

    model: dict[str, torch.Tensor]  # the field's state dict
    occupancy: dict[str, torch.Tensor]  # the density grid's state dict
    meta: dict[str, Any] = field(default_factory=dict)
    coarse_model: dict[str, torch.Tensor] | None = None  # NeRF's coarse field (hierarchical sampling)
    optimizer: dict[str, Any] | None = None  # the optimizer's state dict (to resume)
    step: int = 0
    elapsed: float = 0.0  # seconds of training so far
    history: list[dict] = field(default_factory=list)  # logged {step, loss, psnr, ...}
    generator: torch.Tensor | None = None  # the training random generator's state (uint8)
    # (fraction, elapsed s) from which the schedules follow the clock to the time budget's end (scenelabel.train.schedule)
    budget_anchor: tuple[float, float] | None = None
    rollbacks: list[dict] | None = None  # the divergence guard's record: {"diverged_at", "resumed_from", "lr_factor"} each

    def training_state(self) -> dict:
        """The training state as :meth:`scenelabel.train.trainer.Trainer.load_state_dict` takes it
        (entries that are None left out)."""
        return {k: getattr(self, k) for k in STATE_KEYS if getattr(self, k) is not None}


def _plain(value: Any) -> Any:
    """json.dumps' fallback: numpy and torch values, paths."""
    if isinstance(value, (np.ndarray, np.generic, torch.Tensor)):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"a checkpoint's meta holds a {type(value).__name__}, which JSON cannot hold")


def _to_json(meta: dict, history: list) -> str:
    # Python's json (Infinity for an unbounded far plane is kept)
    return json.dumps({"meta": meta, "history": history}, default=_plain)


def save_checkpoint(path: str | Path, checkpoint: Checkpoint) -> Path:
    """Write ``checkpoint`` to ``path`` atomically (temp file in the same folder, then rename).

    A crash mid-write leaves the previous checkpoint (or none), never a partial one.
    """
    path = Path(path)
    data = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "scenelabel_version": __version__,
        "model": checkpoint.model,
        "occupancy": checkpoint.occupancy,
        "coarse_model": checkpoint.coarse_model,
        "optimizer": checkpoint.optimizer,
        "step": int(checkpoint.step),
        "elapsed": float(checkpoint.elapsed),
        "generator": checkpoint.generator,
        "budget_anchor": checkpoint.budget_anchor,
        "rollbacks": checkpoint.rollbacks,
        "json": _to_json(checkpoint.meta, checkpoint.history),
    }
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(data, tmp)
        os.replace(tmp, path)
    except OSError as err:
        raise InputError(f"cannot write the checkpoint: {err.strerror or err}", path=path) from None
    finally:
        if tmp.exists():
            tmp.unlink(missing_ok=True)
    return path


def _checkpoint_file(path: str | Path) -> Path:
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint here (expected a build folder or {CHECKPOINT_NAME})")
    return path


def _load_error(path: Path, err: Exception) -> CheckpointError:
    """One line for what ``torch.load(weights_only=True)`` raised."""
    text = str(err)
    refused = re.search(r"Unsupported global: GLOBAL (\S+)", text)
    if refused:
        return CheckpointError(
            f"{path}: refused: the file holds a Python object ({refused.group(1)}) that a checkpoint never holds, "
            f"and checkpoints are read without running pickled code; a checkpoint of an older scenelabel that "
            f"you trust can be converted with `{UPGRADE_COMMAND} {path}`"
        )
    reason = text.split("WeightsUnpickler error:", 1)[-1].strip().split("\n")[0].strip()
    return CheckpointError(f"{path}: unreadable checkpoint ({type(err).__name__}: {reason[:200]})")


def load_checkpoint(path: str | Path) -> Checkpoint:
    """Read a checkpoint file, or the one inside a build folder, without running pickled code
    (``torch.load(weights_only=True)``); checks format and version.

    Raises:
        CheckpointError: no file, an unreadable or refused one, not a scenelabel checkpoint, or
            another format version (format 1: convert it with ``scenelabel upgrade-checkpoint``).
    """
    path = _checkpoint_file(path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for corrupt files; UnpicklingError when refused
        raise _load_error(path, err) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a scenelabel checkpoint")
    version = data.get("format_version")
    if version == 1:
        raise CheckpointError(
            f"{path}: checkpoint format version 1 (scenelabel {data.get('scenelabel_version')}) is pickled and is "
            f"not read any more; if you trust the file, convert it with `{UPGRADE_COMMAND} {path}`"
        )
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format version {version} (scenelabel "
            f"{data.get('scenelabel_version')}) is not supported by scenelabel {__version__} "
            f"(format version {FORMAT_VERSION}); rebuild the scene"
        )
    try:
        record = json.loads(data["json"])
        ckpt = Checkpoint(
            model=data["model"],
            occupancy=data["occupancy"],
            meta=record["meta"],
            coarse_model=data.get("coarse_model"),
            optimizer=data.get("optimizer"),
            step=int(data["step"]),
            elapsed=float(data["elapsed"]),
            history=list(record.get("history", [])),
            generator=data.get("generator"),
            budget_anchor=data.get("budget_anchor", data.get("resumed_at")),  # "resumed_at": before 2026-12-03
            rollbacks=data.get("rollbacks"),
        )
    except (KeyError, TypeError, ValueError) as err:
        raise CheckpointError(f"{path}: incomplete checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(ckpt.model, dict) or not isinstance(ckpt.occupancy, dict) or not isinstance(ckpt.meta, dict):
        raise CheckpointError(f"{path}: incomplete checkpoint (model, occupancy or meta of the wrong type)")
    return ckpt


def _from_format_1(data: dict) -> Checkpoint:
    """A format-1 dict (header, Trainer.state_dict entries and the record, all at the top) ->
    a Checkpoint; the record made JSON-able."""
    state = {k: data[k] for k in STATE_KEYS if k in data}
    meta = {k: v for k, v in data.items() if k not in STATE_KEYS and k not in _HEADER_KEYS}
    record = json.loads(_to_json(meta, state.pop("history", [])))
    return Checkpoint(meta=record["meta"], history=record["history"], **state)


def upgrade_checkpoint(path: str | Path) -> tuple[Path, bool]:
    """Rewrite a format-1 checkpoint in the current format, in place (atomically).

    Reads the old file with ``torch.load(weights_only=False)``, i.e. with pickle, which runs
    whatever code the file holds: call this only on checkpoints you trust.

    Returns:
        (the checkpoint file, whether it was converted: False when it was current already).
    Raises:
        CheckpointError: no file, an unreadable one, not a scenelabel checkpoint, or a format
            version other than 1 and the current one.
    """
    path = _checkpoint_file(path)
    try:
        load_checkpoint(path)
        return path, False
    except CheckpointError:
        pass  # format 1, or refused by the restricted unpickler: read it the old way below
    try:
        data = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # torch raises many types for corrupt files
        first = str(err).strip().split("\n")[0][:200]
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(err).__name__}: {first})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a scenelabel checkpoint")
    if data.get("format_version") != 1:
        raise CheckpointError(
            f"{path}: checkpoint format version {data.get('format_version')}: only format 1 is converted "
            f"(to format {FORMAT_VERSION})"
        )
    missing = [k for k in ("model", "occupancy", "step", "elapsed") if k not in data]
    if missing:
        raise CheckpointError(f"{path}: incomplete format-1 checkpoint (no {', '.join(missing)})")
    try:
        ckpt = _from_format_1(data)
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"{path}: cannot convert the checkpoint ({err})") from None
    save_checkpoint(path, ckpt)
    load_checkpoint(path)  # what was written reads back without pickle
    return path, True
