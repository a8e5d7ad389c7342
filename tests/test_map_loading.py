"""Loading a map reads only what every query needs: the attributes' quick schema check decides as
jsonschema does (jsonschema itself is imported only to name a problem), and the stored ESDF is read
on its first use."""

from __future__ import annotations

import copy
import itertools
import math
import shutil

import jsonschema
import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.maps import FREE, UNKNOWN, OccupancyMap, load_schema, validate_attributes
from scenelabel.maps.schema import quick_check


def small_map() -> OccupancyMap:
    rng = np.random.default_rng(0)
    label = rng.choice(np.array([FREE, FREE, UNKNOWN, 0, 3], np.int16), size=(6, 5, 4))
    occupancy = np.where(label >= 0, 0.8, 0.1).astype(np.float32)
    occupancy[label == UNKNOWN] = 0.0
    return OccupancyMap(label, occupancy, 0.25, (1.0, -2.0, 0.5), {0: "floor", 3: "chair"}, occupancy_delta=0.01,
                        class_colors={3: (200, 10, 10)}, unknown_rule="visibility")


ODD_VALUES = [None, True, False, 0, 1, -1, -2, 2, 3, 7, 40000, 0.0, 1.0, 2.0, 0.5, -0.25, math.nan, math.inf, -math.inf,
              "", "x", "metre", "ijk=xyz", "scenelabel.occupancy_map", [], [1.0, 2.0, 3.0], [1, 2], [1.0, "a", 3.0],
              [[1.0] * 4] * 4, {}, {"unknown": "occupied", "units": "metre"}, {"unknown": "free"}, [None] * 3]


def mutations(attrs: dict):
    """Attribute dicts near a valid one: each key removed or given each odd value, and the same
    one level down (the classes' entries, colours, the esdf object, T_world_from_grid's rows)."""
    for key in list(attrs):
        gone = dict(attrs)
        del gone[key]
        yield gone
        for value in ODD_VALUES:
            yield {**attrs, key: value}
    for i, field in itertools.product(range(len(attrs["classes"])), ("id", "name", "color", "extra")):
        for value in ODD_VALUES + ["__delete__", [255, 0, 0], [255, 0, 256], [255, 0], [1.0, 2.0, 3.0], [1.5, 2, 3]]:
            changed = copy.deepcopy(attrs)
            if value == "__delete__":
                changed["classes"][i].pop(field, None)
            else:
                changed["classes"][i][field] = value
            yield changed
    for field, value in itertools.product(("unknown", "units"), ODD_VALUES):
        yield {**attrs, "esdf": {**attrs["esdf"], field: value}}
    for row, value in itertools.product(range(4), ODD_VALUES):
        matrix = copy.deepcopy(attrs["T_world_from_grid"])
        matrix[row] = value
        yield {**attrs, "T_world_from_grid": matrix}
    yield {**attrs, "format_version": 1, "occupancy_encoding": None}  # version 1 needs fewer attributes
    yield {key: value for key, value in attrs.items() if key not in ("occupancy_encoding", "unknown_rule", "T_world_from_grid")} | {"format_version": 1}


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_quick_check_decides_as_jsonschema(tmp_path, zarr_format):
    """Over hundreds of attribute dicts around a written map's (root and level groups): where the
    quick check decides, it says what jsonschema says; it decides almost all of them, the valid
    ones included (so loading a valid map never imports jsonschema)."""
    import zarr

    path = small_map().to_zarr(tmp_path / "m.zarr", zarr_format=zarr_format, levels=2)
    group = zarr.open_group(str(path), mode="r")
    validator = jsonschema.Draft202012Validator(load_schema())
    decided = total = 0
    for attrs in (group.attrs.asdict(), group["levels/1"].attrs.asdict()):
        assert quick_check(attrs) is True
        for candidate in mutations(dict(attrs)):
            quick, valid = quick_check(candidate), validator.is_valid(candidate)
            assert quick is None or quick == valid, candidate
            decided += quick is not None
            total += 1
    assert total > 500 and decided >= 0.95 * total


def test_validate_attributes_names_problems_as_before():
    attrs = small_map().group_attributes(0, 1)
    validate_attributes(attrs)
    with pytest.raises(InputError, match="missing required attribute 'voxel_size'"):
        validate_attributes({k: v for k, v in attrs.items() if k != "voxel_size"})
    with pytest.raises(InputError, match="invalid attribute") as info:
        validate_attributes({**attrs, "voxel_size": -1.0})
    assert info.value.field == "voxel_size"
    with pytest.raises(InputError, match="unique"):
        validate_attributes({**attrs, "classes": attrs["classes"] + attrs["classes"][:1]})


def test_the_stored_esdf_is_read_on_first_use(tmp_path):
    """from_zarr leaves the esdf array unread: the first esdf() / distance() reads it (the same
    values as the map's own), later calls reuse it; a store whose array has gone since falls back
    to computing it from the labels."""
    m = small_map()
    path = m.to_zarr(tmp_path / "m.zarr")
    back = OccupancyMap.from_zarr(path)
    assert "_esdf" not in back.__dict__
    xyz = np.random.default_rng(1).uniform(*m.bounds, size=(100, 3))
    np.testing.assert_array_equal(back.distance(xyz), m.distance(xyz))
    first = back.esdf()
    assert back.esdf() is first and not first.flags.writeable
    np.testing.assert_array_equal(first, m.esdf())
    gone = OccupancyMap.from_zarr(path)
    shutil.rmtree(path / "esdf")
    np.testing.assert_array_equal(gone.esdf(), m.esdf())
