"""Segmenters from spec strings.

:func:`load_segmenter` turns a spec string (the CLI's ``--model``) into a segmenter;
``python:MODULE:ATTR`` plugs in the user's own model (docs/formats.md, "Segmenters").
:func:`check_segmenter` checks that any object is a usable :class:`Segmenter`.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scenelabel.data.io.common import classes_from_json, load_json, validate_json
from scenelabel.data.segmenters.common import Segmenter, is_positive_int
from scenelabel.data.segmenters.onnx import OnnxSegmenter
from scenelabel.data.segmenters.torch_models import torchvision_segmenter
from scenelabel.errors import InputError

__all__ = ["check_segmenter", "load_segmenter"]

_SPEC_FORMS = (
    "torchvision:ARCH[:WEIGHTS.pth], onnx:MODEL.onnx:CLASSES.json or python:MODULE:ATTR "
    "(MODULE a dotted module name or a .py file)"
)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_segmenter(segmenter: Any, source: str = "segmenter") -> Segmenter:
    """Check that ``segmenter`` has a usable ``classes`` vocabulary, ``ignore_index`` and ``__call__``.

    A missing ``ignore_index`` attribute counts as None. Returns the segmenter.

    Raises:
        InputError: naming ``source`` (e.g. the spec string) and the problem.
    """
    if not callable(segmenter):
        raise InputError(f"is not callable (image -> class ids): {type(segmenter).__name__}", field=source)
    classes = getattr(segmenter, "classes", None)
    if not isinstance(classes, Mapping) or not classes:
        raise InputError("needs a non-empty `classes` dict of class id -> name", field=source)
    for key, name in classes.items():
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not isinstance(name, str):
            raise InputError(f"`classes` must map integer ids to names, got {key!r}: {name!r}", field=source)
    ignore = getattr(segmenter, "ignore_index", None)
    if ignore is not None and (isinstance(ignore, bool) or not isinstance(ignore, (int, np.integer))):
        raise InputError(f"`ignore_index` must be an integer or None, got {ignore!r}", field=source)
    return segmenter


def _onnx_from_spec(model: Path, classes_path: Path) -> OnnxSegmenter:
    """An OnnxSegmenter from a classes.json-style file with an optional ``preprocess`` object."""
    data = load_json(classes_path)
    validate_json(data, "classes", classes_path)
    vocabulary = classes_from_json(data, classes_path)
    channel_ids = [int(entry["id"]) for entry in data["classes"]]
    options = data.get("preprocess", {})
    if not isinstance(options, dict):
        raise InputError("must be an object", classes_path, field="$.preprocess")
    known = ("input_size", "mean", "std", "swap_rb", "max_side")
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InputError(f"unknown keys {unknown}; known: {sorted(known)}", classes_path, field="$.preprocess")
    checks = {
        "mean": (lambda v: isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v),
                 "3 numbers (R, G, B)"),
        "std": (lambda v: isinstance(v, list) and len(v) == 3 and all(_is_number(x) and x > 0 for x in v),
                "3 positive numbers (R, G, B)"),
        "input_size": (lambda v: isinstance(v, list) and len(v) == 2 and all(is_positive_int(x) for x in v),
                       "[width, height], integers >= 1"),
        "swap_rb": (lambda v: isinstance(v, bool), "true or false"),
        "max_side": (lambda v: v is None or is_positive_int(v), "an integer >= 1 or null"),
    }
    kwargs: dict[str, Any] = {}
    for key, value in options.items():
        valid, wanted = checks[key]
        if not valid(value):
            raise InputError(f"must be {wanted}, got {value!r}", classes_path, field=f"$.preprocess.{key}")
        kwargs[key] = tuple(value) if key == "input_size" else value
    return OnnxSegmenter(
        model, vocabulary.classes, channel_ids=channel_ids, ignore_index=vocabulary.ignore_index,
        colors=vocabulary.colors, **kwargs,
    )


def _python_object(module_part: str, attr: str, spec: str) -> Any:
    """``attr`` (dotted) of a module given by dotted name or by a ``.py`` file path."""
    if module_part.endswith(".py"):
        path = Path(module_part)
        if not path.is_file():
            raise InputError("Python file of the segmenter not found", path)
        name = f"_scenelabel_user_segmenter_{abs(hash(str(path.resolve())))}"
        spec_obj = importlib.util.spec_from_file_location(name, path)
        if spec_obj is None or spec_obj.loader is None:
            raise InputError("cannot load this file as a Python module", path)
        module = importlib.util.module_from_spec(spec_obj)
        sys.modules[name] = module
        try:
            spec_obj.loader.exec_module(module)
        except BaseException:
            sys.modules.pop(name, None)
            raise
    else:
        try:
            module = importlib.import_module(module_part)
        except ModuleNotFoundError as error:
            if error.name and module_part.startswith(error.name):
                problem = f"no module named {module_part!r} (is it installed or on PYTHONPATH?)"
                raise InputError(problem, field=spec) from None
            raise
    obj: Any = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise InputError(f"{module_part} has no attribute {attr!r}", field=spec)
        obj = getattr(obj, part)
    return obj


def load_segmenter(spec: str, device: str | torch.device | None = None) -> Segmenter:
    """A segmenter from a spec string (the CLI's ``--model``).

    ``device`` (torch device, default CUDA when available) applies to ``torchvision:`` specs;
    ONNX models run on OpenCV's CPU backend, and ``python:`` segmenters choose their own.

    Forms:

    - ``torchvision:ARCH`` / ``torchvision:ARCH:WEIGHTS.pth``: :func:`torchvision_segmenter` (weights
      from the torch hub cache, or that file);
    - ``onnx:MODEL.onnx:CLASSES.json``: :class:`OnnxSegmenter`. CLASSES.json has the classes.json
      format, its ``classes`` list **in the model's channel order** (entry c = output channel c),
      plus an optional ``"preprocess"`` object with ``input_size`` [w, h], ``mean`` and ``std``
      (RGB, on [0, 1] values; default ImageNet's), ``swap_rb`` (bool), ``max_side`` (int);
    - ``python:MODULE:ATTR``: the user's own segmenter. MODULE is a dotted module name or a
      ``.py`` file; ATTR names a segmenter object (it has ``classes``), or a class or function
      called with no arguments that returns one.

    Raises:
        InputError: an unknown form, missing files, or an object that is not a segmenter.
    """
    if not isinstance(spec, str) or ":" not in spec:
        raise InputError(f"unknown segmenter spec {spec!r}; expected {_SPEC_FORMS}", field="--model")
    kind, rest = spec.split(":", 1)
    if kind == "torchvision":
        arch, _, weights = rest.partition(":")
        return torchvision_segmenter(arch, weights or None, device=device)
    if kind == "onnx":
        model, sep, classes_file = rest.rpartition(":")
        if not sep or not model or not classes_file:
            raise InputError(f"expected onnx:MODEL.onnx:CLASSES.json, got {spec!r}", field="--model")
        return _onnx_from_spec(Path(model), Path(classes_file))
    if kind == "python":
        module_part, sep, attr = rest.rpartition(":")
        if not sep or not module_part or not attr:
            raise InputError(f"expected python:MODULE:ATTR, got {spec!r}", field="--model")
        obj = _python_object(module_part, attr, spec)
        if not isinstance(obj, type) and hasattr(obj, "classes"):
            return check_segmenter(obj, spec)
        if not callable(obj):
            raise InputError(f"{attr!r} is neither a segmenter nor a factory returning one", field=spec)
        try:
            inspect.signature(obj).bind()
        except TypeError as error:
            problem = f"{attr!r} is called with no arguments to make the segmenter, but {error}"
            raise InputError(problem, field=spec) from None
        except ValueError:  # builtins without a signature: just call them
            pass
        segmenter = obj()
        return check_segmenter(segmenter, spec)
    raise InputError(f"unknown segmenter kind {kind!r}; expected {_SPEC_FORMS}", field="--model")
