"""Codes and constants of the occupancy map format, and the uint8 quantisation (numpy only).

Label codes (:data:`FREE`, :data:`UNKNOWN`, from :mod:`scenelabel.codes`), format name and version,
array and group names, dtypes, defaults, pyramid limits; :func:`uint8_from_unit` /
:func:`unit_from_uint8` (the codes of ``probs``, ``confidence`` and quantised opacities) and
:func:`confidence_from_probs`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from scenelabel.codes import FREE, UNKNOWN
from scenelabel.errors import InputError
from scenelabel.geometry.lattice import DEFAULT_CHUNKS

__all__ = [
    "FREE",
    "UNKNOWN",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "INDEX_ORDER",
    "DIMENSION_NAMES",
    "DEFAULT_CHUNKS",
    "OCCUPIED_THRESHOLD",
    "DEFAULT_UNITS",
    "DEFAULT_SCALE_SOURCE",
    "DEFAULT_FRAME_ID",
    "LABEL_ARRAY",
    "OCCUPANCY_ARRAY",
    "PROBS_ARRAY",
    "CONFIDENCE_ARRAY",
    "ESDF_ARRAY",
    "ESDF_DTYPE",
    "ESDF_UNKNOWN",
    "LEVELS_GROUP",
    "LABEL_DTYPE",
    "OCCUPANCY_DTYPE",
    "QUANTISED_DTYPE",
    "QUANTISATION_STEPS",
    "PROBS_DIMENSION_NAMES",
    "UNKNOWN_WORD",
    "FREE_WORD",
    "OCCUPANCY_ENCODING",
    "UNKNOWN_RULES",
    "DEFAULT_UNKNOWN_RULE",
    "NGFF_VERSION_V2",
    "NGFF_VERSION_V3",
    "NGFF_METRE_UNITS",
    "PYRAMID_FACTOR",
    "MIN_COARSE_EDGE",
    "MAX_LEVELS",
    "MAX_CLASS_ID",
    "SCHEMA_FILE",
    "uint8_from_unit",
    "unit_from_uint8",
    "confidence_from_probs",
]

FORMAT_NAME = "scenelabel.occupancy_map"
FORMAT_VERSION = 2
"""2: UNKNOWN may also mean "not observed" (``unknown_rule``), optional probs / confidence
arrays, a pyramid under ``levels/``, OME-NGFF multiscales metadata. Version 1 maps still read."""
INDEX_ORDER = "ijk=xyz"
DIMENSION_NAMES = ("x", "y", "z")
OCCUPIED_THRESHOLD = 0.5
"""A point, voxel or ray counts as occupied (hit) when its occupancy (opacity) is at least this
(query answers, maps, the visibility rule; a map read from zarr carries its own ``occupancy_threshold``)."""
DEFAULT_UNITS = "input"
DEFAULT_SCALE_SOURCE = "input"
DEFAULT_FRAME_ID = "world"

LABEL_ARRAY = "label"
OCCUPANCY_ARRAY = "occupancy"
PROBS_ARRAY = "probs"
CONFIDENCE_ARRAY = "confidence"
ESDF_ARRAY = "esdf"
"""The stored Euclidean signed distance field (world units; also the name of its group attribute)."""
ESDF_DTYPE = np.dtype(np.float32)
ESDF_UNKNOWN = "occupied"
"""The rule of the stored ``esdf`` array: UNKNOWN voxels and the map's outside are obstacles
(conservative for planners; :mod:`scenelabel.maps.esdf`)."""
LEVELS_GROUP = "levels"
LABEL_DTYPE = np.dtype(np.int16)
OCCUPANCY_DTYPE = np.dtype(np.float32)
QUANTISED_DTYPE = np.dtype(np.uint8)
QUANTISATION_STEPS = 255
"""Quantised arrays store ``round(value * 255)``; a code q means ``q / 255``."""
PROBS_DIMENSION_NAMES = ("x", "y", "z", "class")
UNKNOWN_WORD, FREE_WORD = "unknown", "free"  # CF flag_meanings of UNKNOWN and FREE

OCCUPANCY_ENCODING = "1 - exp(-sigma_max * occupancy_delta)"
"""How ``occupancy`` encodes density: the opacity of crossing δ at the voxel's largest density."""
UNKNOWN_RULES = ("bounds", "visibility")
"""``bounds``: UNKNOWN only outside the modelled bounds; ``visibility``: also where no training
camera observed the voxel (docs/conventions.md, "Observed space")."""
DEFAULT_UNKNOWN_RULE = "bounds"

NGFF_VERSION_V2 = "0.4"  # OME-NGFF on zarr format 2
NGFF_VERSION_V3 = "0.5"  # OME-Zarr on zarr format 3 (namespaced under "ome")
NGFF_METRE_UNITS = ("metre", "meter")
PYRAMID_FACTOR = 2
MIN_COARSE_EDGE = 16
"""Automatic pyramids stop before the coarsest level's longest axis would drop below this."""
MAX_LEVELS = 8
MAX_CLASS_ID = int(np.iinfo(np.int16).max)
SCHEMA_FILE = "occupancy_map.schema.json"


# --------------------------------------------------------------------------------------------
# Quantisation and confidence (pure)
# --------------------------------------------------------------------------------------------


def uint8_from_unit(values: Any) -> np.ndarray:
    """Values in [0, 1] -> uint8 codes ``round(value * 255)`` (clipped to [0, 1]; NaN -> 0).

    Args:
        values: any shape.
    Returns:
        uint8, same shape; :func:`unit_from_uint8` inverts it within 1 / 510.
    """
    v = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0)
    return np.round(np.clip(v, 0.0, 1.0) * QUANTISATION_STEPS).astype(QUANTISED_DTYPE)


def unit_from_uint8(codes: Any) -> np.ndarray:
    """uint8 codes -> float32 values ``code / 255`` in [0, 1] (same shape)."""
    return np.asarray(codes, dtype=np.float32) / np.float32(QUANTISATION_STEPS)


def confidence_from_probs(probs: Any) -> np.ndarray:
    """``1 - entropy / log C`` of class distributions: 1 for a one-hot, 0 for uniform.

    Rows are normalised to sum 1 first; a row of zeros (UNKNOWN) gets 0; with C = 1 every
    non-zero row gets 1.

    Args:
        probs: [..., C] non-negative class probabilities.
    Returns:
        [...] float64 in [0, 1].
    """
    p = np.asarray(probs, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] < 1:
        raise InputError(f"probs must have shape [..., C] with C >= 1, got {p.shape}", field="probs")
    total = p.sum(-1)  # [...]
    known = total > 0
    if p.shape[-1] == 1:
        return known.astype(np.float64)
    q = p / np.where(known, total, 1.0)[..., None]  # [..., C] rows summing to 1
    entropy = -np.sum(np.where(q > 0, q * np.log(np.where(q > 0, q, 1.0)), 0.0), axis=-1)  # [...]
    return np.where(known, np.clip(1.0 - entropy / math.log(p.shape[-1]), 0.0, 1.0), 0.0)
