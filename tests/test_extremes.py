"""Fields and training at the extremes: scene scale, class counts, sparse and missing labels."""

import json

import numpy as np
import pytest
from PIL import Image

from scenelabel import build, preset, write_toy_scene
from scenelabel.data.io import load_scene

pytestmark = pytest.mark.slow

STEPS = 60


def small_toy(path):
    return write_toy_scene(path, n_train=14, n_test=2, width=32, height=24)


def quick_config(**train):
    return preset("quick", {"train": {"steps": STEPS, **train}, "output": {"write_map": False, "write_renders": False}})


def scale_scene(root, s):
    """Multiply every length of a toy scene folder by s (poses, near/far, aabb, depth maps)."""
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    for frame in data["frames"]:
        m = np.array(frame["transform_matrix"])
        m[:3, 3] *= s
        frame["transform_matrix"] = m.tolist()
        frame["near"] *= s
        frame["far"] *= s
        depth_path = root / frame["depth_path"]
        np.save(depth_path, np.load(depth_path) * s)
    data["aabb"] = (np.array(data["aabb"]) * s).tolist()
    path.write_text(json.dumps(data))


def test_millimetres_to_kilometres_give_the_same_field_up_to_scale(tmp_path):
    results = {}
    for s in (1e-3, 1.0, 1e3):
        root = small_toy(tmp_path / f"s{s}")
        scale_scene(root, s)
        results[s] = build(root, tmp_path / f"out{s}", quick_config(), progress=False)
    ref = results[1.0]
    cam = load_scene(tmp_path / "s1.0").cameras
    ref_render = ref.field.render_camera(cam, 0)
    for s in (1e-3, 1e3):
        r = results[s]
        assert r.metrics["miou"] == pytest.approx(ref.metrics["miou"], abs=0.02)
        assert r.metrics["psnr"] == pytest.approx(ref.metrics["psnr"], abs=0.5)
        render = r.field.render_camera(load_scene(tmp_path / f"s{s}").cameras, 0)
        assert np.mean(render.label == ref_render.label) > 0.98
        hit = ref_render.opacity > 0.5
        np.testing.assert_allclose(render.depth[hit] / s, ref_render.depth[hit], rtol=0.02)
        assert r.field.occupancy_delta == pytest.approx(ref.field.occupancy_delta * s, rel=1e-6)
        q_ref = ref.field.query_points([[0.0, 0.0, 0.3]])
        q = r.field.query_points([[0.0, 0.0, 0.3 * s]])
        assert q.occupancy[0] == pytest.approx(q_ref.occupancy[0], abs=0.05)


def rewrite_labels(root, fn):
    """Apply fn(view index, label array) -> label array to every label PNG (8-bit)."""
    for i, path in enumerate(sorted((root / "labels").glob("*.png"))):
        Image.fromarray(fn(i, np.array(Image.open(path))).astype(np.uint8)).save(path)


def write_classes(root, ids, ignore_index=255):
    classes = [{"id": int(i), "name": f"class_{i}"} for i in ids]
    (root / "classes.json").write_text(json.dumps({"classes": classes, "ignore_index": ignore_index}))


def assert_finite_build(result, n_classes):
    assert all(np.isfinite(h["loss"]) for h in result.metrics["history"])
    assert result.field.class_map.num_classes == n_classes
    points = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    q = result.field.query_points(points)
    inside = result.field._inside(points)  # outside the bounds probs are 0 (label FREE or UNKNOWN)
    np.testing.assert_allclose(q.probs[inside].sum(-1), 1.0, atol=1e-6)
    assert q.probs.shape[1] == n_classes


def test_one_class(tmp_path):
    root = small_toy(tmp_path / "one")
    rewrite_labels(root, lambda i, lab: np.where(lab == 255, 255, 0))
    write_classes(root, [0])
    result = build(root, tmp_path / "out", quick_config(), progress=False)
    assert_finite_build(result, 1)
    assert result.metrics["miou"] == pytest.approx(1.0, abs=0.05)


def test_255_classes(tmp_path):
    root = small_toy(tmp_path / "many")
    rng = np.random.default_rng(0)
    rewrite_labels(root, lambda i, lab: np.where(lab == 255, 255, rng.integers(0, 255, lab.shape)))
    write_classes(root, range(255))
    result = build(root, tmp_path / "out", quick_config(), progress=False)
    assert_finite_build(result, 255)


def test_class_in_one_view_and_views_with_only_ignore(tmp_path):
    root = small_toy(tmp_path / "sparse")

    def edit(i, lab):
        if i == 3:  # a class that only this training view shows
            lab = lab.copy()
            lab[:4, :4] = 9
        if i in (5, 6):  # every pixel ignore_index
            lab = np.full_like(lab, 255)
        return lab

    rewrite_labels(root, edit)
    data = json.loads((root / "classes.json").read_text())
    data["classes"].append({"id": 9, "name": "rare"})
    (root / "classes.json").write_text(json.dumps(data))
    result = build(root, tmp_path / "out", quick_config(), progress=False)
    assert 9 in result.field.class_ids.tolist()
    assert_finite_build(result, 4)
