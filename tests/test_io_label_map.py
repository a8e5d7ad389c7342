"""label_map.json: vocabulary reduction with external ids preserved."""

import json
import shutil

import numpy as np
import pytest

from scenelabel import ClassMap, InputError, load_scene, write_toy_scene
from scenelabel.data.io.label_map import map_ids

BOX = 10  # target id of "box": both toy boxes (source ids 3 and 7)


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("lm") / "scene", n_train=6, n_test=1, width=24, height=18)


def _write_map(root, data):
    (root / "label_map.json").write_text(json.dumps(data))


def test_map_ids_reference_loop():
    rng = np.random.default_rng(0)
    labels = rng.integers(-1, 160, (40, 30))
    mapping = {int(k): int(v) for k, v in zip(rng.choice(150, 40, replace=False), rng.integers(0, 5, 40))}
    got = map_ids(labels, mapping, 255)
    ref = np.array([[mapping.get(int(x), 255) if x >= 0 else -1 for x in row] for row in labels])  # FREE stays
    np.testing.assert_array_equal(got, ref)


def test_label_map_merges_classes_and_keeps_external_ids(toy, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(toy, root)
    raw = load_scene(root)
    _write_map(root, {
        "classes": [{"id": 1, "name": "floor"}, {"id": BOX, "name": "box", "color": [200, 0, 200]}],
        "map": {"1": 1, "3": BOX, "7": BOX},
    })
    scene = load_scene(root)
    assert scene.classes == {1: "floor", BOX: "box"}
    assert scene.info["class_colors"] == {BOX: (200, 0, 200)}
    for before, after in zip(raw.labels, scene.labels):
        np.testing.assert_array_equal(after[before == 1], 1)
        np.testing.assert_array_equal(after[(before == 3) | (before == 7)], BOX)
        np.testing.assert_array_equal(after[before == raw.ignore_index], scene.ignore_index)
    class_map = ClassMap.from_labels(scene.labels, scene.classes, scene.ignore_index)
    assert class_map.ids.tolist() == [1, BOX]  # two channels, external ids kept
    lab = scene.labels[0]
    labelled = lab != scene.ignore_index
    np.testing.assert_array_equal(class_map.ids_from_channels(class_map.channels_from_ids(lab))[labelled], lab[labelled])


def test_unmapped_source_ids_become_unlabelled(toy, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(toy, root)
    _write_map(root, {"classes": [{"id": 0, "name": "box"}], "map": {"3": 0}, "ignore_index": 99})
    scene = load_scene(root)
    values = set(np.unique(np.concatenate([lab.ravel() for lab in scene.labels])).tolist())
    assert values <= {0, 99} and scene.ignore_index == 99


@pytest.mark.parametrize(
    "data,field",
    [
        ({"classes": [{"id": 1, "name": "floor"}], "map": {"1": 2}}, "$.map['1']"),
        ({"classes": [{"id": 1, "name": "floor"}], "map": {"42": 1}}, "$.map"),
        ({"classes": [{"id": 255, "name": "x"}], "map": {"1": 255}}, "$.ignore_index"),
        ({"classes": [{"id": 1, "name": "floor"}], "map": {"one": 1}}, "$.map"),
        ({"classes": [{"id": 1, "name": "floor"}]}, "$"),
    ],
)
def test_bad_label_maps_name_the_file_and_field(toy, tmp_path, data, field):
    root = tmp_path / "scene"
    shutil.copytree(toy, root)
    _write_map(root, data)
    with pytest.raises(InputError) as info:
        load_scene(root)
    assert "label_map.json" in str(info.value) and info.value.field.startswith(field)
