"""Render rays through a field: sampling + field evaluation + the pure rendering maths.

Rays here are in the field's normalised frame (see :class:`scenelabel.geometry.frame.SceneFrame`).
Samples in cells the density grid marks empty are never evaluated (σ = 0 there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from scenelabel.render.constants import EARLY_STOP_TRANS
from scenelabel.render.sampling import (
    importance_sample,
    march,
    merge_intervals,
    normalized_distances,
    ray_aabb_intersect,
)
from scenelabel.render.volume import (
    class_log_probs_from_sample_weights,
    class_log_probs_from_scores,
    class_probs_from_sample_weights,
    composite_rgb,
    depth_at_transmittance,
    depth_from_weights,
    distortion_from_weights,
    weight_before,
    weights_from_density,
)

__all__ = [
    "Marching",
    "CompositeOptions",
    "Skipping",
    "RayBundleOutput",
    "ray_intervals",
    "render_rays",
    "render_rays_early_stop",
    "render_rays_hierarchical",
]


EARLY_STOP_SEGMENT = 8
"""Samples per ray evaluated between two transmittance checks."""

OPAQUE_TRANS = 0.1
"""``RayBundleOutput.t_opaque`` is where a ray's transmittance falls to this: past it, what the
field holds changes a pixel by at most this fraction (the solid-interior term trains there)."""


@dataclass(frozen=True)
class Marching:
    """Where samples go along a ray: equal steps of ``step`` (normalised units), or ``n_samples``
    equal steps of disparity (the warp's spacing, :func:`scenelabel.render.sampling.march`), at most
    ``n_samples`` per ray. Training and queries take it from :meth:`across_box`, so they march alike."""

    step: float
    n_samples: int

    @classmethod
    def across_box(cls, aabb_n: torch.Tensor, n_steps: int) -> "Marching":
        """``n_steps`` steps across the diagonal of the box ``aabb_n`` [2, 3] (``sampling.n_steps``)."""
        diag = float(torch.linalg.norm(aabb_n[1] - aabb_n[0]))
        return cls(diag / n_steps, n_steps + 1)


@dataclass(frozen=True)
class CompositeOptions:
    """What a render composites besides σ and classes."""

    background: torch.Tensor | None = None  # [3] or [n_rays, 3] colour behind the scene; None: black
    with_rgb: bool = True  # evaluate colour (False: density and classes only, cheaper)
    # composite classes with detached weights, so a loss on the class probabilities does not move σ
    detach_semantic_weights: bool = False
    # [n_rays] distances before which each ray should be empty (a depth sensor saw free space
    # there; NaN: no such knowledge): the render reports the weight in front of them (``front_weight``)
    free_until: torch.Tensor | None = None
    # [n_rays] bool: rays whose class composite moves σ but not the classes (their samples' class
    # logits detached): a loss on their labels can only move density to where the field already
    # holds the class (training's open rays, ``sampling.grid_open_labels`` "geometry")
    geometry_only_labels: torch.Tensor | None = None


NO_OPTIONS = CompositeOptions()


@dataclass(frozen=True)
class Skipping:
    """Which of the samples in occupied cells :func:`render_rays` evaluates (training's choices).

    ``min_trans``: 0 evaluates every sample in an occupied cell; above 0, a pass without
    gradients finds each ray's samples behind the point where its transmittance falls below
    ``min_trans`` (:func:`_samples_before_opaque`, from the density alone), and only those in front
    are evaluated and composited (nerfacc's ``early_stop_eps`` in training). The dropped weights
    sum to less than ``min_trans``, so the composite moves by less than that times its range, and so
    does the gradient (T < ``min_trans`` scales it).
    ``open_rays``: [n_rays] bool or None: rays whose samples count as occupied wherever they lie,
    whatever the occupancy says (training: a thin object in cells the grid emptied gets a gradient).
    """

    min_trans: float = 0.0
    open_rays: torch.Tensor | None = None  # [n_rays] bool


NO_SKIPPING = Skipping()


@dataclass
class RayBundleOutput:
    """Per-ray composites (normalised frame). rgb is None when colour was not asked for."""

    rgb: torch.Tensor | None  # [n_rays, 3]
    depth: torch.Tensor  # [n_rays]
    opacity: torch.Tensor  # [n_rays]
    class_log_probs: torch.Tensor  # [n_rays, C]
    n_evaluated: int  # samples the field evaluated
    # training's terms (None from render_rays_early_stop, which renders and queries use):
    distortion: torch.Tensor | None = None  # [n_rays] mip-NeRF 360's L_dist of the weights (a regulariser)
    t_opaque: torch.Tensor | None = None  # [n_rays] where the transmittance falls to OPAQUE_TRANS (inf: never), no gradient
    front_weight: torch.Tensor | None = None  # [n_rays] Σ w_i over samples ending before options.free_until
    # the evaluated samples (render_rays only): their points [k, 3] (world) and σ [k], no gradient
    sample_points: torch.Tensor | None = None
    sample_sigmas: torch.Tensor | None = None


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
    marching: Marching,
    jitter: torch.Tensor | None = None,
    options: CompositeOptions = NO_OPTIONS,
    skipping: Skipping = NO_SKIPPING,
) -> RayBundleOutput:
    """March rays from t_min to t_max and composite the field's outputs.

    Samples are spaced as the field's warp asks (``field.warp.spacing``, :func:`scenelabel.render.sampling.march`):
    equal steps of ``step``, or ``n_samples`` equal steps of disparity.

    Args:
        field: a FieldNetwork (callable as field(points, dirs) and field.semantics(points)).
        occupancy: callable points [..., 3] -> bool [...], True where the field may be non-empty.
        origins, directions: [n_rays, 3] (unit directions).
        t_min, t_max: [n_rays] from :func:`ray_intervals`.
        marching: the step (uniform spacing) and samples per ray.
        jitter: [n_rays] in [0, 1) (training) or None.
        options: background, colour or not, detached class weights (:class:`CompositeOptions`).
        skipping: the transmittance below which a ray's samples are dropped, and the rays that
            ignore ``occupancy`` (:class:`Skipping`; default: neither).
    The class composite follows ``field.config.semantic_rendering``: "probs" (eq. 7) or
    "scores" (softmax after compositing).
    Returns:
        RayBundleOutput; ``n_evaluated`` counts the samples whose density was evaluated (with
        ``skipping.min_trans``: in the pass without gradients; the field then runs again on those kept).
    """
    min_trans, open_rays = skipping.min_trans, skipping.open_rays
    t_min, t_max = field.warp.clip(origins, directions, t_min, t_max)
    t_starts, t_ends = march(field.warp.spacing, t_min, t_max, marching.step, marching.n_samples, jitter)  # [n_rays, S]
    # [n_rays, S] is as wide as the longest ray: the grid is read only at the intervals of positive length
    rows, cols = (t_ends > t_starts).nonzero(as_tuple=True)  # row-major: each ray's samples in order
    t_mids = 0.5 * (_take(t_starts, rows, cols) + _take(t_ends, rows, cols))  # [m]
    points = origins.index_select(0, rows) + t_mids[:, None] * directions.index_select(0, rows)  # [m, 3]
    occupied = occupancy(points)  # [m]
    if open_rays is not None:
        occupied = occupied | open_rays.index_select(0, rows)
    keep = occupied.nonzero().squeeze(1)  # [k]
    rows, cols = rows.index_select(0, keep), cols.index_select(0, keep)
    points = points.index_select(0, keep)
    n_evaluated = len(rows)
    if min_trans > 0:
        deltas = _take(t_ends, rows, cols) - _take(t_starts, rows, cols)
        kept, n_evaluated = _samples_before_opaque(field, (rows, points, deltas), len(origins), min_trans)
        rows, cols, points = rows.index_select(0, kept), cols.index_select(0, kept), points.index_select(0, kept)
    samples = _evaluate(field, points, directions.index_select(0, rows), options.with_rgb)
    out = _composite(field, (rows, cols), (t_starts, t_ends), samples, (t_min, t_max), options)
    return replace(out, n_evaluated=n_evaluated, sample_points=points, sample_sigmas=samples[0].detach())


def render_rays_early_stop(
    field,
    occupancy,
    origins: torch.Tensor,
    directions: torch.Tensor,
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    marching: Marching,
    options: CompositeOptions = NO_OPTIONS,
    *,
    min_trans: float = EARLY_STOP_TRANS,
    segment: int = EARLY_STOP_SEGMENT,
) -> RayBundleOutput:
    """:func:`render_rays` without jitter or gradients, stopping each ray once it is opaque.

    The samples are marched ``segment`` at a time through the field's trunk (σ,
    ``field.features``); a sample in front of which the transmittance T = exp(-Σ σ_j δ_j) has
    already fallen below ``min_trans`` counts as σ = 0 and gets no colour or class work
    (``field.heads`` runs on the others only), and after each segment a ray past that point
    evaluates nothing further. A faint sample, σ δ below ``min_trans`` / S (S the ray's marched
    samples), also counts as σ = 0: its weight T (1 - exp(-σ δ)) is at most σ δ, so all of a
    ray's faint samples together hold less than ``min_trans`` (in a room, many of the samples the
    density grid lets through: free space in the cells beside a surface). The composite
    is then the same as :func:`render_rays`' with those weights dropped: at most 2 ``min_trans``
    of weight in all, so colour and opacity move by at most about 2 ``min_trans`` times their
    range, and class probabilities and depth (averages over the weights: divided by the opacity)
    by at most about 2 ``min_trans`` / opacity times theirs, 4 ``min_trans`` on a ray that hits
    something (opacity at least 0.5). A ray that meets nothing but faint samples composites to
    nothing (uniform classes, depth at its end), as a ray through empty space does.

    Args:
        as :func:`render_rays` (``field`` with ``features`` and ``heads`` as
        :class:`~scenelabel.fields.model.FieldNetwork`'s); ``min_trans``: the transmittance below
        which a ray stops (0: never, the exact composite); ``segment``: samples per ray evaluated
        between checks. An ``occupancy`` with ``cells_along`` (a
        :class:`~scenelabel.render.sampling.DensityGrid` over a box) is read along the rays, not at
        every point.
    Returns:
        RayBundleOutput without training's terms (``distortion``, ``t_opaque``: None), the class
        probabilities summed directly (:func:`_composite`'s ``for_query``); ``n_evaluated``
        counts the samples the trunk evaluated.
    """
    t_min, t_max = field.warp.clip(origins, directions, t_min, t_max)
    t_starts, t_ends = march(field.warp.spacing, t_min, t_max, marching.step, marching.n_samples, None)  # [n_rays, S]
    n_rays, n_cols = t_starts.shape
    with_rgb = options.with_rgb
    optical = torch.zeros(n_rays, dtype=torch.float64, device=origins.device)  # Σ σ δ so far, per ray
    max_optical = -math.log(min_trans) if min_trans > 0 else math.inf
    faint = min_trans / max(n_cols, 1)  # a sample of σ δ below this holds less than min_trans / n_cols of weight
    active = torch.arange(n_rays, device=origins.device)
    found_rows, found_cols, parts = [], [], []
    n_evaluated = 0
    cells = occupancy.cells_along(origins, directions) if hasattr(occupancy, "cells_along") else None
    for start in range(0, n_cols, segment):
        if active.numel() == 0:
            break
        stop = min(start + segment, n_cols)
        ts, te = (t[:, start:stop].index_select(0, active) for t in (t_starts, t_ends))  # [A, s]
        rows, cols, points = _occupied_samples(occupancy, cells, (origins, directions), active, (ts, te))
        sigmas, h, raw = field.features(points)
        n_evaluated += len(rows)
        flat = rows * ts.shape[1] + cols  # [k] into the segment's [A, s]
        taus = (sigmas * (te - ts).reshape(-1).index_select(0, flat)).double()  # σ δ of each sample
        packed = torch.zeros(ts.numel(), dtype=torch.float64, device=origins.device).index_copy_(0, flat, taus)
        in_front = packed.reshape(ts.shape).cumsum(1).reshape(-1).index_select(0, flat) - taus  # Σ σ δ before, this segment
        before = optical.index_select(0, active).index_select(0, rows) + in_front
        # T in front of the sample still at least min_trans, and σ δ not faint
        live = ((before < max_optical) & (taus >= faint)).nonzero().squeeze(1)
        rows, cols = rows.index_select(0, live), cols.index_select(0, live)
        rgbs, logits = field.heads(h.index_select(0, live), raw.index_select(0, live),
                                   directions.index_select(0, active.index_select(0, rows)) if with_rgb else None)
        optical.index_add_(0, active.index_select(0, rows), taus.index_select(0, live))
        found_rows.append(active.index_select(0, rows))
        found_cols.append(cols + start)
        parts.append((sigmas.index_select(0, live), rgbs, logits))
        active = active[optical[active] < max_optical]
    rows = torch.cat(found_rows) if found_rows else torch.zeros(0, dtype=torch.long, device=origins.device)
    cols = torch.cat(found_cols) if found_cols else torch.zeros_like(rows)
    order = torch.argsort(rows * n_cols + cols)  # row-major, as render_rays packs them
    if parts:
        samples = tuple(None if parts[0][k] is None else torch.cat([p[k] for p in parts])[order] for k in range(3))
    else:  # no sample at all: an empty evaluation keeps the shapes right
        samples = _evaluate(field, origins[:0], directions[:0], with_rgb)
    out = _composite(field, (rows[order], cols[order]), (t_starts, t_ends), samples, (t_min, t_max), options, for_query=True)
    return replace(out, n_evaluated=n_evaluated)


def render_rays_hierarchical(
    coarse_field,
    field,
    origins: torch.Tensor,
    directions: torch.Tensor,
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    n_samples: tuple[int, int],
    jitter: tuple[torch.Tensor, torch.Tensor] | None = None,
    options: CompositeOptions = NO_OPTIONS,
) -> tuple[RayBundleOutput, RayBundleOutput]:
    """NeRF's hierarchical sampling (Mildenhall et al. 2020, sec. 5.2) with two networks.

    1. ``n_coarse`` stratified intervals from t_min to t_max, in the spacing of the field's warp
       (:func:`scenelabel.render.sampling.march` with a step of (t_max - t_min) / n_coarse per ray),
       composited through ``coarse_field``;
    2. ``n_fine`` distances drawn from the coarse weights (:func:`scenelabel.render.sampling.importance_sample`);
    3. ``field`` composited at the coarse and fine distances together
       (:func:`scenelabel.render.sampling.merge_intervals`): n_coarse + n_fine + 1 intervals.
    No density grid: every interval of positive length is evaluated.

    Args:
        coarse_field, field: FieldNetwork-like (see :func:`render_rays`).
        origins, directions, t_min, t_max: as :func:`render_rays`.
        n_samples: (n_coarse, n_fine).
        jitter: (coarse [n_rays] in [0, 1), fine [n_rays, n_fine] in [0, 1)) for training, or None.
        options: as :func:`render_rays`.
    Returns:
        (fine, coarse) RayBundleOutputs; n_evaluated counts each network's samples.
    """
    n_coarse, n_fine = n_samples
    coarse_jitter, fine_jitter = (None, None) if jitter is None else jitter
    t_min, t_max = field.warp.clip(origins, directions, t_min, t_max)
    step = ((t_max - t_min).clamp(min=0.0) / n_coarse)[:, None]  # [n_rays, 1]
    t_starts, t_ends = march(field.warp.spacing, t_min, t_max, step, n_coarse + 1, coarse_jitter)
    coarse, sigmas = _render_intervals(coarse_field, origins, directions, (t_starts, t_ends), (t_min, t_max), options)
    weights, _, _ = weights_from_density(sigmas.detach(), t_ends - t_starts)
    t_fine = importance_sample(t_starts, t_ends, weights, n_fine, fine_jitter)
    intervals = merge_intervals(t_starts, t_ends, t_fine)
    fine, _ = _render_intervals(field, origins, directions, intervals, (t_min, t_max), options)
    return fine, coarse


def _render_intervals(field, origins, directions, intervals, limits, options):
    """Evaluate ``field`` at every interval of positive length and composite: (RayBundleOutput,
    σ [n_rays, S] with 0 at the empty intervals)."""
    t_starts, t_ends = intervals
    points = _points(origins, directions, 0.5 * (t_starts + t_ends))  # [n_rays, S, 3]
    rows, cols = (t_ends > t_starts).nonzero(as_tuple=True)
    samples = _evaluate(field, points[rows, cols], directions[rows], options.with_rgb)
    out = _composite(field, (rows, cols), intervals, samples, limits, options)
    return out, t_starts.new_zeros(t_starts.shape).index_put((rows, cols), samples[0].to(t_starts.dtype))


@torch.no_grad()
def _samples_before_opaque(field, samples, n_rays: int, min_trans: float) -> tuple[torch.Tensor, int]:
    """Which of each ray's samples lie in front of the point where its transmittance falls below
    ``min_trans``: found from the trunk's density alone, without gradients.

    The density (``field.density``) is evaluated on the samples of rank
    [start, start + size) within their ray, for the rays still at T ≥ ``min_trans``; the segments
    double (size = max(EARLY_STOP_SEGMENT, start)), so a long ray costs a few calls and a ray
    stopping at rank r evaluates at most about r samples past it. A sample is kept when the
    transmittance in front of it, T = exp(-Σ σ_j δ_j) over the ray's earlier samples (float64), is
    at least ``min_trans``.

    Args:
        samples: (rows [k], points [k, 3], deltas [k]) the occupied samples, row-major (each ray's
            in order), with their interval lengths.
    Returns:
        (kept [k'] indices into the samples, in order; how many samples the trunk evaluated).
    """
    rows, points, deltas = samples
    counts, rank = _ranks_in_rays(rows, n_rays)
    optical = torch.zeros(n_rays, dtype=torch.float64, device=rows.device)  # Σ σ δ so far, per ray
    max_optical = -math.log(min_trans)
    kept, n_evaluated, start = [], 0, 0
    longest = int(counts.max()) if counts.numel() else 0
    while start < longest:
        size = max(EARLY_STOP_SEGMENT, start)
        in_segment = (rank >= start) & (rank < start + size)
        sel = (in_segment & (optical.index_select(0, rows) < max_optical)).nonzero().squeeze(1)  # row-major
        if sel.numel() > 0:
            taus = field.density(points.index_select(0, sel)).double()
            taus = taus * deltas.index_select(0, sel).double()  # σ δ
            n_evaluated += len(sel)
            sel_rows = rows.index_select(0, sel)
            # Σ σ δ in front of each sample: the ray's total so far + its samples before it in this segment
            cum = taus.cumsum(0) - taus
            group_first = torch.arange(len(sel), device=sel.device) - (rank.index_select(0, sel) - start)
            before = optical.index_select(0, sel_rows) + cum - cum.index_select(0, group_first)
            kept.append(sel[before < max_optical])
            optical.index_add_(0, sel_rows, taus)
        start += size
    if not kept:
        return rows[:0], n_evaluated
    return torch.sort(torch.cat(kept)).values, n_evaluated


def _ranks_in_rays(rows: torch.Tensor, n_rays: int) -> tuple[torch.Tensor, torch.Tensor]:
    """For samples ordered row-major by their ray ``rows`` [n]: each ray's sample count [n_rays] and
    each sample's place among its ray's samples [n] (0 for the first)."""
    counts = torch.bincount(rows, minlength=n_rays)
    first = torch.cumsum(counts, 0) - counts  # where each ray's samples begin in ``rows``
    return counts, torch.arange(len(rows), device=rows.device) - first.index_select(0, rows)


def _occupied_samples(occupancy, cells, rays, active: torch.Tensor, intervals):
    """The samples of rays ``active`` [A] at intervals (t_starts, t_ends) [A, s] of positive length
    whose middle ``occupancy`` holds occupied: (rows, cols) [k] into [A, s] and their points [k, 3].
    With ``cells`` (:meth:`~scenelabel.render.sampling.DensityGrid.cells_along`) the grid is read at
    cell coordinates linear in t, and only the kept samples' points are formed."""
    (origins, directions), (ts, te) = rays, intervals
    t_mids = 0.5 * (ts + te)
    if cells is None:
        points = _points(origins.index_select(0, active), directions.index_select(0, active), t_mids)
        rows, cols = ((te > ts) & occupancy(points)).nonzero(as_tuple=True)
        return rows, cols, points[rows, cols]
    along = tuple(c.index_select(0, active) for c in cells)  # [A, 3] each
    rows, cols = ((te > ts) & occupancy.occupied_along(along, t_mids)).nonzero(as_tuple=True)
    ray = active.index_select(0, rows)
    points = origins.index_select(0, ray) + _take(t_mids, rows, cols)[:, None] * directions.index_select(0, ray)
    return rows, cols, points


def _points(origins: torch.Tensor, directions: torch.Tensor, t_mids: torch.Tensor) -> torch.Tensor:
    """Sample points at distances t_mids [n_rays, S] (the interval middles): [n_rays, S, 3]."""
    return origins[:, None, :] + t_mids[..., None] * directions[:, None, :]


def _take(values: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """``values[rows, cols]`` for [n_rays, S] values and [n] indices, as one gather along the flat
    array (index_select, which the CPU does faster than a two-index lookup): [n]."""
    return values.reshape(-1).index_select(0, rows * values.shape[1] + cols)


def _padded(values: torch.Tensor, packed: torch.Tensor, shape: tuple[int, int], dtype: torch.dtype) -> torch.Tensor:
    """[n, ...] values placed at flat indices ``packed`` [n] of ``shape`` (n_rays, K), zeros
    elsewhere: [n_rays, K, ...] of ``dtype`` (one index_copy, differentiable in ``values``)."""
    out = torch.zeros(shape[0] * shape[1], *values.shape[1:], dtype=dtype, device=values.device)
    return out.index_copy(0, packed, values.to(dtype)).reshape(*shape, *values.shape[1:])


def _evaluate(field, points: torch.Tensor, directions: torch.Tensor, with_rgb: bool):
    """The field at [n, 3] points: (sigmas [n], rgbs [n, 3] or None, class_logits [n, C])."""
    if with_rgb:
        sigmas, rgbs, class_logits = field(points, directions)
        return sigmas, rgbs, class_logits
    sigmas, class_logits = field.semantics(points)
    return sigmas, None, class_logits


def _composite(field, at, intervals, samples, limits, options: CompositeOptions, for_query: bool = False) -> RayBundleOutput:
    """Composite evaluated samples (the pure maths of :mod:`scenelabel.render.volume`).

    Skipped samples have σ = 0 and change nothing, so the evaluated ones are moved to the front of
    each ray: [n_rays, K] with K the largest count, padded with zero-length intervals. ``for_query``
    (a render or query, without gradients): no training terms (``distortion``, ``t_opaque`` and
    ``front_weight`` are None), and the class probabilities summed directly
    (:func:`~scenelabel.render.volume.class_probs_from_sample_weights`), not in log space.

    Args:
        at: (rows, cols) [n] each, the evaluated samples, row-major (each ray's in order).
        intervals: (t_starts, t_ends) [n_rays, S] the marched intervals.
        samples: (sigmas [n], rgbs [n, 3] or None, class_logits [n, C]) at ``at``.
        limits: (t_min, t_max) [n_rays] the rays' clipped intervals.
    """
    rows, cols = at
    (t_starts, t_ends), (sigmas, rgbs, class_logits), (t_min, t_max) = intervals, samples, limits
    n_rays = t_starts.shape[0]
    counts, rank = _ranks_in_rays(rows, n_rays)
    K = max(int(counts.max()) if counts.numel() else 0, 1)
    packed = rows * K + rank  # [n] in [n_rays * K]
    dtype = t_starts.dtype
    starts = _padded(_take(t_starts, rows, cols), packed, (n_rays, K), dtype)
    ends = _padded(_take(t_ends, rows, cols), packed, (n_rays, K), dtype)
    t_mids = 0.5 * (starts + ends)
    packed_sigmas = _padded(sigmas, packed, (n_rays, K), dtype)
    weights, _, _ = weights_from_density(packed_sigmas, ends - starts)
    semantic_weights = weights.detach() if options.detach_semantic_weights else weights
    if options.geometry_only_labels is not None:
        class_logits = torch.where(options.geometry_only_labels.index_select(0, rows)[:, None], class_logits.detach(), class_logits)
    if field.config.semantic_rendering == "scores":
        logits = _padded(class_logits, packed, (n_rays, K), dtype)
        class_log_probs = class_log_probs_from_scores(semantic_weights, logits)
    else:  # over the evaluated samples only: rays are padded to the longest
        sample_weights = semantic_weights.reshape(-1).index_select(0, packed)
        if for_query:
            class_log_probs = torch.log(class_probs_from_sample_weights(sample_weights, class_logits, rows, n_rays))
        else:
            class_log_probs = class_log_probs_from_sample_weights(sample_weights, class_logits, rows, n_rays)
    rgb = None
    if rgbs is not None:
        rgb = composite_rgb(weights, _padded(rgbs, packed, (n_rays, K), dtype), options.background)
    # A ray whose interval is empty (t_max < t_min: it misses the box or [near, far]) reports its
    # t_max (≥ 0): the requested far, or where it leaves the box.
    t_hi = t_max.clamp(min=0.0)
    depth = depth_from_weights(weights, t_mids, torch.minimum(t_min, t_hi), t_hi)
    out = RayBundleOutput(rgb, depth, weights.sum(-1), class_log_probs, n_evaluated=int(rows.shape[0]))
    if for_query:
        return out
    s_starts, s_ends = (normalized_distances(field.warp.spacing, t, t_min, t_max) for t in (starts, ends))
    return replace(
        out,
        distortion=distortion_from_weights(weights, s_starts, s_ends),
        t_opaque=depth_at_transmittance(packed_sigmas.detach(), starts, ends, OPAQUE_TRANS),
        front_weight=None if options.free_until is None else weight_before(weights, ends, options.free_until),
    )
