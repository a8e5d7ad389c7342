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

from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.maps.codes import UNKNOWN

__all__ = ["UNKNOWN_AS", "signed_distance", "distance_at", "distance_gradient_at"]

UNKNOWN_AS = ("occupied", "free")
"""How an ESDF reads UNKNOWN voxels (and the map's outside)."""


def _check_unknown(unknown: str) -> None:
    if unknown not in UNKNOWN_AS:
        raise InputError(f"unknown must be one of {list(UNKNOWN_AS)}, got {unknown!r}", field="unknown")


def signed_distance(label: np.ndarray, voxel_size: float, unknown: str = "occupied") -> np.ndarray:
    """The ESDF of a label grid (module docstring), world units.

    Args:
        label: [nx, ny, nz] int: class id >= 0 (occupied), FREE (-1) or UNKNOWN (-2).
        voxel_size: voxel edge, world units.
        unknown: "occupied" or "free" (module docstring).
    Returns:
        [nx, ny, nz] float32. Where no obstacle exists at all: +inf everywhere; where nothing is
        free: -inf everywhere.
    """
    from scipy.ndimage import distance_transform_edt

    _check_unknown(unknown)
    label = np.asarray(label)
    obstacle = (label >= 0) | ((label == UNKNOWN) if unknown == "occupied" else False)
    if unknown == "occupied":  # the map's outside is an obstacle too: one layer of it around the grid
        obstacle = np.pad(obstacle, 1, constant_values=True)
    free = ~obstacle
    out = np.empty(obstacle.shape, dtype=np.float64)
    if not obstacle.any():
        out[:] = np.inf
    elif not free.any():
        out[:] = -np.inf
    else:
        # distance from each voxel centre to the nearest centre of the other kind, minus half a
        # voxel: the faces between the two kinds sit halfway between their centres
        to_obstacle = distance_transform_edt(free, sampling=voxel_size)  # 0 on obstacles
        to_free = distance_transform_edt(obstacle, sampling=voxel_size)  # 0 on free voxels
        half = 0.5 * voxel_size
        out = np.where(obstacle, -(to_free - half), to_obstacle - half)
    if unknown == "occupied":
        out = out[1:-1, 1:-1, 1:-1]
    return out.astype(np.float32)


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
    i0, f, _ = _cell(esdf, origin, voxel_size, xyz)
    if esdf.size and np.isinf(esdf.flat[0]):  # no obstacle, or no free space: one infinite value
        return np.full(len(i0), float(esdf.flat[0]))
    c = _corners(esdf, i0)  # [N, 2, 2, 2]
    c = c[:, 0] * (1 - f[:, 0, None, None]) + c[:, 1] * f[:, 0, None, None]  # along x: [N, 2, 2]
    c = c[:, 0] * (1 - f[:, 1, None]) + c[:, 1] * f[:, 1, None]  # along y: [N, 2]
    return c[:, 0] * (1 - f[:, 2]) + c[:, 1] * f[:, 2]


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
