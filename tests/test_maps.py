"""Tests of scenelabel.maps: OccupancyMap, lattice helpers, zarr I/O (v2 and v3), schema, atomicity."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
import zarr

from scenelabel import maps
from scenelabel.errors import InputError
from scenelabel.maps import (
    FREE,
    UNKNOWN,
    OccupancyMap,
    first_voxel_hits,
    index_from_world,
    iter_chunks,
    lattice,
    ray_box_distances,
    transmittance_crossings,
    uint8_from_unit,
    validate_attributes,
    voxel_centers,
    world_from_index,
)

# Hand-computable grid: voxel [i, j, k] has centre (1 + 0.5 i, -2 + 0.5 j, 0.25 + 0.5 k).
ORIGIN = (1.0, -2.0, 0.25)
VOXEL = 0.5
SHAPE = (4, 5, 6)
CLASSES = {0: "floor", 3: "chair", 7: "table"}


def make_map(**overrides) -> OccupancyMap:
    rng = np.random.default_rng(0)
    label = rng.choice(np.array([FREE, UNKNOWN, 0, 3, 7], np.int16), size=SHAPE).astype(np.int16)
    occupancy = rng.random(SHAPE, dtype=np.float32)
    occupancy[label == UNKNOWN] = 0.0
    label[1, 2, 3] = 7  # a known voxel for the arithmetic checks
    occupancy[1, 2, 3] = 0.875
    kwargs = dict(
        label=label,
        occupancy=occupancy,
        voxel_size=VOXEL,
        origin=ORIGIN,
        classes=CLASSES,
        occupancy_delta=0.01,
        class_colors={0: (10, 20, 30), 7: [255, 0, 128]},
        frame_id="map",
        occupancy_threshold=0.5,
        scale_source="input",
        units="metre",
    )
    kwargs.update(overrides)
    return OccupancyMap(**kwargs)


# ---------------------------------------------------------------------------- construction


def test_constants():
    assert FREE == -1 and UNKNOWN == -2


def test_post_init_normalises_and_validates():
    m = make_map()
    assert m.label.dtype == np.int16 and m.occupancy.dtype == np.float32
    assert m.origin.dtype == np.float64 and m.origin.shape == (3,)
    assert m.shape == SHAPE
    assert m.class_colors == {0: (10, 20, 30), 7: (255, 0, 128)}
    with pytest.raises(ValueError):
        m.label[0, 0, 0] = 3  # frozen arrays
    # an int64 label is accepted and cast
    m2 = make_map(label=m.label.astype(np.int64))
    assert m2.label.dtype == np.int16 and m2 == m


@pytest.mark.parametrize(
    "overrides, field",
    [
        ({"label": np.zeros((4, 5), np.int16)}, "label"),
        ({"label": np.zeros(SHAPE, np.float32)}, "label"),
        ({"label": np.full(SHAPE, 5, np.int16)}, "label"),  # id 5 not in classes
        ({"label": np.full(SHAPE, -3, np.int16)}, "label"),
        ({"occupancy": np.zeros((4, 5, 7), np.float32)}, "occupancy"),
        ({"occupancy": np.full(SHAPE, np.nan, np.float32)}, "occupancy"),
        ({"occupancy": np.full(SHAPE, 1.5, np.float32)}, "occupancy"),
        ({"voxel_size": 0.0}, "voxel_size"),
        ({"voxel_size": float("nan")}, "voxel_size"),
        ({"origin": (0.0, 1.0)}, "origin"),
        ({"occupancy_delta": -1.0}, "occupancy_delta"),
        ({"occupancy_threshold": 2.0}, "occupancy_threshold"),
        ({"classes": {-1: "x"}}, "classes"),
        ({"class_colors": {5: (1, 2, 3)}}, "class_colors"),
        ({"class_colors": {0: (1, 2, 300)}}, "class_colors"),
        ({"frame_id": ""}, "frame_id"),
    ],
)
def test_post_init_rejects(overrides, field):
    with pytest.raises(InputError) as info:
        make_map(**overrides)
    assert info.value.field == field
    assert field in str(info.value)


def test_unknown_voxels_must_have_zero_occupancy():
    label = np.full(SHAPE, UNKNOWN, np.int16)
    with pytest.raises(InputError, match="UNKNOWN"):
        make_map(label=label, occupancy=np.full(SHAPE, 0.3, np.float32))


def test_bounds_and_corner():
    m = make_map()
    lo, hi = m.bounds
    np.testing.assert_allclose(lo, [0.75, -2.25, 0.0])
    np.testing.assert_allclose(hi, [0.75 + 2.0, -2.25 + 2.5, 3.0])
    np.testing.assert_allclose(m.origin_corner, lo)


# ---------------------------------------------------------------------------- index <-> world


def test_index_world_known_points():
    m = make_map()
    np.testing.assert_allclose(m.world_from_index([[0, 0, 0], [1, 2, 3], [3, 4, 5]]),
                               [[1.0, -2.0, 0.25], [1.5, -1.0, 1.75], [2.5, 0.0, 2.75]])
    pts = np.array([
        [1.5, -1.0, 1.75],   # centre of [1, 2, 3]
        [1.7, -0.8, 1.95],   # inside [1, 2, 3], off-centre
        [1.74, -1.24, 1.51],  # near the min corner of [1, 2, 3]
        [0.75, -2.25, 0.0],  # min corner of the grid: voxel [0, 0, 0]
        [1.25, -2.0, 0.25],  # on the face between [0,0,0] and [1,0,0]: the higher index
    ])
    idx, inside = m.index_from_world(pts)
    np.testing.assert_array_equal(idx, [[1, 2, 3], [1, 2, 3], [1, 2, 3], [0, 0, 0], [1, 0, 0]])
    assert inside.all()
    assert idx.dtype == np.int64
    # inverse on every voxel centre
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in SHAPE), indexing="ij"), -1).reshape(-1, 3)
    back, inside = m.index_from_world(m.world_from_index(ijk))
    np.testing.assert_array_equal(back, ijk)
    assert inside.all()


def test_points_outside():
    m = make_map()
    lo, hi = m.bounds
    pts = np.array([
        lo - 1e-9,                 # just below the min corner
        hi,                        # the max corner is outside (half-open voxels)
        [1.5, -1.0, 100.0],
        [np.nan, 0.0, 0.0],
        [np.inf, 0.0, 0.0],
        [1e300, 0.0, 0.0],
    ])
    idx, inside = m.index_from_world(pts)
    assert not inside.any()
    np.testing.assert_array_equal(idx[3], [-1, -1, -1])
    assert np.all(m.label_at(pts) == UNKNOWN)
    assert np.all(m.occupancy_at(pts) == 0)


def test_label_at_and_occupancy_at():
    m = make_map()
    pts = np.array([[1.7, -0.8, 1.95], [1.0, -2.0, 0.25], [-5.0, 0.0, 0.0]])
    np.testing.assert_array_equal(m.label_at(pts), [7, m.label[0, 0, 0], UNKNOWN])
    np.testing.assert_array_equal(m.occupancy_at(pts), [0.875, m.occupancy[0, 0, 0], 0.0])
    assert m.label_at(pts).dtype == np.int16


def test_pure_functions_match_methods():
    m = make_map()
    pts = np.random.default_rng(1).uniform(-1, 4, size=(50, 3))
    a = index_from_world(pts, ORIGIN, VOXEL, SHAPE)
    b = m.index_from_world(pts)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_allclose(world_from_index(a[0], ORIGIN, VOXEL), m.world_from_index(a[0]))


# ---------------------------------------------------------------------------- lattice / chunks


@pytest.mark.parametrize(
    "lo, hi, vs",
    [
        ((0, 0, 0), (1, 1, 1), 0.1),
        ((-1.3, 2.0, 0.7), (2.9, 2.05, 0.7), 0.25),  # thin and degenerate axes
        ((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05), 1.0),  # box smaller than a voxel
        ((10, 20, 30), (13, 21, 30.5), 0.5),
    ],
)
def test_lattice_covers_box_with_centres_inside(lo, hi, vs):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    origin, shape = lattice(lo, hi, vs)
    assert all(isinstance(n, int) and n >= 1 for n in shape)
    cover_lo = origin - vs / 2
    cover_hi = origin + vs * (np.asarray(shape) - 1) + vs / 2
    tol = 1e-6 * vs
    assert np.all(cover_lo <= lo + tol) and np.all(cover_hi >= hi - tol)
    first, last = origin, origin + vs * (np.asarray(shape) - 1)
    assert np.all(first >= lo - 1e-12) and np.all(last <= hi + 1e-12)
    # not wasteful: one voxel fewer would not cover
    assert np.all((np.asarray(shape) - 1) * vs < np.maximum(hi - lo, 1e-300) + tol)


def test_lattice_exact_count_and_limits():
    origin, shape = lattice((0, 0, 0), (1, 2, 3), 0.1)
    assert shape == (10, 20, 30)
    np.testing.assert_allclose(origin, [0.05, 0.05, 0.05])
    with pytest.raises(InputError, match="voxel"):
        lattice((0, 0, 0), (10, 10, 10), 0.01, max_voxels=1_000_000)
    with pytest.raises(InputError):
        lattice((1, 0, 0), (0, 1, 1), 0.1)
    with pytest.raises(InputError):
        lattice((0, 0, 0), (1, 1, 1), 0.0)


def test_lattice_within_a_box_keeps_the_whole_lattices_voxels_that_meet_it():
    origin, shape = lattice((0, 0, 0), (1, 2, 3), 0.1)
    part_origin, part_shape = lattice((0, 0, 0), (1, 2, 3), 0.1, within=((0.25, 0.32, -5.0), (0.55, 0.33, 0.05)))
    # x: cells [0.2, 0.3) .. [0.5, 0.6) meet [0.25, 0.55]; y: [0.3, 0.4) alone; z: cut at the lattice's start
    assert part_shape == (4, 1, 1)
    np.testing.assert_allclose(part_origin, [0.25, 0.35, 0.05])
    offset = (part_origin - origin) / 0.1
    np.testing.assert_allclose(offset, np.round(offset), atol=1e-9)  # the same centres as the whole lattice's
    whole_origin, whole_shape = lattice((0, 0, 0), (1, 2, 3), 0.1, within=((-9, -9, -9), (9, 9, 9)))
    np.testing.assert_allclose(whole_origin, origin)
    assert whole_shape == shape
    assert lattice((0, 0, 0), (1, 2, 3), 0.1, within=((5, 5, 5), (6, 6, 6)))[1] == (1, 1, 1)  # beyond it: one voxel
    # the limit counts the block's voxels, not the whole lattice's
    lattice((0, 0, 0), (10, 10, 10), 0.01, max_voxels=1_000_000, within=((0, 0, 0), (0.5, 0.5, 0.5)))
    with pytest.raises(InputError, match="voxel"):
        lattice((0, 0, 0), (10, 10, 10), 0.01, max_voxels=1_000_000, within=((0, 0, 0), (2, 2, 2)))


@pytest.mark.parametrize("shape, chunk", [((5, 7, 3), 2), ((4, 4, 4), (4, 4, 4)), ((1, 9, 2), (3, 4, 5)), ((6, 1, 1), 64)])
def test_iter_chunks_covers_each_index_once(shape, chunk):
    count = np.zeros(shape, np.int64)
    chunks = (chunk,) * 3 if isinstance(chunk, int) else chunk
    for sl in iter_chunks(shape, chunk):
        assert all(s.stop - s.start <= c for s, c in zip(sl, chunks))
        for i, j, k in itertools.product(*(range(s.start, s.stop) for s in sl)):
            count[i, j, k] += 1
    assert np.all(count == 1)


def test_voxel_centers_blocks_match_grid():
    m = make_map()
    seen = np.zeros(SHAPE, np.int64)
    for sl, centres in voxel_centers(ORIGIN, VOXEL, SHAPE, chunk=(3, 2, 4)):
        block = tuple(s.stop - s.start for s in sl)
        assert centres.shape == (int(np.prod(block)), 3)
        idx, inside = m.index_from_world(centres)
        assert inside.all()
        # C order: reshaping the values fits grid[sl]
        expected = np.stack(np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"), -1)
        np.testing.assert_array_equal(idx.reshape(*block, 3), expected)
        seen[sl] += 1
    assert np.all(seen == 1)


# ---------------------------------------------------------------------------- zarr round trip


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_round_trip(tmp_path, zarr_format):
    m = make_map()
    out = m.to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format, chunks=(2, 3, 4))
    assert out == (tmp_path / "map.zarr").absolute()
    back = OccupancyMap.from_zarr(out)
    np.testing.assert_array_equal(back.label, m.label)
    np.testing.assert_array_equal(back.occupancy, m.occupancy)
    assert back.label.dtype == np.int16 and back.occupancy.dtype == np.float32
    assert back.attributes() == m.attributes()
    assert back.classes == m.classes and back.class_colors == m.class_colors
    assert back == m
    group = zarr.open_group(str(out), mode="r")
    assert group.metadata.zarr_format == zarr_format
    esdf_attrs = {"esdf": {"unknown": "occupied", "units": "metre"}}  # the stored ESDF's rule and unit
    assert group.attrs.asdict() == {
        **m.attributes(), "level": 0, "n_levels": 1, **esdf_attrs, **maps.ngff_multiscales([m], zarr_format)
    }
    for name in ("label", "occupancy", "esdf"):
        array = group[name]
        assert array.chunks == (2, 3, 4)
        if zarr_format == 3:
            assert tuple(array.metadata.dimension_names) == ("x", "y", "z")
        else:
            assert array.attrs["_ARRAY_DIMENSIONS"] == ["x", "y", "z"]
    # nothing left beside the map
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.zarr"]


def test_round_trip_without_colors(tmp_path):
    m = make_map(class_colors=None)
    back = OccupancyMap.from_zarr(m.to_zarr(tmp_path / "m.zarr"))
    assert back.class_colors is None and back == m


def test_overwrite_and_refusals(tmp_path):
    target = tmp_path / "map.zarr"
    make_map().to_zarr(target)
    second = make_map(frame_id="odom", occupancy_delta=0.02)
    second.to_zarr(target, zarr_format=2)  # replaces a v3 map by a v2 one
    assert OccupancyMap.from_zarr(target) == second
    assert not (target / "zarr.json").exists()  # the old store is gone, not merged
    with pytest.raises(InputError, match="already exists"):
        second.to_zarr(target, overwrite=False)
    # never deletes something that is not a zarr group
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.tex").write_text("years of work")
    with pytest.raises(InputError, match="not a zarr group"):
        second.to_zarr(precious)
    assert (precious / "thesis.tex").read_text() == "years of work"
    with pytest.raises(InputError):
        make_map().to_zarr(tmp_path / "m.zarr", zarr_format=4)


# ---------------------------------------------------------------------------- plain zarr reader


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_plain_zarr_reader(tmp_path, zarr_format):
    """What a planner does with zarr + numpy only (the snippet of docs/formats.md)."""
    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)

    g = zarr.open_group(str(path), mode="r")
    a = g.attrs
    assert a["format"] == "scenelabel.occupancy_map" and a["index_order"] == "ijk=xyz"
    assert a["voxel_size"] == 0.5 and a["origin"] == [1.0, -2.0, 0.25]
    assert a["origin_corner"] == [0.75, -2.25, 0.0]
    assert a["free_label"] == -1 and a["unknown_label"] == -2
    assert {c["id"]: c["name"] for c in a["classes"]} == CLASSES

    p = np.array([1.7, -0.8, 1.95])  # hand-computed: voxel [1, 2, 3], centre (1.5, -1.0, 1.75)
    ijk = np.floor((p - np.array(a["origin"])) / a["voxel_size"] + 0.5).astype(int)
    assert ijk.tolist() == [1, 2, 3]
    assert int(g["label"][tuple(ijk)]) == 7
    assert float(g["occupancy"][tuple(ijk)]) == 0.875
    # corner form gives the same voxel
    ijk_corner = np.floor((p - np.array(a["origin_corner"])) / a["voxel_size"]).astype(int)
    assert ijk_corner.tolist() == [1, 2, 3]
    # voxel -> world
    centre = np.array(a["origin"]) + a["voxel_size"] * np.array([1, 2, 3])
    np.testing.assert_allclose(centre, [1.5, -1.0, 1.75])


# ---------------------------------------------------------------------------- schema


def test_schema_is_valid_and_documented():
    import jsonschema

    schema = maps.load_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["additionalProperties"] is True
    # every attribute a map has is required (the newer ones from format_version 2 on)
    required_v2 = schema["allOf"][0]["then"]["required"]
    assert set(schema["required"]) | set(required_v2) == set(make_map().attributes())
    assert not set(schema["required"]) & set(required_v2)
    for name, prop in schema["properties"].items():
        assert prop.get("description"), f"{name} has no description"


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_written_attributes_validate(tmp_path, zarr_format):
    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    attrs = zarr.open_group(str(path), mode="r").attrs.asdict()
    validate_attributes(attrs)
    validate_attributes({**attrs, "some_future_key": {"x": 1}})  # forward compatible


def test_broken_attributes_fail():
    attrs = make_map().attributes()
    missing = {k: v for k, v in attrs.items() if k != "voxel_size"}
    with pytest.raises(InputError, match="voxel_size") as info:
        validate_attributes(missing, path="x.zarr")
    assert info.value.field == "voxel_size" and "x.zarr" in str(info.value)
    with pytest.raises(InputError, match="voxel_size"):
        validate_attributes({**attrs, "voxel_size": "0.5"})
    with pytest.raises(InputError, match="origin"):
        validate_attributes({**attrs, "origin": [1.0, 2.0]})
    with pytest.raises(InputError, match="free_label"):
        validate_attributes({**attrs, "free_label": 0})
    with pytest.raises(InputError, match="classes"):
        validate_attributes({**attrs, "classes": [{"id": "1", "name": "a"}]})
    with pytest.raises(InputError, match="unique"):
        validate_attributes({**attrs, "classes": [{"id": 1, "name": "a"}, {"id": 1, "name": "b"}]})


def _edit_attrs(path: Path, zarr_format: int, edit) -> None:
    g = zarr.open_group(str(path), mode="r+", zarr_format=zarr_format)
    attrs = g.attrs.asdict()
    edit(attrs)
    g.attrs.clear()
    g.attrs.update(attrs)


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_from_zarr_errors_name_path_and_attribute(tmp_path, zarr_format):
    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    _edit_attrs(path, zarr_format, lambda a: a.pop("occupancy_delta"))
    with pytest.raises(InputError) as info:
        OccupancyMap.from_zarr(path)
    assert str(path) in str(info.value) and "occupancy_delta" in str(info.value)

    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    _edit_attrs(path, zarr_format, lambda a: a.update(format="someone.else"))
    with pytest.raises(InputError, match="format"):
        OccupancyMap.from_zarr(path)

    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    _edit_attrs(path, zarr_format, lambda a: a.update(format_version=99))
    with pytest.raises(InputError, match="newer"):
        OccupancyMap.from_zarr(path)

    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    _edit_attrs(path, zarr_format, lambda a: a.update(origin_corner=[0.0, 0.0, 0.0]))
    with pytest.raises(InputError, match="origin_corner"):
        OccupancyMap.from_zarr(path)


def test_from_zarr_not_a_map(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        OccupancyMap.from_zarr(tmp_path / "nothing.zarr")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError) as info:
        OccupancyMap.from_zarr(tmp_path / "empty")
    assert "empty" in str(info.value)
    other = zarr.open_group(str(tmp_path / "other.zarr"), mode="w")
    other.attrs["hello"] = 1
    with pytest.raises(InputError, match="format"):
        OccupancyMap.from_zarr(tmp_path / "other.zarr")


# ---------------------------------------------------------------------------- atomic write


class _Crash(RuntimeError):
    pass


def _crash_on_second_array_write(monkeypatch):
    """Make zarr.Array.__setitem__ write the first array, then raise on the second."""
    original = zarr.Array.__setitem__
    calls = {"n": 0}

    def flaky(self, key, value):
        calls["n"] += 1
        if calls["n"] >= 2:
            raise _Crash("simulated crash while writing")
        return original(self, key, value)

    monkeypatch.setattr(zarr.Array, "__setitem__", flaky)
    return calls


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_crash_keeps_previous_map(tmp_path, monkeypatch, zarr_format):
    target = tmp_path / "map.zarr"
    previous = make_map()
    previous.to_zarr(target, zarr_format=zarr_format)

    newer = make_map(frame_id="newer", label=np.full(SHAPE, FREE, np.int16))
    with monkeypatch.context() as mp:
        calls = _crash_on_second_array_write(mp)
        with pytest.raises(_Crash):
            newer.to_zarr(target, zarr_format=zarr_format)
        assert calls["n"] == 2  # it did crash midway, after one array was written

    assert OccupancyMap.from_zarr(target) == previous
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.zarr"]  # temp folder cleaned up


def test_crash_without_cleanup_leaves_no_complete_looking_map(tmp_path, monkeypatch):
    """As if the process were killed: the cleanup never runs, the temp folder stays."""
    target = tmp_path / "map.zarr"
    previous = make_map()
    previous.to_zarr(target)
    with monkeypatch.context() as mp:
        _crash_on_second_array_write(mp)
        mp.setattr("scenelabel.maps.zarr_io._remove", lambda path: None)
        with pytest.raises(_Crash):
            make_map(frame_id="newer").to_zarr(target)

    leftovers = [p for p in tmp_path.iterdir() if p.name != "map.zarr"]
    assert leftovers and all(p.name.startswith(".map.zarr.tmp-") for p in leftovers)
    for p in leftovers:
        with pytest.raises(InputError, match="format"):
            OccupancyMap.from_zarr(p)
    assert OccupancyMap.from_zarr(target) == previous
    # the next write recovers: the stale temp folder of this pid is replaced, then renamed away
    make_map(frame_id="next").to_zarr(target)
    assert OccupancyMap.from_zarr(target).frame_id == "next"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.zarr"]


def test_crash_on_first_write_to_new_path(tmp_path, monkeypatch):
    target = tmp_path / "fresh.zarr"

    def boom(self, key, value):
        raise _Crash("disk full")

    monkeypatch.setattr(zarr.Array, "__setitem__", boom)
    with pytest.raises(_Crash):
        make_map().to_zarr(target)
    assert list(tmp_path.iterdir()) == []


def test_attributes_are_json():
    attrs = make_map().attributes()
    assert json.loads(json.dumps(attrs)) == attrs
    assert attrs["classes"] == [
        {"id": 0, "name": "floor", "color": [10, 20, 30]},
        {"id": 3, "name": "chair", "color": None},
        {"id": 7, "name": "table", "color": [255, 0, 128]},
    ]


def test_docs_planner_snippet_runs(tmp_path, monkeypatch):
    """The zarr-only snippet of docs/formats.md runs as written and finds the right voxel."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = doc.split("### Reading the map with zarr and numpy only", 1)[1]
    snippet = section.split("```python", 1)[1].split("```", 1)[0]
    assert "scenelabel" not in snippet
    make_map().to_zarr(tmp_path / "map.zarr")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(snippet, "docs/formats.md", "exec"), namespace)
    assert namespace["ijk"].tolist() == [1, 2, 3] and namespace["label"] == 7


# ---------------------------------------------------------------------------- probs, confidence


def random_probs(label: np.ndarray, n_classes: int = len(CLASSES), seed: int = 2) -> np.ndarray:
    """[*label.shape, C] float class distributions, 0 where UNKNOWN."""
    p = np.random.default_rng(seed).random(label.shape + (n_classes,)) ** 3
    p /= p.sum(-1, keepdims=True)
    p[label == UNKNOWN] = 0.0
    return p


def make_map_with_probs(**overrides) -> OccupancyMap:
    base = make_map()
    probs = random_probs(base.label)
    return make_map(probs=probs, confidence=maps.confidence_from_probs(probs), unknown_rule="visibility", **overrides)


def test_quantisation_round_trip_within_one_step():
    values = np.concatenate([np.random.default_rng(0).random(10_000), [0.0, 1.0, 0.5, 1 / 255, 254.5 / 255]])
    codes = maps.uint8_from_unit(values)
    assert codes.dtype == np.uint8
    back = maps.unit_from_uint8(codes)
    assert back.dtype == np.float32
    assert np.max(np.abs(back - values)) <= 0.5 / 255 + 1e-7  # within half a step, so within 1/255
    assert codes[-5:-3].tolist() == [0, 255]
    np.testing.assert_array_equal(maps.uint8_from_unit([-0.5, 2.0, np.nan]), [0, 255, 0])  # clipped


def test_confidence_one_hot_uniform_and_edge_cases():
    c = maps.confidence_from_probs
    np.testing.assert_allclose(c(np.eye(4)), 1.0)
    np.testing.assert_allclose(c(np.full((3, 5), 0.2)), 0.0, atol=1e-12)
    np.testing.assert_allclose(c([[0.5, 0.5, 0.0, 0.0]]), [1.0 - math.log(2) / math.log(4)])
    np.testing.assert_allclose(c([[2.0, 0.0]]), [1.0])  # rows are normalised first
    np.testing.assert_array_equal(c(np.zeros((2, 3))), [0.0, 0.0])  # UNKNOWN rows
    np.testing.assert_array_equal(c([[1.0], [0.3], [0.0]]), [1.0, 1.0, 0.0])  # C = 1
    assert c(np.zeros((2, 3, 4, 3))).shape == (2, 3, 4)


def test_probs_and_confidence_are_quantised_and_checked():
    m = make_map_with_probs()
    assert m.probs.dtype == np.uint8 and m.probs.shape == SHAPE + (3,)
    assert m.confidence.dtype == np.uint8 and m.confidence.shape == SHAPE
    assert np.all(m.probs[m.label == UNKNOWN] == 0) and np.all(m.confidence[m.label == UNKNOWN] == 0)
    np.testing.assert_array_equal(m.class_ids, [0, 3, 7])
    with pytest.raises(ValueError):
        m.probs[0, 0, 0, 0] = 1  # frozen
    # uint8 codes are taken as they are
    assert make_map(probs=m.probs, confidence=m.confidence, unknown_rule="visibility") == m
    bad_unknown = m.probs.copy()
    bad_unknown[tuple(np.argwhere(m.label == UNKNOWN)[0])] = 9
    for overrides, field in [
        ({"probs": np.zeros(SHAPE + (2,), np.uint8)}, "probs"),  # C differs from classes
        ({"probs": bad_unknown}, "probs"),
        ({"probs": np.full(SHAPE + (3,), 1.5)}, "probs"),
        ({"probs": np.zeros(SHAPE + (3,), np.int32)}, "probs"),
        ({"confidence": np.zeros((4, 5), np.uint8)}, "confidence"),
        ({"unknown_rule": "guess"}, "unknown_rule"),
    ]:
        with pytest.raises(InputError) as info:
            make_map(**overrides)
        assert info.value.field == field


# ---------------------------------------------------------------------------- pyramid


def grid_2x2x2(children: list[int], occupancy=None, probs=None, classes=None) -> OccupancyMap:
    """A 2x2x2 map whose 8 voxels are ``children`` (C order), to pool into one coarse voxel."""
    label = np.array(children, np.int16).reshape(2, 2, 2)
    occ = np.where(label >= 0, 0.9, np.where(label == FREE, 0.1, 0.0)) if occupancy is None else occupancy
    return OccupancyMap(
        label=label, occupancy=np.asarray(occ, np.float32).reshape(2, 2, 2), voxel_size=0.5, origin=(0.25, 0.25, 0.25),
        classes=classes or {3: "chair", 7: "table"}, occupancy_delta=0.5,
        probs=None if probs is None else np.asarray(probs).reshape(2, 2, 2, -1),
    )


F, U = FREE, UNKNOWN


@pytest.mark.parametrize(
    "children, expected",
    [
        ([F] * 8, F),                    # all FREE -> FREE
        ([U] * 8, U),                    # all UNKNOWN -> UNKNOWN
        ([F] * 7 + [U], U),              # a FREE / UNKNOWN mix is UNKNOWN (conservative)
        ([U] * 7 + [F], U),
        ([F] * 7 + [3], 3),              # one occupied child keeps the coarse voxel occupied
        ([U] * 7 + [7], 7),              # even among unknown ones
        ([F, U, F, U, 3, F, U, F], 3),
    ],
)
def test_pool_labels_rules(children, expected):
    coarse = grid_2x2x2(children).downsample(2)
    assert coarse.shape == (1, 1, 1)
    assert int(coarse.label[0, 0, 0]) == expected
    # occupancy is the children's max, and 0 where the coarse voxel is UNKNOWN
    want = 0.0 if expected == U else max(0.9 if c >= 0 else 0.1 if c == F else 0.0 for c in children)
    assert coarse.occupancy[0, 0, 0] == pytest.approx(want)


def test_thin_obstacle_survives_every_level():
    label = np.full((16, 16, 16), FREE, np.int16)
    label[5, :, 9] = 7  # a one-voxel-thick pole along y
    occupancy = np.where(label >= 0, 0.8, 0.05).astype(np.float32)
    m = OccupancyMap(label, occupancy, 0.05, (0, 0, 0), {7: "lamp"}, 0.05)
    for level, coarse in enumerate(m.pyramid(5)):
        assert coarse.shape == (16 >> level,) * 3
        assert coarse.voxel_size == pytest.approx(0.05 * 2**level)
        np.testing.assert_allclose(coarse.origin_corner, m.origin_corner)
        # the pole is still there: the coarse voxel containing its points is occupied by class 7
        pts = m.world_from_index(np.array([[5, j, 9] for j in range(16)]))
        assert np.all(coarse.label_at(pts) == 7), level
        assert (coarse.label == 7).sum() == (16 >> level)  # and nothing else became the pole
        assert np.all(coarse.occupancy[coarse.label == 7] == np.float32(0.8))
    assert m.pyramid(5)[4].label.tolist() == [[[7]]]


def test_pooled_class_is_argmax_of_summed_occupied_probs():
    # two occupied children: chair (0.9 / 0.1) and table (0.45 / 0.55): summed 1.35 / 0.65 -> chair.
    # A FREE child's probs (all table) do not count when any child is occupied.
    probs = np.zeros((8, 2))
    children = [3, 7, F, F, F, F, F, F]
    probs[0], probs[1] = [0.9, 0.1], [0.45, 0.55]
    probs[2:] = [0.0, 1.0]
    m = grid_2x2x2(children, occupancy=[0.6, 0.95, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1], probs=probs)
    coarse = m.downsample()
    assert int(coarse.label[0, 0, 0]) == 3  # although the table child is the denser one
    np.testing.assert_allclose(maps.unit_from_uint8(coarse.probs[0, 0, 0]), [0.675, 0.325], atol=1 / 255)
    expected_conf = maps.confidence_from_probs([0.675, 0.325])
    assert abs(int(coarse.confidence[0, 0, 0]) / 255 - expected_conf) <= 1 / 255
    # without probabilities: the densest occupied child decides
    assert int(grid_2x2x2(children, occupancy=[0.6, 0.95, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]).downsample().label[0, 0, 0]) == 7
    # all FREE: the mean of the children's distributions; UNKNOWN: zeros
    free = grid_2x2x2([F] * 8, probs=np.tile([0.25, 0.75], (8, 1))).downsample()
    np.testing.assert_allclose(maps.unit_from_uint8(free.probs[0, 0, 0]), [0.25, 0.75], atol=1 / 255)
    mixed = grid_2x2x2([F] * 7 + [U], probs=np.vstack([np.tile([0.25, 0.75], (7, 1)), [[0, 0]]])).downsample()
    assert mixed.probs[0, 0, 0].tolist() == [0, 0] and int(mixed.confidence[0, 0, 0]) == 0


def test_odd_shapes_pad_with_unknown():
    label = np.full((3, 2, 2), FREE, np.int16)
    m = OccupancyMap(label, np.zeros(label.shape, np.float32), 1.0, (0, 0, 0), {1: "a"}, 1.0)
    coarse = m.downsample(2)
    assert coarse.shape == (2, 1, 1)
    # the second coarse voxel has 4 FREE children and 4 beyond the grid: UNKNOWN, not FREE
    assert coarse.label[:, 0, 0].tolist() == [FREE, UNKNOWN]
    np.testing.assert_allclose(coarse.origin, [0.5, 0.5, 0.5])  # min corner kept at -0.5
    lone = label.copy()
    lone[2, 1, 1] = 1
    assert OccupancyMap(lone, (lone >= 0).astype(np.float32), 1.0, (0, 0, 0), {1: "a"}, 1.0).downsample().label[1, 0, 0] == 1


def test_downsample_factors_and_default_levels():
    m = make_map_with_probs()
    assert m.downsample(1) is m
    assert m.downsample(4).shape == (1, 2, 2)
    assert [lvl.shape for lvl in m.pyramid(3)] == [SHAPE, (2, 3, 3), (1, 2, 2)]
    assert m.pyramid(3)[2] == m.downsample(4)  # level L pools 2^L children per axis at once
    assert maps.default_levels(SHAPE) == 1
    assert maps.default_levels((124, 124, 54)) == 4  # 0.05 m room: 0.05, 0.1, 0.2, 0.4 m
    assert maps.default_levels((4000, 1, 1)) == maps.MAX_LEVELS
    for bad in (0, 2.0, True):
        with pytest.raises(InputError, match="factor"):
            m.downsample(bad)
    with pytest.raises(InputError, match="levels"):
        m.pyramid(0)


# ---------------------------------------------------------------------------- zarr: levels, probs, OME-NGFF


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_round_trip_with_probs_and_levels(tmp_path, zarr_format):
    m = make_map_with_probs()
    path = m.to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format, chunks=(2, 2, 2), levels=3)
    back = OccupancyMap.from_zarr(path)
    assert back == m and back.unknown_rule == "visibility"
    np.testing.assert_array_equal(back.probs, m.probs)
    np.testing.assert_array_equal(back.confidence, m.confidence)
    for level in (1, 2):
        assert OccupancyMap.from_zarr(path, level=level) == m.downsample(2**level)
        # a level's group is a complete map on its own
        assert OccupancyMap.from_zarr(path / "levels" / str(level)) == m.downsample(2**level)
    with pytest.raises(InputError, match="level") as info:
        OccupancyMap.from_zarr(path, level=3)
    assert info.value.field == "level"
    with pytest.raises(InputError, match="level"):
        OccupancyMap.from_zarr(path, level=-1)
    # level 0 keeps its v1 paths; the arrays carry dimension names and CF attributes
    group = zarr.open_group(str(path), mode="r")
    assert set(group.array_keys()) == {"label", "occupancy", "probs", "confidence", "esdf"}
    assert group["probs"].shape == SHAPE + (3,) and group["probs"].chunks == (2, 2, 2, 3)
    label_attrs = group["label"].attrs
    assert label_attrs["flag_values"] == [-2, -1, 0, 3, 7]
    assert label_attrs["flag_meanings"] == "unknown free floor chair table"
    assert group["probs"].attrs["class_ids"] == [0, 3, 7]
    assert group["probs"].attrs["scale_factor"] == pytest.approx(1 / 255)
    dims = ["x", "y", "z", "class"]
    if zarr_format == 3:
        assert list(group["probs"].metadata.dimension_names) == dims
    else:
        assert group["probs"].attrs["_ARRAY_DIMENSIONS"] == dims
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.zarr"]


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_ome_ngff_multiscales_values(tmp_path, zarr_format):
    m = make_map_with_probs()
    path = m.to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format, levels=3)
    attrs = zarr.open_group(str(path), mode="r").attrs.asdict()
    if zarr_format == 3:
        assert attrs["ome"]["version"] == "0.5" and "multiscales" not in attrs
        multiscales = attrs["ome"]["multiscales"]
    else:
        assert "ome" not in attrs
        multiscales = attrs["multiscales"]
        assert all(entry["version"] == "0.4" for entry in multiscales)
    assert [entry["name"] for entry in multiscales] == ["label", "occupancy", "confidence", "esdf"]
    group = zarr.open_group(str(path), mode="r")
    for entry in multiscales:
        assert entry["axes"] == [{"name": n, "type": "space", "unit": "meter"} for n in "xyz"]
        assert len(entry["datasets"]) == 3
        for level, dataset in enumerate(entry["datasets"]):
            scale, translation = dataset["coordinateTransformations"]
            assert scale["type"] == "scale" and translation["type"] == "translation"
            np.testing.assert_allclose(scale["scale"], [VOXEL * 2**level] * 3)
            # the centre of voxel [0, 0, 0] of that level: the min corner plus half a coarse voxel
            np.testing.assert_allclose(translation["translation"], m.origin_corner + VOXEL * 2**level / 2)
            array = group[dataset["path"]]
            assert array.shape == m.downsample(2**level).shape
            assert dataset["path"] == (entry["name"] if level == 0 else f"levels/{level}/{entry['name']}")
    # non-metric maps leave the unit out
    plain = make_map(units="input").to_zarr(tmp_path / "plain.zarr", zarr_format=zarr_format)
    plain_attrs = zarr.open_group(str(plain), mode="r").attrs.asdict()
    entries = plain_attrs["ome"]["multiscales"] if zarr_format == 3 else plain_attrs["multiscales"]
    assert all("unit" not in axis for axis in entries[0]["axes"])


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_written_maps_validate_against_schema(tmp_path, zarr_format):
    path = make_map_with_probs().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format, levels=2)
    group = zarr.open_group(str(path), mode="r")
    for attrs in (group.attrs.asdict(), group["levels/1"].attrs.asdict()):
        validate_attributes(attrs)
        assert attrs["format_version"] == maps.FORMAT_VERSION == 2
    assert group.attrs["n_levels"] == 2 and group.attrs["level"] == 0 and group["levels/1"].attrs["level"] == 1
    attrs = group.attrs.asdict()
    for name in ("occupancy_encoding", "unknown_rule", "T_world_from_grid"):
        with pytest.raises(InputError, match=name):
            validate_attributes({k: v for k, v in attrs.items() if k != name})
    with pytest.raises(InputError, match="unknown_rule"):
        validate_attributes({**attrs, "unknown_rule": "guess"})
    with pytest.raises(InputError, match="T_world_from_grid"):
        validate_attributes({**attrs, "T_world_from_grid": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})
    with pytest.raises(InputError, match="ome"):
        validate_attributes({**attrs, "ome": {"multiscales": []}})
    # a version-1 map needs none of the version-2 attributes
    v1 = {k: v for k, v in attrs.items() if k in V1_ATTRIBUTES}
    validate_attributes({**v1, "format_version": 1})


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_from_zarr_rejects_inconsistent_transform(tmp_path, zarr_format):
    path = make_map().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format)
    bad = np.eye(4).tolist()
    _edit_attrs(path, zarr_format, lambda a: a.update(T_world_from_grid=bad))
    with pytest.raises(InputError, match="T_world_from_grid"):
        OccupancyMap.from_zarr(path)


V1_ATTRIBUTES = (
    "format", "format_version", "scenelabel_version", "voxel_size", "origin", "origin_corner", "index_order",
    "units", "frame_id", "free_label", "unknown_label", "classes", "occupancy_threshold", "occupancy_delta",
    "scale_source",
)


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_reads_version_1_maps(tmp_path, zarr_format):
    """A map as scenelabel's format 1 wrote it: two arrays, the v1 attributes, no levels."""
    m = make_map()
    group = zarr.open_group(str(tmp_path / "old.zarr"), mode="w", zarr_format=zarr_format)
    for name, data, fill in (("label", m.label, UNKNOWN), ("occupancy", m.occupancy, 0.0)):
        group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=(2, 2, 2), fill_value=fill)[...] = data
    group.attrs.update({**{k: v for k, v in m.attributes().items() if k in V1_ATTRIBUTES}, "format_version": 1})
    back = OccupancyMap.from_zarr(tmp_path / "old.zarr")
    assert back == m and back.unknown_rule == "bounds" and back.probs is None and back.confidence is None
    with pytest.raises(InputError, match="level"):
        OccupancyMap.from_zarr(tmp_path / "old.zarr", level=1)


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_plain_zarr_reader_levels_transform_and_probs(tmp_path, zarr_format):
    """A planner with zarr + numpy only: T_world_from_grid, a coarse level, dequantised probs."""
    path = make_map_with_probs().to_zarr(tmp_path / "map.zarr", zarr_format=zarr_format, levels=2)

    g = zarr.open_group(str(path), mode="r")
    T = np.array(g.attrs["T_world_from_grid"])
    assert T.shape == (4, 4)
    centre = (T @ np.array([1, 2, 3, 1.0]))[:3]
    np.testing.assert_allclose(centre, [1.5, -1.0, 1.75])  # hand-computed centre of voxel [1, 2, 3]
    ijk = np.floor(np.linalg.solve(T, np.array([1.7, -0.8, 1.95, 1.0]))[:3] + 0.5).astype(int)
    assert ijk.tolist() == [1, 2, 3] and int(g["label"][tuple(ijk)]) == 7
    # class probabilities of that voxel, by class id
    probs = g["probs"][1, 2, 3] * g["probs"].attrs["scale_factor"]
    by_id = dict(zip(g["probs"].attrs["class_ids"], probs))
    assert set(by_id) == {0, 3, 7} and abs(sum(by_id.values()) - 1.0) < 3 / 255
    # level 1: its own transform
    level = g["levels/1"]
    T1 = np.array(level.attrs["T_world_from_grid"])
    np.testing.assert_allclose(T1[:3, :3], np.eye(3) * 2 * VOXEL)
    np.testing.assert_allclose(T1[:3, 3], np.array(g.attrs["origin_corner"]) + VOXEL)
    i1, j1, k1 = np.floor(np.linalg.solve(T1, np.array([1.7, -0.8, 1.95, 1.0]))[:3] + 0.5).astype(int)
    assert (i1, j1, k1) == (0, 1, 1)  # children [0..1, 2..3, 2..3]
    assert int(level["label"][i1, j1, k1]) >= 0  # occupied, since its child [1, 2, 3] is


# ---------------------------------------------------------------------------- rays through a grid

# A 10^3 grid of 0.1 voxels covering [0, 1]^3.
GRID_ORIGIN = np.array([0.05, 0.05, 0.05])
GRID_VOXEL = 0.1


def naive_first_hit(origin, direction, occupied, near, far, origin_=GRID_ORIGIN, voxel_=GRID_VOXEL):
    """One ray, every voxel: the slab test against each occupied voxel's box in plain Python; the
    ray enters a voxel when its interval there, clipped to [near, far], has positive length."""
    lo = origin_ - voxel_ / 2
    t_lo = max(0.0, near) if math.isfinite(near) else 0.0
    t_hi = far if math.isfinite(far) else math.inf
    best, best_ijk = math.inf, (-1, -1, -1)
    for ijk in zip(*np.nonzero(occupied)):
        t0, t1 = t_lo, t_hi
        for a in range(3):
            v_lo, v_hi = lo[a] + voxel_ * ijk[a], lo[a] + voxel_ * (ijk[a] + 1)
            if direction[a] == 0:
                if not v_lo <= origin[a] <= v_hi:
                    t0, t1 = math.inf, -math.inf
                continue
            ta, tb = (v_lo - origin[a]) / direction[a], (v_hi - origin[a]) / direction[a]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t1 > t0 and t0 < best:
            best, best_ijk = t0, tuple(int(x) for x in ijk)
    return best, best_ijk



@pytest.mark.parametrize("side,fraction", [(10, 0.05), (30, 0.002)])
def test_first_voxel_hits_matches_naive_loop(side, fraction):
    """Exact traversal: the same distance and voxel as the slab test against every stop voxel,
    also for rays that only clip a voxel's edge, rays parallel to a slab and rays from inside;
    on a sparse grid most of the way is leapt over."""
    rng = np.random.default_rng(5)
    occupied = rng.random((side,) * 3) < fraction
    origins = rng.uniform(-1.5, 2.5, (300, 3))
    origins[:15] = rng.uniform(0.0, 1.0, (15, 3))  # some start inside the grid
    directions = rng.uniform(0.0, 1.0, (300, 3)) - origins  # mostly towards the grid
    directions[20:40, 1] = 0.0  # some rays parallel to a slab
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    near = rng.uniform(0.0, 0.5, 300)
    near[:10] = np.nan  # unknown limits: 0 and inf
    far = np.where(rng.random(300) < 0.3, rng.uniform(0.5, 3.0, 300), np.inf)
    depth, index = first_voxel_hits(origins, directions, occupied, GRID_ORIGIN, GRID_VOXEL, near, far)
    slow = [naive_first_hit(o, d, occupied, n, f) for o, d, n, f in zip(origins, directions, near, far)]
    np.testing.assert_allclose(depth, [t for t, _ in slow], rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(index, [ijk for _, ijk in slow])
    assert np.isfinite(depth).sum() >= 20
    # starting inside a stop voxel: the hit is at the first distance, in that voxel
    inside = np.argwhere(occupied)[0]
    d0, i0 = first_voxel_hits((inside * GRID_VOXEL + GRID_ORIGIN)[None], [[0.0, 0.0, 1.0]], occupied, GRID_ORIGIN, GRID_VOXEL)
    assert d0[0] == 0.0 and tuple(i0[0]) == tuple(inside)
    with pytest.raises(InputError, match="directions"):
        first_voxel_hits(origins, directions[:3], occupied, GRID_ORIGIN, GRID_VOXEL)
    with pytest.raises(InputError, match="stop"):
        first_voxel_hits(origins, directions, occupied[0], GRID_ORIGIN, GRID_VOXEL)


def naive_transmittance_crossing(origin, direction, opacity, near, far, transmittance, origin_=GRID_ORIGIN, voxel_=GRID_VOXEL):
    """One ray in float64 plain Python: every voxel's interval by the slab test, sorted along the
    ray; optical depth -log(1 - q / 255) per voxel edge, summed over the crossed lengths until it
    reaches -log(transmittance)."""
    lo = origin_ - voxel_ / 2
    t_lo = max(0.0, near) if math.isfinite(near) else 0.0
    t_hi = far if math.isfinite(far) else math.inf
    pieces = []
    for ijk in zip(*np.nonzero(opacity)):
        t0, t1 = t_lo, t_hi
        for a in range(3):
            v_lo, v_hi = lo[a] + voxel_ * ijk[a], lo[a] + voxel_ * (ijk[a] + 1)
            if direction[a] == 0:
                if not v_lo <= origin[a] < v_hi:
                    t0, t1 = math.inf, -math.inf
                continue
            ta, tb = (v_lo - origin[a]) / direction[a], (v_hi - origin[a]) / direction[a]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t1 > t0:
            q = round(float(opacity[ijk]) * 255) / 255
            sigma = math.inf if q == 1.0 else -math.log1p(-q) / voxel_
            pieces.append((t0, t1, sigma, tuple(int(x) for x in ijk)))
    goal, tau = -math.log(transmittance), 0.0
    for t0, t1, sigma, ijk in sorted(pieces):
        if sigma == math.inf:
            return t0, ijk
        if tau + sigma * (t1 - t0) >= goal:
            return t0 + (goal - tau) / sigma, ijk
        tau += sigma * (t1 - t0)
    return math.inf, (-1, -1, -1)


@pytest.mark.parametrize("side,fraction", [(10, 0.3), (24, 0.02)])
def test_transmittance_crossings_match_naive_loop(side, fraction):
    """Fog of random opacities (some opaque voxels): the crossing of T = 0.5 (and of 0.1) is where
    the float64 per-voxel sum says, in the voxel it says; sparse grids are mostly leapt over."""
    rng = np.random.default_rng(7)
    opacity = np.where(rng.random((side,) * 3) < fraction, rng.uniform(0.0, 1.0, (side,) * 3), 0.0)
    opacity[rng.random((side,) * 3) < fraction / 10] = 1.0
    origins = rng.uniform(-1.5, 2.5, (200, 3))
    origins[:10] = rng.uniform(0.0, 1.0, (10, 3))
    directions = rng.uniform(0.0, 1.0, (200, 3)) - origins
    directions[20:30, 2] = 0.0
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    near = rng.uniform(0.0, 0.5, 200)
    far = np.where(rng.random(200) < 0.3, rng.uniform(0.5, 3.0, 200), np.inf)
    for transmittance in (0.5, 0.1):
        depth, index = transmittance_crossings(origins, directions, opacity, GRID_ORIGIN, GRID_VOXEL, near, far, transmittance)
        slow = [naive_transmittance_crossing(o, d, opacity, n, f, transmittance) for o, d, n, f in zip(origins, directions, near, far)]
        np.testing.assert_allclose(depth, [t for t, _ in slow], rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(index, [ijk for _, ijk in slow])
        assert 5 <= np.isfinite(depth).sum() < 200
    # uint8 codes give the same answer as the opacities they quantise
    codes = uint8_from_unit(opacity)
    np.testing.assert_array_equal(transmittance_crossings(origins, directions, codes, GRID_ORIGIN, GRID_VOXEL, near, far)[0],
                                  transmittance_crossings(origins, directions, opacity, GRID_ORIGIN, GRID_VOXEL, near, far)[0])


def test_transmittance_crossings_hand_built_and_extremes():
    """Uniform fog: T = 0.5 after log 2 / sigma; opaque voxels act as first_voxel_hits' stop
    voxels; nearly clear or empty grids are never crossed; densities near opaque stay finite."""
    fog = np.full((10, 10, 10), 0.2)  # sigma = -log(0.8) / 0.1 per unit
    o, d = np.array([[-1.0, 0.55, 0.55]]), np.array([[1.0, 0.0, 0.0]])
    depth, index = transmittance_crossings(o, d, fog, GRID_ORIGIN, GRID_VOXEL)
    sigma = -math.log1p(-round(0.2 * 255) / 255) / GRID_VOXEL
    assert depth[0] == pytest.approx(1.0 + math.log(2) / sigma, rel=1e-12)
    assert tuple(index[0]) == (int((depth[0] - 1.0) / GRID_VOXEL), 5, 5)
    rng = np.random.default_rng(2)
    stop = rng.random((10, 10, 10)) < 0.02
    origins = rng.uniform(-1.0, 2.0, (100, 3))
    directions = rng.uniform(0.0, 1.0, (100, 3)) - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for a, b in zip(transmittance_crossings(origins, directions, stop.astype(np.float32), GRID_ORIGIN, GRID_VOXEL),
                    first_voxel_hits(origins, directions, stop, GRID_ORIGIN, GRID_VOXEL)):
        np.testing.assert_array_equal(a, b)
    for clear in (np.zeros((10, 10, 10)), np.full((10, 10, 10), 1e-4)):  # code 0: nothing to cross
        assert np.all(np.isinf(transmittance_crossings(origins, directions, clear, GRID_ORIGIN, GRID_VOXEL)[0]))
    dense = np.full((10, 10, 10), 254 / 255)  # the densest finite code
    depth, _ = transmittance_crossings(o, d, dense, GRID_ORIGIN, GRID_VOXEL)
    assert np.isfinite(depth[0]) and 1.0 < depth[0] < 1.0 + GRID_VOXEL
    for bad in (0.0, 1.0, np.nan):
        with pytest.raises(InputError, match="transmittance"):
            transmittance_crossings(o, d, fog, GRID_ORIGIN, GRID_VOXEL, transmittance=bad)
    with pytest.raises(InputError, match="occupancy"):
        transmittance_crossings(o, d, fog[0], GRID_ORIGIN, GRID_VOXEL)


def test_first_voxel_hits_far_from_the_origin_and_with_tiny_voxels():
    """A grid 1e6 units away and 1e-6-unit voxels: the distances stay exact to float64 precision."""
    for offset, voxel in ((1e6, 0.5), (0.0, 1e-6)):
        stop = np.zeros((8, 8, 8), bool)
        stop[5, 3, 3] = True
        origin = np.full(3, offset)
        start = origin + voxel * np.array([-3.0, 3.2, 3.3])
        depth, index = first_voxel_hits(start[None], [[1.0, 0.0, 0.0]], stop, origin, voxel)
        assert tuple(index[0]) == (5, 3, 3)
        assert depth[0] == pytest.approx(7.5 * voxel, rel=1e-9)


def test_cast_rays_hand_built():
    """A wall of class 3 at i = 2, one UNKNOWN voxel, the rest free."""
    label = np.full((4, 5, 6), FREE, np.int16)
    label[2] = 3
    label[0, 4, 5] = UNKNOWN
    occupancy = np.where(label == 3, 0.9, 0.1).astype(np.float32)
    occupancy[label == UNKNOWN] = 0.0
    m = make_map(label=label, occupancy=occupancy, probs=None, confidence=None)
    lo, hi = m.bounds  # x from 0.75 to 2.75; the wall's face at x = 0.75 + 2 * 0.5 = 1.75
    origins = np.array([[0.0, -1.0, 1.1], [0.0, -1.0, 1.1], [0.0, -1.0, 1.1], [1.0, -2.0, 2.75], [0.0, 50.0, 1.0], [1.0, 0.4, 2.75]])
    directions = np.array([[2.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    q = m.cast_rays(origins, directions, far=[np.inf, np.inf, 1.5, np.inf, np.inf, np.inf])
    np.testing.assert_allclose(q.depth, [1.75, 1.75, np.inf, np.inf, np.inf, 0.15])
    np.testing.assert_array_equal(q.label, [3, 3, FREE, FREE, UNKNOWN, UNKNOWN])
    np.testing.assert_array_equal(q.index[:2], [[2, 2, 2], [2, 2, 2]])
    assert np.all(q.index[2:5] == -1) and tuple(q.index[5]) == (0, 4, 5)
    assert q.label.dtype == np.int16
    assert np.all(lo <= origins[3]) and np.all(origins[3] <= hi)
    with pytest.raises(InputError, match="non-zero"):
        m.cast_rays(origins[:1], [[0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match=r"\[N, 3\]"):
        m.cast_rays(origins, directions[:2])


def test_cast_rays_agree_with_label_at_along_the_ray():
    """On a random map: every voxel a ray passes before its depth is free, and the hit voxel's label
    is the answer (checked by sampling the ray finely with label_at)."""
    m = make_map()
    rng = np.random.default_rng(2)
    lo, hi = m.bounds
    origins = rng.uniform(lo - 1.0, hi + 1.0, (200, 3))
    directions = rng.normal(size=(200, 3))
    q = m.cast_rays(origins, directions)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    for o, d, depth, label in zip(origins, unit, q.depth, q.label):
        t_enter, t_exit = ray_box_distances(o[None], d[None], lo, hi)
        end = min(depth, t_exit[0])
        ts = np.linspace(max(t_enter[0], 0.0), end, 400)[1:-1]
        if ts.size and end > max(t_enter[0], 0.0):
            assert np.all(m.label_at(o + ts[:, None] * d) == FREE)
        if np.isfinite(depth):
            assert m.label_at((o + (depth + 1e-9) * d)[None])[0] == label != FREE


def test_ray_box_distances():
    origins = np.array([[-1.0, 0.5, 0.5], [0.5, 0.5, 0.5], [-1.0, 2.0, 0.5], [0.5, -1.0, 0.5]])
    directions = np.array([[2.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    t_enter, t_exit = ray_box_distances(origins, directions, [0, 0, 0], [1, 1, 1])
    np.testing.assert_allclose(t_enter[[0, 1, 3]], [0.5, -0.5, 1.0])  # in multiples of the direction
    np.testing.assert_allclose(t_exit[[0, 1, 3]], [1.0, 0.5, 2.0])
    assert t_exit[2] < t_enter[2]  # parallel to a slab, outside it: a miss
