"""Semantic occupancy maps: the :class:`OccupancyMap` container, lattice helpers and zarr I/O.

Numpy only (no torch). Conventions (docs/conventions.md, "Occupancy grids"):

- Arrays are indexed ``[i, j, k]`` along world **x, y, z**.
- ``origin`` is the world position of the **centre** of voxel ``[0, 0, 0]``; voxel ``[i, j, k]``
  has centre ``origin + voxel_size * (i, j, k)`` and covers that centre ± ``voxel_size / 2``
  (half-open: ``[centre - voxel_size / 2, centre + voxel_size / 2)`` on each axis).
- ``label`` is int16: class id >= 0 (external ids of classes.json), :data:`FREE` = -1,
  :data:`UNKNOWN` = -2 (not observed: outside the modelled bounds, and with ``unknown_rule``
  "visibility" also seen by no training camera).
- ``occupancy`` is float32 in [0, 1]: ``1 - exp(-sigma * occupancy_delta)`` where the field was
  evaluated (raised to the threshold in voxels a training camera's surface lies in, with
  ``unknown_rule`` "visibility"), and 0 where the label is UNKNOWN.
- Optional ``probs``: uint8 [nx, ny, nz, C], the class distribution quantised (code / 255),
  channel c for the c-th class of ``classes`` (ascending id); 0 where UNKNOWN.
- Optional ``confidence``: uint8 [nx, ny, nz], ``1 - entropy / log C`` quantised (code / 255);
  0 where UNKNOWN.
- A pyramid level ``L`` halves the resolution ``L`` times (:meth:`OccupancyMap.downsample`,
  :func:`pool_labels`): occupied if any child is occupied, FREE only if every child is FREE,
  UNKNOWN otherwise (conservative for planners).

The zarr layout is documented in docs/formats.md and its group attributes are described by
``scenelabel/schemas/occupancy_map.schema.json``.

Typical use by an exporter that evaluates a field in bounded memory::

    origin, shape = lattice(aabb_min, aabb_max, voxel_size)
    label = np.full(shape, UNKNOWN, np.int16); occupancy = np.zeros(shape, np.float32)
    for slices, centres in voxel_centers(origin, voxel_size, shape, chunk=64):
        occ, lab = evaluate(centres)                 # [n] each, n = centres.shape[0]
        block = tuple(s.stop - s.start for s in slices)
        occupancy[slices] = occ.reshape(block); label[slices] = lab.reshape(block)
    OccupancyMap(label, occupancy, voxel_size, origin, classes, occupancy_delta=delta).to_zarr(path)
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import os
import shutil
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from ._version import __version__
from .errors import InputError

__all__ = [
    "FREE",
    "UNKNOWN",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "INDEX_ORDER",
    "DEFAULT_CHUNKS",
    "DEFAULT_OCCUPANCY_THRESHOLD",
    "OccupancyMap",
    "lattice",
    "iter_chunks",
    "voxel_centers",
    "block_centers",
    "index_from_world",
    "world_from_index",
    "ray_box_distances",
    "first_voxel_hits",
    "transmittance_crossings",
    "MapRayQuery",
    "validate_attributes",
    "load_schema",
    "OCCUPANCY_ENCODING",
    "UNKNOWN_RULES",
    "uint8_from_unit",
    "unit_from_uint8",
    "confidence_from_probs",
    "world_from_grid_matrix",
    "pool_probs",
    "pool_labels",
    "pool_occupancy",
    "pool_block",
    "array_chunks",
    "default_levels",
    "ngff_multiscales",
]

FREE = -1
"""Label code of space modelled as empty."""
UNKNOWN = -2
"""Label code of unobserved space: outside the modelled bounds, or (``unknown_rule``
"visibility") seen by no training camera."""

FORMAT_NAME = "scenelabel.occupancy_map"
FORMAT_VERSION = 2
"""2: UNKNOWN may also mean "not observed" (``unknown_rule``), optional probs / confidence
arrays, a pyramid under ``levels/``, OME-NGFF multiscales metadata. Version 1 maps still read."""
INDEX_ORDER = "ijk=xyz"
DIMENSION_NAMES = ("x", "y", "z")
DEFAULT_CHUNKS = (64, 64, 64)
DEFAULT_OCCUPANCY_THRESHOLD = 0.5
DEFAULT_UNITS = "input"
DEFAULT_SCALE_SOURCE = "input"
DEFAULT_FRAME_ID = "world"

LABEL_ARRAY = "label"
OCCUPANCY_ARRAY = "occupancy"
PROBS_ARRAY = "probs"
CONFIDENCE_ARRAY = "confidence"
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

# Points farther than this many voxels from the origin get clamped before the int cast (no overflow).
_MAX_INDEX_MAGNITUDE = 2.0**52
# Relative slack so that a box of exactly n voxels (up to float noise) gets n voxels, not n + 1.
_LATTICE_REL_TOL = 1e-6
# Elements per pass when checking label values (bounds the temporary memory of the check).
_CHECK_BLOCK = 1 << 24
# Relative tolerance for origin_corner == origin - voxel_size / 2 on read.
_CORNER_RTOL = 1e-9


# --------------------------------------------------------------------------------------------
# Pure lattice helpers
# --------------------------------------------------------------------------------------------


def _vec3(value: Any, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"{name} must be 3 numbers [x, y, z], got shape {arr.shape}", field=name)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr.tolist()}", field=name)
    return arr


def _positive(value: Any, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}", field=name) from None
    if not (math.isfinite(out) and out > 0):
        raise InputError(f"{name} must be a finite number > 0, got {value!r}", field=name)
    return out


def _shape3(shape: Any, name: str = "shape") -> tuple[int, int, int]:
    try:
        out = tuple(int(n) for n in shape)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 integers, got {shape!r}", field=name) from None
    if len(out) != 3 or any(n < 1 for n in out):
        raise InputError(f"{name} must be 3 integers >= 1, got {shape!r}", field=name)
    return out  # type: ignore[return-value]


def lattice(
    bounds_min: Any,
    bounds_max: Any,
    voxel_size: float,
    max_voxels: int | None = None,
) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A voxel grid that covers the box ``[bounds_min, bounds_max]``, centred on it.

    Per axis the grid has ``n = max(1, ceil(extent / voxel_size))`` voxels (up to a 1e-6 relative
    slack against float noise), so the covered volume ``n * voxel_size`` contains the box and
    every voxel centre lies inside the box (on a degenerate axis: at the box's centre).

    Args:
        bounds_min, bounds_max: [3] world min and max corners of the box to cover.
        voxel_size: voxel edge, world units, > 0.
        max_voxels: raise InputError when the grid would have more voxels than this.
    Returns:
        origin: [3] float64 world centre of voxel [0, 0, 0].
        shape: (nx, ny, nz).
    """
    lo = _vec3(bounds_min, "bounds_min")
    hi = _vec3(bounds_max, "bounds_max")
    voxel_size = _positive(voxel_size, "voxel_size")
    if np.any(hi < lo):
        raise InputError(f"bounds_max {hi.tolist()} is below bounds_min {lo.tolist()}", field="bounds")
    counts = np.ceil((hi - lo) / voxel_size * (1.0 - _LATTICE_REL_TOL))
    counts = np.maximum(counts, 1.0)
    total = float(np.prod(counts))
    if max_voxels is not None and total > max_voxels:
        raise InputError(
            f"a {voxel_size:g} voxel grid over {(hi - lo).tolist()} needs {counts.astype(np.int64).tolist()} "
            f"= {total:.3g} voxels, more than the limit {max_voxels}; use a larger voxel size",
            field="voxel_size",
        )
    centre = (lo + hi) / 2.0
    origin = centre - (counts - 1.0) / 2.0 * voxel_size
    return origin, _shape3(counts.astype(np.int64))


def iter_chunks(shape: Any, chunk: int | tuple[int, int, int] = DEFAULT_CHUNKS) -> Iterator[tuple[slice, slice, slice]]:
    """Slices that tile a 3D grid, each block at most ``chunk`` voxels per axis, in C order.

    Every index of ``shape`` is in exactly one block; blocks at the upper ends are smaller.

    Args:
        shape: (nx, ny, nz).
        chunk: block edge (int) or per-axis block edges.
    Yields:
        (slice_i, slice_j, slice_k) with explicit start and stop.
    """
    shape = _shape3(shape)
    chunks = _shape3((chunk,) * 3 if np.isscalar(chunk) else chunk, "chunk")
    for i in range(0, shape[0], chunks[0]):
        for j in range(0, shape[1], chunks[1]):
            for k in range(0, shape[2], chunks[2]):
                yield (
                    slice(i, min(i + chunks[0], shape[0])),
                    slice(j, min(j + chunks[1], shape[1])),
                    slice(k, min(k + chunks[2], shape[2])),
                )


def world_from_index(ijk: Any, origin: Any, voxel_size: float) -> np.ndarray:
    """World centres of voxels: ``origin + voxel_size * ijk``.

    Args:
        ijk: [..., 3] voxel indices (any numeric dtype; fractional indices interpolate).
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
    Returns:
        [..., 3] float64 world points.
    """
    ijk = np.asarray(ijk, dtype=np.float64)
    if ijk.shape[-1:] != (3,):
        raise InputError(f"ijk must have shape [..., 3], got {ijk.shape}", field="ijk")
    return np.asarray(origin, np.float64) + float(voxel_size) * ijk


def index_from_world(
    xyz: Any, origin: Any, voxel_size: float, shape: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The voxel containing each world point: ``floor((xyz - origin) / voxel_size + 0.5)``.

    That is the nearest voxel centre; a point exactly on the face between two voxels goes to
    the higher index (voxels are half-open boxes).

    Args:
        xyz: [..., 3] world points.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        shape: (nx, ny, nz) of the grid.
    Returns:
        idx: [..., 3] int64 voxel indices, not clipped (they may lie outside the grid);
            -1 on every axis for non-finite points.
        inside: [...] bool, the point falls in a voxel of the grid.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.shape[-1:] != (3,):
        raise InputError(f"xyz must have shape [..., 3], got {xyz.shape}", field="xyz")
    shape_arr = np.asarray(_shape3(shape), dtype=np.int64)
    finite = np.all(np.isfinite(xyz), axis=-1)
    f = np.floor((xyz - np.asarray(origin, np.float64)) / float(voxel_size) + 0.5)
    f = np.where(finite[..., None], f, -1.0)
    idx = np.clip(f, -_MAX_INDEX_MAGNITUDE, _MAX_INDEX_MAGNITUDE).astype(np.int64)
    inside = finite & np.all((idx >= 0) & (idx < shape_arr), axis=-1)
    return idx, inside


def ray_box_distances(origins: Any, directions: Any, lo: Any, hi: Any) -> tuple[np.ndarray, np.ndarray]:
    """Where rays cross the box [lo, hi] (slab test, rays extended both ways).

    Args:
        origins, directions: [R, 3] rays (directions need not be unit; distances are in
            multiples of them; zero components are fine).
        lo, hi: [3] box corners.
    Returns:
        t_enter, t_exit: [R] float64; ``t_exit < t_enter`` where the line misses the box.
    """
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - origins) / directions  # [R, 3]
        tb = (hi - origins) / directions
    parallel = directions == 0
    within = (origins >= lo) & (origins <= hi)
    t_lo = np.where(parallel, np.where(within, -np.inf, np.inf), np.minimum(ta, tb))
    t_hi = np.where(parallel, np.where(within, np.inf, -np.inf), np.maximum(ta, tb))
    return t_lo.max(-1), t_hi.min(-1)


def _ray_limits(n: int, near: Any, far: Any) -> tuple[np.ndarray, np.ndarray]:
    """[n] near and far distances from None, scalars or arrays (None or non-finite: 0 and inf)."""
    near = np.broadcast_to(np.nan if near is None else np.asarray(near, np.float64), (n,))
    far = np.broadcast_to(np.nan if far is None else np.asarray(far, np.float64), (n,))
    return np.where(np.isfinite(near), np.maximum(near, 0.0), 0.0), np.where(np.isfinite(far), far, np.inf)


def first_voxel_hits(
    origins: Any,
    directions: Any,
    stop: np.ndarray,
    origin: Any,
    voxel_size: float,
    near: Any = None,
    far: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The first voxel of ``stop`` each ray enters, and the distance where it enters it.

    Each ray is clipped to the grid's box (voxel ``[i, j, k]`` covers centre ± voxel_size / 2,
    centre ``origin + voxel_size * (i, j, k)``) and to ``[near, far]``. It then leaps through
    empty space by a distance no stop voxel can be nearer than (:func:`_safe_leaps`), and
    walks the last stretch voxel by voxel across the nearest face (Amanatides & Woo 1987, "A
    fast voxel traversal algorithm"), so the answer is exact: a ray that only clips a voxel's
    edge meets it too. A ray that starts inside a ``stop`` voxel hits it at its first distance
    (``near``, or 0). No eps: a zero direction component never crosses a face (its next
    crossing is inf).

    Args:
        origins, directions: [R, 3] world rays, unit directions (the leaps assume unit length).
        stop: [nx, ny, nz] bool, the voxels that end a ray.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        near, far: [R] or scalar distance limits (None or non-finite: 0 and inf).
    Returns:
        depth: [R] float64 distance where the ray enters its first ``stop`` voxel, ``inf`` where
            it meets none; index: [R, 3] int64 that voxel's index, -1 where none.
    """
    stop = np.asarray(stop, dtype=bool)
    if stop.ndim != 3:
        raise InputError(f"need stop [nx, ny, nz], got {stop.shape}", field="stop")
    # an opaque voxel: infinite optical depth, so any positive threshold is crossed where the ray enters it
    opaque = np.array([0.0, np.inf])
    return _optical_depth_crossings(origins, directions, stop.view(np.uint8), opaque, origin, voxel_size, near, far, 1.0)


def transmittance_crossings(
    origins: Any,
    directions: Any,
    occupancy: np.ndarray,
    origin: Any,
    voxel_size: float,
    near: Any = None,
    far: Any = None,
    transmittance: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each ray's transmittance through a grid of per-voxel opacities falls to ``transmittance``.

    A voxel of opacity ``a`` (a map's ``occupancy``: ``1 - exp(-sigma * voxel_size)``) holds the
    constant density ``sigma = -log(1 - a) / voxel_size``; a ray's transmittance after crossing
    lengths ``l_v`` of voxels ``v`` is ``T = exp(-sum_v sigma_v l_v)`` (NeRF eq. 1, integrated
    exactly for piecewise-constant density). The crossing is where ``sum sigma_v l_v`` reaches
    ``-log(transmittance)``; with 0.5 that is the ray's median termination depth, the depth a
    volume renderer's surface sits at. Opacities are quantised to codes ``round(a * 255)`` first
    (:func:`uint8_from_unit`, as a map's probs are), so the answer is the same for a map in
    memory and one read back chunk by chunk; code 255 is opaque (infinite density: the crossing
    is where the ray enters), code 0 empty (leapt over as in :func:`first_voxel_hits`). Rays are
    clipped to the grid's box and ``[near, far]`` and walked voxel by voxel (exact traversal).

    Args:
        origins, directions: [R, 3] world rays, unit directions.
        occupancy: [nx, ny, nz] per-voxel opacity in [0, 1] (float), or uint8 codes of it.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        near, far: [R] or scalar distance limits (None or non-finite: 0 and inf).
        transmittance: in (0, 1): the transmittance that counts as the surface.
    Returns:
        depth: [R] float64 distance of the crossing, ``inf`` where the ray keeps more than
            ``transmittance`` through the grid; index: [R, 3] int64 the voxel it lies in, -1 where none.
    """
    if not 0.0 < float(transmittance) < 1.0:
        raise InputError(f"transmittance must lie in (0, 1), got {transmittance}", field="transmittance")
    occupancy = np.asarray(occupancy)
    if occupancy.ndim != 3:
        raise InputError(f"need occupancy [nx, ny, nz], got {occupancy.shape}", field="occupancy")
    codes = occupancy if occupancy.dtype == QUANTISED_DTYPE else uint8_from_unit(occupancy)
    return _optical_depth_crossings(
        origins, directions, codes, _OPTICAL_DEPTH_OF_CODE, origin, voxel_size, near, far, -math.log(float(transmittance))
    )


def _optical_depth_of_codes() -> np.ndarray:
    """[256] the optical depth of crossing a voxel edge-on at each opacity code, ``-log(1 - q / 255)``
    (inf for code 255)."""
    with np.errstate(divide="ignore"):
        return -np.log1p(-np.arange(QUANTISATION_STEPS + 1) / QUANTISATION_STEPS)


_OPTICAL_DEPTH_OF_CODE = _optical_depth_of_codes()


def _optical_depth_crossings(
    origins: Any, directions: Any, codes: np.ndarray, tau_of_code: np.ndarray, origin: Any, voxel_size: float,
    near: Any, far: Any, threshold: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The common body of :func:`first_voxel_hits` and :func:`transmittance_crossings`: rays
    through a grid of uint8 ``codes`` whose voxels hold optical depth ``tau_of_code[code]`` per
    voxel edge (``tau_of_code[0]`` must be 0: those voxels are leapt over), stopping where the
    accumulated optical depth reaches ``threshold`` > 0."""
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(origins) != len(directions):
        raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
    n, shape = len(origins), np.asarray(codes.shape)
    voxel_size = float(voxel_size)
    corner = np.asarray(origin, np.float64) - voxel_size / 2.0
    near, far = _ray_limits(n, near, far)
    t_enter, t_exit = ray_box_distances(origins, directions, corner, corner + voxel_size * shape)
    t_enter, t_exit = np.maximum(t_enter, near), np.minimum(t_exit, far)
    depth, index = np.full(n, np.inf), np.full((n, 3), -1, dtype=np.int64)
    rays = np.flatnonzero(t_exit > t_enter)
    matter = codes > 0
    if not matter.any() or rays.size == 0:
        return depth, index
    t = _safe_leaps(origins[rays], directions[rays], t_enter[rays], t_exit[rays], _leap_lengths(matter), corner, voxel_size)
    walk = t < t_exit[rays]
    rays = rays[walk]
    sigma_of_code = tau_of_code / voxel_size  # density per world unit
    hit_depth, hit_index = _walk_voxels(
        origins[rays], directions[rays], t[walk], t_exit[rays], codes, sigma_of_code, corner, voxel_size, threshold
    )
    depth[rays], index[rays] = hit_depth, hit_index
    return depth, index


def _leap_lengths(stop: np.ndarray) -> np.ndarray:
    """[nx, ny, nz] int32: from anywhere in a voxel, no ``stop`` voxel is nearer than this many
    voxel edges. With k the chessboard distance between the voxel's centre and the nearest stop
    voxel's centre, the two voxels are k - 1 edges apart along some axis, so k - 1 is safe
    (0 at stop voxels and their neighbours)."""
    from scipy import ndimage

    return np.maximum(ndimage.distance_transform_cdt(~stop, metric="chessboard") - 1, 0).astype(np.int32)


def _voxel_of(o: np.ndarray, d: np.ndarray, t: np.ndarray, corner: np.ndarray, voxel_size: float, shape) -> np.ndarray:
    return np.clip(np.floor((o + t[:, None] * d - corner) / voxel_size), 0, np.asarray(shape) - 1).astype(np.int64)


def _safe_leaps(o, d, t, t_end, leaps: np.ndarray, corner, voxel_size: float) -> np.ndarray:
    """Move each ray (unit directions) forward while the voxel it is in allows a leap of at least
    one voxel edge (sphere tracing on :func:`_leap_lengths`); returns [A] the distances reached
    (``>= t_end`` for rays that left their interval without coming near a stop voxel)."""
    t = t.copy()
    active = np.arange(len(t))
    flat, strides = leaps.ravel(), np.asarray(leaps.strides) // leaps.itemsize
    while active.size:
        leap = flat[_voxel_of(o[active], d[active], t[active], corner, voxel_size, leaps.shape) @ strides]
        moving = leap > 0
        active = active[moving]
        t[active] += leap[moving] * voxel_size
        active = active[t[active] < t_end[active]]
    return t


def _walk_voxels(
    o, d, t, t_end, codes: np.ndarray, sigma_of_code: np.ndarray, corner, voxel_size: float, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """Voxel-by-voxel traversal (Amanatides & Woo) of rays from ``t`` to ``t_end``, accumulating
    optical depth ``sigma * length`` per voxel crossed: the depth where it reaches ``threshold``
    and the voxel it does so in (inf and -1 where it never does). An infinite density stops a ray
    where it enters the voxel, even one it only touches; a finite one where the crossing lies
    inside its segment."""
    shape = np.asarray(codes.shape)
    depth, index = np.full(len(t), np.inf), np.full((len(t), 3), -1, dtype=np.int64)
    rays = np.arange(len(t))
    ijk = _voxel_of(o, d, t, corner, voxel_size, shape)
    step = np.sign(d).astype(np.int64)  # [A, 3] -1, 0 or +1
    with np.errstate(divide="ignore", invalid="ignore"):
        # distance at which each axis' next face is crossed, and between faces on that axis
        t_next = np.where(d != 0, (corner + (ijk + (step > 0)) * voxel_size - o) / d, np.inf)
        t_delta = np.where(d != 0, voxel_size / np.abs(d), np.inf)
    flat, strides = codes.ravel(), np.asarray(codes.strides) // codes.itemsize
    t, t_end = t.copy(), t_end.copy()
    tau = np.zeros(len(t))  # optical depth accumulated so far
    while rays.size:
        rows = np.arange(len(rays))
        axis = t_next.argmin(-1)
        t_out = np.minimum(t_next[rows, axis], t_end)  # where the ray leaves this voxel
        sigma = sigma_of_code[flat[ijk @ strides]]  # [A]
        opaque = np.isinf(sigma)
        with np.errstate(invalid="ignore"):
            tau_out = np.where(opaque, np.inf, tau + sigma * (t_out - t))
            hit = tau_out >= threshold
            # inside the segment, linear in t: tau + sigma (t_hit - t) = threshold; 0 for opaque voxels
            depth[rays[hit]] = t[hit] + np.where(opaque[hit], 0.0, (threshold - tau[hit]) / sigma[hit])
        index[rays[hit]] = ijk[hit]
        t, tau = t_out, tau_out
        ijk[rows, axis] += step[rows, axis]
        t_next[rows, axis] += t_delta[rows, axis]
        moved = ijk[rows, axis]
        keep = ~hit & (t < t_end) & (moved >= 0) & (moved < shape[axis])
        rays, t, t_end, tau, ijk, step, t_next, t_delta = (
            a[keep] for a in (rays, t, t_end, tau, ijk, step, t_next, t_delta)
        )
    return depth, index


@dataclass(frozen=True)
class MapRayQuery:
    """What rays cast through an :class:`OccupancyMap` meet (:meth:`OccupancyMap.cast_rays`).

    Attributes:
        depth: [N] float64 distance along the unit direction to where the ray enters the voxel
            that stopped it; ``inf`` where nothing stopped it.
        label: [N] int16: the stopping voxel's class id, or UNKNOWN when an UNKNOWN voxel
            stopped it (or it never entered the map); FREE when it crossed the map within
            [near, far] through free voxels only.
        index: [N, 3] int64 the stopping voxel's index, -1 where none.
    """

    depth: np.ndarray
    label: np.ndarray
    index: np.ndarray


def voxel_centers(
    origin: Any, voxel_size: float, shape: Any, chunk: int | tuple[int, int, int] = DEFAULT_CHUNKS
) -> Iterator[tuple[tuple[slice, slice, slice], np.ndarray]]:
    """World centres of a grid's voxels, block by block (bounded memory).

    Args:
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        shape: (nx, ny, nz).
        chunk: block edge (int) or per-axis block edges, as in :func:`iter_chunks`.
    Yields:
        slices: the block, (slice_i, slice_j, slice_k).
        centres: [bi * bj * bk, 3] float64 world centres in C order of the block, so that
            ``values.reshape(block_shape)`` fits ``grid[slices]``.
    """
    origin = _vec3(origin, "origin")
    voxel_size = _positive(voxel_size, "voxel_size")
    for slices in iter_chunks(shape, chunk):
        yield slices, block_centers(origin, voxel_size, slices)


def block_centers(origin: Any, voxel_size: float, block: tuple[slice, slice, slice]) -> np.ndarray:
    """World centres of one block of a grid's voxels (what :func:`voxel_centers` yields for it).

    Args:
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        block: (slice_i, slice_j, slice_k) with explicit start and stop.
    Returns:
        [bi * bj * bk, 3] float64 world centres in C order of the block.
    """
    ii, jj, kk = np.meshgrid(*(np.arange(s.start, s.stop) for s in block), indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=-1)
    return world_from_index(ijk, origin, voxel_size)


def world_from_grid_matrix(origin: Any, voxel_size: float) -> np.ndarray:
    """The 4x4 affine ``T_world_from_grid``: ``[x, y, z, 1] = T @ [i, j, k, 1]``, a voxel's centre.

    Args:
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
    Returns:
        [4, 4] float64: ``voxel_size * I`` on the diagonal, ``origin`` in the last column.
    """
    transform = np.eye(4)
    transform[:3, :3] *= _positive(voxel_size, "voxel_size")
    transform[:3, 3] = _vec3(origin, "origin")
    return transform


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


# --------------------------------------------------------------------------------------------
# Pyramid pooling (pure)
# --------------------------------------------------------------------------------------------


def _factor(factor: Any) -> int:
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
    factor = _factor(factor)
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
    factor = _factor(factor)
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
    pooled = _children(np.asarray(occupancy, dtype=OCCUPANCY_DTYPE), _factor(factor), 0.0).max(-1)
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
    factor = _factor(factor)
    pooled = None if probs is None else pool_probs(label, unit_from_uint8(probs), factor)
    coarse = pool_labels(label, occupancy, factor, class_ids, pooled)
    confidence = None
    if pooled is not None:
        confidence = np.where(coarse == UNKNOWN, 0, uint8_from_unit(confidence_from_probs(pooled))).astype(QUANTISED_DTYPE)
        pooled = uint8_from_unit(pooled)
    return coarse, pool_occupancy(occupancy, coarse, factor), pooled, confidence


def _check_levels(levels: Any, shape: Any) -> int:
    """``levels`` checked (an integer in [1, MAX_LEVELS]); None: :func:`default_levels` of ``shape``."""
    levels = default_levels(shape) if levels is None else levels
    if isinstance(levels, (bool, np.bool_)) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= MAX_LEVELS:
        raise InputError(f"levels must be an integer in [1, {MAX_LEVELS}], got {levels!r}", field="levels")
    return int(levels)


def default_levels(shape: Any, min_edge: int = MIN_COARSE_EDGE, max_levels: int = MAX_LEVELS) -> int:
    """How many pyramid levels (level 0 included) a grid gets by default: halve while the
    coarsest level's longest axis keeps at least ``min_edge`` voxels, at most ``max_levels``."""
    longest = max(_shape3(shape))
    levels = 1
    while levels < max_levels and -(-longest // PYRAMID_FACTOR**levels) >= min_edge:
        levels += 1
    return levels


# --------------------------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("scenelabel").joinpath("schemas", SCHEMA_FILE).read_text(encoding="utf-8")


def load_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the map's zarr group attributes (a fresh copy)."""
    return json.loads(_schema_text())


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema

    schema = load_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def validate_attributes(attrs: Mapping[str, Any], path: str | Path | None = None) -> None:
    """Check a map's group attributes against ``schemas/occupancy_map.schema.json``.

    Beyond the schema, class ids must be unique. Unknown extra attributes are allowed.

    Args:
        attrs: the zarr group attributes (a JSON-like dict).
        path: the map's path, used in the error message.
    Raises:
        InputError naming the path and the first offending attribute.
    """
    import jsonschema

    attrs = dict(attrs)
    error = jsonschema.exceptions.best_match(_validator().iter_errors(attrs))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path)
        if error.validator == "required":
            # error.message is "'voxel_size' is a required property"; name the attribute itself.
            missing = [k for k in error.validator_value if k not in error.instance]
            where = "/".join([where, missing[0]]) if where and missing else (missing[0] if missing else where)
            problem = f"missing required attribute {missing[0]!r}" if missing else error.message
        else:
            problem = f"invalid attribute: {error.message}"
        raise InputError(problem, path=path, field=where or None)
    ids = [c["id"] for c in attrs["classes"]]
    if len(set(ids)) != len(ids):
        raise InputError(f"class ids must be unique, got {ids}", path=path, field="classes")


# --------------------------------------------------------------------------------------------
# The map
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A semantic occupancy grid in the world frame (see the module docstring for conventions).

    Attributes:
        label: [nx, ny, nz] int16, indexed [i, j, k] along world x, y, z: class id >= 0,
            FREE (-1) or UNKNOWN (-2).
        occupancy: [nx, ny, nz] float32 in [0, 1] (no NaN); 0 wherever label is UNKNOWN.
        voxel_size: voxel edge, world units.
        origin: [3] float64 world centre of voxel [0, 0, 0].
        classes: external class id -> name, the classes that may appear in ``label``.
        occupancy_delta: δ (world units) in ``occupancy = 1 - exp(-σ δ)``.
        class_colors: external class id -> (r, g, b) 0-255, or None.
        frame_id: name of the world frame.
        occupancy_threshold: a voxel is occupied when ``occupancy >= occupancy_threshold``.
        scale_source: where the world scale comes from ("input": the input's poses).
        units: unit of lengths: "metre" when known metric, else "input" (the input's unit).
        version: scenelabel version that made the map.
        probs: [nx, ny, nz, C] uint8 or None: class probabilities quantised (code / 255),
            channel c for the c-th id of ``classes`` (ascending); 0 wherever label is UNKNOWN.
            Floats in [0, 1] are accepted and quantised.
        confidence: [nx, ny, nz] uint8 or None: ``1 - entropy / log C`` of the class
            distribution, quantised (code / 255); 0 wherever label is UNKNOWN. Floats in [0, 1]
            are accepted and quantised.
        unknown_rule: what UNKNOWN means: "bounds" (outside the modelled bounds) or
            "visibility" (also: observed by no training camera).

    Arrays are converted (copy-free when already right) and checked on construction, and kept
    as read-only views: the instance and its arrays are frozen (copy an array to edit it).
    """

    label: np.ndarray
    occupancy: np.ndarray
    voxel_size: float
    origin: np.ndarray
    classes: dict[int, str]
    occupancy_delta: float
    class_colors: dict[int, tuple[int, int, int]] | None = None
    frame_id: str = DEFAULT_FRAME_ID
    occupancy_threshold: float = DEFAULT_OCCUPANCY_THRESHOLD
    scale_source: str = DEFAULT_SCALE_SOURCE
    units: str = DEFAULT_UNITS
    version: str = __version__
    probs: np.ndarray | None = None
    confidence: np.ndarray | None = None
    unknown_rule: str = DEFAULT_UNKNOWN_RULE

    def __post_init__(self) -> None:
        set_ = functools.partial(object.__setattr__, self)

        label = np.asarray(self.label)
        if label.ndim != 3:
            raise InputError(f"label must be a 3D array [nx, ny, nz], got shape {label.shape}", field="label")
        if not np.issubdtype(label.dtype, np.integer):
            raise InputError(f"label must hold integers (int16), got dtype {label.dtype}", field="label")
        occupancy = np.asarray(self.occupancy)
        if occupancy.shape != label.shape:
            raise InputError(
                f"occupancy shape {occupancy.shape} differs from label shape {label.shape}", field="occupancy"
            )
        if not (np.issubdtype(occupancy.dtype, np.floating) or np.issubdtype(occupancy.dtype, np.integer)):
            raise InputError(f"occupancy must hold floats (float32), got dtype {occupancy.dtype}", field="occupancy")

        classes = self._check_classes(self.classes)
        label = self._check_label(label, classes)
        occupancy = self._check_occupancy(occupancy.astype(OCCUPANCY_DTYPE, copy=False), label)
        set_("label", _read_only(label))
        set_("occupancy", _read_only(occupancy))
        set_("probs", self._check_quantised(self.probs, label, label.shape + (len(classes),), PROBS_ARRAY))
        set_("confidence", self._check_quantised(self.confidence, label, label.shape, CONFIDENCE_ARRAY))
        if self.unknown_rule not in UNKNOWN_RULES:
            raise InputError(f"unknown_rule must be one of {list(UNKNOWN_RULES)}, got {self.unknown_rule!r}", field="unknown_rule")
        set_("classes", classes)
        set_("class_colors", self._check_colors(self.class_colors, classes))
        set_("voxel_size", _positive(self.voxel_size, "voxel_size"))
        set_("origin", _vec3(self.origin, "origin"))
        set_("occupancy_delta", _positive(self.occupancy_delta, "occupancy_delta"))
        threshold = float(self.occupancy_threshold)
        if not 0.0 <= threshold <= 1.0:
            raise InputError(f"occupancy_threshold must be in [0, 1], got {threshold}", field="occupancy_threshold")
        set_("occupancy_threshold", threshold)
        for name in ("frame_id", "scale_source", "units", "version"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise InputError(f"{name} must be a non-empty string, got {value!r}", field=name)

    # ---- validation pieces ----

    @staticmethod
    def _check_classes(classes: Mapping[int, str]) -> dict[int, str]:
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

    @staticmethod
    def _check_label(label: np.ndarray, classes: dict[int, str]) -> np.ndarray:
        if label.size and (label.min() < UNKNOWN or label.max() > MAX_CLASS_ID):
            raise InputError(
                f"label values must be in [{UNKNOWN}, {MAX_CLASS_ID}], got [{label.min()}, {label.max()}]",
                field="label",
            )
        label = label.astype(LABEL_DTYPE, copy=False)
        # Which values occur, counted in blocks to bound the memory of the check.
        present = np.zeros(MAX_CLASS_ID + 1 - UNKNOWN, dtype=bool)
        flat = label.reshape(-1)
        for start in range(0, flat.size, _CHECK_BLOCK):
            counts = np.bincount(flat[start : start + _CHECK_BLOCK].astype(np.int64) - UNKNOWN)
            present[: counts.size] |= counts > 0
        ids = (np.flatnonzero(present) + UNKNOWN).tolist()
        stray = [i for i in ids if i >= 0 and i not in classes]
        if stray:
            raise InputError(f"label holds class ids {stray[:10]} that are not in classes", field="label")
        return label

    @staticmethod
    def _check_occupancy(occupancy: np.ndarray, label: np.ndarray) -> np.ndarray:
        if occupancy.size:
            if np.isnan(occupancy).any():
                raise InputError("occupancy holds NaN; store 0 where the field was not evaluated", field="occupancy")
            lo, hi = float(occupancy.min()), float(occupancy.max())
            if lo < 0.0 or hi > 1.0:
                raise InputError(f"occupancy must be in [0, 1], got [{lo}, {hi}]", field="occupancy")
            if np.any(occupancy[label == UNKNOWN] != 0):
                raise InputError("occupancy must be 0 where label is UNKNOWN (-2)", field="occupancy")
        return occupancy

    @staticmethod
    def _check_quantised(values: Any, label: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray | None:
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
        if np.any(codes[label == UNKNOWN]):
            raise InputError(f"{name} must be 0 where label is UNKNOWN (-2)", field=name)
        return _read_only(codes)

    @staticmethod
    def _check_colors(
        colors: Mapping[int, Any] | None, classes: dict[int, str]
    ) -> dict[int, tuple[int, int, int]] | None:
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

    # ---- geometry ----

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz)."""
        return tuple(int(n) for n in self.label.shape)  # type: ignore[return-value]

    @property
    def origin_corner(self) -> np.ndarray:
        """[3] world min corner of voxel [0, 0, 0] (= origin - voxel_size / 2)."""
        return self.origin - self.voxel_size / 2.0

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """([3] min corner, [3] max corner) of the volume the grid covers, world units."""
        lo = self.origin_corner
        return lo, lo + self.voxel_size * np.asarray(self.shape, dtype=np.float64)

    @property
    def class_ids(self) -> np.ndarray:
        """[C] int64 class ids, ascending: the channel order of ``probs``."""
        return np.fromiter(self.classes, dtype=np.int64, count=len(self.classes))

    @property
    def T_world_from_grid(self) -> np.ndarray:
        """[4, 4] affine from voxel index to world centre: ``[x, y, z, 1] = T @ [i, j, k, 1]``."""
        return world_from_grid_matrix(self.origin, self.voxel_size)

    @property
    def occupied(self) -> np.ndarray:
        """[nx, ny, nz] bool: occupancy >= occupancy_threshold."""
        return self.occupancy >= self.occupancy_threshold

    def index_from_world(self, xyz: Any) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index of world points; see :func:`index_from_world`.

        Args:
            xyz: [N, 3] (or [..., 3]) world points.
        Returns:
            idx [N, 3] int64 (unclipped), inside [N] bool.
        """
        return index_from_world(xyz, self.origin, self.voxel_size, self.shape)

    def world_from_index(self, ijk: Any) -> np.ndarray:
        """World centres [N, 3] float64 of voxel indices [N, 3]."""
        return world_from_index(ijk, self.origin, self.voxel_size)

    def label_at(self, xyz: Any) -> np.ndarray:
        """Label of the voxel containing each world point [N, 3] -> [N] int16; UNKNOWN outside."""
        idx, inside = self.index_from_world(xyz)
        out = np.full(inside.shape, UNKNOWN, dtype=LABEL_DTYPE)
        out[inside] = self.label[tuple(idx[inside].T)]
        return out

    def occupancy_at(self, xyz: Any) -> np.ndarray:
        """Occupancy of the voxel containing each world point [N, 3] -> [N] float32; 0 outside."""
        idx, inside = self.index_from_world(xyz)
        out = np.zeros(inside.shape, dtype=OCCUPANCY_DTYPE)
        out[inside] = self.occupancy[tuple(idx[inside].T)]
        return out

    def cast_rays(self, origins: Any, directions: Any, near: Any = None, far: Any = None) -> MapRayQuery:
        """What each ray meets first in the map, and how far: numpy only, no field needed.

        A ray stops at the first voxel it enters (exact voxel traversal,
        :func:`first_voxel_hits`) whose label is a class (occupied) or UNKNOWN (unobserved
        space is not known to be free). The depth is where the ray enters that voxel, so it is exact
        for the map and within a voxel of the surface the map was made from.

        Args:
            origins: [N, 3] world ray origins.
            directions: [N, 3] world directions (need not be unit length; no zero vector).
            near, far: optional [N] or scalar limits, distances along the unit direction.
        Returns:
            MapRayQuery (depth, label, index).
        """
        origins, directions = (np.asarray(x, dtype=np.float64) for x in (origins, directions))
        if origins.ndim != 2 or origins.shape[-1] != 3 or directions.shape != origins.shape:
            raise InputError(
                f"origins and directions must both be [N, 3], got {origins.shape} and {directions.shape}",
                field="directions",
            )
        norms = np.linalg.norm(directions, axis=-1, keepdims=True)
        if not np.all(np.isfinite(origins)) or not np.all(np.isfinite(norms) & (norms > 0)):
            raise InputError("origins must be finite and directions finite and non-zero", field="directions")
        directions = directions / norms
        stop = self.label != FREE
        depth, index = first_voxel_hits(origins, directions, stop, self.origin, self.voxel_size, near, far)
        lo, hi = self.bounds
        t_enter, t_exit = ray_box_distances(origins, directions, lo, hi)
        near_n, far_n = _ray_limits(len(origins), near, far)
        entered = np.minimum(t_exit, far_n) > np.maximum(t_enter, near_n)
        label = np.where(entered, FREE, UNKNOWN).astype(LABEL_DTYPE)
        hit = index[:, 0] >= 0
        label[hit] = self.label[tuple(index[hit].T)]
        return MapRayQuery(depth=depth, label=label, index=index)

    # ---- pyramid ----

    def downsample(self, factor: int = PYRAMID_FACTOR) -> OccupancyMap:
        """The map at 1 / ``factor`` the resolution: each coarse voxel pools ``factor``³ children.

        Rules (:func:`pool_labels`, :func:`pool_probs`, :func:`pool_occupancy`): occupied if any
        child is occupied, with the argmax class of the occupied children's summed probabilities;
        FREE only if every child is FREE; UNKNOWN otherwise (a FREE / UNKNOWN mix is UNKNOWN).
        Occupancy is the children's max (same ``occupancy_delta``); confidence is recomputed from
        the pooled probabilities (None when the map has no probs). The coarse grid starts at the
        same min corner and has ``ceil(n / factor)`` voxels per axis; children beyond the fine
        grid count as UNKNOWN.

        Args:
            factor: children per axis, an integer >= 1 (1 returns this map).
        Returns:
            a new OccupancyMap with ``voxel_size * factor``.
        """
        factor = _factor(factor)
        if factor == 1:
            return self
        label, occupancy, probs, confidence = pool_block(self.label, self.occupancy, self.probs, factor, self.class_ids)
        voxel_size = self.voxel_size * factor
        return dataclasses.replace(
            self,
            label=label,
            occupancy=occupancy,
            voxel_size=voxel_size,
            origin=self.origin_corner + voxel_size / 2.0,
            probs=probs,
            confidence=confidence,
        )

    def pyramid(self, levels: int | None = None) -> list[OccupancyMap]:
        """Levels 0 (this map), 1, ..., ``levels - 1``; level L is ``downsample(2 ** L)``.

        Args:
            levels: number of levels >= 1; None: :func:`default_levels` of the shape.
        """
        return [self.downsample(PYRAMID_FACTOR**level) for level in range(_check_levels(levels, self.shape))]

    # ---- comparison ----

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OccupancyMap):
            return NotImplemented
        return (
            np.array_equal(self.label, other.label)
            and np.array_equal(self.occupancy, other.occupancy)
            and _same_optional(self.probs, other.probs)
            and _same_optional(self.confidence, other.confidence)
            and self.attributes() == other.attributes()
        )

    __hash__ = None  # type: ignore[assignment]

    # ---- zarr ----

    def attributes(self) -> dict[str, Any]:
        """The map's own zarr group attributes (JSON-ready; see the schema).

        :meth:`to_zarr` adds the layout ones: ``level`` and ``n_levels`` on every level's group,
        and the OME-NGFF metadata (:func:`ngff_multiscales`) on the root.
        """
        colors = self.class_colors or {}
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "scenelabel_version": self.version,
            "voxel_size": self.voxel_size,
            "origin": self.origin.tolist(),
            "origin_corner": self.origin_corner.tolist(),
            "index_order": INDEX_ORDER,
            "units": self.units,
            "frame_id": self.frame_id,
            "free_label": FREE,
            "unknown_label": UNKNOWN,
            "classes": [
                {"id": cid, "name": name, "color": list(colors[cid]) if cid in colors else None}
                for cid, name in self.classes.items()
            ],
            "occupancy_threshold": self.occupancy_threshold,
            "occupancy_delta": self.occupancy_delta,
            "scale_source": self.scale_source,
            "occupancy_encoding": OCCUPANCY_ENCODING,
            "unknown_rule": self.unknown_rule,
            "T_world_from_grid": self.T_world_from_grid.tolist(),
        }

    def to_zarr(
        self,
        path: str | Path,
        zarr_format: int = 3,
        chunks: tuple[int, int, int] = DEFAULT_CHUNKS,
        *,
        overwrite: bool = True,
        levels: int | None = None,
    ) -> Path:
        """Write the map and its pyramid as a zarr group (directory store), atomically.

        Layout (docs/formats.md): level 0's arrays at the root (``label``, ``occupancy``, and
        ``probs`` / ``confidence`` when the map has them), level L >= 1 in the sub-group
        ``levels/L`` with the same arrays and its own map attributes (:meth:`pyramid`); the
        root also carries OME-NGFF multiscales metadata (``multiscales``, NGFF 0.4, in zarr
        format 2; ``ome``, NGFF 0.5, in zarr format 3).

        The group is written into a hidden sibling ``.{name}.tmp-{pid}`` and renamed into place;
        an existing map at ``path`` is renamed aside first and removed once the new one is in
        place. The root group attributes (among them ``format``) are written last, so a temp
        folder left by a killed process is never taken for a complete map.

        Args:
            path: the target directory (conventionally ``*.zarr``).
            zarr_format: 3 (default) or 2.
            chunks: spatial chunk shape of every array (clipped to each level's shape; ``probs``
                keeps all classes in one chunk).
            overwrite: replace an existing zarr group at ``path``; otherwise raise.
            levels: pyramid levels to write, level 0 included; None: :func:`default_levels`.
        Returns:
            the absolute path written.
        Raises:
            InputError: bad zarr_format / chunks / levels, or ``path`` exists and is not a zarr
                group (it is never deleted then) or overwrite is False.
        """
        import zarr

        zarr_format, chunks, path = _check_target(path, zarr_format, chunks, overwrite)
        pyramid = self.pyramid(levels)
        with _staged_group(path) as tmp:
            root = zarr.open_group(str(tmp), mode="w", zarr_format=zarr_format)
            for level, level_map in enumerate(pyramid):
                group = root if level == 0 else _level_group(root, level)
                level_map._write_arrays(group, zarr_format, chunks)
                if level:
                    group.attrs.update(level_map._group_attributes(level, len(pyramid)))
            # last: marks the map complete
            root.attrs.update(_root_attributes(pyramid, zarr_format))
        return path

    def _group_attributes(self, level: int, n_levels: int) -> dict[str, Any]:
        """Attributes of the group holding this map as pyramid level ``level`` of ``n_levels``."""
        return {**self.attributes(), "level": level, "n_levels": n_levels}

    def _write_arrays(self, group: Any, zarr_format: int, chunks: tuple[int, int, int]) -> None:
        """Write this map's arrays into a zarr group (no group attributes)."""
        for name, array in self._create_arrays(group, zarr_format, chunks, self.shape).items():
            array[...] = getattr(self, name)

    def _create_arrays(
        self, group: Any, zarr_format: int, chunks: tuple[int, int, int], shape: tuple[int, int, int]
    ) -> dict[str, Any]:
        """Create (unfilled) the arrays of a map of this one's classes, with ``probs`` /
        ``confidence`` when this map has them, and ``shape``, in a zarr group.

        Returns:
            name -> zarr array; spatial chunks ``chunks`` clipped to ``shape`` (:func:`array_chunks`).
        """
        chunks = array_chunks(chunks, shape)
        n_classes = len(self.classes)
        scaled = {"scale_factor": 1.0 / QUANTISATION_STEPS, "add_offset": 0.0}  # CF: value = code * scale_factor
        names = [UNKNOWN_WORD, FREE_WORD] + [_flag_word(cid, name) for cid, name in self.classes.items()]
        arrays = [
            (LABEL_ARRAY, LABEL_DTYPE, shape, UNKNOWN, {
                "description": "class id >= 0, FREE = -1, UNKNOWN = -2",
                "flag_values": [UNKNOWN, FREE, *self.classes],  # CF: flag_values / flag_meanings
                "flag_meanings": " ".join(names),
            }),
            (OCCUPANCY_ARRAY, OCCUPANCY_DTYPE, shape, 0.0, {
                "description": "occupancy = 1 - exp(-sigma * occupancy_delta), in [0, 1]",
            }),
        ]
        if self.probs is not None:
            arrays.append((PROBS_ARRAY, QUANTISED_DTYPE, (*shape, n_classes), 0, {
                "description": "class probabilities quantised: p = code / 255; channel c is class_ids[c]; 0 where UNKNOWN",
                "class_ids": self.class_ids.tolist(),
                **scaled,
            }))
        if self.confidence is not None:
            arrays.append((CONFIDENCE_ARRAY, QUANTISED_DTYPE, shape, 0, {
                "description": "1 - entropy / log(C) of the class distribution, quantised: code / 255; 0 where UNKNOWN",
                **scaled,
            }))
        created = {}
        for name, dtype, array_shape, fill, array_attrs in arrays:
            dims = PROBS_DIMENSION_NAMES if len(array_shape) == 4 else DIMENSION_NAMES
            extra: dict[str, Any] = {}
            if zarr_format == 3:
                extra["dimension_names"] = list(dims)
            else:  # v2 has no dimension names: the xarray convention
                array_attrs["_ARRAY_DIMENSIONS"] = list(dims)
            created[name] = group.create_array(
                name, shape=array_shape, dtype=dtype, chunks=chunks + tuple(array_shape[3:]), fill_value=fill,
                attributes=array_attrs, **extra,
            )
        return created

    @staticmethod
    def from_zarr(path: str | Path, level: int = 0) -> "OccupancyMap":
        """Read a map written by :meth:`to_zarr` (zarr format 2 or 3; map format 1 or 2).

        Args:
            path: the map's root group (a ``levels/L`` sub-group also reads, as a map of its own).
            level: pyramid level to read (0: full resolution; see the root's ``n_levels``).
        Raises:
            InputError naming the path and the attribute or array at fault: not a zarr group,
            not a scenelabel map, a newer format_version, an invalid or missing attribute, a
            missing or malformed array, a level the map does not have.
        """
        import zarr

        path = Path(path).expanduser()
        if not path.exists():
            raise InputError("no occupancy map here (path does not exist)", path=path)
        try:
            group = zarr.open_group(str(path), mode="r")
        except Exception as exc:  # zarr raises several types for "not a group"
            raise InputError(f"not a zarr group ({type(exc).__name__}: {exc})", path=path) from None
        attrs = _checked_attributes(group, path)
        if level != 0:
            n_levels = int(attrs.get("n_levels", 1))
            if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, np.integer)) or not 0 < level < n_levels:
                raise InputError(
                    f"no level {level!r} in this map: it has levels 0 to {n_levels - 1}", path=path, field="level"
                )
            try:
                group = group[f"{LEVELS_GROUP}/{int(level)}"]
            except KeyError:
                raise InputError(f"missing group '{LEVELS_GROUP}/{level}'", path=path, field="level") from None
            path = path / LEVELS_GROUP / str(int(level))
            attrs = _checked_attributes(group, path)

        arrays = {}
        for name, dtype, required in (
            (LABEL_ARRAY, LABEL_DTYPE, True),
            (OCCUPANCY_ARRAY, OCCUPANCY_DTYPE, True),
            (PROBS_ARRAY, QUANTISED_DTYPE, False),
            (CONFIDENCE_ARRAY, QUANTISED_DTYPE, False),
        ):
            try:
                node = group[name]
            except KeyError:
                if required:
                    raise InputError(f"missing array {name!r}", path=path, field=name) from None
                continue
            if not isinstance(node, zarr.Array):
                raise InputError(f"{name!r} is not an array", path=path, field=name)
            if node.dtype != dtype:
                raise InputError(f"array {name!r} has dtype {node.dtype}, expected {dtype}", path=path, field=name)
            arrays[name] = np.asarray(node[...])

        classes = {int(c["id"]): str(c["name"]) for c in attrs["classes"]}
        colors = {int(c["id"]): tuple(c["color"]) for c in attrs["classes"] if c.get("color") is not None}
        try:
            return OccupancyMap(
                label=arrays[LABEL_ARRAY],
                occupancy=arrays[OCCUPANCY_ARRAY],
                voxel_size=float(attrs["voxel_size"]),
                origin=np.asarray(attrs["origin"], np.float64),
                classes=classes,
                occupancy_delta=float(attrs["occupancy_delta"]),
                class_colors=colors or None,
                frame_id=attrs["frame_id"],
                occupancy_threshold=float(attrs["occupancy_threshold"]),
                scale_source=attrs["scale_source"],
                units=attrs["units"],
                version=attrs["scenelabel_version"],
                probs=arrays.get(PROBS_ARRAY),
                confidence=arrays.get(CONFIDENCE_ARRAY),
                unknown_rule=attrs.get("unknown_rule", DEFAULT_UNKNOWN_RULE),  # version 1: bounds
            )
        except InputError as exc:
            raise InputError(exc.problem, path=path, field=exc.field) from None


def array_chunks(chunks: Any, shape: Any) -> tuple[int, int, int]:
    """The spatial chunk shape :meth:`OccupancyMap.to_zarr` gives a level of ``shape``: ``chunks``
    clipped to it per axis."""
    return tuple(min(c, n) for c, n in zip(_shape3(chunks, "chunks"), _shape3(shape)))  # type: ignore[return-value]


def _level_group(root: Any, level: int) -> Any:
    """The group of pyramid level ``level`` >= 1 (``levels/L``), created when missing."""
    return root.require_group(LEVELS_GROUP).require_group(str(level))


def _root_attributes(pyramid: list[OccupancyMap], zarr_format: int) -> dict[str, Any]:
    """The root group's attributes of a written pyramid: level 0's map attributes, ``level``,
    ``n_levels`` and the OME-NGFF metadata. (Only metadata of the levels is used, never their
    arrays.)"""
    return {**pyramid[0]._group_attributes(0, len(pyramid)), **ngff_multiscales(pyramid, zarr_format)}


def _check_target(path: Any, zarr_format: Any, chunks: Any, overwrite: bool) -> tuple[int, tuple[int, int, int], Path]:
    """Checks of :meth:`OccupancyMap.to_zarr`'s arguments before anything is written.

    Returns:
        zarr_format, chunks (3 ints), the absolute target path.
    Raises:
        InputError: bad zarr_format or chunks; ``path`` exists and is not a zarr group or
            overwrite is False; its parent folder does not exist.
    """
    if zarr_format not in (2, 3):
        raise InputError(f"zarr_format must be 2 or 3, got {zarr_format!r}", field="zarr_format")
    chunks = _shape3(chunks, "chunks")
    path = Path(path).expanduser().absolute()
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise InputError("already exists (pass overwrite=True to replace it)", path=path)
        if not _is_replaceable(path):
            raise InputError("exists and is not a zarr group; refusing to replace it", path=path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    return int(zarr_format), chunks, path


@contextlib.contextmanager
def _staged_group(path: Path) -> Iterator[Path]:
    """Write a map atomically: yields the hidden sibling ``.{name}.tmp-{pid}`` to write into;
    when the block ends without an error, moves it into place at ``path`` (an existing map is
    renamed aside first and removed once the new one is in place); on any error removes it and
    re-raises (``path`` untouched)."""
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    _remove(tmp)
    try:
        yield tmp
    except BaseException:
        _remove(tmp)
        raise

    aside = path.parent / f".{path.name}.old-{os.getpid()}"
    if path.exists() or path.is_symlink():
        _remove(aside)
        os.replace(path, aside)
    try:
        os.replace(tmp, path)
    except BaseException:
        if aside.exists() and not path.exists():
            os.replace(aside, path)
        _remove(tmp)
        raise
    _remove(aside)


def _checked_attributes(group: Any, path: Path) -> dict[str, Any]:
    """A map group's attributes, checked: format, version, schema, origin_corner, T_world_from_grid."""
    attrs = dict(group.attrs.asdict())
    if "format" not in attrs:
        raise InputError(
            "missing attribute 'format': not a scenelabel occupancy map, or an incomplete write",
            path=path, field="format",
        )
    if attrs["format"] != FORMAT_NAME:
        raise InputError(f"format is {attrs['format']!r}, expected {FORMAT_NAME!r}", path=path, field="format")
    version = attrs.get("format_version")
    if isinstance(version, int) and version > FORMAT_VERSION:
        raise InputError(
            f"format_version {version} is newer than this scenelabel reads ({FORMAT_VERSION}); upgrade scenelabel",
            path=path, field="format_version",
        )
    validate_attributes(attrs, path=path)
    voxel_size = float(attrs["voxel_size"])
    origin = np.asarray(attrs["origin"], np.float64)
    derived = {"origin_corner": origin - voxel_size / 2.0}
    if "T_world_from_grid" in attrs:
        derived["T_world_from_grid"] = world_from_grid_matrix(origin, voxel_size)
    for name, expected in derived.items():
        if not np.allclose(
            np.asarray(attrs[name], np.float64), expected, rtol=_CORNER_RTOL, atol=_CORNER_RTOL * voxel_size
        ):
            raise InputError(f"{name} {attrs[name]} does not match origin and voxel_size", path=path, field=name)
    return attrs


def _flag_word(class_id: int, name: str) -> str:
    """A class name as one CF flag_meanings word (whitespace -> '_'; empty -> class_ID)."""
    word = "_".join(name.split())
    return word or f"class_{class_id}"


LABEL_POOLING_RULE = (
    "occupied if any child is occupied (argmax class of the occupied children's summed probabilities), "
    "FREE if every child is FREE, else UNKNOWN"
)


def ngff_multiscales(levels: list[OccupancyMap], zarr_format: int) -> dict[str, Any]:
    """OME-NGFF multiscales metadata of a pyramid written by :meth:`OccupancyMap.to_zarr`.

    One multiscale per spatial array (``label``, ``occupancy``, ``confidence`` when present;
    ``probs`` is channel-last, which NGFF does not allow, so it is not listed). Axes x, y, z of
    type "space" (unit "meter" when the map is metric, none otherwise); each level's dataset
    maps an index to the world with ``scale = voxel_size`` then ``translation = origin`` (the
    centre of voxel [0, 0, 0] of that level).

    Args:
        levels: the pyramid, level 0 first (:meth:`OccupancyMap.pyramid`).
        zarr_format: 2 -> ``{"multiscales": [...]}`` (NGFF 0.4); 3 -> ``{"ome": {"version":
            "0.5", "multiscales": [...]}}`` (NGFF 0.5).
    Returns:
        the group attributes to add.
    """
    base = levels[0]
    unit = {"unit": "meter"} if base.units in NGFF_METRE_UNITS else {}
    axes = [{"name": name, "type": "space", **unit} for name in DIMENSION_NAMES]
    entries = []
    for name, method, rule in (
        (LABEL_ARRAY, "scenelabel.pool_labels", LABEL_POOLING_RULE),
        (OCCUPANCY_ARRAY, "max", "max over the children; 0 where the coarse label is UNKNOWN"),
        (CONFIDENCE_ARRAY, "scenelabel.pool_probs", "1 - entropy / log C of the pooled class probabilities"),
    ):
        if getattr(base, name) is None:
            continue
        datasets = [
            {
                "path": name if level == 0 else f"{LEVELS_GROUP}/{level}/{name}",
                "coordinateTransformations": [
                    {"type": "scale", "scale": [m.voxel_size] * 3},
                    {"type": "translation", "translation": m.origin.tolist()},
                ],
            }
            for level, m in enumerate(levels)
        ]
        entries.append({"name": name, "axes": axes, "datasets": datasets, "type": method, "metadata": {"method": rule}})
    if zarr_format == 2:
        return {"multiscales": [{"version": NGFF_VERSION_V2, **entry} for entry in entries]}
    return {"ome": {"version": NGFF_VERSION_V3, "multiscales": entries}}


def _same_optional(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays."""
    if a is None or b is None:
        return a is None and b is None
    return np.array_equal(a, b)


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array`` (the caller's array itself stays writeable)."""
    view = array.view()
    view.flags.writeable = False
    return view


def _is_replaceable(path: Path) -> bool:
    """An existing path that to_zarr may replace: an empty folder or a zarr group folder."""
    if path.is_symlink() or not path.is_dir():
        return False
    return (path / "zarr.json").is_file() or (path / ".zgroup").is_file() or not any(path.iterdir())


def _remove(path: Path) -> None:
    """Remove a folder (or file) if present."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)
