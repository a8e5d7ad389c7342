"""The compiled ray casts (scenelabel.maps.raycast_kernels behind first_voxel_hits,
transmittance_crossings and OccupancyMap.cast_rays) give bit for bit the answers of the numpy
voxel walk they replaced, kept here as the reference (the naive float64 loops of
tests/test_maps.py check both against the geometry)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenelabel.geometry.boxes import ray_box_distances
from scenelabel.maps import FREE, UNKNOWN, OccupancyMap, first_voxel_hits, transmittance_crossings, uint8_from_unit
from scenelabel.maps.raycast import leap_lengths, ray_limits

# ---------------------------------------------------------------------------- the numpy reference
# (scenelabel/maps/raycast.py before the compiled kernels, unchanged but for the names)


def reference_leap_lengths(stop: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return np.maximum(ndimage.distance_transform_cdt(~stop, metric="chessboard") - 1, 0).astype(np.int32)


def _voxel_of(o, d, t, corner, voxel_size, shape):
    return np.clip(np.floor((o + t[:, None] * d - corner) / voxel_size), 0, np.asarray(shape) - 1).astype(np.int64)


def _safe_leaps(o, d, t, t_end, leaps, corner, voxel_size):
    t = t.copy()
    active = np.arange(len(t))
    flat, strides = leaps.ravel(), np.asarray(leaps.strides) // leaps.itemsize
    while active.size:
        leap = flat[_voxel_of(o[active], d[active], t[active], corner, voxel_size, leaps.shape) @ strides]
        moving = leap > 0
        active = active[moving]
        t[active] += leap[moving] * voxel_size
        active = active[t[active] < t_end[active]]
    return t


def _walk_voxels(o, d, t, t_end, codes, sigma_of_code, corner, voxel_size, threshold):
    shape = np.asarray(codes.shape)
    depth, index = np.full(len(t), np.inf), np.full((len(t), 3), -1, dtype=np.int64)
    rays = np.arange(len(t))
    ijk = _voxel_of(o, d, t, corner, voxel_size, shape)
    step = np.sign(d).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_next = np.where(d != 0, (corner + (ijk + (step > 0)) * voxel_size - o) / d, np.inf)
        t_delta = np.where(d != 0, voxel_size / np.abs(d), np.inf)
    flat, strides = codes.ravel(), np.asarray(codes.strides) // codes.itemsize
    t, t_end = t.copy(), t_end.copy()
    tau = np.zeros(len(t))
    while rays.size:
        rows = np.arange(len(rays))
        axis = t_next.argmin(-1)
        t_out = np.minimum(t_next[rows, axis], t_end)
        sigma = sigma_of_code[flat[ijk @ strides]]
        opaque = np.isinf(sigma)
        with np.errstate(invalid="ignore"):
            tau_out = np.where(opaque, np.inf, tau + sigma * (t_out - t))
            hit = tau_out >= threshold
            depth[rays[hit]] = t[hit] + np.where(opaque[hit], 0.0, (threshold - tau[hit]) / sigma[hit])
        index[rays[hit]] = ijk[hit]
        t, tau = t_out, tau_out
        ijk[rows, axis] += step[rows, axis]
        t_next[rows, axis] += t_delta[rows, axis]
        moved = ijk[rows, axis]
        keep = ~hit & (t < t_end) & (moved >= 0) & (moved < shape[axis])
        rays, t, t_end, tau, ijk, step, t_next, t_delta = (a[keep] for a in (rays, t, t_end, tau, ijk, step, t_next, t_delta))
    return depth, index


def reference_crossings(origins, directions, codes, tau_of_code, origin, voxel_size, near, far, threshold):
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    n, shape = len(origins), np.asarray(codes.shape)
    voxel_size = float(voxel_size)
    corner = np.asarray(origin, np.float64) - voxel_size / 2.0
    near, far = ray_limits(n, near, far)
    t_enter, t_exit = ray_box_distances(origins, directions, corner, corner + voxel_size * shape)
    t_enter, t_exit = np.maximum(t_enter, near), np.minimum(t_exit, far)
    depth, index = np.full(n, np.inf), np.full((n, 3), -1, dtype=np.int64)
    rays = np.flatnonzero(t_exit > t_enter)
    matter = codes > 0
    if not matter.any() or rays.size == 0:
        return depth, index
    t = _safe_leaps(origins[rays], directions[rays], t_enter[rays], t_exit[rays], reference_leap_lengths(matter), corner, voxel_size)
    walk = t < t_exit[rays]
    rays = rays[walk]
    hit_depth, hit_index = _walk_voxels(
        origins[rays], directions[rays], t[walk], t_exit[rays], codes, tau_of_code / voxel_size, corner, voxel_size, threshold
    )
    depth[rays], index[rays] = hit_depth, hit_index
    return depth, index


def reference_first_voxel_hits(origins, directions, stop, origin, voxel_size, near=None, far=None):
    opaque = np.array([0.0, np.inf])
    return reference_crossings(origins, directions, np.asarray(stop, bool).view(np.uint8), opaque, origin, voxel_size, near, far, 1.0)


def reference_transmittance_crossings(origins, directions, occupancy, origin, voxel_size, near=None, far=None, transmittance=0.5):
    with np.errstate(divide="ignore"):
        tau_of_code = -np.log1p(-np.arange(256) / 255)
    codes = occupancy if occupancy.dtype == np.uint8 else uint8_from_unit(occupancy)
    return reference_crossings(origins, directions, codes, tau_of_code, origin, voxel_size, near, far, -math.log(transmittance))


def reference_cast_rays(m: OccupancyMap, origins, directions, near=None, far=None):
    origins, directions = np.asarray(origins, np.float64), np.asarray(directions, np.float64)
    directions = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    depth, index = reference_first_voxel_hits(origins, directions, m.label != FREE, m.origin, m.voxel_size, near, far)
    lo, hi = m.bounds
    t_enter, t_exit = ray_box_distances(origins, directions, lo, hi)
    near_n, far_n = ray_limits(len(origins), near, far)
    label = np.where(np.minimum(t_exit, far_n) > np.maximum(t_enter, near_n), FREE, UNKNOWN).astype(np.int16)
    hit = index[:, 0] >= 0
    label[hit] = m.label[tuple(index[hit].T)]
    return depth, label, index


# ---------------------------------------------------------------------------- rays for the checks


def assert_same(got, want):
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)


def random_rays(rng, n, lo, hi):
    """Rays from inside and around the box [lo, hi], mostly towards it, with a share of the
    extremes: directions along one or two axes, origins on voxel faces, edges and corners."""
    extent = hi - lo
    origins = rng.uniform(lo - extent, hi + extent, (n, 3))
    origins[: n // 3] = rng.uniform(lo, hi, (n // 3, 3))  # a third start inside
    directions = rng.uniform(lo, hi, (n, 3)) - origins
    directions[n // 3 : n // 2] = rng.normal(size=(n // 2 - n // 3, 3))  # any way
    axes = np.eye(3)[rng.integers(0, 3, n)] * rng.choice([-1.0, 1.0], (n, 1))
    parallel = rng.random(n) < 0.15
    directions[parallel] = axes[parallel]  # along one axis
    flat = rng.random(n) < 0.1
    directions[flat, rng.integers(0, 3, n)[flat]] = 0.0  # along a plane
    directions[np.all(directions == 0, axis=1)] = [1.0, 0.0, 0.0]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins, directions


def snap_to_faces(rng, origins, lo, voxel, fraction=0.3):
    """Move a share of the origins' coordinates exactly onto voxel faces (grid planes)."""
    snapped = origins.copy()
    mask = rng.random(origins.shape) < fraction
    snapped[mask] = (lo + np.round((origins - lo) / voxel) * voxel)[mask]
    return snapped


def random_limits(rng, n):
    near = rng.uniform(0.0, 1.0, n)
    near[rng.random(n) < 0.2] = np.nan  # unknown: 0
    near[rng.random(n) < 0.05] = -1.0  # clipped to 0
    far = np.where(rng.random(n) < 0.4, rng.uniform(0.0, 3.0, n), np.inf)
    far[rng.random(n) < 0.05] = np.nan  # unknown: inf
    return near, far


# ---------------------------------------------------------------------------- the checks


@pytest.mark.parametrize("shape,fraction,seed", [((10, 10, 10), 0.05, 0), ((23, 9, 14), 0.01, 1), ((6, 7, 5), 0.4, 2), ((40, 40, 40), 0.003, 3)])
def test_first_voxel_hits_match_the_numpy_walk_bit_for_bit(shape, fraction, seed):
    rng = np.random.default_rng(seed)
    stop = rng.random(shape) < fraction
    origin, voxel = np.array([0.3, -1.2, 0.05]), 0.1
    lo = origin - voxel / 2
    hi = lo + voxel * np.array(shape)
    origins, directions = random_rays(rng, 3000, lo, hi)
    origins = snap_to_faces(rng, origins, lo, voxel)
    near, far = random_limits(rng, len(origins))
    for limits in ((None, None), (near, far), (0.2, 1.5)):
        got = first_voxel_hits(origins, directions, stop, origin, voxel, *limits)
        assert_same(got, reference_first_voxel_hits(origins, directions, stop, origin, voxel, *limits))
        if limits[0] is None:
            assert np.isfinite(got[0]).sum() > 50 and np.isinf(got[0]).sum() > 50


@pytest.mark.parametrize("shape,fraction,seed", [((10, 10, 10), 0.3, 4), ((17, 12, 9), 0.03, 5)])
def test_transmittance_crossings_match_the_numpy_walk_bit_for_bit(shape, fraction, seed):
    rng = np.random.default_rng(seed)
    opacity = np.where(rng.random(shape) < fraction, rng.uniform(0.0, 1.0, shape), 0.0)
    opacity[rng.random(shape) < fraction / 10] = 1.0  # some opaque voxels
    origin, voxel = np.array([-2.0, 0.5, 1.0]), 0.25
    lo = origin - voxel / 2
    hi = lo + voxel * np.array(shape)
    origins, directions = random_rays(rng, 2000, lo, hi)
    origins = snap_to_faces(rng, origins, lo, voxel)
    near, far = random_limits(rng, len(origins))
    for transmittance in (0.5, 0.1, 0.9):
        got = transmittance_crossings(origins, directions, opacity, origin, voxel, near, far, transmittance)
        assert_same(got, reference_transmittance_crossings(origins, directions, opacity, origin, voxel, near, far, transmittance))
        assert np.isfinite(got[0]).sum() > 20
    codes = uint8_from_unit(opacity)
    assert_same(transmittance_crossings(origins, directions, codes, origin, voxel), reference_transmittance_crossings(origins, directions, codes, origin, voxel))


def test_extremes_match_the_numpy_walk():
    """Rays along the axes from voxel faces, edges and corners (ties between faces), rays that start
    inside a stop voxel, rays that miss, near / far at the box and at faces, empty grids, grids of
    one voxel or one voxel thick, a grid with nothing but stop voxels."""
    rng = np.random.default_rng(6)
    origin, voxel = np.zeros(3), 1.0
    stop = rng.random((8, 8, 8)) < 0.1
    stop[4, 4, 4] = True
    lo = origin - voxel / 2
    # along each axis, both ways, from every voxel corner / face centre / edge of a slice
    starts = np.stack(np.meshgrid(*[np.arange(-1.0, 9.0, 0.5) - 0.5] * 2, indexing="ij"), -1).reshape(-1, 2)
    origins, directions = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            o = np.insert(starts, axis, -1.5 if sign > 0 else 8.5, axis=1)
            d = np.zeros_like(o)
            d[:, axis] = sign
            origins.append(o)
            directions.append(d)
    diagonal = np.full((50, 3), 1 / math.sqrt(3))  # exactly through voxel corners
    origins.append(lo + np.arange(50)[:, None] * 0.25 - 3.0)
    directions.append(diagonal)
    origins, directions = np.concatenate(origins), np.concatenate(directions)
    for near, far in ((None, None), (2.0, None), (None, 2.0), (1.5, 1.5), (3.0, 2.0), (0.0, 0.0), (np.inf, np.nan)):
        assert_same(
            first_voxel_hits(origins, directions, stop, origin, voxel, near, far),
            reference_first_voxel_hits(origins, directions, stop, origin, voxel, near, far),
        )
    # from inside stop voxels: the hit is at the first distance, in that voxel
    inside = np.argwhere(stop)
    o = inside + rng.uniform(-0.5, 0.5, inside.shape)
    d = rng.normal(size=o.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    depth, index = first_voxel_hits(o, d, stop, origin, voxel, near=0.0)
    assert_same((depth, index), reference_first_voxel_hits(o, d, stop, origin, voxel, 0.0))
    np.testing.assert_array_equal(depth, 0.0)
    np.testing.assert_array_equal(index, inside)
    # misses: pointing away, parallel outside a slab, limits before the box
    o = np.array([[-3.0, 2.0, 2.0], [-3.0, 9.0, 2.0], [-3.0, 2.0, 2.0], [20.0, 20.0, 20.0]])
    d = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 1.0]]) / np.array([[1.0], [1.0], [1.0], [math.sqrt(3)]])
    depth, index = first_voxel_hits(o, d, stop, origin, voxel, far=[np.inf, np.inf, 2.4, np.inf])
    assert np.all(np.isinf(depth)) and np.all(index == -1)
    # grids of one voxel, one voxel thick, empty, full and without any voxel
    grids = [np.ones((1, 1, 1), bool), np.zeros((1, 1, 1), bool), rng.random((1, 9, 1)) < 0.3, rng.random((7, 1, 5)) < 0.2,
             np.zeros((5, 6, 7), bool), np.ones((5, 6, 7), bool), np.zeros((0, 4, 4), bool), np.ones((3, 0, 2), bool)]
    for grid in grids:
        g_lo, g_hi = lo, lo + voxel * np.maximum(np.array(grid.shape), 1)
        o, d = random_rays(rng, 500, g_lo, g_hi)
        o = snap_to_faces(rng, o, lo, voxel, 0.5)
        got = first_voxel_hits(o, d, grid, origin, voxel)
        assert_same(got, reference_first_voxel_hits(o, d, grid, origin, voxel))
        if not grid.any():
            assert np.all(np.isinf(got[0]))
        fog = np.where(grid, 0.6, 0.0)
        assert_same(transmittance_crossings(o, d, fog, origin, voxel), reference_transmittance_crossings(o, d, fog, origin, voxel))


def test_given_leaps_and_long_leaps():
    """Leaps passed in (uint8 or int32) give the same answers as leaps computed per call; a grid long
    enough for leaps past 255 keeps them exact in int32."""
    rng = np.random.default_rng(8)
    stop = rng.random((12, 10, 9)) < 0.03
    leaps = leap_lengths(stop)
    assert leaps.dtype == np.uint8
    np.testing.assert_array_equal(leaps, reference_leap_lengths(stop))
    origin, voxel = np.array([1.0, 2.0, 3.0]), 0.5
    lo = origin - voxel / 2
    o, d = random_rays(rng, 1000, lo, lo + voxel * np.array(stop.shape))
    want = reference_first_voxel_hits(o, d, stop, origin, voxel)
    for given in (leaps, leaps.astype(np.int32), leaps.astype(np.int64)):
        assert_same(first_voxel_hits(o, d, stop, origin, voxel, leaps=given), want)
    long = np.zeros((2, 1, 700), bool)
    long[0, 0, 0] = True
    long_leaps = leap_lengths(long)
    assert long_leaps.dtype == np.int32 and long_leaps.max() == 698
    o = np.column_stack([np.full(200, 0.3), np.zeros(200), rng.uniform(-5.0, 710.0, 200)])
    d = np.tile([0.0, 0.0, -1.0], (200, 1))
    d[::3] = [0.6, 0.0, -0.8]
    got = first_voxel_hits(o, d, long, np.zeros(3), 1.0)
    assert_same(got, reference_first_voxel_hits(o, d, long, np.zeros(3), 1.0))
    assert np.isfinite(got[0]).sum() > 50


def test_many_rays_split_over_threads_match():
    """Enough rays for the batch to be split over threads: the same answers as the reference."""
    rng = np.random.default_rng(9)
    stop = rng.random((16, 16, 16)) < 0.02
    origin, voxel = np.zeros(3), 0.1
    lo = origin - voxel / 2
    o, d = random_rays(rng, 20_000, lo, lo + voxel * 16)
    assert_same(first_voxel_hits(o, d, stop, origin, voxel), reference_first_voxel_hits(o, d, stop, origin, voxel))


def test_cast_rays_match_the_reference_and_keep_their_cache():
    """OccupancyMap.cast_rays (cached leaps, the box test only for rays that hit nothing) answers
    as the reference did: depth, label and index, for rays of any length, with and without limits;
    a map without stop voxels answers FREE / UNKNOWN."""
    rng = np.random.default_rng(10)
    shape = (12, 9, 7)
    label = rng.choice(np.array([FREE, FREE, FREE, FREE, FREE, FREE, UNKNOWN, 0, 3], np.int16), size=shape)
    occupancy = np.where(label >= 0, 0.9, 0.1).astype(np.float32)
    occupancy[label == UNKNOWN] = 0.0
    m = OccupancyMap(label, occupancy, 0.2, (0.5, -1.0, 2.0), {0: "floor", 3: "chair"}, occupancy_delta=0.01)
    lo, hi = m.bounds
    o, d = random_rays(rng, 3000, lo, hi)
    d *= rng.uniform(0.1, 10.0, (len(d), 1))  # cast_rays normalises
    near, far = random_limits(rng, len(o))
    for limits in ((None, None), (near, far), (0.5, 1.0)):
        for _ in range(2):  # the second call reads the cached leaps
            q = m.cast_rays(o, d, *limits)
            assert_same((q.depth, q.label, q.index), reference_cast_rays(m, o, d, *limits))
    assert set(np.unique(q.label)) == {FREE, UNKNOWN, 0, 3}
    clear = OccupancyMap(np.full(shape, FREE, np.int16), np.zeros(shape, np.float32), 0.2, (0.5, -1.0, 2.0), {0: "floor"}, occupancy_delta=0.01)
    q = clear.cast_rays(o, d, near, far)
    assert_same((q.depth, q.label, q.index), reference_cast_rays(clear, o, d, near, far))
    assert np.all(np.isinf(q.depth)) and set(np.unique(q.label)) == {FREE, UNKNOWN}
