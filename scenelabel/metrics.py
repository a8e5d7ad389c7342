"""Evaluation metrics: PSNR, SSIM, confusion matrix / mIoU, depth error (numpy in, numbers out).

Pixels labelled ``ignore_index`` never count; neither do pixels whose true class has no channel.
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

__all__ = ["psnr", "ssim", "confusion_matrix", "miou", "depth_error"]

SSIM_WINDOW = 7
"""skimage's default SSIM window; smaller images use the largest odd window that fits."""


def psnr(pred: np.ndarray, target: np.ndarray, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio 10 log10(max² / MSE) in dB; inf for identical images.

    Args:
        pred, target: [H, W, 3] (any matching shape) in [0, max_value].
    """
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(target, np.float64)) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(max_value**2 / mse))


def ssim(pred: np.ndarray, target: np.ndarray) -> float:
    """Structural similarity (skimage, Gaussian-free 7x7 window) of [H, W, 3] images in [0, 1]."""
    win = min(SSIM_WINDOW, *pred.shape[:2])
    win = win if win % 2 == 1 else win - 1
    return float(
        structural_similarity(
            np.asarray(pred, np.float64), np.asarray(target, np.float64), channel_axis=-1, data_range=1.0, win_size=win
        )
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
    if pred.shape != target.shape:
        raise ValueError(f"prediction {np.shape(pred_ids)} and target {np.shape(target_ids)} differ")
    C = len(class_ids)
    t_pos = np.searchsorted(class_ids, target).clip(0, C - 1)
    valid = class_ids[t_pos] == target
    if ignore_index is not None:
        valid &= target != ignore_index
    p_pos = np.searchsorted(class_ids, pred).clip(0, C - 1)
    cols = np.where(class_ids[p_pos] == pred, p_pos, C)
    conf = np.zeros((C, C + 1), dtype=np.int64)
    np.add.at(conf, (t_pos[valid], cols[valid]), 1)
    return conf


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


def depth_error(pred: np.ndarray, target: np.ndarray, valid: np.ndarray | None = None) -> dict[str, float]:
    """Depth errors over valid pixels: abs_rel = mean |p - t| / t, rmse, mae (world units)."""
    pred = np.asarray(pred, np.float64)
    target = np.asarray(target, np.float64)
    valid = (target > 0) if valid is None else (np.asarray(valid, bool) & (target > 0))
    if not valid.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "mae": float("nan")}
    diff = pred[valid] - target[valid]
    return {
        "abs_rel": float(np.mean(np.abs(diff) / target[valid])),
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "mae": float(np.mean(np.abs(diff))),
    }
