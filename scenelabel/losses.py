"""Training losses: photometric MSE and cross-entropy on rendered class probabilities."""

from __future__ import annotations

import torch

__all__ = ["photometric_mse", "semantic_cross_entropy"]


def photometric_mse(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error over rays and channels. rgb, target: [n_rays, 3] -> scalar."""
    return torch.mean((rgb - target) ** 2)


def semantic_cross_entropy(class_log_probs: torch.Tensor, target_channels: torch.Tensor) -> torch.Tensor:
    """Cross-entropy -log P_target of the composited class distribution (seed paper eq. 7 + CE).

    Pixels with target -1 (ignore_index, unlabelled views, classes without a channel) are excluded;
    with no labelled pixel in the batch the loss is 0 (and still differentiable).

    Args:
        class_log_probs: [n_rays, C] log-probabilities.
        target_channels: [n_rays] int64 channel index or -1.
    Returns:
        scalar mean over labelled rays.
    """
    labelled = target_channels >= 0
    if not bool(labelled.any()):
        return class_log_probs.sum() * 0.0
    picked = class_log_probs[labelled].gather(1, target_channels[labelled, None])
    return -picked.mean()
