"""Class meshes from the continuous occupancy (one surface at the threshold, labelled, split, decimated),
their PLY files and the GLB, on hand-made maps whose surfaces are known analytically.

Meshes are checked with trimesh (watertight, winding, volume) and the GLB read back with
``trimesh.load``; PLY files with open3d (an independent reader).
"""

import json
import struct

import numpy as np
import open3d as o3d
import pytest
import trimesh
from test_exports import CLASSES, COLORS, ORIGIN, VS  # the same hand-made maps' frame and classes

from scenelabel import FREE, UNKNOWN, InputError, OccupancyMap
from scenelabel.maps.exports import (
    GLTF_FROM_WORLD,
    class_meshes,
    class_palette,
    class_surface,
    decimate,
    default_color,
    face_labels,
    occupancy_surface,
    vertex_normals,
    write_class_meshes,
    write_glb,
)


def make_map(label, occupancy=None, threshold=0.5, **kwargs):
    label = np.asarray(label, np.int16)
    if occupancy is None:
        occupancy = np.where(label >= 0, 0.9, np.where(label == FREE, 0.1, 0.0))
    return OccupancyMap(
        label,
        np.asarray(occupancy, np.float32),
        VS,
        ORIGIN,
        CLASSES,
        VS,
        class_colors=COLORS,
        occupancy_threshold=threshold,
        **kwargs,
    )


def index_of(xyz):
    """World points [N, 3] -> fractional voxel indices [N, 3]."""
    return (np.asarray(xyz) - np.array(ORIGIN)) / VS


def box_distance(ijk, centre, half):
    """Exact Euclidean distance [N] (voxel units) from points [N, 3] to the surface of a box."""
    q = np.abs(np.asarray(ijk) - centre) - half  # [N, 3]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = -np.max(q, axis=1)
    return np.where(np.all(q <= 0, axis=1), inside, outside)


def ramp_box(shape=(16, 14, 12), centre=(7.3, 6.6, 5.8), half=(4.2, 3.1, 2.6), slope=0.15):
    """Occupancy 0.5 + slope * (signed distance inside a box, voxels), clipped to [0, 1]; label 3
    where it reaches 0.5, FREE elsewhere."""
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, 3)
    q = np.abs(ijk - np.array(centre)) - np.array(half)
    signed = -np.max(q, axis=1)  # > 0 inside; outside: >= -distance, equal on the faces' normals
    occupancy = np.clip(0.5 + slope * signed, 0.0, 1.0).reshape(shape)
    label = np.where(occupancy >= 0.5, 3, FREE)
    return make_map(label, occupancy), np.array(centre), np.array(half)


def as_trimesh(mesh):
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def union(meshes):
    """The class meshes as one mesh, coincident vertices merged."""
    whole = trimesh.util.concatenate([as_trimesh(m) for m in meshes.values()])
    whole.merge_vertices()
    return whole


# --------------------------------------------------------------------------------------------
# The surface


def test_ramp_box_surface_lies_on_the_analytic_iso_surface():
    occ_map, centre, half = ramp_box()
    vertices, faces, normals = occupancy_surface(occ_map)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    # marching cubes interpolates linearly along grid edges: exact on the faces, cut at edges
    distance = box_distance(index_of(vertices), centre, half)
    assert np.median(distance) < 1e-4 and distance.max() < 0.2
    assert mesh.volume == pytest.approx(np.prod(2 * half) * VS**3, rel=0.08)  # > 0: outward; edges cut
    outward = np.einsum("ij,ij->i", normals, index_of(vertices) - centre)
    assert np.all(outward > 0)

    meshes = class_meshes(occ_map)
    assert list(meshes) == [3]
    box = meshes[3]
    decimated = as_trimesh(box)
    assert decimated.is_watertight and decimated.is_winding_consistent
    assert len(box.faces) <= 64 < len(faces) / 5  # MIN_DECIMATED_FACES
    assert box_distance(index_of(box.vertices), centre, half).max() < 0.3  # within a third of a voxel
    assert decimated.volume == pytest.approx(mesh.volume, rel=0.02)
    # normals: unit, outward, consistent with the winding
    np.testing.assert_allclose(np.linalg.norm(box.normals, axis=1), 1.0, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", box.normals, index_of(box.vertices) - centre) > 0)
    assert box.vertices.dtype == np.float64 and box.faces.dtype == np.int32 and box.normals.dtype == np.float32


def test_flat_floor_slab_decimates_to_a_few_dozen_triangles():
    # Not two per face: marching cubes cuts the slab's edges into thin strips, and the decimator
    # never makes slivers; ~76 triangles remain of ~5400.
    label = np.full((40, 30, 6), FREE, np.int16)
    label[:, :, 1:3] = 1  # a slab two voxels thick, touching four sides of the grid
    occ_map = make_map(label)
    before = len(class_surface(label == 1, ORIGIN, VS)[1])
    surface = occupancy_surface(occ_map)
    meshes = class_meshes(occ_map)
    floor = meshes[1]
    assert before > 5000 and len(surface[1]) > 5000
    assert len(floor.faces) <= 80, len(floor.faces)
    mesh = as_trimesh(floor)
    assert mesh.is_watertight and mesh.volume > 0
    # still the slab: its top and bottom half-way between the occupied and free voxel centres,
    # its sides on the grid's boundary faces; every vertex on one of these six planes
    ijk = index_of(floor.vertices)
    on_plane = (
        np.isclose(ijk[:, 2], 0.5)
        | np.isclose(ijk[:, 2], 2.5)
        | np.isclose(ijk[:, 0], -0.5)
        | np.isclose(ijk[:, 0], 39.5)
        | np.isclose(ijk[:, 1], -0.5)
        | np.isclose(ijk[:, 1], 29.5)
    )
    assert on_plane.all()
    lo, hi = ijk.min(0), ijk.max(0)
    np.testing.assert_allclose([lo[2], hi[2]], [0.5, 2.5], atol=1e-6)
    np.testing.assert_allclose(lo[:2], [-0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi[:2], [39.5, 29.5], atol=1e-6)


def test_two_classes_side_by_side_are_labelled_and_share_their_border():
    label = np.full((14, 8, 8), FREE, np.int16)
    label[2:7, 2:6, 2:6] = 1
    label[7:12, 2:6, 2:6] = 3  # touching along x = 6.5 (voxel units)
    occ_map = make_map(label)
    meshes = class_meshes(occ_map)
    assert sorted(meshes) == [1, 3]
    for cid, side in ((1, -1), (3, 1)):
        centroids = index_of(meshes[cid].vertices[meshes[cid].faces].mean(1))
        assert np.all(side * (centroids[:, 0] - 6.5) > 0), cid  # each triangle on its class's side
        assert not as_trimesh(meshes[cid]).is_watertight  # open where the classes meet
    whole = union(meshes)
    assert whole.is_watertight and whole.is_winding_consistent  # together: the one closed surface
    vertices, faces, _ = occupancy_surface(occ_map)
    assert whole.volume == pytest.approx(trimesh.Trimesh(vertices, faces).volume, rel=1e-4)  # no loss
    assert whole.volume == pytest.approx(10 * 4 * 4 * VS**3, rel=0.06)  # marching cubes cuts the edges
    # face_labels on the undecimated surface: by the side of the contact plane
    labels = face_labels(occ_map, vertices, faces)
    x = index_of(vertices[faces].mean(1))[:, 0]
    assert np.all(labels[x < 6.4] == 1) and np.all(labels[x > 6.6] == 3)


def test_face_labels_fall_back_to_the_nearest_labelled_voxel():
    label = np.full((10, 4, 4), FREE, np.int16)
    label[1, 1, 1], label[8, 2, 2] = 1, 3
    occ_map = make_map(label)
    # a triangle far from both voxels, nearer the class-3 one, and one next to the class-1 one
    vertices = np.array(ORIGIN) + VS * np.array([[6.0, 0.0, 0.0], [6.0, 3.0, 0.0], [6.0, 0.0, 3.0], [1.2, 1.0, 1.0]])
    labels = face_labels(occ_map, vertices, [[0, 1, 2], [3, 3, 3]])
    assert labels.tolist() == [3, 1]
    with pytest.raises(InputError, match="labelled"):
        face_labels(make_map(np.full((3, 3, 3), FREE)), vertices, [[0, 1, 2]])


def test_threshold_is_the_maps_own():
    label = np.full((8, 8, 8), FREE, np.int16)
    label[2:6, 2:6, 2:6] = 3
    occupancy = np.where(label >= 0, 0.4, 0.1)  # occupied at threshold 0.3, crossing at 0.3
    occ_map = make_map(label, occupancy, threshold=0.3)
    box = class_meshes(occ_map, reduction=0.0)[3]
    ijk = index_of(box.vertices)
    # 0.4 -> 0.1 crosses 0.3 a third of the way out of the box's outer voxels
    np.testing.assert_allclose(ijk.min(0), [2 - 1 / 3] * 3, atol=1e-6)
    np.testing.assert_allclose(ijk.max(0), [5 + 1 / 3] * 3, atol=1e-6)


def test_unknown_counts_as_outside():
    label = np.full((6, 6, 6), UNKNOWN, np.int16)
    label[:, :, 3:] = FREE
    label[:, :, 2] = 1  # a floor observed from above only, unobserved below
    occ_map = make_map(label)
    floor = class_meshes(occ_map)[1]
    mesh = as_trimesh(floor)
    assert mesh.is_watertight  # closed behind the observed voxels, not around the unknown region
    z = np.round(index_of(floor.vertices)[:, 2], 6)
    assert z.max() == 2.5 and z.min() == pytest.approx(2 - 0.4 / 0.9, abs=1e-6)  # 0.9 -> 0 (UNKNOWN)


# --------------------------------------------------------------------------------------------
# Extremes


def test_a_map_without_occupied_voxels_writes_no_mesh(tmp_path):
    occ_map = make_map(np.full((4, 4, 4), FREE))
    assert class_meshes(occ_map) == {}
    vertices, faces, normals = occupancy_surface(occ_map)
    assert vertices.shape == (0, 3) and faces.shape == (0, 3) and normals.shape == (0, 3)
    assert write_class_meshes(occ_map, tmp_path / "meshes") == {}
    assert list((tmp_path / "meshes").iterdir()) == []
    with pytest.raises(InputError, match="no surface"):
        write_glb(occ_map, tmp_path / "map.glb")
    assert not (tmp_path / "map.glb").exists()


def test_a_single_occupied_voxel():
    label = np.full((3, 3, 3), FREE, np.int16)
    label[1, 1, 1] = 5
    meshes = class_meshes(make_map(label))
    chair = meshes[5]
    mesh = as_trimesh(chair)
    assert mesh.is_watertight and mesh.volume > 0 and len(chair.faces) == 8  # an octahedron
    np.testing.assert_allclose(np.abs(index_of(chair.vertices) - 1).max(1), 0.5, atol=1e-9)
    # and at the grid's corner: closed on the boundary faces
    corner = np.full((2, 2, 2), FREE, np.int16)
    corner[0, 0, 0] = 5
    mesh = as_trimesh(class_meshes(make_map(corner))[5])
    assert mesh.is_watertight and mesh.volume > 0


def test_binary_occupancy_gives_the_voxel_faces():
    label = np.full((9, 8, 7), FREE, np.int16)
    label[2:7, 1:5, 1:6] = 3
    occ_map = make_map(label, np.where(label >= 0, 1.0, 0.0))
    box = class_meshes(occ_map)[3]
    ijk = index_of(box.vertices)
    np.testing.assert_allclose(ijk.min(0), [1.5, 0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(ijk.max(0), [6.5, 4.5, 5.5], atol=1e-6)
    mesh = as_trimesh(box)
    assert mesh.is_watertight and mesh.volume == pytest.approx(5 * 4 * 5 * VS**3, rel=0.08)  # edges cut
    everything = class_meshes(make_map(np.full((3, 2, 2), 1, np.int16), np.ones((3, 2, 2))))[1]
    assert as_trimesh(everything).is_watertight  # the whole grid occupied: closed on its boundary


def test_decimate_and_normals_contracts():
    occ_map, _, _ = ramp_box()
    vertices, faces, _ = occupancy_surface(occ_map)
    with pytest.raises(InputError, match="reduction"):
        decimate(vertices, faces, 1.0)
    with pytest.raises(InputError, match="reduction"):
        class_meshes(occ_map, reduction=-0.1)
    v, f = decimate(vertices, faces, 0.0)  # lossless only: the flat faces still collapse
    assert len(f) < len(faces) and trimesh.Trimesh(v, f, process=False).is_watertight
    assert np.unique(f).tolist() == list(range(len(v)))  # no unused vertex
    _, tiny_f = decimate(vertices[:3], [[0, 1, 2]], 0.9)
    assert len(tiny_f) == 1
    normals = vertex_normals([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], [[0, 1, 2]])
    np.testing.assert_allclose(normals, [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 0]])


# --------------------------------------------------------------------------------------------
# Files


def box_on_floor():
    label = np.full((12, 10, 8), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:5, 3:7, 1:4] = 3
    return make_map(label)


def test_ply_files_carry_geometry_colour_and_labels(tmp_path):
    occ_map = box_on_floor()
    meshes = class_meshes(occ_map)
    paths = write_class_meshes(occ_map, tmp_path / "meshes", meshes=meshes)
    assert [p.name for p in paths.values()] == ["class_1_floor.ply", "class_3_box.ply"]
    for cid, path in paths.items():
        mesh = o3d.io.read_triangle_mesh(str(path))
        np.testing.assert_allclose(np.asarray(mesh.vertices), meshes[cid].vertices, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(mesh.triangles), meshes[cid].faces)
        np.testing.assert_allclose(np.asarray(mesh.vertex_normals), meshes[cid].normals, atol=1e-6)
        colours = np.asarray(mesh.vertex_colors) * 255
        np.testing.assert_allclose(colours, np.tile(class_palette(CLASSES, COLORS)[cid], (len(colours), 1)), atol=1e-6)
        assert np.all(o3d.t.io.read_point_cloud(str(path)).point.label.numpy() == cid)
        assert b"comment frame world; units input" in path.read_bytes()[:300]
    assert union(meshes).is_watertight


def test_glb_has_a_node_and_material_per_class(tmp_path):
    label = np.full((12, 10, 8), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:5, 3:7, 1:4] = 3
    label[8:10, 6:8, 1:3] = 5  # chair: no colour of its own
    occ_map = make_map(label)
    meshes = class_meshes(occ_map)
    path = write_glb(occ_map, tmp_path / "map.glb", meshes=meshes)
    assert path.read_bytes()[:4] == b"glTF"

    scene = trimesh.load(path)
    assert isinstance(scene, trimesh.Scene)
    assert sorted(scene.graph.nodes_geometry) == ["box", "chair", "floor"]
    assert len(scene.geometry) == 3
    expected = {"floor": COLORS[1], "box": COLORS[3], "chair": default_color(5)}
    ids = {"floor": 1, "box": 3, "chair": 5}
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        np.testing.assert_allclose(transform, GLTF_FROM_WORLD, atol=1e-12)
        geometry = scene.geometry[geometry_name]
        assert tuple(geometry.visual.material.baseColorFactor[:3]) == expected[node]
        assert geometry.metadata["class_id"] == ids[node]
        # buffers in world coordinates; the node turns world +z into glTF +y
        np.testing.assert_allclose(geometry.vertices, meshes[ids[node]].vertices, atol=1e-5)  # float32 buffers
        assert len(geometry.faces) == len(meshes[ids[node]].faces)
    extras = scene.metadata["scenelabel"]
    assert extras["frame_id"] == "world" and extras["classes"] == ids and extras["up"] == "world +z"
    np.testing.assert_allclose(extras["gltf_from_world"], GLTF_FROM_WORLD)
    # in glTF axes the floor lies below the box along +y
    bounds = {
        node: trimesh.transform_points(scene.geometry[g].vertices, t)
        for node, (t, g) in ((n, scene.graph[n]) for n in scene.graph.nodes_geometry)
    }
    assert (
        bounds["floor"][:, 1].min() < bounds["box"][:, 1].min()
        and bounds["box"][:, 1].max() > bounds["floor"][:, 1].max()
    )

    # raw glTF: materials named after the classes, a parent node "world", normals present
    data = path.read_bytes()
    (length,) = struct.unpack("<I", data[12:16])
    gltf = json.loads(data[20 : 20 + length])
    assert sorted(m["name"] for m in gltf["materials"]) == ["box", "chair", "floor"]
    assert any(n.get("name") == "world" and len(n.get("children", [])) == 3 for n in gltf["nodes"])
    assert all("NORMAL" in p["attributes"] for m in gltf["meshes"] for p in m["primitives"])

    flat = write_glb(occ_map, tmp_path / "z_up.glb", meshes=meshes, y_up=False)
    transform, _ = trimesh.load(flat).graph["floor"]
    np.testing.assert_allclose(transform, np.eye(4), atol=1e-12)


def test_glb_path_checks(tmp_path):
    occ_map = box_on_floor()
    with pytest.raises(InputError, match=r"\.glb"):
        write_glb(occ_map, tmp_path / "map.gltf")
    with pytest.raises(InputError, match="parent folder"):
        write_glb(occ_map, tmp_path / "missing" / "map.glb")
