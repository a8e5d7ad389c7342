"""Where to evaluate the field along rays: ray/AABB clipping, uniform or disparity marching, empty-space skipping;
which training rays to draw by class.

Pure functions, plus :class:`DensityGrid`, a thin state holder (a bit grid over the scene box,
refreshed from the field's density during training) whose lookup is a pure function.
"""

from __future__ import annotations

import math
from typing import Callable

import torch
from torch import nn

__all__ = [
    "ray_aabb_intersect",
    "march_uniform",
    "march_disparity",
    "march",
    "normalized_distances",
    "importance_sample",
    "merge_intervals",
    "occupied_at",
    "cell_indices",
    "free_cells_from_depth",
    "cell_steps",
    "DensityGrid",
    "rays_by_class",
    "class_balanced_rays",
]



def ray_aabb_intersect(
    origins: torch.Tensor, directions: torch.Tensor, aabb: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances of rays through an axis-aligned box: the slab rule of
    :mod:`scenelabel.geometry.boxes` (a zero direction component decided exactly, no eps), for tensors.

    Args:
        origins: [n_rays, 3].
        directions: [n_rays, 3] (need not be unit; t is in units of |d|).
        aabb: [2, 3] (min corner, max corner).
    Returns:
        t_min, t_max: [n_rays]; a ray misses the box when t_max < max(t_min, 0).
        Rays starting inside the box have t_min < 0.
    """
    lo, hi = aabb[0], aabb[1]
    ta = (lo - origins) / directions  # ±inf or nan where a component is 0: replaced below
    tb = (hi - origins) / directions
    parallel = directions == 0
    within = (origins >= lo) & (origins <= hi)
    inf = torch.full_like(ta, float("inf"))
    t_min = torch.where(parallel, torch.where(within, -inf, inf), torch.minimum(ta, tb)).amax(-1)
    t_max = torch.where(parallel, torch.where(within, inf, -inf), torch.maximum(ta, tb)).amin(-1)
    return t_min, t_max


MIN_DISPARITY_T = 1e-6
"""Disparity marching starts no closer than this (normalised units): 1 / t stays finite."""

MIN_DISPARITY = 1e-30
"""Disparities are clamped to at least this: an end at ``t_max = inf`` is 1e30, not inf (δ stays finite)."""


def march_uniform(
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    step: float | torch.Tensor,
    n_samples: int,
    jitter: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fixed-step intervals from t_min to t_max, the last one cut at t_max.

    Interval k spans [t_min + (k + u - 1) step, t_min + (k + u) step] clipped to [t_min, t_max],
    with u in [0, 1) a per-ray jitter (0 for deterministic rendering). Intervals past t_max have
    zero length and contribute nothing to rendering.

    Args:
        t_min, t_max: [n_rays] (rays that miss have t_max <= t_min: all intervals empty).
        step: interval length: a float, or [n_rays, 1] (one per ray).
        n_samples: intervals per ray (enough to cover the longest ray: ceil(max length / step) + 1).
        jitter: [n_rays] in [0, 1) or None.
    Returns:
        t_starts, t_ends: [n_rays, n_samples].
    """
    k = torch.arange(n_samples, dtype=t_min.dtype, device=t_min.device)
    u = torch.zeros_like(t_min) if jitter is None else jitter
    t_max = torch.maximum(t_max, t_min)  # a ray that misses collapses onto t_min
    edges = t_min[:, None] + (k[None, :] + u[:, None]) * step  # [n_rays, n_samples] interval ends
    t_ends = torch.minimum(edges, t_max[:, None])
    t_starts = torch.cat([t_min[:, None], t_ends[:, :-1]], dim=-1)
    return t_starts, t_ends


def march_disparity(
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    n_samples: int,
    jitter: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Intervals from t_min to t_max in equal steps of disparity 1 / t (LLFF's ``lindisp``).

    Interval ends sit at ``1 / t = (1 - s) / t_min + s / t_max`` with
    ``s = min((k + u) / (n_samples - 1), 1)``, k = 0 .. n_samples - 1 and u in [0, 1) a per-ray
    jitter (as :func:`march_uniform`, one interval more than the steps: the first starts at t_min,
    the last ends at t_max). Ends are clamped to [t_min, t_max]. Near the camera the intervals are
    short, far away long, as a pixel's footprint grows with distance.

    Args:
        t_min, t_max: [n_rays], ``t_min > 0`` (clamped to ``MIN_DISPARITY_T``; rays that miss
            have t_max <= t_min: all intervals empty). ``t_max = inf`` gives 1 / t_max = 0; the
            last end is then capped at ``1 / MIN_DISPARITY`` (finite).
        n_samples: intervals per ray (>= 2 to reach t_max).
        jitter: [n_rays] in [0, 1) or None.
    Returns:
        t_starts, t_ends: [n_rays, n_samples].
    """
    t_lo = t_min.clamp(min=MIN_DISPARITY_T)
    t_max = torch.maximum(t_max, t_lo)
    k = torch.arange(n_samples, dtype=t_min.dtype, device=t_min.device)
    u = torch.zeros_like(t_min) if jitter is None else jitter
    s = ((k[None, :] + u[:, None]) / max(n_samples - 1, 1)).clamp(max=1.0)  # [n_rays, n_samples]
    inv = ((1.0 - s) / t_lo[:, None] + s / t_max[:, None]).clamp(min=MIN_DISPARITY)
    t_ends = torch.minimum(torch.maximum(1.0 / inv, t_lo[:, None]), t_max[:, None])
    t_starts = torch.cat([t_lo[:, None], t_ends[:, :-1]], dim=-1)
    return t_starts, t_ends


def march(
    spacing: str,
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    step: float | torch.Tensor,
    n_samples: int,
    jitter: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`march_uniform` (``spacing="uniform"``, steps of ``step``: a float, or [n_rays, 1] for
    a step per ray) or :func:`march_disparity` (``"disparity"``, ``step`` unused): the spacing a
    field's warp asks for (``warp.spacing``)."""
    if spacing == "disparity":
        return march_disparity(t_min, t_max, n_samples, jitter)
    if spacing == "uniform":
        return march_uniform(t_min, t_max, step, n_samples, jitter)
    raise ValueError(f"unknown spacing {spacing!r}")


def normalized_distances(spacing: str, t: torch.Tensor, t_min: torch.Tensor, t_max: torch.Tensor) -> torch.Tensor:
    """Distances along rays as the fraction s in [0, 1] of the way from t_min to t_max in the
    march's spacing (the inverse of :func:`march`'s map from s to t; mip-NeRF 360's normalised
    ray distance): ``(t - t_min) / (t_max - t_min)`` for uniform spacing, the same in disparity
    1 / t (clamped as :func:`march_disparity` clamps) for disparity spacing.

    Args:
        spacing: "uniform" or "disparity" (a warp's ``spacing``).
        t: [n_rays, n] distances in [t_min, t_max].
        t_min, t_max: [n_rays].
    Returns:
        [n_rays, n] s, clamped to [0, 1]. A ray with an empty interval (t_max <= t_min) has no
        samples; its s is 0 (the denominator is clamped to the smallest positive float).
    """
    if spacing == "disparity":
        t_lo = t_min.clamp(min=MIN_DISPARITY_T)
        t_hi = torch.maximum(t_max, t_lo)
        g, g_min, g_max = (1.0 / x.clamp(min=MIN_DISPARITY_T) for x in (t, t_lo[:, None], t_hi[:, None]))
        span, offset = g_min - g_max, g_min - g
    elif spacing == "uniform":
        span, offset = (t_max - t_min)[:, None], t - t_min[:, None]
    else:
        raise ValueError(f"unknown spacing {spacing!r}")
    return (offset / span.clamp(min=torch.finfo(span.dtype).tiny)).clamp(0.0, 1.0)


PDF_EPS = 1e-5
"""Probability mass added to a ray's weights before :func:`importance_sample` draws from them,
spread over the intervals in proportion to their length (NeRF adds 1e-5 per bin): every interval
of positive length keeps some probability, and a ray with no weight at all samples uniformly."""


def importance_sample(
    t_starts: torch.Tensor,
    t_ends: torch.Tensor,
    weights: torch.Tensor,
    n_samples: int,
    jitter: torch.Tensor | None = None,
) -> torch.Tensor:
    """Distances drawn from the piecewise-constant density the weights put on the intervals
    (inverse transform sampling: NeRF's hierarchical sampling, Mildenhall et al. 2020, eq. 5).

    The density is p(t) = (w_i + PDF_EPS δ_i / Σ_j δ_j) / Z / δ_i inside interval i, with
    δ_i = t_ends - t_starts; its CDF is inverted at the stratified quantiles
    u_k = (k + jitter_k) / n_samples, so the samples come out sorted. Zero-length intervals
    (past a ray's end) get no samples. A ray whose intervals all have zero length returns its
    first t_start n_samples times. No gradient flows through the sampling.

    Args:
        t_starts, t_ends: [n_rays, S] sorted, non-overlapping intervals.
        weights: [n_rays, S] ≥ 0 (e.g. a coarse render's w_i).
        n_samples: samples per ray.
        jitter: [n_rays, n_samples] in [0, 1) (training) or None (0.5: the middle of each stratum).
    Returns:
        [n_rays, n_samples] sorted distances inside the rays' intervals.
    """
    with torch.no_grad():
        lengths = (t_ends - t_starts).clamp(min=0.0)  # [n_rays, S]
        total = lengths.sum(-1, keepdim=True)
        pdf = weights.detach().clamp(min=0.0) * (lengths > 0) + PDF_EPS * lengths / total.clamp(min=torch.finfo(lengths.dtype).tiny)
        cdf = torch.cumsum(pdf, -1)
        cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf / cdf[:, -1:].clamp(min=torch.finfo(cdf.dtype).tiny)], -1)
        k = torch.arange(n_samples, dtype=t_starts.dtype, device=t_starts.device)
        u = (k + (0.5 if jitter is None else jitter.to(t_starts.dtype))) / n_samples  # [n_rays, n_samples]
        u = u.expand(t_starts.shape[0], n_samples).contiguous()
        idx = (torch.searchsorted(cdf.contiguous(), u, right=True) - 1).clamp(0, t_starts.shape[1] - 1)
        c_lo, c_hi = cdf.gather(-1, idx), cdf.gather(-1, idx + 1)
        frac = ((u - c_lo) / (c_hi - c_lo).clamp(min=torch.finfo(cdf.dtype).tiny)).clamp(0.0, 1.0)
        return t_starts.gather(-1, idx) + frac * lengths.gather(-1, idx)


def merge_intervals(t_starts: torch.Tensor, t_ends: torch.Tensor, t_new: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Split contiguous intervals at new distances: NeRF's fine samples (the coarse ones and the
    importance samples, sorted together).

    Args:
        t_starts, t_ends: [n_rays, S] contiguous (t_starts[:, i + 1] == t_ends[:, i]).
        t_new: [n_rays, K] distances inside [t_starts[:, 0], t_ends[:, -1]].
    Returns:
        t_starts, t_ends: [n_rays, S + K], covering the same span.
    """
    edges = torch.cat([t_starts[:, :1], t_ends, t_new.to(t_ends.dtype)], -1).sort(-1).values
    return edges[:, :-1], edges[:, 1:]


def occupied_at(bits: torch.Tensor, aabb: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Look up a boolean density grid covering ``aabb`` at ``points`` (outside -> False).

    Args:
        bits: [R, R, R] bool, indexed [i, j, k] along x, y, z.
        aabb: [2, 3] box the grid spans.
        points: [..., 3].
    Returns:
        [...] bool.
    """
    res = torch.tensor(bits.shape, device=points.device)
    rel = (points - aabb[0]) / (aabb[1] - aabb[0])
    inside = ((rel >= 0) & (rel < 1)).all(-1)
    return _bits_at(bits, torch.minimum((rel * res).long().clamp_(min=0), res - 1)) & inside


def _bits_at(bits: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``bits[idx[..., 0], idx[..., 1], idx[..., 2]]`` for in-range [..., 3] cell indices, as one
    gather along the flat array (faster on the CPU than three index tensors): [...] bool."""
    flat = (idx[..., 0] * bits.shape[1] + idx[..., 1]) * bits.shape[2] + idx[..., 2]
    return bits.reshape(-1).index_select(0, flat.reshape(-1)).reshape(flat.shape)


def cell_indices(resolution: int, points_cube: torch.Tensor) -> torch.Tensor:
    """Flat indices (i·R² + j·R + k, [i, j, k] along x, y, z) of the [R, R, R] cells over the cube
    [-1, 1]³ holding ``points_cube`` [n, 3]: [n] int64, -1 outside the cube."""
    rel = (points_cube + 1.0) * 0.5
    inside = ((rel >= 0) & (rel < 1)).all(-1)
    idx = (rel * resolution).long().clamp(0, resolution - 1)
    flat = (idx[:, 0] * resolution + idx[:, 1]) * resolution + idx[:, 2]
    return torch.where(inside, flat, torch.full_like(flat, -1))


def _dilated(cells: torch.Tensor, radius: int = 1) -> torch.Tensor:
    """[R, R, R] bool: the cells marked in ``cells`` ([R, R, R], bool or > 0) and those within
    ``radius`` cells of one along every axis (a (2 radius + 1)³ neighbourhood, clipped at the faces)."""
    grown = nn.functional.max_pool3d(cells.float()[None, None], 2 * radius + 1, stride=1, padding=radius)
    return grown[0, 0] > 0


CARVE_MARGIN = 0.05
""":func:`free_cells_from_depth` stops this fraction of each measured depth (and one step more) short
of the measured surface: three times a phone's 1.5 % depth noise."""

CARVE_MIN_POINTS = 3
"""A cell is free when at least this many carve points fall in it: one ray crosses a cell with at
most two points one step apart (a step is a cell's side), so one stray depth cannot free a cell."""

CARVE_RAYS = 200_000
"""At most this many sensor-depth rays (a seeded random subset) carve the grid."""


@torch.no_grad()
def free_cells_from_depth(
    warp: nn.Module,
    resolution: int,
    origins: torch.Tensor,  # [n_rays, 3]
    directions: torch.Tensor,  # [n_rays, 3]
    t_min: torch.Tensor,  # [n_rays]
    t_max: torch.Tensor,  # [n_rays]
    depth: torch.Tensor,  # [n_rays], NaN = no measurement
    step: float,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """[R, R, R] bool: the density-grid cells that sensor depth shows empty (space carving).

    Points every ``step`` (jittered) along each ray with a measured ``depth``, from ``t_min`` to
    ``depth · (1 - CARVE_MARGIN) - step`` but not past ``t_max`` (the box's far side), vote for
    the cells they fall in. A cell with at least CARVE_MIN_POINTS votes is free unless a measured
    surface point (``origins + depth · directions``) lies in it or in one of its 26 neighbours,
    which keeps a surface that grazing rays pass beside (a depth resampled across an edge carries
    the far side's value). Points map to cells through ``warp`` (normalised frame -> the grid's
    cube); distances are in units of |directions|. Rays without depth (NaN: holes, masked pixels)
    carve nothing, nor do depths at or before ``t_min`` or rays with an infinite ``t_max``.
    """
    if not step > 0:
        raise ValueError(f"free_cells_from_depth: step must be > 0, got {step}")
    n_cells = resolution**3
    device = origins.device
    valid = (torch.isfinite(depth) & torch.isfinite(t_max) & (depth > t_min)).nonzero().squeeze(1)
    if len(valid) > CARVE_RAYS:
        valid = valid[torch.randperm(len(valid), generator=generator)[:CARVE_RAYS].to(device)]
    o, d, t0, t1 = origins[valid], directions[valid], t_min[valid].clamp(min=0.0), depth[valid]
    hits = torch.zeros(n_cells + 1, device=device)  # the last slot takes the points outside the cube (index -1)
    hits[cell_indices(resolution, warp(o + d * t1[:, None]))] = 1.0
    t_end = torch.minimum(t1 * (1.0 - CARVE_MARGIN) - step, t_max[valid])
    votes = torch.zeros(n_cells + 1, dtype=torch.int64, device=device)
    chunk = 1 << 13
    for i in range(0, len(valid), chunk):
        c0, c1 = t0[i : i + chunk], t_end[i : i + chunk]
        u = torch.rand((len(c0), 1), generator=generator).to(device)  # drawn for every chunk: reproducible
        if not bool((c1 > c0).any()):
            continue
        n = int(math.ceil(float((c1 - c0).max()) / step))
        ts = c0[:, None] + step * (torch.arange(n, device=device) + u)  # [chunk, n]
        pts = o[i : i + chunk, None, :] + d[i : i + chunk, None, :] * ts[..., None]
        cells = cell_indices(resolution, warp(pts[ts < c1[:, None]]))
        votes += torch.bincount(cells % (n_cells + 1), minlength=n_cells + 1)
    near_hit = _dilated(hits[:n_cells].reshape((resolution,) * 3))
    return (votes[:n_cells] >= CARVE_MIN_POINTS).reshape((resolution,) * 3) & ~near_hit


REBUILD_SAMPLES = 3
"""Points per axis and cell at which :meth:`DensityGrid.rebuild` evaluates the density (27 per cell)."""

REBUILD_BORDER = 1
""":meth:`DensityGrid.rebuild` looks again at the cells within this many cells of an occupied one."""

REBUILD_BORDER_SAMPLES = 6
"""Points per axis and cell at which :meth:`DensityGrid.rebuild` looks again at a border cell (216)."""

REOPEN_FACTOR = 2.0
""":meth:`DensityGrid.reopen` gives a cell this many times the threshold: with a refresh's decay of
0.8 it then stays occupied for three refreshes unless the field makes it dense."""

REOPEN_POINTS_PER_CELL = 4
"""Points per cell of the grid's side at which :meth:`DensityGrid.reopen` samples a segment."""


def cell_steps(warp: nn.Module, aabb_n: torch.Tensor, resolution: int, n_steps: int) -> float | torch.Tensor:
    """The marching step through an occupancy-grid cell (normalised units), for its opacity threshold.

    Uniform marching: the box diagonal / n_steps everywhere. Disparity marching (n_steps equal
    steps of 1/t from near to far): a step at depth t is about t² Δ(1/t), so [resolution] per
    slice along the cube's depth axis.
    """
    if warp.spacing == "disparity":
        inv_near, inv_far = warp.inv_range.tolist()
        s = (torch.arange(resolution) + 0.5) / resolution * 2.0 - 1.0  # slice centres along the depth axis
        inv_t = inv_near - (s + 1.0) * 0.5 * (inv_near - inv_far)
        return (inv_near - inv_far) / n_steps / inv_t**2
    return float(torch.linalg.norm(aabb_n[1] - aabb_n[0])) / n_steps


class DensityGrid(nn.Module):
    """A [R, R, R] grid over the field's cube (its warp's [-1, 1]^3) marking cells that may hold density.

    Each cell keeps an exponential moving average of the largest density seen at random points
    inside it (:meth:`update`), and at the samples a training step marched there (:meth:`observe`);
    a cell is occupied when that density could make a marching step at least ``alpha_threshold``
    opaque. Until the first update every cell is occupied, except cells
    :meth:`carve` marks empty (sensor depth saw through them), which stay empty. Cells live in
    the warp's cube (:mod:`scenelabel.geometry.warps`): for a box warp they are boxes, for a forward warp
    frustum slices that grow with depth.
    """

    def __init__(
        self, warp: nn.Module, resolution: int = 64, step: float | torch.Tensor = 0.01, alpha_threshold: float = 0.005
    ):
        """``step``: the marching step through a cell (normalised units): a float, or [resolution]
        per slice along the cube's third axis (disparity marching: steps grow with depth)."""
        super().__init__()
        self.resolution = resolution
        self.warp = warp
        self.register_buffer("cube", torch.tensor([[-1.0] * 3, [1.0] * 3]))
        self.register_buffer("density", torch.full((resolution,) * 3, float("inf")))
        self.register_buffer("bits", torch.ones((resolution,) * 3, dtype=torch.bool))
        # cells known empty (carve): not saved, since a saved grid's bits already leave them out
        self.register_buffer("carved", torch.zeros((resolution,) * 3, dtype=torch.bool), persistent=False)
        # σ that makes one step alpha_threshold opaque: [1, 1, 1] or [1, 1, R], broadcast over the grid
        threshold = -math.log1p(-alpha_threshold) / torch.as_tensor(step, dtype=torch.float32)
        self.register_buffer("sigma_threshold", threshold.reshape(1, 1, -1), persistent=False)

    @classmethod
    def for_march(
        cls, warp: nn.Module, aabb_n: torch.Tensor, resolution: int, n_steps: int, alpha_threshold: float
    ) -> "DensityGrid":
        """A grid whose threshold matches marching ``aabb_n`` (normalised) in ``n_steps``
        (:func:`cell_steps`): what training builds and what a loaded field rebuilds."""
        return cls(warp, resolution, cell_steps(warp, aabb_n, resolution, n_steps), alpha_threshold)

    def carve(self, free: torch.Tensor) -> None:
        """Hold ``free`` ([R, R, R] bool, e.g. :func:`free_cells_from_depth`) empty from now on:
        no refresh or rebuild marks those cells occupied, so marching skips them from the first step."""
        self.carved = free.to(self.bits.device) | self.carved
        self.bits = self.bits & ~self.carved

    def release_carve_border(self) -> None:
        """Hand the carved cells beside uncarved ones back to the refreshes (erode the carve by one
        cell): a cell carved wrongly lies at a surface (its depth edge a hole, grazing rays beside
        it), and comes back if the field holds density there; open space stays carved."""
        self.carved = self.carved & ~_dilated(~self.carved)

    def cell_points(self, cells: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """One random point (normalised frame) in each of ``cells`` (flat indices into the grid): [n, 3]."""
        r = self.resolution
        idx = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1)
        u = torch.rand(idx.shape, generator=generator)
        unit = ((idx + u) / r * 2.0 - 1.0).to(self.cube.device)
        return self.warp.inverse(unit)

    @torch.no_grad()
    def update(
        self,
        density_fn: Callable[[torch.Tensor], torch.Tensor],
        decay: float = 0.95,
        all_cells: bool = True,
        chunk: int = 1 << 16,
        generator: torch.Generator | None = None,
    ) -> None:
        """Refresh from ``density_fn(points [n, 3]) -> sigmas [n]`` at one random point per cell.

        ``all_cells=False`` refreshes the occupied cells plus a random quarter of all cells (as
        nerfacc does after its warm-up), which is 2-4x cheaper; the others keep their value.
        """
        n_cells = self.resolution**3
        if all_cells:
            cells = torch.arange(n_cells)
        else:
            random_cells = torch.randint(n_cells, (n_cells // 4,), generator=generator)
            cells = torch.unique(torch.cat([random_cells, self.bits.flatten().nonzero().squeeze(1).cpu()]))
        cells = cells[~self.carved.flatten().cpu()[cells]]  # carved cells stay empty: not evaluated
        points = self.cell_points(cells, generator)
        sigmas = torch.cat([density_fn(points[i : i + chunk]) for i in range(0, len(points), chunk)]).float()
        density = self.density.flatten()
        density = torch.where(torch.isinf(density), torch.zeros_like(density), density)  # inf: never refreshed
        cells = cells.to(density.device)
        density[cells] = torch.maximum(density[cells] * decay, sigmas.to(density.device))
        self.density = density.reshape(self.density.shape)
        self.bits = (self.density > self.sigma_threshold) & ~self.carved

    @torch.no_grad()
    def reopen(
        self,
        origins: torch.Tensor,  # [n_rays, 3]
        directions: torch.Tensor,  # [n_rays, 3]
        t_starts: torch.Tensor,  # [n_rays]
        t_ends: torch.Tensor,  # [n_rays]
        factor: float = REOPEN_FACTOR,
    ) -> None:
        """Re-open the cells the segments ``origins + t directions``, t in [t_starts, t_ends], cross:
        each gets at least ``factor`` x the threshold as its remembered density, so it stays occupied
        for a few refreshes whatever the field holds there now (carved cells stay empty).

        For the training rays a grid has wrongly emptied: a thin object (a lamp's 5 cm pole) whose
        cells a refresh's random point missed before the field had learnt it is never sampled again,
        and its rays see the wall behind it for the rest of the run; re-opened, the field can grow it.
        A segment is sampled at REOPEN_POINTS_PER_CELL x the grid's side points evenly in t: with the
        box warp it meets every cell it crosses over more than a 1 / REOPEN_POINTS_PER_CELL of a cell's
        side (a corner it clips may stay closed); with the forward warp, whose cells shrink toward the
        camera, it may skip some of the nearest."""
        n = REOPEN_POINTS_PER_CELL * self.resolution
        u = torch.linspace(0.0, 1.0, n, device=origins.device)
        t = t_starts[:, None] + (t_ends - t_starts)[:, None] * u  # [n_rays, n]
        points = origins[:, None, :] + directions[:, None, :] * t[..., None]
        cells = cell_indices(self.resolution, self.warp(points.reshape(-1, 3)))
        cells = torch.unique(cells[cells >= 0]).to(self.density.device)
        density = self.density.flatten()
        threshold = self.sigma_threshold.to(density.device).expand_as(self.density).flatten()
        density[cells] = torch.maximum(density[cells], factor * threshold[cells])
        self.density = density.reshape(self.density.shape)
        self.bits = (self.density > self.sigma_threshold) & ~self.carved

    @torch.no_grad()
    def observe(self, points: torch.Tensor, sigmas: torch.Tensor) -> None:
        """Raise each cell's remembered density to the largest ``sigmas`` [n] seen at ``points`` [n, 3]
        (world) inside it, e.g. a training step's samples; the occupancy bits change at the next refresh."""
        cells = cell_indices(self.resolution, self.warp(points.detach()))
        inside = cells >= 0
        density = self.density.flatten()
        density.scatter_reduce_(0, cells[inside].to(density.device), sigmas.detach().float()[inside], "amax")
        self.density = density.reshape(self.density.shape)

    @torch.no_grad()
    def rebuild(
        self,
        density_fn: Callable[[torch.Tensor], torch.Tensor],
        samples_per_axis: int = REBUILD_SAMPLES,
        border: int = REBUILD_BORDER,
        border_samples: int = REBUILD_BORDER_SAMPLES,
        chunk: int = 1 << 16,
    ) -> None:
        """Recompute every cell from ``density_fn`` as it is now (e.g. at the end of training).

        A cell's density is the largest at the centres of an s x s x s lattice of sub-cells
        (s = ``samples_per_axis``); it is occupied when that is above the threshold. The cells
        within ``border`` cells of an occupied one are then looked at again on a finer lattice
        (``border_samples`` per axis) and keep the larger density: what the coarse lattice passes
        between (a sheet thinner than a sub-cell, a surface's edge) lies next to what it finds.
        The moving average of :meth:`update` keeps a cell occupied for many refreshes after its
        density has gone (a decay of 0.95 per refresh); this grid follows the field as it is.
        Looking again, rather than marking every cell beside an occupied one, keeps the free space
        in front of a surface empty: marching skips it (docs/grid_border.md). Carved cells stay
        empty (density 0) and are not evaluated.
        """
        r = self.resolution
        cells = (~self.carved).flatten().nonzero().squeeze(1).cpu()  # carved cells stay empty: not evaluated
        density = torch.zeros(r**3, device=self.density.device)
        density[cells.to(density.device)] = self._lattice_max(density_fn, cells, samples_per_axis, chunk)
        if border > 0:
            bits = density.reshape(r, r, r) > self.sigma_threshold
            again = (_dilated(bits, border) & ~bits & ~self.carved).flatten().nonzero().squeeze(1)  # on the grid's device
            density[again] = torch.maximum(density[again], self._lattice_max(density_fn, again.cpu(), border_samples, chunk))
        self.density = density.reshape(r, r, r)
        self.bits = (self.density > self.sigma_threshold) & ~self.carved

    def _lattice_max(self, density_fn: Callable[[torch.Tensor], torch.Tensor], cells: torch.Tensor, s: int, chunk: int):
        """The largest ``density_fn`` at the centres of an s x s x s lattice of sub-cells in each of
        ``cells`` (flat indices, [n]): [n] float32 on the grid's device."""
        r = self.resolution
        centres = (torch.arange(s, dtype=torch.float32) + 0.5) / s
        offsets = torch.stack(torch.meshgrid(centres, centres, centres, indexing="ij"), -1).reshape(1, -1, 3)  # [1, s³, 3]
        idx = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1).float()  # [n, 3]
        per_chunk = max(chunk // s**3, 1)
        out = [torch.zeros(0, device=self.density.device)]
        for i in range(0, len(cells), per_chunk):
            unit = ((idx[i : i + per_chunk, None, :] + offsets) / r * 2.0 - 1.0).reshape(-1, 3)
            sigmas = density_fn(self.warp.inverse(unit.to(self.cube.device))).float()
            out.append(sigmas.reshape(-1, s**3).amax(-1).to(self.density.device))
        return torch.cat(out)

    def __call__(self, points: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        return occupied_at(self.bits, self.cube, self.warp(points))

    def cells_along(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """For a box warp (affine): (start, step) [n_rays, 3] such that the point at distance t along
        ray i lies at cell coordinates start_i + t step_i (cell [i, j, k] spans [i, i + 1) x [j, j + 1)
        x [k, k + 1)), so that a marcher reads the grid (:meth:`occupied_along`) without forming
        the points; None for other warps."""
        if self.warp.kind != "box":
            return None
        lo, hi = self.warp.aabb[0], self.warp.aabb[1]
        scale = self.resolution / (hi - lo)
        return (origins - lo) * scale, directions * scale

    def occupied_along(self, cells: tuple[torch.Tensor, torch.Tensor], t: torch.Tensor) -> torch.Tensor:
        """Whether the cells at distances ``t`` [n_rays, s] along rays with :meth:`cells_along`'s
        ``cells`` (start, step [n_rays, 3]) are occupied: [n_rays, s] bool. A point outside the
        grid reads the nearest cell (a marcher's samples lie between the box's entry and exit:
        outside only by rounding; an empty interval's t = inf, times a step of 0 NaN, reads a cell
        too, clamped after the cast to an integer). The cell index is formed axis by axis in int32
        (exact for grids of up to 1290 cells a side: 1290³ < 2³¹), without the [n_rays, s, 3]
        coordinates."""
        (start, step), r = cells, self.resolution
        flat = None
        for axis in range(3):
            i = torch.addcmul(start[:, axis, None], t, step[:, axis, None]).to(torch.int32).clamp_(0, r - 1)
            flat = i if flat is None else flat.mul_(r).add_(i)
        return self.bits.reshape(-1).index_select(0, flat.reshape(-1)).reshape(t.shape)

    @property
    def occupied_fraction(self) -> float:
        return float(self.bits.float().mean())


def rays_by_class(channels: torch.Tensor, rays: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``rays`` [n] (indices) grouped by their label ``channels`` [n] (-1: unlabelled, left out):
    (the labelled rays ordered by channel [m], each labelling channel's [start, count] in it [C, 2])."""
    labelled = channels >= 0
    order = torch.argsort(channels[labelled], stable=True)
    _, counts = torch.unique_consecutive(channels[labelled][order], return_counts=True)
    starts = torch.cumsum(counts, 0) - counts
    return rays[labelled][order], torch.stack([starts, counts], -1)


def class_balanced_rays(
    grouped: tuple[torch.Tensor, torch.Tensor], n: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """[n] rays drawn from ``grouped`` (:func:`rays_by_class`) class by class: each draw picks a
    labelling class uniformly, then one of its rays, so a lamp's few pixels come up as often as the
    walls'; and [n] their importance weights, K x the drawn class's share of the grouped rays (K
    classes): the ratio of a ray's chance in a uniform draw to its chance here, so a weighted mean
    over the drawn rays estimates the mean over all of them (weights average 1 over draws)."""
    rays, spans = grouped
    which = torch.randint(len(spans), (n,), generator=generator)
    start, count = spans[which].to(rays.device).unbind(-1)
    within = (torch.rand(n, generator=generator).to(rays.device) * count).long().clamp_(max=count - 1)
    share = count.double() / spans[:, 1].sum().to(rays.device)
    return rays[start + within], (len(spans) * share).float()
