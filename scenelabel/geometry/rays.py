"""Cameras -> rays, in scenelabel's conventions (docs/conventions.md).

Pixel centres are at +0.5; ``directions`` are unit vectors in the world frame; a point on a ray is
``origins + t * directions`` with ``t`` the distance along the ray.
"""

from __future__ import annotations

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lens import CAMERA_MODELS, FISHEYE, PINHOLE, fisheye_directions_from_pixels

__all__ = ["row_norms", "pixel_grid", "pixel_centres", "camera_directions_from_pixels", "rays_from_cameras", "normalize_directions"]

DIRECTION_EPS = 1e-12
"""Directions shorter than this cannot be normalised; :func:`normalize_directions` rejects them."""

UNDISTORT_EPS_PX = 1e-10
"""``cv2.undistortPoints`` iterates until the undistorted point reprojects within this many pixels
of the distorted one (OpenCV's default stops after 5 iterations, up to ~1e-3 px off) ..."""

UNDISTORT_MAX_ITER = 100
"""... or after this many iterations."""


def row_norms(vectors: np.ndarray) -> np.ndarray:
    """[n] Euclidean lengths of ``vectors`` [n, 3]: ``sqrt((x² + y²) + z²)``, the sum in the order
    ``np.linalg.norm(vectors, axis=-1)`` takes (the same float64 bits), in a third of its time on
    an image's rays (it reduces each row of three in a loop of its own)."""
    return np.sqrt((vectors[:, 0] * vectors[:, 0] + vectors[:, 1] * vectors[:, 1]) + vectors[:, 2] * vectors[:, 2])


def pixel_grid(width: int, height: int) -> np.ndarray:
    """Continuous coordinates of every pixel centre, row-major.

    Returns:
        [height * width, 2] float64 (u, v) = (col + 0.5, row + 0.5).
    """
    return pixel_centres(np.arange(height * width), width)


def pixel_centres(indices: np.ndarray, width: int) -> np.ndarray:
    """Continuous coordinates of the centres of pixels ``indices`` [k] (row-major, in an image
    ``width`` pixels wide): [k, 2] float64 (u, v) = (index % width + 0.5, index // width + 0.5), the
    rows of :func:`pixel_grid` they index."""
    indices = np.asarray(indices, dtype=np.int64)
    return np.stack([indices % width + 0.5, indices // width + 0.5], axis=-1).astype(np.float64)


def camera_directions_from_pixels(
    pixels: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion: np.ndarray | None = None,
    model: str = PINHOLE,
) -> np.ndarray:
    """Camera-frame (OpenCV axes) ray directions through continuous pixel coordinates.

    The inverse of :func:`scenelabel.geometry.lens.pixels_from_camera_points`.

    Args:
        pixels: [n, 2] (u, v) in pixels; a pixel's centre is (col + 0.5, row + 0.5).
        fx, fy, cx, cy: intrinsics in pixels.
        distortion: [4] the model's coefficients or None (zeros). A pinhole's OpenCV
            (k1, k2, p1, p2): distorted pixels are undistorted with ``cv2.undistortPoints``
            (iterative inverse of the radial-tangential model, run to UNDISTORT_EPS_PX); a
            fisheye's (k1, k2, k3, k4): :func:`scenelabel.geometry.lens.fisheye_directions_from_pixels`.
        model: ``"pinhole"`` or ``"fisheye"`` (docs/conventions.md, "Camera models").
    Returns:
        [n, 3] float64 unit directions (z forward for a pinhole; a fisheye's may point sideways
        or backwards, z <= 0, past 90° from its axis).
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    if model == FISHEYE:
        return fisheye_directions_from_pixels(pixels, fx, fy, cx, cy, np.zeros(4) if distortion is None else distortion)
    if model != PINHOLE:
        raise InputError(f"unknown camera model {model!r}; known: {', '.join(CAMERA_MODELS)}", field="model")
    if distortion is not None and np.any(np.asarray(distortion) != 0):
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        import cv2  # only for distortion: a planner's process answering rays need not load OpenCV

        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, UNDISTORT_MAX_ITER, UNDISTORT_EPS_PX)
        xy = cv2.undistortPoints(
            pixels.reshape(-1, 1, 2), K, np.asarray(distortion, np.float64), criteria=criteria
        ).reshape(-1, 2)
    else:
        xy = np.stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy], axis=-1)
    dirs = np.concatenate([xy, np.ones((len(xy), 1))], axis=-1)
    return dirs / row_norms(dirs)[:, None]


def rays_from_cameras(cameras: Cameras, index: int, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays of camera ``index`` through ``pixels`` (all pixel centres when None).

    Args:
        cameras: the camera batch.
        index: which camera.
        pixels: [n, 2] continuous pixel coordinates, or None for every pixel centre (row-major).
    Returns:
        origins [n, 3], directions [n, 3] (unit), float64.
    """
    cam = cameras[index]
    if pixels is None:
        pixels = pixel_grid(int(cam.width[0]), int(cam.height[0]))
    dirs_cam = camera_directions_from_pixels(
        pixels, cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0], cam.distortion[0], str(cam.model[0])
    )
    c2w = cam.c2w[0]
    directions = dirs_cam @ c2w[:3, :3].T
    directions /= row_norms(directions)[:, None]
    origins = np.broadcast_to(c2w[:3, 3], directions.shape).copy()
    return origins, directions


def normalize_directions(directions: np.ndarray, name: str = "directions") -> tuple[np.ndarray, np.ndarray]:
    """Unit directions and their original lengths; zero-length or non-finite input is an error.

    Args:
        directions: [n, 3].
    Returns:
        unit [n, 3], norms [n].
    """
    norms = np.linalg.norm(directions, axis=-1)
    bad = ~(norms > DIRECTION_EPS) | ~np.isfinite(norms)
    if np.any(bad):
        raise InputError(f"{int(bad.sum())} of {len(norms)} directions are zero-length or non-finite", field=name)
    return directions / norms[:, None], norms
