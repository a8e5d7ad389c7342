"""How many views see each point of a scene's observed geometry: the evidence its depth rests on;
and where an object can be, from the views' silhouettes (:func:`visual_hull_points`).

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

__all__ = ["THIN_VIEWS", "HULL_CELLS", "HULL_PASSES", "WHOLE_BORDER_MAX", "views_seeing_points", "thinly_seen_fraction",
           "shows_whole", "visual_hull_points"]

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


HULL_CELLS = 64
"""Cells per side of each pass of :func:`visual_hull_points`."""
HULL_PASSES = 3
"""Passes of :func:`visual_hull_points`, each on the bounds the previous one left: the last pass's
cells are about HULL_CELLS ** -HULL_PASSES of the first box (a 30 m frusta box: well under a cm)."""
WHOLE_BORDER_MAX = 0.01
"""A silhouette shows its object whole (:func:`shows_whole`) when at most this fraction of its border
pixels show something: the object is inside the image, not cut by its edge."""


def shows_whole(silhouette: np.ndarray) -> bool:
    """Whether a silhouette [h, w] bool (True: the pixel shows something) has its object inside the
    image: at most WHOLE_BORDER_MAX of the pixels on the image's border show something."""
    border = np.concatenate([silhouette[0], silhouette[-1], silhouette[1:-1, 0], silhouette[1:-1, -1]])
    return bool(np.mean(border) <= WHOLE_BORDER_MAX)


def visual_hull_points(
    cameras: Cameras, silhouettes: list[np.ndarray], box: np.ndarray, cells: int = HULL_CELLS, passes: int = HULL_PASSES
) -> np.ndarray | None:
    """Where an object that every view shows whole can be (its visual hull, carved from the
    silhouettes as in space carving): the centres of the cells of a ``cells``³ grid over ``box``
    that project, in every view, inside the image onto a pixel of the silhouette. Repeated
    ``passes`` times, each over the bounds of the previous pass's cells (one cell of margin, within
    ``box``). Only a cell's centre is tested, so a part thinner than a cell can be carved away: the
    result bounds the object to about a cell of the last pass.

    Args:
        cameras: n cameras (any lens model of :mod:`scenelabel.geometry.lens`).
        silhouettes: n arrays [h, w] bool at the cameras' sizes (True: the pixel shows the object;
            False: its ray meets nothing).
        box: [2, 3] world bounds to carve (min corner, max corner).
    Returns:
        [k, 3] world points, or None when no cell survives.
    """
    if len(silhouettes) != len(cameras):
        raise InputError(f"{len(silhouettes)} silhouettes for {len(cameras)} cameras", field="silhouettes")
    box = np.asarray(box, dtype=np.float64)
    for _ in range(passes):
        size = (box[1] - box[0]) / cells
        axes = [box[0, a] + (np.arange(cells) + 0.5) * size[a] for a in range(3)]
        points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        for i, silhouette in enumerate(silhouettes):
            uv, _, _ = project_points(
                points, cameras.c2w[i], cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i],
                cameras.distortion[i], cameras.model[i],
            )  # [k, 2], NaN where the lens does not project the point
            keep = inside_image(uv, cameras.width[i], cameras.height[i])
            pixels = np.floor(uv[keep]).astype(np.int64)  # pixel j covers [j, j + 1): centres at +0.5
            keep[keep] = silhouette[pixels[:, 1], pixels[:, 0]]
            points = points[keep]
        if len(points) == 0:
            return None
        box = np.stack([np.maximum(points.min(0) - size, box[0]), np.minimum(points.max(0) + size, box[1])])
    return points
