"""Tests of scenelabel.data.synthetic: exact ray casting, the written scene folders, conventions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import binary_erosion

from scenelabel.data.synthetic import (
    BACKGROUND_ID,
    ROOM_BOXES,
    TOY_BOXES,
    Box,
    cast_rays,
    furnished_room_geometry,
    look_at,
    toy_scene_geometry,
    write_furnished_room,
    write_toy_scene,
)
from scenelabel.errors import InputError

FLOOR_TOP = 0.0
TOY_PRESENT = {1, 3, 7, BACKGROUND_ID}


@pytest.fixture(scope="module")
def toy_dir(tmp_path_factory) -> Path:
    return write_toy_scene(tmp_path_factory.mktemp("toy") / "scene")


@pytest.fixture(scope="module")
def room_dir(tmp_path_factory) -> Path:
    return write_furnished_room(tmp_path_factory.mktemp("room") / "scene", width=64, height=48)


def _load(root: Path) -> tuple[dict, dict]:
    return json.loads((root / "transforms.json").read_text()), json.loads((root / "classes.json").read_text())


def _rays_from_transforms(tf: dict, frame: dict) -> tuple[np.ndarray, np.ndarray]:
    """Independent ray generation in OpenGL camera axes, pixel centres at +0.5."""
    w, h = tf["w"], tf["h"]
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d_cam = np.stack([(u - tf["cx"]) / tf["fl_x"], -(v - tf["cy"]) / tf["fl_y"], -np.ones_like(u)], -1)
    c2w = np.asarray(frame["transform_matrix"])
    d = d_cam @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(c2w[:3, 3], d.shape), d


def _distance_to_box_surface(points: np.ndarray, box: Box) -> np.ndarray:
    """[n] distance of points to the surface of a box (exact for points inside or outside)."""
    lo, hi = np.asarray(box.lo), np.asarray(box.hi)
    outside = np.linalg.norm(np.maximum(0, np.maximum(lo - points, points - hi)), axis=1)
    inside = np.minimum(points - lo, hi - points).min(axis=1)
    return np.where(outside > 0, outside, np.abs(inside))


# ---------------------------------------------------------------- ray casting


def test_ray_straight_down_hits_floor_exactly():
    hits = cast_rays(np.array([[0.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -1.0]]), TOY_BOXES)
    assert hits.depth[0] == 5.0 - FLOOR_TOP
    assert hits.class_id[0] == 1
    np.testing.assert_array_equal(hits.normal[0], [0, 0, 1])
    np.testing.assert_array_equal(hits.hit_point[0], [0, 0, FLOOR_TOP])


def test_ray_into_box_face_analytic_depth():
    # box_red spans x in [-0.7, -0.2]; a ray along -x at y=-0.25, z=0.3 from x=2 passes box_blue? no:
    # box_blue is y in [0, 0.5], so the first hit is box_red's +x face at x=-0.2.
    hits = cast_rays(np.array([[2.0, -0.25, 0.3]]), np.array([[-1.0, 0.0, 0.0]]), TOY_BOXES)
    assert hits.class_id[0] == 3
    assert hits.depth[0] == pytest.approx(2.2, abs=1e-12)
    np.testing.assert_array_equal(hits.normal[0], [1, 0, 0])
    # oblique, non-unit direction: depth is along the unit direction
    o = np.array([[0.4, 0.25, 2.0]])
    d = np.array([[0.0, 0.3, -2.0]])  # hits box_blue's top (z=0.4) at t = 1.6 * |d|/2
    hits = cast_rays(o, d, TOY_BOXES)
    expected = 1.6 / 2.0 * np.linalg.norm(d)
    assert hits.class_id[0] == 7
    assert hits.depth[0] == pytest.approx(expected, abs=1e-12)
    np.testing.assert_allclose(hits.hit_point[0], o[0] + 0.8 * d[0], atol=1e-12)


def test_ray_into_sky_misses():
    hits = cast_rays(np.array([[0.0, 0.0, 1.0], [3.0, 3.0, 1.0]]), np.array([[0.1, 0.2, 1.0], [1.0, 0.0, -0.1]]), TOY_BOXES)
    np.testing.assert_array_equal(hits.depth, [0.0, 0.0])
    np.testing.assert_array_equal(hits.class_id, [BACKGROUND_ID, BACKGROUND_ID])
    assert np.isnan(hits.hit_point).all()
    assert not hits.hit.any()


def test_nearest_hit_wins_and_behind_is_ignored():
    boxes = [Box((4, -1, -1), (5, 1, 1), 9), Box((2, -1, -1), (3, 1, 1), 4), Box((-3, -1, -1), (-2, 1, 1), 8)]
    hits = cast_rays(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), boxes)
    assert hits.class_id[0] == 4 and hits.depth[0] == 2.0


def test_ray_from_inside_box_hits_its_inside():
    hits = cast_rays(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]), [Box((-3, -3, 0), (3, 3, 2), 2)])
    assert hits.depth[0] == 3.0 and hits.class_id[0] == 2
    np.testing.assert_array_equal(hits.normal[0], [-1, 0, 0])  # faces the ray


def test_cast_rays_vectorised_matches_single():
    rng = np.random.default_rng(1)
    o = rng.uniform(-2, 2, (200, 3)) + [0, 0, 2]
    d = rng.normal(size=(200, 3))
    batch = cast_rays(o, d, TOY_BOXES)
    for k in range(0, 200, 17):
        one = cast_rays(o[k : k + 1], d[k : k + 1], TOY_BOXES)
        assert one.depth[0] == batch.depth[k] and one.class_id[0] == batch.class_id[k]


def test_cast_rays_rejects_zero_direction():
    with pytest.raises(InputError):
        cast_rays(np.zeros((1, 3)), np.zeros((1, 3)), TOY_BOXES)


def test_look_at_is_opengl():
    c2w = look_at([3.0, 0.0, 2.0], [0.0, 0.0, 0.2])
    forward = -c2w[:3, 2]
    expected = np.array([-3.0, 0.0, -1.8]) / np.linalg.norm([-3.0, 0.0, -1.8])
    np.testing.assert_allclose(forward, expected, atol=1e-12)
    assert c2w[2, 1] > 0  # camera y (up) has a positive world-z component
    np.testing.assert_allclose(c2w[:3, :3] @ c2w[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(c2w[:3, :3]) == pytest.approx(1.0)


# ---------------------------------------------------------------- scene definitions


def test_toy_geometry_as_data():
    scene = toy_scene_geometry()
    assert {b.class_id for b in scene.boxes} == {1, 3, 7}
    assert {c.id for c in scene.classes} == {1, 3, 5, 7}  # chair (5) never appears
    assert scene.present_ids == [1, 3, 7]


def test_room_geometry_as_data():
    scene = furnished_room_geometry()
    ids = {c.id for c in scene.classes}
    assert 6 <= len(ids) <= 8
    assert ids != set(range(min(ids), min(ids) + len(ids)))  # non-contiguous
    pole = next(b for b in ROOM_BOXES if b.part == "lamp_pole")
    assert min(np.subtract(pole.hi, pole.lo)[:2]) == pytest.approx(0.05)


# ---------------------------------------------------------------- written folders


def test_toy_folder_layout(toy_dir: Path):
    tf, classes = _load(toy_dir)
    assert classes["ignore_index"] == 255
    assert {c["id"] for c in classes["classes"]} == {1, 3, 5, 7}
    assert tf["camera_model"] == "PINHOLE" and tf["w"] == 96 and tf["h"] == 72
    assert tf["frame_id"] == "toy_world"
    assert len(tf["frames"]) == 32
    assert sum(1 for i in range(32) if i % 8 == 0) == 4
    aabb = np.asarray(tf["aabb"])
    assert aabb.shape == (2, 3) and np.all(aabb[0] < [-1.5, -1.5, -0.02]) and np.all(aabb[1] > [1.5, 1.5, 0.6])
    for frame in tf["frames"]:
        for key in ("file_path", "label_path", "depth_path"):
            assert (toy_dir / frame[key]).is_file()
        assert np.asarray(frame["transform_matrix"]).shape == (4, 4)
        assert 0 < frame["near"] < frame["far"]


def test_toy_images_labels_depths(toy_dir: Path):
    tf, _ = _load(toy_dir)
    seen: set[int] = set()
    for frame in tf["frames"]:
        img = np.asarray(Image.open(toy_dir / frame["file_path"]))
        lab = np.asarray(Image.open(toy_dir / frame["label_path"]))
        depth = np.load(toy_dir / frame["depth_path"])
        assert img.shape == (72, 96, 3) and img.dtype == np.uint8
        assert lab.shape == (72, 96) and lab.dtype == np.uint8
        assert depth.shape == (72, 96) and depth.dtype == np.float32
        assert set(np.unique(lab).tolist()) <= TOY_PRESENT
        seen |= set(np.unique(lab).tolist())
        assert np.all((depth == 0) == (lab == BACKGROUND_ID))
        assert np.all(np.isfinite(depth))
        # background away from edges is pure white (edge pixels mix by 2x2 supersampling)
        sky = binary_erosion(lab == BACKGROUND_ID, np.ones((3, 3), bool), border_value=1)
        assert sky.any() and np.all(img[sky] == 255)
        # near/far bracket every true depth
        hit = depth[depth > 0]
        assert frame["near"] <= hit.min() and hit.max() <= frame["far"]
        assert frame["near"] == pytest.approx(0.8 * hit.min(), rel=1e-5)
    assert seen == TOY_PRESENT


def test_toy_depth_consistent_with_cameras(toy_dir: Path):
    tf, _ = _load(toy_dir)
    for frame in tf["frames"][::5]:
        lab = np.asarray(Image.open(toy_dir / frame["label_path"])).astype(np.int64)
        depth = np.load(toy_dir / frame["depth_path"]).astype(np.float64)
        o, d = _rays_from_transforms(tf, frame)
        points = o + depth[..., None] * d
        for class_id in (1, 3, 7):
            sel = lab == class_id
            p = points[sel]
            dist = np.min([_distance_to_box_surface(p, b) for b in TOY_BOXES if b.class_id == class_id], axis=0)
            assert dist.max() < 1e-4, (class_id, dist.max())


def test_transform_matrix_is_opengl_looking_at_target(toy_dir: Path):
    tf, _ = _load(toy_dir)
    target = np.array([0.0, 0.0, 0.2])
    for frame in tf["frames"]:
        c2w = np.asarray(frame["transform_matrix"])
        forward = -c2w[:3, 2]
        to_target = target - c2w[:3, 3]
        cos = forward @ to_target / np.linalg.norm(to_target)
        assert cos > 0.999  # target jitter is at most a few cm at ~3 m
        assert c2w[2, 1] > 0  # image up is world up
        radius = np.linalg.norm(c2w[:2, 3])
        assert 2.55 <= radius <= 3.05 and 1.25 <= c2w[2, 3] <= 2.25


def test_held_out_views_are_between_training_views(toy_dir: Path):
    tf, _ = _load(toy_dir)
    centres = np.array([np.asarray(f["transform_matrix"])[:3, 3] for f in tf["frames"]])
    az = np.unwrap(np.arctan2(centres[:, 1], centres[:, 0]))
    n = len(az)
    step = np.diff(az)
    assert np.all(np.sign(step) == np.sign(step[0]))  # monotone closed orbit
    for i in range(0, n, 8):
        prev_c, next_c = centres[i - 1], centres[(i + 1) % n]
        gap = np.linalg.norm(next_c - prev_c)
        assert np.linalg.norm(centres[i] - (prev_c + next_c) / 2) < 0.5 * gap


def test_deterministic_for_seed(tmp_path: Path):
    a = write_toy_scene(tmp_path / "a", width=32, height=24, seed=3)
    b = write_toy_scene(tmp_path / "b", width=32, height=24, seed=3)
    c = write_toy_scene(tmp_path / "c", width=32, height=24, seed=4)
    for name in ("transforms.json", "images/005.png", "labels/005.png", "depths/005.npy"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert (a / "transforms.json").read_bytes() != (c / "transforms.json").read_bytes()


def test_split_must_match_holdout(tmp_path: Path):
    with pytest.raises(InputError, match="n_test"):
        write_toy_scene(tmp_path / "x", n_train=28, n_test=3)


def test_room_every_ray_hits(room_dir: Path):
    tf, classes = _load(room_dir)
    ids = {c["id"] for c in classes["classes"]}
    assert len(tf["frames"]) == 40
    seen: set[int] = set()
    for frame in tf["frames"]:
        lab = np.asarray(Image.open(room_dir / frame["label_path"]))
        depth = np.load(room_dir / frame["depth_path"])
        assert np.all(depth > 0) and BACKGROUND_ID not in lab
        seen |= set(np.unique(lab).tolist())
        height = np.asarray(frame["transform_matrix"])[2, 3]
        assert 0.99 <= height <= 1.81
    assert seen == ids  # every class, including the thin lamp, is seen


def test_room_depth_consistent_with_cameras(room_dir: Path):
    tf, _ = _load(room_dir)
    for frame in tf["frames"][::7]:
        lab = np.asarray(Image.open(room_dir / frame["label_path"])).astype(np.int64)
        depth = np.load(room_dir / frame["depth_path"]).astype(np.float64)
        o, d = _rays_from_transforms(tf, frame)
        points = o + depth[..., None] * d
        for class_id in np.unique(lab).tolist():
            p = points[lab == class_id]
            dist = np.min([_distance_to_box_surface(p, b) for b in ROOM_BOXES if b.class_id == class_id], axis=0)
            assert dist.max() < 1e-4, (class_id, dist.max())


def test_room_held_out_surfaces_are_seen_in_training(room_dir: Path):
    """Every class a held-out view (every 8th) sees was seen by some training view at the same
    surface point: a held-out label is learnable. (The first room trajectory saw 1% of the
    held-out ceiling in training, which no method could label.)"""
    tf, _ = _load(room_dir)
    frames = tf["frames"]
    w, h = tf["w"], tf["h"]
    train = [f for i, f in enumerate(frames) if i % 8]
    train_depth = [np.load(room_dir / f["depth_path"]) for f in train]
    for frame in frames[::8]:
        lab = np.asarray(Image.open(room_dir / frame["label_path"])).astype(np.int64)
        o, d = _rays_from_transforms(tf, frame)
        points = (o + np.load(room_dir / frame["depth_path"])[..., None] * d).reshape(-1, 3)
        seen = np.zeros(len(points), bool)
        for f, depth in zip(train, train_depth):
            c2w = np.asarray(f["transform_matrix"])
            p_cam = (points - c2w[:3, 3]) @ c2w[:3, :3]  # OpenGL camera axes: looking along -z
            z = -p_cam[:, 2]
            ahead = z > 1e-6
            z_safe = np.where(ahead, z, 1.0)
            u = tf["fl_x"] * p_cam[:, 0] / z_safe + tf["cx"]
            v = -tf["fl_y"] * p_cam[:, 1] / z_safe + tf["cy"]
            ok = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            dist = np.linalg.norm(points - c2w[:3, 3], axis=1)
            hit = depth[np.clip(v.astype(int), 0, h - 1), np.clip(u.astype(int), 0, w - 1)]
            seen |= ok & (np.abs(hit - dist) < 0.05 * dist)
        for class_id in np.unique(lab).tolist():
            fraction = seen[lab.ravel() == class_id].mean()
            assert fraction > 0.9, (frame["file_path"], class_id, fraction)


# ---------------------------------------------------------------- the lead's original checks (kept)

def test_known_ray_hits():
    scene = toy_scene_geometry()
    o = np.array([[1.2, 1.2, 5.0], [-0.45, -0.25, 5.0], [-3.0, -0.25, 0.3], [0.0, 0.0, 5.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -2.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    hits = cast_rays(o, d, scene.boxes)
    np.testing.assert_allclose(hits.depth[:3], [5.0, 5.0 - 0.6, 3.0 - 0.7])  # floor top, red box top, red box face
    assert hits.class_id.tolist() == [1, 3, 3, 255]
    assert hits.depth[3] == 0.0  # looking up: the sky


def test_written_scene_is_consistent(tmp_path):
    root = write_toy_scene(tmp_path / "toy", n_train=7, n_test=1, width=32, height=24)
    meta = json.loads((root / "transforms.json").read_text())
    assert len(meta["frames"]) == 8
    frame = meta["frames"][3]
    label = np.array(Image.open(root / frame["label_path"]))
    depth = np.load(root / frame["depth_path"])
    assert set(np.unique(label).tolist()) <= {1, 3, 7, 255}
    assert np.all((depth > 0) == (label != 255))
    # re-cast the labelled pixels' rays (OpenGL c2w, pixel centres +0.5): same depth and class
    c2w = np.array(frame["transform_matrix"])
    rows, cols = np.nonzero(label != 255)
    dirs_cam = np.stack([(cols + 0.5 - meta["cx"]) / meta["fl_x"], -(rows + 0.5 - meta["cy"]) / meta["fl_y"], -np.ones(len(rows))], -1)
    dirs = dirs_cam @ c2w[:3, :3].T
    hits = cast_rays(np.broadcast_to(c2w[:3, 3], dirs.shape), dirs, TOY_BOXES)
    np.testing.assert_allclose(hits.depth, depth[rows, cols], rtol=1e-5)
    np.testing.assert_array_equal(hits.class_id, label[rows, cols])
    # OpenGL: the camera looks down its -z axis, towards the scene centre
    forward = -c2w[:3, 2]
    to_centre = -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])
    assert forward @ to_centre > 0.9


def test_deterministic(tmp_path):
    a = write_toy_scene(tmp_path / "a", n_train=7, n_test=1, width=16, height=12)
    b = write_toy_scene(tmp_path / "b", n_train=7, n_test=1, width=16, height=12)
    np.testing.assert_array_equal(np.array(Image.open(a / "images" / "005.png")), np.array(Image.open(b / "images" / "005.png")))


def test_corrupt_labels_hits_the_fraction_and_keeps_ignored_pixels():
    from scenelabel.data.synthetic import corrupt_labels

    rng = np.random.default_rng(0)
    lab = np.full((60, 80), 1, np.int64)
    lab[20:40, 30:50] = 3
    lab[:5] = BACKGROUND_ID
    for fraction in (0.0, 0.1, 0.3, 0.5):
        out = corrupt_labels(lab, fraction, [1, 3, 7], rng)
        labelled = lab != BACKGROUND_ID
        got = ((out != lab) & labelled).sum() / labelled.sum()
        assert fraction <= got < fraction + 0.15, (fraction, got)
        np.testing.assert_array_equal(out[~labelled], BACKGROUND_ID)
        assert set(np.unique(out[labelled]).tolist()) <= {1, 3, 7}
    a = corrupt_labels(lab, 0.2, [1, 3], np.random.default_rng(5))
    b = corrupt_labels(lab, 0.2, [1, 3], np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(InputError):
        corrupt_labels(lab, 1.0, [1, 3], rng)
