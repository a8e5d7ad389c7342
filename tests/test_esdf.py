"""The map's Euclidean signed distance field: against brute force over voxel centres, its trilinear
queries and their gradient, and the extremes (no obstacle, no free space, tiny and huge voxels)."""

import itertools

import numpy as np
import pytest

from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap
from scenelabel.maps.esdf import distance_at, distance_gradient_at, signed_distance


def _brute_force(label, voxel_size, unknown):
    """Signed distance of every voxel centre to the nearest centre of the other kind, minus half a
    voxel, in float64 loops; the map's outside is one layer of obstacles when unknown="occupied"."""
    if unknown == "occupied":
        label = np.pad(label, 1, constant_values=UNKNOWN)
    obstacle = (label >= 0) | ((label == UNKNOWN) if unknown == "occupied" else False)
    cells = list(itertools.product(*map(range, label.shape)))
    out = np.zeros(label.shape)
    for c in cells:
        other = [d for d in cells if obstacle[d] != obstacle[c]]
        nearest = min(np.linalg.norm(np.subtract(c, d)) for d in other) * voxel_size
        out[c] = (-1 if obstacle[c] else 1) * (nearest - voxel_size / 2)
    return out[1:-1, 1:-1, 1:-1] if unknown == "occupied" else out


def _label(seed=0, shape=(7, 6, 5)):
    rng = np.random.default_rng(seed)
    return rng.choice([FREE, FREE, FREE, 3, UNKNOWN], size=shape).astype(np.int16)


@pytest.mark.parametrize("unknown", ["occupied", "free"])
@pytest.mark.parametrize("seed", [0, 1])
def test_signed_distance_matches_brute_force(unknown, seed):
    label = _label(seed)
    got = signed_distance(label, 0.1, unknown)
    np.testing.assert_allclose(got, _brute_force(label, 0.1, unknown), atol=1e-6)
    assert np.all(got[label >= 0] < 0) and np.all(got[label == FREE] > 0)


def _room_map(voxel_size=0.1):
    """A 2 x 1 x 1 box of FREE voxels with a floor of class 3 (layer k = 0)."""
    label = np.full((20, 10, 10), FREE, dtype=np.int16)
    label[:, :, 0] = 3
    occupancy = (label >= 0).astype(np.float32)
    return OccupancyMap(label, occupancy, voxel_size, np.zeros(3), {3: "floor"}, voxel_size)


def test_distance_above_a_floor_is_the_height_over_its_top_face():
    m = _room_map()
    xyz = np.array([[1.0, 0.45, 0.35], [1.0, 0.45, 0.52]])  # away from the walls (the map's outside)
    np.testing.assert_allclose(m.distance(xyz, unknown="free"), xyz[:, 2] - 0.05, atol=1e-6)
    np.testing.assert_allclose(m.distance_gradient(xyz, unknown="free"), [[0, 0, 1]] * 2, atol=1e-6)
    # with the map's outside as an obstacle, its top face (z = 0.95) is the nearest at z = 0.8
    assert m.distance(np.array([[1.0, 0.45, 0.8]]))[0] == pytest.approx(0.15, abs=1e-6)


def test_trilinear_queries_hit_voxel_centres_and_the_gradient_matches_finite_differences():
    label = _label(3, (9, 8, 7))
    origin, vs = np.array([0.2, -1.0, 0.5]), 0.05
    esdf = signed_distance(label, vs, "occupied")
    ijk = np.argwhere(np.ones(label.shape, bool))
    np.testing.assert_allclose(distance_at(esdf, origin, vs, origin + ijk * vs), esdf[tuple(ijk.T)], atol=1e-6)
    rng = np.random.default_rng(0)
    xyz = origin + rng.uniform(0.1, np.array(label.shape) - 1.1, size=(50, 3)) * vs
    h = 1e-6
    fd = np.stack([(distance_at(esdf, origin, vs, xyz + h * e) - distance_at(esdf, origin, vs, xyz - h * e)) / (2 * h) for e in np.eye(3)], -1)
    np.testing.assert_allclose(distance_gradient_at(esdf, origin, vs, xyz), fd, rtol=1e-4, atol=1e-4)
    outside = np.array([[-5.0, -5.0, -5.0]])  # clamped to the corner voxel; no slope outside
    assert distance_at(esdf, origin, vs, outside)[0] == pytest.approx(float(esdf[0, 0, 0]))
    np.testing.assert_array_equal(distance_gradient_at(esdf, origin, vs, outside), [[0.0, 0.0, 0.0]])


@pytest.mark.parametrize("voxel_size", [1e-6, 1.0, 1e6])
def test_extremes_stay_finite_or_infinite_by_design(voxel_size):
    free = np.full((4, 3, 2), FREE, dtype=np.int16)
    assert np.all(signed_distance(free, voxel_size, "free") == np.inf)
    assert np.all(distance_at(signed_distance(free, voxel_size, "free"), np.zeros(3), voxel_size, np.zeros((2, 3))) == np.inf)
    solid = np.full((4, 3, 2), 7, dtype=np.int16)
    assert np.all(signed_distance(solid, voxel_size, "occupied") == -np.inf)
    mixed = _label(5)
    esdf = signed_distance(mixed, voxel_size, "occupied")
    assert np.all(np.isfinite(esdf)) and np.abs(esdf).max() <= voxel_size * np.linalg.norm(mixed.shape)
    assert np.all(np.isfinite(distance_gradient_at(esdf, np.zeros(3), voxel_size, np.ones((3, 3)) * voxel_size)))


def test_bad_rule_and_points_are_refused():
    m = _room_map()
    with pytest.raises(InputError, match="unknown"):
        m.esdf(unknown="maybe")
    with pytest.raises(InputError, match="xyz|shape"):
        m.distance(np.zeros((4, 2)))
