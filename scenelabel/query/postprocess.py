"""Post-processing of rendered masks (the seed paper's Gaussian smoothing) and label images."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from scenelabel.errors import InputError
from scenelabel.maps.exports.palette import default_color

__all__ = ["colorize_labels", "default_color", "side_by_side", "smooth_class_probs"]

PROB_EPS = 1e-12
"""Floor of the per-pixel sum before renormalising smoothed probabilities."""

NO_CLASS_COLOR = (40, 40, 40)  # FREE, UNKNOWN and other negative codes: dark grey
IGNORE_COLOR = (0, 0, 0)  # ignore_index: black
GAP_COLOR = 255  # side_by_side spacer and padding: white


def smooth_class_probs(probs: np.ndarray, sigma: float | tuple[float, float] | None) -> np.ndarray:
    """Gaussian-filter each class-probability image, then renormalise each pixel to sum 1.

    The seed paper's smoothing of rendered masks: each channel is filtered in image space
    (``scipy.ndimage.gaussian_filter``, ``mode="nearest"``, no mixing across channels), then
    divided by its per-pixel sum, floored at PROB_EPS (a pixel whose probabilities are all 0
    stays 0).

    Args:
        probs: [H, W, C] class probabilities.
        sigma: standard deviation in pixels, one number or (sigma_rows, sigma_cols); None or 0
            returns an unchanged copy.
    Returns:
        [H, W, C] in the input's float dtype (float64 for non-float input).
    """
    probs = np.asarray(probs)
    dtype = probs.dtype if np.issubdtype(probs.dtype, np.floating) else np.float64
    if probs.ndim != 3:
        raise InputError(f"probs must have shape [H, W, C], got {probs.shape}", field="probs")
    if sigma is not None and np.size(sigma) not in (1, 2):
        raise InputError(f"sigma must be one number or (rows, cols), got {sigma}", field="sigma")
    sigmas = (0.0, 0.0) if sigma is None else np.broadcast_to(np.asarray(sigma, np.float64).ravel(), (2,))
    if np.any(np.asarray(sigmas) < 0) or not np.all(np.isfinite(sigmas)):
        raise InputError(f"sigma must be finite and >= 0, got {sigma}", field="sigma")
    if not np.any(np.asarray(sigmas) > 0):
        return probs.astype(dtype, copy=True)
    out = gaussian_filter(probs.astype(np.float64), sigma=(sigmas[0], sigmas[1], 0.0), mode="nearest")
    return (out / np.maximum(out.sum(-1, keepdims=True), PROB_EPS)).astype(dtype)


def colorize_labels(
    label_ids: np.ndarray, class_colors: dict | None = None, ignore_index: int | None = None
) -> np.ndarray:
    """Colour-code a label image: [H, W] ids -> [H, W, 3] uint8.

    Args:
        label_ids: [H, W] external class ids (or FREE = -1 / UNKNOWN = -2).
        class_colors: external id (int or str key, as read from JSON) -> (r, g, b) in 0..255.
        ignore_index: label value of unlabelled pixels.
    Negative codes (FREE, UNKNOWN) are dark grey (NO_CLASS_COLOR), ignore_index black
    (IGNORE_COLOR), ids without a colour in ``class_colors`` get :func:`default_color`.
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
    """Concatenate uint8 images left to right with white gaps of ``gap`` px.

    Args:
        images: [H_i, W_i, 3] (or [H_i, W_i] grey) uint8 images; shorter ones are padded with
            white at the bottom to the tallest.
    Returns:
        [max H_i, sum W_i + gap * (n - 1), 3] uint8.
    """
    if len(images) == 0:
        raise InputError("side_by_side needs at least one image", field="images")
    if gap < 0:
        raise InputError(f"gap must be >= 0, got {gap}", field="gap")
    panels = []
    for im in images:
        im = np.asarray(im)
        if im.dtype != np.uint8 or im.ndim not in (2, 3) or (im.ndim == 3 and im.shape[2] != 3):
            raise InputError(f"side_by_side needs uint8 [H, W, 3] or [H, W] images, got {im.dtype} {im.shape}", field="images")
        panels.append(np.repeat(im[..., None], 3, axis=2) if im.ndim == 2 else im)
    h = max(p.shape[0] for p in panels)
    parts = []
    for i, p in enumerate(panels):
        if i:
            parts.append(np.full((h, gap, 3), GAP_COLOR, np.uint8))
        pad = np.full((h - p.shape[0], p.shape[1], 3), GAP_COLOR, np.uint8)
        parts.append(np.concatenate([p, pad], axis=0))
    return np.concatenate(parts, axis=1)
