"""Chunked map export (scenelabel.query.map_writer): the store equals the in-memory map's, in this
process and on a 2-worker Dask cluster; it validates, reads back, and a failed task leaves no
half map.

toy_build (tests/conftest.py): the toy scene built once per session with the quick preset.
"""

import subprocess
import sys

import numpy as np
import pytest
import zarr

import scenelabel
from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap, write_occupancy_map
from scenelabel.maps import iter_chunks, pool_block, unit_from_uint8, validate_attributes
from scenelabel.query import mapping

CROP = np.array([[-1.0, -1.3, -0.15], [1.0, 1.0, 0.3]])  # cuts the field: the floor's edges and the box tops lie outside


def assert_same_store(a, b):
    """Two zarr groups hold the same arrays (values, dtype, shape, chunks, fill value, attributes)
    and the same group attributes, at every depth. Returns the member names."""
    ga, gb = zarr.open_group(str(a), mode="r"), zarr.open_group(str(b), mode="r")
    assert ga.metadata.zarr_format == gb.metadata.zarr_format
    assert ga.attrs.asdict() == gb.attrs.asdict()
    ma, mb = dict(ga.members(max_depth=None)), dict(gb.members(max_depth=None))
    assert sorted(ma) == sorted(mb)
    for name, node in ma.items():
        other = mb[name]
        assert node.attrs.asdict() == other.attrs.asdict(), name
        if isinstance(node, zarr.Array):
            assert (node.shape, node.chunks, node.dtype, node.fill_value) == (
                other.shape, other.chunks, other.dtype, other.fill_value
            ), name
            np.testing.assert_array_equal(node[...], other[...], err_msg=name)
    return sorted(ma)


# ---------------------------------------------------------------------------- single process


@pytest.mark.parametrize(
    "zarr_format, bounds, chunks, levels, visibility, esdf",
    [
        (3, None, (16, 16, 16), 3, True, True),  # a multiple of the shape on no axis: (33, 33, 10)
        (2, CROP, (7, 9, 5), 4, True, True),  # bounds cut the field (occluders); level 3 pools 8 > chunk edge
        (3, None, (64, 64, 64), None, False, False),  # default chunks, default levels, bounds rule only, no ESDF
    ],
    ids=["v3-visibility", "v2-cropped-odd-chunks", "v3-no-visibility-no-esdf"],
)
def test_chunked_store_equals_the_in_memory_map(
    toy_build, tmp_path, zarr_format, bounds, chunks, levels, visibility, esdf
):
    field = toy_build.field
    in_memory = field.occupancy_map(0.1, bounds, visibility=visibility)
    expected = in_memory.to_zarr(
        tmp_path / "memory.zarr", zarr_format=zarr_format, chunks=chunks, levels=levels, esdf=esdf
    )
    path = write_occupancy_map(
        field, tmp_path / "chunked.zarr", 0.1, bounds=bounds, zarr_format=zarr_format, chunks=chunks,
        levels=levels, visibility=visibility, esdf=esdf,
    )
    assert path == (tmp_path / "chunked.zarr").absolute()
    names = assert_same_store(expected, path)  # the esdf arrays and attributes included
    n_levels = zarr.open_group(str(path), mode="r").attrs["n_levels"]
    assert n_levels == (levels or 2) and all(f"levels/{level}/probs" in names for level in range(1, n_levels))
    # the ESDF the writer computed from the labels it read back is the in-memory map's, level by level
    assert all((f"levels/{level}/esdf" in names) == esdf for level in range(1, n_levels)) and ("esdf" in names) == esdf
    if esdf:
        g = zarr.open_group(str(path), mode="r")
        for level in range(n_levels):
            stored = g["esdf" if level == 0 else f"levels/{level}/esdf"][...]
            np.testing.assert_array_equal(stored, in_memory.downsample(2**level).esdf(), err_msg=f"level {level}")
    # the cases mean something: a map with occupied, free and (with visibility) unobserved voxels
    label = zarr.open_group(str(path), mode="r")["label"][...]
    assert (label >= 0).any() and (label == FREE).any() and (label == UNKNOWN).any() == visibility
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chunked.zarr", "memory.zarr"]  # no temp folder left


def test_build_folder_source_and_replacing_a_map(toy_build, tmp_path):
    """A build folder (the field loaded from its checkpoint) gives the loaded field's store; an
    existing map at the path is replaced."""
    target = tmp_path / "map.zarr"
    OccupancyMap.from_zarr(toy_build.out_dir / "map.zarr").to_zarr(target)  # something to replace
    write_occupancy_map(toy_build.out_dir, target, 0.15, chunks=(8, 8, 8))
    write_occupancy_map(toy_build.field, tmp_path / "field.zarr", 0.15, chunks=(8, 8, 8))
    assert_same_store(target, tmp_path / "field.zarr")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["field.zarr", "map.zarr"]


@pytest.mark.parametrize("shape", [(13, 7, 9), (8, 8, 8), (1, 5, 17)])
@pytest.mark.parametrize("factor", [2, 4, 8])
def test_pooling_blocks_equals_downsample(shape, factor):
    """pool_block on blocks of the fine grid that start at multiples of the factor (the pyramid
    tasks) gives exactly OccupancyMap.downsample of the whole map, edges included."""
    rng = np.random.default_rng(sum(shape) * factor)
    label = rng.choice(np.array([UNKNOWN, FREE, FREE, 1, 3], np.int16), size=shape)
    occupancy = np.where(label >= 0, rng.uniform(0.5, 1.0, shape), np.where(label == FREE, rng.uniform(0, 0.5, shape), 0))
    probs = rng.dirichlet(np.ones(2), size=shape) * (label != UNKNOWN)[..., None]
    m = OccupancyMap(
        label, occupancy.astype(np.float32), 0.1, [0, 0, 0], {1: "a", 3: "b"}, 0.1, probs=probs, confidence=np.zeros(shape)
    )
    whole = m.downsample(factor)
    names = ("label", "occupancy", "probs", "confidence")
    out = {name: np.zeros_like(getattr(whole, name)) for name in names}
    # 2 coarse voxels per block edge: blocks end inside the grid and at its (odd) edge
    for coarse in iter_chunks(whole.shape, 2):
        fine = tuple(slice(s.start * factor, min(s.stop * factor, n)) for s, n in zip(coarse, shape))
        for name, block in zip(names, pool_block(m.label[fine], m.occupancy[fine], m.probs[fine], factor, m.class_ids)):
            out[name][coarse] = block
    for name in names:
        np.testing.assert_array_equal(out[name], getattr(whole, name), err_msg=name)


# ---------------------------------------------------------------------------- reading it back


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_store_validates_and_reads_back(toy_build, tmp_path, zarr_format):
    field = toy_build.field
    path = write_occupancy_map(field, tmp_path / "m.zarr", 0.15, zarr_format=zarr_format, chunks=(8, 8, 4), levels=2)
    expected = field.occupancy_map(0.15)

    g = zarr.open_group(str(path), mode="r")
    validate_attributes(g.attrs.asdict(), path=path)
    validate_attributes(g["levels/1"].attrs.asdict(), path=path / "levels" / "1")
    a = g.attrs
    assert a["format"] == "scenelabel.occupancy_map" and a["unknown_rule"] == "visibility" and a["n_levels"] == 2
    assert g["label"].shape == expected.shape and g["probs"].shape == (*expected.shape, 3)
    # a planner's read (docs/formats.md): the voxel of an occupied world point, with zarr + numpy only
    ijk = np.argwhere(expected.label >= 0)[0]
    p = np.array(a["origin"]) + a["voxel_size"] * ijk + 0.3 * a["voxel_size"]
    found = np.floor((p - np.array(a["origin"])) / a["voxel_size"] + 0.5).astype(int)
    assert found.tolist() == ijk.tolist()
    assert int(g["label"][tuple(found)]) == int(expected.label[tuple(ijk)]) >= 0
    np.testing.assert_allclose(unit_from_uint8(g["probs"][tuple(found)]).sum(), 1.0, atol=3 / 255)

    assert OccupancyMap.from_zarr(path) == expected
    assert OccupancyMap.from_zarr(path, level=1) == expected.downsample(2)
    # the stored ESDF (schema-checked above) gives a planner the in-memory map's distances
    assert g.attrs["esdf"] == {"unknown": "occupied", "units": a["units"]}
    xyz = np.random.default_rng(0).uniform(*expected.bounds, size=(100, 3))
    np.testing.assert_array_equal(OccupancyMap.from_zarr(path).distance(xyz), expected.distance(xyz))


# ---------------------------------------------------------------------------- failures


class _Broken(RuntimeError):
    pass


def test_failed_chunk_leaves_no_half_map(toy_build, tmp_path, monkeypatch):
    field = toy_build.field
    original = mapping.evaluate_map_block
    calls = {"n": 0}

    def flaky(field, origin, voxel_size, block):
        calls["n"] += 1
        if calls["n"] == 3:
            raise _Broken("evaluation failed")
        return original(field, origin, voxel_size, block)

    monkeypatch.setattr(mapping, "evaluate_map_block", flaky)
    with pytest.raises(_Broken):
        write_occupancy_map(field, tmp_path / "new.zarr", 0.15, chunks=(8, 8, 8))
    assert calls["n"] == 3 and list(tmp_path.iterdir()) == []  # nothing at the path, no temp folder

    previous = OccupancyMap.from_zarr(toy_build.out_dir / "map.zarr")
    previous.to_zarr(tmp_path / "old.zarr")
    calls["n"] = 0
    with pytest.raises(_Broken):
        write_occupancy_map(field, tmp_path / "old.zarr", 0.15, chunks=(8, 8, 8))
    assert OccupancyMap.from_zarr(tmp_path / "old.zarr") == previous  # the previous map is intact
    assert [p.name for p in tmp_path.iterdir()] == ["old.zarr"]


def test_bad_arguments(toy_build, tmp_path):
    field = toy_build.field
    with pytest.raises(InputError, match="client"):
        write_occupancy_map(field, tmp_path / "m.zarr", client=object())  # a loaded field stays in this process
    with pytest.raises(InputError, match="zarr_format"):
        write_occupancy_map(field, tmp_path / "m.zarr", zarr_format=4)
    with pytest.raises(InputError, match="levels"):
        write_occupancy_map(field, tmp_path / "m.zarr", 0.2, levels=0)
    with pytest.raises(InputError, match="voxel"):
        write_occupancy_map(field, tmp_path / "m.zarr", 1e-4)  # more voxels than MAX_EXPORT_VOXELS
    with pytest.raises(scenelabel.CheckpointError, match="no checkpoint"):
        write_occupancy_map(tmp_path, tmp_path / "m.zarr")
    assert list(tmp_path.iterdir()) == []


def test_a_task_refuses_a_rewritten_checkpoint(toy_build):
    """Every chunk of a map comes from one field: a task whose checkpoint changed since the
    export began fails rather than mixing two fields."""
    from scenelabel.query.map_writer import _checkpoint, _field

    now = _checkpoint(toy_build.out_dir)
    assert now.path.endswith("checkpoint.pt") and _field(now) is _field(now)  # loaded once, then cached
    with pytest.raises(scenelabel.CheckpointError, match="changed while the map was being written"):
        _field(now._replace(mtime_ns=now.mtime_ns - 1))


# ---------------------------------------------------------------------------- on a Dask cluster


@pytest.mark.slow
def test_two_worker_cluster_writes_the_single_process_map(toy_build, client, tmp_path):
    """Tasks on 2 worker processes (each loads the field from the checkpoint once) write the
    same store as the single-process loop; bounds cut the field, chunks do not divide the shape."""
    kwargs = {"bounds": CROP, "chunks": (16, 16, 3), "levels": 3}
    cluster_map = write_occupancy_map(toy_build.out_dir, tmp_path / "cluster.zarr", 0.07, client=client, **kwargs)
    local_map = write_occupancy_map(toy_build.out_dir, tmp_path / "local.zarr", 0.07, **kwargs)
    assert_same_store(cluster_map, local_map)
    assert (zarr.open_group(str(local_map), mode="r")["label"][...] == UNKNOWN).any()
    # both worker processes took part: each holds the field it loaded from the checkpoint
    cached = client.run(lambda: [key[0] for key in sys.modules["scenelabel.query.map_writer"]._FIELD_CACHE])
    checkpoint = str((toy_build.out_dir / "checkpoint.pt").resolve())
    assert len(cached) == 2 and all(paths == [checkpoint] for paths in cached.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cluster.zarr", "local.zarr"]


def _break_evaluation(broken_voxel_size):
    """On a worker: evaluating a map at ``broken_voxel_size`` raises (other sizes still work)."""
    from scenelabel.query import mapping

    original = mapping.evaluate_map_block

    def flaky(field, origin, voxel_size, block):
        if voxel_size == broken_voxel_size and block[0].start > 0:
            raise RuntimeError("worker evaluation failed")
        return original(field, origin, voxel_size, block)

    flaky.original = original
    mapping.evaluate_map_block = flaky


def _restore_evaluation():
    from scenelabel.query import mapping

    mapping.evaluate_map_block = getattr(mapping.evaluate_map_block, "original", mapping.evaluate_map_block)


@pytest.mark.slow
def test_failed_task_on_the_cluster_leaves_no_half_map(toy_build, client, tmp_path):
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers do not import this module
    try:
        client.run(_break_evaluation, 0.123)
        try:
            with pytest.raises(RuntimeError, match="worker evaluation failed"):
                write_occupancy_map(toy_build.out_dir, tmp_path / "m.zarr", 0.123, chunks=(8, 8, 8), client=client)
        finally:
            client.run(_restore_evaluation)
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert list(tmp_path.iterdir()) == []  # every task ended before the temp folder was removed


# ---------------------------------------------------------------------------- command line


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], check=False, capture_output=True, text=True, timeout=300
    )


@pytest.mark.slow
def test_cli_export_with_workers(toy_build, tmp_path):
    out = tmp_path / "m.zarr"
    proc = run_cli("export", toy_build.out_dir, out, "--voxel-size", "0.15", "--workers", "2", "--zarr-format", "2", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"wrote {out}") and "voxels of 0.15" in proc.stdout
    assert (out / ".zgroup").is_file()
    assert OccupancyMap.from_zarr(out) == toy_build.field.occupancy_map(0.15)


def test_cli_export_cluster_flags_errors(toy_build, tmp_path, capsys):
    from scenelabel.cli import main

    assert main(["export", str(toy_build.out_dir), str(tmp_path / "m.zarr"), "--workers", "0"]) == 2
    assert "error: --workers: must be at least 1" in capsys.readouterr().err
    assert main(["export", str(toy_build.out_dir), str(tmp_path / "p.ply"), "--format", "ply", "--workers", "2"]) == 2
    assert "--format zarr from a build folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:  # argparse: one or the other
        main(["export", str(toy_build.out_dir), str(tmp_path / "m.zarr"), "--workers", "2", "--scheduler", "tcp://x:1"])
    assert exit_info.value.code == 2 and "not allowed with" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
