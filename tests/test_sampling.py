"""Ray/AABB clipping, uniform marching and the occupancy grid, against naive references."""

import numpy as np
import torch

from scenelabel.sampling import OccupancyGrid, march_uniform, occupied_at, ray_aabb_intersect


def naive_slab(o, d, lo, hi):
    """Float64 loop over axes (the reference slab test); returns (t_min, t_max)."""
    t0, t1 = -np.inf, np.inf
    for a in range(3):
        if d[a] == 0.0:
            if o[a] < lo[a] or o[a] > hi[a]:
                return np.inf, -np.inf
            continue
        ta, tb = (lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t0, t1


def test_ray_aabb_matches_naive_loop():
    rng = np.random.default_rng(0)
    o = rng.uniform(-3, 3, (200, 3))
    d = rng.normal(size=(200, 3))
    d[:20, 0] = 0.0  # axis-parallel rays
    lo, hi = np.array([-1.0, -0.5, -0.2]), np.array([1.0, 0.5, 0.7])
    t_min, t_max = ray_aabb_intersect(torch.tensor(o), torch.tensor(d), torch.tensor(np.stack([lo, hi])))
    for i in range(len(o)):
        r0, r1 = naive_slab(o[i], d[i], lo, hi)
        hit_ref = r1 >= max(r0, 0)
        hit = t_max[i] >= max(t_min[i], 0)
        assert bool(hit) == bool(hit_ref)
        if hit_ref:
            np.testing.assert_allclose([t_min[i], t_max[i]], [r0, r1], rtol=1e-9, atol=1e-9)


def test_ray_starting_inside_has_negative_entry():
    t_min, t_max = ray_aabb_intersect(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0]]), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    assert t_min.item() == -1.0 and t_max.item() == 1.0


def test_march_covers_interval_exactly_once():
    t_min = torch.tensor([0.5, 1.0, 2.0])
    t_max = torch.tensor([1.7, 1.05, 1.0])  # last ray misses
    for jitter in (None, torch.tensor([0.3, 0.9, 0.0])):
        t_starts, t_ends = march_uniform(t_min, t_max, 0.25, 8, jitter)
        lengths = (t_ends - t_starts).sum(-1)
        np.testing.assert_allclose(lengths.numpy(), [1.2, 0.05, 0.0], atol=1e-6)
        assert torch.all(t_ends >= t_starts)
        assert torch.all(t_starts[:, 1:] == t_ends[:, :-1])


def test_occupied_at_indexing_and_outside():
    bits = torch.zeros(4, 4, 4, dtype=torch.bool)
    bits[3, 0, 2] = True
    aabb = torch.tensor([[0.0, 0.0, 0.0], [4.0, 8.0, 4.0]])
    pts = torch.tensor([[3.5, 1.0, 2.5], [3.5, 3.0, 2.5], [4.5, 1.0, 2.5], [-0.1, 1.0, 2.5]])
    assert occupied_at(bits, aabb, pts).tolist() == [True, False, False, False]


def test_grid_update_marks_dense_cells_only():
    aabb = torch.tensor([[-1.0] * 3, [1.0] * 3])
    grid = OccupancyGrid(aabb, resolution=8, step=0.01, alpha_threshold=0.01)
    assert grid.occupied_fraction == 1.0  # before the first update

    def density(p):  # a dense ball of radius 0.5
        return torch.where(p.norm(dim=-1) < 0.5, torch.full_like(p[:, 0], 100.0), torch.zeros_like(p[:, 0]))

    grid.update(density, decay=0.0, generator=torch.Generator().manual_seed(0))
    assert grid(torch.zeros(1, 3)).item()
    assert not grid(torch.tensor([[0.9, 0.9, 0.9]])).item()
    assert 0 < grid.occupied_fraction < 0.2
