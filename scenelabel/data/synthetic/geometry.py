"""Scene geometry as data and its exact ray caster.

A scene is a list of labelled axis-aligned boxes (:class:`Box`) plus one texture function per
class (:class:`SyntheticScene`). One exact ray caster (:func:`cast_rays`, ray/AABB slabs in
float64, vectorised over rays) finds the nearest hits; :func:`shade_hits` colours them.

World frame: z up, metres. Lighting is view-independent (wrapped Lambertian shading from one
fixed directional light plus ambient), so every surface point has one colour from every view.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.boxes import slab_distances

__all__ = [
    "BACKGROUND_ID",
    "BACKGROUND_RGB",
    "AABB_PAD",
    "HIT_EPS",
    "LIGHT_DIR",
    "AMBIENT",
    "Texture",
    "Box",
    "ClassInfo",
    "SyntheticScene",
    "RayHits",
    "cast_rays",
    "shade_hits",
]

BACKGROUND_ID = 255  # label of rays that hit nothing (also the scenes' ignore_index)
BACKGROUND_RGB = (1.0, 1.0, 1.0)  # colour of rays that hit nothing
AABB_PAD = 0.05  # scene aabb = geometry bounds padded by 5% of the largest extent
HIT_EPS = 1e-9  # hits closer than this (at or behind the origin) are not hits

# Lighting: one directional light (world, towards the light) + ambient, "wrapped" Lambertian
# (half-Lambert) so that the six faces of a box all get different brightness.
LIGHT_DIR = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
AMBIENT = 0.35

Texture = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (points [n,3], normals [n,3]) -> albedo [n,3]


@dataclass(frozen=True)
class Box:
    """A labelled axis-aligned box: ``lo`` <= x <= ``hi`` (world units); ``part`` is a free name."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    class_id: int
    part: str = ""


@dataclass(frozen=True)
class ClassInfo:
    """One entry of classes.json: external id, name, display colour (0-255 RGB)."""

    id: int
    name: str
    color: tuple[int, int, int]


@dataclass(frozen=True)
class SyntheticScene:
    """A scene definition as data: boxes, class vocabulary and per-class textures.

    ``classes`` may list classes that no box carries (they never appear in the labels).
    """

    name: str
    boxes: tuple[Box, ...]
    classes: tuple[ClassInfo, ...]
    textures: dict[int, Texture]
    frame_id: str
    ignore_index: int = BACKGROUND_ID
    background_rgb: tuple[float, float, float] = BACKGROUND_RGB

    @property
    def bounds(self) -> np.ndarray:
        """[2, 3] tight bounds (min corner, max corner) of all boxes."""
        lo = np.array([b.lo for b in self.boxes], dtype=np.float64).min(axis=0)
        hi = np.array([b.hi for b in self.boxes], dtype=np.float64).max(axis=0)
        return np.stack([lo, hi])

    @property
    def aabb(self) -> np.ndarray:
        """[2, 3] bounds padded on every side by AABB_PAD x the largest extent."""
        bounds = self.bounds
        pad = AABB_PAD * float((bounds[1] - bounds[0]).max())
        return bounds + np.array([[-pad], [pad]])

    @property
    def present_ids(self) -> list[int]:
        """Sorted class ids carried by at least one box."""
        return sorted({b.class_id for b in self.boxes})


class RayHits(NamedTuple):
    """Nearest hits of a batch of rays (n rays).

    depth: [n] float64 distance along the unit direction; 0 where the ray misses.
    class_id: [n] int64 class id of the hit box; ``miss_label`` where the ray misses.
    normal: [n, 3] float64 unit normal of the hit face, facing the ray (n . d < 0); 0 on a miss.
    hit_point: [n, 3] float64 origin + depth * unit direction; NaN on a miss.
    """

    depth: np.ndarray
    class_id: np.ndarray
    normal: np.ndarray
    hit_point: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """[n] bool: the ray hit a box."""
        return self.depth > 0


# --------------------------------------------------------------------------------------------
# Ray casting and shading


def _ray_box(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """n rays against one box (the slab rule of :mod:`scenelabel.geometry.boxes`).

    Returns (t [n] first surface crossing ahead of the origin, inf if none; axis [n] of the
    crossed face). A ray starting inside the box hits the box's inside at its exit face.
    """
    t_enter, t_exit = slab_distances(origins, directions, lo, hi)  # [n, 3] per axis
    enter_axis = t_enter.argmax(axis=1)
    exit_axis = t_exit.argmin(axis=1)
    t_near = np.take_along_axis(t_enter, enter_axis[:, None], 1)[:, 0]
    t_far = np.take_along_axis(t_exit, exit_axis[:, None], 1)[:, 0]
    crosses = (t_near <= t_far) & (t_far > HIT_EPS)
    from_outside = t_near > HIT_EPS
    t = np.where(crosses, np.where(from_outside, t_near, t_far), np.inf)
    axis = np.where(from_outside, enter_axis, exit_axis)
    return t, axis


def cast_rays(
    origins: np.ndarray, directions: np.ndarray, boxes, miss_label: int = BACKGROUND_ID
) -> RayHits:
    """Exact nearest hit of each ray among labelled boxes (float64).

    Args:
        origins: [n, 3] ray origins (world).
        directions: [n, 3] ray directions; normalised here (depth is along the unit direction).
        boxes: sequence of :class:`Box`.
        miss_label: class id reported for rays that hit nothing.
    Returns:
        :class:`RayHits`. Ties at equal depth go to the earlier box in ``boxes``.
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if origins.shape != directions.shape:
        raise InputError(f"origins {origins.shape} and directions {directions.shape} differ", field="directions")
    norm = np.linalg.norm(directions, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise InputError("ray directions must be non-zero", field="directions")
    directions = directions / norm
    n = len(origins)
    best_t = np.full(n, np.inf)
    best_class = np.full(n, miss_label, dtype=np.int64)
    best_axis = np.zeros(n, dtype=np.int64)
    for box in boxes:
        t, axis = _ray_box(origins, directions, np.asarray(box.lo, np.float64), np.asarray(box.hi, np.float64))
        closer = t < best_t
        best_t = np.where(closer, t, best_t)
        best_class = np.where(closer, box.class_id, best_class)
        best_axis = np.where(closer, axis, best_axis)
    hit = np.isfinite(best_t)
    depth = np.where(hit, best_t, 0.0)
    normal = np.zeros((n, 3))
    d_axis = directions[np.arange(n), best_axis]
    normal[np.arange(n), best_axis] = np.where(hit, -np.sign(d_axis), 0.0)
    hit_point = np.where(hit[:, None], origins + depth[:, None] * directions, np.nan)
    return RayHits(depth=depth, class_id=best_class, normal=normal, hit_point=hit_point)


def shade_hits(hits: RayHits, scene: SyntheticScene) -> np.ndarray:
    """View-independent colour of each hit: albedo(class texture) x wrapped Lambertian light.

    Returns:
        [n, 3] float64 RGB in [0, 1]; ``scene.background_rgb`` where the ray missed.
    """
    n = len(hits.depth)
    rgb = np.empty((n, 3))
    rgb[:] = scene.background_rgb
    hit = hits.hit
    light = AMBIENT + (1.0 - AMBIENT) * 0.5 * (1.0 + hits.normal @ LIGHT_DIR)  # [n]
    for class_id in np.unique(hits.class_id[hit]).tolist():
        sel = hit & (hits.class_id == class_id)
        albedo = scene.textures[class_id](hits.hit_point[sel], hits.normal[sel])
        rgb[sel] = albedo * light[sel, None]
    return np.clip(rgb, 0.0, 1.0)
