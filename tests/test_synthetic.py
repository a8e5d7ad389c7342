"""The analytic synthetic scenes: exact ray hits, consistent labels/depth, OpenGL poses, determinism."""

import json

import numpy as np
from PIL import Image

from scenelabel.synthetic import TOY_BOXES, cast_rays, toy_scene_geometry, write_toy_scene


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
