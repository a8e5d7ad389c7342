"""Rays through voxel grids (numpy only): where a ray crosses a box, the first voxel of a mask it
enters, where its transmittance through per-voxel opacities falls to a level (exact voxel
traversal), and :class:`MapRayQuery`, what :meth:`OccupancyMap.cast_rays` answers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.boxes import ray_box_distances
from scenelabel.maps.codes import QUANTISATION_STEPS, QUANTISED_DTYPE, uint8_from_unit

__all__ = [
    "ray_limits",
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
    near, far = ray_limits(n, near, far)
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
