"""One slab rule for rays against boxes: numpy (geometry.boxes) and torch (render.sampling) agree
with a naive float64 loop, decide parallel rays exactly, and stay finite-or-infinite at extremes."""

import math

import numpy as np
import pytest
import torch

from scenelabel.geometry.boxes import box_corners, ray_box_distances, slab_distances
from scenelabel.render.sampling import ray_aabb_intersect

LO, HI = np.array([-1.0, -2.0, 0.5]), np.array([1.0, 0.5, 3.0])


def _naive(o, d, lo, hi):
    """Entry / exit of one line through a box, axis by axis, in float64."""
    t_in, t_out = -math.inf, math.inf
    for a in range(3):
        if d[a] == 0.0:
            if not lo[a] <= o[a] <= hi[a]:
                return math.inf, -math.inf
            continue
        t0, t1 = (lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]
        t_in, t_out = max(t_in, min(t0, t1)), min(t_out, max(t0, t1))
    return t_in, t_out


def _rays(n=500, seed=0):
    rng = np.random.default_rng(seed)
    o = rng.normal(0, 2, (n, 3))
    d = rng.normal(0, 1, (n, 3))
    d[::5, 0] = 0.0  # parallel to the x slabs
    d[::7, 2] = 0.0
    o[::9, 0] = LO[0]  # on a face, and parallel to it
    d[::9, 0] = 0.0
    return o, d


def test_numpy_and_torch_match_a_naive_loop():
    o, d = _rays()
    want = np.array([_naive(o[i], d[i], LO, HI) for i in range(len(o))])
    t_enter, t_exit = ray_box_distances(o, d, LO, HI)
    hit = want[:, 0] <= want[:, 1]
    np.testing.assert_array_equal(t_enter <= t_exit, hit)
    np.testing.assert_allclose(t_enter[hit], want[hit, 0], rtol=1e-12)
    np.testing.assert_allclose(t_exit[hit], want[hit, 1], rtol=1e-12)
    t_min, t_max = ray_aabb_intersect(torch.tensor(o), torch.tensor(d), torch.tensor(np.stack([LO, HI])))
    np.testing.assert_array_equal((t_min <= t_max).numpy(), hit)
    np.testing.assert_allclose(t_min.numpy()[hit], want[hit, 0], rtol=1e-12)
    np.testing.assert_allclose(t_max.numpy()[hit], want[hit, 1], rtol=1e-12)


def test_a_parallel_ray_inside_its_slab_is_unbounded_along_it_and_outside_misses():
    enter, exit_ = slab_distances([[0.0, 0.0, 1.0], [5.0, 0.0, 1.0]], [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], LO, HI)
    assert enter[0, 0] == -np.inf and exit_[0, 0] == np.inf  # within x's slab for every t
    assert enter[1, 0] == np.inf and exit_[1, 0] == -np.inf  # never within it
    t_enter, t_exit = ray_box_distances([[5.0, 0.0, 1.0]], [[0.0, 1.0, 0.0]], LO, HI)
    assert t_exit[0] < t_enter[0]


@pytest.mark.parametrize("scale", [1e-30, 1e-8, 1.0, 1e8, 1e30])
def test_extreme_scales_give_no_nan(scale):
    o, d = _rays(200, seed=1)
    t_enter, t_exit = ray_box_distances(o * scale, d, LO * scale, HI * scale)
    assert not np.isnan(t_enter).any() and not np.isnan(t_exit).any()
    t_min, t_max = ray_aabb_intersect(torch.tensor(o * scale), torch.tensor(d), torch.tensor(np.stack([LO, HI]) * scale))
    assert not torch.isnan(t_min).any() and not torch.isnan(t_max).any()
    np.testing.assert_array_equal(t_enter <= t_exit, (t_min <= t_max).numpy())


def test_box_corners_against_a_loop():
    aabb = np.array([[-1.0, 0.5, 2.0], [3.0, 0.75, 2.5]])
    expected = [[aabb[a, 0], aabb[b, 1], aabb[c, 2]] for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    np.testing.assert_array_equal(box_corners(aabb), expected)
    assert box_corners(aabb.tolist()).dtype == np.float64
