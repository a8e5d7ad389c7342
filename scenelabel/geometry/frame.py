"""Scene bounds from the cameras, and the world <-> normalised frame transform.

The field works in a normalised frame ``x_n = (x_world - centre) * scale`` where the scene box
fits [-1, 1]^3 (its longest side spans exactly [-1, 1]). The transform is isotropic, so
directions are unchanged and distances scale by ``scale``; it is undone on every output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenelabel.config import POINTS_PAD
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.rays import camera_directions_from_pixels

__all__ = [
    "SceneFrame",
    "aabb_from_cameras",
    "aabb_from_points",
    "frustum_points",
    "forward_rig",
    "looking_one_way",
    "mean_optical_axis",
    "near_far_or_fallback",
    "observed_extent",
    "FORWARD_MAX_ANGLE_DEG",
]

FORWARD_MAX_ANGLE_DEG = 45.0
"""A capture is forward-facing when every camera's optical axis is within this angle of the mean axis
(:func:`looking_one_way`; :func:`scenelabel.geometry.warps.forward_facing_reference` also asks for the
scene in front)."""

FALLBACK_FAR_FACTOR = 1.5
"""Without near/far, far = this x the diameter of the camera centres (an inward-looking capture)."""

FORWARD_FALLBACK_FAR_FACTOR = 30.0
"""Without near/far, for a :func:`forward_rig` (an LLFF-like capture, whose cameras stand close
together and look at a scene far away), far = this x the diameter of the camera centres: at least
twice fern's far (its poses_bounds.npy) and the forward-facing suite rooms' farthest walls
(tests/test_io_llff.py, tests/test_suite.py); the build's coarse fit then bounds the scene within
that far (:func:`aabb_from_cameras` with observed points)."""

FORWARD_RIG_DEPTH_RATIO = 0.5
"""A :func:`forward_rig`'s camera centres spread along the mean viewing direction at most this
fraction of their spread across it (fern and the forward-facing suite rooms, well within it: the
tests); a camera carried forward, down a corridor, spreads along it."""

FALLBACK_NEAR_FRACTION = 0.02
"""Without near, near = this fraction of far."""

AABB_PAD = 0.02
"""Bounds are padded by this fraction of their longest side on every face."""

POINTS_PERCENTILES = (0.5, 99.5)
"""Bounds from observed points span these percentiles of the points on each axis (stray points
beyond them move nothing)."""

MIN_BOUNDING_POINTS = 100
"""Fewer observed points than this do not bound a scene (the camera frusta do instead)."""


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
            pix, cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i], cameras.distortion[i], str(cameras.model[i])
        )
        dirs_w = dirs @ cameras.c2w[i, :3, :3].T
        origin = cameras.c2w[i, :3, 3]
        for t in (near[i], far[i]):
            points.append(origin + t * dirs_w)
    return np.concatenate(points)


def mean_optical_axis(cameras: Cameras) -> np.ndarray | None:
    """[3] unit mean of the cameras' optical axes (``c2w[:, :3, 2]``); None where they cancel (norm
    of the mean below 1e-9: no mean direction)."""
    mean_axis = cameras.c2w[:, :3, 2].mean(0)
    norm = np.linalg.norm(mean_axis)
    return None if norm < 1e-9 else mean_axis / norm


def looking_one_way(cameras: Cameras, max_angle_deg: float = FORWARD_MAX_ANGLE_DEG) -> bool:
    """Every optical axis within ``max_angle_deg`` of their mean direction (:func:`mean_optical_axis`)."""
    axis = mean_optical_axis(cameras)
    if axis is None:
        return False
    return bool(np.degrees(np.arccos(np.clip(cameras.c2w[:, :3, 2] @ axis, -1, 1))).max() <= max_angle_deg)


def forward_rig(cameras: Cameras, max_angle_deg: float = FORWARD_MAX_ANGLE_DEG) -> bool:
    """Cameras that photograph a scene in front of them from a patch across their view (LLFF's
    captures): :func:`looking_one_way`, and the centres' extent along the mean optical axis at most
    FORWARD_RIG_DEPTH_RATIO x their extent across it."""
    if not looking_one_way(cameras, max_angle_deg):
        return False
    axis = mean_optical_axis(cameras)
    offsets = cameras.centres - cameras.centres.mean(0)
    along = offsets @ axis
    across = offsets - along[:, None] * axis
    return bool(np.ptp(along) <= FORWARD_RIG_DEPTH_RATIO * np.linalg.norm(across.max(0) - across.min(0)))


def near_far_or_fallback(cameras: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's [near, far], with the fallbacks where the input gives none.

    Without far: FALLBACK_FAR_FACTOR x the diameter of the camera centres (FORWARD_FALLBACK_FAR_FACTOR x
    for a :func:`forward_rig`); without near: FALLBACK_NEAR_FRACTION x far.

    Returns:
        near, far: [n] float64.
    """
    far = cameras.far.copy()
    if np.any(~np.isfinite(far)):
        centres = cameras.centres
        diameter = float(np.linalg.norm(centres.max(0) - centres.min(0)))
        if diameter <= 0:
            raise InputError("cannot bound the scene: no near/far and all cameras at one point", field="far")
        factor = FORWARD_FALLBACK_FAR_FACTOR if forward_rig(cameras) else FALLBACK_FAR_FACTOR
        far = np.where(np.isfinite(far), far, factor * diameter)
    near = np.where(np.isfinite(cameras.near), cameras.near, FALLBACK_NEAR_FRACTION * far)
    return near, far


def aabb_from_points(points: np.ndarray, pad: float = POINTS_PAD) -> np.ndarray | None:
    """Bounds of observed points: POINTS_PERCENTILES per axis, padded by ``pad`` of the longest
    side; None for fewer than MIN_BOUNDING_POINTS points or a flat point set.

    Args:
        points: [k, 3] world points (e.g. where the training rays of a coarse field end).
        pad: fraction of the longest side added on every face.
    Returns:
        aabb [2, 3] float64 or None.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) < MIN_BOUNDING_POINTS:
        return None
    lo, hi = np.percentile(points, POINTS_PERCENTILES, axis=0)
    extent = float((hi - lo).max())
    if not extent > 0:
        return None
    return np.stack([lo - pad * extent, hi + pad * extent])


def observed_extent(points: np.ndarray, aabb: np.ndarray) -> np.ndarray | None:
    """The box of the finite observed ``points`` [k, 3] inside ``aabb`` [2, 3]: their full extent (no
    percentiles, no pad: a point beyond the bounds of :func:`aabb_from_points` is still geometry a
    camera saw, unless it lies outside ``aabb``). None where :func:`aabb_from_points` gives none.

    Returns:
        [2, 3] float64 (min corner, max corner) or None.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = np.asarray(aabb, dtype=np.float64)
    points = points[np.all(np.isfinite(points) & (points >= lo) & (points <= hi), axis=1)]
    if len(points) < MIN_BOUNDING_POINTS or not float((points.max(0) - points.min(0)).max()) > 0:
        return None
    return np.stack([points.min(0), points.max(0)])


def aabb_from_cameras(
    cameras: Cameras, explicit: np.ndarray | None = None, points: np.ndarray | None = None,
    points_source: str = "observed geometry", points_pad: float = POINTS_PAD,
) -> tuple[np.ndarray, str]:
    """Scene bounds: explicit ones when given; else, where the cameras have no far and enough
    observed ``points`` are given, the points' bounds (:func:`aabb_from_points`, padded by
    ``points_pad`` of their longest side) within the camera frusta; else the union of the camera
    frusta over [near, far]. ``points_source`` names where the points came from in the returned
    word (a coarse fit's "observed geometry", or "sensor depth").

    Where a camera has no near/far: :func:`near_far_or_fallback`.

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
    frusta = np.stack([lo - pad, hi + pad])
    observed = None if points is None or np.all(np.isfinite(cameras.far)) else aabb_from_points(points, points_pad)
    if observed is not None:
        clipped = np.stack([np.maximum(observed[0], frusta[0]), np.minimum(observed[1], frusta[1])])
        if np.all(clipped[1] > clipped[0]):
            padded = f"padded {points_pad:.0%} of the longest side"
            return clipped, f"{points_source} ({len(points)} points, {padded}; the input has no near/far or aabb)"
    return frusta, source


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

    def to_normalised(self, xyz: np.ndarray) -> np.ndarray:
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
