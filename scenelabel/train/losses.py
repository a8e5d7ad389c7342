"""Training losses: photometric MSE and cross-entropy on rendered class probabilities."""

from __future__ import annotations

import torch

__all__ = ["photometric_mse", "semantic_cross_entropy", "semantic_focal_loss", "class_balance_weights", "total_variation",
           "total_variation_grad", "solid_interior_loss", "depth_loss", "free_space_loss", "composite_target",
           "mean_colour_mse"]

SOLID_TAU = 1.4
"""The solid-interior term asks for this optical depth per marching step inside surfaces: one step
there is 1 - exp(-1.4) ≈ 75% opaque (a point is occupied at 50%)."""

SOLID_SIGMA_EPS = 1e-10
"""Added to σ before its log in :func:`solid_interior_loss`: σ = 0 (outside a forward warp's
frustum) gives a finite loss and gradient."""


def solid_interior_loss(sigmas: torch.Tensor, step: float, tau: float = SOLID_TAU) -> torch.Tensor:
    """Mean hinge on log density, ``relu(log(tau / step) - log(σ + SOLID_SIGMA_EPS))``, at points
    just inside the surfaces the rays render: those points barely change any pixel (the ray is
    nearly opaque there), so photometric losses leave their density where it started, and a
    point on a wall or a table top reads as free space. With σ = exp(raw), the gradient on raw is
    -1 per point until one marching step there has optical depth ``tau``.

    Args:
        sigmas: [n] densities (per unit length) at points inside surfaces.
        step: the marching step (same length unit).
        tau: target optical depth per step.
    Returns:
        scalar; 0 for no points.
    """
    if sigmas.numel() == 0:
        return sigmas.new_zeros(())
    target = torch.log(torch.as_tensor(tau / step, dtype=sigmas.dtype, device=sigmas.device))
    return torch.relu(target - torch.log(sigmas + SOLID_SIGMA_EPS)).mean()


DEPTH_HUBER = 0.02
"""Relative depth error at which :func:`depth_loss` turns from quadratic to linear: sensor noise
(1-2 % for a phone's LiDAR) is fitted in the quadratic part, and a wrong measurement (a flying pixel,
a reflection) pulls no harder than any other error beyond 2 %."""


def depth_loss(termination: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Huber loss (threshold DEPTH_HUBER) on the relative error of each ray's expected termination
    distance, ``(termination - target) / target``, over the rays with a measurement.

    ``termination`` should be Σ_i w_i t_i + (1 - Σ_i w_i) t_far (the expected depth with the
    transmittance left at the end of the ray placed at its far end; DS-NeRF, Deng et al. 2022, and
    Urban Radiance Fields use the expected termination the same way): a ray left partly transparent
    in front of a measured surface then terminates too far, so the loss also asks for an opaque
    surface, not fog at the right mean distance.

    Args:
        termination: [n_rays] expected termination distance.
        target: [n_rays] measured distance along the ray (same unit); NaN = no measurement.
    Returns:
        scalar; 0 when no ray has a measurement.
    """
    valid = torch.isfinite(target) & (target > 0)
    if not bool(valid.any()):
        return termination.sum() * 0.0  # zero, with a (zero) gradient
    relative = (termination[valid] - target[valid]) / target[valid]
    return torch.nn.functional.smooth_l1_loss(relative, torch.zeros_like(relative), beta=DEPTH_HUBER)


def free_space_loss(front_weight: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean weight in front of the measured surfaces (:func:`scenelabel.render.volume.weight_before`),
    over the rays with a measurement: the fog a photometric loss leaves in free space.

    Args:
        front_weight: [n_rays] in [0, 1].
        target: [n_rays] measured distances; NaN = no measurement (those rays do not count).
    Returns:
        scalar; 0 when no ray has a measurement.
    """
    valid = torch.isfinite(target) & (target > 0)
    if not bool(valid.any()):
        return front_weight.sum() * 0.0  # zero, with a (zero) gradient
    return front_weight[valid].mean()


def composite_target(rgb, alpha, background):
    """The colour a pixel with transparency stands for: ``rgb * alpha + background * (1 - alpha)``,
    composited on the same background the render composites on (Scene.image_alphas, train.background).

    Torch tensors or numpy arrays alike (one kind per call).

    Args:
        rgb: [..., 3] the stored colour.
        alpha: [...] in [0, 1], or None (an opaque pixel: ``rgb`` is returned unchanged).
        background: [3] or [..., 3] (a random colour per ray), a scalar, or None (black).
    Returns:
        [..., 3].
    """
    if alpha is None:
        return rgb
    a = alpha[..., None]
    out = rgb * a
    return out if background is None else out + background * (1.0 - a)


def mean_colour_mse(rgb: torch.Tensor, alpha: torch.Tensor | None, background, random_background: bool) -> float:
    """The photometric MSE of predicting every target as their mean colour: the colour variance of
    the targets (:func:`composite_target` on ``background``; with ``random_background`` composited on
    its mean, 0.5 grey, plus the uniform colour's variance 1/12 weighted by (1 - alpha)^2).

    Args:
        rgb: [n, 3] stored colours; alpha: [n] or None (opaque).
        background: what :func:`composite_target` takes (ignored with ``random_background``).
        random_background: a new uniform random colour behind each ray.
    Returns:
        float.
    """
    composited = composite_target(rgb, alpha, 0.5 if random_background else background)
    mse = float(composited.var(0, unbiased=False).mean())
    if alpha is not None and random_background:
        mse += float(((1.0 - alpha) ** 2).mean()) / 12.0
    return mse


def photometric_mse(rgb: torch.Tensor, target: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error over rays and channels. rgb, target: [n_rays, 3] -> scalar.

    ``weights``: [n_rays] per-ray factors on the squared error (None: 1 each), still divided by
    3 n_rays, e.g. importance weights of rays drawn class by class
    (:func:`scenelabel.render.sampling.class_balanced_rays`)."""
    squared = (rgb - target) ** 2
    if weights is None:
        return torch.mean(squared)
    return torch.sum(weights[:, None] * squared) / squared.numel()


def total_variation(grid: torch.Tensor) -> torch.Tensor:
    """Squared total variation of a vertex grid, the smoothness prior of explicit radiance
    fields (Plenoxels, Fridovich-Keil et al. 2022, eq. 4, squared differences as in DVGO):
    the mean over vertices of Σ_axes (v_next - v)^2, summed over channels.

    Args:
        grid: [X, Y, Z, C], X, Y, Z >= 2.
    Returns:
        scalar.
    """
    if grid.ndim != 4 or min(grid.shape[:3]) < 2:
        raise ValueError(f"total_variation needs a [X, Y, Z, C] grid with >= 2 vertices per axis, got {tuple(grid.shape)}")
    dx = (grid[1:, :-1, :-1] - grid[:-1, :-1, :-1]).square()
    dy = (grid[:-1, 1:, :-1] - grid[:-1, :-1, :-1]).square()
    dz = (grid[:-1, :-1, 1:] - grid[:-1, :-1, :-1]).square()
    return (dx + dy + dz).sum(-1).mean()


def total_variation_grad(grid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`total_variation` and its gradient with respect to ``grid``, without autograd (for a
    slab of a large grid: a step adds it to the slab of the grid's gradient in place).

    Args:
        grid: [X, Y, Z, C], X, Y, Z >= 2.
    Returns:
        (scalar, [X, Y, Z, C]).
    """
    with torch.no_grad():
        value = total_variation(grid)
        base = grid[:-1, :-1, :-1]
        scale = 2.0 / (base[..., 0].numel())  # d/dv of mean_v Σ d^2
        grad = torch.zeros_like(grid)
        for axis in range(3):
            step = [slice(None, -1)] * 3
            step[axis] = slice(1, None)
            diff = (grid[tuple(step)] - base) * scale
            grad[tuple(step)] += diff
            grad[:-1, :-1, :-1] -= diff
    return value, grad


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


def _labelled_mean(
    per_ray: torch.Tensor,
    targets: torch.Tensor,
    labelled: torch.Tensor,
    class_weights: torch.Tensor | None,
    ray_weights: torch.Tensor | None,
) -> torch.Tensor:
    """Σ w loss / Σ w over the labelled rays, w = class_weights[target] x ray_weights (1 where None);
    the plain mean without either. per_ray, targets: [n_labelled]; labelled: [n_rays] bool. The
    1e-12 floor on Σ w only keeps an all-zero weighting finite (the loss is then 0)."""
    if class_weights is None and ray_weights is None:
        return per_ray.mean()
    w = torch.ones_like(per_ray) if class_weights is None else class_weights[targets]
    if ray_weights is not None:
        w = w * ray_weights[labelled]
    return (w * per_ray).sum() / w.sum().clamp(min=1e-12)


def semantic_cross_entropy(
    class_log_probs: torch.Tensor,
    target_channels: torch.Tensor,
    class_weights: torch.Tensor | None = None,
    ray_weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Cross-entropy -log P_target of the composited class distribution (seed paper eq. 7 + CE).

    Pixels with target -1 (ignore_index, unlabelled views, classes without a channel) are excluded;
    with no labelled pixel in the batch the loss is 0 (and still differentiable). With
    ``class_weights`` [C] and / or ``ray_weights`` [n_rays] (e.g. the importance weights of rays drawn
    class by class, :func:`scenelabel.render.sampling.class_balanced_rays`), the loss is the
    weighted mean Σ w (-log P_t) / Σ w, w = w_t x the ray's weight.

    Args:
        class_log_probs: [n_rays, C] log-probabilities.
        target_channels: [n_rays] int64 channel index or -1.
        class_weights: [C] or None.
        ray_weights: [n_rays] or None.
    Returns:
        scalar mean over labelled rays.
    """
    labelled = target_channels >= 0
    if not bool(labelled.any()):
        return class_log_probs.sum() * 0.0
    targets = target_channels[labelled]
    nll = -class_log_probs[labelled].gather(1, targets[:, None]).squeeze(1)
    return _labelled_mean(nll, targets, labelled, class_weights, ray_weights)


def semantic_focal_loss(
    class_log_probs: torch.Tensor,
    target_channels: torch.Tensor,
    gamma: float = 2.0,
    class_weights: torch.Tensor | None = None,
    ray_weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Focal loss -α_t (1 - P_t)^γ log P_t (Lin et al. 2017) on the composited class distribution.

    Down-weights pixels the field already labels confidently, so rare and hard pixels (thin
    structures, boundaries) count more. γ = 0 gives exactly :func:`semantic_cross_entropy`;
    ``class_weights`` [C] play the per-class α_t and ``ray_weights`` [n_rays] weigh rays, both as
    there (normalised: Σ w loss / Σ w). Masking of unlabelled pixels (-1) is as in :func:`semantic_cross_entropy`.

    Args:
        class_log_probs: [n_rays, C] log-probabilities.
        target_channels: [n_rays] int64 channel index or -1.
        gamma: focusing parameter γ >= 0.
        class_weights: [C] or None.
        ray_weights: [n_rays] or None.
    Returns:
        scalar mean over labelled rays.
    """
    if not gamma >= 0:
        raise ValueError(f"focal gamma must be >= 0, got {gamma}")
    labelled = target_channels >= 0
    if not bool(labelled.any()):
        return class_log_probs.sum() * 0.0
    targets = target_channels[labelled]
    log_p = class_log_probs[labelled].gather(1, targets[:, None]).squeeze(1)
    # (1 - P)^γ with 1 - P = -expm1(log P): exact for P near 1, where the focal factor matters most
    loss = -(-torch.expm1(log_p)).clamp(min=0.0).pow(gamma) * log_p
    return _labelled_mean(loss, targets, labelled, class_weights, ray_weights)
