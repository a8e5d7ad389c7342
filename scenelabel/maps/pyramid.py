"""Pyramid pooling (numpy only): coarse voxels from their children, conservative for planners
(occupied if any child is occupied, FREE only if every child is FREE, UNKNOWN otherwise), and how
many levels a map gets.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.lattice import shape3
from scenelabel.maps.codes import (
    FREE,
    LABEL_DTYPE,
    MAX_LEVELS,
    MIN_COARSE_EDGE,
    OCCUPANCY_DTYPE,
    PYRAMID_FACTOR,
    QUANTISED_DTYPE,
    UNKNOWN,
    confidence_from_probs,
    uint8_from_unit,
    unit_from_uint8,
)

__all__ = [
    "LABEL_POOLING_RULE",
    "check_factor",
    "pool_probs",
    "pool_labels",
    "pool_occupancy",
    "pool_block",
    "check_levels",
    "default_levels",
]

LABEL_POOLING_RULE = (
    "occupied if any child is occupied (argmax class of the occupied children's summed probabilities), "
    "FREE if every child is FREE, else UNKNOWN"
)


# --------------------------------------------------------------------------------------------
# Pyramid pooling (pure)
# --------------------------------------------------------------------------------------------


def check_factor(factor: Any) -> int:
    """``factor`` checked: an integer >= 1 (children per axis of a coarse voxel)."""
    if isinstance(factor, (bool, np.bool_)) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise InputError(f"factor must be an integer >= 1, got {factor!r}", field="factor")
    return int(factor)


def _children(array: np.ndarray, factor: int, fill: Any) -> np.ndarray:
    """[nx, ny, nz, ...] -> [X, Y, Z, factor³, ...]: the children of each coarse voxel.

    ``X = ceil(nx / factor)`` (and so on); children beyond the grid (when a side is not a multiple
    of ``factor``) are ``fill``.
    """
    rest = array.shape[3:]
    coarse = [-(-n // factor) for n in array.shape[:3]]  # ceil
    pad = [(0, c * factor - n) for c, n in zip(coarse, array.shape[:3])] + [(0, 0)] * len(rest)
    if any(after for _, after in pad):
        array = np.pad(array, pad, constant_values=fill)
    blocks = array.reshape(coarse[0], factor, coarse[1], factor, coarse[2], factor, *rest)
    blocks = blocks.transpose(0, 2, 4, 1, 3, 5, *range(6, 6 + len(rest)))
    return blocks.reshape(*coarse, factor**3, *rest)


def pool_probs(label: np.ndarray, probs: np.ndarray, factor: int = PYRAMID_FACTOR) -> np.ndarray:
    """Class distributions of coarse voxels (``factor``³ children each).

    The normalised sum of the children's distributions over the *occupied* children where any
    child is occupied; over all children where every child is FREE; zeros otherwise (UNKNOWN).

    Args:
        label: [nx, ny, nz] int labels (class id >= 0, FREE, UNKNOWN).
        probs: [nx, ny, nz, C] float class probabilities.
        factor: children per axis.
    Returns:
        [X, Y, Z, C] float64, rows summing to 1 or 0; X = ceil(nx / factor), ...
    """
    factor = check_factor(factor)
    children = _children(np.asarray(label), factor, UNKNOWN)  # [X, Y, Z, n]
    occupied = children >= 0
    any_occupied = occupied.any(-1)  # [X, Y, Z]
    all_free = np.all(children == FREE, axis=-1)  # [X, Y, Z]
    weight = np.where(any_occupied[..., None], occupied, all_free[..., None])  # [X, Y, Z, n]
    child_probs = _children(np.asarray(probs, dtype=np.float64), factor, 0.0)  # [X, Y, Z, n, C]
    total = np.einsum("xyzn,xyznc->xyzc", weight.astype(np.float64), child_probs)  # [X, Y, Z, C]
    norm = total.sum(-1, keepdims=True)
    return np.where(norm > 0, total / np.where(norm > 0, norm, 1.0), 0.0)


def pool_labels(
    label: np.ndarray,
    occupancy: np.ndarray,
    factor: int = PYRAMID_FACTOR,
    class_ids: Any = None,
    pooled_probs: np.ndarray | None = None,
) -> np.ndarray:
    """Labels of coarse voxels (``factor``³ children each), conservative for planners.

    - occupied when **any** child is occupied (a thin obstacle never disappears); its class is
      the argmax of ``pooled_probs`` (:func:`pool_probs`: the summed distributions of the
      occupied children), or, without probabilities, the class of the occupied child with the
      largest occupancy;
    - FREE when **every** child is FREE;
    - UNKNOWN otherwise: all children UNKNOWN, or a mix of FREE and UNKNOWN (children beyond the
      grid's edge count as UNKNOWN).

    Args:
        label: [nx, ny, nz] int labels.
        occupancy: [nx, ny, nz] occupancy (picks the class when ``pooled_probs`` is None).
        factor: children per axis.
        class_ids: [C] class id of each channel of ``pooled_probs``.
        pooled_probs: [X, Y, Z, C] from :func:`pool_probs`, or None.
    Returns:
        [X, Y, Z] int16, X = ceil(nx / factor), ...
    """
    factor = check_factor(factor)
    children = _children(np.asarray(label), factor, UNKNOWN)  # [X, Y, Z, n]
    occupied = children >= 0
    child_occ = _children(np.asarray(occupancy, dtype=np.float64), factor, 0.0)  # [X, Y, Z, n]
    densest = np.where(occupied, child_occ, -1.0).argmax(-1)  # [X, Y, Z]
    cls = np.take_along_axis(children, densest[..., None], -1)[..., 0]  # [X, Y, Z]
    if pooled_probs is not None and pooled_probs.shape[-1] > 0:
        ids = np.asarray(class_ids, dtype=np.int64)
        if ids.shape != pooled_probs.shape[-1:]:
            raise InputError(
                f"class_ids has {ids.size} entries for {pooled_probs.shape[-1]} probability channels", field="class_ids"
            )
        has_probs = pooled_probs.sum(-1) > 0
        cls = np.where(has_probs, ids[pooled_probs.argmax(-1)], cls)
    out = np.where(np.all(children == FREE, axis=-1), FREE, UNKNOWN)
    return np.where(occupied.any(-1), cls, out).astype(LABEL_DTYPE)


def pool_occupancy(occupancy: np.ndarray, coarse_label: np.ndarray, factor: int = PYRAMID_FACTOR) -> np.ndarray:
    """Occupancy of coarse voxels: the max over the children (the densest child), 0 where the
    coarse label is UNKNOWN.

    Since ``max(1 - exp(-σ_i δ)) = 1 - exp(-max σ_i δ)``, the encoding and δ stay those of the
    fine grid.

    Args:
        occupancy: [nx, ny, nz] in [0, 1].
        coarse_label: [X, Y, Z] from :func:`pool_labels`.
        factor: children per axis.
    Returns:
        [X, Y, Z] float32.
    """
    pooled = _children(np.asarray(occupancy, dtype=OCCUPANCY_DTYPE), check_factor(factor), 0.0).max(-1)
    if pooled.shape != np.shape(coarse_label):
        raise InputError(f"coarse_label has shape {np.shape(coarse_label)}, expected {pooled.shape}", field="coarse_label")
    return np.where(np.asarray(coarse_label) == UNKNOWN, np.float32(0), pooled).astype(OCCUPANCY_DTYPE)


def pool_block(
    label: np.ndarray,
    occupancy: np.ndarray,
    probs: np.ndarray | None = None,
    factor: int = PYRAMID_FACTOR,
    class_ids: Any = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Coarse voxels from their ``factor``³ children: every array of a map at once, the one
    implementation behind :meth:`OccupancyMap.downsample` (:func:`pool_probs`,
    :func:`pool_labels`, :func:`pool_occupancy`).

    Each coarse voxel depends on its own children only, so a block of a fine grid that starts
    at a multiple of ``factor`` gives exactly those coarse voxels of the whole grid's result
    (children beyond the block's upper edge count as UNKNOWN, as beyond the grid's).

    Args:
        label: [nx, ny, nz] int labels.
        occupancy: [nx, ny, nz] in [0, 1].
        probs: [nx, ny, nz, C] uint8 codes (value * 255), or None.
        factor: children per axis, >= 1.
        class_ids: [C] class id of each channel of ``probs``.
    Returns:
        label [X, Y, Z] int16, occupancy [X, Y, Z] float32, probs [X, Y, Z, C] uint8 (or None),
        confidence [X, Y, Z] uint8 (or None), X = ceil(nx / factor), ...
    """
    factor = check_factor(factor)
    pooled = None if probs is None else pool_probs(label, unit_from_uint8(probs), factor)
    coarse = pool_labels(label, occupancy, factor, class_ids, pooled)
    confidence = None
    if pooled is not None:
        confidence = np.where(coarse == UNKNOWN, 0, uint8_from_unit(confidence_from_probs(pooled))).astype(QUANTISED_DTYPE)
        pooled = uint8_from_unit(pooled)
    return coarse, pool_occupancy(occupancy, coarse, factor), pooled, confidence


def check_levels(levels: Any, shape: Any) -> int:
    """``levels`` checked (an integer in [1, MAX_LEVELS]); None: :func:`default_levels` of ``shape``."""
    levels = default_levels(shape) if levels is None else levels
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= MAX_LEVELS:
        raise InputError(f"levels must be an integer in [1, {MAX_LEVELS}], got {levels!r}", field="levels")
    return int(levels)


def default_levels(shape: Any, min_edge: int = MIN_COARSE_EDGE, max_levels: int = MAX_LEVELS) -> int:
    """How many pyramid levels (level 0 included) a grid gets by default: halve while the
    coarsest level's longest axis keeps at least ``min_edge`` voxels, at most ``max_levels``."""
    longest = max(shape3(shape))
    levels = 1
    while levels < max_levels and -(-longest // PYRAMID_FACTOR**levels) >= min_edge:
        levels += 1
    return levels
