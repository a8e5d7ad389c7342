"""Where to evaluate the field along rays: ray/AABB clipping, uniform marching, empty-space skipping.

Pure functions, plus :class:`OccupancyGrid`, a thin state holder (a bit grid over the scene box,
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
    "occupied_at",
    "OccupancyGrid",
]

DIR_EPS = 1e-12
"""Direction components smaller than this are replaced by ±DIR_EPS before 1/d (slab test)."""


def ray_aabb_intersect(
    origins: torch.Tensor, directions: torch.Tensor, aabb: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances of rays through an axis-aligned box (slab test).

    Args:
        origins: [n_rays, 3].
        directions: [n_rays, 3] (need not be unit; t is in units of |d|).
        aabb: [2, 3] (min corner, max corner).
    Returns:
        t_min, t_max: [n_rays]; a ray misses the box when t_max < max(t_min, 0).
        Rays starting inside the box have t_min < 0.
    """
    d = torch.where(directions.abs() < DIR_EPS, torch.where(directions < 0, -DIR_EPS, DIR_EPS), directions)
    inv = 1.0 / d
    t0 = (aabb[0] - origins) * inv
    t1 = (aabb[1] - origins) * inv
    t_min = torch.minimum(t0, t1).amax(-1)
    t_max = torch.maximum(t0, t1).amin(-1)
    return t_min, t_max


def march_uniform(
    t_min: torch.Tensor,
    t_max: torch.Tensor,
    step: float,
    n_samples: int,
    jitter: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fixed-step intervals from t_min to t_max, the last one cut at t_max.

    Interval k spans [t_min + (k + u - 1) step, t_min + (k + u) step] clipped to [t_min, t_max],
    with u in [0, 1) a per-ray jitter (0 for deterministic rendering). Intervals past t_max have
    zero length and contribute nothing to rendering.

    Args:
        t_min, t_max: [n_rays] (rays that miss have t_max <= t_min: all intervals empty).
        step: interval length.
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


def occupied_at(bits: torch.Tensor, aabb: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Look up a boolean occupancy grid covering ``aabb`` at ``points`` (outside -> False).

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
    idx = (rel * res).long()
    idx = torch.minimum(idx.clamp(min=0), res - 1)
    return bits[idx[..., 0], idx[..., 1], idx[..., 2]] & inside


class OccupancyGrid(nn.Module):
    """A [R, R, R] grid over the scene box marking cells that may hold density.

    Each cell keeps an exponential moving average of the largest density seen at random points
    inside it; a cell is occupied when that density could make a marching step at least
    ``alpha_threshold`` opaque. Until the first update every cell is occupied.
    """

    def __init__(self, aabb: torch.Tensor, resolution: int = 64, step: float = 0.01, alpha_threshold: float = 0.005):
        super().__init__()
        self.resolution = resolution
        self.register_buffer("aabb", aabb.clone().float())
        self.register_buffer("density", torch.full((resolution,) * 3, float("inf")))
        self.register_buffer("bits", torch.ones((resolution,) * 3, dtype=torch.bool))
        self.sigma_threshold = -math.log1p(-alpha_threshold) / step

    def cell_points(self, cells: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """One random point in each of ``cells`` (flat indices into the grid): [n, 3]."""
        r = self.resolution
        idx = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1)
        u = torch.rand(idx.shape, generator=generator)
        rel = (idx + u) / r
        return (self.aabb[0].cpu() + rel * (self.aabb[1] - self.aabb[0]).cpu()).to(self.aabb.device)

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
        points = self.cell_points(cells, generator)
        sigmas = torch.cat([density_fn(points[i : i + chunk]) for i in range(0, len(points), chunk)]).float()
        density = self.density.flatten()
        density = torch.where(torch.isinf(density), torch.zeros_like(density), density)  # inf: never refreshed
        cells = cells.to(density.device)
        density[cells] = torch.maximum(density[cells] * decay, sigmas.to(density.device))
        self.density = density.reshape(self.density.shape)
        self.bits = self.density > self.sigma_threshold

    def __call__(self, points: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        return occupied_at(self.bits, self.aabb, points)

    @property
    def occupied_fraction(self) -> float:
        return float(self.bits.float().mean())
