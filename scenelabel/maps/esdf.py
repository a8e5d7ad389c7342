"""Euclidean signed distance fields (ESDF) of a map, and their trilinear queries (numpy + scipy).

The ESDF of a map (voxblox / nvblox's quantity, what CHOMP / TrajOpt-style planners and costmaps
read) holds at every voxel centre the signed Euclidean distance, in world units, to the boundary
between obstacle voxels and free voxels: positive in free space, negative inside obstacles, zero
on the faces between an obstacle voxel and a free one. Obstacles are the occupied voxels (a class
id >= 0) and, with ``unknown="occupied"`` (the default, the safe reading for a planner), UNKNOWN
voxels and everything outside the map; with ``unknown="free"`` UNKNOWN counts as free space and
the map's outside as nothing.

Between voxel centres the distance is trilinear (:func:`distance_at`), and its gradient is that
interpolant's exact gradient (:func:`distance_gradient_at`); points outside the lattice of voxel
centres read its nearest border value (and a zero gradient along the axes they are outside of).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.maps.codes import UNKNOWN

__all__ = [
    "UNKNOWN_AS",
    "obstacle_mask",
    "signed_distance",
    "signed_distance_blocks",
    "signed_distance_of_mask",
    "distance_at",
    "distance_gradient_at",
]

UNKNOWN_AS = ("occupied", "free")
"""How an ESDF reads UNKNOWN voxels (and the map's outside)."""

# Voxels per slab when distances are made from a feature transform (bounds the float64 temporaries).
_SLAB_VOXELS = 1 << 18


def _check_unknown(unknown: str) -> None:
    if unknown not in UNKNOWN_AS:
        raise InputError(f"unknown must be one of {list(UNKNOWN_AS)}, got {unknown!r}", field="unknown")


def obstacle_mask(label: Any, unknown: str = "occupied") -> np.ndarray:
    """The obstacle voxels of a label grid (or block) under a rule (module docstring).

    Args:
        label: [nx, ny, nz] int: class id >= 0, FREE (-1) or UNKNOWN (-2).
        unknown: "occupied" (UNKNOWN voxels are obstacles) or "free".
    Returns:
        [nx, ny, nz] bool (the map's outside is not in it: see :func:`signed_distance_blocks`).
    """
    _check_unknown(unknown)
    label = np.asarray(label)
    return (label >= 0) | (label == UNKNOWN) if unknown == "occupied" else label >= 0


def signed_distance_of_mask(obstacle: np.ndarray, voxel_size: float) -> np.ndarray:
    """The signed distance of every voxel centre of a mask to the faces between its obstacle and
    free voxels, world units: the nearest centre of the other kind, minus half a voxel.

    Memory: scipy's feature transform (int32 [3, nx, ny, nz], 12 bytes per voxel, plus a 1-byte
    and, briefly, an 8-byte copy of the mask inside scipy) once per kind, one after the other, and
    the float32 result; distances are made from the feature transform a slab at a time (scipy's own
    distances would be float64 [3, nx, ny, nz] on the way). About 19 bytes per voxel at the peak,
    the mask included.

    Args:
        obstacle: [nx, ny, nz] bool, True at obstacle voxels (taken as is: no outside is added).
        voxel_size: voxel edge, world units.
    Returns:
        [nx, ny, nz] float32, positive at free voxels, negative at obstacles; +inf everywhere when
        there is no obstacle, -inf everywhere when nothing is free.
    """
    from scipy.ndimage import distance_transform_edt

    obstacle = np.asarray(obstacle, dtype=bool)
    out = np.empty(obstacle.shape, dtype=np.float32)
    if not obstacle.any():
        out.fill(np.inf)
        return out
    if obstacle.all():
        out.fill(-np.inf)
        return out
    for sign in (1.0, -1.0):  # free voxels: to the nearest obstacle centre; obstacles: to the nearest free one
        sites = ~obstacle if sign > 0 else obstacle  # distances are measured from these voxels
        features = distance_transform_edt(sites, return_distances=False, return_indices=True)  # int32 [3, ...]
        del sites
        _fill_from_features(out, features, obstacle, sign, voxel_size)
        del features
    return out


def _fill_from_features(
    out: np.ndarray, features: np.ndarray, obstacle: np.ndarray, sign: float, voxel_size: float
) -> None:
    """``out`` at free voxels (sign 1) or obstacles (sign -1): sign * (|nearest feature - voxel| *
    voxel_size - voxel_size / 2), computed a slab of rows at a time (float64 within a slab)."""
    nx = out.shape[0]
    rows = max(1, _SLAB_VOXELS // max(1, int(np.prod(out.shape[1:]))))
    j = np.arange(out.shape[1])[None, :, None]
    k = np.arange(out.shape[2])[None, None, :]
    for start in range(0, nx, rows):
        stop = min(nx, start + rows)
        i = np.arange(start, stop)[:, None, None]
        squared = np.square(features[0, start:stop] - i.astype(np.int64))
        squared += np.square(features[1, start:stop] - j.astype(np.int64))
        squared += np.square(features[2, start:stop] - k.astype(np.int64))
        value = sign * (np.sqrt(squared) * voxel_size - 0.5 * voxel_size)
        selected = obstacle[start:stop] if sign < 0 else ~obstacle[start:stop]
        np.copyto(out[start:stop], value, casting="same_kind", where=selected)


def signed_distance_blocks(
    blocks: Iterable[tuple[tuple[slice, slice, slice], np.ndarray]],
    shape: tuple[int, int, int],
    voxel_size: float,
    unknown: str = "occupied",
) -> np.ndarray:
    """The ESDF of a label grid handed over block by block (for instance read chunk by chunk from
    a zarr array): only a bool obstacle mask of the whole grid (1 byte per voxel, plus a one-voxel
    border of the map's outside with ``unknown="occupied"``) is built, then
    :func:`signed_distance_of_mask`.

    Args:
        blocks: (slices into the grid, [bx, by, bz] int labels of that block); together they must
            cover the grid (a voxel left out counts as an obstacle).
        shape: (nx, ny, nz) of the grid.
        voxel_size: voxel edge, world units.
        unknown: "occupied" or "free" (module docstring).
    Returns:
        [nx, ny, nz] float32, as :func:`signed_distance` (a view into the bordered result when
        ``unknown="occupied"``: ``np.ascontiguousarray`` it to keep it compactly).
    """
    _check_unknown(unknown)
    border = 1 if unknown == "occupied" else 0  # the map's outside: one layer of obstacles around the grid
    obstacle = np.ones(tuple(int(n) + 2 * border for n in shape), dtype=bool)
    for block, label in blocks:
        obstacle[tuple(slice(s.start + border, s.stop + border) for s in block)] = obstacle_mask(label, unknown)
    out = signed_distance_of_mask(obstacle, voxel_size)
    del obstacle
    return out[tuple(slice(border, border + int(n)) for n in shape)]


def signed_distance(label: np.ndarray, voxel_size: float, unknown: str = "occupied") -> np.ndarray:
    """The ESDF of a label grid (module docstring), world units.

    Args:
        label: [nx, ny, nz] int: class id >= 0 (occupied), FREE (-1) or UNKNOWN (-2).
        voxel_size: voxel edge, world units.
        unknown: "occupied" or "free" (module docstring).
    Returns:
        [nx, ny, nz] float32. Where no obstacle exists at all: +inf everywhere; where nothing is
        free: -inf everywhere. Memory: :func:`signed_distance_of_mask` (about 19 bytes per voxel at
        the peak) plus the label.
    """
    label = np.asarray(label)
    whole = (tuple(slice(0, n) for n in label.shape), label)
    return np.ascontiguousarray(signed_distance_blocks([whole], label.shape, voxel_size, unknown))


def _cell(values: np.ndarray, origin: Any, voxel_size: float, xyz: Any):
    """Lower corner index [N, 3], fractions [N, 3] and the in-range mask [N, 3] of points in the
    lattice of voxel centres (clamped at its border)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(f"expected points of shape (N, 3), got {xyz.shape}", field="xyz")
    shape = np.asarray(values.shape[:3])
    u = (xyz - np.asarray(origin, np.float64)) / voxel_size  # continuous index of voxel centres
    inside = (u >= 0) & (u <= shape - 1)
    u = np.clip(u, 0, shape - 1)
    i0 = np.minimum(np.floor(u).astype(np.int64), np.maximum(shape - 2, 0))
    frac = u - i0
    return i0, np.clip(frac, 0.0, 1.0), inside


def _corners(values: np.ndarray, i0: np.ndarray) -> np.ndarray:
    """[N, 2, 2, 2] values at the 8 lattice points around each cell (an axis of one voxel repeats)."""
    shape = np.asarray(values.shape[:3])
    i1 = np.minimum(i0 + 1, shape - 1)
    ix, iy, iz = (np.stack([i0[:, a], i1[:, a]], -1) for a in range(3))  # [N, 2] each
    return values[ix[:, :, None, None], iy[:, None, :, None], iz[:, None, None, :]].astype(np.float64)


def distance_at(esdf: np.ndarray, origin: Any, voxel_size: float, xyz: Any) -> np.ndarray:
    """Trilinear ESDF at world points.

    Args:
        esdf: [nx, ny, nz] values at voxel centres (:func:`signed_distance`).
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        xyz: [N, 3] world points.
    Returns:
        [N] float64.
    """
    from scipy.ndimage import map_coordinates

    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(f"expected points of shape (N, 3), got {xyz.shape}", field="xyz")
    if esdf.size and np.isinf(esdf.flat[0]):  # no obstacle, or no free space: one infinite value
        return np.full(len(xyz), float(esdf.flat[0]))
    u = np.clip((xyz - np.asarray(origin, np.float64)) / voxel_size, 0, np.asarray(esdf.shape[:3]) - 1)
    # order 1 without prefilter: trilinear between voxel centres, in float64, clamped at the border
    return map_coordinates(esdf, u.T, output=np.float64, order=1, mode="nearest", prefilter=False)


def distance_gradient_at(esdf: np.ndarray, origin: Any, voxel_size: float, xyz: Any) -> np.ndarray:
    """The exact gradient of :func:`distance_at`'s trilinear interpolant (world units per world
    unit; about a unit vector away from the nearest obstacle), zero along an axis on which the
    point lies outside the lattice of voxel centres.

    Args:
        as :func:`distance_at`.
    Returns:
        [N, 3] float64.
    """
    i0, f, inside = _cell(esdf, origin, voxel_size, xyz)
    if esdf.size and np.isinf(esdf.flat[0]):  # a constant (infinite) field
        return np.zeros((len(i0), 3))
    c = _corners(esdf, i0)  # [N, 2, 2, 2] indexed [n, x, y, z]
    fx, fy, fz = (f[:, a] for a in range(3))
    wx = np.stack([1 - fx, fx], -1)  # [N, 2]
    wy = np.stack([1 - fy, fy], -1)
    wz = np.stack([1 - fz, fz], -1)
    dx = np.einsum("nxyz,ny,nz->n", c[:, 1:] - c[:, :1], wy, wz)
    dy = np.einsum("nxyz,nx,nz->n", c[:, :, 1:] - c[:, :, :1], wx, wz)
    dz = np.einsum("nxyz,nx,ny->n", c[:, :, :, 1:] - c[:, :, :, :1], wx, wy)
    grad = np.stack([dx, dy, dz], -1) / voxel_size
    single = np.asarray(esdf.shape[:3]) < 2  # an axis of one voxel: no slope along it
    return np.where(inside & ~single, grad, 0.0)
