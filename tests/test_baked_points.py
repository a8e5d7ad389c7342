"""BakedField.query_points through the fused, prefetching kernel (scenelabel.render.lattice_kernels
.points_kernel) answers bit for bit as the kernel and numpy steps it replaced, kept here as the
reference (tests/test_baking.py checks both against naive float64 loops)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from scenelabel.maps import uint8_from_unit
from scenelabel.query.answers import PointQuery, inside_bounds, labels_from_answers, softmax64
from scenelabel.query.baked import BakedField
from scenelabel.render.lattice_kernels import blend_channels, blend_scalar, cell_weights, normalise_into, softmax_into

# ---------------------------------------------------------------------------- the reference
# (points_kernel and BakedField.query_points before the fused kernel, unchanged but for the names)


@njit(cache=True)
def reference_points_kernel(density, class_values, frame, points, scores, density_out, probs):
    ijk, w = np.empty(3, np.int64), np.empty(8)
    n_classes = class_values.shape[3]
    for n in range(points.shape[0]):
        if cell_weights(density.shape, frame, points[n, 0], points[n, 1], points[n, 2], ijk, w):
            density_out[n] = max(blend_scalar(density, ijk, w), 0.0)
            blend_channels(class_values, ijk, w, probs[n])
            if scores:
                softmax_into(probs[n], probs[n])
            else:
                normalise_into(probs[n], probs[n])
        else:
            density_out[n] = 0.0
            probs[n, :] = 1.0 / n_classes


def reference_query_points(baked: BakedField, xyz: np.ndarray) -> PointQuery:
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    n, n_classes = len(xyz), len(baked.class_ids)
    density, probs = np.empty(n), np.empty((n, n_classes))
    frame = np.append(baked.corner, 1.0 / baked.voxel_size)
    reference_points_kernel(baked.density, baked.class_values, frame, xyz, baked.scores, density, probs)
    inside = inside_bounds(xyz, baked.aabb)
    density[~inside] = 0.0
    probs[~inside] = 0.0
    occupancy = -np.expm1(-density * baked.occupancy_delta)
    label = labels_from_answers(baked.class_ids[probs.argmax(-1)], occupancy, inside)
    return PointQuery(density, occupancy, probs, baked.class_ids.copy(), label)


# ---------------------------------------------------------------------------- the checks


def random_baked(rng, shape, n_classes, scores, aabb_margin=0.0):
    density = (rng.exponential(30.0, shape) * (rng.uniform(size=shape) > 0.4)).astype(np.float32)
    logits = rng.normal(0, 3, (*shape, n_classes))
    class_values = logits.astype(np.float32) if scores else uint8_from_unit(softmax64(logits))
    if not scores:
        class_values[0, 0, 0] = 0  # a vertex whose probabilities sum to 0: the uniform law near it
    corner, spacing = np.array([-1.0, 0.5, 2.0]), 0.25
    hi = corner + spacing * (np.array(shape) - 1)
    aabb = np.stack([corner + aabb_margin, hi - aabb_margin])
    classes = {int(c): f"c{c}" for c in rng.choice(40, n_classes, replace=False)}
    return BakedField((density, class_values, corner, spacing), aabb, dict(sorted(classes.items())), (0.05, 0.1, scores))


def assert_same_answers(got: PointQuery, want: PointQuery):
    for name in ("density", "occupancy", "probs", "class_ids", "label"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize("scores", [False, True])
@pytest.mark.parametrize("shape,n_classes", [((9, 7, 8), 7), ((2, 2, 2), 1), ((3, 12, 2), 20)])
def test_query_points_match_the_reference_bit_for_bit(scores, shape, n_classes):
    """Points inside and outside the bounds, on vertices, faces and the far corner, in a box smaller
    than the lattice (inside the lattice, outside the bounds: UNKNOWN) and one larger (outside the
    lattice, inside the bounds: zero density, the uniform law); enough points for several threads."""
    rng = np.random.default_rng(len(shape) * n_classes + scores)
    for margin in (0.0, 0.1, -0.1):
        baked = random_baked(rng, shape, n_classes, scores, margin)
        lo, hi = baked.corner, baked.corner + baked.voxel_size * (np.array(shape) - 1)
        xyz = rng.uniform(lo - 0.3, hi + 0.3, (20_000, 3))
        vertices = lo + baked.voxel_size * np.stack([rng.integers(0, s, 200) for s in shape], -1)
        on_faces = xyz[:300].copy()
        on_faces[:, 0] = rng.choice([lo[0], hi[0]], 300)
        xyz = np.concatenate([xyz, vertices, on_faces, [lo, hi, baked.aabb[0], baked.aabb[1]]])
        got = baked.query_points(xyz)
        assert_same_answers(got, reference_query_points(baked, xyz))
        assert len(np.unique(got.label)) >= 2
    assert_same_answers(baked.query_points(xyz[:1]), reference_query_points(baked, xyz[:1]))
    empty = baked.query_points(np.zeros((0, 3)))
    assert empty.density.shape == (0,) and empty.probs.shape == (0, n_classes)
