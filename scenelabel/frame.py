"""Scene bounds from the cameras, and the world <-> normalised frame transform.

The field works in a normalised frame ``x_n = (x_world - centre) * scale`` where the scene box
fits [-1, 1]^3 (its longest side spans exactly [-1, 1]). The transform is isotropic, so
directions are unchanged and distances scale by ``scale``; it is undone on every output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .rays import camera_directions_from_pixels
from .scene import Cameras

__all__ = ["SceneFrame", "aabb_from_cameras", "frustum_points", "near_far_or_fallback"]

FALLBACK_FAR_FACTOR = 1.5
"""Without near/far, far = this x the diameter of the camera centres (an inward-looking capture)."""

FALLBACK_NEAR_FRACTION = 0.02
"""Without near, near = this fraction of far."""

AABB_PAD = 0.02
"""Bounds are padded by this fraction of their longest side on every face."""


def frustum_points(cameras: Cameras, near: np.ndarray, far: np.ndarray) -> np.ndarray:
    """Corners (and centre rays) of every camera's frustum between ``near`` and ``far``.

    Args:
        cameras: n cameras.
        near, far: [n] distances along the unit rays.
    Returns:
        [n * 10, 3] world points: 5 rays (4 image corners, centre) at near and at far.
    """
    points = []
    for i in range(len(cameras)):
        w, h = float(cameras.width[i]), float(cameras.height[i])
        pix = np.array([[0, 0], [w, 0], [0, h], [w, h], [w / 2, h / 2]], dtype=np.float64)
        dirs = camera_directions_from_pixels(
            pix, cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i], cameras.distortion[i]
        )
        dirs_w = dirs @ cameras.c2w[i, :3, :3].T
        origin = cameras.c2w[i, :3, 3]
        for t in (near[i], far[i]):
            points.append(origin + t * dirs_w)
    return np.concatenate(points)


def near_far_or_fallback(cameras: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's [near, far], with the fallbacks where the input gives none.

    Without far: FALLBACK_FAR_FACTOR x the diameter of the camera centres; without near:
    FALLBACK_NEAR_FRACTION x far.

    Returns:
        near, far: [n] float64.
    """
    far = cameras.far.copy()
    if np.any(~np.isfinite(far)):
        centres = cameras.centres
        diameter = float(np.linalg.norm(centres.max(0) - centres.min(0)))
        if diameter <= 0:
            raise InputError("cannot bound the scene: no near/far and all cameras at one point", field="far")
        far = np.where(np.isfinite(far), far, FALLBACK_FAR_FACTOR * diameter)
    near = np.where(np.isfinite(cameras.near), cameras.near, FALLBACK_NEAR_FRACTION * far)
    return near, far


def aabb_from_cameras(cameras: Cameras, explicit: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """Scene bounds: explicit ones when given, else the union of the camera frusta over [near, far].

    Where a camera has no near/far, far = FALLBACK_FAR_FACTOR x the camera-centre diameter and
    near = FALLBACK_NEAR_FRACTION x far.

    Returns:
        aabb [2, 3] float64 (min corner, max corner), and a word on where it came from.
    """
    if explicit is not None:
        aabb = np.asarray(explicit, dtype=np.float64).reshape(2, 3)
        if not np.all(np.isfinite(aabb)) or np.any(aabb[1] <= aabb[0]):
            raise InputError(f"scene aabb must be finite with max > min, got {aabb.tolist()}", field="aabb")
        return aabb, "explicit aabb"
    near, far = near_far_or_fallback(cameras)
    source = "camera frusta over near/far"
    if np.any(~np.isfinite(cameras.far)):
        source = "camera frusta (far from camera spread: the input has no near/far)"
    pts = frustum_points(cameras, near, far)
    lo, hi = pts.min(0), pts.max(0)
    pad = AABB_PAD * float((hi - lo).max())
    return np.stack([lo - pad, hi + pad]), source


@dataclass(frozen=True)
class SceneFrame:
    """x_n = (x_world - centre) * scale; an isotropic similarity, so angles are kept."""

    centre: np.ndarray  # [3]
    scale: float

    @staticmethod
    def from_aabb(aabb: np.ndarray) -> "SceneFrame":
        aabb = np.asarray(aabb, dtype=np.float64)
        half = 0.5 * (aabb[1] - aabb[0])
        return SceneFrame(centre=0.5 * (aabb[0] + aabb[1]), scale=float(1.0 / half.max()))

    def to_internal(self, xyz: np.ndarray) -> np.ndarray:
        """World points [..., 3] -> normalised points."""
        return (np.asarray(xyz, np.float64) - self.centre) * self.scale

    def to_world(self, xyz: np.ndarray) -> np.ndarray:
        """Normalised points [..., 3] -> world points."""
        return np.asarray(xyz, np.float64) / self.scale + self.centre

    def to_dict(self) -> dict:
        return {"centre": self.centre.tolist(), "scale": self.scale}

    @staticmethod
    def from_dict(data: dict) -> "SceneFrame":
        return SceneFrame(centre=np.asarray(data["centre"], np.float64), scale=float(data["scale"]))
