"""Checks of an :class:`OccupancyMap`'s arrays, classes and colours on construction (numpy only)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from scenelabel.errors import InputError
from scenelabel.maps.codes import (
    ESDF_ARRAY,
    ESDF_DTYPE,
    FREE,
    LABEL_DTYPE,
    MAX_CLASS_ID,
    QUANTISED_DTYPE,
    UNKNOWN,
    uint8_from_unit,
)
from scenelabel.maps.esdf import obstacle_mask

__all__ = [
    "check_classes",
    "check_label",
    "check_occupancy",
    "check_quantised",
    "check_colors",
    "check_esdf",
    "read_only",
]

# Elements per pass when checking label values (bounds the temporary memory of the check).
_CHECK_BLOCK = 1 << 24


def check_classes(classes: Mapping[int, str]) -> dict[int, str]:
    """``classes`` checked (integer ids in [0, MAX_CLASS_ID], string names), sorted by id."""
    if not isinstance(classes, Mapping):
        raise InputError(f"classes must be a dict id -> name, got {type(classes).__name__}", field="classes")
    out: dict[int, str] = {}
    for key, name in classes.items():
        if isinstance(key, (bool, np.bool_)) or not isinstance(key, (int, np.integer)):
            raise InputError(f"class id {key!r} is not an integer", field="classes")
        if not 0 <= int(key) <= MAX_CLASS_ID:
            raise InputError(f"class id {key} is outside [0, {MAX_CLASS_ID}]", field="classes")
        if not isinstance(name, str):
            raise InputError(f"class {key} name must be a string, got {name!r}", field="classes")
        out[int(key)] = name
    return dict(sorted(out.items()))


def check_label(label: np.ndarray, classes: dict[int, str]) -> np.ndarray:
    """``label`` checked (values UNKNOWN, FREE or an id of ``classes``), as int16."""
    if label.size and (label.min() < UNKNOWN or label.max() > MAX_CLASS_ID):
        raise InputError(
            f"label values must be in [{UNKNOWN}, {MAX_CLASS_ID}], got [{label.min()}, {label.max()}]",
            field="label",
        )
    label = label.astype(LABEL_DTYPE, copy=False)
    flat = label.reshape(-1)
    # Quick: every value a known one (a table of the 2^16 int16 bit patterns), in blocks to bound memory.
    known = np.zeros(1 << 16, dtype=bool)
    known[np.array([UNKNOWN, FREE, *classes], LABEL_DTYPE).view(np.uint16)] = True
    blocks = range(0, flat.size, _CHECK_BLOCK)
    if all(known[flat[start : start + _CHECK_BLOCK].view(np.uint16)].all() for start in blocks):
        return label
    # Which values occur, counted in blocks to bound the memory of the check.
    present = np.zeros(MAX_CLASS_ID + 1 - UNKNOWN, dtype=bool)
    for start in range(0, flat.size, _CHECK_BLOCK):
        counts = np.bincount(flat[start : start + _CHECK_BLOCK].astype(np.int64) - UNKNOWN)
        present[: counts.size] |= counts > 0
    ids = (np.flatnonzero(present) + UNKNOWN).tolist()
    stray = [i for i in ids if i >= 0 and i not in classes]
    if stray:
        raise InputError(f"label holds class ids {stray[:10]} that are not in classes", field="label")
    return label


def check_occupancy(occupancy: np.ndarray, label: np.ndarray) -> np.ndarray:
    """``occupancy`` checked: no NaN, in [0, 1], 0 wherever label is UNKNOWN."""
    if occupancy.size:
        if np.isnan(occupancy).any():
            raise InputError("occupancy holds NaN; store 0 where the field was not evaluated", field="occupancy")
        lo, hi = float(occupancy.min()), float(occupancy.max())
        if lo < 0.0 or hi > 1.0:
            raise InputError(f"occupancy must be in [0, 1], got [{lo}, {hi}]", field="occupancy")
        if np.any(occupancy[label == UNKNOWN] != 0):
            raise InputError("occupancy must be 0 where label is UNKNOWN (-2)", field="occupancy")
    return occupancy


def check_quantised(values: Any, label: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray | None:
    """None, or a read-only uint8 array of ``shape`` that is 0 wherever label is UNKNOWN."""
    if values is None:
        return None
    array = np.asarray(values)
    if array.shape != shape:
        raise InputError(f"{name} must have shape {list(shape)}, got {list(array.shape)}", field=name)
    if array.dtype == QUANTISED_DTYPE:
        codes = array
    elif np.issubdtype(array.dtype, np.floating):
        if array.size and not (np.all(np.isfinite(array)) and array.min() >= 0.0 and array.max() <= 1.0):
            raise InputError(f"{name} must be finite and in [0, 1]", field=name)
        codes = uint8_from_unit(array)
    else:
        raise InputError(f"{name} must be uint8 codes (value * 255) or floats in [0, 1], got dtype {array.dtype}", field=name)
    unknown = label == UNKNOWN
    if (codes * unknown.reshape(unknown.shape + (1,) * (codes.ndim - unknown.ndim))).any():  # (faster than codes[unknown])
        raise InputError(f"{name} must be 0 where label is UNKNOWN (-2)", field=name)
    return read_only(codes)


def check_esdf(values: Any, label: np.ndarray, unknown: str) -> np.ndarray:
    """A stored ESDF checked against the map's labels: float32 of label's shape, no NaN, negative
    exactly at the obstacle voxels of rule ``unknown`` and positive elsewhere (the values are at
    least half a voxel from 0, so this catches an array of another map or a missing chunk).

    Args:
        values: [nx, ny, nz] float32.
        label: [nx, ny, nz] int16, the map's labels.
        unknown: the rule it was computed with ("occupied" or "free").
    Returns:
        a read-only view of ``values``.
    Raises:
        InputError (field ``esdf``).
    """
    array = np.asarray(values)
    if array.shape != label.shape or array.dtype != ESDF_DTYPE:
        raise InputError(
            f"{ESDF_ARRAY} must be {ESDF_DTYPE} of shape {list(label.shape)}, got {array.dtype} {list(array.shape)}",
            field=ESDF_ARRAY,
        )
    if np.isnan(array).any():
        raise InputError(f"{ESDF_ARRAY} holds NaN", field=ESDF_ARRAY)
    obstacle = obstacle_mask(label, unknown)
    if not (np.array_equal(array < 0, obstacle) and np.array_equal(array > 0, ~obstacle)):
        raise InputError(
            f"{ESDF_ARRAY} does not match label: it must be negative exactly at the obstacles "
            f"(unknown={unknown!r}) and positive elsewhere",
            field=ESDF_ARRAY,
        )
    return read_only(array)


def check_colors(
    colors: Mapping[int, Any] | None, classes: dict[int, str]
) -> dict[int, tuple[int, int, int]] | None:
    """``colors`` checked (ids of ``classes``, 3 integers in 0-255), sorted by id; None when empty."""
    if colors is None or len(colors) == 0:
        return None
    out: dict[int, tuple[int, int, int]] = {}
    for key, rgb in colors.items():
        if int(key) not in classes:
            raise InputError(f"class_colors has id {key}, which is not in classes", field="class_colors")
        try:
            rgb_arr = np.asarray(rgb, dtype=np.float64)
        except (TypeError, ValueError):
            rgb_arr = np.full(1, np.nan)
        if (
            rgb_arr.shape != (3,)
            or not np.all(np.isfinite(rgb_arr))
            or np.any(rgb_arr != np.round(rgb_arr))
            or rgb_arr.min() < 0
            or rgb_arr.max() > 255
        ):
            raise InputError(f"colour of class {key} must be 3 integers in 0-255, got {rgb!r}", field="class_colors")
        out[int(key)] = tuple(int(c) for c in rgb_arr.tolist())  # type: ignore[assignment]
    return dict(sorted(out.items()))


def read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array`` (the caller's array itself stays writeable)."""
    view = array.view()
    view.flags.writeable = False
    return view
