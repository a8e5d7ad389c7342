"""transforms.json loader: conventions (OpenGL -> OpenCV), intrinsics, labels, depth, errors."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from PIL import Image
from shared_data import DATA

from scenelabel.data.io import load_scene
from scenelabel.data.io.transforms_json import load_transforms
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import OPENGL_TO_OPENCV, opengl_to_opencv

FOX = DATA / "instant_ngp_fox"

WIDTH, HEIGHT = 8, 6


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues rotation matrix."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _opengl_pose(index: int) -> np.ndarray:
    """A known OpenGL camera-to-world: frame 0 has identity rotation (looks down world -z)."""
    pose = np.eye(4)
    pose[:3, :3] = _rotation([1.0, 2.0, 0.5], 0.4 * index)
    pose[:3, 3] = [0.5 * index, -1.0, 2.0 + index]
    return pose


def _image_pixels(index: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    rng = np.random.default_rng(index)
    return rng.integers(0, 256, (height, width, 3), dtype=np.uint8)


def make_scene(root: Path, n: int = 3, edit: Callable[[dict], None] | None = None, **top) -> Path:
    """Write a tiny transforms.json scene: n PNGs of WIDTH x HEIGHT, known poses, optional edits."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(n):
        Image.fromarray(_image_pixels(i)).save(root / "images" / f"f{i}.png")
        frames.append({"file_path": f"images/f{i}.png", "transform_matrix": _opengl_pose(i).tolist()})
    data = {"fl_x": 10.0, "fl_y": 11.0, "cx": 4.5, "cy": 2.5, "w": WIDTH, "h": HEIGHT, "frames": frames, **top}
    if edit is not None:
        edit(data)
    (root / "transforms.json").write_text(json.dumps(data))
    return root


def write_classes(root: Path, ids: list[int], ignore_index: int | None = 255) -> None:
    data = {"classes": [{"id": i, "name": f"class{i}"} for i in ids]}
    if ignore_index is not None:
        data["ignore_index"] = ignore_index
    (root / "classes.json").write_text(json.dumps(data))


def write_label(root: Path, stem: str, label: np.ndarray) -> Path:
    (root / "labels").mkdir(exist_ok=True)
    path = root / "labels" / f"{stem}.png"
    Image.fromarray(label).save(path)
    return path


def load_quiet(root: Path, downscale: int = 1):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a valid scene loads without warnings
        return load_scene(root, downscale=downscale)


# ---------------------------------------------------------------------------------------------
# conventions


def test_c2w_is_opengl_times_flip(tmp_path: Path) -> None:
    scene = load_quiet(make_scene(tmp_path))
    assert scene.info["format"] == "transforms.json"
    assert scene.names == ["f0", "f1", "f2"]
    for i in range(3):
        expected = _opengl_pose(i) @ np.diag([1.0, -1.0, -1.0, 1.0])
        np.testing.assert_allclose(scene.cameras.c2w[i], expected, atol=1e-12)
    np.testing.assert_array_equal(OPENGL_TO_OPENCV, np.diag([1.0, -1.0, -1.0, 1.0]))


def test_identity_opengl_camera_looks_down_world_minus_z(tmp_path: Path) -> None:
    c2w = load_quiet(make_scene(tmp_path)).cameras.c2w[0]
    np.testing.assert_allclose(c2w[:3, 0], [1, 0, 0])  # right stays right
    np.testing.assert_allclose(c2w[:3, 1], [0, -1, 0])  # OpenCV y (down) = world -y
    np.testing.assert_allclose(c2w[:3, 2], [0, 0, -1])  # OpenCV forward = world -z
    np.testing.assert_allclose(c2w[:3, 3], _opengl_pose(0)[:3, 3])  # centre unchanged
    np.testing.assert_allclose(opengl_to_opencv(np.eye(4))[:3, 2], [0, 0, -1])


def test_images_float_rgb(tmp_path: Path) -> None:
    scene = load_quiet(make_scene(tmp_path))
    assert scene.images[1].dtype == np.float32 and scene.images[1].shape == (HEIGHT, WIDTH, 3)
    np.testing.assert_allclose(scene.images[1], _image_pixels(1) / 255.0, atol=1e-7)
    assert scene.labels == [None] * 3 and scene.depths == [None] * 3 and scene.classes == {}


# ---------------------------------------------------------------------------------------------
# intrinsics


def test_intrinsics_globals_and_per_frame_override(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["frames"][1].update(fl_x=20.0, cx=3.0)
        data.update(k1=0.1, k2=-0.02, p1=0.001, p2=-0.003)
        data["frames"][2]["k1"] = 0.2

    cams = load_quiet(make_scene(tmp_path, edit=edit)).cameras
    np.testing.assert_array_equal(cams.fx, [10, 20, 10])
    np.testing.assert_array_equal(cams.fy, [11, 11, 11])
    np.testing.assert_array_equal(cams.cx, [4.5, 3.0, 4.5])
    np.testing.assert_array_equal(cams.cy, [2.5, 2.5, 2.5])
    np.testing.assert_array_equal(cams.width, [WIDTH] * 3)
    np.testing.assert_array_equal(cams.height, [HEIGHT] * 3)
    np.testing.assert_allclose(cams.distortion[0], [0.1, -0.02, 0.001, -0.003])
    np.testing.assert_allclose(cams.distortion[2], [0.2, -0.02, 0.001, -0.003])


def test_focal_from_camera_angle_and_defaults(tmp_path: Path) -> None:
    angle = 0.8

    def edit(data: dict) -> None:
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            del data[key]
        data["camera_angle_x"] = angle
        for frame in data["frames"]:  # nerf-synthetic: file paths without extension
            frame["file_path"] = "./" + frame["file_path"][: -len(".png")]

    cams = load_quiet(make_scene(tmp_path, edit=edit)).cameras
    expected = 0.5 * WIDTH / math.tan(0.5 * angle)
    np.testing.assert_allclose(cams.fx, expected)
    np.testing.assert_allclose(cams.fy, expected)  # fl_y falls back to fl_x
    np.testing.assert_allclose(cams.cx, WIDTH / 2)
    np.testing.assert_allclose(cams.cy, HEIGHT / 2)
    np.testing.assert_array_equal(cams.width, WIDTH)
    np.testing.assert_array_equal(cams.distortion, 0.0)


def test_downscale_scales_intrinsics_and_resamples(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    scene = load_quiet(root, downscale=2)
    cams = scene.cameras
    np.testing.assert_allclose(cams.fx, 5.0)
    np.testing.assert_allclose(cams.fy, 5.5)
    np.testing.assert_allclose(cams.cx, 2.25)  # cx / d under the +0.5 pixel-centre convention
    np.testing.assert_allclose(cams.cy, 1.25)
    np.testing.assert_array_equal(cams.width, WIDTH // 2)
    np.testing.assert_array_equal(cams.height, HEIGHT // 2)
    area_mean = (_image_pixels(0) / 255.0).reshape(HEIGHT // 2, 2, WIDTH // 2, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(scene.images[0], area_mean, atol=1e-6)
    assert scene.info["downscale"] == 2


# ---------------------------------------------------------------------------------------------
# extensions: near/far, aabb, frame_id


def test_near_far_aabb_frame_id(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["frames"][2].update(near=0.5, far=3.0)

    aabb = [[-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]]
    root = make_scene(tmp_path, edit=edit, near=0.1, far=8.0, aabb=aabb, frame_id="map", aabb_scale=4)
    scene = load_quiet(root)
    np.testing.assert_array_equal(scene.cameras.near, [0.1, 0.1, 0.5])
    np.testing.assert_array_equal(scene.cameras.far, [8.0, 8.0, 3.0])
    np.testing.assert_array_equal(scene.aabb, aabb)
    assert scene.frame_id == "map"


def test_near_far_absent_is_nan(tmp_path: Path) -> None:
    scene = load_quiet(make_scene(tmp_path))
    assert np.all(np.isnan(scene.cameras.near)) and np.all(np.isnan(scene.cameras.far))
    assert scene.aabb is None and scene.frame_id == "world"


# ---------------------------------------------------------------------------------------------
# labels and depth


def test_labels_8_bit_with_unlabelled_view(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    write_classes(root, [0, 3, 7], ignore_index=255)
    label = np.zeros((HEIGHT, WIDTH), np.uint8)
    label[:, 4:] = 7
    label[0, 0] = 255
    write_label(root, "f0", label)
    write_label(root, "f2", np.full((HEIGHT, WIDTH), 3, np.uint8))
    scene = load_quiet(root)
    assert scene.classes == {0: "class0", 3: "class3", 7: "class7"} and scene.ignore_index == 255
    assert scene.labels[0].dtype == np.int64
    np.testing.assert_array_equal(scene.labels[0], label)
    assert scene.labels[1] is None  # no label file: photometric only
    np.testing.assert_array_equal(scene.labels[2], 3)
    assert scene.info["labelled_views"] == 2


def test_labels_16_bit_and_downscale_nearest(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    write_classes(root, [300, 1000, 32767], ignore_index=65535)
    label = np.full((HEIGHT, WIDTH), 300, np.uint16)
    label[:, 2:4] = 1000
    label[:, 4:6] = 32767
    label[:, 6:] = 65535
    write_label(root, "f1", label)
    scene = load_quiet(root)
    np.testing.assert_array_equal(scene.labels[1], label.astype(np.int64))
    small = load_quiet(root, downscale=2)
    # nearest: output column j takes input column 2j + 1
    np.testing.assert_array_equal(small.labels[1], np.tile([300, 1000, 32767, 65535], (HEIGHT // 2, 1)))


def test_explicit_label_path(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["frames"][0]["label_path"] = "masks/first.png"

    root = make_scene(tmp_path, edit=edit)
    (root / "masks").mkdir()
    Image.fromarray(np.full((HEIGHT, WIDTH), 2, np.uint8)).save(root / "masks" / "first.png")
    write_classes(root, [2], ignore_index=None)
    scene = load_quiet(root)
    np.testing.assert_array_equal(scene.labels[0], 2)
    assert scene.labels[1] is None and scene.ignore_index is None


def test_class_colors_in_info(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    (root / "classes.json").write_text(json.dumps({"classes": [{"id": 1, "name": "wall", "color": [9, 8, 7]}]}))
    scene = load_quiet(root)
    assert scene.classes == {1: "wall"} and scene.info["class_colors"] == {1: (9, 8, 7)}


def test_depth(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["frames"][1]["depth_path"] = "depth/f1.npy"

    root = make_scene(tmp_path, edit=edit)
    (root / "depth").mkdir()
    depth = np.arange(HEIGHT * WIDTH, dtype=np.float32).reshape(HEIGHT, WIDTH) / 10
    np.save(root / "depth" / "f1.npy", depth)
    scene = load_quiet(root)
    assert scene.depths[0] is None
    assert scene.depths[1].dtype == np.float32
    np.testing.assert_array_equal(scene.depths[1], depth)
    np.testing.assert_array_equal(load_quiet(root, downscale=2).depths[1], depth[1::2, 1::2])


# ---------------------------------------------------------------------------------------------
# missing frames


def test_missing_frames_skipped_with_one_counting_warning(tmp_path: Path) -> None:
    root = make_scene(tmp_path, n=4)
    (root / "images" / "f2.png").unlink()
    with pytest.warns(UserWarning, match=r"1 of 4 frames in transforms.json have no image file; skipped") as record:
        scene = load_scene(root)
    assert len(record) == 1
    assert scene.names == ["f0", "f1", "f3"]
    np.testing.assert_allclose(scene.cameras.c2w[2], opengl_to_opencv(_opengl_pose(3)))
    assert scene.info["skipped_frames"] == 1 and scene.info["frames_listed"] == 4


def test_fewer_than_two_views(tmp_path: Path) -> None:
    root = make_scene(tmp_path, n=3)
    (root / "images" / "f0.png").unlink()
    (root / "images" / "f1.png").unlink()
    with pytest.warns(UserWarning, match="2 of 3 frames"):
        with pytest.raises(InputError, match=r"transforms.json.*only 1 of 3 frames.*at least 2 views"):
            load_scene(root)


# ---------------------------------------------------------------------------------------------
# bad inputs: every error is an InputError naming the file and the problem


def _set(frame: int, **values) -> Callable[[dict], None]:
    def edit(data: dict) -> None:
        data["frames"][frame].update(values)

    return edit


def _scaled_pose(data: dict) -> None:
    pose = np.array(data["frames"][1]["transform_matrix"])
    pose[:3, :3] *= 1.1
    data["frames"][1]["transform_matrix"] = pose.tolist()


def _mirrored_pose(data: dict) -> None:
    pose = np.array(data["frames"][2]["transform_matrix"])
    pose[:3, 0] *= -1
    data["frames"][2]["transform_matrix"] = pose.tolist()


def _nan_pose(data: dict) -> None:
    data["frames"][0]["transform_matrix"][1][3] = float("nan")


def _duplicate(data: dict) -> None:
    data["frames"][2]["file_path"] = "./images/f0.png"


def _drop(key: str) -> Callable[[dict], None]:
    def edit(data: dict) -> None:
        del data[key]

    return edit


def _drop_focal(data: dict) -> None:
    del data["fl_x"]


@pytest.mark.parametrize(
    "edit, pattern",
    [
        (_drop("frames"), r"'frames' is a required property"),
        (_set(0, transform_matrix=[[1, 0, 0, 0]]), r"\$\.frames\[0\]\.transform_matrix.*too short"),
        (_set(1, fl_x=-3.0), r"\$\.frames\[1\]\.fl_x.*minimum"),
        (_set(0, file_path=7), r"\$\.frames\[0\]\.file_path.*not of type 'string'"),
        (_nan_pose, r"\$\.frames\[0\]\.transform_matrix\[1\]\[3\].*non-finite"),
        (_scaled_pose, r"\$\.frames\[1\]\.transform_matrix.*not rigid"),
        (_mirrored_pose, r"\$\.frames\[2\]\.transform_matrix.*not rigid.*det R = -1"),
        (_duplicate, r"\$\.frames\[2\]\.file_path.*duplicate frame.*frames 0 and 2"),
        (_drop_focal, r"\$\.frames\[0\]\.fl_x.*no focal length"),
        (_set(0, near=2.0, far=1.0), r"\$\.frames\[0\].*near \(2.0\) must be smaller than far \(1.0\)"),
        (_set(1, k3=0.01), r"\$\.frames\[1\]\.k3.*only OpenCV k1, k2, p1, p2"),
        (_set(0, w=8.5), r"\$\.frames\[0\]\.w.*whole number"),
    ],
)
def test_bad_transforms_json(tmp_path: Path, edit: Callable[[dict], None], pattern: str) -> None:
    with pytest.raises(InputError, match=r"transforms.json.*" + pattern):
        load_scene(make_scene(tmp_path, edit=edit))


@pytest.mark.parametrize(
    "top, pattern",
    [
        ({"camera_model": "FISHEYE624"}, r"\$\.camera_model.*'FISHEYE624' is not supported; supported: .*OPENCV_FISHEYE"),
        ({"camera_model": "EQUIRECTANGULAR"}, r"\$\.camera_model.*not supported"),
        ({"is_fisheye": True, "camera_model": "OPENCV"}, r"\$\.is_fisheye.*'OPENCV' is a pinhole model"),
        ({"camera_model": "OPENCV_FISHEYE", "p1": 0.01}, r"\$\.p1.*an OpenCV fisheye has only k1, k2, k3, k4"),
        ({"aabb": [[0, 0, 0], [1, -1, 1]]}, r"\$\.aabb.*min corner must be below"),
        ({"aabb": [[0, 0, 0]]}, r"\$\.aabb.*too short"),
        ({"frame_id": 3}, r"\$\.frame_id.*not of type 'string'"),
    ],
)
def test_bad_top_level_keys(tmp_path: Path, top: dict, pattern: str) -> None:
    with pytest.raises(InputError, match=r"transforms.json.*" + pattern):
        load_scene(make_scene(tmp_path, **top))


def test_supported_camera_model_loads(tmp_path: Path) -> None:
    scene = load_quiet(make_scene(tmp_path, camera_model="OPENCV", k1=0.01))
    assert scene.info["camera_model"] == "OPENCV"
    assert scene.cameras.distortion[0, 0] == 0.01
    np.testing.assert_array_equal(scene.cameras.model, "pinhole")


FISHEYE_K = {"k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0005}


def test_opencv_fisheye_loads_k1_to_k4_with_per_frame_overrides(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["frames"][1].update(k3=0.003, fl_x=12.0)

    scene = load_quiet(make_scene(tmp_path, edit=edit, camera_model="OPENCV_FISHEYE", **FISHEYE_K))
    cams = scene.cameras
    assert scene.info["camera_model"] == "OPENCV_FISHEYE"
    np.testing.assert_array_equal(cams.model, ["fisheye"] * 3)
    np.testing.assert_array_equal(cams.distortion[0], [0.05, -0.01, 0.002, -0.0005])
    np.testing.assert_array_equal(cams.distortion[1], [0.05, -0.01, 0.003, -0.0005])
    np.testing.assert_array_equal(cams.fx, [10.0, 12.0, 10.0])


def test_is_fisheye_flag_means_opencv_fisheye(tmp_path: Path) -> None:
    cams = load_quiet(make_scene(tmp_path, is_fisheye=True, **FISHEYE_K)).cameras
    np.testing.assert_array_equal(cams.model, "fisheye")
    np.testing.assert_array_equal(cams.distortion, np.tile([0.05, -0.01, 0.002, -0.0005], (3, 1)))
    plain = load_quiet(make_scene(tmp_path / "plain", is_fisheye=False, k1=0.01)).cameras
    np.testing.assert_array_equal(plain.model, "pinhole")


def test_fisheye_downscale_keeps_coefficients(tmp_path: Path) -> None:
    root = make_scene(tmp_path, camera_model="OPENCV_FISHEYE", **FISHEYE_K)
    full, half = load_quiet(root).cameras, load_quiet(root, downscale=2).cameras
    np.testing.assert_array_equal(half.model, "fisheye")
    np.testing.assert_array_equal(half.distortion, full.distortion)  # they act on normalised coordinates
    np.testing.assert_allclose(half.fx, full.fx / 2)
    np.testing.assert_allclose(half.cx, full.cx / 2)


def test_invalid_json_syntax(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    (root / "transforms.json").write_text('{"frames": [}')
    with pytest.raises(InputError, match=r"transforms.json.*invalid JSON.*line 1"):
        load_scene(root)


def test_truncated_image(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    big = np.random.default_rng(0).integers(0, 256, (HEIGHT, WIDTH, 3), np.uint8)
    Image.fromarray(big).save(root / "images" / "f1.png")
    data = (root / "images" / "f1.png").read_bytes()
    (root / "images" / "f1.png").write_bytes(data[: len(data) - 30])
    with pytest.raises(InputError, match=r"f1.png.*(unreadable|truncated)"):
        load_scene(root)


def test_image_size_differs_from_intrinsics(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    Image.fromarray(np.zeros((HEIGHT, WIDTH + 2, 3), np.uint8)).save(root / "images" / "f2.png")
    with pytest.raises(InputError, match=r"f2.png.*image size 10x6 differs from the intrinsics w x h = 8x6"):
        load_scene(root)


def test_label_size_differs(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    write_classes(root, [0])
    write_label(root, "f0", np.zeros((HEIGHT + 1, WIDTH), np.uint8))
    with pytest.raises(InputError, match=r"f0.png.*label size 8x7 differs from the image size 8x6"):
        load_scene(root)


def test_label_ids_not_in_classes(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    write_classes(root, [0, 1], ignore_index=255)
    label = np.zeros((HEIGHT, WIDTH), np.uint8)
    label[0, :3] = [5, 9, 255]
    write_label(root, "f1", label)
    with pytest.raises(InputError, match=r"labels.f1.png.*label ids \[5, 9\] are not in classes.json"):
        load_scene(root)


def test_labels_without_classes_json(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    write_label(root, "f0", np.zeros((HEIGHT, WIDTH), np.uint8))
    with pytest.raises(InputError, match=r"classes.json.*label files were found but classes.json is missing"):
        load_scene(root)


def test_bad_classes_json(tmp_path: Path) -> None:
    root = make_scene(tmp_path)
    (root / "classes.json").write_text(json.dumps({"classes": [{"id": -1, "name": "x"}]}))
    write_label(root, "f0", np.zeros((HEIGHT, WIDTH), np.uint8))
    with pytest.raises(InputError, match=r"classes.json \[\$\.classes\[0\]\.id\].*minimum"):
        load_scene(root)


def test_missing_explicit_label_and_depth(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"transforms.json \[\$\.frames\[1\]\.label_path\].*'nope.png' not found"):
        load_scene(make_scene(tmp_path / "a", edit=_set(1, label_path="nope.png")))
    with pytest.raises(InputError, match=r"transforms.json \[\$\.frames\[0\]\.depth_path\].*'d.npy' not found"):
        load_scene(make_scene(tmp_path / "b", edit=_set(0, depth_path="d.npy")))


def test_depth_shape_mismatch(tmp_path: Path) -> None:
    root = make_scene(tmp_path, edit=_set(2, depth_path="f2_depth.npy"))
    np.save(root / "f2_depth.npy", np.ones((WIDTH, HEIGHT), np.float32))
    with pytest.raises(InputError, match=r"f2_depth.npy.*depth shape \[8, 6\] does not match the image: expected \[6, 8\]"):
        load_scene(root)


def test_bad_downscale(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="downscale.*integer >= 1"):
        load_transforms(make_scene(tmp_path), downscale=0)


# ---------------------------------------------------------------------------------------------
# real data: instant-ngp fox


@pytest.mark.skipif(not FOX.is_dir(), reason="shared data (../shared/data/instant_ngp_fox) not present")
def test_fox() -> None:
    with pytest.warns(UserWarning, match=r"17 of 67 frames in transforms.json have no image file; skipped") as record:
        scene = load_scene(FOX, downscale=8)
    assert len(record) == 1
    assert len(scene) == 50 and scene.info["skipped_frames"] == 17
    data = json.loads((FOX / "transforms.json").read_text())
    cams = scene.cameras
    np.testing.assert_array_equal(cams.width, 1080 // 8)
    np.testing.assert_array_equal(cams.height, 1920 // 8)
    np.testing.assert_allclose(cams.fx, data["fl_x"] / 8)
    np.testing.assert_allclose(cams.fy, data["fl_y"] / 8)
    np.testing.assert_allclose(cams.cx, data["cx"] / 8)
    np.testing.assert_allclose(cams.cy, data["cy"] / 8)
    np.testing.assert_allclose(cams.distortion, np.tile([0.0578421, -0.0805099, -0.000980296, 0.00015575], (50, 1)))
    first = next(f for f in data["frames"] if (FOX / f["file_path"]).is_file())
    assert scene.names[0] == Path(first["file_path"]).stem
    np.testing.assert_allclose(cams.c2w[0], np.array(first["transform_matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0]))
    assert scene.images[0].shape == (240, 135, 3) and scene.images[0].dtype == np.float32
    assert 0.0 <= scene.images[0].min() and scene.images[0].max() <= 1.0
    assert scene.labels == [None] * 50 and scene.classes == {}
