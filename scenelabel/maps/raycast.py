"""Rays through voxel grids: where a ray crosses a box, the first voxel of a mask it enters, where
its transmittance through per-voxel opacities falls to a level (exact voxel traversal), and
:class:`MapRayQuery`, what :meth:`OccupancyMap.cast_rays` answers. Numpy in and out; the per-ray
loops are compiled (numba, :mod:`scenelabel.maps.raycast_kernels`, imported on the first cast).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.maps.codes import QUANTISATION_STEPS, QUANTISED_DTYPE, uint8_from_unit

__all__ = [
    "ray_limits",
    "leap_lengths",
    "first_voxel_hits",
    "transmittance_crossings",
    "MapRayQuery",
]


def ray_limits(n: int, near: Any, far: Any) -> tuple[np.ndarray, np.ndarray]:
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
    *,
    leaps: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The first voxel of ``stop`` each ray enters, and the distance where it enters it.

    Each ray is clipped to the grid's box (voxel ``[i, j, k]`` covers centre ± voxel_size / 2,
    centre ``origin + voxel_size * (i, j, k)``) and to ``[near, far]``. It then leaps through
    empty space by a distance no stop voxel can be nearer than (:func:`leap_lengths`), and
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
        leaps: optional [nx, ny, nz] :func:`leap_lengths` of ``stop``, kept by a caller that
            casts through the same grid many times (computed here otherwise).
    Returns:
        depth: [R] float64 distance where the ray enters its first ``stop`` voxel, ``inf`` where
            it meets none; index: [R, 3] int64 that voxel's index, -1 where none.
    """
    stop = np.asarray(stop, dtype=bool)
    if stop.ndim != 3:
        raise InputError(f"need stop [nx, ny, nz], got {stop.shape}", field="stop")
    # an opaque voxel: infinite optical depth, so any positive threshold is crossed where the ray enters it
    opaque = np.array([0.0, np.inf])
    return _optical_depth_crossings(
        origins, directions, stop.view(np.uint8), opaque, origin, voxel_size, near, far, 1.0, leaps
    )


def transmittance_crossings(
    origins: Any,
    directions: Any,
    occupancy: np.ndarray,
    origin: Any,
    voxel_size: float,
    near: Any = None,
    far: Any = None,
    transmittance: float = 0.5,
    *,
    leaps: np.ndarray | None = None,
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
        leaps: optional [nx, ny, nz] :func:`leap_lengths` of ``codes > 0`` (the voxels of a
            non-zero code), kept by a caller that casts through the same grid many times.
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
        origins, directions, codes, _OPTICAL_DEPTH_OF_CODE, origin, voxel_size, near, far,
        -math.log(float(transmittance)), leaps,
    )


def _optical_depth_of_codes() -> np.ndarray:
    """[256] the optical depth of crossing a voxel edge-on at each opacity code, ``-log(1 - q / 255)``
    (inf for code 255)."""
    with np.errstate(divide="ignore"):
        return -np.log1p(-np.arange(QUANTISATION_STEPS + 1) / QUANTISATION_STEPS)


_OPTICAL_DEPTH_OF_CODE = _optical_depth_of_codes()


def _optical_depth_crossings(
    origins: Any, directions: Any, codes: np.ndarray, tau_of_code: np.ndarray, origin: Any, voxel_size: float,
    near: Any, far: Any, threshold: float, leaps: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The common body of :func:`first_voxel_hits` and :func:`transmittance_crossings`: rays
    through a grid of uint8 ``codes`` whose voxels hold optical depth ``tau_of_code[code]`` per
    voxel edge (``tau_of_code[0]`` must be 0: those voxels are leapt over), stopping where the
    accumulated optical depth reaches ``threshold`` > 0. ``leaps``: :func:`leap_lengths` of
    ``codes > 0`` when the caller keeps it (computed here otherwise)."""
    origins = np.ascontiguousarray(np.asarray(origins, dtype=np.float64).reshape(-1, 3))
    directions = np.ascontiguousarray(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
    if len(origins) != len(directions):
        raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
    n, shape = len(origins), np.asarray(codes.shape)
    voxel_size = float(voxel_size)
    corner = np.asarray(origin, np.float64) - voxel_size / 2.0
    limits = np.stack(ray_limits(n, near, far), -1)  # [R, 2] near, far
    depth, index = np.empty(n), np.empty((n, 3), dtype=np.int64)
    if leaps is None and codes.size:
        matter = codes > 0
        leaps = leap_lengths(matter) if matter.any() else None
    if leaps is None or not codes.size:  # nothing to stop at
        depth[:], index[:] = np.inf, -1
        return depth, index
    from scenelabel.maps import raycast_kernels as kernels  # numba: imported on first use

    codes = np.ascontiguousarray(codes, dtype=np.uint8)
    leaps = np.ascontiguousarray(leaps, dtype=leaps.dtype if leaps.dtype in (np.uint8, np.int32) else np.int32)
    sigma_of_code = np.ascontiguousarray(tau_of_code / voxel_size)  # density per world unit
    grid = np.concatenate([corner, corner + voxel_size * shape, [voxel_size]])  # the box, then the voxel edge
    threshold = float(threshold)

    def run(rows: slice) -> None:
        kernels.crossings_kernel(
            origins[rows], directions[rows], limits[rows], codes, sigma_of_code, leaps, grid, threshold,
            depth[rows], index[rows],
        )

    kernels.in_threads(run, n)
    return depth, index


def leap_lengths(stop: np.ndarray) -> np.ndarray:
    """[nx, ny, nz] uint8 (int32 where a length exceeds 255): from anywhere in a voxel, no ``stop``
    voxel is nearer than this many voxel edges. With k the chessboard distance between the voxel's
    centre and the nearest stop voxel's centre, the two voxels are k - 1 edges apart along some
    axis, so k - 1 is safe (0 at stop voxels and their neighbours). ``stop`` must hold at least
    one True. The rays' leaps, and so their answers to the last bit, follow these lengths: callers
    that cast rays through one grid many times keep it and pass it as ``leaps``. (The narrowest
    dtype because the leaps are read on each ray's critical path: a grid of bytes stays in cache.)"""
    from scipy import ndimage

    leaps = np.maximum(ndimage.distance_transform_cdt(~stop, metric="chessboard") - 1, 0)
    return leaps.astype(np.uint8 if leaps.max(initial=0) <= np.iinfo(np.uint8).max else np.int32)


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
