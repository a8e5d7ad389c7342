"""Render rays through a field: sampling + field evaluation + the pure rendering maths.

Rays here are in the field's normalised frame (see :class:`scenelabel.frame.SceneFrame`).
Samples in cells the occupancy grid marks empty are never evaluated (σ = 0 there).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .rendering import (
    class_log_probs_from_scores,
    class_log_probs_from_weights,
    composite_rgb,
    depth_from_weights,
    weights_from_density,
)
from .sampling import march, ray_aabb_intersect

__all__ = ["RayBundleOutput", "ray_intervals", "render_rays"]


@dataclass
class RayBundleOutput:
    """Per-ray composites (normalised frame). rgb is None when colour was not asked for."""

    rgb: torch.Tensor | None  # [n_rays, 3]
    depth: torch.Tensor  # [n_rays]
    opacity: torch.Tensor  # [n_rays]
    class_log_probs: torch.Tensor  # [n_rays, C]
    n_evaluated: int  # samples the field evaluated


def ray_intervals(
    origins: torch.Tensor,
    directions: torch.Tensor,
    aabb: torch.Tensor,
    near: torch.Tensor | None = None,
    far: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Where rays are inside the scene box, intersected with an optional [near, far] (t ≥ 0).

    Args:
        origins, directions: [n_rays, 3], directions unit length.
        aabb: [2, 3].
        near, far: [n_rays] or None.
    Returns:
        t_min, t_max: [n_rays]; t_max <= t_min for rays that see nothing of the box.
    """
    t_min, t_max = ray_aabb_intersect(origins, directions, aabb)
    t_min = t_min.clamp(min=0.0)
    if near is not None:
        t_min = torch.maximum(t_min, near)
    if far is not None:
        t_max = torch.minimum(t_max, far)
    return t_min, t_max


def render_rays(
    field,
    occupancy,
    origins: torch.Tensor,
    directions: torch.Tensor,
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    step: float,
    n_samples: int,
    jitter: torch.Tensor | None = None,
    background: torch.Tensor | None = None,
    with_rgb: bool = True,
    *,
    detach_semantic_weights: bool = False,
) -> RayBundleOutput:
    """March rays from t_min to t_max and composite the field's outputs.

    Samples are spaced as the field's warp asks (``field.warp.spacing``, :func:`scenelabel.sampling.march`):
    equal steps of ``step``, or ``n_samples`` equal steps of disparity.

    Args:
        field: a SemanticField3D (callable as field(points, dirs) and field.semantics(points)).
        occupancy: callable points [..., 3] -> bool [...], True where the field may be non-empty.
        origins, directions: [n_rays, 3] (unit directions).
        t_min, t_max: [n_rays] from :func:`ray_intervals`.
        step, n_samples: marching step (uniform spacing) and samples per ray.
        jitter: [n_rays] in [0, 1) (training) or None.
        background: [3] colour behind the scene, or None for black.
        with_rgb: evaluate colour (False: density and classes only, cheaper).
        detach_semantic_weights: composite classes with detached weights, so a loss on the class
            probabilities does not move σ (only the class scores).
    The class composite follows ``field.config.semantic_rendering``: "probs" (eq. 7) or
    "scores" (softmax after compositing).
    Returns:
        RayBundleOutput.
    """
    t_min, t_max = field.warp.clip(origins, directions, t_min, t_max)
    t_starts, t_ends = march(field.warp.spacing, t_min, t_max, step, n_samples, jitter)  # [n_rays, S]
    t_mids = 0.5 * (t_starts + t_ends)
    points = origins[:, None, :] + t_mids[..., None] * directions[:, None, :]  # [n_rays, S, 3]
    keep = (t_ends > t_starts) & occupancy(points)  # [n_rays, S]
    # Skipped samples have σ = 0 and change nothing, so the kept ones are moved to the front of
    # each ray: [n_rays, K] with K the largest count, padded with zero-length intervals.
    counts = keep.sum(-1)
    K = max(int(counts.max()) if counts.numel() else 0, 1)
    rows, cols = keep.nonzero(as_tuple=True)
    packed_cols = torch.cumsum(keep, dim=-1)[rows, cols] - 1
    at = (rows, packed_cols)
    kept_points = points[rows, cols]
    zeros = torch.zeros(t_min.shape[0], K, dtype=points.dtype, device=points.device)
    t_starts = zeros.index_put(at, t_starts[rows, cols])
    t_ends = zeros.index_put(at, t_ends[rows, cols])
    t_mids = zeros.index_put(at, t_mids[rows, cols])
    if with_rgb:
        s, c, l = field(kept_points, directions[rows])
        rgbs = points.new_zeros(t_min.shape[0], K, 3).index_put(at, c)
    else:
        s, l = field.semantics(kept_points)
    sigmas = zeros.index_put(at, s)
    class_logits = points.new_zeros(t_min.shape[0], K, field.num_classes).index_put(at, l)
    weights, _, _ = weights_from_density(sigmas, t_ends - t_starts)
    composite_classes = (
        class_log_probs_from_scores if field.config.semantic_rendering == "scores" else class_log_probs_from_weights
    )
    rgb = composite_rgb(weights, rgbs, background) if with_rgb else None
    # A ray whose interval is empty (t_max < t_min: it misses the box or [near, far]) reports its
    # t_max (≥ 0): the requested far, or where it leaves the box.
    t_hi = t_max.clamp(min=0.0)
    depth = depth_from_weights(weights, t_mids, torch.minimum(t_min, t_hi), t_hi)
    return RayBundleOutput(
        rgb=rgb,
        depth=depth,
        opacity=weights.sum(-1),
        class_log_probs=composite_classes(weights.detach() if detach_semantic_weights else weights, class_logits),
        n_evaluated=int(kept_points.shape[0]),
    )
