"""Evaluation metrics: PSNR, SSIM, confusion matrix / mIoU, depth error (numpy in, numbers out).

Pixels labelled ``ignore_index`` never count; neither do pixels whose true class is not in the
evaluated ``class_ids``. Predictions outside ``class_ids`` (FREE, UNKNOWN, other ids) are always
wrong: they count as misses of the true class (a last "other" column of the confusion matrix).
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

from .errors import InputError

__all__ = [
    "boundary_f1",
    "confusion_matrix",
    "depth_error",
    "label_boundaries",
    "miou",
    "pose_centre_errors",
    "pose_rotation_errors_deg",
    "psnr",
    "ssim",
]

SSIM_WINDOW = 7
"""skimage's default SSIM window; smaller images use the largest odd window that fits."""
SSIM_MIN_WINDOW = 3
"""skimage cannot compute SSIM with a window below 3 px: smaller images are an error."""


def _same_shape(pred: np.ndarray, target: np.ndarray, what: str) -> None:
    if pred.shape != target.shape:
        raise InputError(f"{what}: prediction {pred.shape} and target {target.shape} differ", field="pred")


def psnr(pred: np.ndarray, target: np.ndarray, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio 10 log10(max² / MSE) in dB; inf for identical images.

    Args:
        pred, target: [H, W, 3] (any matching shape) in [0, max_value].
    Returns:
        PSNR in dB; ``inf`` when the images are identical (MSE 0).
    """
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    _same_shape(pred, target, "psnr")
    mse = float(np.mean((pred - target) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(max_value**2 / mse))


def ssim(pred: np.ndarray, target: np.ndarray, data_range: float = 1.0) -> float:
    """Structural similarity (skimage, uniform 7x7 window) of images in [0, data_range].

    Args:
        pred, target: [H, W, 3] colour (channel axis last) or [H, W] grey images.
    Images smaller than 7 px use the largest odd window that fits (at least 3 px; smaller
    images raise InputError).
    """
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    _same_shape(pred, target, "ssim")
    if pred.ndim not in (2, 3):
        raise InputError(f"ssim needs [H, W] or [H, W, C] images, got {pred.shape}", field="pred")
    win = min(SSIM_WINDOW, *pred.shape[:2])
    win = win if win % 2 == 1 else win - 1
    if win < SSIM_MIN_WINDOW:
        raise InputError(f"ssim needs images of at least {SSIM_MIN_WINDOW}x{SSIM_MIN_WINDOW} px, got {pred.shape[:2]}", field="pred")
    channel_axis = -1 if pred.ndim == 3 else None
    return float(
        structural_similarity(pred, target, channel_axis=channel_axis, data_range=data_range, win_size=win)
    )


def confusion_matrix(
    pred_ids: np.ndarray, target_ids: np.ndarray, class_ids: np.ndarray, ignore_index: int | None = None
) -> np.ndarray:
    """Counts [C, C + 1]: rows = true class, columns = predicted class over ``class_ids``, and a
    last column for predictions outside class_ids (FREE, UNKNOWN, other ids: always wrong).

    Pixels whose target is ignore_index or not in class_ids are skipped.

    Args:
        pred_ids, target_ids: int arrays of external ids, same shape.
        class_ids: [C] ascending external ids.
    """
    class_ids = np.asarray(class_ids, np.int64)
    pred = np.asarray(pred_ids, np.int64).ravel()
    target = np.asarray(target_ids, np.int64).ravel()
    if np.shape(pred_ids) != np.shape(target_ids):
        raise InputError(f"prediction {np.shape(pred_ids)} and target {np.shape(target_ids)} differ", field="pred_ids")
    if class_ids.ndim != 1 or len(class_ids) == 0 or np.any(np.diff(class_ids) <= 0):
        raise InputError(f"class_ids must be non-empty, unique and ascending, got {class_ids.tolist()}", field="class_ids")
    C = len(class_ids)
    t_pos = np.searchsorted(class_ids, target).clip(0, C - 1)
    valid = class_ids[t_pos] == target
    if ignore_index is not None:
        valid &= target != ignore_index
    p_pos = np.searchsorted(class_ids, pred).clip(0, C - 1)
    cols = np.where(class_ids[p_pos] == pred, p_pos, C)
    flat = t_pos[valid] * (C + 1) + cols[valid]
    return np.bincount(flat, minlength=C * (C + 1)).astype(np.int64).reshape(C, C + 1)


def miou(confusion: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean intersection over union from a [C, C + 1] confusion matrix (or a plain [C, C] one).

    IoU_c = TP / (TP + FP + FN). Classes absent from both target and prediction get NaN and are
    left out of the mean.

    Returns:
        (mean IoU, [C] per-class IoU).
    """
    confusion = np.asarray(confusion, np.float64)
    C = confusion.shape[0]
    tp = np.diag(confusion[:, :C])
    fn = confusion.sum(1) - tp
    fp = confusion[:, :C].sum(0) - tp
    denom = tp + fp + fn
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(denom > 0, tp / denom, np.nan)
    return (float(np.nanmean(iou)) if np.any(denom > 0) else float("nan")), iou


def depth_error(
    pred_depth: np.ndarray, target_depth: np.ndarray, valid_mask: np.ndarray | None = None
) -> dict[str, float]:
    """Depth errors over valid pixels: abs_rel = mean |p - t| / t, rmse, mae (world units).

    Args:
        pred_depth, target_depth: [H, W] depth along the unit ray (any matching shape).
        valid_mask: [H, W] bool, or None for all pixels. Pixels whose target is not finite and
            positive (0 = no surface in the synthetic scenes) never count. A non-finite
            prediction at a valid pixel is not skipped: it makes the errors non-finite.
    Returns:
        {"abs_rel", "rmse", "mae"}: NaN each when no pixel is valid.
    """
    pred = np.asarray(pred_depth, np.float64)
    target = np.asarray(target_depth, np.float64)
    _same_shape(pred, target, "depth_error")
    valid = np.isfinite(target) & (target > 0)
    if valid_mask is not None:
        valid &= np.asarray(valid_mask, bool)
    if not valid.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "mae": float("nan")}
    diff = pred[valid] - target[valid]
    return {
        "abs_rel": float(np.mean(np.abs(diff) / target[valid])),
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "mae": float(np.mean(np.abs(diff))),
    }


def label_boundaries(labels: np.ndarray, ignore_index: int | None = None) -> np.ndarray:
    """[H, W] bool: pixels whose right or lower 4-neighbour has another label.

    A pair where either pixel is ``ignore_index`` is not a boundary.
    """
    labels = np.asarray(labels)
    edge = np.zeros(labels.shape, dtype=bool)
    for axis in (0, 1):
        a = labels.take(np.arange(labels.shape[axis] - 1), axis=axis)
        b = labels.take(np.arange(1, labels.shape[axis]), axis=axis)
        diff = a != b
        if ignore_index is not None:
            diff &= (a != ignore_index) & (b != ignore_index)
        pad = [(0, 1) if ax == axis else (0, 0) for ax in range(2)]
        edge |= np.pad(diff, pad)
    return edge


def boundary_f1(pred: np.ndarray, target: np.ndarray, tolerance: float = 2.0, ignore_index: int | None = None) -> float:
    """Boundary F-score (Csurka et al. 2013): how well predicted label boundaries match true ones.

    Precision: fraction of predicted boundary pixels within ``tolerance`` pixels (Euclidean) of a
    true boundary; recall: the converse; F1 their harmonic mean. 1.0 when neither has a boundary,
    0.0 when only one has.

    Args:
        pred, target: [H, W] integer label images.
        tolerance: pixels.
        ignore_index: target pixels with this value are never boundaries (pred boundaries there
            are dropped too).
    """
    from scipy.ndimage import distance_transform_edt

    _same_shape(pred, target, "boundary_f1")
    bt = label_boundaries(target, ignore_index)
    bp = label_boundaries(pred)
    if ignore_index is not None:
        bp &= np.asarray(target) != ignore_index
    if not bt.any() and not bp.any():
        return 1.0
    if not bt.any() or not bp.any():
        return 0.0
    near_true = distance_transform_edt(~bt) <= tolerance
    near_pred = distance_transform_edt(~bp) <= tolerance
    precision = float(near_true[bp].mean())
    recall = float(near_pred[bt].mean())
    return 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)


# ------------------------------------------------------------------ camera poses


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix to ``m`` [3, 3] (SVD, det +1)."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def pose_rotation_errors_deg(c2w_true: np.ndarray, c2w_est: np.ndarray) -> np.ndarray:
    """Per-camera rotation error in degrees, after fitting the unknown world rotation G.

    For poses recovered in another world frame (structure from motion): G is the rotation
    nearest to Σ_i R_true_i R_est_iᵀ (the least-squares fit of R_true ≈ G R_est), and the error of
    camera i is the angle of R_true_iᵀ G R_est_i.

    Args:
        c2w_true, c2w_est: [n, 4, 4] camera-to-world, the same camera axes, matched by index.
    Returns:
        [n] float64 degrees.
    """
    r_true, r_est = np.asarray(c2w_true)[:, :3, :3], np.asarray(c2w_est)[:, :3, :3]
    g = _nearest_rotation(np.sum(r_true @ np.transpose(r_est, (0, 2, 1)), axis=0))
    cos = (np.trace(np.transpose(r_true, (0, 2, 1)) @ g @ r_est, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_centre_errors(c2w_true: np.ndarray, c2w_est: np.ndarray) -> np.ndarray:
    """Per-camera centre error after a similarity fit (Umeyama 1991), relative to the true spread.

    Args:
        c2w_true, c2w_est: [n, 4, 4] matched by index (n >= 3, centres not all collinear).
    Returns:
        [n] float64: |s R x_est + t - x_true| / RMS distance of the true centres from their mean.
    """
    x, y = np.asarray(c2w_est)[:, :3, 3], np.asarray(c2w_true)[:, :3, 3]
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    u, s, vt = np.linalg.svd(yc.T @ xc / len(x))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ d @ vt
    scale = np.trace(np.diag(s) @ d) / xc.var(0).sum()
    aligned = scale * xc @ rotation.T + my
    spread = np.sqrt((yc**2).sum(1).mean())
    return np.linalg.norm(aligned - y, axis=1) / spread
