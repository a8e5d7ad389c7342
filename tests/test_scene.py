"""ClassMap id <-> channel mapping (example-based and property-based) and Cameras."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scenelabel.data.scene import ClassMap
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras

CLASSES = {0: "floor", 3: "box", 7: "wall", 200: "lamp"}


def test_only_present_classes_get_channels():
    labels = [np.array([[3, 255], [7, 7]]), None, np.array([[255, 3]])]
    cm = ClassMap.from_labels(labels, CLASSES, ignore_index=255)
    assert cm.ids.tolist() == [3, 7]
    assert cm.names == ("box", "wall")
    np.testing.assert_array_equal(cm.channels_from_ids(np.array([3, 7, 255, 0])), [0, 1, -1, -1])
    np.testing.assert_array_equal(cm.ids_from_channels(np.array([1, 0, -1, -2])), [7, 3, -1, -2])


def test_free_pixels_get_no_channel():
    """FREE (classes.json's free_index: the ray meets nothing) is no class: no channel, no loss."""
    labels = [np.array([[3, -1], [-1, 255]])]
    cm = ClassMap.from_labels(labels, CLASSES, ignore_index=255)
    assert cm.ids.tolist() == [3]
    np.testing.assert_array_equal(cm.channels_from_ids(labels[0]), [[0, -1], [-1, -1]])
    with pytest.raises(InputError, match="no labelled pixel"):
        ClassMap.from_labels([np.array([-1, 255])], CLASSES, ignore_index=255)


def test_unknown_label_id_and_no_labels_are_errors():
    with pytest.raises(InputError, match=r"label ids \[42\] are not in classes.json"):
        ClassMap.from_labels([np.array([42])], CLASSES)
    with pytest.raises(InputError, match="no labelled pixel"):
        ClassMap.from_labels([np.array([255])], CLASSES, ignore_index=255)


def test_one_class_and_255_classes():
    one = ClassMap.from_labels([np.zeros((4, 4), np.int64)], {0: "only"})
    assert one.num_classes == 1
    np.testing.assert_array_equal(one.channels_from_ids(np.zeros(3, np.int64)), 0)
    many = {i: f"c{i}" for i in range(255)}
    cm = ClassMap.from_labels([np.arange(255).reshape(15, 17)], many, ignore_index=255)
    assert cm.num_classes == 255
    np.testing.assert_array_equal(cm.ids_from_channels(cm.channels_from_ids(np.arange(255))), np.arange(255))


@given(
    ids=st.lists(st.integers(0, 32767), min_size=1, max_size=60, unique=True),
    queries=st.lists(st.integers(-5, 40000), max_size=50),
)
def test_round_trip_property(ids, queries):
    cm = ClassMap(ids=np.array(sorted(ids)), names=tuple(f"c{i}" for i in sorted(ids)))
    q = np.array(queries, np.int64)
    ch = cm.channels_from_ids(q)
    known = np.isin(q, ids)
    np.testing.assert_array_equal(ch >= 0, known)
    np.testing.assert_array_equal(cm.ids_from_channels(ch)[known], q[known])
    assert ClassMap.from_dict(cm.to_dict()).ids.tolist() == cm.ids.tolist()


def test_cameras_shape_checks_and_indexing():
    cams = Cameras.create(np.stack([np.eye(4)] * 3), 10.0, 10.0, 5.0, 5.0, 10, 10)
    assert len(cams) == 3 and len(cams[1:]) == 2 and len(cams[0]) == 1
    assert np.all(np.isnan(cams.near))
    with pytest.raises(InputError, match="c2w"):
        Cameras.create(np.eye(3), 1, 1, 1, 1, 1, 1)


def _scene(aabb=True):
    from pathlib import Path

    from scenelabel.data.scene import Scene

    rng = np.random.default_rng(0)
    c2w = np.stack([np.eye(4)] * 3)
    c2w[:, :3, 3] = rng.normal(size=(3, 3))
    c2w[1, :3, :3] = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    cams = Cameras.create(c2w, [10.0, 11, 12], 10.0, 5.0, 4.0, 10, 8, distortion=[0.1, 0, 0, 0], near=[0.5, 0.6, np.nan], far=[4.0, 5.0, np.nan])
    images = [rng.uniform(size=(8, 10, 3)).astype(np.float32) for _ in range(3)]
    labels = [np.zeros((8, 10), np.int64), None, np.ones((8, 10), np.int64)]
    depths = [rng.uniform(1, 3, (8, 10)).astype(np.float32), None, rng.uniform(1, 3, (8, 10)).astype(np.float32)]
    return Scene(
        root=Path("/nowhere"),
        cameras=cams,
        names=["a", "b", "c"],
        images=images,
        labels=labels,
        depths=depths,
        classes={0: "floor", 1: "wall"},
        ignore_index=255,
        aabb=np.array([[-1.0, -2, -3], [1, 2, 3]]) if aabb else None,
        frame_id="lab",
        info={"source": "test"},
    )


def test_scene_scaled_multiplies_lengths_only():
    scene = _scene()
    before_c2w = scene.cameras.c2w.copy()
    scaled = scene.scaled(2.0)
    np.testing.assert_array_equal(scaled.cameras.centres, 2.0 * scene.cameras.centres)
    np.testing.assert_array_equal(scaled.cameras.c2w[:, :3, :3], scene.cameras.c2w[:, :3, :3])
    np.testing.assert_array_equal(scaled.cameras.c2w[:, 3], scene.cameras.c2w[:, 3])
    np.testing.assert_array_equal(scaled.cameras.near, 2.0 * scene.cameras.near)  # NaN stays NaN
    np.testing.assert_array_equal(scaled.cameras.far, 2.0 * scene.cameras.far)
    for name in ("fx", "fy", "cx", "cy", "width", "height", "distortion"):
        np.testing.assert_array_equal(getattr(scaled.cameras, name), getattr(scene.cameras, name))
    for a, b in zip(scaled.images, scene.images):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(scaled.labels, scene.labels):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
    for a, b in zip(scaled.depths, scene.depths):
        assert (a is None) == (b is None)
        if a is not None:
            assert a.dtype == np.float32
            np.testing.assert_allclose(a, 2.0 * b, rtol=1e-7)
    np.testing.assert_array_equal(scaled.aabb, 2.0 * scene.aabb)
    assert scaled.names == scene.names and scaled.classes == scene.classes
    assert scaled.ignore_index == 255 and scaled.frame_id == "lab" and scaled.root == scene.root
    assert scaled.info == {"source": "test", "world_scale": 2.0}
    # the original is untouched
    np.testing.assert_array_equal(scene.cameras.c2w, before_c2w)
    assert "world_scale" not in scene.info and scene.aabb[1, 2] == 3.0
    # repeated calls multiply
    twice = scaled.scaled(0.25)
    assert twice.info["world_scale"] == 0.5
    np.testing.assert_allclose(twice.cameras.centres, 0.5 * scene.cameras.centres)
    np.testing.assert_allclose(twice.aabb, 0.5 * scene.aabb)
    assert _scene(aabb=False).scaled(3.0).aabb is None


@pytest.mark.parametrize("factor", [0.0, -1.0, float("nan"), float("inf"), -float("inf")])
def test_scene_scaled_rejects_bad_factors(factor):
    with pytest.raises(InputError, match="scale must be a positive finite number"):
        _scene().scaled(factor)


def test_unlabelled_class_map():
    cm = ClassMap.unlabelled()
    assert cm.ids.tolist() == [0] and cm.names == ("unlabelled",) and cm.num_classes == 1
    assert cm.ignore_index is None
    np.testing.assert_array_equal(cm.ids_from_channels(np.array([0, -1, -2])), [0, -1, -2])
    again = ClassMap.from_dict(cm.to_dict())
    assert again.ids.tolist() == [0] and again.names == ("unlabelled",) and again.ignore_index is None
