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


def _segmenter_spec_unknown(tmp):
    return ["segment", str(toy(tmp)), "--model", "caffe:model.prototxt"]


CASES = [
    Case("scene folder missing", _missing_folder, ("no_such_scene",)),
    Case("images/ empty", _empty_images, ("0 of 8 frames have an image file",)),
    Case("truncated image", _truncated_image, ("002.png",)),
    Case("image size differs from the intrinsics", _image_vs_intrinsics, ("000.png", "30")),
    Case("label map size differs from the image", _label_size, ("001.png",)),
    Case("label id not in classes.json", _label_id_unknown, ("002.png", "42")),
    Case("classes.json malformed", _classes_malformed, ("classes.json",)),
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
    Case("unknown segmenter spec", _segmenter_spec_unknown, ("caffe",)),
    Case("export input neither a build nor a map", _export_unknown_source, ("photos", "neither a build folder")),
    Case("export --voxel-size of a map", _export_voxel_size_of_a_map, ("map.zarr", "--voxel-size")),
    Case("export --format ply to a non-.ply file", _export_ply_suffix, ("points.txt", ".ply")),
    Case("export --format nav2 with an empty height band", _export_empty_band, ("no voxel layer",)),
    Case("export to OctoMap a map beyond its key range", _export_octomap_out_of_range, ("far.bt", "OctoMap's key range")),
]
