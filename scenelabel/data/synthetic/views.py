"""Cameras and rays: :func:`look_at` camera poses, :func:`pixel_rays` through every pixel, and
the exact rendering of one view (:func:`render_view`: colour, labels and depth; no NeRF involved).
"""

from __future__ import annotations

import numpy as np

from scenelabel.data.synthetic.geometry import SyntheticScene, cast_rays, shade_hits
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import opengl_to_opencv
from scenelabel.geometry.rays import camera_directions_from_pixels

__all__ = ["SUPERSAMPLE", "look_at", "pixel_rays", "render_view"]

SUPERSAMPLE = 2  # colour is averaged over SUPERSAMPLE x SUPERSAMPLE sub-pixel rays


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
