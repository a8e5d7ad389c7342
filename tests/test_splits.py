"""The Blender-synthetic split layout (transforms_train / _val / _test.json) and RGBA images:
one scene with the input's splits, builds that train and evaluate on them, alpha composited on the
background in training and evaluation."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from shared_data import DATA

from scenelabel import build, preset, write_toy_scene
from scenelabel.config import render_background
from scenelabel.data.io import load_scene, load_transforms
from scenelabel.data.io.common import read_image_alpha, resize_area
from scenelabel.errors import InputError
from scenelabel.fields.checkpoint import load_checkpoint
from scenelabel.geometry.cameras import opengl_to_opencv
from scenelabel.train import trainer as trainer_module
from scenelabel.train.evaluation import evaluate
from scenelabel.train.losses import composite_target
from scenelabel.train.pipeline import choose_views, prepare_training

LEGO = DATA / "nerf_synthetic_lego"

SPLIT_OF_VIEW = ["train", "train", "val", "train", "train", "val", "train", "test"]
"""The split of each of the toy scene's 8 views."""

ANGLES = {"train": 2 * math.atan(16 / (2 * 34.31)), "val": 0.9, "test": 1.0}
"""camera_angle_x per split file (train: the toy's 50° render; val / test differ: intrinsics are per file)."""


def write_split_scene(root: Path, angles: dict[str, float] | None = None, transparent_colour=(0, 0, 0)) -> Path:
    """The toy scene (8 views, 32 x 24) rewritten in the Blender layout: ``<split>/r_<k>.png`` RGBA
    (alpha 0 where no surface, the stored colour there ``transparent_colour``), one transforms file
    per split (nerf-synthetic's ``file_path`` without extension, ``camera_angle_x``), labels and depths
    by ``label_path`` / ``depth_path``, the toy's aabb and near / far."""
    source = write_toy_scene(root.parent / (root.name + "_source"), n_train=7, n_test=1, width=32, height=24)
    data = json.loads((source / "transforms.json").read_text())
    root.mkdir(parents=True)
    (root / "classes.json").write_text((source / "classes.json").read_text())
    (root / "labels").mkdir()
    (root / "depths").mkdir()
    files: dict[str, dict] = {}
    for frame, split in zip(data["frames"], SPLIT_OF_VIEW):
        out = files.setdefault(split, {"camera_angle_x": (angles or ANGLES)[split], "aabb": data["aabb"], "frames": []})
        k = len(out["frames"])
        (root / split).mkdir(exist_ok=True)
        rgb = np.asarray(Image.open(source / frame["file_path"]))
        depth = np.load(source / frame["depth_path"])
        alpha = np.where(depth > 0, 255, 0).astype(np.uint8)
        rgb = np.where(alpha[..., None] > 0, rgb, np.asarray(transparent_colour, np.uint8))
        Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(root / split / f"r_{k}.png")
        Image.open(source / frame["label_path"]).save(root / "labels" / f"{split}_r_{k}.png")
        np.save(root / "depths" / f"{split}_r_{k}.npy", depth)
        out["frames"].append({
            "file_path": f"./{split}/r_{k}",
            "label_path": f"labels/{split}_r_{k}.png",
            "depth_path": f"depths/{split}_r_{k}.npy",
            "near": frame["near"],
            "far": frame["far"],
            "transform_matrix": frame["transform_matrix"],
        })
    for split, out in files.items():
        (root / f"transforms_{split}.json").write_text(json.dumps(out))
    return root


@pytest.fixture(scope="module")
def split_scene(tmp_path_factory) -> Path:
    return write_split_scene(tmp_path_factory.mktemp("splits") / "scene")


def load_quiet(path: Path, downscale: int = 1):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete split layout loads without warnings
        return load_scene(path, downscale)


def _without_test_images(tmp_path: Path) -> Path:
    root = write_split_scene(tmp_path / "scene")
    for path in (root / "test").iterdir():
        path.unlink()
    return root


# ------------------------------------------------------------------ loading


def test_split_files_load_as_one_scene_in_train_val_test_order(split_scene: Path) -> None:
    scene = load_quiet(split_scene)
    assert scene.names == ["train_r_0", "train_r_1", "train_r_2", "train_r_3", "train_r_4", "val_r_0", "val_r_1", "test_r_0"]
    assert scene.splits == {"train": [0, 1, 2, 3, 4], "val": [5, 6], "test": [7]}
    assert len(set(scene.names)) == len(scene)
    # views keep their poses (train, val, test order), OpenGL -> OpenCV as for transforms.json
    frames = [f for split in ("train", "val", "test")
              for f in json.loads((split_scene / f"transforms_{split}.json").read_text())["frames"]]
    for i, frame in enumerate(frames):
        np.testing.assert_allclose(scene.cameras.c2w[i], opengl_to_opencv(np.asarray(frame["transform_matrix"])))
    # intrinsics per file: each file's camera_angle_x
    for split, views in scene.splits.items():
        np.testing.assert_allclose(scene.cameras.fx[views], 0.5 * 32 / math.tan(0.5 * ANGLES[split]))
    assert scene.info["split_source"] == "input files: transforms_train.json, transforms_val.json, transforms_test.json"
    assert scene.info["splits"]["val"] == {"file": "transforms_val.json", "views": 2, "frames_listed": 2, "skipped_frames": 0,
                                           "image_folder": "val"}
    assert scene.info["source"] == str(split_scene) and scene.info["image_folder"] == "."
    assert scene.info["labelled_views"] == 8 and scene.info["depth_views"] == 8
    assert all(label is not None for label in scene.labels) and all(d is not None for d in scene.depths)
    np.testing.assert_allclose(scene.aabb, json.loads((split_scene / "transforms_train.json").read_text())["aabb"])
    # load_transforms on the folder is the same scene
    assert load_transforms(split_scene).names == scene.names


def test_rgba_images_keep_their_alpha(split_scene: Path) -> None:
    scene = load_quiet(split_scene)
    assert scene.image_alphas is not None and len(scene.image_alphas) == len(scene)
    for i in range(len(scene)):
        alpha = scene.image_alphas[i]
        assert alpha.dtype == np.float32 and alpha.shape == (24, 32)
        np.testing.assert_array_equal(alpha, (scene.depths[i] > 0).astype(np.float32))
        np.testing.assert_array_equal(scene.images[i][alpha == 0], 0.0)  # the stored colour, not composited


def test_a_single_split_file_loads_that_file_alone(split_scene: Path) -> None:
    scene = load_quiet(split_scene / "transforms_val.json")
    assert scene.names == ["r_0", "r_1"] and scene.splits is None
    np.testing.assert_allclose(scene.cameras.fx, 0.5 * 32 / math.tan(0.5 * ANGLES["val"]))


def test_transforms_json_beside_split_files_wins(split_scene: Path, tmp_path: Path) -> None:
    root = tmp_path / "both"
    root.mkdir()
    for item in split_scene.iterdir():
        (root / item.name).symlink_to(item)
    data = json.loads((split_scene / "transforms_train.json").read_text())
    (root / "transforms.json").write_text(json.dumps(data))
    scene = load_quiet(root)
    assert scene.splits is None and scene.names == [f"r_{k}" for k in range(5)]


def test_a_split_without_images_is_empty_and_warns_once(tmp_path: Path) -> None:
    root = _without_test_images(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(root)
    messages = [str(w.message) for w in caught]
    assert messages == ["1 of 1 frames in transforms_test.json have no image file; the test split is empty"]
    assert scene.splits == {"train": [0, 1, 2, 3, 4], "val": [5, 6], "test": []}
    assert scene.info["splits"]["test"]["skipped_frames"] == 1 and scene.info["skipped_frames"] == 1


def test_split_layout_errors(tmp_path: Path) -> None:
    root = write_split_scene(tmp_path / "scene")
    (root / "transforms_train.json").rename(root / "train.json")
    with pytest.raises(InputError, match="no transforms_train.json") as info:
        load_scene(root)
    assert info.value.path == root / "transforms_train.json"
    (root / "train.json").rename(root / "transforms_train.json")
    for path in (root / "train").iterdir():
        path.unlink()
    with pytest.raises(InputError, match="none of the 5 frames has an image file: no training view"):
        load_scene(root)


def test_downscaled_alpha_composites_like_the_downscaled_composite(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 256, (12, 16, 4), dtype=np.uint8)
    rgba[:4, :, 3] = 0  # a transparent band: its (random) stored colour must not leak
    rgba[4:8, :, 3] = 255
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    rgb, alpha = read_image_alpha(tmp_path / "a.png", size=(4, 3))
    full_rgb, full_alpha = rgba[..., :3] / 255.0, rgba[..., 3] / 255.0
    np.testing.assert_allclose(alpha, resize_area(full_alpha[..., None].astype(np.float32), 4, 3)[..., 0], atol=1e-6)
    for background in ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.2, 0.7, 0.4)):
        bg = np.asarray(background, np.float32)
        composite_then_resize = resize_area(composite_target(full_rgb, full_alpha, bg).astype(np.float32), 4, 3)
        np.testing.assert_allclose(composite_target(rgb, alpha, bg), composite_then_resize, atol=1e-5)


def test_rgb_and_opaque_rgba_images_have_no_alpha(tmp_path: Path) -> None:
    pixels = np.full((3, 4, 4), 90, np.uint8)
    pixels[..., 3] = 255
    Image.fromarray(pixels, "RGBA").save(tmp_path / "opaque.png")
    Image.fromarray(pixels[..., :3]).save(tmp_path / "rgb.png")
    la = np.stack([np.full((3, 4), 50, np.uint8), np.full((3, 4), 51, np.uint8)], -1)
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    for name in ("opaque.png", "rgb.png"):
        rgb, alpha = read_image_alpha(tmp_path / name)
        assert alpha is None
        np.testing.assert_allclose(rgb, 90 / 255.0, atol=1e-7)
    rgb, alpha = read_image_alpha(tmp_path / "la.png")
    np.testing.assert_allclose(rgb, 50 / 255.0, atol=1e-7)
    np.testing.assert_allclose(alpha, 51 / 255.0, atol=1e-7)


# ------------------------------------------------------------------ the target colour


def test_composite_target_alpha_zero_is_the_background_alpha_one_the_pixel() -> None:
    rgb = torch.tensor([[0.9, 0.1, 0.3], [0.9, 0.1, 0.3], [0.9, 0.1, 0.3]])
    alpha = torch.tensor([0.0, 1.0, 0.25])
    bg = torch.tensor([0.2, 0.4, 0.6])
    out = composite_target(rgb, alpha, bg)
    torch.testing.assert_close(out[0], bg)
    torch.testing.assert_close(out[1], rgb[1])
    torch.testing.assert_close(out[2], 0.25 * rgb[2] + 0.75 * bg)
    per_ray = torch.rand(3, 3, generator=torch.Generator().manual_seed(0))  # "random": one colour per ray
    torch.testing.assert_close(composite_target(rgb, alpha, per_ray)[0], per_ray[0])
    torch.testing.assert_close(composite_target(rgb, alpha, None)[0], torch.zeros(3))  # None: black
    assert composite_target(rgb, None, bg) is rgb  # opaque images: the target is the pixel itself
    np.testing.assert_allclose(composite_target(np.zeros((2, 2, 3)), np.zeros((2, 2)), np.ones(3, np.float32)), 1.0)
    assert render_background("random") == (1.0, 1.0, 1.0) and render_background(None) is None
    assert render_background([0, 0.5, 1]) == (0.0, 0.5, 1.0)


def _quick(**train) -> object:
    return preset("quick", {
        "sampling": {"n_steps": 32, "grid_resolution": 16},
        "train": {"steps": 2, "batch_rays": 64, "log_every": 1, **train},
        "output": {"write_map": False},
    })


def test_transparent_pixels_train_toward_the_background(split_scene: Path, monkeypatch) -> None:
    scene = load_quiet(split_scene)
    scene.image_alphas = [np.zeros_like(a) for a in scene.image_alphas]  # every pixel transparent
    targets = []
    real = trainer_module.photometric_mse
    monkeypatch.setattr(trainer_module, "photometric_mse", lambda rgb, target, weights=None: targets.append(target) or real(rgb, target, weights))
    trainer, _, _ = prepare_training(scene, _quick(background=[0.2, 0.4, 0.6]), torch.device("cpu"))
    assert trainer.rays.alpha is not None and float(trainer.rays.alpha.max()) == 0.0
    trainer.train_step()
    assert len(targets) == 1 and targets[0].shape == (64, 3)
    torch.testing.assert_close(targets[0], torch.tensor([0.2, 0.4, 0.6]).expand(64, 3))


def test_opaque_scenes_train_on_the_pixels_unchanged(tmp_path: Path, monkeypatch) -> None:
    scene = load_quiet(write_toy_scene(tmp_path / "toy", n_train=7, n_test=1, width=32, height=24))
    assert scene.image_alphas is None
    targets = []
    real = trainer_module.photometric_mse
    monkeypatch.setattr(trainer_module, "photometric_mse", lambda rgb, target, weights=None: targets.append(target) or real(rgb, target, weights))
    trainer, _, _ = prepare_training(scene, _quick(), torch.device("cpu"))
    assert trainer.rays.alpha is None
    trainer.train_step()
    assert len(targets) == 1 and targets[0].shape == (64, 3)
    # every target is exactly a training pixel's stored colour
    assert bool((targets[0][:, None, :] == trainer.rays.rgb[None]).all(-1).any(-1).all())


# ------------------------------------------------------------------ builds


def test_choose_views_uses_the_input_splits(split_scene: Path, tmp_path: Path) -> None:
    scene = load_quiet(split_scene)
    assert choose_views(scene, 8) == ([0, 1, 2, 3, 4], [7], "input files: train, test held out")
    scene.splits = {"train": [0, 1, 2, 3, 4], "val": [5, 6], "test": []}
    assert choose_views(scene, 8) == ([0, 1, 2, 3, 4], [5, 6], "input files: train, val held out")
    scene.splits = {"train": [0, 1, 2, 3, 4, 5, 6, 7], "val": [], "test": []}
    assert choose_views(scene, 2)[1:] == ([], "input files: train, none held out")
    scene.splits = {"train": [], "val": [0], "test": [1]}
    with pytest.raises(InputError, match="train split is empty"):
        choose_views(scene, 8)
    scene.splits = None
    assert choose_views(scene, 4) == ([1, 2, 3, 5, 6, 7], [0, 4], "train.holdout = 4: views 0, 4, 8, ... held out")


def test_a_build_trains_and_evaluates_on_the_input_splits_and_resumes(tmp_path: Path) -> None:
    root = _without_test_images(tmp_path)
    config = _quick(holdout=2)  # not used: the input has splits
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the empty test split
        result = build(root, tmp_path / "out", config, progress=False, device="cpu")
    meta = load_checkpoint(tmp_path / "out").meta
    assert meta["train_views"] == [f"train_r_{k}" for k in range(5)]
    assert meta["test_views"] == ["val_r_0", "val_r_1"]  # the test split is empty: held out = val
    assert meta["split"] == "input files: train, val held out"
    assert meta["scene_info"]["split_source"].startswith("input files: transforms_train.json")
    assert result.metrics["n_test_views"] == 2 and result.metrics["n_train_views"] == 5
    assert [v["view"] for v in result.metrics["per_view"]] == ["val_r_0", "val_r_1"]
    assert sorted(p.name for p in (tmp_path / "out" / "renders").iterdir() if p.name.startswith("val")) == [
        "val_r_0.png", "val_r_1.png"]
    config.train.steps = 3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        resumed = build(root, tmp_path / "out", config, progress=False, device="cpu", resume=True)
    assert resumed.metrics["steps"] == 3 and load_checkpoint(tmp_path / "out").meta["train_views"] == meta["train_views"]


def test_evaluation_composites_the_ground_truth_on_the_render_background(tmp_path: Path) -> None:
    root = write_split_scene(tmp_path / "scene", transparent_colour=(255, 0, 255))  # magenta under alpha 0
    result = build(root, tmp_path / "out", _quick(background="random"), progress=False, device="cpu")
    scene = load_quiet(root)
    test = scene.splits["test"]
    composited = load_quiet(root)
    white = np.ones(3, np.float32)  # "random" training renders on white
    composited.images = [composite_target(im, a, white) for im, a in zip(scene.images, scene.image_alphas)]
    composited.image_alphas = None
    with_alpha = evaluate(result.field, scene, test, None, None)
    on_white = evaluate(result.field, composited, test, None, None)
    assert with_alpha["psnr"] == pytest.approx(on_white["psnr"], abs=1e-6)
    scene.image_alphas = None  # the magenta stored under transparent pixels, not composited: a different score
    assert abs(evaluate(result.field, scene, test, None, None)["psnr"] - with_alpha["psnr"]) > 0.5


# ------------------------------------------------------------------ nerf-synthetic lego


@pytest.mark.skipif(not LEGO.is_dir(), reason="../shared/data/nerf_synthetic_lego is absent")
def test_lego_loads_train_and_val_with_an_empty_test_split() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(LEGO, downscale=8)
    assert [str(w.message) for w in caught] == [
        "200 of 200 frames in transforms_test.json have no image file; the test split is empty"]
    assert scene.splits == {"train": list(range(100)), "val": list(range(100, 200)), "test": []}
    assert scene.names[0] == "train_r_0" and scene.names[100] == "val_r_0" and len(set(scene.names)) == 200
    assert scene.images[0].shape == (100, 100, 3) and scene.image_alphas is not None
    alpha = scene.image_alphas[0]
    assert alpha.shape == (100, 100) and alpha.min() == 0.0 and alpha.max() == 1.0
    angle = json.loads((LEGO / "transforms_train.json").read_text())["camera_angle_x"]
    np.testing.assert_allclose(scene.cameras.fx, 0.5 * 100 / math.tan(0.5 * angle))
    train, test, rule = choose_views(scene, 8)
    assert train == list(range(100)) and test == list(range(100, 200)) and rule == "input files: train, val held out"


def test_the_viewer_finds_the_photos_of_split_views(split_scene: Path, tmp_path: Path) -> None:
    """Views named ``<split>_r_<k>`` have their photo at ``<split>/r_<k>.png``: the viewer's frusta find it."""
    from scenelabel.data.io.transforms_json import split_view_parts
    from scenelabel.viz.viewer import find_view_images, view_image_candidates

    scene = load_quiet(split_scene)
    assert split_view_parts("train_r_0", scene.info["splits"]) == ("train", "r_0")
    assert split_view_parts("r_0", scene.info["splits"]) is None
    build_dir = tmp_path / "elsewhere" / "build"  # nothing beside it: only scene_info leads to the photos
    photos = find_view_images(view_image_candidates(build_dir, {"scene_info": scene.info}, scene.names))
    assert all(photo is not None for photo in photos)
    for name, photo, image in zip(scene.names, photos, scene.images):
        split, stem = split_view_parts(name, scene.info["splits"])
        on_disk = np.asarray(Image.open(split_scene / split / f"{stem}.png").convert("RGB"))
        np.testing.assert_array_equal(photo, on_disk)
