"""Lattices of voxels (numpy only): the grid that covers a box, its blocks, voxel index <-> world.

Conventions (docs/conventions.md, "Occupancy grids"): arrays are indexed ``[i, j, k]`` along world
**x, y, z**; ``origin`` is the world position of the **centre** of voxel ``[0, 0, 0]``; voxel
``[i, j, k]`` has centre ``origin + voxel_size * (i, j, k)`` and covers that centre ±
``voxel_size / 2`` (half-open: ``[centre - voxel_size / 2, centre + voxel_size / 2)`` on each axis).
"""

from __future__ import annotations

import math
from typing import Any, Iterator

import numpy as np

from scenelabel.errors import InputError

__all__ = [
    "DEFAULT_CHUNKS",
    "lattice",
    "iter_chunks",
    "voxel_centers",
    "block_centers",
    "index_from_world",
    "world_from_index",
    "world_from_grid_matrix",
    "vec3",
    "positive",
    "shape3",
]

DEFAULT_CHUNKS = (64, 64, 64)
"""Default block edges of :func:`iter_chunks` / :func:`voxel_centers` (and the zarr chunks of maps)."""

# Points farther than this many voxels from the origin get clamped before the int cast (no overflow).
_MAX_INDEX_MAGNITUDE = 2.0**52
# Relative slack so that a box of exactly n voxels (up to float noise) gets n voxels, not n + 1.
_LATTICE_REL_TOL = 1e-6


def vec3(value: Any, name: str) -> np.ndarray:
    """``value`` as a finite [3] float64 array; InputError naming ``name`` otherwise."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"{name} must be 3 numbers [x, y, z], got shape {arr.shape}", field=name)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr.tolist()}", field=name)
    return arr


def positive(value: Any, name: str) -> float:
    """``value`` as a finite float > 0; InputError naming ``name`` otherwise."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}", field=name) from None
    if not (math.isfinite(out) and out > 0):
        raise InputError(f"{name} must be a finite number > 0, got {value!r}", field=name)
    return out


def shape3(shape: Any, name: str = "shape") -> tuple[int, int, int]:
    """``shape`` as 3 integers >= 1; InputError naming ``name`` otherwise."""
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
    within: tuple[Any, Any] | None = None,
) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A voxel grid that covers the box ``[bounds_min, bounds_max]``, centred on it.

    Per axis the grid has ``n = max(1, ceil(extent / voxel_size))`` voxels (up to a 1e-6 relative
    slack against float noise), so the covered volume ``n * voxel_size`` contains the box and
    every voxel centre lies inside the box (on a degenerate axis: at the box's centre).

    Args:
        bounds_min, bounds_max: [3] world min and max corners of the box to cover.
        voxel_size: voxel edge, world units, > 0.
        max_voxels: raise InputError when the grid would have more voxels than this.
        within: (min corner, max corner) of a box: keep only the voxels whose cells meet it (at
            least one per axis): a block of the grid over the whole box, whose voxels are that
            grid's, not a new grid's.
    Returns:
        origin: [3] float64 world centre of voxel [0, 0, 0].
        shape: (nx, ny, nz).
    """
    lo = vec3(bounds_min, "bounds_min")
    hi = vec3(bounds_max, "bounds_max")
    voxel_size = positive(voxel_size, "voxel_size")
    if np.any(hi < lo):
        raise InputError(f"bounds_max {hi.tolist()} is below bounds_min {lo.tolist()}", field="bounds")
    counts = np.ceil((hi - lo) / voxel_size * (1.0 - _LATTICE_REL_TOL))
    counts = np.maximum(counts, 1.0)
    origin = (lo + hi) / 2.0 - (counts - 1.0) / 2.0 * voxel_size
    if within is not None:  # cell i covers [corner + i v, corner + (i + 1) v)
        corner = origin - voxel_size / 2.0
        first = np.clip(np.floor((vec3(within[0], "within min") - corner) / voxel_size), 0.0, counts - 1.0)
        stop = np.clip(np.ceil((vec3(within[1], "within max") - corner) / voxel_size), first + 1.0, counts)
        lo, hi = corner + first * voxel_size, corner + stop * voxel_size  # the block's extent, for the message
        origin, counts = origin + first * voxel_size, stop - first
    total = float(np.prod(counts))
    if max_voxels is not None and total > max_voxels:
        raise InputError(
            f"a {voxel_size:g} voxel grid over {(hi - lo).tolist()} needs {counts.astype(np.int64).tolist()} "
            f"= {total:.3g} voxels, more than the limit {max_voxels}; use a larger voxel size",
            field="voxel_size",
        )
    return origin, shape3(counts.astype(np.int64))


def iter_chunks(shape: Any, chunk: int | tuple[int, int, int] = DEFAULT_CHUNKS) -> Iterator[tuple[slice, slice, slice]]:
    """Slices that tile a 3D grid, each block at most ``chunk`` voxels per axis, in C order.

    Every index of ``shape`` is in exactly one block; blocks at the upper ends are smaller.

    Args:
        shape: (nx, ny, nz).
        chunk: block edge (int) or per-axis block edges.
    Yields:
        (slice_i, slice_j, slice_k) with explicit start and stop.
    """
    shape = shape3(shape)
    chunks = shape3((chunk,) * 3 if np.isscalar(chunk) else chunk, "chunk")
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
    shape_arr = np.asarray(shape3(shape), dtype=np.int64)
    finite = np.all(np.isfinite(xyz), axis=-1)
    f = np.floor((xyz - np.asarray(origin, np.float64)) / float(voxel_size) + 0.5)
    f = np.where(finite[..., None], f, -1.0)
    idx = np.clip(f, -_MAX_INDEX_MAGNITUDE, _MAX_INDEX_MAGNITUDE).astype(np.int64)
    inside = finite & np.all((idx >= 0) & (idx < shape_arr), axis=-1)
    return idx, inside


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
    origin = vec3(origin, "origin")
    voxel_size = positive(voxel_size, "voxel_size")
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
    transform[:3, :3] *= positive(voxel_size, "voxel_size")
    transform[:3, 3] = vec3(origin, "origin")
    return transform
