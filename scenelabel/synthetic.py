"""Analytic scenes with exact labels and depth: the toy two-box scene and a furnished room.

A scene is a list of labelled axis-aligned boxes (:class:`Box`) plus one texture function per
class. One exact ray caster (:func:`cast_rays`, ray/AABB slabs in float64, vectorised over rays)
renders colour, labels and depth for both scene definitions; no NeRF is involved. The writers
produce a scene folder in the ``transforms.json`` layout (see docs/conventions.md)::

    images/NNN.png      RGB 8-bit, 2x2 supersampled colour
    labels/NNN.png      single-channel 8-bit external class ids (ignore_index 255 = background)
    depths/NNN.npy      float32 [h, w] distance along the unit ray; 0 = no surface (background)
    classes.json        {"classes": [{"id", "name", "color"}...], "ignore_index": 255}
    transforms.json     nerfstudio convention: OpenGL camera-to-world ``transform_matrix``

Views form one closed, interleaved camera path, so that the project's default hold-out (every
8th view, ``index % 8 == 0``) picks views lying *between* training views (interpolations).

World frame: z up, metres. Lighting is view-independent (wrapped Lambertian shading from one
fixed directional light plus ambient), so every surface point has one colour from every view.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from PIL import Image

from .errors import InputError
from .io.transforms_json import opengl_to_opencv
from .rays import camera_directions_from_pixels

__all__ = [
    "BACKGROUND_ID",
    "HOLDOUT_EVERY",
    "ROOM_BOXES",
    "ROOM_CLASSES",
    "TOY_BOXES",
    "TOY_CLASSES",
    "Box",
    "ClassInfo",
    "RayHits",
    "SyntheticScene",
    "cast_rays",
    "corrupt_labels",
    "furnished_room_geometry",
    "look_at",
    "pixel_rays",
    "render_view",
    "room_cameras",
    "shade_hits",
    "toy_cameras",
    "toy_scene_geometry",
    "write_furnished_room",
    "write_scene",
    "write_toy_scene",
]

BACKGROUND_ID = 255  # label of rays that hit nothing (also the scenes' ignore_index)
HOLDOUT_EVERY = 8  # the project's default hold-out: views with index % 8 == 0 are test views
BACKGROUND_RGB = (1.0, 1.0, 1.0)  # colour of rays that hit nothing
SUPERSAMPLE = 2  # colour is averaged over SUPERSAMPLE x SUPERSAMPLE sub-pixel rays
AABB_PAD = 0.05  # scene aabb = geometry bounds padded by 5% of the largest extent
NEAR_FACTOR, FAR_FACTOR = 0.8, 1.2  # per-frame near/far = factor * min/max true depth
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
    """Slab test of n rays against one box.

    Returns (t [n] first surface crossing ahead of the origin, inf if none; axis [n] of the
    crossed face). A ray starting inside the box hits the box's inside at its exit face.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - origins) / directions  # [n, 3]
        t2 = (hi - origins) / directions
    t_enter = np.minimum(t1, t2)
    t_exit = np.maximum(t1, t2)
    parallel = directions == 0
    if parallel.any():
        inside_slab = (origins >= lo) & (origins <= hi)
        t_enter = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), t_enter)
        t_exit = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), t_exit)
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


# --------------------------------------------------------------------------------------------
# Cameras and rays


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """[4, 4] camera-to-world with **OpenGL axes** (x right, y up, looking down -z) at ``eye``."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise InputError("look_at: viewing direction is parallel to up", field="target")
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, -forward, eye
    return c2w


def pixel_rays(
    c2w_opengl: np.ndarray, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
    offsets: tuple[float, float] = (0.5, 0.5),
) -> tuple[np.ndarray, np.ndarray]:
    """World rays through the point (col + ox, row + oy) of every pixel (pixel centre: 0.5, 0.5).

    Camera-frame direction (OpenCV axes) ``((u - cx) / fx, (v - cy) / fy, 1)``, rotated by
    ``c2w_opengl @ diag(1, -1, -1, 1)`` and normalised (docs/conventions.md).

    Returns:
        origins [height, width, 3], unit directions [height, width, 3] (float64).
    """
    c2w_cv = opengl_to_opencv(c2w_opengl)
    u = np.arange(width, dtype=np.float64) + offsets[0]
    v = np.arange(height, dtype=np.float64) + offsets[1]
    uu, vv = np.meshgrid(u, v)  # [h, w]
    d_cam = camera_directions_from_pixels(np.stack([uu.ravel(), vv.ravel()], -1), fx, fy, cx, cy)
    d_world = (d_cam @ c2w_cv[:3, :3].T).reshape(height, width, 3)
    d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
    origins = np.broadcast_to(c2w_cv[:3, 3], d_world.shape).copy()
    return origins, d_world


def render_view(
    scene: SyntheticScene, c2w_opengl: np.ndarray, fx: float, fy: float, cx: float, cy: float,
    width: int, height: int, supersample: int = SUPERSAMPLE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one view exactly.

    Colour is the mean of ``supersample``² sub-pixel rays; labels and depth are taken by the
    ray through the pixel centre.

    Returns:
        rgb [h, w, 3] float64 in [0, 1], labels [h, w] int64 (ignore_index on background),
        depth [h, w] float64 along the unit ray (0 on background).
    """
    rgb = np.zeros((height, width, 3))
    subs = (np.arange(supersample) + 0.5) / supersample
    for oy in subs:
        for ox in subs:
            o, d = pixel_rays(c2w_opengl, fx, fy, cx, cy, width, height, (ox, oy))
            hits = cast_rays(o.reshape(-1, 3), d.reshape(-1, 3), scene.boxes, scene.ignore_index)
            rgb += shade_hits(hits, scene).reshape(height, width, 3)
    rgb /= supersample**2
    o, d = pixel_rays(c2w_opengl, fx, fy, cx, cy, width, height)
    hits = cast_rays(o.reshape(-1, 3), d.reshape(-1, 3), scene.boxes, scene.ignore_index)
    return rgb, hits.class_id.reshape(height, width), hits.depth.reshape(height, width)


# --------------------------------------------------------------------------------------------
# Textures (smooth, low-frequency, learnable by a small NeRF)


def _soft_checker(a: np.ndarray, b: np.ndarray, period: float, sharpness: float = 2.5) -> np.ndarray:
    """Soft-edged checker in [0, 1] over coordinates a, b with the given period (world units)."""
    s = np.sin(2 * np.pi * a / period) * np.sin(2 * np.pi * b / period)
    return 0.5 + 0.5 * np.tanh(sharpness * s) / np.tanh(sharpness)


def _blend(t: np.ndarray, c0, c1) -> np.ndarray:
    """[n, 3] linear blend of two colours by t [n] in [0, 1]."""
    return (1.0 - t)[:, None] * np.asarray(c0, np.float64) + t[:, None] * np.asarray(c1, np.float64)


def _face_coords(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two in-face coordinates of points on axis-aligned faces (drop the normal's axis)."""
    axis = np.abs(normals).argmax(axis=1)
    a = np.where(axis == 0, points[:, 1], points[:, 0])
    b = np.where(axis == 2, points[:, 1], points[:, 2])
    return a, b


def _plain_with_stripes(color, amplitude: float = 0.08, period: float = 0.25) -> Texture:
    """Plain colour modulated by a subtle diagonal sinusoid on each face."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, b = _face_coords(points, normals)
        mod = 1.0 + amplitude * np.sin(2 * np.pi * (a + b) / period)
        return np.asarray(color, np.float64)[None] * mod[:, None]

    return texture


def _checker_texture(c0, c1, period: float) -> Texture:
    """Soft checker between two colours on each face."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, b = _face_coords(points, normals)
        return _blend(_soft_checker(a, b, period), c0, c1)

    return texture


def _wood_texture(c0, c1, period: float, along_axis: int = 0) -> Texture:
    """Smooth plank-like bands across ``along_axis`` with a slow wobble."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        other = 1 - along_axis if along_axis < 2 else 0
        x = points[:, along_axis] + 0.04 * np.sin(2 * np.pi * points[:, other] / 1.3)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * x / period)
        return _blend(t, c0, c1)

    return texture


def _wall_texture(c0, c1, period: float) -> Texture:
    """Soft vertical stripes along the wall plus a gentle vertical gradient."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, _ = _face_coords(points, normals)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * a / period)
        base = _blend(t, c0, c1)
        return base * (0.92 + 0.08 * np.clip(points[:, 2] / 2.6, 0, 1))[:, None]

    return texture


# --------------------------------------------------------------------------------------------
# Scene definitions


def toy_scene_geometry() -> SyntheticScene:
    """The toy two-box scene (world z up, metres).

    Floor (id 1): slab [-1.5, 1.5]² x [-0.02, 0], top at z = 0. box_red (id 3):
    [-0.7, -0.2] x [-0.5, 0.0] x [0, 0.6]. box_blue (id 7): [0.1, 0.7] x [0.0, 0.5] x [0, 0.4].
    classes.json also lists chair (id 5), which no box carries. Background: white, label 255.
    """
    boxes = (
        Box((-1.5, -1.5, -0.02), (1.5, 1.5, 0.0), 1, "floor"),
        Box((-0.7, -0.5, 0.0), (-0.2, 0.0, 0.6), 3, "box_red"),
        Box((0.1, 0.0, 0.0), (0.7, 0.5, 0.4), 7, "box_blue"),
    )
    classes = (
        ClassInfo(1, "floor", (190, 170, 130)),
        ClassInfo(3, "box_red", (220, 40, 40)),
        ClassInfo(5, "chair", (40, 200, 60)),
        ClassInfo(7, "box_blue", (40, 80, 230)),
    )
    textures = {
        1: _checker_texture((0.82, 0.76, 0.62), (0.56, 0.52, 0.44), period=0.5),
        3: _plain_with_stripes((0.88, 0.22, 0.16)),
        7: _plain_with_stripes((0.22, 0.38, 0.90)),
    }
    return SyntheticScene("toy_two_box", boxes, classes, textures, frame_id="toy_world")


ROOM_HALF = 3.0  # room interior [-3, 3]² x [0, ROOM_HEIGHT]
ROOM_HEIGHT = 2.6
ROOM_SLAB = 0.1  # thickness of walls, floor and ceiling slabs


def furnished_room_geometry() -> SyntheticScene:
    """A 6 x 6 x 2.6 m furnished room (interior [-3, 3]² x [0, 2.6]); cameras go inside.

    Classes (non-contiguous ids): floor 1, wall 2, ceiling 4, table 6, sofa 9, cabinet 12,
    lamp 20. The lamp pole is 5 cm thick (a thin obstacle).
    """
    h, s, top = ROOM_HALF, ROOM_SLAB, ROOM_HEIGHT
    boxes = [
        Box((-h - s, -h - s, -s), (h + s, h + s, 0.0), 1, "floor"),
        Box((-h - s, -h - s, top), (h + s, h + s, top + s), 4, "ceiling"),
        Box((-h - s, -h - s, 0.0), (-h, h + s, top), 2, "wall_x-"),
        Box((h, -h - s, 0.0), (h + s, h + s, top), 2, "wall_x+"),
        Box((-h, -h - s, 0.0), (h, -h, top), 2, "wall_y-"),
        Box((-h, h, 0.0), (h, h + s, top), 2, "wall_y+"),
        # table in the middle: top + four 5 cm legs
        Box((-0.6, -0.4, 0.72), (0.6, 0.4, 0.76), 6, "table_top"),
    ]
    for x0 in (-0.57, 0.52):
        for y0 in (-0.37, 0.32):
            boxes.append(Box((x0, y0, 0.0), (x0 + 0.05, y0 + 0.05, 0.72), 6, "table_leg"))
    boxes += [
        # sofa against the y+ wall
        Box((-1.2, 2.0, 0.0), (1.2, 2.95, 0.45), 9, "sofa_seat"),
        Box((-1.2, 2.7, 0.45), (1.2, 2.95, 0.9), 9, "sofa_back"),
        Box((-1.2, 2.0, 0.45), (-1.0, 2.7, 0.65), 9, "sofa_arm"),
        Box((1.0, 2.0, 0.45), (1.2, 2.7, 0.65), 9, "sofa_arm"),
        # cabinet against the x+ wall
        Box((2.5, -1.5, 0.0), (3.0, -0.3, 1.8), 12, "cabinet"),
        # floor lamp next to the sofa: base, 5 cm pole, shade
        Box((-1.9, 2.15, 0.0), (-1.55, 2.5, 0.04), 20, "lamp_base"),
        Box((-1.75, 2.3, 0.04), (-1.7, 2.35, 1.6), 20, "lamp_pole"),
        Box((-1.95, 2.1, 1.6), (-1.5, 2.55, 1.9), 20, "lamp_shade"),
    ]
    classes = (
        ClassInfo(1, "floor", (160, 110, 60)),
        ClassInfo(2, "wall", (200, 200, 170)),
        ClassInfo(4, "ceiling", (235, 235, 255)),
        ClassInfo(6, "table", (120, 60, 20)),
        ClassInfo(9, "sofa", (40, 170, 80)),
        ClassInfo(12, "cabinet", (50, 100, 220)),
        ClassInfo(20, "lamp", (240, 200, 20)),
    )
    textures = {
        1: _wood_texture((0.80, 0.63, 0.42), (0.66, 0.50, 0.32), period=0.45, along_axis=1),
        2: _wall_texture((0.88, 0.85, 0.78), (0.76, 0.78, 0.72), period=0.8),
        4: _checker_texture((0.97, 0.97, 0.97), (0.86, 0.86, 0.90), period=1.0),
        6: _wood_texture((0.45, 0.28, 0.16), (0.36, 0.21, 0.12), period=0.2, along_axis=0),
        9: _checker_texture((0.25, 0.58, 0.36), (0.18, 0.45, 0.28), period=0.4),
        12: _plain_with_stripes((0.30, 0.46, 0.74), amplitude=0.1, period=0.3),
        20: _plain_with_stripes((0.95, 0.80, 0.30), amplitude=0.05, period=0.2),
    }
    return SyntheticScene("furnished_room", tuple(boxes), classes, textures, frame_id="room_world")


_TOY = toy_scene_geometry()
TOY_BOXES: tuple[Box, ...] = _TOY.boxes
TOY_CLASSES: tuple[ClassInfo, ...] = _TOY.classes
_ROOM = furnished_room_geometry()
ROOM_BOXES: tuple[Box, ...] = _ROOM.boxes
ROOM_CLASSES: tuple[ClassInfo, ...] = _ROOM.classes


# --------------------------------------------------------------------------------------------
# Camera paths (closed loops: view i sits between views i - 1 and i + 1)


def _check_split(n_train: int, n_test: int) -> int:
    """Total view count; n_test must be the number of views with index % HOLDOUT_EVERY == 0."""
    n_total = n_train + n_test
    if n_train < 1 or n_test < 0:
        raise InputError(f"need n_train >= 1 and n_test >= 0, got {n_train}, {n_test}", field="n_train")
    expected = len(range(0, n_total, HOLDOUT_EVERY))
    if n_test != expected:
        raise InputError(
            f"every {HOLDOUT_EVERY}th view is held out, so {n_total} views give {expected} test views, "
            f"not {n_test} (e.g. n_train={n_total - expected}, n_test={expected})",
            field="n_test",
        )
    return n_total


def toy_cameras(n_views: int, seed: int = 0) -> np.ndarray:
    """[n, 4, 4] OpenGL camera-to-world on a closed orbit around the toy scene.

    Radius 2.6-3.0 m, height 1.3-2.2 m, looking at a point near (0, 0, 0.2); evenly spaced
    azimuths (jittered by up to a quarter step with ``seed``), so every view is between its
    neighbours.
    """
    rng = np.random.default_rng(seed)
    i = np.arange(n_views)
    phase = 2 * np.pi * i / n_views
    azimuth = phase + rng.uniform(0, 2 * np.pi) + rng.uniform(-0.25, 0.25, n_views) * 2 * np.pi / n_views
    radius = 2.8 + 0.2 * np.sin(3 * phase + rng.uniform(0, 2 * np.pi))
    height = 1.75 + 0.45 * np.sin(2 * phase + rng.uniform(0, 2 * np.pi))
    targets = np.array([0.0, 0.0, 0.2]) + rng.uniform(-0.05, 0.05, (n_views, 3))
    eyes = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), height], axis=-1)
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


def room_cameras(n_views: int, seed: int = 0, scene: SyntheticScene | None = None) -> np.ndarray:
    """[n, 4, 4] OpenGL camera-to-world on a closed loop inside the furnished room.

    Cameras circle the table at 1.5-2.0 m from the room centre, heights 1.0-1.8 m, and look
    across the room at targets that swing between walls and furniture, tilting up and down
    from one view to the next (target heights 0.1-2.3 m) like a person scanning a room, so the
    ceiling and the floor behind furniture are seen by training views too: at least 99% of the
    held-out views' labelled pixels are seen by a training view (every 8th view held out,
    seeds 0 and 1; tests/test_synthetic.py checks the ceiling).
    """
    scene = _ROOM if scene is None else scene
    rng = np.random.default_rng(seed)
    i = np.arange(n_views)
    phase = 2 * np.pi * i / n_views
    azimuth = phase + rng.uniform(0, 2 * np.pi) + rng.uniform(-0.2, 0.2, n_views) * 2 * np.pi / n_views
    radius = 1.75 + 0.25 * np.sin(3 * phase + rng.uniform(0, 2 * np.pi))
    height = 1.4 + 0.4 * np.sin(2 * phase + rng.uniform(0, 2 * np.pi))
    eyes = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), height], axis=-1)
    swing = 0.8 * np.sin(5 * phase)  # look direction swings +-0.8 rad around "across the room"
    look_az = azimuth + np.pi + swing
    target_dist = 2.0
    targets = np.stack(
        [
            eyes[:, 0] + target_dist * np.cos(look_az),
            eyes[:, 1] + target_dist * np.sin(look_az),
            1.2 + 1.1 * np.sin(17 * phase + 1.0),  # 17 cycles per loop: neighbours alternate up / down
        ],
        axis=-1,
    )
    margin = 0.2
    for eye in eyes:
        for box in scene.boxes:
            if np.all(eye > np.asarray(box.lo) - margin) and np.all(eye < np.asarray(box.hi) + margin):
                raise AssertionError(f"room camera at {eye} is within {margin} m of {box.part}")
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


# --------------------------------------------------------------------------------------------
# Writers


def _focal_from_fov(width: int, fov_x_deg: float) -> float:
    return (width / 2.0) / math.tan(math.radians(fov_x_deg) / 2.0)


def write_scene(
    path: str | Path, scene: SyntheticScene, c2ws: np.ndarray, width: int, height: int,
    fov_x_deg: float = 50.0, bounds_in_file: bool = True,
) -> Path:
    """Render every camera of ``c2ws`` ([n, 4, 4] OpenGL) and write the scene folder.

    With ``bounds_in_file`` (default), every frame gets ``near``/``far`` and the file a top-level
    ``aabb`` (:attr:`SyntheticScene.aabb`): per-frame near/far are NEAR_FACTOR x min and
    FAR_FACTOR x max of the true depth over the frame's hit pixels (background ignored); a frame
    that sees nothing gets the range of the scene's aabb corners. With ``bounds_in_file=False``
    neither per-frame near/far nor ``aabb`` is written, like users' files (nerfstudio never
    writes them); everything else is identical. Returns the folder path.
    """
    if width < 1 or height < 1:
        raise InputError(f"image size must be positive, got {width}x{height}", field="width")
    root = Path(path)
    for sub in ("images", "labels", "depths"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    f = _focal_from_fov(width, fov_x_deg)
    cx, cy = width / 2.0, height / 2.0
    aabb = scene.aabb
    corners = np.array([[aabb[a][0], aabb[b][1], aabb[c][2]] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    frames = []
    digits = max(3, len(str(len(c2ws) - 1)))
    for index, c2w in enumerate(c2ws):
        rgb, labels, depth = render_view(scene, c2w, f, f, cx, cy, width, height)
        name = f"{index:0{digits}d}"
        Image.fromarray(np.round(rgb * 255.0).astype(np.uint8)).save(root / "images" / f"{name}.png")
        Image.fromarray(labels.astype(np.uint8)).save(root / "labels" / f"{name}.png")
        np.save(root / "depths" / f"{name}.npy", depth.astype(np.float32))
        hit_depth = depth[depth > 0]
        if hit_depth.size:
            near, far = NEAR_FACTOR * hit_depth.min(), FAR_FACTOR * hit_depth.max()
        else:
            dist = np.linalg.norm(corners - c2w[:3, 3], axis=1)
            near, far = max(1e-3, NEAR_FACTOR * dist.min()), FAR_FACTOR * dist.max()
        frame = {
            "file_path": f"images/{name}.png",
            "label_path": f"labels/{name}.png",
            "depth_path": f"depths/{name}.npy",
            "transform_matrix": np.asarray(c2w, np.float64).tolist(),
        }
        if bounds_in_file:
            frame["near"], frame["far"] = float(near), float(far)
        frames.append(frame)
    transforms = {
        "camera_model": "PINHOLE",
        "fl_x": f,
        "fl_y": f,
        "cx": cx,
        "cy": cy,
        "w": int(width),
        "h": int(height),
        "frame_id": scene.frame_id,
        "aabb": aabb.tolist(),
        "frames": frames,
    }
    if not bounds_in_file:
        del transforms["aabb"]
    classes = {
        "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in scene.classes],
        "ignore_index": scene.ignore_index,
    }
    (root / "transforms.json").write_text(json.dumps(transforms, indent=2))
    (root / "classes.json").write_text(json.dumps(classes, indent=2))
    return root


def write_toy_scene(
    path: str | Path, n_train: int = 28, n_test: int = 4, width: int = 96, height: int = 72, seed: int = 0
) -> Path:
    """Write the toy two-box scene (:func:`toy_scene_geometry`) to ``path``.

    ``n_train + n_test`` views on one interleaved orbit; views with index % 8 == 0 are the
    held-out ones, so ``n_test`` must equal their count (4 for 32 views). Horizontal FOV 50°.
    Deterministic for a seed. Returns the folder path.
    """
    n_total = _check_split(n_train, n_test)
    return write_scene(path, _TOY, toy_cameras(n_total, seed), width, height)


def write_furnished_room(
    path: str | Path, n_train: int = 35, n_test: int = 5, width: int = 160, height: int = 120, seed: int = 0
) -> Path:
    """Write the furnished room (:func:`furnished_room_geometry`) to ``path``.

    40 views by default (every 8th held out: 5 test views), cameras inside the room, so every
    ray hits a surface. Horizontal FOV 50°. Deterministic for a seed. Returns the folder path.
    """
    n_total = _check_split(n_train, n_test)
    return write_scene(path, _ROOM, room_cameras(n_total, seed), width, height)


# --------------------------------------------------------------------------------------------
# Label noise (what a real 2D segmenter's mistakes look like: blobs of a wrong class)


def corrupt_labels(
    label: np.ndarray, fraction: float, class_ids, rng: np.random.Generator, ignore_index: int | None = BACKGROUND_ID
) -> np.ndarray:
    """A copy of ``label`` with random discs of wrong classes over ~``fraction`` of its labelled pixels.

    Discs (radius 3-12% of the image's shorter side) are painted one by one, each with a class
    drawn from ``class_ids``; a pixel counts as corrupted once its class differs from the
    original. Painting stops as soon as at least ``fraction`` of the labelled (not
    ``ignore_index``) pixels are corrupted, so the result is within one disc of the target.

    Args:
        label: [H, W] int class ids.
        fraction: in [0, 1).
        class_ids: the classes the blobs may take (at least two).
        rng: numpy Generator (deterministic for a seed).
    Returns:
        [H, W] int64.
    """
    if not 0.0 <= fraction < 1.0:
        raise InputError(f"fraction must be in [0, 1), got {fraction}", field="fraction")
    class_ids = np.asarray(sorted(set(int(c) for c in class_ids)), dtype=np.int64)
    if len(class_ids) < 2:
        raise InputError("corrupting labels needs at least two classes", field="class_ids")
    original = np.asarray(label, dtype=np.int64)
    out = original.copy()
    labelled = original != ignore_index if ignore_index is not None else np.ones(original.shape, bool)
    n_labelled = int(labelled.sum())
    h, w = original.shape
    rows, cols = np.mgrid[0:h, 0:w]
    short = min(h, w)
    while n_labelled and ((out != original) & labelled).sum() < fraction * n_labelled:
        r = rng.uniform(0.03, 0.12) * short
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        disc = ((rows - cy) ** 2 + (cols - cx) ** 2 <= r * r) & labelled
        out[disc] = rng.choice(class_ids)
    return out
