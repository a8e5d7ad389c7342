"""Post-processing of rendered masks (the seed paper's Gaussian smoothing) and label images."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = ["smooth_class_probs", "colorize_labels", "side_by_side", "default_color"]

PROB_EPS = 1e-12
"""Floor of the per-pixel sum before renormalising smoothed probabilities."""

NO_CLASS_COLOR = (40, 40, 40)  # FREE, UNKNOWN, ignore and other negative codes
IGNORE_COLOR = (0, 0, 0)


def smooth_class_probs(probs: np.ndarray, sigma: float | None) -> np.ndarray:
    """Gaussian-filter each class-probability image, then renormalise each pixel to sum 1.

    Args:
        probs: [H, W, C] class probabilities.
        sigma: standard deviation in pixels; None or 0 returns an unchanged copy.
    Returns:
        [H, W, C] float64.
    """
    probs = np.asarray(probs, np.float64)
    if not sigma:
        return probs.copy()
    out = gaussian_filter(probs, sigma=(sigma, sigma, 0), mode="nearest")
    return out / np.maximum(out.sum(-1, keepdims=True), PROB_EPS)


def default_color(class_id: int) -> tuple[int, int, int]:
    """A deterministic, well-spread colour for a class id without one (golden-ratio hues)."""
    hue = (class_id * 0.618033988749895) % 1.0
    h6 = hue * 6
    x = 1 - abs(h6 % 2 - 1)
    rgb = [(1, x, 0), (x, 1, 0), (0, 1, x), (0, x, 1), (x, 0, 1), (1, 0, x)][int(h6) % 6]
    return tuple(int(40 + 200 * c) for c in rgb)


def colorize_labels(
    label_ids: np.ndarray, class_colors: dict | None = None, ignore_index: int | None = None
) -> np.ndarray:
    """Colour-code a label image: [H, W] ids -> [H, W, 3] uint8.

    Negative codes (FREE, UNKNOWN) are dark grey, ignore_index black, ids without a colour in
    ``class_colors`` get :func:`default_color`.
    """
    label_ids = np.asarray(label_ids, np.int64)
    out = np.empty(label_ids.shape + (3,), np.uint8)
    out[...] = NO_CLASS_COLOR
    colors = {int(k): v for k, v in (class_colors or {}).items()}
    for cid in np.unique(label_ids).tolist():
        if cid == ignore_index:
            out[label_ids == cid] = IGNORE_COLOR
        elif cid >= 0:
            out[label_ids == cid] = colors.get(cid, default_color(cid))
    return out


def side_by_side(images: list[np.ndarray], gap: int = 2) -> np.ndarray:
    """Concatenate [H, W, 3] uint8 images left to right with white gaps (heights must match)."""
    h = images[0].shape[0]
    if any(im.shape[0] != h for im in images):
        raise ValueError("side_by_side needs images of one height")
    spacer = np.full((h, gap, 3), 255, np.uint8)
    parts = []
    for i, im in enumerate(images):
        parts += [spacer] if i else []
        parts.append(np.asarray(im, np.uint8))
    return np.concatenate(parts, axis=1)
