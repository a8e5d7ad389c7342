"""COLMAP loader: w2c -> OpenCV c2w, camera models, image matching, near/far, real models."""

from __future__ import annotations

import shutil
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
from PIL import Image
from shared_data import DATA, read_points3d_bin

from scenelabel.data.io import load_colmap, load_scene
from scenelabel.data.io.colmap import (
    FAR_MARGIN,
    FAR_PERCENTILE,
    NEAR_MARGIN,
    NEAR_PERCENTILE,
    colmap_camera_model,
    colmap_intrinsics,
    find_sparse_dir,
    read_colmap_cameras,
)
from scenelabel.data.io.llff import read_poses_bounds
from scenelabel.errors import InputError
from scenelabel.geometry.lens import pixels_from_camera_points
from scenelabel.geometry.rays import camera_directions_from_pixels

FERN = DATA / "llff_fern"
ROOM = DATA / "llff_room_poses"

# the LLFF loader's cameras must agree with the COLMAP model's after the documented conversions
LLFF_COLMAP_TOLERANCE = 1e-6

SIZE = (40, 30)  # (width, height) of every synthetic COLMAP camera and image
# camera_id -> (COLMAP model, params in COLMAP order, expected (fx, fy, cx, cy), expected k1 k2 p1 p2)
CAMERAS = {
    1: ("SIMPLE_RADIAL", [52.0, 20.5, 14.5, 0.03], (52.0, 52.0, 20.5, 14.5), [0.03, 0.0, 0.0, 0.0]),
    2: ("PINHOLE", [50.0, 51.0, 19.0, 16.0], (50.0, 51.0, 19.0, 16.0), [0.0, 0.0, 0.0, 0.0]),
    3: (
        "OPENCV",
        [48.0, 49.0, 21.0, 15.5, 0.1, -0.02, 0.001, -0.002],
        (48.0, 49.0, 21.0, 15.5),
        [0.1, -0.02, 0.001, -0.002],
    ),
}
# image name -> (image_id, camera_id); ids deliberately not in name order
VIEWS = {"v2.png": (1, 3), "v0.png": (7, 1), "v3.png": (3, 1), "v1.png": (5, 2)}
SORTED_NAMES = sorted(VIEWS)
# v3 observes only the points with z <= PARTIAL_MAX_Z (its near/far must come from those)
PARTIAL_VIEW, PARTIAL_MAX_Z = "v3.png", 6.5


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _w2c(name: str) -> np.ndarray:
    """The known world-to-camera (OpenCV axes) of a synthetic view."""
    i = SORTED_NAMES.index(name)
    w2c = np.eye(4)
    w2c[:3, :3] = _rotation([0.3, -1.0, 0.2 + i], 0.15 * i + 0.05)
    w2c[:3, 3] = [0.2 * i, -0.3, 0.1 * i - 0.2]
    return w2c


def _points() -> np.ndarray:
    """[24, 3] points in front of every synthetic camera (z from 5 to 9)."""
    x, y, z = np.meshgrid([-1.5, 0.0, 1.5], [-1.0, 1.0], [5.0, 6.5, 8.0, 9.0], indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def _observed(name: str) -> np.ndarray:
    """Indices of the points a view observes."""
    points = _points()
    return np.flatnonzero(points[:, 2] <= PARTIAL_MAX_Z) if name == PARTIAL_VIEW else np.arange(len(points))


def make_colmap(
    root: Path,
    fmt: str = "bin",
    cameras: dict | None = None,
    image_folders: dict | None = None,
    sparse: str = "sparse/0",
) -> Path:
    """A scene folder with a COLMAP model written by pycolmap (``fmt`` "bin" or "txt") and PNGs.

    Args:
        cameras: overrides of CAMERAS (camera_id -> (model, params, ...)).
        image_folders: folder name -> (width, height) of its PNGs; default {"images": SIZE}.
    """
    cameras = {**CAMERAS, **(cameras or {})}
    reconstruction = pycolmap.Reconstruction()
    for camera_id, (model, params, *_) in cameras.items():
        reconstruction.add_camera_with_trivial_rig(
            pycolmap.Camera(camera_id=camera_id, model=model, width=SIZE[0], height=SIZE[1], params=params)
        )
    points = _points()
    tracks = [pycolmap.Track() for _ in points]
    for name, (image_id, camera_id) in VIEWS.items():
        w2c = _w2c(name)
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        uv = cam[:, :2] / cam[:, 2:] * 40.0 + 20.0  # roughly where they are seen; unused by the loader
        observed = _observed(name)
        points2d = [pycolmap.Point2D(uv[j]) for j in observed]
        image = pycolmap.Image(image_id=image_id, name=name, camera_id=camera_id, points2D=points2d)
        reconstruction.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[:3]))
        for idx, j in enumerate(observed):
            tracks[j].add_element(image_id, idx)
    for xyz, track in zip(points, tracks):
        reconstruction.add_point3D(xyz, track)
    model_dir = root / sparse
    model_dir.mkdir(parents=True)
    (reconstruction.write_binary if fmt == "bin" else reconstruction.write_text)(str(model_dir))
    for folder, (width, height) in ({"images": SIZE} if image_folders is None else image_folders).items():
        (root / folder).mkdir()
        for i, name in enumerate(SORTED_NAMES):
            pixels = np.random.default_rng(i).integers(0, 256, (height, width, 3), dtype=np.uint8)
            Image.fromarray(pixels).save(root / folder / name)
    return root


def _load_quietly(root: Path, downscale: int = 1):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_scene(root, downscale)


# ---------------------------------------------------------------------------------------------
# synthetic models: poses, intrinsics, formats


@pytest.mark.parametrize("fmt", ["bin", "txt"])
def test_known_model_loads_exact_c2w_and_intrinsics(tmp_path: Path, fmt: str) -> None:
    scene = _load_quietly(make_colmap(tmp_path, fmt))
    assert scene.info["format"] == "colmap" and scene.info["model_format"] == fmt
    assert scene.names == ["v0", "v1", "v2", "v3"]  # sorted by name, not by image id
    assert scene.info["registered"] == 4 and scene.info["points3D"] == 24 and scene.info["skipped_missing"] == 0
    assert scene.info["camera_models"] == ["OPENCV", "PINHOLE", "SIMPLE_RADIAL"]
    assert scene.aabb is None and scene.depths == [None] * 4 and scene.classes == {}
    cams = scene.cameras
    for i, name in enumerate(SORTED_NAMES):
        np.testing.assert_allclose(cams.c2w[i], np.linalg.inv(_w2c(name)), rtol=0, atol=1e-12)
        _, _, (fx, fy, cx, cy), distortion = CAMERAS[VIEWS[name][1]]
        assert (cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i]) == (fx, fy, cx, cy)
        np.testing.assert_array_equal(cams.distortion[i], distortion)
        assert scene.images[i].shape == (30, 40, 3) and scene.images[i].dtype == np.float32
    np.testing.assert_array_equal(cams.width, 40)
    np.testing.assert_array_equal(cams.height, 30)


def test_c2w_is_opencv_camera_to_world(tmp_path: Path) -> None:
    # a world point's camera-frame coordinates from c2w equal COLMAP's w2c applied to it
    scene = _load_quietly(make_colmap(tmp_path))
    point = np.array([0.3, -0.7, 6.0])
    for i, name in enumerate(SORTED_NAMES):
        c2w = scene.cameras.c2w[i]
        in_camera = c2w[:3, :3].T @ (point - c2w[:3, 3])
        np.testing.assert_allclose(in_camera, _w2c(name)[:3, :3] @ point + _w2c(name)[:3, 3], atol=1e-12)
        assert in_camera[2] > 0  # the point is in front (+z forward)


@pytest.mark.parametrize(
    "model, params, expected",
    [
        ("SIMPLE_PINHOLE", [10.0, 4.0, 3.0], (10, 10, 4, 3, [0, 0, 0, 0])),
        ("PINHOLE", [10.0, 11.0, 4.0, 3.0], (10, 11, 4, 3, [0, 0, 0, 0])),
        ("SIMPLE_RADIAL", [10.0, 4.0, 3.0, 0.2], (10, 10, 4, 3, [0.2, 0, 0, 0])),
        ("RADIAL", [10.0, 4.0, 3.0, 0.2, -0.1], (10, 10, 4, 3, [0.2, -0.1, 0, 0])),
        ("OPENCV", [10.0, 11.0, 4.0, 3.0, 0.2, -0.1, 0.01, 0.02], (10, 11, 4, 3, [0.2, -0.1, 0.01, 0.02])),
        ("FULL_OPENCV", [10.0, 11.0, 4.0, 3.0, 0.2, -0.1, 0.01, 0.02, 0, 0, 0, 0], (10, 11, 4, 3, [0.2, -0.1, 0.01, 0.02])),
    ],
)
def test_camera_models_map_to_opencv(model: str, params: list, expected: tuple) -> None:
    fx, fy, cx, cy, distortion = colmap_intrinsics(model, params)
    assert (fx, fy, cx, cy) == expected[:4]
    np.testing.assert_array_equal(distortion, expected[4])


def test_camera_model_params_agree_with_pycolmap() -> None:
    # pycolmap's own focal / principal point accessors read the same parameters
    for model, params, _, _ in CAMERAS.values():
        camera = pycolmap.Camera(camera_id=1, model=model, width=SIZE[0], height=SIZE[1], params=params)
        fx, fy, cx, cy, _ = colmap_intrinsics(camera.model.name, camera.params)
        assert (fx, fy, cx, cy) == (
            camera.focal_length_x,
            camera.focal_length_y,
            camera.principal_point_x,
            camera.principal_point_y,
        )


def test_distortion_matches_colmap_projection(tmp_path: Path) -> None:
    # OpenCV projection with the loaded intrinsics lands where COLMAP's own camera model does
    scene = _load_quietly(make_colmap(tmp_path))
    xyz = np.array([[0.3, -0.2, 1.0], [-0.25, 0.2, 1.0], [0.1, 0.15, 1.0]])  # camera-frame points
    for i, name in enumerate(SORTED_NAMES):
        model, params, _, _ = CAMERAS[VIEWS[name][1]]
        camera = pycolmap.Camera(camera_id=1, model=model, width=SIZE[0], height=SIZE[1], params=params)
        expected = camera.img_from_cam(xyz)
        c = scene.cameras
        k = np.array([[c.fx[i], 0, c.cx[i]], [0, c.fy[i], c.cy[i]], [0, 0, 1]])
        projected, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), k, c.distortion[i])
        np.testing.assert_allclose(projected.reshape(-1, 2), expected, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# fisheye cameras


FISHEYES = {
    1: ("SIMPLE_RADIAL_FISHEYE", [30.0, 20.5, 14.5, 0.04], (30.0, 30.0, 20.5, 14.5), [0.04, 0.0, 0.0, 0.0]),
    2: ("RADIAL_FISHEYE", [28.0, 19.0, 16.0, 0.05, -0.01], (28.0, 28.0, 19.0, 16.0), [0.05, -0.01, 0.0, 0.0]),
    3: (
        "OPENCV_FISHEYE",
        [26.0, 27.0, 21.0, 15.5, 0.06, -0.02, 0.004, -0.001],
        (26.0, 27.0, 21.0, 15.5),
        [0.06, -0.02, 0.004, -0.001],
    ),
}


@pytest.mark.parametrize("camera_id", sorted(FISHEYES))
def test_fisheye_models_map_to_opencv_equidistant(camera_id: int) -> None:
    model, params, expected, distortion = FISHEYES[camera_id]
    fx, fy, cx, cy, coeffs = colmap_intrinsics(model, params)
    assert (fx, fy, cx, cy) == expected
    np.testing.assert_array_equal(coeffs, distortion)
    assert colmap_camera_model(model) == "fisheye"
    assert colmap_camera_model("OPENCV") == colmap_camera_model("SIMPLE_RADIAL") == "pinhole"


@pytest.mark.parametrize("fmt", ["txt", "bin"])
def test_fisheye_model_loads_and_projects_as_colmap(tmp_path: Path, fmt: str) -> None:
    """A COLMAP model of fisheye cameras loads with model "fisheye" and COLMAP's coefficients; our
    projection lands where pycolmap's does, and our pixel rays are pycolmap's."""
    scene = _load_quietly(make_colmap(tmp_path, fmt, cameras=FISHEYES))
    assert scene.info["camera_models"] == sorted(m for m, *_ in FISHEYES.values())
    cams = scene.cameras
    np.testing.assert_array_equal(cams.model, "fisheye")
    xyz = np.array([[0.3, -0.2, 1.0], [-0.8, 0.5, 0.6], [0.1, 0.15, 1.0], [1.5, -0.3, 0.4]])  # camera frame, z > 0
    pixels = np.array([[0.5, 0.5], [39.5, 29.5], [20.0, 15.0], [3.25, 27.5]])
    for i, name in enumerate(SORTED_NAMES):
        model, params, (fx, fy, cx, cy), distortion = FISHEYES[VIEWS[name][1]]
        assert (cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i]) == (fx, fy, cx, cy)
        np.testing.assert_array_equal(cams.distortion[i], distortion)
        camera = pycolmap.Camera(camera_id=1, model=model, width=SIZE[0], height=SIZE[1], params=params)
        uv = pixels_from_camera_points(xyz, fx, fy, cx, cy, cams.distortion[i], "fisheye")
        np.testing.assert_allclose(uv, camera.img_from_cam(xyz), atol=1e-9)
        dirs = camera_directions_from_pixels(pixels, fx, fy, cx, cy, cams.distortion[i], "fisheye")
        np.testing.assert_allclose(dirs[:, :2] / dirs[:, 2:], camera.cam_from_img(pixels), atol=1e-9)


def test_fisheye_downscale_keeps_model_and_coefficients(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, cameras=FISHEYES, image_folders={"images": SIZE, "images_2": (20, 15)})
    full, half = _load_quietly(root), _load_quietly(root, downscale=2)
    np.testing.assert_array_equal(half.cameras.model, full.cameras.model)
    np.testing.assert_array_equal(half.cameras.distortion, full.cameras.distortion)  # normalised coordinates
    np.testing.assert_allclose(half.cameras.fx, full.cameras.fx / 2, rtol=1e-12)
    # the same continuous image point has the same ray at both resolutions
    for i in range(len(full)):
        a = camera_directions_from_pixels(np.array([[3.0, 4.0]]), half.cameras.fx[i], half.cameras.fy[i], half.cameras.cx[i],
                                          half.cameras.cy[i], half.cameras.distortion[i], "fisheye")
        b = camera_directions_from_pixels(np.array([[6.0, 8.0]]), full.cameras.fx[i], full.cameras.fy[i], full.cameras.cx[i],
                                          full.cameras.cy[i], full.cameras.distortion[i], "fisheye")
        np.testing.assert_allclose(a, b, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# downscale


def test_downscale_uses_images_n_and_scales_intrinsics(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, image_folders={"images": SIZE, "images_2": (20, 15)})
    scene = _load_quietly(root, downscale=2)
    full = _load_quietly(root)
    assert scene.info["image_folder"] == "images_2" and scene.info["resize_factor"] == 1
    assert scene.images[0].shape == (15, 20, 3)
    for key in ("fx", "fy", "cx", "cy"):
        np.testing.assert_allclose(getattr(scene.cameras, key), getattr(full.cameras, key) / 2, rtol=1e-12)
    np.testing.assert_array_equal(scene.cameras.width, 20)
    np.testing.assert_array_equal(scene.cameras.height, 15)
    np.testing.assert_array_equal(scene.cameras.distortion, full.cameras.distortion)  # normalised coords
    np.testing.assert_array_equal(scene.cameras.c2w, full.cameras.c2w)
    np.testing.assert_array_equal(scene.cameras.near, full.cameras.near)


def test_downscale_resamples_images_folder(tmp_path: Path) -> None:
    scene = _load_quietly(make_colmap(tmp_path), downscale=2)
    assert scene.info["image_folder"] == "images" and scene.info["resize_factor"] == 2
    assert scene.images[0].shape == (15, 20, 3)
    np.testing.assert_allclose(scene.cameras.fx[0], 52.0 / 2)
    np.testing.assert_allclose(scene.cameras.cy[0], 14.5 / 2)


def test_only_images_n_with_downscale_1_uses_it_with_warning(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, image_folders={"images_4": (10, 7)})
    with pytest.warns(UserWarning, match="using images_4/"):
        scene = load_scene(root)
    assert scene.info["image_folder"] == "images_4"
    np.testing.assert_allclose(scene.cameras.fx[0], 52.0 * 10 / 40)
    np.testing.assert_allclose(scene.cameras.fy[0], 52.0 * 7 / 30)


# ---------------------------------------------------------------------------------------------
# near / far


def test_near_far_from_observed_points(tmp_path: Path) -> None:
    scene = _load_quietly(make_colmap(tmp_path))
    points = _points()
    for i, name in enumerate(SORTED_NAMES):
        distances = np.linalg.norm(points[_observed(name)] - scene.cameras.centres[i], axis=1)
        low, high = np.percentile(distances, [NEAR_PERCENTILE, FAR_PERCENTILE])
        assert scene.cameras.near[i] == pytest.approx(NEAR_MARGIN * low, rel=1e-12)
        assert scene.cameras.far[i] == pytest.approx(FAR_MARGIN * high, rel=1e-12)
        assert 0 < scene.cameras.near[i] < distances.min() and scene.cameras.far[i] > distances.max()
    # v3 sees only the nearer points: its far is not that of all points
    v3 = SORTED_NAMES.index(PARTIAL_VIEW)
    all_far = FAR_MARGIN * np.percentile(np.linalg.norm(points - scene.cameras.centres[v3], axis=1), FAR_PERCENTILE)
    assert scene.cameras.far[v3] < 0.9 * all_far
    box = np.asarray(scene.info["points_aabb"])
    assert np.all(box[0] <= scene.cameras.centres.min(0)) and np.all(box[1] >= points.max(0) - 0.05)


def test_view_without_observations_uses_points_in_its_image(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    model = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    for point_id in list(model.points3D):
        model.delete_observation(VIEWS["v1.png"][0], _find_point2d(model, point_id, VIEWS["v1.png"][0]))
    model.write_binary(str(root / "sparse" / "0"))
    names, cameras, points = read_colmap_cameras(root / "sparse" / "0")
    i = names.index("v1.png")
    c2w = cameras.c2w[i]
    cam = (points - c2w[:3, 3]) @ c2w[:3, :3]
    u = cameras.fx[i] * cam[:, 0] / cam[:, 2] + cameras.cx[i]
    v = cameras.fy[i] * cam[:, 1] / cam[:, 2] + cameras.cy[i]
    inside = (cam[:, 2] > 0) & (u >= 0) & (u < 40) & (v >= 0) & (v < 30)
    assert 0 < inside.sum() < len(points)
    distances = np.linalg.norm(points[inside] - c2w[:3, 3], axis=1)
    assert cameras.near[i] == pytest.approx(NEAR_MARGIN * np.percentile(distances, NEAR_PERCENTILE), rel=1e-12)
    assert cameras.far[i] == pytest.approx(FAR_MARGIN * np.percentile(distances, FAR_PERCENTILE), rel=1e-12)


def _find_point2d(model, point_id: int, image_id: int) -> int:
    """The point2D index through which ``image_id`` observes ``point_id``."""
    for element in model.points3D[point_id].track.elements:
        if element.image_id == image_id:
            return element.point2D_idx
    raise AssertionError("not observed")


def test_model_without_points_has_nan_bounds(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    model = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    for point_id in list(model.points3D):
        model.delete_point3D(point_id)
    model.write_binary(str(root / "sparse" / "0"))
    scene = _load_quietly(root)
    assert scene.info["points3D"] == 0 and scene.info["points_aabb"] is None
    assert np.all(np.isnan(scene.cameras.near)) and np.all(np.isnan(scene.cameras.far))


# ---------------------------------------------------------------------------------------------
# image files


def test_missing_image_files_skipped_with_one_counting_warning(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    (root / "images" / "v0.png").unlink()
    (root / "images" / "v2.png").unlink()
    Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(root / "images" / "extra.png")  # not in the model
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(root)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "2 of 4 registered images" in messages[0] and "v0.png, v2.png" in messages[0]
    assert scene.names == ["v1", "v3"] and scene.info["skipped_missing"] == 2
    assert scene.info["unregistered_images"] == 1
    np.testing.assert_allclose(scene.cameras.c2w[0], np.linalg.inv(_w2c("v1.png")), atol=1e-12)
    np.testing.assert_allclose(scene.cameras.c2w[1], np.linalg.inv(_w2c("v3.png")), atol=1e-12)


def test_fewer_than_two_image_files(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    for name in SORTED_NAMES[1:]:
        (root / "images" / name).unlink()
    with pytest.warns(UserWarning, match="3 of 4"), pytest.raises(InputError, match=r"only 1 of 4 registered images"):
        load_scene(root)


def test_model_names_match_files_by_stem(tmp_path: Path) -> None:
    # LLFF-style downsampled folders convert IMG.JPG to IMG.png
    root = make_colmap(tmp_path)
    for name in SORTED_NAMES:
        (root / "images" / name).rename(root / "images" / name.replace(".png", ".JPG"))
    scene = _load_quietly(root)
    assert scene.names == ["v0", "v1", "v2", "v3"] and scene.images[0].shape == (30, 40, 3)


def test_image_aspect_must_match_camera(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, image_folders={"images": (40, 40)})
    with pytest.raises(InputError, match=r"v0.png: image size 40x40 does not have the aspect ratio.*40x30 in cameras.bin"):
        load_scene(root)


def test_no_images_folder(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, image_folders={})
    with pytest.raises(InputError, match=r"no image folder for downscale=1: expected images_1/ or images/"):
        load_scene(root)


# ---------------------------------------------------------------------------------------------
# labels


def test_labels_and_classes(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    (root / "labels").mkdir()
    Image.fromarray(np.full((30, 40), 3, np.uint8)).save(root / "labels" / "v1.png")
    (root / "classes.json").write_text('{"classes": [{"id": 3, "name": "chair"}], "ignore_index": 255}')
    scene = _load_quietly(root)
    assert scene.classes == {3: "chair"} and scene.ignore_index == 255 and scene.info["labelled_views"] == 1
    assert scene.labels[0] is None and scene.labels[1].dtype == np.int64 and np.all(scene.labels[1] == 3)


def test_labels_without_classes(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    (root / "labels").mkdir()
    Image.fromarray(np.zeros((30, 40), np.uint8)).save(root / "labels" / "v0.png")
    with pytest.raises(InputError, match="classes.json is missing"):
        load_colmap(root)


# ---------------------------------------------------------------------------------------------
# bad models, dispatch


@pytest.mark.parametrize(
    "model, params, pattern",
    [
        ("FOV", [50.0, 50.0, 20.0, 15.0, 0.9], r"FOV.*supported: .*OPENCV_FISHEYE.*colmap image_undistorter"),
        (
            "THIN_PRISM_FISHEYE",
            [50.0, 50.0, 20.0, 15.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            r"THIN_PRISM_FISHEYE.*colmap image_undistorter",
        ),
        ("FULL_OPENCV", [50.0, 50.0, 20.0, 15.0, 0.1, 0.0, 0.0, 0.0, 0.01, 0, 0, 0], r"FULL_OPENCV with non-zero k3..k6.*image_undistorter"),
    ],
)
def test_unsupported_camera_model(tmp_path: Path, model: str, params: list, pattern: str) -> None:
    root = make_colmap(tmp_path, cameras={2: (model, params, None, None)})
    with pytest.raises(InputError, match=r"cameras.bin: camera 2 \(image 'v1.png'\).*" + pattern):
        load_scene(root)


def test_incomplete_model(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    (root / "sparse" / "0" / "images.bin").unlink()
    with pytest.raises(InputError, match=r"sparse/0: incomplete COLMAP model: images.bin / .txt missing"):
        load_scene(root)


@pytest.mark.parametrize(
    "name, content, pattern",
    [
        ("points3D.bin", b"garbage!x", r"points3D.bin: corrupt or truncated COLMAP file: a count of \d+ records cannot fit in its 9 bytes"),
        ("cameras.bin", b"\x01\x00", r"cameras.bin: corrupt or truncated COLMAP file: 2 bytes, too short for its record count"),
        ("images.bin", None, r"images.bin: corrupt or truncated COLMAP file: a count of 4 records cannot fit in its 100 bytes"),
    ],
)
def test_corrupt_binary_model_file(tmp_path: Path, name: str, content: bytes | None, pattern: str) -> None:
    # checked before pycolmap reads it: a huge count in a corrupt header costs pycolmap minutes
    root = make_colmap(tmp_path)
    path = root / "sparse" / "0" / name
    path.write_bytes(path.read_bytes()[:100] if content is None else content)
    with pytest.raises(InputError, match=pattern):
        load_scene(root)


def test_unreadable_text_model_file(tmp_path: Path) -> None:
    root = make_colmap(tmp_path, fmt="txt")
    (root / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE forty thirty 50 50 20 15\n")
    with pytest.raises(InputError, match=r"sparse/0: cannot read the COLMAP model"):
        load_scene(root)


def test_undistorter_layout_sparse_without_0(tmp_path: Path) -> None:
    # colmap image_undistorter writes OUT/images and OUT/sparse/{cameras,images,points3D}.bin
    root = make_colmap(tmp_path, sparse="sparse")
    assert find_sparse_dir(root) == root / "sparse"
    scene = _load_quietly(root)
    assert scene.info["source"] == str(root / "sparse") and len(scene) == 4


def test_poses_bounds_takes_precedence_over_sparse(tmp_path: Path) -> None:
    root = make_colmap(tmp_path)
    c2w = np.linalg.inv(_w2c("v0.png"))
    row = np.concatenate([np.column_stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3], [30, 40, 50]]).ravel(), [1, 9]])
    np.save(root / "poses_bounds.npy", np.stack([row] * 4))
    assert _load_quietly(root).info["format"] == "llff"


def test_one_image_and_no_poses_says_what_is_expected(tmp_path: Path) -> None:
    (tmp_path / "images").mkdir()
    Image.fromarray(np.zeros((6, 8, 3), np.uint8)).save(tmp_path / "images" / "a.png")
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    message = str(info.value)
    for expected in ("no poses found", "COLMAP sparse model", "sparse/0/", "at least 2 photos in images/"):
        assert expected in message


def test_images_only_folder_runs_sfm_and_stops_when_too_few_register(tmp_path: Path) -> None:
    """Unrelated noise photos: SfM registers none, and the load stops with the matcher hint."""
    (tmp_path / "images").mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)).save(tmp_path / "images" / f"{i}.png")
    with pytest.raises(InputError, match=r"registered only \d+ of 3 images.*matcher="):
        load_scene(tmp_path)
    assert not (tmp_path / "sparse" / "0" / "images.bin").exists()


def test_load_colmap_without_model(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"no COLMAP sparse model: expected sparse/0/"):
        load_colmap(tmp_path)


# ---------------------------------------------------------------------------------------------
# real models: room (images.bin present) and fern (cameras.bin + points3D.bin only)


def _sorted_llff(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not path.is_file():
        pytest.skip(f"shared data ({path}) not present")
    return read_poses_bounds(path)


def test_room_llff_cameras_agree_with_colmap_model() -> None:
    c2w_llff, hwf, bounds = _sorted_llff(ROOM / "poses_bounds.npy")
    names, cameras, points = read_colmap_cameras(ROOM / "sparse" / "0")
    assert len(names) == 41 and names == sorted(names) and len(points) == 8772
    # LLFF pairs rows with sorted image names; so does read_colmap_cameras
    difference = np.abs(cameras.c2w - c2w_llff).max()
    assert difference <= LLFF_COLMAP_TOLERANCE, f"max |c2w_colmap - c2w_llff| = {difference:.3g}"
    np.testing.assert_allclose(cameras.fx, hwf[:, 2], rtol=1e-12)
    np.testing.assert_allclose(cameras.fy, hwf[:, 2], rtol=1e-12)
    np.testing.assert_array_equal(cameras.cx, hwf[:, 1] / 2)
    np.testing.assert_array_equal(cameras.cy, hwf[:, 0] / 2)
    np.testing.assert_array_equal(cameras.width, hwf[:, 1])
    np.testing.assert_array_equal(cameras.distortion[:, 1:], 0.0)
    assert cameras.distortion[0, 0] == pytest.approx(0.0096159, abs=1e-7)  # SIMPLE_RADIAL k
    # both bound the same geometry: LLFF from z-depths (0.1 / 99.9 percentiles), ours from distances
    assert np.all(np.isfinite(cameras.near)) and np.all(np.isfinite(cameras.far))
    assert np.all(np.abs(cameras.near / bounds[:, 0] - 1) < 0.1)  # measured: within 8%
    assert np.all((cameras.far / bounds[:, 1] > 1.0) & (cameras.far / bounds[:, 1] < 1.3))  # 1.10 .. 1.24


def test_room_observations_reproject_with_loaded_cameras() -> None:
    if not (ROOM / "sparse" / "0").is_dir():
        pytest.skip("shared data (../shared/data/llff_room_poses) not present")
    names, cameras, _ = read_colmap_cameras(ROOM / "sparse" / "0")
    model = pycolmap.Reconstruction(str(ROOM / "sparse" / "0"))
    for i in range(0, len(names), 8):
        image = model.find_image_with_name(names[i])
        observations = [p for p in image.points2D if p.has_point3D()]
        xyz = np.array([model.points3D[p.point3D_id].xyz for p in observations])
        keypoints = np.array([p.xy for p in observations])
        w2c = np.linalg.inv(cameras.c2w[i])
        k = np.array([[cameras.fx[i], 0, cameras.cx[i]], [0, cameras.fy[i], cameras.cy[i]], [0, 0, 1]])
        rvec = cv2.Rodrigues(w2c[:3, :3])[0]
        projected, _ = cv2.projectPoints(xyz, rvec, w2c[:3, 3], k, cameras.distortion[i])
        errors = np.linalg.norm(projected.reshape(-1, 2) - keypoints, axis=1)
        assert np.median(errors) < 1.5, f"{names[i]}: median reprojection error {np.median(errors):.2f} px"


def test_room_loads_with_stand_in_images(tmp_path: Path) -> None:
    # the room's images are style-transferred: tiny stand-ins with the model's names instead
    if not (ROOM / "sparse" / "0").is_dir():
        pytest.skip("shared data (../shared/data/llff_room_poses) not present")
    (tmp_path / "sparse").symlink_to((ROOM / "sparse").resolve(), target_is_directory=True)
    (tmp_path / "images").mkdir()
    names, cameras, _ = read_colmap_cameras(ROOM / "sparse" / "0")
    for i, name in enumerate(names):  # 8x6 has the 4032x3024 aspect ratio
        Image.fromarray(np.full((6, 8, 3), i, np.uint8)).save(tmp_path / "images" / Path(name).with_suffix(".png"))
    scene = _load_quietly(tmp_path)
    assert scene.info["format"] == "colmap" and len(scene) == 41 and scene.info["points3D"] == 8772
    assert scene.names == [Path(n).stem for n in names]
    np.testing.assert_allclose(scene.cameras.fx, 3070.638 * 8 / 4032, rtol=1e-6)
    np.testing.assert_array_equal(scene.cameras.cx, 4.0)
    np.testing.assert_array_equal(scene.cameras.c2w, cameras.c2w)


def test_room_stylized_images_are_not_an_image_folder_for_colmap() -> None:
    if not ROOM.is_dir():
        pytest.skip("shared data (../shared/data/llff_room_poses) not present")
    with pytest.raises(InputError, match="no image folder"):
        load_colmap(ROOM)


def _fern_camera(tmp_path: Path) -> pycolmap.Camera:
    """Fern's cameras.bin read by pycolmap (beside empty images.bin / points3D.bin: fern has none)."""
    shutil.copy(FERN / "sparse" / "0" / "cameras.bin", tmp_path / "cameras.bin")
    for name in ("images.bin", "points3D.bin"):
        (tmp_path / name).write_bytes(struct.pack("<Q", 0))  # a binary model file with 0 records
    model = pycolmap.Reconstruction(str(tmp_path))
    assert model.num_cameras() == 1
    return model.cameras[1]


def test_fern_model_has_no_images_file() -> None:
    if not (FERN / "sparse" / "0").is_dir():
        pytest.skip("shared data (../shared/data/llff_fern) not present")
    # fern's snapshot lacks images.bin (its README): no COLMAP poses to compare, and a clear error
    with pytest.raises(InputError, match=r"incomplete COLMAP model: images.bin / .txt missing.*camera poses"):
        read_colmap_cameras(FERN / "sparse" / "0")


def test_fern_colmap_camera_and_points_agree_with_llff(tmp_path: Path) -> None:
    c2w, hwf, bounds = _sorted_llff(FERN / "poses_bounds.npy")
    camera = _fern_camera(tmp_path)
    fx, fy, cx, cy, distortion = colmap_intrinsics(camera.model.name, camera.params)
    assert camera.model.name == "SIMPLE_RADIAL" and (camera.width, camera.height) == (4032, 3024)
    np.testing.assert_allclose([fx, fy], hwf[:, 2].max(), rtol=1e-12)
    assert (cx, cy) == (hwf[0, 1] / 2, hwf[0, 0] / 2)
    assert distortion[0] == pytest.approx(0.01975, abs=1e-5) and np.all(distortion[1:] == 0)
    points = read_points3d_bin(FERN / "sparse" / "0" / "points3D.bin")
    assert len(points) == 10091
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    for i in range(len(c2w)):
        cam = (points - c2w[i, :3, 3]) @ c2w[i, :3, :3]
        assert np.all(cam[:, 2] > 0)  # every sparse point in front of every LLFF camera (OpenCV +z)
        uv = cam @ k.T
        uv = uv[:, :2] / uv[:, 2:]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 4032) & (uv[:, 1] >= 0) & (uv[:, 1] < 3024)
        assert inside.mean() > 0.9  # a forward-facing capture: nearly all points in every view
        distances = np.linalg.norm(points - c2w[i, :3, 3], axis=1)
        assert bounds[i, 0] < np.percentile(distances, 1) and np.percentile(distances, 50) < bounds[i, 1]
