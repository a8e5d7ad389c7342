"""Volume rendering as pure functions (the seed paper's eqs. 2-7, after Mildenhall et al. 2020).

Samples along a ray i are intervals [t_starts, t_ends) with density σ_i. With δ_i = t_ends - t_starts:

    τ_i = σ_i δ_i                          optical depth of interval i
    α_i = 1 - exp(-τ_i)                    opacity of interval i                (eq. 3)
    T_i = exp(-Σ_{j<i} τ_j)                transmittance reaching interval i    (eq. 2)
    w_i = T_i α_i                          weight of interval i
    C   = Σ w_i c_i                        composite colour                     (eq. 2)
    P   = Σ w_i softmax(l_i) / Σ w_i       class probabilities                  (eq. 7)
    P'  = softmax(Σ w_i l_i)               scores composited, softmax after     ("eq. 3" variant)

and, as a training regulariser, mip-NeRF 360's distortion of the weights along a ray
(:func:`distortion_from_weights`).

Transmittance is computed in log space (an exclusive cumulative sum of τ, then one exp) so it
neither underflows step by step nor loses precision for tiny τ; α uses ``-expm1(-τ)``, exact for
tiny τ. fp16/bf16 inputs are computed in fp32 (and returned as fp32). σ is clamped to
[0, SIGMA_MAX] and τ to [0, TAU_MAX] so that σ in [0, inf] and δ in
[0, 1e10] give finite values and finite gradients (inf * 0 would otherwise be NaN).

All functions take ``[n_rays, n_samples]`` tensors (any leading batch shape works) and are
differentiable. The maths never imports models or training.
"""

from __future__ import annotations

import math

import torch

from scenelabel.render.constants import OPACITY_EPS

__all__ = [
    "SIGMA_MAX",
    "DELTA_MAX",
    "TAU_MAX",
    "OPACITY_EPS",
    "optical_depth",
    "alphas_from_density",
    "trans_from_density",
    "weights_from_density",
    "composite",
    "composite_rgb",
    "depth_from_weights",
    "depth_at_transmittance",
    "depth_of_max_weight",
    "class_probs_from_weights",
    "class_log_probs_from_weights",
    "class_log_probs_from_sample_weights",
    "class_probs_from_sample_weights",
    "class_log_probs_from_scores",
    "distortion_from_weights",
    "weight_before",
]

SIGMA_MAX = 1e30
"""σ is clamped to this finite value first, so σ = inf still gives τ = σ δ = 0 for δ = 0."""

DELTA_MAX = 1e30
"""δ is clamped to this finite value, so an overflowed δ (inf in fp16) times σ = 0 is 0, not NaN."""

TAU_MAX = 1e4
"""τ above this is already fully opaque (exp(-1e4) == 0 in fp64); the clamp keeps sums finite."""



def optical_depth(sigmas: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """τ = σ δ, finite for σ in [0, inf] and δ in [0, 1e10].

    Args:
        sigmas: [n_rays, n_samples] densities (per unit length), ≥ 0 (negatives are clamped).
        deltas: [n_rays, n_samples] interval lengths, ≥ 0.
    Returns:
        [n_rays, n_samples] τ in [0, TAU_MAX].
    """
    if sigmas.dtype in (torch.float16, torch.bfloat16):  # 16-bit input: do the maths in fp32
        sigmas, deltas = sigmas.float(), deltas.float()
    sigmas = sigmas.clamp(0.0, SIGMA_MAX)
    return (sigmas * deltas.clamp(0.0, DELTA_MAX)).clamp(0.0, TAU_MAX)


def alphas_from_density(sigmas: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """α_i = 1 - exp(-σ_i δ_i) (eq. 3), computed as -expm1(-τ) for precision at tiny τ.

    Args:
        sigmas, deltas: [n_rays, n_samples].
    Returns:
        [n_rays, n_samples] α in [0, 1].
    """
    return -torch.expm1(-optical_depth(sigmas, deltas))


def trans_from_density(sigmas: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """T_i = exp(-Σ_{j<i} σ_j δ_j) (eq. 2), the exclusive cumulative sum taken in log space.

    The exclusive sum is built by shifting (never by subtracting τ_i from an inclusive sum, which
    gives inf - inf = NaN after an opaque sample).

    Args:
        sigmas, deltas: [n_rays, n_samples].
    Returns:
        [n_rays, n_samples] T in [0, 1]; T_0 = 1.
    """
    tau = optical_depth(sigmas, deltas)
    csum = torch.cumsum(tau, dim=-1)
    exclusive = torch.cat([torch.zeros_like(csum[..., :1]), csum[..., :-1]], dim=-1)
    return torch.exp(-exclusive)


def weights_from_density(
    sigmas: torch.Tensor, deltas: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rendering weights w_i = T_i α_i.

    Args:
        sigmas: [n_rays, n_samples] densities.
        deltas: [n_rays, n_samples] interval lengths (t_ends - t_starts).
    Returns:
        weights, trans, alphas: each [n_rays, n_samples]. Σ_i w_i = 1 - T_{n} ≤ 1.
    """
    if sigmas.shape != deltas.shape:
        raise ValueError(f"sigmas {tuple(sigmas.shape)} and deltas {tuple(deltas.shape)} must match")
    alphas = alphas_from_density(sigmas, deltas)
    trans = trans_from_density(sigmas, deltas)
    return trans * alphas, trans, alphas


def depth_at_transmittance(
    sigmas: torch.Tensor, t_starts: torch.Tensor, t_ends: torch.Tensor, level: float = 0.5
) -> torch.Tensor:
    """Where each ray's transmittance T(t) = exp(-∫ σ) (eq. 1) falls to ``level``: with 0.5, the
    median termination depth, the surface as the maps define it (docs/conventions.md).

    σ is constant within each interval, so T is integrated exactly: inside the interval where the
    optical depth τ(t) crosses L = -log(level), t = t_start + (L - τ_before) / σ.

    Args:
        sigmas: [n_rays, n_samples] densities (per unit length).
        t_starts, t_ends: [n_rays, n_samples] sorted, non-overlapping intervals.
        level: transmittance in (0, 1).
    Returns:
        [n_rays] depth; ``inf`` where the ray keeps more than ``level`` to its last interval's end.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    target = -math.log(level)
    tau = optical_depth(sigmas, t_ends - t_starts)
    after = torch.cumsum(tau, dim=-1)  # τ at each interval's end
    crossed = after >= target
    reached = crossed.any(-1)
    i = crossed.to(torch.int8).argmax(-1, keepdim=True)  # the first interval that crosses
    before = (after - tau).gather(-1, i)[:, 0]
    sigma = sigmas.clamp(0.0, SIGMA_MAX).gather(-1, i)[:, 0].to(after.dtype)
    start, end = t_starts.gather(-1, i)[:, 0], t_ends.gather(-1, i)[:, 0]
    inside = start + (target - before) / sigma.clamp(min=torch.finfo(after.dtype).tiny)
    depth = torch.minimum(inside.to(start.dtype), end)
    return torch.where(reached, depth, torch.full_like(depth, math.inf))


def depth_of_max_weight(weights: torch.Tensor, t_starts: torch.Tensor, t_ends: torch.Tensor) -> torch.Tensor:
    """The middle of each ray's interval of largest weight w_i: the mode of its termination
    distribution (a surface's spike, where fog spread in front of it moves the median and the mean).

    Args:
        weights: [n_rays, n_samples].
        t_starts, t_ends: [n_rays, n_samples].
    Returns:
        [n_rays] distance; ``inf`` for a ray whose weights sum to at most OPACITY_EPS.
    """
    i = weights.argmax(-1, keepdim=True)
    t = (0.5 * (t_starts + t_ends)).gather(-1, i)[:, 0]
    return torch.where(weights.sum(-1) > OPACITY_EPS, t, torch.full_like(t, math.inf))


def composite(weights: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Σ_i w_i v_i over the sample axis.

    Args:
        weights: [n_rays, n_samples].
        values: [n_rays, n_samples, d].
    Returns:
        [n_rays, d].
    """
    dtype = torch.promote_types(weights.dtype, values.dtype)
    return torch.einsum("...s,...sd->...d", weights.to(dtype), values.to(dtype))


def composite_rgb(weights: torch.Tensor, rgbs: torch.Tensor, background: torch.Tensor | None = None) -> torch.Tensor:
    """Composite colour C = Σ w_i c_i + (1 - Σ w_i) c_bg (eq. 2 with a background colour).

    Args:
        weights: [n_rays, n_samples].
        rgbs: [n_rays, n_samples, 3].
        background: [3] or [n_rays, 3] colour behind the last sample, or None (black).
    Returns:
        [n_rays, 3].
    """
    rgb = composite(weights, rgbs)
    if background is not None:
        rgb = rgb + (1.0 - weights.sum(-1, keepdim=True)).clamp(min=0.0) * background.to(rgb.dtype)
    return rgb


def depth_from_weights(
    weights: torch.Tensor, t_mids: torch.Tensor, near: torch.Tensor, far: torch.Tensor
) -> torch.Tensor:
    """Expected depth of the visible surface, Σ w_i t_i / Σ w_i, clipped to [near, far].

    Depth is the distance along the unit ray direction. A ray with opacity below OPACITY_EPS
    reports ``far``.

    Args:
        weights: [n_rays, n_samples].
        t_mids: [n_rays, n_samples] sample distances.
        near, far: [n_rays] the ray's interval.
    Returns:
        [n_rays] depth.
    """
    t_mids, near, far = (x.to(weights.dtype) for x in (t_mids, near, far))
    opacity = weights.sum(-1)
    hit = opacity > OPACITY_EPS
    depth = (weights * t_mids).sum(-1) / torch.where(hit, opacity, torch.ones_like(opacity))
    depth = torch.where(hit, depth, far)
    return torch.minimum(torch.maximum(depth, near), far)


def _log_softmax(logits: torch.Tensor) -> torch.Tensor:
    """log softmax over the last axis as ``logits - logsumexp(logits)``: torch.log_softmax's values
    (logsumexp subtracts the row's largest logit first, so nothing overflows), faster on the CPU
    for rows as short as a room's classes (torch's log_softmax kernel is made for long rows)."""
    return logits - torch.logsumexp(logits, dim=-1, keepdim=True)


def class_log_probs_from_weights(weights: torch.Tensor, class_logits: torch.Tensor) -> torch.Tensor:
    """log P_c with P = Σ w_i softmax(l_i) / Σ w_i (eq. 7), computed stably in log space.

    log P_c = logsumexp_i(log w_i + log_softmax(l_i)_c) - log Σ w_i. Samples with w_i = 0 drop
    out exactly (log 0 = -inf); a ray whose weights are all below OPACITY_EPS gets the uniform
    distribution, so the result is finite everywhere and its gradient is too.

    Args:
        weights: [n_rays, n_samples].
        class_logits: [n_rays, n_samples, C].
    Returns:
        [n_rays, C] log-probabilities (each row's exp sums to 1).
    """
    n_classes = class_logits.shape[-1]
    opacity = weights.sum(-1, keepdim=True)  # [n_rays, 1]
    hit = opacity > OPACITY_EPS
    # Rays without weight get pseudo-weights 1 so that the discarded branch stays finite (a NaN
    # there would leak into the gradient through torch.where); their output is the uniform law.
    safe_weights = torch.where(hit, weights, torch.ones_like(weights))
    log_w = torch.log(safe_weights.clamp(min=torch.finfo(weights.dtype).tiny))
    log_w = torch.where(safe_weights > 0, log_w, torch.full_like(log_w, -torch.inf))
    log_p = _log_softmax(class_logits.to(weights.dtype))  # [n_rays, n_samples, C]
    joint = torch.logsumexp(log_w[..., None] + log_p, dim=-2)  # [n_rays, C]
    norm = torch.logsumexp(log_w, dim=-1, keepdim=True)  # [n_rays, 1]
    uniform = torch.full_like(joint, -math.log(n_classes))
    return torch.where(hit, joint - norm, uniform)


def class_log_probs_from_sample_weights(
    weights: torch.Tensor, class_logits: torch.Tensor, ray_indices: torch.Tensor, n_rays: int
) -> torch.Tensor:
    """:func:`class_log_probs_from_weights` (eq. 7 in log space) over samples given as a flat list
    with each sample's ray, not padded to [n_rays, n_samples]: the work follows the samples that
    exist, not the longest ray.

    Per ray and class, log Σ_i w_i softmax(l_i)_c is a segment log-sum-exp: the per-ray largest
    term (detached: the result and its gradient do not depend on the shift) is subtracted before
    the exponentials are summed (``index_add``). A ray whose weights sum to at most OPACITY_EPS
    gets the uniform distribution; a ray with more has a term equal to 1 after the shift, so the
    sum is at least 1 and its log is finite. A sample of weight 0 drops out exactly (log 0 = -inf:
    its weight is clamped to the dtype's smallest normal before the log only so that the discarded
    branch has a finite gradient).

    Args:
        weights: [n] sample weights (eq. 5), each ray's samples anywhere in the list.
        class_logits: [n, C].
        ray_indices: [n] int64, the ray of each sample, in [0, n_rays).
        n_rays: number of rays.
    Returns:
        [n_rays, C] log-probabilities (each row's exp sums to 1).
    """
    n_classes = class_logits.shape[-1]
    log_p = _log_softmax(class_logits.to(weights.dtype))  # [n, C]
    weighted = weights > 0  # [n]
    log_w = torch.log(weights.clamp(min=torch.finfo(weights.dtype).tiny))
    log_w = torch.where(weighted, log_w, torch.full_like(log_w, -torch.inf))
    terms = log_w[:, None] + log_p  # [n, C]
    shift = terms.new_full((n_rays, n_classes), -torch.inf).scatter_reduce(
        0, ray_indices[:, None].expand(-1, n_classes), terms.detach(), "amax"
    )
    shift = torch.where(torch.isfinite(shift), shift, torch.zeros_like(shift))  # [n_rays, C]
    sums = terms.new_zeros(n_rays, n_classes).index_add(0, ray_indices, torch.exp(terms - shift.index_select(0, ray_indices)))
    # Σ w over the samples of positive weight: as in the padded form, a sample of weight 0 has dropped
    # out and gets no gradient (through the normalisation either)
    positive = torch.where(weighted, weights, torch.zeros_like(weights))
    opacity = weights.new_zeros(n_rays).index_add(0, ray_indices, positive)[:, None]  # [n_rays, 1]
    hit = opacity > OPACITY_EPS
    joint = torch.log(torch.where(hit, sums, torch.ones_like(sums))) + shift  # sums >= 1 where hit
    norm = torch.log(torch.where(hit, opacity, torch.ones_like(opacity)))
    return torch.where(hit, joint - norm, torch.full_like(joint, -math.log(n_classes)))


def class_probs_from_sample_weights(
    weights: torch.Tensor, class_logits: torch.Tensor, ray_indices: torch.Tensor, n_rays: int
) -> torch.Tensor:
    """P = Σ w_i softmax(l_i) / Σ w_i (eq. 7) over samples given as a flat list with each sample's
    ray, summed directly: for renders and queries, which need no gradient (training uses
    :func:`class_log_probs_from_sample_weights`, whose log space keeps the gradient finite). Each
    term is a weight (at most 1) times a probability, so no sum overflows; a ray whose weights sum
    to at most OPACITY_EPS (nothing hit) gets the uniform distribution.

    Args:
        weights: [n] sample weights (eq. 5), ≥ 0, each ray's samples anywhere in the list.
        class_logits: [n, C].
        ray_indices: [n] int64, the ray of each sample, in [0, n_rays).
        n_rays: number of rays.
    Returns:
        [n_rays, C] probabilities (each row sums to 1).
    """
    n_classes = class_logits.shape[-1]
    probs = torch.softmax(class_logits.to(weights.dtype), dim=-1)  # [n, C]
    sums = probs.new_zeros(n_rays, n_classes).index_add_(0, ray_indices, probs * weights[:, None])
    opacity = weights.new_zeros(n_rays).index_add_(0, ray_indices, weights)[:, None]  # [n_rays, 1]
    hit = opacity > OPACITY_EPS
    return torch.where(hit, sums / torch.where(hit, opacity, torch.ones_like(opacity)), 1.0 / n_classes)


def class_probs_from_weights(weights: torch.Tensor, class_logits: torch.Tensor) -> torch.Tensor:
    """P = Σ w_i softmax(l_i) / Σ w_i (eq. 7): per-ray class probabilities, summing to 1.

    Args:
        weights: [n_rays, n_samples].
        class_logits: [n_rays, n_samples, C].
    Returns:
        [n_rays, C]; uniform for rays with opacity below OPACITY_EPS.
    """
    return torch.exp(class_log_probs_from_weights(weights, class_logits))


def class_log_probs_from_scores(weights: torch.Tensor, class_logits: torch.Tensor) -> torch.Tensor:
    """log softmax(Σ_i w_i l_i): class scores composited like colour, softmax after.

    The seed paper's eq. 3 alternative to eq. 7 (no per-sample class probabilities), as
    Semantic-NeRF renders logits. The scores l_i are the class head's logits (eq. 6 field) or the
    per-class log-densities (eq. 5 field). A ray without weight composites to 0 scores: uniform.

    Args:
        weights: [n_rays, n_samples].
        class_logits: [n_rays, n_samples, C].
    Returns:
        [n_rays, C] log-probabilities (each row's exp sums to 1).
    """
    dtype = torch.promote_types(weights.dtype, torch.float32)
    return _log_softmax(composite(weights.to(dtype), class_logits.to(dtype)))


def distortion_from_weights(weights: torch.Tensor, s_starts: torch.Tensor, s_ends: torch.Tensor) -> torch.Tensor:
    """The distortion of each ray's weights (Barron et al. 2022, mip-NeRF 360, eq. 15):

        L_dist = Σ_i Σ_j w_i w_j |m_i - m_j| + 1/3 Σ_i w_i² (s_ends_i - s_starts_i),  m = (s_starts + s_ends) / 2

    It is small when a ray's weight sits in one short stretch (a surface) and large when it is
    spread along the ray (fog, a surface smeared in depth). Computed in O(n_samples) with
    exclusive cumulative sums (their eq. in appendix: Σ_{i,j} w_i w_j |m_i - m_j| =
    2 Σ_i w_i (m_i Σ_{j<i} w_j - Σ_{j<i} w_j m_j)), which needs each ray's intervals sorted and
    not overlapping; intervals of zero weight may come anywhere (padding). No eps: every term is
    a product of finite inputs.

    Args:
        weights: [n_rays, n_samples] w_i.
        s_starts, s_ends: [n_rays, n_samples] interval ends as normalised ray distances s in
            [0, 1] (:func:`scenelabel.render.sampling.normalized_distances`), so the loss does not
            depend on the scene's scale.
    Returns:
        [n_rays] L_dist >= 0.
    """
    s_starts, s_ends = s_starts.to(weights.dtype), s_ends.to(weights.dtype)
    mids = 0.5 * (s_starts + s_ends)
    weighted = weights * mids

    def exclusive_cumsum(x: torch.Tensor) -> torch.Tensor:
        return torch.cat([torch.zeros_like(x[..., :1]), torch.cumsum(x, -1)[..., :-1]], -1)

    between = 2.0 * (weights * (mids * exclusive_cumsum(weights) - exclusive_cumsum(weighted))).sum(-1)
    within = (weights**2 * (s_ends - s_starts)).sum(-1) / 3.0
    return between + within


def weight_before(weights: torch.Tensor, t_ends: torch.Tensor, t_free: torch.Tensor) -> torch.Tensor:
    """How much of each ray terminates before ``t_free``: Σ_i w_i over the samples that end at or
    before it (the line-of-sight idea of Urban Radiance Fields, Rematas et al. 2022, eq. 8: a depth
    sensor saw empty space up to there, so no weight belongs in front of it).

    Args:
        weights: [n_rays, n_samples] (eq. 3's w_i).
        t_ends: [n_rays, n_samples] sample interval ends.
        t_free: [n_rays] the free-space limit; NaN (no measurement) gives 0.
    Returns:
        [n_rays] in [0, 1].
    """
    front = t_ends <= t_free[:, None]  # NaN compares False: no sample counts
    return (weights * front.to(weights.dtype)).sum(-1)

