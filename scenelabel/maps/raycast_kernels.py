"""Compiled loops (numba) behind :mod:`scenelabel.maps.raycast`: one ray at a time, no allocation
inside the loops, the same float64 operations in the same order as the numpy reference
(tests/test_raycast_kernels.py keeps it), so the answers are bit for bit the same. Imported on
first use (importing numba takes a while); :func:`in_threads` splits a batch over the cores.

A grid is read through ``grid`` = (corner x, y, z, voxel_size): voxel ``[i, j, k]`` covers
``corner + voxel_size * [i, i + 1) x [j, j + 1) x [k, k + 1)``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np
from numba import njit

__all__ = ["MIN_ROWS_PER_THREAD", "in_threads", "crossings_kernel"]

MIN_ROWS_PER_THREAD = 4096
"""Kernels are split over threads (one per core) in chunks of at least this many points or rays."""


def in_threads(run: Callable[[slice], None], n: int) -> None:
    """run(rows) over [0, n) split into one contiguous slice per core (each at least
    MIN_ROWS_PER_THREAD rows); the kernels release the GIL, so the slices run in parallel."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = max(1, min(cores, n // MIN_ROWS_PER_THREAD))
    if workers == 1:
        run(slice(0, n))
        return
    bounds = np.linspace(0, n, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(run, [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]))


@njit(cache=True, nogil=True)
def _cell(o, d, t, corner, size, n):  # pragma: no cover - compiled
    """The voxel index along one axis of the point ``o + t d``, clipped to [0, n - 1]."""
    v = np.floor((o + t * d - corner) / size)
    if v < 0.0:
        v = 0.0
    elif v > n - 1:
        v = n - 1.0
    return int(v)


@njit(cache=True, nogil=True)
def _first_face(o, d, i, corner, size):  # pragma: no cover - compiled
    """Distance along one axis to the face the ray leaves voxel ``i`` by (inf when d == 0)."""
    if d > 0.0:
        return (corner + (i + 1) * size - o) / d
    if d < 0.0:
        return (corner + i * size - o) / d
    return np.inf


@njit(cache=True, nogil=True)
def _slab(o, d, lo, hi):  # pragma: no cover - compiled
    """Entry and exit distances of a ray through the slab [lo, hi] of one axis, as
    :func:`scenelabel.geometry.boxes.slab_distances` (a zero direction: inside for every t or none)."""
    if d == 0.0:
        if lo <= o <= hi:
            return -np.inf, np.inf
        return np.inf, -np.inf
    ta = (lo - o) / d
    tb = (hi - o) / d
    return (ta if ta <= tb else tb), (ta if ta >= tb else tb)


@njit(cache=True, nogil=True)
def crossings_kernel(
    origins, directions, limits, codes, sigma_of_code, leaps, grid, threshold, depth, index
):  # pragma: no cover - compiled
    """Per ray r: clip it to the grid's box (``grid`` = (min corner x, y, z, max corner x, y, z,
    voxel_size)) and to limits[r] = (near, far); leap through empty space while the voxel it is in
    allows it (t += leaps[voxel] * voxel_size, sphere tracing on
    :func:`scenelabel.maps.raycast.leap_lengths`); then walk voxel by voxel (Amanatides & Woo)
    accumulating optical depth ``sigma_of_code[codes[voxel]] * length`` until it reaches
    ``threshold``: depth[r] is that distance (where the ray enters the voxel for an infinite
    sigma) and index[r] the voxel; inf and -1 where it never does."""
    nx, ny, nz = codes.shape
    cx, cy, cz, size = grid[0], grid[1], grid[2], grid[6]
    for r in range(origins.shape[0]):
        depth[r] = np.inf
        index[r, 0] = index[r, 1] = index[r, 2] = -1
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        enter_x, exit_x = _slab(ox, dx, cx, grid[3])
        enter_y, exit_y = _slab(oy, dy, cy, grid[4])
        enter_z, exit_z = _slab(oz, dz, cz, grid[5])
        t_enter = enter_x if enter_x >= enter_y else enter_y  # numpy's maximum and minimum, ties included
        t_enter = t_enter if t_enter >= enter_z else enter_z
        t_exit = exit_x if exit_x <= exit_y else exit_y
        t_exit = t_exit if t_exit <= exit_z else exit_z
        t = t_enter if t_enter >= limits[r, 0] else limits[r, 0]
        t_end = t_exit if t_exit <= limits[r, 1] else limits[r, 1]
        if not t_end > t:
            continue
        while True:  # the leaps
            leap = leaps[_cell(ox, dx, t, cx, size, nx), _cell(oy, dy, t, cy, size, ny), _cell(oz, dz, t, cz, size, nz)]
            if leap <= 0:
                break
            t += leap * size
            if not t < t_end:
                break
        if not t < t_end:
            continue
        i, j, k = _cell(ox, dx, t, cx, size, nx), _cell(oy, dy, t, cy, size, ny), _cell(oz, dz, t, cz, size, nz)
        si = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
        sj = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
        sk = 1 if dz > 0.0 else (-1 if dz < 0.0 else 0)
        next_i = _first_face(ox, dx, i, cx, size)  # where the ray crosses its next face along each axis
        next_j = _first_face(oy, dy, j, cy, size)
        next_k = _first_face(oz, dz, k, cz, size)
        delta_i = size / abs(dx) if dx != 0.0 else np.inf
        delta_j = size / abs(dy) if dy != 0.0 else np.inf
        delta_k = size / abs(dz) if dz != 0.0 else np.inf
        tau = 0.0  # optical depth accumulated so far
        while True:  # the walk
            axis, t_face = 0, next_i  # the first axis of the nearest face (ties: the lowest axis)
            if next_j < t_face:
                axis, t_face = 1, next_j
            if next_k < t_face:
                axis, t_face = 2, next_k
            t_out = t_face if t_face < t_end else t_end  # where the ray leaves this voxel
            sigma = sigma_of_code[codes[i, j, k]]
            if np.isinf(sigma):  # opaque: stops where the ray enters
                depth[r] = t + 0.0
                index[r, 0], index[r, 1], index[r, 2] = i, j, k
                break
            tau_out = tau + sigma * (t_out - t)
            if tau_out >= threshold:  # inside the segment, linear in t
                depth[r] = t + (threshold - tau) / sigma
                index[r, 0], index[r, 1], index[r, 2] = i, j, k
                break
            t, tau = t_out, tau_out
            if axis == 0:
                i += si
                next_i += delta_i
                moved, n_axis = i, nx
            elif axis == 1:
                j += sj
                next_j += delta_j
                moved, n_axis = j, ny
            else:
                k += sk
                next_k += delta_k
                moved, n_axis = k, nz
            if not (t < t_end and 0 <= moved < n_axis):
                break
