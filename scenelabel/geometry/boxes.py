"""Rays against axis-aligned boxes: one slab test (Kay & Kajiya 1986), numpy only (its torch twin,
:func:`scenelabel.render.sampling.ray_aabb_intersect`, follows the same rule).

A box is ``lo``, ``hi`` (its min and max corners) or ``aabb = [lo, hi]`` [2, 3]. Along each axis
a ray ``origins + t * directions`` is inside the slab ``lo <= x <= hi`` for t between the two
plane crossings; a direction component of exactly 0 is parallel to that slab: inside it for every
t (-inf, +inf) when the origin lies within the slab (faces included), for none (+inf, -inf)
otherwise. No eps: a parallel ray is decided exactly, every other one by IEEE division. The line
meets the box from ``t_enter`` (the largest entry) to ``t_exit`` (the smallest exit), a miss when
``t_exit < t_enter``. Distances are in multiples of ``directions`` (world units for unit ones).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["box_corners", "slab_distances", "ray_box_distances"]


def box_corners(aabb: Any) -> np.ndarray:
    """[8, 3] float64 corners of the box ``aabb`` [2, 3]: x slowest, z fastest
    ((lo, lo, lo), (lo, lo, hi), (lo, hi, lo), ..., (hi, hi, hi) per axis)."""
    aabb = np.asarray(aabb, np.float64).reshape(2, 3)
    return np.stack(np.meshgrid(*aabb.T, indexing="ij"), -1).reshape(-1, 3)


def slab_distances(origins: Any, directions: Any, lo: Any, hi: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis entry and exit distances of rays through the slabs of the box [lo, hi].

    Args:
        origins, directions: [R, 3] (directions need not be unit; zero components are fine).
        lo, hi: [3] box corners.
    Returns:
        enter, exit: [R, 3] float64; the ray is inside slab a for enter[:, a] <= t <= exit[:, a].
    """
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - origins) / directions  # [R, 3]
        tb = (hi - origins) / directions
    parallel = directions == 0
    within = (origins >= lo) & (origins <= hi)
    enter = np.where(parallel, np.where(within, -np.inf, np.inf), np.minimum(ta, tb))
    exit_ = np.where(parallel, np.where(within, np.inf, -np.inf), np.maximum(ta, tb))
    return enter, exit_


def ray_box_distances(origins: Any, directions: Any, lo: Any, hi: Any) -> tuple[np.ndarray, np.ndarray]:
    """Where rays' lines cross the box [lo, hi] (extended both ways).

    Args:
        origins, directions: [R, 3] rays.
        lo, hi: [3] box corners.
    Returns:
        t_enter, t_exit: [R] float64; ``t_exit < t_enter`` where the line misses the box.
    """
    enter, exit_ = slab_distances(origins, directions, lo, hi)
    return enter.max(-1), exit_.min(-1)
