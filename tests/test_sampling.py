"""Ray/AABB clipping, uniform marching and the density grid, against naive references."""

import math

import numpy as np
import pytest
import torch

from scenelabel.geometry.warps import BoxWarp, ForwardWarp
from scenelabel.render.sampling import (
    CARVE_MARGIN,
    CARVE_MIN_POINTS,
    MIN_DISPARITY,
    MIN_DISPARITY_T,
    PDF_EPS,
    DensityGrid,
    cell_indices,
    class_balanced_rays,
    free_cells_from_depth,
    importance_sample,
    march,
    march_disparity,
    march_uniform,
    merge_intervals,
    normalized_distances,
    occupied_at,
    ray_aabb_intersect,
    rays_by_class,
)


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


def test_grid_read_along_rays_matches_the_points():
    """cells_along + occupied_along (a marcher's read, no points formed) give the grid's answer at
    o + t d for points inside the box; a forward warp has no such read."""
    aabb = torch.tensor([[-1.0, -2.0, 0.5], [3.0, 1.0, 2.0]])
    grid = DensityGrid(BoxWarp(aabb), resolution=7, step=0.01)
    grid.bits = torch.rand(7, 7, 7, generator=torch.Generator().manual_seed(0)) < 0.5
    g = torch.Generator().manual_seed(1)
    origins = aabb[0] + torch.rand(50, 3, generator=g) * (aabb[1] - aabb[0])
    directions = torch.nn.functional.normalize(torch.randn(50, 3, generator=g), dim=-1)
    t = torch.rand(50, 9, generator=g) * 0.5
    points = origins[:, None] + t[..., None] * directions[:, None]
    inside = ((points >= aabb[0]) & (points < aabb[1])).all(-1)
    along = grid.occupied_along(grid.cells_along(origins, directions), t)
    # rays along the axes that miss the box: their marched t are inf (inf x a step of 0: NaN), still cells
    even = DensityGrid(BoxWarp(aabb), resolution=8, step=0.01)  # an even side: a NaN's wrapped index is out of range
    outside = even.cells_along(torch.full((3, 3), 10.0), torch.eye(3))
    assert even.occupied_along(outside, torch.full((3, 4), math.inf)).shape == (3, 4)
    assert int(inside.sum()) > 200
    torch.testing.assert_close(along[inside], grid(points)[inside])
    assert DensityGrid(_forward_warp(), resolution=4, step=0.01).cells_along(origins, directions) is None


def test_grid_update_marks_dense_cells_only():
    aabb = torch.tensor([[-1.0] * 3, [1.0] * 3])
    grid = DensityGrid(BoxWarp(aabb), resolution=8, step=0.01, alpha_threshold=0.01)
    assert grid.occupied_fraction == 1.0  # before the first update

    def density(p):  # a dense ball of radius 0.5
        return torch.where(p.norm(dim=-1) < 0.5, torch.full_like(p[:, 0], 100.0), torch.zeros_like(p[:, 0]))

    grid.update(density, decay=0.0, generator=torch.Generator().manual_seed(0))
    assert grid(torch.zeros(1, 3)).item()
    assert not grid(torch.tensor([[0.9, 0.9, 0.9]])).item()
    assert 0 < grid.occupied_fraction < 0.2



def _cells_crossed_naive(aabb_lo, aabb_hi, r, origin, direction, t0, t1):
    """float64 slab test per cell: the cells [i, j, k] whose box the segment meets."""
    size = (aabb_hi - aabb_lo) / r
    crossed = set()
    for i in range(r):
        for j in range(r):
            for k in range(r):
                lo = aabb_lo + size * np.array([i, j, k])
                hi = lo + size
                enter, leave = t0, t1
                for a in range(3):
                    if abs(direction[a]) < 1e-12:
                        if not lo[a] <= origin[a] < hi[a]:
                            enter, leave = 1.0, 0.0
                        continue
                    ta, tb = sorted(((lo[a] - origin[a]) / direction[a], (hi[a] - origin[a]) / direction[a]))
                    enter, leave = max(enter, ta), min(leave, tb)
                if leave - enter > 1e-3:  # crossed, not grazed at an edge
                    crossed.add((i, j, k))
    return crossed


def test_grid_reopen_opens_the_cells_a_segment_crosses_for_three_refreshes():
    """A grid emptied by a refresh: reopen gives the cells a segment crosses (against a float64 slab
    test per cell) 2x the threshold, no other; carved cells stay empty; with a decay of 0.8 and a
    field empty there they stay occupied for three refreshes and close at the fourth."""
    lo, hi, r = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]), 6
    grid = DensityGrid(BoxWarp(torch.tensor(np.stack([lo, hi]), dtype=torch.float32)), resolution=r, step=0.01)
    empty = lambda p: torch.zeros(len(p))  # noqa: E731
    grid.update(empty, decay=0.8, generator=torch.Generator().manual_seed(0))
    assert grid.occupied_fraction == 0.0
    grid.carved[0, 0, 0] = True
    origin, direction = np.array([-1.5, -0.9, -0.95]), np.array([1.0, 0.6, 0.5]) / np.linalg.norm([1.0, 0.6, 0.5])
    t0, t1 = 0.6, 2.9
    grid.reopen(*(torch.tensor(x[None], dtype=torch.float32) for x in (origin, direction)),
                torch.tensor([t0]), torch.tensor([t1]))
    expected = _cells_crossed_naive(lo, hi, r, origin, direction, t0, t1) - {(0, 0, 0)}
    assert len(expected) > r
    assert set(map(tuple, grid.bits.nonzero().tolist())) == expected
    threshold = float(grid.sigma_threshold.flatten()[0])
    i, j, k = next(iter(expected))
    assert grid.density[i, j, k].item() == pytest.approx(2.0 * threshold)
    for refresh in range(4):
        grid.update(empty, decay=0.8, generator=torch.Generator().manual_seed(refresh + 1))
        assert grid.bits.sum().item() == (len(expected) if refresh < 3 else 0)


def test_grid_observe_keeps_the_densest_sample_of_each_cell():
    """observe raises each cell's remembered density to the largest σ of the samples inside it (a
    float64 loop over the samples), ignores samples outside the box, and a cell held so survives a
    refresh whose random point misses what made it dense (a thin pole the training rays find)."""
    aabb = torch.tensor([[-2.0] * 3, [2.0] * 3])
    r = 4
    grid = DensityGrid(BoxWarp(aabb), resolution=r, step=0.01, alpha_threshold=0.01)
    grid.update(lambda p: torch.zeros(len(p)), decay=0.5, generator=torch.Generator().manual_seed(0))
    assert grid.occupied_fraction == 0.0
    rng = np.random.default_rng(3)
    points = rng.uniform(-2.5, 2.5, (200, 3))  # some outside the box
    sigmas = rng.uniform(0.0, 10.0, 200) ** 3
    grid.observe(torch.tensor(points, dtype=torch.float32), torch.tensor(sigmas, dtype=torch.float32))
    expected = np.zeros((r, r, r))
    for p, sigma in zip(points, sigmas):
        if np.all(p >= -2.0) and np.all(p < 2.0):
            i, j, k = ((p + 2.0) / 4.0 * r).astype(int)
            expected[i, j, k] = max(expected[i, j, k], sigma)
    np.testing.assert_allclose(grid.density.numpy(), expected, rtol=1e-6)
    threshold = float(grid.sigma_threshold.flatten()[0])
    grid.update(lambda p: torch.zeros(len(p)), decay=0.5, generator=torch.Generator().manual_seed(1))
    np.testing.assert_array_equal(grid.bits.numpy(), 0.5 * expected > threshold)
    assert grid.bits.any()


# ------------------------------------------------------------------ disparity marching, march()


def naive_disparity(t_min, t_max, n, u):
    """Float64 loop of march_disparity's docstring: ends at 1/t = (1-s)/t_min + s/t_max,
    s = min((k+u)/(n-1), 1), clamped to [t_min, t_max]; the first interval starts at t_min (clamped
    to MIN_DISPARITY_T)."""
    t_lo = max(t_min, MIN_DISPARITY_T)
    t_hi = max(t_max, t_lo)
    starts, ends = np.zeros(n), np.zeros(n)
    prev = t_lo
    for k in range(n):
        s = min((k + u) / max(n - 1, 1), 1.0)
        inv = max((1 - s) / t_lo + (0.0 if np.isinf(t_hi) else s / t_hi), MIN_DISPARITY)
        end = min(max(1.0 / inv, t_lo), t_hi)
        starts[k], ends[k] = prev, end
        prev = end
    return starts, ends


def test_march_disparity_matches_naive_loop():
    rng = np.random.default_rng(0)
    t_min = np.concatenate([rng.uniform(0.05, 2.0, 40), [0.3, 1.0, 2.0, 0.5]])
    t_max = np.concatenate([t_min[:40] + rng.uniform(0.0, 20.0, 40), [0.3, 0.5, 1e4, 0.5001]])  # equal, miss, long, short
    u = rng.uniform(0, 1, len(t_min))
    u[:5] = 0.0
    for n in (1, 2, 7, 64):
        for jitter in (None, u):
            t_starts, t_ends = march_disparity(
                torch.tensor(t_min), torch.tensor(t_max), n, None if jitter is None else torch.tensor(jitter)
            )
            assert t_starts.shape == t_ends.shape == (len(t_min), n)
            for i in range(len(t_min)):
                ref_s, ref_e = naive_disparity(t_min[i], t_max[i], n, 0.0 if jitter is None else jitter[i])
                np.testing.assert_allclose(t_starts[i].numpy(), ref_s, rtol=1e-12, atol=0)
                np.testing.assert_allclose(t_ends[i].numpy(), ref_e, rtol=1e-12, atol=0)


def test_march_disparity_intervals_are_contiguous_ordered_and_within_range():
    g = torch.Generator().manual_seed(1)
    t_min = torch.rand(300, generator=g) * 2 + 0.01
    t_max = t_min + torch.rand(300, generator=g) * 50
    jitter = torch.rand(300, generator=g)
    for n in (3, 33, 193):
        for j in (None, jitter):
            t_starts, t_ends = march_disparity(t_min, t_max, n, j)
            assert torch.all(t_starts[:, 0] == t_min)  # the first interval starts at t_min
            assert torch.all(t_starts[:, 1:] == t_ends[:, :-1])  # contiguous
            # non-negative lengths within [t_min, t_max] (ends are clamped: float32's 1 / (1 / t_min)
            # can round just below t_min)
            assert torch.all(t_ends >= t_starts)
            assert torch.all(t_ends <= t_max[:, None]) and torch.all(t_starts >= t_min[:, None])
            torch.testing.assert_close(t_ends[:, -1], t_max)  # the last end reaches t_max
            # n - 1 equal steps of disparity between consecutive ends (before the cut at t_max)
            inv = 1.0 / t_ends.double()
            steps = (inv[:, 1:] - inv[:, :-1])[:, :-1]
            expected = ((1.0 / t_max.double() - 1.0 / t_min.double()) / (n - 1))[:, None].expand_as(steps)
            torch.testing.assert_close(steps, expected, rtol=1e-4, atol=1e-6)
            # lengths grow with depth (a pixel's footprint does), before the cut at t_max
            lengths = (t_ends - t_starts)[:, 1:-1]
            assert torch.all(lengths[:, 1:] >= lengths[:, :-1] * (1 - 1e-5))


def test_march_disparity_covers_t_min_to_t_max():
    """n intervals, n - 1 equal disparity steps: the first starts at t_min, the last ends at t_max."""
    t_min, t_max = torch.tensor([1.0, 0.5, 1.0]), torch.tensor([4.0, 0.9, 100.0])
    for jitter in (None, torch.tensor([0.3, 0.9, 0.5])):
        t_starts, t_ends = march_disparity(t_min, t_max, 10, jitter)
        torch.testing.assert_close(t_starts[:, 0], t_min)
        torch.testing.assert_close(t_ends[:, -1], t_max)
        torch.testing.assert_close((t_ends - t_starts).sum(-1), t_max - t_min)
        assert torch.all(t_ends >= t_starts)  # ends clamped to [t_min, t_max]: no negative length


def test_march_disparity_far_infinity_and_near_zero_stay_finite():
    inf = float("inf")
    t_min = torch.tensor([0.5, 0.0, 0.0, 1e-9, 2.0])
    t_max = torch.tensor([inf, 3.0, inf, 1.0, inf])
    for jitter in (None, torch.tensor([0.0, 0.5, 0.99, 0.25, 0.9])):
        t_starts, t_ends = march_disparity(t_min, t_max, 16, jitter)
        assert torch.isfinite(t_starts).all() and torch.isfinite(t_ends).all()
        assert torch.all(t_starts[:, 1:] == t_ends[:, :-1]) and torch.all(t_ends >= t_starts)
        # t_min is clamped to MIN_DISPARITY_T: no 1/0
        assert torch.all(t_starts[:, 0] == t_min.clamp(min=MIN_DISPARITY_T))
        # with t_max = inf the last end is 1 / MIN_DISPARITY: huge, finite
        far_inf = torch.isinf(t_max)
        torch.testing.assert_close(t_ends[far_inf, -1], torch.full((3,), 1.0 / MIN_DISPARITY), rtol=1e-6, atol=0)


def test_march_disparity_rays_that_miss_have_empty_intervals():
    t_min = torch.tensor([2.0, 1.0, 0.0])
    t_max = torch.tensor([1.0, 1.0, -1.0])
    for jitter in (None, torch.tensor([0.3, 0.7, 0.1])):
        t_starts, t_ends = march_disparity(t_min, t_max, 8, jitter)
        assert torch.all(t_ends == t_starts)
        assert torch.isfinite(t_ends).all()


def test_march_dispatches_on_spacing():
    g = torch.Generator().manual_seed(4)
    t_min = torch.rand(20, generator=g) + 0.1
    t_max = t_min + torch.rand(20, generator=g) * 3
    jitter = torch.rand(20, generator=g)
    for j in (None, jitter):
        for got, ref in (
            (march("uniform", t_min, t_max, 0.1, 40, j), march_uniform(t_min, t_max, 0.1, 40, j)),
            (march("disparity", t_min, t_max, 0.1, 40, j), march_disparity(t_min, t_max, 40, j)),
        ):
            torch.testing.assert_close(got[0], ref[0], atol=0, rtol=0)
            torch.testing.assert_close(got[1], ref[1], atol=0, rtol=0)
    with pytest.raises(ValueError, match="unknown spacing"):
        march("lindisp", t_min, t_max, 0.1, 40)


# ------------------------------------------------------------------ density grid over a forward warp


def _forward_warp():
    c, s = np.cos(0.3), np.sin(0.3)
    rotation = np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])
    return ForwardWarp(np.array([0.1, -0.2, 0.05]), rotation, [0.8, 0.6], 0.2, 4.0)


def test_forward_grid_cell_points_lie_in_their_cells():
    r = 8
    grid = DensityGrid(_forward_warp(), resolution=r, step=0.01)
    cells = torch.arange(r**3)
    pts = grid.cell_points(cells, torch.Generator().manual_seed(0))
    assert pts.shape == (r**3, 3) and torch.isfinite(pts).all()
    unit = grid.warp(pts).double()
    idx = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1).double()
    lo, hi = idx / r * 2 - 1, (idx + 1) / r * 2 - 1
    tol = 1e-4
    assert torch.all(unit >= lo - tol) and torch.all(unit <= hi + tol)
    # away from the cell faces the index is exact
    found = ((unit + 1) / 2 * r).floor()
    clear = ((unit - lo).abs() > tol) & ((unit - hi).abs() > tol)
    assert clear.all(-1).float().mean() > 0.95
    assert torch.all((found == idx) | ~clear)
    # the lookup sees the same cells: mark one cell, only its points are occupied
    grid.bits = torch.zeros((r,) * 3, dtype=torch.bool)
    grid.bits[2, 5, 7] = True
    cell = 2 * r * r + 5 * r + 7
    inner = grid.cell_points(torch.full((50,), cell), torch.Generator().manual_seed(1))
    assert grid(inner).float().mean() > 0.95
    others = grid.cell_points(torch.tensor([c for c in range(r**3) if c != cell]), torch.Generator().manual_seed(2))
    assert grid(others).float().mean() < 0.01


def test_forward_grid_per_slice_step_gives_per_slice_threshold():
    r = 8
    steps = torch.linspace(0.01, 0.5, r)  # disparity marching: steps grow with depth (slice index)
    alpha = 0.01
    grid = DensityGrid(_forward_warp(), resolution=r, step=steps, alpha_threshold=alpha)
    thresholds = -np.log1p(-alpha) / steps.double().numpy()
    np.testing.assert_allclose(grid.sigma_threshold.reshape(-1).numpy(), thresholds, rtol=1e-6)
    sigma = float(np.sqrt(thresholds[0] * thresholds[-1]))  # above the far slices' threshold, below the near ones'
    assert thresholds[-1] < sigma < thresholds[0]
    grid.update(lambda p: torch.full((len(p),), sigma), decay=0.0, generator=torch.Generator().manual_seed(0))
    expected = torch.tensor(sigma > thresholds)  # [r] per depth slice
    assert expected[-1] and not expected[0]
    assert torch.equal(grid.bits, expected.reshape(1, 1, r).expand(r, r, r))
    # a scalar step is one threshold for every slice
    flat = DensityGrid(_forward_warp(), resolution=r, step=0.05, alpha_threshold=alpha)
    flat.update(lambda p: torch.full((len(p),), sigma), decay=0.0, generator=torch.Generator().manual_seed(0))
    assert bool(flat.bits.all()) == (sigma > -np.log1p(-alpha) / 0.05) and flat.bits.unique().numel() == 1


def naive_importance_sample(starts, ends, weights, us):
    """Float64 loop: walk the CDF of (w_i + PDF_EPS δ_i / Σ δ) interval by interval for each u."""
    lengths = [max(e - s, 0.0) for s, e in zip(starts, ends)]
    total = sum(lengths)
    mass = [(w if d > 0 else 0.0) + PDF_EPS * d / total for w, d in zip(weights, lengths)]
    z = sum(mass)
    out = []
    for u in us:
        acc = 0.0
        for s, d, m in zip(starts, lengths, mass):
            if m > 0 and acc + m / z > u:
                out.append(s + (u - acc) / (m / z) * d)
                break
            acc += m / z
        else:
            out.append(starts[-1] + lengths[-1])
    return np.array(out)


def test_importance_sample_matches_a_naive_float64_loop():
    g = torch.Generator().manual_seed(0)
    n_rays, n_int, n_new = 30, 12, 17
    lengths = torch.rand(n_rays, n_int, generator=g, dtype=torch.float64) * 0.3
    lengths[:5, -3:] = 0.0  # zero-length intervals past the ray's end
    t_ends = 0.5 + torch.cumsum(lengths, -1)
    t_starts = torch.cat([torch.full((n_rays, 1), 0.5, dtype=torch.float64), t_ends[:, :-1]], -1)
    weights = torch.rand(n_rays, n_int, generator=g, dtype=torch.float64) ** 4
    weights[5:8] = 0.0  # nothing seen: uniform along the ray
    jitter = torch.rand(n_rays, n_new, generator=g, dtype=torch.float64)
    for j in (None, jitter):
        t = importance_sample(t_starts, t_ends, weights, n_new, j)
        assert t.shape == (n_rays, n_new) and torch.all(t[:, 1:] >= t[:, :-1])
        for r in range(n_rays):
            u = (np.arange(n_new) + (0.5 if j is None else j[r].numpy())) / n_new
            ref = naive_importance_sample(t_starts[r].tolist(), t_ends[r].tolist(), weights[r].tolist(), u)
            np.testing.assert_allclose(t[r].numpy(), ref, rtol=0, atol=1e-9)
    uniform = importance_sample(t_starts[5:8], t_ends[5:8], weights[5:8], n_new)  # zero weights: evenly spread
    span = t_ends[5:8, -1:] - t_starts[5:8, :1]
    expected = t_starts[5:8, :1] + span * (torch.arange(n_new, dtype=torch.float64) + 0.5) / n_new
    torch.testing.assert_close(uniform, expected)


def test_importance_sample_puts_the_samples_where_the_weight_is():
    t_starts = torch.linspace(0.0, 0.9, 10)[None].repeat(2, 1)
    t_ends = t_starts + 0.1
    weights = torch.zeros(2, 10)
    weights[0, 6] = 1.0
    weights[1, 2] = weights[1, 7] = 0.5
    t = importance_sample(t_starts, t_ends, weights, 64)
    assert torch.all((t[0] >= 0.6) & (t[0] <= 0.7))
    assert ((t[1] >= 0.2) & (t[1] <= 0.3)).sum() == 32 and ((t[1] >= 0.7) & (t[1] <= 0.8)).sum() == 32


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_importance_sample_is_finite_at_extremes(dtype):
    # a ray that misses (all intervals empty), one ending at the 1e30 disparity cap, tiny and huge weights
    t_starts = torch.tensor([[1.0, 1.0, 1.0], [0.1, 1.0, 2.0], [1e-6, 2e-6, 3e-6], [0.0, 1.0, 2.0]], dtype=dtype)
    t_ends = torch.tensor([[1.0, 1.0, 1.0], [1.0, 2.0, 1e30], [2e-6, 3e-6, 4e-6], [1.0, 2.0, 3.0]], dtype=dtype)
    weights = torch.tensor([[0.0, 0.0, 0.0], [1e-30, 1.0, 1e-3], [1.0, 0.0, 0.0], [1e-38, 0.0, 1.0]], dtype=dtype)
    t = importance_sample(t_starts, t_ends, weights, 9, torch.rand(4, 9, dtype=dtype))
    assert torch.isfinite(t).all()
    assert torch.all(t >= t_starts[:, :1]) and torch.all(t <= t_ends[:, -1:])
    torch.testing.assert_close(t[0], torch.ones(9, dtype=dtype))  # the empty ray: its start


def test_merge_intervals_splits_the_same_span():
    t_starts, t_ends = march_uniform(torch.tensor([0.2, 1.0]), torch.tensor([1.4, 1.6]), 0.25, 7, torch.tensor([0.3, 0.0]))
    t_new = torch.tensor([[0.3, 0.31, 1.39], [1.0, 1.2, 1.6]])
    starts, ends = merge_intervals(t_starts, t_ends, t_new)
    assert starts.shape == (2, 10)
    torch.testing.assert_close(starts[:, 1:], ends[:, :-1])  # contiguous
    assert torch.all(ends >= starts)
    torch.testing.assert_close((ends - starts).sum(-1), (t_ends - t_starts).sum(-1))
    for r in range(2):
        edges = set(torch.cat([starts[r], ends[r]]).tolist())
        assert set(t_new[r].tolist()) <= edges and set(t_ends[r].tolist()) <= edges


def naive_rebuild(density, warp, r, s, threshold, border, border_s):
    """Float64 loops: each cell's largest density at its s³ sub-cell centres; then each cell within
    ``border`` cells (along every axis) of an occupied one, not occupied itself, at border_s³."""

    def lattice_max(i, j, k, n):
        best = 0.0
        for a in range(n):
            for b in range(n):
                for c in range(n):
                    unit = (np.array([i + (a + 0.5) / n, j + (b + 0.5) / n, k + (c + 0.5) / n]) / r) * 2 - 1
                    point = warp.inverse(torch.tensor(unit[None], dtype=torch.float32))
                    best = max(best, float(density(point)[0]))
        return best

    cells = [(i, j, k) for i in range(r) for j in range(r) for k in range(r)]
    dense = np.zeros((r, r, r), dtype=bool)
    for i, j, k in cells:
        dense[i, j, k] = lattice_max(i, j, k, s) > threshold
    out = dense.copy()
    for i, j, k in cells:
        near = dense[max(i - border, 0) : i + border + 1, max(j - border, 0) : j + border + 1, max(k - border, 0) : k + border + 1]
        if border > 0 and not dense[i, j, k] and near.any():
            out[i, j, k] = lattice_max(i, j, k, border_s) > threshold
    return out


@pytest.mark.parametrize("border", [0, 1])
def test_grid_rebuild_matches_a_naive_loop_and_forgets_stale_cells(border):
    aabb = torch.tensor([[-1.0] * 3, [1.0] * 3])
    r, s, border_s = 6, 3, 6
    grid = DensityGrid(BoxWarp(aabb), resolution=r, step=0.01, alpha_threshold=0.01)

    def density(p):  # a slab at 0.25 < x < 0.37 across the cell face at x = 1/3, faint haze elsewhere:
        # the 3³ lattice meets it in the cell below the face (at x = 0.28) only, the 6³ in both (x = 0.36)
        return torch.where((p[:, 0] - 0.31).abs() < 0.06, torch.full_like(p[:, 0], 50.0), torch.full_like(p[:, 0], 1e-3))

    grid.update(lambda p: torch.full((len(p),), 1e3), decay=0.95, generator=torch.Generator().manual_seed(0))
    assert grid.occupied_fraction == 1.0  # a dense field earlier: every cell held occupied
    grid.rebuild(density, samples_per_axis=s, border=border, border_samples=border_s, chunk=100)
    threshold = float(grid.sigma_threshold.flatten()[0])
    expected = naive_rebuild(density, grid.warp, r, s, threshold, border, border_s)
    np.testing.assert_array_equal(grid.bits.numpy(), expected)
    assert grid(torch.tensor([[0.3, 0.0, 0.0], [0.3, -0.9, 0.9]])).all()  # the slab is never skipped
    assert not grid(torch.tensor([[-0.9, 0.0, 0.0], [0.7, 0.0, 0.0]])).any()  # far from it: free
    # one slice of cells, and with the second look the slice beyond the face the slab crosses, not
    # the free slice on the other side
    assert expected.mean() == pytest.approx((1 + border) / r)


def test_normalized_distances_invert_the_march():
    """The march puts its disparity ends at s = min((k + u) / (n - 1), 1); uniform s is the fraction
    of the way (a naive float64 loop); both stay in [0, 1] and finite at the extremes."""
    rng = np.random.default_rng(7)
    t_min = torch.tensor(np.concatenate([rng.uniform(0.05, 2.0, 30), [0.5, 1e-9, 1.0]]))
    t_max = torch.tensor(np.concatenate([t_min[:30].numpy() + rng.uniform(0.1, 20.0, 30), [np.inf, 3.0, 1.0]]))
    u = torch.tensor(rng.uniform(0.0, 1.0, len(t_min)))
    n = 16
    _, t_ends = march_disparity(t_min, t_max, n, u)
    s = normalized_distances("disparity", t_ends, t_min, t_max)
    expected = ((torch.arange(n)[None, :] + u[:, None]) / (n - 1)).clamp(max=1.0)
    np.testing.assert_allclose(s[:-1].numpy(), expected[:-1].numpy(), atol=1e-9)  # the last ray is empty
    assert torch.all(s[-1] == 0.0)
    t = t_min[:, None] + torch.tensor(rng.uniform(0.0, 1.0, (len(t_min), 5))) * (t_max - t_min).clamp(max=1e6)[:, None]
    uniform = normalized_distances("uniform", t, t_min, t_max)
    for r in range(30):
        for k in range(5):
            ref = (float(t[r, k]) - float(t_min[r])) / (float(t_max[r]) - float(t_min[r]))
            assert float(uniform[r, k]) == pytest.approx(ref, rel=1e-12, abs=1e-15)
    for spacing in ("uniform", "disparity"):
        out = normalized_distances(spacing, t.float(), t_min.float(), t_max.float())
        assert torch.all(torch.isfinite(out)) and torch.all((out >= 0) & (out <= 1))
    with pytest.raises(ValueError, match="spacing"):
        normalized_distances("log", t, t_min, t_max)


# ------------------------------------------------------------------ space carving from sensor depth

CUBE = torch.tensor([[-1.0] * 3, [1.0] * 3])


def naive_cell(r, p):
    """The [i, j, k] cell of point p (float64) in an [r, r, r] grid over [-1, 1]^3, None outside."""
    if not all(-1.0 <= x < 1.0 for x in p):
        return None
    return tuple(min(int((x + 1.0) / 2.0 * r), r - 1) for x in p)


def naive_free_cells(r, origins, directions, t_min, t_max, depth, step, u):
    """Float64 loop of free_cells_from_depth's rule with the rays' jitter ``u`` (identity warp)."""
    votes, hits = np.zeros((r, r, r), int), np.zeros((r, r, r), bool)
    valid = [i for i in range(len(depth)) if np.isfinite(depth[i]) and np.isfinite(t_max[i]) and depth[i] > t_min[i]]
    for n, i in enumerate(valid):
        o, d = origins[i].astype(np.float64), directions[i].astype(np.float64)
        hit = naive_cell(r, o + d * float(depth[i]))
        if hit is not None:
            hits[hit] = True
        t0, t_end = max(float(t_min[i]), 0.0), min(float(depth[i]) * (1 - CARVE_MARGIN) - step, float(t_max[i]))
        k = 0
        while t0 + step * (k + u[n]) < t_end:
            cell = naive_cell(r, o + d * (t0 + step * (k + u[n])))
            if cell is not None:
                votes[cell] += 1
            k += 1
    near = np.zeros_like(hits)
    for i, j, k in zip(*np.nonzero(hits)):
        near[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2, max(k - 1, 0) : k + 2] = True
    return (votes >= CARVE_MIN_POINTS) & ~near


def test_cell_indices_match_a_naive_loop():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1.2, 1.2, (500, 3))
    pts[:3] = [[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.999, 0.999, 0.999]]  # the cube's corner, outside, the last cell
    flat = cell_indices(5, torch.tensor(pts, dtype=torch.float64))
    for p, f in zip(pts, flat.tolist()):
        cell = naive_cell(5, p)
        assert f == (-1 if cell is None else (cell[0] * 5 + cell[1]) * 5 + cell[2])


def _rays_towards(origin, targets):
    """Unit rays from ``origin`` to each target, with the distance as depth (float32 tensors)."""
    vec = np.asarray(targets, np.float64) - np.asarray(origin, np.float64)
    depth = np.linalg.norm(vec, axis=1)
    origins = torch.tensor(np.broadcast_to(origin, vec.shape), dtype=torch.float32)
    return origins, torch.tensor(vec / depth[:, None], dtype=torch.float32), torch.tensor(depth, dtype=torch.float32)


def test_free_cells_from_depth_match_a_naive_float64_loop():
    rng = np.random.default_rng(0)
    targets = np.column_stack([rng.uniform(0.5, 0.9, 300), rng.uniform(-0.9, 0.9, (300, 2))])  # a far, rough wall
    origins, directions, depth = _rays_towards([-0.95, 0.1, -0.2], targets)
    depth[::7] = float("nan")  # holes
    depth[5] = 1e-3  # at the camera: before t_min
    t_min, t_max = ray_aabb_intersect(origins, directions, CUBE)
    t_max[9] = float("inf")
    r, step = 8, 2.0 / 8
    free = free_cells_from_depth(
        BoxWarp(CUBE), r, origins, directions, t_min.clamp(min=0.01), t_max, depth, step, torch.Generator().manual_seed(4)
    )
    n_valid = int((torch.isfinite(depth) & torch.isfinite(t_max) & (depth > t_min.clamp(min=0.01))).sum())
    u = torch.rand((n_valid, 1), generator=torch.Generator().manual_seed(4))[:, 0].double().numpy()
    expected = naive_free_cells(r, origins.numpy(), directions.numpy(), t_min.clamp(min=0.01).numpy(), t_max.numpy(),
                                depth.numpy(), step, u)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(free.numpy(), expected)


def _wall_rays(n=32, wall_x=0.6):
    """n x n rays from x = -0.95 straight at a wall x = wall_x, over the whole cube's face."""
    yz = (np.arange(n) + 0.5) / n * 1.9 - 0.95
    targets = [[wall_x, y, z] for y in yz for z in yz]
    origins = torch.tensor([[-0.95, y, z] for y, z in np.asarray(targets)[:, 1:]], dtype=torch.float32)
    directions = torch.tensor([[1.0, 0.0, 0.0]] * len(targets))
    depth = torch.full((len(targets),), wall_x + 0.95)
    t_min, t_max = ray_aabb_intersect(origins, directions, CUBE)
    return origins, directions, t_min.clamp(min=0.0), t_max, depth


def test_carving_frees_the_space_in_front_of_a_wall_and_nothing_at_or_behind_it():
    origins, directions, t_min, t_max, depth = _wall_rays()
    free = free_cells_from_depth(BoxWarp(CUBE), 8, origins, directions, t_min, t_max, depth, 0.25)
    # cells along x: [-1, -0.75), ... the wall at 0.6 is in cell 6; cells 5-7 lie within one of its cells
    assert free[:5].all()
    assert not free[5:].any()


def test_carving_needs_several_points_and_measured_depth():
    origins, directions, t_min, t_max, depth = _wall_rays()
    warp = BoxWarp(CUBE)
    assert not free_cells_from_depth(warp, 8, origins, directions, t_min, t_max, torch.full_like(depth, float("nan")), 0.25).any()
    one = free_cells_from_depth(warp, 8, origins[:1], directions[:1], t_min[:1], t_max[:1], depth[:1], 0.25)
    assert not one.any()  # one ray puts at most two points in a cell: no cell is freed by one stray depth
    with pytest.raises(ValueError, match="step"):
        free_cells_from_depth(warp, 8, origins, directions, t_min, t_max, depth, 0.0)


@pytest.mark.parametrize("value", [0.0, 1e-30, 1e30, float("inf"), float("nan")])
def test_carving_is_finite_at_extreme_depths(value):
    """A depth at the camera, tiny, beyond the box or missing carves nothing wrong and stays cheap:
    points never go past the box (t_max), and a surface outside the cube marks no cell."""
    origins, directions, t_min, t_max, depth = _wall_rays()
    free = free_cells_from_depth(BoxWarp(CUBE), 8, origins, directions, t_min, t_max, torch.full_like(depth, value), 0.25)
    if value == 1e30:  # seen through the whole box: every cell the rays cross is free
        assert free.any()
    else:
        assert not free.any()


def test_carved_cells_stay_empty_through_refreshes_and_rebuilds():
    grid = DensityGrid(BoxWarp(CUBE), resolution=6, step=0.01, alpha_threshold=0.01)
    free = torch.zeros(6, 6, 6, dtype=torch.bool)
    free[:2] = True
    grid.carve(free)
    assert not grid.bits[:2].any() and grid.bits[2:].all()  # before any refresh: carved cells are skipped
    dense = lambda p: torch.full((len(p),), 1e3)  # noqa: E731
    grid.update(dense, generator=torch.Generator().manual_seed(0))
    assert not grid.bits[:2].any() and grid.bits[2:].all()
    grid.update(dense, all_cells=False, generator=torch.Generator().manual_seed(1))
    seen = []
    grid.rebuild(lambda p: seen.append(p) or dense(p), border=1)
    assert not grid.bits[:2].any() and grid.bits[2:].all()
    # the rebuild evaluates the uncarved cells alone (27 points each; all occupied, none is looked at again)
    # and leaves the carved ones at 0
    points = torch.cat(seen)
    assert len(points) == 4 * 36 * 27 and bool((grid.warp(points)[:, 0] > -1 + 2 * 2 / 6).all())
    assert not grid.density[:2].any()
    assert "carved" not in grid.state_dict()  # a saved grid's bits already leave the carved cells out
    grid.release_carve_border()  # the carve's border (the cells beside uncarved ones) back to the field
    grid.update(dense, generator=torch.Generator().manual_seed(2))
    assert grid.bits[1:].all() and not grid.bits[0].any()
    assert grid.carved[0].all() and not grid.carved[1:].any()


def test_class_balanced_rays_draw_each_labelling_class_alike():
    """rays_by_class groups a pool by label (unlabelled rays left out); class_balanced_rays draws the
    five rays of a rare class as often as the thousand of a common one, and every one of them; each
    draw's importance weight is 2 x its class's share of the labelled rays, 1 on average."""
    channels = torch.cat([torch.zeros(1000, dtype=torch.long), torch.full((5,), 3), torch.full((50,), -1)])
    pool = torch.arange(len(channels)) + 7  # ray indices, not positions
    grouped = rays_by_class(channels, pool)
    assert grouped[1].tolist() == [[0, 1000], [1000, 5]]
    drawn, weights = class_balanced_rays(grouped, 4000, torch.Generator().manual_seed(0))
    labels = channels[drawn - 7]
    assert torch.allclose(weights, torch.where(labels == 3, 2 * 5 / 1005, 2 * 1000 / 1005))
    assert float(weights.mean()) == pytest.approx(1.0, abs=0.05)
    assert (labels >= 0).all()
    assert 0.45 < float((labels == 3).float().mean()) < 0.55
    assert set(drawn[labels == 3].tolist()) == set(range(1007, 1012))
    assert [len(t) for t in class_balanced_rays(grouped, 0, torch.Generator())] == [0, 0]
