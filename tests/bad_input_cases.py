"""Bad inputs and the one-line message each must give: shared by tests/test_bad_inputs.py and
tools/errors_table.py (which writes docs/errors.md from these cases, run for real)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from PIL import Image

from scenelabel.data.synthetic import write_toy_scene


@dataclass
class Case:
    name: str
    setup: Callable[[Path], list[str]]  # tmp folder -> CLI arguments
    expect: tuple[str, ...]  # substrings of the one error line


def toy(tmp: Path) -> Path:
    return write_toy_scene(tmp / "scene", n_train=7, n_test=1, width=24, height=18)


def edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


def build_args(scene: Path, *extra: str) -> list[str]:
    return ["build", str(scene), "--steps", "1", "--quiet", *extra]


def _missing_folder(tmp):
    return build_args(tmp / "no_such_scene")


def _empty_images(tmp):
    scene = toy(tmp)
    for p in (scene / "images").iterdir():
        p.unlink()
    return build_args(scene)


def _truncated_image(tmp):
    scene = toy(tmp)
    path = scene / "images" / "002.png"
    path.write_bytes(path.read_bytes()[:60])
    return build_args(scene)


def _image_vs_intrinsics(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(w=30))
    return build_args(scene)


def _label_size(tmp):
    scene = toy(tmp)
    Image.fromarray(np.zeros((5, 5), np.uint8)).save(scene / "labels" / "001.png")
    return build_args(scene)


def _label_id_unknown(tmp):
    scene = toy(tmp)
    path = scene / "labels" / "002.png"
    arr = np.array(Image.open(path))
    arr[0, 0] = 42
    Image.fromarray(arr).save(path)
    return build_args(scene)


def _classes_malformed(tmp):
    scene = toy(tmp)
    (scene / "classes.json").write_text('{"classes": [{"id": 1, "name": "floor"}')
    return build_args(scene)


def _free_index_is_a_class(tmp):
    scene = toy(tmp)
    edit_json(scene / "classes.json", lambda d: d.update(free_index=d["classes"][0]["id"]))
    return build_args(scene)


def _transforms_schema(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d["frames"][0].pop("transform_matrix"))
    return build_args(scene)


def _non_finite_pose(tmp):
    scene = toy(tmp)
    path = scene / "transforms.json"
    data = json.loads(path.read_text())
    data["frames"][3]["transform_matrix"][0][3] = float("nan")
    path.write_text(json.dumps(data))  # Python writes NaN, which JSON does not allow
    return build_args(scene)


def _non_rigid_pose(tmp):
    scene = toy(tmp)

    def scale_rotation(d):
        m = np.array(d["frames"][2]["transform_matrix"])
        m[:3, :3] *= 2.0
        d["frames"][2]["transform_matrix"] = m.tolist()

    edit_json(scene / "transforms.json", scale_rotation)
    return build_args(scene)


def _duplicate_frames(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d["frames"].append(dict(d["frames"][1])))
    return build_args(scene)


def _one_view(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(frames=d["frames"][:1]))
    return build_args(scene)


def _unknown_config_key(tmp):
    scene = toy(tmp)
    cfg = tmp / "cfg.json"
    cfg.write_text(json.dumps({"train": {"stepz": 3}}))
    return build_args(scene, "--config", str(cfg))


def _incompatible_checkpoint(tmp):
    build_dir = tmp / "old_build"
    build_dir.mkdir()
    torch.save({"format": "scenelabel.checkpoint", "format_version": 999, "scenelabel_version": "9.9"}, build_dir / "checkpoint.pt")
    return ["export", str(build_dir), str(tmp / "map.zarr")]


def _pickled_checkpoint(tmp):
    """A build folder from before checkpoints were read without pickle (format version 1)."""
    build_dir = tmp / "old_build"
    build_dir.mkdir()
    torch.save({"format": "scenelabel.checkpoint", "format_version": 1, "scenelabel_version": "0.1.0"}, build_dir / "checkpoint.pt")
    return ["export", str(build_dir), str(tmp / "map.zarr")]


def _output_not_writable(tmp):
    scene = toy(tmp)
    blocker = tmp / "a_file"
    blocker.write_text("not a folder")
    return build_args(scene, "--out", str(blocker / "out"))


def small_map(tmp: Path) -> Path:
    """A 4 x 4 x 4 map .zarr: a floor layer, FREE above."""
    from scenelabel import FREE, OccupancyMap

    label = np.full((4, 4, 4), FREE, np.int16)
    label[:, :, 0] = 1
    occupancy = (label >= 0).astype(np.float32)
    return OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], {1: "floor"}, 0.1).to_zarr(tmp / "map.zarr")


def _export_unknown_source(tmp):
    (tmp / "photos").mkdir()
    return ["export", str(tmp / "photos"), str(tmp / "out.zarr")]


def _export_voxel_size_of_a_map(tmp):
    return ["export", str(small_map(tmp)), str(tmp / "out.zarr"), "--voxel-size", "0.2"]


def _export_ply_suffix(tmp):
    return ["export", str(small_map(tmp)), str(tmp / "points.txt"), "--format", "ply"]


def _export_empty_band(tmp):
    return ["export", str(small_map(tmp)), str(tmp / "plan"), "--format", "nav2", "--z-min", "5", "--z-max", "6"]


def _export_octomap_out_of_range(tmp):
    """A map 5 km from the world origin at 0.1: beyond OctoMap's 65536 cells per axis (+-3276.8)."""
    from scenelabel import FREE, OccupancyMap

    label = np.full((4, 4, 4), FREE, np.int16)
    occ = OccupancyMap(label, np.zeros(label.shape, np.float32), 0.1, [5000.0, 0.0, 0.0], {1: "floor"}, 0.1)
    return ["export", str(occ.to_zarr(tmp / "far.zarr")), str(tmp / "far.bt")]


def _photos_that_do_not_register(tmp):
    photos = tmp / "photos"
    (photos / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):  # unrelated noise: structure from motion registers none of them
        Image.fromarray(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)).save(photos / "images" / f"{i}.png")
    return build_args(photos)


def _no_poses_one_photo(tmp):
    (tmp / "photos" / "images").mkdir(parents=True)
    Image.fromarray(np.zeros((18, 24, 3), np.uint8)).save(tmp / "photos" / "images" / "0.png")
    return build_args(tmp / "photos")


def _video_unreadable(tmp):
    clip = tmp / "clip.mp4"
    clip.write_text("not a video\n" * 20)
    return build_args(clip)


def _segmenter_spec_unknown(tmp):
    return ["segment", str(toy(tmp)), "--model", "caffe:model.prototxt"]


def _transforms_camera_model_unsupported(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(camera_model="FISHEYE624"))
    return build_args(scene)


def _transforms_is_fisheye_with_pinhole_model(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(camera_model="OPENCV", is_fisheye=True))
    return build_args(scene)


def _transforms_fisheye_with_tangential(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(camera_model="OPENCV_FISHEYE", k1=0.01, p1=0.002))
    return build_args(scene)


def _colmap_camera_model_unsupported(tmp):
    """A COLMAP model whose camera is THIN_PRISM_FISHEYE (neither a pinhole nor OpenCV's fisheye)."""
    import pycolmap

    scene = tmp / "colmap_scene"
    (scene / "images").mkdir(parents=True)
    reconstruction = pycolmap.Reconstruction()
    params = [20.0, 20.0, 12.0, 9.0, 0.1] + [0.0] * 7
    reconstruction.add_camera_with_trivial_rig(
        pycolmap.Camera(camera_id=1, model="THIN_PRISM_FISHEYE", width=24, height=18, params=params)
    )
    for i in range(2):
        name = f"{i}.png"
        Image.fromarray(np.zeros((18, 24, 3), np.uint8)).save(scene / "images" / name)
        w2c = np.eye(4)[:3]
        w2c[0, 3] = 0.1 * i
        image = pycolmap.Image(image_id=i + 1, name=name, camera_id=1, points2D=[])
        reconstruction.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c))
    (scene / "sparse" / "0").mkdir(parents=True)
    reconstruction.write_text(str(scene / "sparse" / "0"))
    return build_args(scene)


def _with_sensor_file(tmp, key: str, name: str, write=None, **top):
    """The toy scene with ``frames[1][key] = name`` (``write(path)`` creates the file) and top-level keys."""
    scene = toy(tmp)
    if write is not None:
        (scene / name).parent.mkdir(parents=True, exist_ok=True)
        write(scene / name)

    def edit(d):
        d["frames"][1][key] = name
        d.update(top)

    edit_json(scene / "transforms.json", edit)
    return build_args(scene)


def _png16(shape):
    return lambda path: Image.fromarray(np.full(shape, 2000, np.uint16)).save(path)


def _sensor_depth_missing(tmp):
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.png")


def _sensor_depth_unreadable(tmp):
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.png", lambda p: p.write_bytes(b"\x89PNG\r\n not a png"))


def _sensor_depth_channels(tmp):
    rgb = lambda p: Image.fromarray(np.zeros((18, 24, 3), np.uint8)).save(p)  # noqa: E731
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.png", rgb)


def _colour_exr(path):
    import OpenEXR

    ramp = np.linspace(1.0, 2.0, 18 * 24 * 3, dtype=np.float32).reshape(18, 24, 3)
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": ramp}) as exr:
        exr.write(str(path))


def _sensor_depth_colour_exr(tmp):
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.exr", _colour_exr)


def _sensor_depth_aspect(tmp):
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.png", _png16((10, 10)))


def _sensor_depth_scale(tmp):
    return _with_sensor_file(tmp, "depth_file_path", "depth/001.png", _png16((18, 24)), depth_unit_scale_factor=0)


def _mask_missing(tmp):
    return _with_sensor_file(tmp, "mask_path", "masks/001.png")


def _mask_aspect(tmp):
    return _with_sensor_file(tmp, "mask_path", "masks/001.png", lambda p: Image.fromarray(np.zeros((9, 9), np.uint8)).save(p))


def _applied_transform_not_rigid(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(applied_transform=[[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0]]))
    return build_args(scene)


def _split_files_without_train(tmp):
    """The Blender layout with transforms_val.json only."""
    scene = toy(tmp)
    (scene / "transforms.json").rename(scene / "transforms_val.json")
    return build_args(scene)


def _split_train_without_images(tmp):
    scene = toy(tmp)
    (scene / "transforms.json").rename(scene / "transforms_train.json")
    for p in (scene / "images").iterdir():
        p.unlink()
    return build_args(scene)


def _split_files_one_view(tmp):
    scene = toy(tmp)
    edit_json(scene / "transforms.json", lambda d: d.update(frames=d["frames"][:1]))
    (scene / "transforms.json").rename(scene / "transforms_train.json")
    return build_args(scene)


CASES = [
    Case("scene folder missing", _missing_folder, ("no_such_scene",)),
    Case("images/ empty", _empty_images, ("0 of 8 frames have an image file",)),
    Case("truncated image", _truncated_image, ("002.png",)),
    Case("image size differs from the intrinsics", _image_vs_intrinsics, ("000.png", "30")),
    Case("label map size differs from the image", _label_size, ("001.png",)),
    Case("label id not in classes.json", _label_id_unknown, ("002.png", "42")),
    Case("classes.json malformed", _classes_malformed, ("classes.json",)),
    Case("classes.json free_index is a class id", _free_index_is_a_class, ("classes.json", "free_index")),
    Case("transforms.json fails its schema", _transforms_schema, ("transforms.json", "transform_matrix")),
    Case("non-finite pose", _non_finite_pose, ("transforms.json",)),
    Case("non-rigid pose", _non_rigid_pose, ("transforms.json",)),
    Case("duplicate frames", _duplicate_frames, ("transforms.json",)),
    Case("fewer than 2 views", _one_view, ("2",)),
    Case("unknown config key", _unknown_config_key, ("stepz",)),
    Case("checkpoint from an incompatible version", _incompatible_checkpoint, ("checkpoint.pt", "not supported")),
    Case("pickled checkpoint (format version 1)", _pickled_checkpoint, ("checkpoint.pt", "upgrade-checkpoint")),
    Case("output path not writable", _output_not_writable, ("a_file",)),
    Case("photos only, too few register in SfM", _photos_that_do_not_register, ("registered only 0 of 3", "matcher=")),
    Case("no poses and a single photo", _no_poses_one_photo, ("no poses found", "at least 2 photos")),
    Case("video OpenCV cannot decode", _video_unreadable, ("clip.mp4", "cannot read the video")),
    Case("unknown segmenter spec", _segmenter_spec_unknown, ("caffe",)),
    Case("transforms.json camera_model not supported", _transforms_camera_model_unsupported,
         ("transforms.json", "FISHEYE624", "OPENCV_FISHEYE")),
    Case("transforms.json is_fisheye with a pinhole camera_model", _transforms_is_fisheye_with_pinhole_model,
         ("transforms.json", "is_fisheye", "pinhole model")),
    Case("transforms.json fisheye with p1 / p2", _transforms_fisheye_with_tangential,
         ("transforms.json", "p1", "k1, k2, k3, k4")),
    Case("COLMAP camera model not supported", _colmap_camera_model_unsupported,
         ("cameras.txt", "THIN_PRISM_FISHEYE", "OPENCV_FISHEYE", "image_undistorter")),
    Case("export input neither a build nor a map", _export_unknown_source, ("photos", "neither a build folder")),
    Case("export --voxel-size of a map", _export_voxel_size_of_a_map, ("map.zarr", "--voxel-size")),
    Case("export --format ply to a non-.ply file", _export_ply_suffix, ("points.txt", ".ply")),
    Case("export --format nav2 with an empty height band", _export_empty_band, ("no voxel layer",)),
    Case("export to OctoMap a map beyond its key range", _export_octomap_out_of_range, ("far.bt", "OctoMap's key range")),
    Case("sensor depth file missing (depth_file_path)", _sensor_depth_missing, ("transforms.json", "depth/001.png", "not found")),
    Case("sensor depth file unreadable", _sensor_depth_unreadable, ("001.png", "cannot read the depth image")),
    Case("sensor depth with 3 channels", _sensor_depth_channels, ("001.png", "one channel, got 3")),
    Case("sensor depth EXR in colour", _sensor_depth_colour_exr, ("001.exr", "one named Z, depth, Y", "B, G, R")),
    Case("sensor depth with another aspect than its image", _sensor_depth_aspect, ("001.png", "10x10", "aspect")),
    Case("depth_unit_scale_factor not positive", _sensor_depth_scale, ("transforms.json", "depth_unit_scale_factor")),
    Case("mask file missing (mask_path)", _mask_missing, ("transforms.json", "masks/001.png", "not found")),
    Case("mask with another aspect than its image", _mask_aspect, ("001.png", "9x9", "aspect")),
    Case("applied_transform not rigid", _applied_transform_not_rigid, ("transforms.json", "applied_transform", "rigid")),
    Case("split files without transforms_train.json", _split_files_without_train,
         ("transforms_train.json", "training views are missing")),
    Case("transforms_train.json with no image file", _split_train_without_images, ("transforms_train.json", "no training view")),
    Case("split files with a single view", _split_files_one_view, ("transforms_train.json", "at least 2 views")),
]
