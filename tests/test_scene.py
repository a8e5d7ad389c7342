"""ClassMap id <-> channel mapping (example-based and property-based) and Cameras."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scenelabel.errors import InputError
from scenelabel.scene import Cameras, ClassMap

CLASSES = {0: "floor", 3: "box", 7: "wall", 200: "lamp"}


def test_only_present_classes_get_channels():
    labels = [np.array([[3, 255], [7, 7]]), None, np.array([[255, 3]])]
    cm = ClassMap.from_labels(labels, CLASSES, ignore_index=255)
    assert cm.ids.tolist() == [3, 7]
    assert cm.names == ("box", "wall")
    np.testing.assert_array_equal(cm.channels_from_ids(np.array([3, 7, 255, 0])), [0, 1, -1, -1])
    np.testing.assert_array_equal(cm.ids_from_channels(np.array([1, 0, -1, -2])), [7, 3, -1, -2])


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
