"""LLFF loader: pose conversion [down, right, back] -> OpenCV, image folders, intrinsics, real data."""

from __future__ import annotations

import dataclasses
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from shared_data import DATA, read_points3d_bin

from scenelabel.data.io import load_scene
from scenelabel.data.io.llff import choose_image_folder, llff_to_opencv, load_llff, read_poses_bounds
from scenelabel.errors import InputError
from scenelabel.geometry.frame import forward_rig, mean_optical_axis, near_far_or_fallback
from scenelabel.geometry.warps import capture_reference

FERN = DATA / "llff_fern"
ROOM = DATA / "llff_room_poses"

FERN_FOCAL = 3260.526  # poses_bounds.npy hwf focal at 4032 px wide (data README)
FERN_FULL_WIDTH = 4032
# all sparse points vs the points one view sees (images.bin is absent): percentiles agree to ~4%
BOUNDS_REL_TOLERANCE = 0.1


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _row(c2w_opencv: np.ndarray, hwf=(30.0, 40.0, 50.0), bounds=(1.0, 10.0)) -> np.ndarray:
    """An LLFF row built by hand from an OpenCV c2w: columns [down, right, back] = [y, x, -z]."""
    r = c2w_opencv[:3, :3]
    pose = np.column_stack([r[:, 1], r[:, 0], -r[:, 2], c2w_opencv[:3, 3], hwf])
    return np.concatenate([pose.ravel(), bounds])


def _c2w(index: int) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, :3] = _rotation([0.3, -1.0, 0.2], 0.25 * index + 0.1)
    c2w[:3, 3] = [index, 2.0, -0.5 * index]
    return c2w


def make_llff(root: Path, n: int = 3, folder: str = "images", size=(8, 6), hwf=(30.0, 40.0, 50.0)) -> Path:
    """A tiny LLFF scene: n images of size (w, h) in ``folder`` and matching poses_bounds.npy."""
    (root / folder).mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(n):
        pixels = np.random.default_rng(i).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
        Image.fromarray(pixels).save(root / folder / f"img{i:03d}.png")
        rows.append(_row(_c2w(i), hwf=hwf, bounds=(1.0 + i, 10.0 + i)))
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    r = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


# ---------------------------------------------------------------------------------------------
# conversion


def test_llff_identity_axes_by_hand() -> None:
    # LLFF R = I: camera down = world x, right = world y, back = world z
    pose = np.hstack([np.eye(3), [[1.0], [2.0], [3.0]]])
    expected = np.array(
        [
            # columns: OpenCV x (right) = world y, y (down) = world x, z (forward) = -back = world -z
            [0.0, 1.0, 0.0, 1.0],
            [1.0, 0.0, 0.0, 2.0],
            [0.0, 0.0, -1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    np.testing.assert_array_equal(llff_to_opencv(pose), expected)
    assert np.linalg.det(expected[:3, :3]) == pytest.approx(1.0)


def test_known_rows_load_as_expected_opencv_c2w(tmp_path: Path) -> None:
    scene = load_scene(make_llff(tmp_path))
    assert scene.info["format"] == "llff" and scene.names == ["img000", "img001", "img002"]
    for i in range(3):
        np.testing.assert_allclose(scene.cameras.c2w[i], _c2w(i), atol=1e-12)
    np.testing.assert_array_equal(scene.cameras.near, [1, 2, 3])
    np.testing.assert_array_equal(scene.cameras.far, [10, 11, 12])
    assert scene.aabb is None and scene.depths == [None] * 3 and scene.classes == {}


def test_intrinsics_scaled_to_actual_image(tmp_path: Path) -> None:
    # hwf is at full resolution (h=30, w=40, f=50); images are 8x6 => scale 8/40
    cams = load_scene(make_llff(tmp_path)).cameras
    np.testing.assert_allclose(cams.fx, 50 * 8 / 40)
    np.testing.assert_allclose(cams.fy, 50 * 6 / 30)
    np.testing.assert_array_equal(cams.cx, 4.0)
    np.testing.assert_array_equal(cams.cy, 3.0)
    np.testing.assert_array_equal(cams.width, 8)
    np.testing.assert_array_equal(cams.height, 6)
    np.testing.assert_array_equal(cams.distortion, 0.0)


def test_downscale_resizes_images_folder(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    scene = load_scene(root, downscale=2)
    assert scene.info["image_folder"] == "images" and scene.info["resize_factor"] == 2
    np.testing.assert_array_equal(scene.cameras.width, 4)
    np.testing.assert_allclose(scene.cameras.fx, 50 * 4 / 40)
    original = np.asarray(Image.open(root / "images" / "img001.png")) / 255.0
    np.testing.assert_allclose(scene.images[1], original.reshape(3, 2, 4, 2, 3).mean(axis=(1, 3)), atol=1e-6)


def test_downscale_prefers_images_n_folder(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    make_llff(root, folder="images_2", size=(4, 3))
    for i in range(3):  # mark images_2 content so we can tell which folder was read
        Image.fromarray(np.full((3, 4, 3), 77, np.uint8)).save(root / "images_2" / f"img{i:03d}.png")
    scene = load_scene(root, downscale=2)
    assert scene.info["image_folder"] == "images_2" and scene.info["resize_factor"] == 1
    np.testing.assert_allclose(scene.images[0], 77 / 255.0, atol=1e-7)
    assert choose_image_folder(root, 1) == (root / "images", 1)
    assert choose_image_folder(root, 4) == (root / "images", 4)


def test_no_images_folder_falls_back_to_smallest_images_n_with_warning(tmp_path: Path) -> None:
    root = make_llff(tmp_path, folder="images_8", size=(8, 6))
    make_llff(root, folder="images_4", size=(16, 12))
    with pytest.warns(UserWarning, match=r"no images/ folder; using images_4/"):
        scene = load_scene(root)
    np.testing.assert_array_equal(scene.cameras.width, 16)
    np.testing.assert_allclose(scene.cameras.fx, 50 * 16 / 40)
    with pytest.raises(InputError, match=r"no image folder for downscale=2: expected images_2/ or images/.*images_4/, images_8/"):
        load_scene(root, downscale=2)


def test_labels_beside_images(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    (root / "labels").mkdir()
    label = np.zeros((6, 8), np.uint16)
    label[3:] = 1000
    Image.fromarray(label).save(root / "labels" / "img002.png")
    (root / "classes.json").write_text('{"classes": [{"id": 0, "name": "a"}, {"id": 1000, "name": "b"}]}')
    scene = load_scene(root)
    assert scene.labels[:2] == [None, None]
    np.testing.assert_array_equal(scene.labels[2], label.astype(np.int64))
    assert scene.classes == {0: "a", 1000: "b"} and scene.ignore_index is None


# ---------------------------------------------------------------------------------------------
# bad inputs


def test_image_count_differs_from_poses(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    (root / "images" / "img001.png").unlink()
    with pytest.raises(InputError, match=r"images.*2 images in images/ but 3 poses in poses_bounds.npy"):
        load_scene(root)


def test_empty_or_missing_images_folder(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    shutil.rmtree(root / "images")
    with pytest.raises(InputError, match=r"no image folder for downscale=1: expected images_1/ or images/"):
        load_scene(root)
    (root / "images").mkdir()
    with pytest.raises(InputError, match=r"images: no image files"):
        load_scene(root)


@pytest.mark.parametrize(
    "mutate, pattern",
    [
        (lambda a: a[:, :16], r"expected shape \[n, 17\].*\[3, 16\]"),
        (lambda a: a.__setitem__((1, 3), np.nan) or a, r"\[row 1\].*non-finite"),
        (lambda a: a.__setitem__((2, 0), a[2, 0] * 1.5) or a, r"\[row 2\].*not rigid"),
        (lambda a: a.__setitem__((0, 15), 20.0) or a, r"\[row 0\].*0 <= near < far"),
        (lambda a: a.__setitem__((1, 14), -5.0) or a, r"\[row 1\].*must be positive"),
    ],
)
def test_bad_poses_bounds(tmp_path: Path, mutate, pattern: str) -> None:
    root = make_llff(tmp_path)
    array = np.load(root / "poses_bounds.npy")
    np.save(root / "poses_bounds.npy", mutate(array))
    with pytest.raises(InputError, match=r"poses_bounds.npy.*" + pattern):
        load_scene(root)


def test_unreadable_poses_bounds(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    (root / "poses_bounds.npy").write_bytes(b"not numpy")
    with pytest.raises(InputError, match=r"poses_bounds.npy.*cannot read"):
        load_scene(root)


def test_aspect_ratio_mismatch(tmp_path: Path) -> None:
    root = make_llff(tmp_path, size=(8, 8))
    with pytest.raises(InputError, match=r"img000.png.*8x8 does not have the aspect ratio of.*40x30"):
        load_scene(root)


def test_llff_labels_without_classes(tmp_path: Path) -> None:
    root = make_llff(tmp_path)
    (root / "labels").mkdir()
    Image.fromarray(np.zeros((6, 8), np.uint8)).save(root / "labels" / "img000.png")
    with pytest.raises(InputError, match="classes.json is missing"):
        load_llff(root)


# ---------------------------------------------------------------------------------------------
# real data: fern


@pytest.fixture(scope="module")
def fern():
    if not FERN.is_dir():
        pytest.skip("shared data (../shared/data/llff_fern) not present")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_scene(FERN, downscale=8)


def test_fern_views_and_intrinsics(fern) -> None:
    assert len(fern) == 20 and fern.info["image_folder"] == "images_8"
    for image in fern.images:
        assert image.shape == (378, 504, 3) and image.dtype == np.float32
    cams = fern.cameras
    np.testing.assert_array_equal(cams.width, 504)
    np.testing.assert_array_equal(cams.height, 378)
    np.testing.assert_allclose(cams.fx, FERN_FOCAL * 504 / FERN_FULL_WIDTH, rtol=1e-6)
    np.testing.assert_allclose(cams.fy, FERN_FOCAL * 504 / FERN_FULL_WIDTH, rtol=1e-6)
    np.testing.assert_array_equal(cams.cx, 252.0)
    np.testing.assert_array_equal(cams.cy, 189.0)


def test_fern_bounds_from_file_and_rigid(fern) -> None:
    raw = np.load(FERN / "poses_bounds.npy")
    np.testing.assert_array_equal(fern.cameras.near, raw[:, 15])
    np.testing.assert_array_equal(fern.cameras.far, raw[:, 16])
    r = fern.cameras.c2w[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-5)


def test_fern_is_forward_facing(fern) -> None:
    forward = fern.cameras.c2w[:, :3, 2]
    angles = np.degrees(np.arccos(np.clip(forward @ mean_optical_axis(fern.cameras), -1, 1)))
    assert angles.max() < 30.0
    # a forward rig (its far fallback, were its file without near/far) whose scene lies within that far
    assert forward_rig(fern.cameras) and capture_reference(fern.cameras) is not None
    unknown = np.full(len(fern.cameras), np.nan)
    unbounded = dataclasses.replace(fern.cameras, near=unknown, far=unknown)
    _, fallback_far = near_far_or_fallback(unbounded)
    assert 2 * fern.cameras.far.max() < fallback_far.min()


def test_fern_sparse_points_lie_in_front_within_bounds(fern) -> None:
    points_path = FERN / "sparse" / "0" / "points3D.bin"
    if not points_path.is_file():
        pytest.skip("fern points3D.bin not present")
    points = read_points3d_bin(points_path)
    assert len(points) == 10091
    for i in range(len(fern)):
        c2w = fern.cameras.c2w[i]
        z = (points - c2w[:3, 3]) @ c2w[:3, 2]  # camera-frame depth along OpenCV +z (forward)
        assert np.mean(z > 0) > 0.99  # with a wrong axis flip the scene would be behind the camera
        # LLFF's bounds are the 0.1 / 99.9 percentiles of the z-depths of the points a view sees
        low, high = np.percentile(z, [0.1, 99.9])
        assert low == pytest.approx(fern.cameras.near[i], rel=BOUNDS_REL_TOLERANCE)
        assert high == pytest.approx(fern.cameras.far[i], rel=BOUNDS_REL_TOLERANCE)


def test_fern_downscale_1_uses_images_4_with_warning() -> None:
    if not FERN.is_dir():
        pytest.skip("shared data (../shared/data/llff_fern) not present")
    with pytest.warns(UserWarning, match="using images_4/"):
        scene = load_scene(FERN)
    assert scene.info["image_folder"] == "images_4" and scene.images[0].shape == (756, 1008, 3)
    np.testing.assert_allclose(scene.cameras.fx, FERN_FOCAL * 1008 / FERN_FULL_WIDTH, rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# real poses: room (its images are style-transferred: never loaded; tiny stand-ins instead)


def test_room_poses_with_generated_images(tmp_path: Path) -> None:
    if not (ROOM / "poses_bounds.npy").is_file():
        pytest.skip("shared data (../shared/data/llff_room_poses) not present")
    shutil.copy(ROOM / "poses_bounds.npy", tmp_path / "poses_bounds.npy")
    (tmp_path / "images").mkdir()
    for i in range(41):  # 8x6 has the 4032x3024 aspect ratio
        Image.fromarray(np.full((6, 8, 3), i, np.uint8)).save(tmp_path / "images" / f"v{i:02d}.png")
    scene = load_scene(tmp_path)
    assert len(scene) == 41
    assert scene.cameras.near.min() == pytest.approx(10.71, abs=0.005)
    assert scene.cameras.far.max() == pytest.approx(91.67, abs=0.005)
    np.testing.assert_allclose(scene.cameras.fx, 3070.638 * 8 / 4032, rtol=1e-6)
    # relative rotations cross-checked against an independent transforms.json (data README)
    assert _angle_deg(scene.cameras.c2w[1], scene.cameras.c2w[2]) == pytest.approx(4.2893, abs=1e-3)
    assert _angle_deg(scene.cameras.c2w[1], scene.cameras.c2w[3]) == pytest.approx(8.0675, abs=1e-3)
    c2w, hwf, bounds = read_poses_bounds(ROOM / "poses_bounds.npy")
    np.testing.assert_array_equal(scene.cameras.c2w, c2w)
    np.testing.assert_array_equal(hwf[0], [3024, 4032, hwf[0, 2]])


def test_room_stylized_images_are_not_an_image_folder() -> None:
    if not ROOM.is_dir():
        pytest.skip("shared data (../shared/data/llff_room_poses) not present")
    with pytest.raises(InputError, match="no image folder"):
        load_scene(ROOM)
