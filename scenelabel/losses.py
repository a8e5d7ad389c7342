"""Training losses: photometric MSE and cross-entropy on rendered class probabilities."""

from __future__ import annotations

import torch

__all__ = ["photometric_mse", "semantic_cross_entropy", "class_balance_weights"]


def photometric_mse(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error over rays and channels. rgb, target: [n_rays, 3] -> scalar."""
    return torch.mean((rgb - target) ** 2)


def class_balance_weights(channels: torch.Tensor, num_classes: int) -> torch.Tensor:
    """Median-frequency balancing (Eigen & Fergus 2015): w_c = median(f) / f_c.

    Args:
        channels: [N] int64 training-pixel channels (-1 = unlabelled, ignored).
        num_classes: C.
    Returns:
        [C] weights; a class with no pixel gets weight 0 (it never appears as a target).
    """
    counts = torch.bincount(channels[channels >= 0], minlength=num_classes).double()
    present = counts > 0
    freq = counts / counts.sum().clamp(min=1.0)
    median = freq[present].median() if bool(present.any()) else torch.tensor(1.0, dtype=torch.float64)
    weights = torch.where(present, median / freq.clamp(min=1e-12), torch.zeros_like(freq))
    return weights.float()


def semantic_cross_entropy(
    class_log_probs: torch.Tensor, target_channels: torch.Tensor, class_weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Cross-entropy -log P_target of the composited class distribution (seed paper eq. 7 + CE).

    Pixels with target -1 (ignore_index, unlabelled views, classes without a channel) are excluded;
    with no labelled pixel in the batch the loss is 0 (and still differentiable). With
    ``class_weights`` [C], the loss is the weighted mean Σ w_t (-log P_t) / Σ w_t.

    Args:
        class_log_probs: [n_rays, C] log-probabilities.
        target_channels: [n_rays] int64 channel index or -1.
    Returns:
        scalar mean over labelled rays.
    """
    labelled = target_channels >= 0
    if not bool(labelled.any()):
        return class_log_probs.sum() * 0.0
    targets = target_channels[labelled]
    nll = -class_log_probs[labelled].gather(1, targets[:, None]).squeeze(1)
    if class_weights is None:
        return nll.mean()
    w = class_weights[targets]
    return (w * nll).sum() / w.sum().clamp(min=1e-12)
