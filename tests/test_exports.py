"""Exports on hand-made maps: point cloud, per-class meshes, floor plan rules, Nav2 files.

Files are read back with independent readers (open3d, Pillow, a PGM/YAML parse by hand) and
checked against voxel positions known from the map's origin and voxel size.
"""

import json

import numpy as np
import open3d as o3d
import pytest
from PIL import Image

from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap
from scenelabel.maps.exports import (
    class_palette,
    default_color,
    floor_plan,
    floor_plan_from_grid,
    height_band,
    image_from_plan,
    write_class_meshes,
    write_nav2,
    write_ply,
    write_point_cloud,
)

VS = 0.1
ORIGIN = (1.0, 2.0, -0.5)  # world centre of voxel [0, 0, 0]
CLASSES = {1: "floor", 3: "box", 5: "chair"}
COLORS = {1: (190, 170, 130), 3: (220, 40, 40)}  # chair has no colour: fallback palette


def make_map(label, occupancy=None, classes=CLASSES, colors=COLORS):
    label = np.asarray(label, np.int16)
    if occupancy is None:
        occupancy = np.where(label >= 0, 0.9, np.where(label == FREE, 0.1, 0.0))
    return OccupancyMap(label, occupancy.astype(np.float32), VS, ORIGIN, classes, VS, class_colors=colors)


def centre(i, j, k):
    return np.array(ORIGIN) + VS * np.array([i, j, k], float)


def box_on_floor(shape=(12, 10, 8), box=((2, 5), (3, 7), (1, 4))):
    """A floor layer (k = 0) and a box of class 3; everything else FREE."""
    label = np.full(shape, FREE, np.int16)
    label[:, :, 0] = 1
    (i0, i1), (j0, j1), (k0, k1) = box
    label[i0:i1, j0:j1, k0:k1] = 3
    return label


# --------------------------------------------------------------------------------------------
# Point cloud


def test_point_cloud_positions_colours_labels_read_back(tmp_path):
    label = np.full((4, 3, 2), FREE, np.int16)
    label[0, 0, 0] = 1
    label[3, 2, 1] = 3
    label[1, 2, 0] = 5
    label[2, 1, 1] = UNKNOWN
    occ_map = make_map(label)
    path = write_point_cloud(occ_map, tmp_path / "points.ply")

    pcd = o3d.t.io.read_point_cloud(str(path))
    xyz = pcd.point.positions.numpy()
    labels = pcd.point.label.numpy().ravel()
    assert len(xyz) == 3 and labels.dtype == np.int32
    by_label = {int(lab): (p, c) for lab, p, c in zip(labels, xyz, pcd.point.colors.numpy())}
    np.testing.assert_allclose(by_label[1][0], centre(0, 0, 0), atol=1e-12)
    np.testing.assert_allclose(by_label[3][0], centre(3, 2, 1), atol=1e-12)
    np.testing.assert_allclose(by_label[5][0], centre(1, 2, 0), atol=1e-12)
    assert tuple(by_label[3][1]) == COLORS[3]
    assert tuple(by_label[5][1]) == default_color(5)  # chair (id 5): no colour of its own
    np.testing.assert_allclose(pcd.point.occupancy.numpy().ravel(), 0.9, rtol=1e-6)
    # a plain (legacy) reader sees coloured points
    legacy = o3d.io.read_point_cloud(str(path))
    assert len(legacy.points) == 3 and legacy.has_colors()


def test_point_cloud_carries_each_voxels_confidence(tmp_path):
    label = np.full((3, 2, 2), FREE, np.int16)
    label[0, 0, 0], label[2, 1, 1] = 1, 3
    confidence = np.zeros(label.shape, np.uint8)
    confidence[0, 0, 0], confidence[2, 1, 1] = 255, 51  # 1.0 and 0.2
    occ_map = make_map(label)
    occ_map = OccupancyMap(
        occ_map.label, occ_map.occupancy, VS, ORIGIN, CLASSES, VS, class_colors=COLORS, confidence=confidence
    )
    pcd = o3d.t.io.read_point_cloud(str(write_point_cloud(occ_map, tmp_path / "points.ply")))
    by_label = dict(zip(pcd.point.label.numpy().ravel().tolist(), pcd.point.confidence.numpy().ravel().tolist()))
    assert by_label == pytest.approx({1: 1.0, 3: 0.2}, abs=1e-6)
    # a map without confidence writes no such property
    assert b"confidence" not in write_point_cloud(make_map(label), tmp_path / "plain.ply").read_bytes()[:400]


def test_point_cloud_of_an_empty_map_and_bad_suffix(tmp_path):
    occ_map = make_map(np.full((2, 2, 2), FREE))
    path = write_point_cloud(occ_map, tmp_path / "empty.ply")
    assert b"element vertex 0" in path.read_bytes()
    with pytest.raises(InputError, match=r"\.ply"):
        write_point_cloud(occ_map, tmp_path / "points.xyz")


def test_palette_prefers_class_colours():
    assert class_palette(CLASSES, COLORS) == {1: COLORS[1], 3: COLORS[3], 5: default_color(5)}


def test_write_ply_rejects_bad_faces(tmp_path):
    with pytest.raises(InputError, match="faces"):
        write_ply(tmp_path / "m.ply", {"x": np.zeros(3, np.float32)}, faces=np.array([[0, 1, 3]]))


# --------------------------------------------------------------------------------------------
# Meshes


def test_box_mesh_is_outward_and_matches_the_box_extent(tmp_path):
    box = ((2, 5), (3, 7), (1, 4))
    paths = write_class_meshes(make_map(box_on_floor(box=box)), tmp_path / "meshes")
    assert sorted(paths) == [1, 3]  # chair has no voxel: no file
    assert paths[3].name == "class_3_box.ply"

    # One surface for the whole map, split by class: the box stands on the floor, so its mesh is
    # open there (the contact lies inside the occupied volume); box and floor together are closed.
    mesh = o3d.io.read_triangle_mesh(str(paths[3]))
    assert not mesh.is_watertight() and mesh.is_orientable()
    both = mesh + o3d.io.read_triangle_mesh(str(paths[1]))
    both.merge_close_vertices(1e-9)
    assert both.is_watertight() and both.is_orientable()
    assert both.get_volume() > 0  # counter-clockwise seen from outside
    vertices = np.asarray(mesh.vertices)
    # the box's voxels cover centre ± VS / 2: its world extent
    lo = centre(box[0][0], box[1][0], box[2][0]) - VS / 2
    hi = centre(box[0][1] - 1, box[1][1] - 1, box[2][1] - 1) + VS / 2
    # top and bottom: exactly the voxels' faces; at its foot marching cubes cuts the concave edge
    # with the floor, and those triangles may go to the box: half a voxel out onto the floor at most
    np.testing.assert_allclose([vertices[:, 2].min(), vertices[:, 2].max()], [lo[2], hi[2]], atol=1e-9)
    assert np.all((vertices.min(0) <= lo + 1e-9) & (vertices.min(0) >= lo - VS / 2 - 1e-9))
    assert np.all((vertices.max(0) >= hi - 1e-9) & (vertices.max(0) <= hi + VS / 2 + 1e-9))
    above_foot = vertices[:, 2] > lo[2] + VS / 2
    np.testing.assert_allclose(vertices[above_foot].min(0)[:2], lo[:2], atol=1e-9)  # the sides: the faces
    np.testing.assert_allclose(vertices[above_foot].max(0)[:2], hi[:2], atol=1e-9)
    normals = np.asarray(mesh.vertex_normals)
    assert np.all(np.einsum("ij,ij->i", normals, vertices - (lo + hi) / 2) > 0)  # outward
    np.testing.assert_allclose(np.asarray(mesh.vertex_colors) * 255, np.tile(COLORS[3], (len(vertices), 1)), atol=1e-6)

    # per-vertex labels survive (open3d's tensor reader keeps custom vertex properties)
    labels = o3d.t.io.read_point_cloud(str(paths[3])).point.label.numpy().ravel()
    assert len(labels) == len(vertices) and np.all(labels == 3)
    assert np.all(o3d.t.io.read_point_cloud(str(paths[1])).point.label.numpy() == 1)


def test_mesh_closes_at_the_grid_border(tmp_path):
    label = np.full((3, 3, 3), FREE, np.int16)
    label[0:2, :, 0:2] = 3  # touches four faces of the grid
    paths = write_class_meshes(make_map(label), tmp_path)
    mesh = o3d.io.read_triangle_mesh(str(paths[3]))
    assert mesh.is_watertight()
    np.testing.assert_allclose(np.asarray(mesh.vertices).min(0), centre(0, 0, 0) - VS / 2, atol=1e-9)


# --------------------------------------------------------------------------------------------
# Floor plan


def test_floor_plan_rules_per_column():
    F, U = FREE, UNKNOWN
    columns = {
        (0, 0): [F, F, F],  # all free -> FREE
        (1, 0): [F, U, F],  # one unknown -> UNKNOWN (never free)
        (2, 0): [U, U, U],  # -> UNKNOWN
        (0, 1): [3, F, 1],  # two classes -> the highest: 1
        (1, 1): [U, 3, U],  # a class wins over unknown -> 3
        (2, 1): [5, F, F],  # -> 5
    }
    band = np.zeros((3, 2, 3), np.int16)
    for ij, column in columns.items():
        band[ij] = column
    plan = floor_plan_from_grid(band)
    assert plan.dtype == np.int16
    expected = {(0, 0): F, (1, 0): U, (2, 0): U, (0, 1): 1, (1, 1): 3, (2, 1): 5}
    assert {ij: int(plan[ij]) for ij in expected} == expected


@pytest.mark.parametrize("seed", range(5))
def test_floor_plan_never_reports_unknown_space_free(seed):
    rng = np.random.default_rng(seed)
    band = rng.choice(np.array([UNKNOWN, FREE, FREE, FREE, 1, 3], np.int16), size=(20, 20, 4), p=[0.1, 0.5, 0.2, 0.1, 0.05, 0.05])
    plan = floor_plan_from_grid(band)
    assert np.array_equal(plan == FREE, np.all(band == FREE, axis=2))
    assert np.array_equal(plan >= 0, np.any(band >= 0, axis=2))
    assert np.array_equal(plan == UNKNOWN, ~np.any(band >= 0, axis=2) & np.any(band == UNKNOWN, axis=2))


def test_height_band_defaults_floor_ceiling_and_overrides():
    label = np.full((6, 6, 12), FREE, np.int16)
    label[:, :, 0:2] = 1  # a two-layer floor slab
    label[0, 0, 6] = 1  # a stray "floor" voxel high up does not lift the floor
    label[:, :, 10:12] = 4  # ceiling
    occ_map = make_map(label, classes={1: "Floor", 4: "ceiling"}, colors=None)
    z = lambda k: ORIGIN[2] + VS * k  # centre z of layer k
    z_min, z_max = height_band(occ_map)
    assert z_min == pytest.approx(z(1) + VS / 2 + VS)  # top face of the floor + one voxel
    assert z_max == pytest.approx(z(10) - VS / 2 - VS)  # bottom face of the ceiling - one voxel
    plan = floor_plan(occ_map)
    assert (plan.k_lo, plan.k_hi) == (3, 9)  # layer centres in [z_min, z_max]
    assert plan.label[0, 0] == 1 and plan.free.sum() == 35  # the stray voxel is an obstacle

    assert height_band(occ_map, robot_height=0.5)[1] == pytest.approx(z(1) + VS / 2 + 0.5)
    assert height_band(occ_map, z_min=0.0, z_max=0.2) == (0.0, 0.2)
    with pytest.raises(InputError, match="z_min < z_max"):
        height_band(occ_map, z_min=0.3, z_max=0.2)
    with pytest.raises(InputError, match="no voxel layer"):
        floor_plan(occ_map, z_min=5.0, z_max=6.0)


def test_height_band_without_a_floor_class_starts_above_the_lowest_occupied_layer():
    label = np.full((4, 4, 8), FREE, np.int16)
    label[:, :, 2] = 3
    occ_map = make_map(label)
    assert height_band(occ_map) == pytest.approx((ORIGIN[2] + VS * 3.5, ORIGIN[2] + VS * 7.5))
    empty = make_map(np.full((4, 4, 8), FREE, np.int16))
    assert height_band(empty) == pytest.approx((ORIGIN[2] - VS / 2, ORIGIN[2] + VS * 7.5))


def test_plan_index_from_world():
    plan = floor_plan(make_map(box_on_floor()))
    ij, inside = plan.index_from_world(np.array([[1.24, 2.36], [0.94, 2.0]]))
    assert ij[0].tolist() == [2, 4] and inside.tolist() == [True, False]
    np.testing.assert_allclose(plan.origin_corner, [0.95, 1.95])


# --------------------------------------------------------------------------------------------
# Nav2


def read_pgm(path):
    """A binary PGM (P5, maxval 255, no comments) -> [height, width] uint8."""
    data = path.read_bytes()
    magic, width, height, maxval, pixels = data.split(maxsplit=4)
    assert magic == b"P5" and maxval == b"255"
    width, height = int(width), int(height)
    assert len(pixels) == width * height
    return np.frombuffer(pixels, np.uint8).reshape(height, width)


def read_map_yaml(path):
    """The flat key: value map_server YAML (comments skipped; lists parsed as JSON)."""
    out = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            key, value = (s.strip() for s in line.split(":", 1))
            try:
                out[key] = json.loads(value)
            except json.JSONDecodeError:
                out[key] = value
    return out


def test_nav2_files_origin_and_obstacle_pixel(tmp_path):
    label = box_on_floor(shape=(12, 10, 8), box=((2, 5), (3, 7), (1, 6)))
    label[11, :, :] = UNKNOWN  # the column x = max is unknown
    label[7, 8, 4] = 5  # one chair voxel at a known position
    occ_map = make_map(label)
    paths = write_nav2(occ_map, tmp_path / "plan.yaml")  # a .yaml suffix is dropped
    assert {p.name for p in paths.values()} == {"plan.pgm", "plan.yaml", "plan_labels.png"}

    meta = read_map_yaml(paths["yaml"])
    assert meta["image"] == "plan.pgm" and meta["mode"] == "trinary" and meta["negate"] == 0
    assert meta["resolution"] == pytest.approx(VS)
    assert meta["occupied_thresh"] == 0.65 and meta["free_thresh"] == 0.196
    # origin: the lower-left CORNER of the lower-left pixel = min corner of voxel [0, 0]
    np.testing.assert_allclose(meta["origin"], [ORIGIN[0] - VS / 2, ORIGIN[1] - VS / 2, 0.0], atol=1e-12)

    pgm = read_pgm(paths["pgm"])
    assert pgm.shape == (10, 12)  # [ny, nx]
    assert set(np.unique(pgm).tolist()) == {0, 205, 254}

    def pixel_of(x, y):
        """map_server's reading: column from x, row counted from the top (row 0 = max y)."""
        col = int(np.floor((x - meta["origin"][0]) / meta["resolution"]))
        row = pgm.shape[0] - 1 - int(np.floor((y - meta["origin"][1]) / meta["resolution"]))
        return row, col

    chair_xy = centre(7, 8, 4)[:2]
    assert pgm[pixel_of(*chair_xy)] == 0  # the obstacle lands on its pixel
    assert pgm[pixel_of(*(chair_xy + [0, VS]))] == 254  # free just above it in y
    assert pgm[pixel_of(*(chair_xy - [VS, 0]))] == 254  # and left of it in x
    assert pgm[pixel_of(*centre(3, 4, 0)[:2])] == 0  # the box
    assert pgm[pixel_of(*centre(11, 0, 0)[:2])] == 205  # the unknown column
    assert pgm[9 - 8, 7] == 0 and pgm[0, 7] == 254  # row r = j 9 - r: the chair (7, 8) is on row 1

    labels = np.asarray(Image.open(paths["labels"]).convert("RGB"))
    assert labels.shape == (10, 12, 3)
    assert tuple(labels[pixel_of(*centre(3, 4, 0)[:2])]) == COLORS[3]
    assert tuple(labels[pixel_of(*chair_xy)]) == default_color(5)
    assert tuple(labels[pixel_of(*centre(11, 0, 0)[:2])]) == (205, 205, 205)
    assert tuple(labels[pixel_of(*(chair_xy - [VS, 0]))]) == (254, 254, 254)


def test_image_from_plan_orientation():
    grid = np.arange(6).reshape(3, 2)  # [nx = 3, ny = 2]
    image = image_from_plan(grid)
    assert image.tolist() == [[1, 3, 5], [0, 2, 4]]  # row 0 = max y, column = x
