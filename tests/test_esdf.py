"""The map's Euclidean signed distance field: against brute force over voxel centres, its trilinear
queries and their gradient, the extremes (no obstacle, no free space, tiny and huge voxels), and
the ``esdf`` arrays of the zarr store (every level's own, read back instead of recomputed, maps
without them, the schema, the zarr-only reading of docs/formats.md)."""

import itertools
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr

from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap
from scenelabel.maps import array_chunks, iter_chunks, validate_attributes
from scenelabel.maps import occupancy_map as occupancy_map_module
from scenelabel.maps.esdf import distance_at, distance_gradient_at, signed_distance, signed_distance_blocks


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


# ---------------------------------------------------------------------------- the stored ESDF (zarr)


def _map_with_unknown(shape=(13, 9, 7), seed=4):
    """A map with classes, FREE and UNKNOWN voxels (odd shape: its pyramid pads with UNKNOWN)."""
    label = _label(seed, shape)
    occupancy = (label >= 0).astype(np.float32)
    return OccupancyMap(label, occupancy, 0.1, [0.3, -0.2, 0.05], {3: "box"}, 0.1, units="metre")


def test_blocks_give_the_whole_grid_esdf():
    """signed_distance_blocks (the chunked writer's path) equals signed_distance, bit for bit."""
    label = _label(6, (11, 8, 9))
    for unknown in ("occupied", "free"):
        blocks = [(b, label[b]) for b in iter_chunks(label.shape, (4, 3, 5))]
        whole = signed_distance(label, 0.1, unknown)
        np.testing.assert_array_equal(signed_distance_blocks(blocks, label.shape, 0.1, unknown), whole)


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_zarr_stores_every_levels_own_esdf_and_reading_it_skips_the_transform(tmp_path, zarr_format, monkeypatch):
    m = _map_with_unknown()
    path = m.to_zarr(tmp_path / "m.zarr", zarr_format=zarr_format, chunks=(4, 4, 4), levels=3)
    g = zarr.open_group(str(path), mode="r")
    for level in range(3):
        group = g if level == 0 else g[f"levels/{level}"]
        level_map = m.downsample(2**level)
        array = group["esdf"]
        assert array.dtype == np.float32 and array.shape == level_map.shape
        assert array.chunks == array_chunks((4, 4, 4), level_map.shape)
        assert array.attrs["unknown"] == "occupied" and array.attrs["units"] == "metre"
        assert group.attrs["esdf"] == {"unknown": "occupied", "units": "metre"}
        validate_attributes(group.attrs.asdict())
        # each level's ESDF is its own map's (pooled labels are conservative), not a pooled ESDF
        np.testing.assert_array_equal(array[...], level_map.esdf())

    def no_transform(*args, **kwargs):
        raise AssertionError("the ESDF was recomputed")

    xyz = np.random.default_rng(0).uniform(*m.bounds, size=(200, 3))
    levels = [m.downsample(2**level) for level in range(3)]
    expected = [level_map.esdf() for level_map in levels], m.distance(xyz), m.distance_gradient(xyz)
    monkeypatch.setattr(occupancy_map_module, "signed_distance", no_transform)
    for level in range(3):
        back = OccupancyMap.from_zarr(path, level=level)
        assert back == levels[level]  # the ESDF is derived data: not part of equality
        np.testing.assert_array_equal(back.esdf(), expected[0][level])
        assert not back.esdf().flags.writeable
    back = OccupancyMap.from_zarr(path)
    np.testing.assert_array_equal(back.distance(xyz), expected[1])
    np.testing.assert_array_equal(back.distance_gradient(xyz), expected[2])
    with pytest.raises(AssertionError, match="recomputed"):  # only the stored rule is stored
        back.esdf(unknown="free")


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_maps_without_an_esdf_array_still_load_and_compute_it(tmp_path, zarr_format, monkeypatch):
    m = _map_with_unknown()
    path = m.to_zarr(tmp_path / "m.zarr", zarr_format=zarr_format, levels=2)
    for array in (path / "esdf", path / "levels" / "1" / "esdf"):  # as a map written before the ESDF was stored
        shutil.rmtree(array)
    calls = []
    original = occupancy_map_module.signed_distance
    monkeypatch.setattr(occupancy_map_module, "signed_distance", lambda *a: calls.append(a) or original(*a))
    back = OccupancyMap.from_zarr(path)
    assert back == m and not calls
    xyz = np.random.default_rng(1).uniform(*m.bounds, size=(50, 3))
    np.testing.assert_array_equal(back.distance(xyz), m.distance(xyz))
    assert len(calls) == 1  # computed on demand, once
    np.testing.assert_array_equal(OccupancyMap.from_zarr(path, level=1).esdf(), m.downsample(2).esdf())

    plain = m.to_zarr(tmp_path / "plain.zarr", zarr_format=zarr_format, levels=2, esdf=False)
    g = zarr.open_group(str(plain), mode="r")
    assert "esdf" not in g.array_keys() and "esdf" not in g["levels/1"].array_keys() and "esdf" not in g.attrs
    multiscales = g.attrs["ome"]["multiscales"] if zarr_format == 3 else g.attrs["multiscales"]
    assert [entry["name"] for entry in multiscales] == ["label", "occupancy"]
    assert OccupancyMap.from_zarr(plain) == m


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_a_stored_esdf_that_does_not_fit_the_labels_is_refused(tmp_path, zarr_format):
    m = _map_with_unknown()
    path = m.to_zarr(tmp_path / "m.zarr", zarr_format=zarr_format, levels=1)
    g = zarr.open_group(str(path), mode="r+")
    g["esdf"][...] = -g["esdf"][...]  # another map's field, say
    back = OccupancyMap.from_zarr(path)  # the ESDF is read (and checked) on its first use
    with pytest.raises(InputError, match="esdf") as info:
        back.distance(np.zeros((1, 3)))
    assert info.value.field == "esdf" and str(path) in str(info.value)
    g["esdf"][0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        OccupancyMap.from_zarr(path).esdf()
    # a rule this version does not know is ignored: the ESDF is computed instead
    g["esdf"].attrs["unknown"] = "some_future_rule"
    np.testing.assert_array_equal(OccupancyMap.from_zarr(path).esdf(), m.esdf())


def test_esdf_group_attribute_schema():
    attrs = _map_with_unknown().group_attributes(0, 1)
    assert attrs["esdf"] == {"unknown": "occupied", "units": "metre"}
    validate_attributes(attrs)
    for bad in ({"unknown": "maybe", "units": "metre"}, {"unknown": "occupied"}, "occupied"):
        with pytest.raises(InputError, match="esdf"):
            validate_attributes({**attrs, "esdf": bad})


def test_docs_esdf_snippet_reads_the_distance_with_zarr_alone(tmp_path, monkeypatch):
    """The zarr-only ESDF snippet of docs/formats.md runs as written and gives OccupancyMap.distance."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = doc.split("### Distance field (`esdf`)", 1)[1]
    snippet = section.split("```python", 1)[1].split("```", 1)[0]
    assert "scenelabel" not in snippet
    m = _map_with_unknown((20, 16, 12), seed=8)
    m.to_zarr(tmp_path / "map.zarr")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(snippet, "docs/formats.md", "exec"), namespace)
    p = namespace["p"]
    assert namespace["distance"] == pytest.approx(float(m.distance(p[None])[0]), abs=1e-6)
