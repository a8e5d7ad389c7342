"""How many views see each point of a scene's observed geometry: the evidence its depth rests on.

A surface point inside the image of one or two training views has its depth fixed by little more
than those views' colours; the build gathers ray weights into sharp surfaces (the distortion
term) only where most of the observed geometry is seen by more views than that
(``train.distortion_weight = "auto"``, docs/models.md). Occlusion is not tested: a view counts
when the point projects inside its image, in front of the camera.
"""

from __future__ import annotations

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lens import inside_image, project_points

__all__ = ["THIN_VIEWS", "views_seeing_points", "thinly_seen_fraction"]

THIN_VIEWS = 3
"""A point inside the images of fewer views than this is thinly seen: one or two views fix its depth."""


def views_seeing_points(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """How many of ``cameras`` have each point inside their image, in front of the lens.

    Args:
        cameras: n cameras (any lens model of :mod:`scenelabel.geometry.lens`).
        points: [k, 3] world points.
    Returns:
        [k] int64 counts in 0..n.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape [k, 3], got {points.shape}", field="points")
    count = np.zeros(len(points), dtype=np.int64)
    for i in range(len(cameras)):
        uv, _, _ = project_points(
            points, cameras.c2w[i], cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i],
            cameras.distortion[i], cameras.model[i],
        )  # [k, 2], NaN where the lens does not project the point
        count += inside_image(uv, cameras.width[i], cameras.height[i])
    return count


def thinly_seen_fraction(cameras: Cameras, points: np.ndarray, views: int = THIN_VIEWS) -> float:
    """The fraction of ``points`` [k, 3] inside the images of fewer than ``views`` cameras
    (:func:`views_seeing_points`); 1.0 for no points (nothing is known to be well seen)."""
    counts = views_seeing_points(cameras, points)
    return float(np.mean(counts < views)) if len(counts) else 1.0
