"""The vertical from straight lines in the photos: the direction that the vertical edges of a room
(wall corners, door and window frames, the sides of furniture) run along, found where their
images converge: the vertical vanishing point, the first thing single-view room-layout methods
take from a photo (Hedau, Hoiem & Forsyth, "Recovering the spatial layout of cluttered rooms",
ICCV 2009). With known poses every view's segments vote for one world direction.

Why a room's layout needs it (scenelabel.geometry.layout): the layout's planes come from where the
masks' floor-wall and wall-ceiling boundaries cut candidate planes, and a plane tilted towards the
cameras bunches those cuts more tightly than the true one, since the rays meet it less obliquely.
Seen from inside, boundaries on every side hold the tilt; a forward-facing capture sees one or two
walls, and from several starts its layout settled tilted by up to 5 degrees (docs/layout.md). A
segment's direction in the image does not depend on where the camera stands, so a narrow rig
fixes the vertical as well as a wide one.

Conventions (docs/conventions.md): cameras are :class:`scenelabel.Cameras` (OpenCV axes, world
frame, pixel centres at (col + 0.5, row + 0.5)); a segment is (u1, v1, u2, v2) in those pixels.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.rays import rays_from_cameras

__all__ = [
    "MIN_SEGMENT_SHARE",
    "MIN_VERTICAL_SEGMENTS",
    "MIN_VERTICAL_VIEWS",
    "VOTE_PASSES",
    "INLIER_DEGREES",
    "MAX_SEGMENTS",
    "MAX_SIDE",
    "MAX_VIEWS",
    "line_segments",
    "segments_at_most",
    "world_axis_across",
    "tilted",
    "segment_normals",
    "vertical_from_normals",
    "vertical_from_images",
]

MIN_SEGMENT_SHARE = 0.08
"""Segments shorter than this share of the image's shorter side are left out: a short segment's
direction is loose (an endpoint off by a tenth of a pixel turns a 10-pixel segment by half a degree)."""

MIN_VERTICAL_SEGMENTS = 20
"""The fewest segments whose planes must hold the vertical (within :data:`INLIER_DEGREES`)."""

MIN_VERTICAL_VIEWS = 3
"""The fewest views those segments must come from: one view's edges can share a direction by chance."""

VOTE_PASSES = ((20.0, 1.0, 1.0), (1.5, 0.1, 0.3), (0.15, 0.01, 0.15))
"""(half range, step, tolerance) in degrees: each pass tries the directions on a grid of tilts
about the best so far (the first about the start) and keeps the one whose plane the most segment
length lies within the tolerance of (a vertical segment's plane holds the vertical)."""

INLIER_DEGREES = 0.5
"""Segments whose plane lies within this of the voted direction refine it (least squares)."""

MAX_SEGMENTS = 20_000
"""The longest this many segments vote (the first pass holds a [segments, 41²] table)."""

MAX_SIDE = 640
"""Pixels: a larger photo is shrunk to this longer side before its segments are found (the
detector takes about 0.35 s on a 1920x1440 photo and 1.4 s at 4032x3024 on this machine class;
directions, which are all that is used, barely change with the scale)."""

MAX_VIEWS = 60
"""At most this many views (evenly spread over them) give segments."""


def line_segments(image: np.ndarray) -> np.ndarray:
    """[n, 4] the straight segments of ``image`` ([H, W, 3] float in [0, 1], or [H, W]) as OpenCV's
    line segment detector (LSD, von Gioi et al., IPOL 2012) finds them in its grey levels, at least
    :data:`MIN_SEGMENT_SHARE` of the shorter side long; (u1, v1, u2, v2) with pixel centres at
    (col + 0.5, row + 0.5) (OpenCV puts them at whole numbers)."""
    import cv2

    grey = np.asarray(image, np.float64)
    if grey.ndim == 3:
        grey = grey @ np.array([0.299, 0.587, 0.114])
    found = cv2.createLineSegmentDetector().detect(np.clip(grey * 255.0 + 0.5, 0, 255).astype(np.uint8))[0]
    if found is None:
        return np.zeros((0, 4))
    segments = found.reshape(-1, 4).astype(np.float64) + 0.5
    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    return segments[length >= MIN_SEGMENT_SHARE * min(grey.shape[:2])]


def segment_normals(cameras: Cameras, segments: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The world-frame unit normals of the planes through each camera and its segments (the
    segment's "interpretation plane": a line in the world lies in it, so a vertical line's plane
    holds the vertical), through the cameras' lens model.

    Args:
        cameras: n cameras.
        segments: n arrays [k_i, 4] (:func:`line_segments`).
    Returns:
        normals [k, 3], weights [k] (the segments' lengths in pixels), views [k] (camera index).
    """
    normals, weights, views = [np.zeros((0, 3))], [np.zeros(0)], [np.zeros(0, np.int64)]
    for index, seg in enumerate(segments):
        if len(seg) == 0:
            continue
        _, d1 = rays_from_cameras(cameras, index, seg[:, :2])
        _, d2 = rays_from_cameras(cameras, index, seg[:, 2:])
        n = np.cross(d1, d2)
        normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
        weights.append(np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]))
        views.append(np.full(len(seg), index))
    return np.concatenate(normals), np.concatenate(weights), np.concatenate(views)


def world_axis_across(up: np.ndarray) -> np.ndarray:
    """World x, or world y where ``up`` is near x: an axis far from parallel to ``up``."""
    return np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])


def tilted(up: np.ndarray, a, b) -> np.ndarray:
    """``up`` [3] (unit) turned by ``a`` and ``b`` degrees (floats, or arrays of one shape) about two
    axes normal to it: ``up x`` :func:`world_axis_across`, and ``up x`` that. Returns [..., 3] unit."""
    e1 = np.cross(up, world_axis_across(up))
    e1 = e1 - (e1 @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    v = up + np.tan(np.radians(a))[..., None] * e1 + np.tan(np.radians(b))[..., None] * e2
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tilted_grid(start: np.ndarray, half: float, step: float) -> np.ndarray:
    """[m, 3] unit directions ``start`` :func:`tilted` on a square grid of (a, b) degrees, each in
    [-half, half] at ``step``."""
    a, b = np.meshgrid(*[np.arange(-half, half + 1e-9, step)] * 2)
    return tilted(start, a.ravel(), b.ravel())


def vertical_from_normals(
    normals: np.ndarray, weights: np.ndarray, views: np.ndarray, start: np.ndarray
) -> np.ndarray | None:
    """The direction within :data:`VOTE_PASSES`' first half range of ``start`` that the most
    segment length's planes hold (:data:`VOTE_PASSES`), refined as the least-squares direction
    normal to the planes within :data:`INLIER_DEGREES` of it (the smallest eigenvector of
    Σ w n nᵀ over them); signed like ``start``.

    Args:
        normals, weights, views: [k, 3], [k], [k] (:func:`segment_normals`).
        start: [3] unit: where to search about (the cameras' mean up).
    Returns:
        [3] unit, or None where fewer than :data:`MIN_VERTICAL_SEGMENTS` segments from fewer than
        :data:`MIN_VERTICAL_VIEWS` views agree on it.
    """
    up = np.asarray(start, np.float64) / np.linalg.norm(start)
    if len(normals) > MAX_SEGMENTS:
        keep = np.argsort(-weights, kind="stable")[:MAX_SEGMENTS]
        normals, weights, views = normals[keep], weights[keep], views[keep]
    if len(normals) == 0:
        return None
    for half, step, tolerance in VOTE_PASSES:
        candidates = _tilted_grid(up, half, step)
        held = np.abs(normals @ candidates.T) < np.sin(np.radians(tolerance))  # [k, m]
        up = candidates[int(np.argmax(weights @ held))]
    held = np.abs(normals @ up) < np.sin(np.radians(INLIER_DEGREES))
    if held.sum() < MIN_VERTICAL_SEGMENTS or len(np.unique(views[held])) < MIN_VERTICAL_VIEWS:
        return None
    _, vectors = np.linalg.eigh((normals[held] * weights[held, None]).T @ normals[held])
    refined = vectors[:, 0]
    return refined * np.sign(refined @ up)


def segments_at_most(image: np.ndarray, side: int = MAX_SIDE) -> np.ndarray:
    """:func:`line_segments` of ``image`` shrunk to a longer side of ``side`` pixels where it is
    larger (OpenCV's area interpolation), in ``image``'s pixel coordinates: with pixel centres at
    + 0.5 a coordinate scales with the image."""
    import cv2

    image = np.asarray(image)
    height, width = image.shape[:2]
    if max(height, width) <= side:
        return line_segments(image)
    size = (max(1, round(width * side / max(height, width))), max(1, round(height * side / max(height, width))))
    small = cv2.resize(image.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    return line_segments(small) * np.array([width / size[0], height / size[1]] * 2)


def vertical_from_images(cameras: Cameras, images: Sequence[np.ndarray], start: np.ndarray) -> np.ndarray | None:
    """:func:`vertical_from_normals` of the straight segments in ``images`` (one per camera; at
    most :data:`MAX_VIEWS` of them, evenly spread; :func:`segments_at_most` :data:`MAX_SIDE`)."""
    views = set(np.linspace(0, len(images) - 1, min(len(images), MAX_VIEWS)).round().astype(np.int64).tolist())
    segments = [segments_at_most(image) if i in views else np.zeros((0, 4)) for i, image in enumerate(images)]
    return vertical_from_normals(*segment_normals(cameras, segments), start)
