"""Metric scale from sensor depth: the factor that makes camera poses of arbitrary scale (structure
from motion) agree with depth measured in metres.

Poses from SfM are right up to one unknown factor ``s``; an RGB-D camera or a phone's LiDAR measures
distances in metres. With every camera centre multiplied by ``s``, a pixel's measured surface point,
seen from a second camera, must land where that camera measured it too. :func:`scale_from_depth`
searches ``s`` (log-spaced, then finer around the best) for the largest number of such agreements
(a robust count, so occlusions, holes and noise do not bias it). Cameras that only rotate cannot tell
the scale: then it returns None.
"""

from __future__ import annotations

import numpy as np

from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lens import inside_image, project_points
from scenelabel.geometry.rays import pixel_centres, rays_from_cameras

__all__ = ["scale_from_depth", "AGREEMENT", "MAX_PAIRS", "MIN_AGREEING"]

AGREEMENT = 0.03
"""A pixel's measured point agrees with a second view when the distance that view measured differs
from the predicted one by less than this fraction (sensor noise of 1-2 % passes)."""

MIN_AGREEING = 200
"""Fewer agreeing pixels than this at the best scale: the views do not overlap enough to tell."""

MAX_PAIRS = 64
"""At most this many view pairs are searched, spread evenly over the sequence: 64 pairs of 2000
pixels settle the count, and the search's time no longer grows with the views (a 150-view capture
would otherwise search 300 pairs)."""

PIXELS_PER_VIEW = 2000
"""Pixels with depth sampled (seeded) from each first view of a pair."""

COARSE_PIXELS = 200
"""The coarse search counts agreements of this many of each pair's pixels (the finer passes, all)."""

SEARCH_DECADES = 4.0
"""The coarse search covers s in [10^-4, 10^4]: SfM's unit is arbitrary but never that far off."""

COARSE_RATIO = 1.05
"""Ratio between neighbouring candidates of the coarse search (finer passes follow)."""

FLAT_RATIO = 1.2
"""When the best count beats the count at 10x and 0.1x the best scale by less than this factor, the
scale does not change what the views agree on (the cameras only rotate): no answer."""


def _pairs(views: list[int], max_pairs: int) -> list[tuple[int, int]]:
    """Each view with its successor and with the view a quarter of the sequence later; at most
    ``max_pairs`` of them, evenly spaced in that sorted list."""
    n = len(views)
    far = max(1, n // 4)
    pairs = {(views[a], views[(a + 1) % n]) for a in range(n)} | {(views[a], views[(a + far) % n]) for a in range(n)}
    pairs = sorted((i, j) for i, j in pairs if i != j)
    if len(pairs) <= max_pairs:
        return pairs
    return [pairs[k] for k in np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)]


def _nearest_depth(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """[k] the depth image's value at the pixel holding each (u, v) (NaN outside the image)."""
    h, w = depth.shape
    inside = inside_image(uv, w, h)
    out = np.full(len(uv), np.nan)
    out[inside] = depth[np.floor(uv[inside, 1]).astype(np.int64), np.floor(uv[inside, 0]).astype(np.int64)]
    return out


def _agreements(samples: list[tuple], cameras: Cameras, depths: list, scales: np.ndarray) -> np.ndarray:
    """How many sampled pixels agree with their pair's second view when centres are multiplied by
    each of ``scales`` [S]: [S] counts.

    Seen from view j, the scene with centres times s and a pixel's point at its measured distance m
    is the unscaled scene with that point at m / s, magnified s times: the same pixel, at s times
    the distance. So all scales are one projection through view j's own pose.
    """
    scales = np.asarray(scales, dtype=np.float64)
    totals = np.zeros(len(scales), dtype=np.int64)
    for j, origin, directions, measured in samples:
        points = origin + (measured[None, :, None] / scales[:, None, None]) * directions[None]  # [S, k, 3], pose units
        uv, _, distance = project_points(
            points.reshape(-1, 3), cameras.c2w[j], cameras.fx[j], cameras.fy[j], cameras.cx[j], cameras.cy[j],
            cameras.distortion[j], cameras.model[j],
        )  # NaN where view j's lens does not see the point; distance: from view j
        predicted = scales[:, None] * distance.reshape(len(scales), -1)  # [S, k] metres
        seen = _nearest_depth(depths[j], uv).reshape(len(scales), -1)
        with np.errstate(invalid="ignore"):
            totals += np.sum(np.abs(predicted - seen) < AGREEMENT * seen, axis=1)
    return totals


def scale_from_depth(
    cameras: Cameras, depths: list[np.ndarray | None], seed: int = 0, max_pairs: int = MAX_PAIRS
) -> float | None:
    """The factor ``s`` (metres per pose unit) that makes the views' sensor depths agree.

    Points are projected through each camera's lens model and distortion
    (:func:`scenelabel.geometry.lens.project_points`).

    Args:
        cameras: [n] cameras in the poses' own unit.
        depths: n arrays [h, w] (distance along each pixel's unit ray, metres, NaN = none) or None.
        seed: for the sampled pixels.
        max_pairs: how many view pairs are searched at most (:data:`MAX_PAIRS`).
    Returns:
        ``s``, or None when fewer than two views have depth, the views do not overlap, or the
        cameras only rotate (the scale changes nothing).
    """
    views = [i for i, d in enumerate(depths) if d is not None]
    if len(views) < 2:
        return None
    rng = np.random.default_rng(seed)
    samples = []
    for i, j in _pairs(views, max_pairs):
        measured = depths[i].reshape(-1).astype(np.float64)
        valid = np.flatnonzero(np.isfinite(measured) & (measured > 0))
        pick = rng.choice(valid, min(PIXELS_PER_VIEW, len(valid)), replace=False) if len(valid) else valid
        directions = rays_from_cameras(cameras, i, pixel_centres(pick, depths[i].shape[1]))[1]
        samples.append((j, cameras.c2w[i, :3, 3], directions, measured[pick]))

    def counts(scales: np.ndarray, per_pair: int = PIXELS_PER_VIEW) -> np.ndarray:
        return _agreements([(j, o, d[:per_pair], m[:per_pair]) for j, o, d, m in samples], cameras, depths, scales)

    candidates = np.exp(np.arange(-SEARCH_DECADES * np.log(10), SEARCH_DECADES * np.log(10), np.log(COARSE_RATIO)))
    best = float(candidates[int(np.argmax(counts(candidates, COARSE_PIXELS)))])
    for ratio in (COARSE_RATIO, 1.0 + AGREEMENT / 2):  # refine: +-one coarse step, then +-half the agreement band
        fine = best * np.exp(np.linspace(-np.log(ratio), np.log(ratio), 21))
        best = float(fine[int(np.argmax(counts(fine)))])
    peak, at_ten, at_tenth = counts(np.array([best, best * 10.0, best / 10.0]))
    if peak < MIN_AGREEING or peak < FLAT_RATIO * max(at_ten, at_tenth):
        return None
    return best
