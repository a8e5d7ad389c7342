"""Shared reading helpers (scenelabel.data.io.common) and the load_scene dispatcher."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scenelabel import write_toy_scene
from scenelabel.codes import FREE
from scenelabel.data.io import load_scene
from scenelabel.data.io.common import (
    check_downscale,
    check_pose,
    load_json,
    read_classes,
    read_depth,
    read_image,
    read_label,
    resize_area,
    resize_nearest,
    resolve_image_path,
    validate_json,
)
from scenelabel.errors import InputError


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------------------------------------
# images


def test_read_image_rgb_scaled_to_unit_range(tmp_path: Path) -> None:
    pixels = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3) * 10
    Image.fromarray(pixels).save(tmp_path / "a.png")
    image = read_image(tmp_path / "a.png")
    assert image.dtype == np.float32 and image.shape == (2, 3, 3)
    np.testing.assert_allclose(image, pixels / 255.0, atol=1e-7)


def test_read_image_drops_alpha_without_compositing(tmp_path: Path) -> None:
    rgba = np.zeros((2, 2, 4), dtype=np.uint8)
    rgba[..., 0] = 200
    rgba[..., 3] = 0  # fully transparent: compositing onto white would give 1.0 in G and B
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    image = read_image(tmp_path / "a.png")
    assert image.shape == (2, 2, 3)
    np.testing.assert_allclose(image[..., 0], 200 / 255.0, atol=1e-7)
    np.testing.assert_array_equal(image[..., 1:], 0.0)


def test_read_image_grayscale_8_and_16_bit(tmp_path: Path) -> None:
    Image.fromarray(np.full((2, 2), 51, np.uint8)).save(tmp_path / "g8.png")
    Image.fromarray(np.full((2, 2), 65535, np.uint16)).save(tmp_path / "g16.png")
    np.testing.assert_allclose(read_image(tmp_path / "g8.png"), 0.2, atol=1e-6)
    np.testing.assert_allclose(read_image(tmp_path / "g16.png"), 1.0, atol=1e-6)
    assert read_image(tmp_path / "g16.png").shape == (2, 2, 3)


def test_read_image_downscale_is_area_mean(tmp_path: Path) -> None:
    pixels = np.random.default_rng(0).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "a.png")
    image = read_image(tmp_path / "a.png", size=(3, 2))
    expected = (pixels / 255.0).reshape(2, 2, 3, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(image, expected, atol=1e-6)


def test_truncated_image_names_the_file(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((64, 64, 3), np.uint8) + 7).save(tmp_path / "broken.png")
    data = (tmp_path / "broken.png").read_bytes()
    (tmp_path / "broken.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="broken.png.*(unreadable|truncated)"):
        read_image(tmp_path / "broken.png")


def test_not_an_image_names_the_file(tmp_path: Path) -> None:
    (tmp_path / "notes.jpg").write_text("hello")
    with pytest.raises(InputError, match="notes.jpg.*cannot read the image"):
        read_image(tmp_path / "notes.jpg")


def test_resolve_image_path_tries_extensions(tmp_path: Path) -> None:
    (tmp_path / "train").mkdir()
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "train" / "r_0.png")
    assert resolve_image_path(tmp_path, "./train/r_0") == tmp_path / "train" / "r_0.png"
    assert resolve_image_path(tmp_path, "train/r_1") is None
    assert resolve_image_path(tmp_path, "train/r_0.jpg") is None


# ---------------------------------------------------------------------------------------------
# labels and depths


def test_read_label_16_bit_true_values(tmp_path: Path) -> None:
    ids = np.array([[0, 300], [32767, 65535]], dtype=np.uint16)
    Image.fromarray(ids).save(tmp_path / "l.png")
    label = read_label(tmp_path / "l.png", (2, 2))
    assert label.dtype == np.int64
    np.testing.assert_array_equal(label, ids.astype(np.int64))


def test_read_label_palette_gives_indices(tmp_path: Path) -> None:
    image = Image.fromarray(np.array([[0, 1], [2, 5]], np.uint8), "L").convert("P")
    image.putpalette([v for i in range(256) for v in (i * 3 % 256, 0, 0)])
    image.save(tmp_path / "p.png")
    np.testing.assert_array_equal(read_label(tmp_path / "p.png", (2, 2)), [[0, 1], [2, 5]])


def test_read_label_rejects_rgb_and_jpeg(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(InputError, match="rgb.png.*single-channel.*RGB"):
        read_label(tmp_path / "rgb.png", (2, 2))
    Image.fromarray(np.zeros((2, 2), np.uint8)).save(tmp_path / "lossy.jpg")
    with pytest.raises(InputError, match="lossy.jpg.*PNG"):
        read_label(tmp_path / "lossy.jpg", (2, 2))


def test_read_label_size_mismatch_names_both_sizes(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((3, 5), np.uint8)).save(tmp_path / "l.png")
    with pytest.raises(InputError, match=r"l.png.*5x3.*4x2"):
        read_label(tmp_path / "l.png", (4, 2))


def test_resize_nearest_picks_pixel_containing_the_centre() -> None:
    array = np.arange(16).reshape(4, 4)
    # new pixel j covers old [2j, 2j + 2); its centre 2j + 1 lies in old pixel 2j + 1
    np.testing.assert_array_equal(resize_nearest(array, 2, 2), [[5, 7], [13, 15]])
    assert resize_nearest(array, 4, 4) is array


def test_resize_area_keeps_size_identity() -> None:
    image = np.ones((3, 4, 3), np.float32)
    assert resize_area(image, 4, 3) is image


def test_read_depth_shape_and_mismatch(tmp_path: Path) -> None:
    depth = np.linspace(1, 2, 12, dtype=np.float32).reshape(3, 4)
    np.save(tmp_path / "d.npy", depth)
    np.testing.assert_array_equal(read_depth(tmp_path / "d.npy", (4, 3)), depth)
    with pytest.raises(InputError, match=r"d.npy.*\[3, 4\].*\[4, 3\]"):
        read_depth(tmp_path / "d.npy", (3, 4))


# ---------------------------------------------------------------------------------------------
# JSON, classes


def test_load_json_syntax_error_has_line(tmp_path: Path) -> None:
    (tmp_path / "x.json").write_text('{"a": 1,\n "b": }')
    with pytest.raises(InputError, match=r"x.json.*invalid JSON.*line 2"):
        load_json(tmp_path / "x.json")


def test_validate_json_reports_json_path(tmp_path: Path) -> None:
    data = {"classes": [{"id": 0, "name": "floor"}, {"id": "wall", "name": "wall"}]}
    with pytest.raises(InputError, match=r"c.json \[\$\.classes\[1\]\.id\].*'wall' is not of type 'integer'"):
        validate_json(data, "classes", tmp_path / "c.json")


def test_validate_json_rejects_nan(tmp_path: Path) -> None:
    data = {"frames": [{"file_path": "a.png", "transform_matrix": [[1, 0, 0, float("nan")]] * 4}]}
    with pytest.raises(InputError, match=r"t.json \[\$\.frames\[0\]\.transform_matrix\[0\]\[3\]\].*non-finite"):
        validate_json(data, "transforms", tmp_path / "t.json")


def _write_classes(folder: Path, data: dict) -> Path:
    path = folder / "classes.json"
    path.write_text(json.dumps(data))
    return path


def test_read_classes_valid(tmp_path: Path) -> None:
    path = _write_classes(
        tmp_path, {"classes": [{"id": 0, "name": "floor", "color": [1, 2, 3]}, {"id": 7, "name": "chair"}], "ignore_index": 255}
    )
    parsed = read_classes(path)
    assert parsed.classes == {0: "floor", 7: "chair"}
    assert parsed.ignore_index == 255
    assert parsed.colors == {0: (1, 2, 3)}
    assert read_classes(_write_classes(tmp_path, {"classes": [{"id": 1, "name": "a"}]})).ignore_index is None
    with_free = {"classes": [{"id": 1, "name": "a"}], "free_index": 0}
    assert read_classes(_write_classes(tmp_path, with_free)).free_index == 0


def test_free_index_pixels_load_as_free(tmp_path: Path) -> None:
    """classes.json's free_index (the toy's backdrop, 255, here) is read as FREE; the class ids stay."""
    scene = write_toy_scene(tmp_path / "toy", n_train=7, n_test=1, width=24, height=18)
    original = load_scene(scene)
    data = json.loads((scene / "classes.json").read_text())
    _write_classes(scene, {**data, "ignore_index": None, "free_index": 255})
    loaded = load_scene(scene)
    assert loaded.ignore_index is None
    for before, after in zip(original.labels, loaded.labels):
        np.testing.assert_array_equal(after, np.where(before == 255, FREE, before))
    assert any(np.any(label == FREE) for label in loaded.labels)


@pytest.mark.parametrize(
    "data, pattern",
    [
        ({"classes": [{"id": 0, "name": "a"}, {"id": 0, "name": "b"}]}, r"\[\$\.classes\[1\]\.id\].*appears twice"),
        ({"classes": [{"id": 255, "name": "a"}], "ignore_index": 255}, r"ignore_index 255 is also a class id"),
        ({"classes": [{"id": 0, "name": "a"}], "free_index": 0}, r"free_index 0 is also a class id"),
        ({"classes": [{"id": 0, "name": "a"}], "ignore_index": 9, "free_index": 9},
         r"free_index 9 is also the ignore_index"),
        ({"classes": [{"id": 0}]}, r"\$\.classes\[0\].*'name' is a required property"),
        ({"classes": [{"id": 0, "name": "a", "color": [1, 2]}]}, r"\$\.classes\[0\]\.color.*too short"),
        ({"classes": [{"id": 40000, "name": "a"}]}, r"\$\.classes\[0\]\.id.*32767"),
        ({"labels": []}, r"'classes' is a required property"),
    ],
)
def test_read_classes_errors(tmp_path: Path, data: dict, pattern: str) -> None:
    with pytest.raises(InputError, match="classes.json.*" + pattern):
        read_classes(_write_classes(tmp_path, data))


# ---------------------------------------------------------------------------------------------
# poses, arguments


def _pose(rotation: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = [1.0, 2.0, 3.0]
    return pose


def test_check_pose_accepts_rigid_and_3x4() -> None:
    pose = _pose(_rotation_z(0.3))
    np.testing.assert_array_equal(check_pose(pose, Path("t.json"), "f"), pose)
    np.testing.assert_array_equal(check_pose(pose[:3], Path("t.json"), "f"), pose)


@pytest.mark.parametrize(
    "pose, pattern",
    [
        (_pose(_rotation_z(0.3) * 1.01), "not rigid"),
        (_pose(np.diag([1.0, 1.0, -1.0])), r"not rigid.*det R = -1"),
        (_pose(np.eye(3)) + np.diag([0.0, 0.0, 0.0, 1.0]), "bottom row"),
        (np.where(np.eye(4) == 1, np.inf, 0.0), "non-finite"),
        (np.eye(3), "4x4 or 3x4"),
    ],
)
def test_check_pose_errors_name_file_and_frame(pose: np.ndarray, pattern: str) -> None:
    with pytest.raises(InputError, match=r"t.json \[frame 3\].*" + pattern):
        check_pose(pose, Path("t.json"), "frame 3")


@pytest.mark.parametrize("value", [0, -2, 1.5, True, "2"])
def test_check_downscale_rejects(value) -> None:
    with pytest.raises(InputError, match="downscale"):
        check_downscale(value)


# ---------------------------------------------------------------------------------------------
# load_scene dispatch


def test_load_scene_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="nowhere.*scene folder not found"):
        load_scene(tmp_path / "nowhere")


def test_load_scene_unknown_folder_says_what_is_expected(tmp_path: Path) -> None:
    (tmp_path / "transforms_orig.json").write_text("{}")  # (split files transforms_train.json etc. load: test_splits.py)
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    message = str(info.value)
    for expected in (str(tmp_path), "transforms.json", "poses_bounds.npy", "COLMAP", "structure from motion", "transforms_orig.json"):
        assert expected in message


def _tiny_scene(folder: Path, width: int = 8, height: int = 6) -> None:
    """Two images plus both a transforms.json and a poses_bounds.npy."""
    (folder / "images").mkdir(parents=True)
    frames = []
    for i in range(2):
        Image.fromarray(np.full((height, width, 3), 40 * i, np.uint8)).save(folder / "images" / f"v{i}.png")
        pose = np.eye(4)
        pose[0, 3] = i
        frames.append({"file_path": f"images/v{i}.png", "transform_matrix": pose.tolist()})
    (folder / "transforms.json").write_text(json.dumps({"fl_x": 10.0, "frames": frames}))
    row = np.concatenate([np.hstack([np.eye(3), np.zeros((3, 1)), [[height], [width], [10.0]]]).ravel(), [1.0, 5.0]])
    np.save(folder / "poses_bounds.npy", np.stack([row, row]))


def test_load_scene_prefers_transforms_json_and_accepts_files(tmp_path: Path) -> None:
    _tiny_scene(tmp_path)
    assert load_scene(tmp_path).info["format"] == "transforms.json"
    assert load_scene(tmp_path / "transforms.json").info["format"] == "transforms.json"
    assert load_scene(tmp_path / "poses_bounds.npy").info["format"] == "llff"
    (tmp_path / "transforms.json").unlink()
    scene = load_scene(tmp_path, downscale=2)
    assert scene.info["format"] == "llff"
    assert scene.images[0].shape == (3, 4, 3)
