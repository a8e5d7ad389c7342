"""Tests of scenelabel.data.suite: the procedurally varied room suite the project's defaults are chosen on."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from PIL import Image

from scenelabel.data.io import load_scene
from scenelabel.data.suite import (
    CAMERA_CLEARANCE,
    FORWARD_SUITE,
    FOV_X_DEG,
    RIG_HALF_WIDTH,
    RIG_HEIGHTS,
    STRUCTURAL_PARTS,
    SUITE,
    SUITE_CLASSES,
    SuiteSpec,
    suite_cameras,
    suite_geometry,
    suite_spec,
    write_suite_scene,
)
from scenelabel.data.synthetic import (
    BACKGROUND_ID,
    HOLDOUT_EVERY,
    cast_rays,
    pixel_rays,
    render_view,
    toy_cameras,
    toy_scene_geometry,
    write_scene,
)
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, opengl_to_opencv
from scenelabel.geometry.frame import forward_rig, near_far_or_fallback
from scenelabel.geometry.warps import capture_reference

VOCAB = {c.id for c in SUITE_CLASSES}
TARGET_ROOMS = [s for s in SUITE if (s.width, s.height) == (160, 120) and 30 <= s.n_views <= 60]


@pytest.fixture(scope="module")
def rooms() -> dict:
    """name -> (spec, scene, c2ws) for every suite room (geometry and cameras only, no rendering)."""
    out = {}
    for spec in SUITE:
        scene = suite_geometry(spec)
        out[spec.name] = (spec, scene, suite_cameras(spec, scene))
    return out


def _piece(box) -> str | None:
    """Piece name ("table#0") of a furniture box; None for the structural slabs."""
    return None if box.part in STRUCTURAL_PARTS else box.part.split("/")[0]


def _focal(width: int) -> float:
    return (width / 2.0) / math.tan(math.radians(FOV_X_DEG) / 2.0)


def _depth_maps(scene, c2ws, width: int, height: int) -> np.ndarray:
    """[n, h, w] exact depth (along the unit ray) of every view at the given size."""
    f = _focal(width)
    out = []
    for c2w in c2ws:
        o, d = pixel_rays(c2w, f, f, width / 2, height / 2, width, height)
        out.append(cast_rays(o.reshape(-1, 3), d.reshape(-1, 3), scene.boxes).depth.reshape(height, width))
    return np.stack(out)


def _project(c2w_opengl: np.ndarray, points: np.ndarray, f: float, width: int, height: int):
    """Pixel coordinates (u, v) and forward depth z of world points in an OpenGL camera."""
    cam = (points - c2w_opengl[:3, 3]) @ c2w_opengl[:3, :3]  # world -> camera (x right, y up, -z forward)
    z = -cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = width / 2 + f * cam[:, 0] / z
        v = height / 2 - f * cam[:, 1] / z
    return u, v, z


# ---------------------------------------------------------------- the suite as data


def test_suite_composition():
    names = [s.name for s in SUITE]
    assert len(SUITE) >= 10 and len(set(names)) == len(names)
    assert len(TARGET_ROOMS) >= 7
    held_out = [s for s in SUITE if not s.tuning]
    assert len(held_out) == 3 and all(s in TARGET_ROOMS for s in held_out)
    assert len({max(s.size[:2]) for s in held_out}) == 3  # spread over sizes
    assert min(max(s.size[:2]) for s in SUITE) <= 3.5 and max(max(s.size[:2]) for s in SUITE) >= 9.0
    assert all(2.4 <= s.size[2] <= 3.2 for s in SUITE)
    assert any(s.n_views <= 20 for s in SUITE) and any(s.n_views >= 150 for s in SUITE)
    assert any((s.width, s.height) == (640, 480) for s in SUITE)
    assert {s.texture for s in SUITE} == {"plain", "mixed", "busy"}
    assert {s.path for s in SUITE} == {"walk", "orbit", "handheld"}
    assert {s.furniture for s in SUITE} >= {4, 10} and min(s.furniture for s in SUITE) >= 2
    ids = [c.id for c in SUITE_CLASSES]
    assert len(set(ids)) == len(ids) and BACKGROUND_ID not in ids and ids != list(range(min(ids), max(ids) + 1))


def test_suite_spec_lookup():
    assert suite_spec("office-5x4") is next(s for s in SUITE if s.name == "office-5x4")
    with pytest.raises(InputError, match="hall-10x6"):
        suite_spec("no-such-room")
    with pytest.raises(InputError):
        suite_geometry(dataclasses.replace(SUITE[0], texture="shiny"))


def test_geometry_deterministic():
    for spec in SUITE[:4]:
        assert suite_geometry(spec).boxes == suite_geometry(spec).boxes


def test_geometry_valid(rooms):
    against_wall = free = 0
    for spec, scene, _ in rooms.values():
        sx, sy, h = spec.size
        assert sorted(b.part for b in scene.boxes if b.part in STRUCTURAL_PARTS) == sorted(STRUCTURAL_PARTS)
        furniture = [b for b in scene.boxes if _piece(b) is not None]
        assert len({_piece(b) for b in furniture}) == spec.furniture, spec.name
        assert {b.class_id for b in scene.boxes} <= VOCAB
        for b in scene.boxes:
            assert all(lo < hi for lo, hi in zip(b.lo, b.hi)), (spec.name, b)
        for b in furniture:
            inside = np.all(np.array(b.lo) >= -1e-9) and np.all(np.array(b.hi) <= np.array([sx, sy, h]) + 1e-9)
            assert inside, (spec.name, b)
        for i, a in enumerate(furniture):
            for b in furniture[i + 1 :]:
                if _piece(a) != _piece(b):
                    overlap = all(min(a.hi[k], b.hi[k]) - max(a.lo[k], b.lo[k]) > 1e-9 for k in range(3))
                    assert not overlap, (spec.name, a.part, b.part)
        thin = [b for b in furniture if min(hi - lo for lo, hi in zip(b.lo, b.hi)) <= 0.05]
        assert thin, f"{spec.name} has no thin part"
        for piece in {_piece(b) for b in furniture}:
            lo = np.min([b.lo for b in furniture if _piece(b) == piece], axis=0)
            hi = np.max([b.hi for b in furniture if _piece(b) == piece], axis=0)
            near_wall = min(lo[0], lo[1], sx - hi[0], sy - hi[1]) <= 0.1
            against_wall += near_wall
            free += not near_wall
    assert against_wall > 2 * free > 0  # most pieces against walls, some free-standing


def test_textures_plain_to_busy(rooms):
    x = np.linspace(1.0, 2.0, 401)
    points = np.stack([x, np.zeros_like(x), np.full_like(x, 1.2)], -1)  # along the y- wall
    normals = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    for spec, scene, _ in rooms.values():
        wall = scene.textures[2](points, normals).mean(axis=1)
        assert np.all((wall >= 0) & (wall <= 1))
        if spec.texture == "plain":
            assert np.ptp(wall) < 0.03, spec.name
        if spec.texture == "busy":  # high frequency: the 1 m line crosses its mean >= 20 times (period <= 10 cm)
            assert np.ptp(wall) > 0.1 and np.sum(np.diff(np.sign(wall - wall.mean())) != 0) >= 20, spec.name


# ---------------------------------------------------------------- cameras


def test_cameras_valid(rooms):
    for spec, scene, c2ws in rooms.values():
        sx, sy, h = spec.size
        assert c2ws.shape == (spec.n_views, 4, 4)
        np.testing.assert_allclose(c2ws[:, 3], np.tile([0, 0, 0, 1.0], (spec.n_views, 1)))
        rot = c2ws[:, :3, :3]
        np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
        np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-9)
        eyes = c2ws[:, :3, 3]
        assert np.all((eyes > 0) & (eyes < [sx, sy, h])), spec.name
        assert np.all((eyes[:, 2] >= 1.0) & (eyes[:, 2] <= 1.8)), spec.name
        for b in scene.boxes:
            dist = np.linalg.norm(np.maximum(0, np.maximum(np.array(b.lo) - eyes, eyes - np.array(b.hi))), axis=1)
            assert dist.min() >= CAMERA_CLEARANCE, (spec.name, b.part)
        forward_z = -c2ws[:, 2, 2]
        assert forward_z.max() > 0.2 and forward_z.min() < -0.3, spec.name  # views tilt up and down
        steps = np.linalg.norm(np.diff(eyes[:, :2], axis=0, append=eyes[:1, :2]), axis=1)
        assert steps.max() < 4 * np.median(steps) + 0.2, spec.name  # one closed loop, no jumps


def test_cameras_deterministic(rooms):
    for name in ("studio-3x3", "living-6x5", "hall-10x6"):
        spec, scene, c2ws = rooms[name]
        np.testing.assert_array_equal(suite_cameras(spec, suite_geometry(spec)), c2ws)


def _cameras(spec: SuiteSpec, c2ws_opengl: np.ndarray) -> Cameras:
    """The views as the loaders give them (OpenCV axes), without near / far like a suite room's file."""
    f = _focal(spec.width)
    c2w_cv = opengl_to_opencv(c2ws_opengl)
    return Cameras.create(c2w_cv, f, f, spec.width / 2, spec.height / 2, spec.width, spec.height)


def test_suite_rooms_are_not_forward_facing_and_the_forward_rooms_are(rooms):
    """The preset "auto" gives a suite room the fast preset and a forward room what forward-facing
    cameras get (the voxels preset, or the fast one over a box where a room's layout is found): the
    cameras' rule (capture_reference) tells them apart."""
    for spec, _, c2ws in rooms.values():
        assert capture_reference(_cameras(spec, c2ws)) is None and not forward_rig(_cameras(spec, c2ws)), spec.name
    names = [s.name for s in SUITE + FORWARD_SUITE]
    assert len(set(names)) == len(names) and {s.path for s in FORWARD_SUITE} == {"forward"}
    assert any(s.tuning for s in FORWARD_SUITE) and any(not s.tuning for s in FORWARD_SUITE)
    for spec in FORWARD_SUITE:
        assert suite_spec(spec.name) is spec
        scene = suite_geometry(spec)
        c2ws = suite_cameras(spec, scene)
        assert c2ws.shape == (spec.n_views, 4, 4)
        np.testing.assert_array_equal(suite_cameras(spec, scene), c2ws)  # deterministic
        cameras = _cameras(spec, c2ws)
        assert capture_reference(cameras) is not None and forward_rig(cameras), spec.name
        eyes = c2ws[:, :3, 3]
        across = np.ptp(eyes[:, :2], axis=0).max()
        assert across <= 2 * RIG_HALF_WIDTH + 0.15 and np.ptp(eyes[:, :2], axis=0).min() <= 0.15, spec.name
        assert np.all((eyes[:, 2] >= RIG_HEIGHTS[0]) & (eyes[:, 2] <= RIG_HEIGHTS[1])), spec.name
        for b in scene.boxes:
            dist = np.linalg.norm(np.maximum(0, np.maximum(np.array(b.lo) - eyes, eyes - np.array(b.hi))), axis=1)
            assert dist.min() >= CAMERA_CLEARANCE, (spec.name, b.part)
        steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
        assert steps.max() <= 0.35, spec.name  # serpentine: a held-out view sits between its neighbours
        depth = _depth_maps(scene, c2ws, 16, 12)
        assert np.median(depth) >= 2.0, spec.name  # the cameras look across the room, not at a near wall
        _, far = near_far_or_fallback(cameras)  # the far fallback (no near/far given) reaches past the far walls
        assert 2 * depth.max() < far.min(), spec.name


def test_views_see_closed_room_with_vocabulary_labels(rooms):
    w, h = 20, 15
    for spec, scene, c2ws in rooms.values():
        picks = [0, spec.n_views // 3, 2 * spec.n_views // 3]
        f = _focal(w)
        for i in picks:
            o, d = pixel_rays(c2ws[i], f, f, w / 2, h / 2, w, h)
            hits = cast_rays(o.reshape(-1, 3), d.reshape(-1, 3), scene.boxes)
            assert hits.hit.all(), (spec.name, i)
            assert set(np.unique(hits.class_id).tolist()) <= set(scene.present_ids), (spec.name, i)
            assert np.median(hits.depth) > 1.0, (spec.name, i)  # looking across the room, not into a wall
    spec, scene, c2ws = rooms["office-5x4"]
    for i in (1, 2):
        rgb, labels, depth = render_view(scene, c2ws[i], _focal(32), _focal(32), 16, 12, 32, 24)
        assert np.all(depth > 0) and set(np.unique(labels).tolist()) <= VOCAB
        assert np.all((rgb >= 0) & (rgb <= 1))


# ---------------------------------------------------------------- writing


def test_write_scene_bounds_in_file(tmp_path):
    scene, c2ws = toy_scene_geometry(), toy_cameras(2)
    write_scene(tmp_path / "a", scene, c2ws, 8, 6)
    write_scene(tmp_path / "b", scene, c2ws, 8, 6, bounds_in_file=False)
    with_bounds = json.loads((tmp_path / "a" / "transforms.json").read_text())
    without = json.loads((tmp_path / "b" / "transforms.json").read_text())
    assert "aabb" in with_bounds and all("near" in fr and "far" in fr for fr in with_bounds["frames"])
    del with_bounds["aabb"]
    for fr in with_bounds["frames"]:
        del fr["near"], fr["far"]
    assert without == with_bounds
    for sub in ("images/000.png", "labels/001.png", "depths/001.npy"):
        assert (tmp_path / "a" / sub).read_bytes() == (tmp_path / "b" / sub).read_bytes()


def test_write_suite_scene_small(tmp_path):
    spec = dataclasses.replace(suite_spec("kitchen-4x3"), n_views=9, width=40, height=30)
    root = write_suite_scene(tmp_path / "kitchen", spec)
    assert root == tmp_path / "kitchen"
    tf = json.loads((root / "transforms.json").read_text())
    assert "aabb" not in tf and len(tf["frames"]) == 9
    assert not any("near" in fr or "far" in fr for fr in tf["frames"])
    assert (tf["w"], tf["h"]) == (40, 30)
    assert tf["fl_x"] == pytest.approx(_focal(40))
    classes = json.loads((root / "classes.json").read_text())
    assert {c["id"]: c["name"] for c in classes["classes"]} == {c.id: c.name for c in SUITE_CLASSES}
    assert classes["ignore_index"] == BACKGROUND_ID
    present = set(suite_geometry(spec).present_ids)
    for fr in tf["frames"]:
        assert (root / fr["file_path"]).is_file() and (root / fr["depth_path"]).is_file()
        labels = np.asarray(Image.open(root / fr["label_path"]))
        assert set(np.unique(labels).tolist()) <= present
        assert np.all(np.load(root / fr["depth_path"]) > 0)
    loaded = load_scene(root)
    assert len(loaded.cameras.near) == 9 and np.all(np.isnan(loaded.cameras.near))
    assert loaded.aabb is None
    with pytest.raises(InputError):
        write_suite_scene(tmp_path / "x", "no-such-room")


# ---------------------------------------------------------------- held-out views lie between training views


@pytest.mark.parametrize("spec", TARGET_ROOMS, ids=lambda s: s.name)
def test_holdout_pixels_seen_by_training_views(rooms, spec: SuiteSpec):
    """>= 97% of the held-out views' surface points (exact depth, 40x30) are visible in a training view."""
    _, scene, c2ws = rooms[spec.name]
    w, h = 40, 30
    f = _focal(w)
    depth = _depth_maps(scene, c2ws, w, h)
    test = [i for i in range(len(c2ws)) if i % HOLDOUT_EVERY == 0]
    train = [i for i in range(len(c2ws)) if i % HOLDOUT_EVERY]
    seen_total = count = 0
    for i in test:
        o, d = pixel_rays(c2ws[i], f, f, w / 2, h / 2, w, h)
        points = (o + d * depth[i][..., None]).reshape(-1, 3)
        seen = np.zeros(len(points), bool)
        for j in train:
            u, v, z = _project(c2ws[j], points, f, w, h)
            inside = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            ui = np.clip(np.where(inside, u, 0).astype(int), 0, w - 1)
            vi = np.clip(np.where(inside, v, 0).astype(int), 0, h - 1)
            dist = np.linalg.norm(points - c2ws[j][:3, 3], axis=1)
            seen |= inside & (np.abs(depth[j][vi, ui] - dist) <= 0.02 * dist + 0.02)
        seen_total += seen.sum()
        count += len(points)
    assert seen_total / count >= 0.97, f"{spec.name}: {seen_total / count:.4f}"
