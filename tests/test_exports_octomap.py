"""OctoMap export (.bt / .ot) on hand-made maps, read back with pyoctomap itself.

Every voxel is looked up at its world centre (``tree.search``): occupied where the map has a
class, free where it is FREE, no node where it is UNKNOWN; .ot nodes carry the class colour and
the log-odds of the voxel's occupancy (clipped to OctoMap's clamping range).
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pyoctomap as po
import pytest

from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap
from scenelabel.maps.exports import class_palette, read_octomap, write_octomap
from scenelabel.maps.exports.octomap import (
    FREE_MAX_LOG_ODDS,
    KEY_OFFSET,
    P_CLAMP_MAX,
    P_CLAMP_MIN,
    octomap_base_key,
    octomap_log_odds,
    octomap_shift,
)

VS = 0.1
ORIGIN = (1.05, 2.05, -0.45)  # voxel centres on OctoMap's cell centres (odd multiples of VS / 2)
CLASSES = {1: "floor", 3: "box", 5: "chair"}
COLORS = {1: (190, 170, 130), 3: (220, 40, 40)}  # chair has no colour: fallback palette


def logit(p):
    p = np.clip(np.asarray(p, np.float64), P_CLAMP_MIN, P_CLAMP_MAX)
    return np.log(p / (1 - p))


def make_map(label, occupancy=None, origin=ORIGIN, voxel_size=VS, **kwargs):
    label = np.asarray(label, np.int16)
    if occupancy is None:
        occupancy = np.where(label >= 0, 0.9, np.where(label == FREE, 0.1, 0.0))
    return OccupancyMap(
        label, np.asarray(occupancy, np.float32), voxel_size, origin, CLASSES, voxel_size, class_colors=COLORS, **kwargs
    )


def scene_label():
    """A floor layer, a box of class 3, a chair voxel, FREE air and an UNKNOWN corner."""
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:3] = 3
    label[6, 1, 1] = 5
    label[5:, 4:, 2:] = UNKNOWN
    return label


def centres(occ_map):
    """[N, 3] world centres and [N, 3] indices of every voxel, C order."""
    ijk = np.argwhere(np.ones(occ_map.shape, bool))
    return occ_map.origin + occ_map.voxel_size * ijk, ijk


def read_bt(path):
    tree = po.OcTree(0.1)
    assert tree.readBinary(str(path))
    return tree


def assert_states(tree, occ_map, offset=(0.0, 0.0, 0.0)):
    """Occupied / free / no node at every voxel centre (+ offset), as the map's label says."""
    xyz, ijk = centres(occ_map)
    for point, index in zip(xyz + np.asarray(offset), map(tuple, ijk)):
        node = tree.search(point)
        label = occ_map.label[index]
        if label == UNKNOWN:
            assert node is None, index
        else:
            assert node is not None, index
            assert tree.isNodeOccupied(node) == (label >= 0), (index, label)


# --------------------------------------------------------------------------------------------
# .bt


def test_bt_occupied_free_unknown_and_resolution(tmp_path):
    occ_map = make_map(scene_label())
    path = write_octomap(occ_map, tmp_path / "map.bt")
    assert path == tmp_path / "map.bt" and path.read_bytes().startswith(b"# Octomap OcTree binary file\n")
    tree = read_bt(path)
    assert tree.getResolution() == pytest.approx(VS, rel=1e-12)
    assert_states(tree, occ_map)
    # pruned: the FREE air collapses, so fewer leaves than known voxels
    assert tree.getNumLeafNodes() < int((occ_map.label != UNKNOWN).sum())
    # read_octomap gives the same tree
    assert read_octomap(path).getNumLeafNodes() == tree.getNumLeafNodes()


def test_bt_free_block_prunes_to_one_leaf(tmp_path):
    label = np.full((4, 4, 4), FREE, np.int16)  # keys 32778.. along x: blocks aligned to 2
    occ_map = make_map(label, origin=(0.05, 0.05, 0.05))
    tree = read_bt(write_octomap(occ_map, tmp_path / "free.bt"))
    assert tree.getNumLeafNodes() == 1  # the 4 x 4 x 4 block is one node of depth 14
    assert not tree.isNodeOccupied(tree.search(np.array([0.35, 0.35, 0.35])))


# --------------------------------------------------------------------------------------------
# .ot


def test_ot_colours_and_log_odds(tmp_path):
    label = scene_label()
    rng = np.random.default_rng(0)
    occupancy = np.where(label >= 0, rng.uniform(0.5, 1.0, label.shape), rng.uniform(0.0, 0.5, label.shape))
    occupancy[label == UNKNOWN] = 0.0
    occ_map = make_map(label, occupancy)
    path = write_octomap(occ_map, tmp_path / "map.ot")
    assert path.read_bytes().startswith(b"# Octomap OcTree file\n")
    tree = po.ColorOcTree(str(path))
    assert tree.getTreeType() == "ColorOcTree"
    assert tree.getResolution() == pytest.approx(VS, rel=1e-12)
    assert_states(tree, occ_map)
    palette = class_palette(CLASSES, COLORS)
    assert palette[5] != palette[3]
    xyz, ijk = centres(occ_map)
    for point, index in zip(xyz, map(tuple, ijk)):
        lab = occ_map.label[index]
        if lab == UNKNOWN:
            continue
        node = tree.search(point)
        expected = logit(occ_map.occupancy[index])
        expected = max(expected, 0.0) if lab >= 0 else min(expected, FREE_MAX_LOG_ODDS)
        assert node.getLogOdds() == pytest.approx(expected, abs=1e-5), index
        if lab >= 0:
            assert node.getColor() == palette[lab], index
        else:
            assert node.getColor() == (255, 255, 255)  # OctoMap's "no colour"


def test_ot_prunes_equal_leaves_but_never_blends_classes(tmp_path):
    # two aligned 2 x 2 x 2 blocks at one occupancy: one of a single class, one of two classes
    label = np.full((4, 2, 2), 1, np.int16)
    label[2:, :, :] = 3
    label[3, 1, 1] = 5
    occ_map = make_map(label, np.ones(label.shape), origin=(0.05, 0.05, 0.05))
    tree = po.ColorOcTree(str(write_octomap(occ_map, tmp_path / "blocks.ot")))
    assert tree.getNumLeafNodes() == 1 + 8  # the floor block collapsed, the mixed one kept
    palette = class_palette(CLASSES, COLORS)
    xyz, ijk = centres(occ_map)
    for point, index in zip(xyz, map(tuple, ijk)):
        assert tree.search(point).getColor() == palette[occ_map.label[index]], index


def test_extremes_give_finite_log_odds_on_the_labels_side(tmp_path):
    label = np.array([[[1, 1, FREE, FREE, 3, FREE]]], np.int16)
    occupancy = np.array([[[1.0, 0.3, 0.0, 0.7, 0.5, 0.49]]], np.float32)
    occ_map = make_map(label, occupancy, occupancy_threshold=0.3)
    values = octomap_log_odds(occ_map.occupancy.ravel(), label.ravel())
    assert np.all(np.isfinite(values)) and values.dtype == np.float32
    np.testing.assert_allclose(
        values, [logit(P_CLAMP_MAX), 0.0, logit(P_CLAMP_MIN), FREE_MAX_LOG_ODDS, 0.0, logit(0.49)], rtol=1e-6, atol=1e-7
    )
    tree = po.ColorOcTree(str(write_octomap(occ_map, tmp_path / "extremes.ot")))
    xyz, _ = centres(occ_map)
    read = [tree.search(p).getLogOdds() for p in xyz]
    np.testing.assert_allclose(read, values, rtol=1e-6, atol=1e-7)
    assert_states(tree, occ_map)  # the 0.3 class voxel is occupied, the 0.7 FREE one free
    assert_states(read_bt(write_octomap(occ_map, tmp_path / "extremes.bt")), occ_map)


# --------------------------------------------------------------------------------------------
# Alignment and key range


def test_non_aligned_origin_maps_one_voxel_to_one_leaf(tmp_path):
    # a checkerboard of occupied and FREE: no two siblings are equal, so nothing prunes
    shape = (5, 4, 3)
    label = np.where(np.indices(shape).sum(0) % 2 == 0, 1, FREE).astype(np.int16)
    origin = (0.013, -0.027, 0.4)
    occ_map = make_map(label, origin=origin)
    shift = octomap_shift(occ_map)
    assert np.all(np.abs(shift) <= VS / 2 + 1e-12)
    for suffix in ("bt", "ot"):
        path = write_octomap(occ_map, tmp_path / f"map.{suffix}")
        tree = read_bt(path) if suffix == "bt" else po.ColorOcTree(str(path))
        assert tree.getNumLeafNodes() == label.size
        xyz, ijk = centres(occ_map)
        keys = {tuple(tree.coordToKey(p)) for p in xyz}
        assert len(keys) == label.size  # distinct cells
        base = octomap_base_key(occ_map)
        for point, index in zip(xyz, ijk):
            key = tree.coordToKey(point)
            assert tuple(key) == tuple(base + index)
            np.testing.assert_allclose(tree.keyToCoord(key), point + shift, atol=1e-5)  # float32 coordinates
        assert_states(tree, occ_map)


def test_grid_aligned_origin_shifts_by_half_a_voxel(tmp_path):
    occ_map = make_map(scene_label(), origin=(0.0, 0.3, -1.2))  # voxel centres on cell boundaries
    np.testing.assert_allclose(octomap_shift(occ_map), [VS / 2] * 3, atol=1e-9)
    np.testing.assert_array_equal(octomap_base_key(occ_map), [KEY_OFFSET, KEY_OFFSET + 3, KEY_OFFSET - 12])
    tree = read_bt(write_octomap(occ_map, tmp_path / "aligned.bt"))
    assert_states(tree, occ_map, offset=[VS / 4] * 3)  # inside the leaf, away from its boundary
    assert b"leaf centre = voxel centre + (0.05 0.05 0.05)" in (tmp_path / "aligned.bt").read_bytes()


def test_map_at_the_edge_of_the_key_range_fits(tmp_path):
    origin = (-KEY_OFFSET * VS + VS / 2, 0.05, (KEY_OFFSET - 2) * VS + VS / 2)  # keys 0.. and ..65535
    occ_map = make_map(np.ones((3, 2, 2), np.int16), origin=origin)
    np.testing.assert_array_equal(octomap_base_key(occ_map), [0, KEY_OFFSET, 2 * KEY_OFFSET - 2])
    tree = read_bt(write_octomap(occ_map, tmp_path / "edge.bt"))
    assert_states(tree, occ_map)


@pytest.mark.parametrize(
    "shape, origin, axis",
    [
        ((65537, 1, 1), (0.05, 0.05, 0.05), "x"),  # wider than 65536 voxels
        ((2, 2, 2), (0.05, 5000.0, 0.05), "y"),  # too far from the world origin
        ((2, 2, 3), (0, 0, 3276.65), "z"),  # keys 65534 to 65536: one past the last
    ],
)
def test_map_beyond_the_key_range_is_refused(tmp_path, shape, origin, axis):
    occ_map = make_map(np.full(shape, FREE, np.int16), origin=origin)
    with pytest.raises(InputError, match=f"does not fit OctoMap's key range: along {axis}") as err:
        write_octomap(occ_map, tmp_path / "big.bt")
    assert "65536 cells per axis" in str(err.value) and "coarser voxel size" in str(err.value)
    assert not (tmp_path / "big.bt").exists()


def test_names_and_empty_maps(tmp_path):
    occ_map = make_map(scene_label())
    with pytest.raises(InputError, match=r"\.bt .*\.ot"):
        write_octomap(occ_map, tmp_path / "map.ply")
    with pytest.raises(InputError, match="parent folder does not exist"):
        write_octomap(occ_map, tmp_path / "missing" / "map.bt")
    plain = po.OcTree(VS)  # a text .ot of a plain OcTree: read_octomap wants a ColorOcTree
    plain.updateNode(np.array([0.05, 0.05, 0.05]), True)
    (tmp_path / "plain.ot").write_bytes(plain.write())
    with pytest.raises(InputError, match="not a ColorOcTree file .*id OcTree"):
        read_octomap(tmp_path / "plain.ot")
    (tmp_path / "junk.bt").write_bytes(b"not an octree")
    with pytest.raises(InputError, match="not a readable OctoMap"):
        read_octomap(tmp_path / "junk.bt")
    unknown = make_map(np.full((3, 3, 3), UNKNOWN, np.int16))
    for suffix in ("bt", "ot"):
        tree = read_octomap(write_octomap(unknown, tmp_path / f"empty.{suffix}"))
        assert tree.getNumLeafNodes() == 0 and tree.getResolution() == pytest.approx(VS)


def test_docs_loading_snippet_runs(tmp_path, monkeypatch):
    """The pyoctomap snippet of docs/formats.md ("OctoMap", "Loading it") runs as written."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = doc.split("### OctoMap (", 1)[1].split("**Loading it.**", 1)[1]
    snippet = section.split("```python", 1)[1].split("```", 1)[0]
    occ_map = make_map(scene_label())
    write_octomap(occ_map, tmp_path / "map.bt")
    monkeypatch.chdir(tmp_path)
    for index, expected in (((2, 2, 1), True), ((5, 0, 3), False)):
        x, y, z = occ_map.origin + VS * np.array(index)
        namespace: dict = {"x": x, "y": y, "z": z}
        exec(compile(snippet, "docs/formats.md", "exec"), namespace)  # noqa: S102 (the docs snippet)
        assert namespace["occupied"] is expected, index


# --------------------------------------------------------------------------------------------
# Command line


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], check=False, capture_output=True, text=True, timeout=300
    )


def test_cli_export_octomap(tmp_path):
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:4] = 3
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    zarr_path = OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], CLASSES, 0.1).to_zarr(tmp_path / "box.zarr")
    proc = run_cli("export", zarr_path, tmp_path / "out.bt")  # the format from the name
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("wrote") and "60 occupied" in proc.stdout, proc.stdout
    assert read_bt(tmp_path / "out.bt").getNumLeafNodes() > 0
    proc = run_cli("export", zarr_path, tmp_path / "out.ot", "--format", "octomap")
    assert proc.returncode == 0, proc.stderr
    assert po.ColorOcTree(str(tmp_path / "out.ot")).getNumLeafNodes() > 0
    proc = run_cli("export", zarr_path, tmp_path / "out.ply", "--format", "octomap")
    assert proc.returncode == 2 and "--format octomap, but the name ends in .ply" in proc.stderr
    assert not (tmp_path / "out.ply").exists()
    proc = run_cli("export", zarr_path, tmp_path / "out", "--format", "octomap")
    assert proc.returncode == 2 and ".bt" in proc.stderr and ".ot" in proc.stderr
