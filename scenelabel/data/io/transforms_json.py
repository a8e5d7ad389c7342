"""Loader for ``transforms.json`` scenes (nerfstudio / instant-ngp / nerf-synthetic).

The file is validated against scenelabel/schemas/transforms.schema.json (which documents every key
and scenelabel's extensions: ``frames[].label_path``, ``frames[].depth_path``, ``near``, ``far``,
``aabb``, ``frame_id``). Conversions into docs/conventions.md:

- ``transform_matrix`` is camera-to-world in OpenGL camera axes (x right, y up, looking down -z);
  scenelabel's ``c2w = T @ diag(1, -1, -1, 1)`` (OpenCV axes: x right, y down, z forward).
- intrinsics: global ``fl_x fl_y cx cy w h`` with per-frame overrides; ``fl_x`` falls back to
  ``camera_angle_x`` (``fl_x = w / (2 tan(camera_angle_x / 2))``), ``fl_y`` to ``camera_angle_y``
  then ``fl_x``, ``cx``/``cy`` to ``w/2``/``h/2``, ``w``/``h`` to the image file's size.
- camera models (docs/conventions.md, "Camera models"): a pinhole with OpenCV ``k1 k2 p1 p2``
  (``camera_model`` absent or one of SUPPORTED_CAMERA_MODELS), or OpenCV's equidistant fisheye
  with ``k1 k2 k3 k4`` (``camera_model: OPENCV_FISHEYE``, or instant-ngp's ``is_fisheye: true``);
  coefficients per frame like the other intrinsics, unchanged by ``downscale`` (they act on
  normalised coordinates). Other models (EQUIRECTANGULAR, FISHEYE624, ...) are rejected.
- ``downscale = d``: images area-resampled, labels and depths nearest, to ``(w // d, h // d)``;
  intrinsics scale by new_size / old_size per axis (pixel centres at +0.5, so ``cx' = cx * sx``).
- near / far: distances along the unit ray, NaN where the file does not say.
- nerfstudio's per-frame ``depth_file_path`` (z-depth, times ``depth_unit_scale_factor``) and
  ``mask_path`` fill ``Scene.sensor_depths`` (distance along the ray) and ``Scene.masks`` at the
  training resolution (:mod:`scenelabel.data.io.depth`); ``applied_transform`` is recorded in
  ``info`` and undone with ``world_frame="original"`` (:mod:`scenelabel.data.io.applied_transform`).
  ``depth_path`` (scenelabel's ground truth, distance along the ray) fills ``Scene.depths``.

Frames are kept in file order. Frames whose image file is missing are skipped with one warning.

The Blender-synthetic layout (a folder with ``transforms_train.json`` / ``_val`` / ``_test`` and no
``transforms.json``) loads as one scene (:func:`load_split_transforms`): each file with its own
intrinsics, views in the order train, val, test, named ``<split>_<image stem>``, and
``Scene.splits`` listing each split's views (a build trains on ``train`` and evaluates on ``test``,
or on ``val`` when the test split is empty). Passing one split file loads that file alone.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from scenelabel.data.io.applied_transform import (
    WORLD_FRAMES,
    applied_transform_of,
    original_frame_aabb,
    original_frame_c2w,
)
from scenelabel.data.io.common import (
    LABEL_SUFFIX,
    ViewFiles,
    alphas_or_none,
    check_downscale,
    check_pose,
    image_size,
    load_json,
    read_view,
    resolve_image_path,
    scaled_size,
    scene_classes,
    validate_json,
)
from scenelabel.data.io.depth import SensorFiles, frame_sensor_files, read_sensor_inputs
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, opengl_to_opencv
from scenelabel.geometry.lens import FISHEYE, PINHOLE

__all__ = [
    "TRANSFORMS_FILE",
    "SPLIT_FILES",
    "SUPPORTED_CAMERA_MODELS",
    "FISHEYE_CAMERA_MODELS",
    "load_transforms",
    "load_split_transforms",
    "split_files",
    "split_view_name",
    "split_view_parts",
]

#: The file this loader reads from a scene folder.
TRANSFORMS_FILE = "transforms.json"

#: nerfstudio / COLMAP camera models that are a pinhole with (at most) OpenCV k1 k2 p1 p2.
SUPPORTED_CAMERA_MODELS = frozenset({"PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "RADIAL", "SIMPLE_RADIAL"})

#: nerfstudio / COLMAP camera models that are OpenCV's equidistant fisheye (k1 k2 k3 k4; COLMAP's
#: SIMPLE_RADIAL_FISHEYE and RADIAL_FISHEYE are the same model with k1 or k1, k2 only).
FISHEYE_CAMERA_MODELS = frozenset({"OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"})

#: Distortion keys scenelabel's pinhole cameras carry (Cameras.distortion order) ...
DISTORTION_KEYS = ("k1", "k2", "p1", "p2")
#: ... and keys of higher-order models that must be absent or zero.
UNSUPPORTED_DISTORTION_KEYS = ("k3", "k4", "k5", "k6")
#: The same for a fisheye camera: its coefficients, and keys it has no use for.
FISHEYE_DISTORTION_KEYS = ("k1", "k2", "k3", "k4")
FISHEYE_UNSUPPORTED_DISTORTION_KEYS = ("p1", "p2", "k5", "k6")

#: How many missing file names a warning lists before "...".
_LIST_LIMIT = 3


@dataclass(frozen=True)
class _Intrinsics:
    """One frame's camera at image-file resolution."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, float, float, float]
    near: float
    far: float
    model: str = PINHOLE  # Cameras.model: "pinhole" (k1 k2 p1 p2) or "fisheye" (k1 k2 k3 k4)


def _lookup(frame: dict, data: dict, key: str) -> Any:
    """Per-frame value of ``key``, else the global one, else None (nerfstudio overrides)."""
    return frame[key] if key in frame else data.get(key)


def _check_camera_model(data: dict, path: Path) -> str | None:
    """Reject camera models other than pinholes (OpenCV k1 k2 p1 p2) and OpenCV fisheyes, and
    ``is_fisheye`` beside a pinhole model; return the model name (or None)."""
    model = data.get("camera_model")
    known = SUPPORTED_CAMERA_MODELS | FISHEYE_CAMERA_MODELS
    if model is not None and model.upper() not in known:
        raise InputError(
            f"camera_model {model!r} is not supported; supported: {', '.join(sorted(known))} (pinholes with OpenCV "
            f"k1, k2, p1, p2; OpenCV fisheyes with k1, k2, k3, k4)",
            path,
            field="$.camera_model",
        )
    if data.get("is_fisheye") and model is not None and model.upper() in SUPPORTED_CAMERA_MODELS:
        raise InputError(f"is_fisheye is true but camera_model {model!r} is a pinhole model", path, field="$.is_fisheye")
    return model


def _lens_model(data: dict) -> str:
    """The Cameras.model of a (checked) transforms file: "fisheye" for a fisheye camera_model or
    ``is_fisheye: true``, else "pinhole"."""
    model = data.get("camera_model")
    fisheye = bool(data.get("is_fisheye")) or (model is not None and model.upper() in FISHEYE_CAMERA_MODELS)
    return FISHEYE if fisheye else PINHOLE


def _check_aabb(data: dict, path: Path) -> np.ndarray | None:
    """The explicit scene bounds [2, 3] (min corner, max corner), or None."""
    if "aabb" not in data:
        return None
    aabb = np.asarray(data["aabb"], dtype=np.float64)
    if np.any(aabb[0] >= aabb[1]):
        raise InputError(f"aabb min corner must be below the max corner on every axis, got {aabb.tolist()}", path, field="$.aabb")
    return aabb


def _check_duplicates(frames: list[dict], path: Path) -> None:
    """Raise InputError if two frames name the same image file."""
    seen: dict[str, int] = {}
    for index, frame in enumerate(frames):
        key = os.path.normpath(frame["file_path"])
        if key in seen:
            raise InputError(
                f"duplicate frame: file_path {frame['file_path']!r} appears in frames {seen[key]} and {index}",
                path,
                field=f"$.frames[{index}].file_path",
            )
        seen[key] = index


def _integer_size(value: Any, path: Path, field: str) -> int | None:
    """An image size given as a number (1080 or 1080.0) -> int; a fractional value is an error."""
    if value is None:
        return None
    if float(value) != int(value):
        raise InputError(f"image size must be a whole number of pixels, got {value}", path, field=field)
    return int(value)


def _frame_intrinsics(data: dict, frame: dict, index: int, file_size: tuple[int, int], image: Path, path: Path) -> _Intrinsics:
    """Resolve one frame's intrinsics (per-frame overrides, fallbacks) and check the image size."""
    field = f"$.frames[{index}]"
    width = _integer_size(_lookup(frame, data, "w"), path, field + ".w") or file_size[0]
    height = _integer_size(_lookup(frame, data, "h"), path, field + ".h") or file_size[1]
    if (width, height) != tuple(file_size):
        raise InputError(
            f"image size {file_size[0]}x{file_size[1]} differs from the intrinsics w x h = {width}x{height} "
            f"in {path.name}",
            image,
        )
    fx = _lookup(frame, data, "fl_x")
    if fx is None:
        angle = _lookup(frame, data, "camera_angle_x")
        if angle is None:
            raise InputError("no focal length: give fl_x or camera_angle_x", path, field=field + ".fl_x")
        fx = 0.5 * width / math.tan(0.5 * angle)
    fy = _lookup(frame, data, "fl_y")
    if fy is None:
        angle = _lookup(frame, data, "camera_angle_y")
        fy = fx if angle is None else 0.5 * height / math.tan(0.5 * angle)
    cx = _lookup(frame, data, "cx")
    cy = _lookup(frame, data, "cy")
    lens = _lens_model(data)
    keys, refused = (
        (FISHEYE_DISTORTION_KEYS, FISHEYE_UNSUPPORTED_DISTORTION_KEYS)
        if lens == FISHEYE
        else (DISTORTION_KEYS, UNSUPPORTED_DISTORTION_KEYS)
    )
    for key in refused:
        if _lookup(frame, data, key):
            supported = "an OpenCV fisheye has only k1, k2, k3, k4" if lens == FISHEYE else "only OpenCV k1, k2, p1, p2 are supported"
            raise InputError(
                f"distortion coefficient {key} is non-zero; {supported}",
                path,
                field=f"{field}.{key}" if key in frame else f"$.{key}",
            )
    distortion = tuple(float(_lookup(frame, data, key) or 0.0) for key in keys)
    near = _lookup(frame, data, "near")
    far = _lookup(frame, data, "far")
    if near is not None and far is not None and not near < far:
        raise InputError(f"near ({near}) must be smaller than far ({far})", path, field=field)
    return _Intrinsics(
        fx=float(fx),
        fy=float(fy),
        cx=width / 2.0 if cx is None else float(cx),
        cy=height / 2.0 if cy is None else float(cy),
        width=width,
        height=height,
        distortion=distortion,  # type: ignore[arg-type]
        near=math.nan if near is None else float(near),
        far=math.nan if far is None else float(far),
        model=lens,
    )


def _frame_files(root: Path, frame: dict, index: int, image: Path, path: Path) -> ViewFiles:
    """Image, label and depth files of one frame.

    The label is ``frames[].label_path`` (which must exist) or else ``labels/<image stem>.png``
    when that exists; the depth is ``frames[].depth_path``.
    """
    label = None
    if "label_path" in frame:
        label = root / frame["label_path"]
        if not label.is_file():
            raise InputError(f"label file {frame['label_path']!r} not found", path, field=f"$.frames[{index}].label_path")
    else:
        default = root / "labels" / (image.stem + LABEL_SUFFIX)
        label = default if default.is_file() else None
    depth = None
    if "depth_path" in frame:
        depth = root / frame["depth_path"]
        if not depth.is_file():
            raise InputError(f"depth file {frame['depth_path']!r} not found", path, field=f"$.frames[{index}].depth_path")
    return ViewFiles(name=image.stem, image=image, label=label, depth=depth)


def _scaled(intr: _Intrinsics, size: tuple[int, int]) -> _Intrinsics:
    """Intrinsics for the image resampled (same extent) to ``size`` = (width, height)."""
    sx, sy = size[0] / intr.width, size[1] / intr.height
    return _Intrinsics(
        fx=intr.fx * sx,
        fy=intr.fy * sy,
        cx=intr.cx * sx,
        cy=intr.cy * sy,
        width=size[0],
        height=size[1],
        distortion=intr.distortion,
        near=intr.near,
        far=intr.far,
        model=intr.model,
    )


def _image_folder(root: Path, images: list[Path]) -> str:
    """The folder (relative to root, POSIX) holding all the images, e.g. 'images'."""
    common = os.path.commonpath([str(p.parent) for p in images])
    try:
        return PurePosixPath(Path(common).relative_to(root)).as_posix()
    except ValueError:
        return common


def _load_transforms_file(
    path: str | Path, downscale: int = 1, min_views: int = 2, world_frame: str = "transforms"
) -> Scene:
    """Load one transforms-style JSON file (or a folder's ``transforms.json``) into scenelabel's
    conventions (see the module docstring); :func:`load_transforms` is the entry point.

    Args:
        path: the scene folder (holding ``transforms.json``) or the JSON file itself
            (e.g. nerf-synthetic's ``transforms_train.json``); paths inside are relative to its folder.
        downscale: integer factor to shrink images, labels, depths and intrinsics by.
        min_views: frames with an image file needed (2 for a scene; 1 for one split of a split layout).
        world_frame: "transforms" (the transform_matrix frame) or "original" (applied_transform undone).
    Returns:
        a Scene; ``info`` holds format, source, image_folder, downscale, frames_listed,
        skipped_frames, camera_model, labelled_views, depth_views, class_colors, sensor_depth_views,
        masked_views, depth_unit_scale_factors, applied_transform (4x4 or None),
        applied_transform_source, world_frame.
    Raises:
        InputError: for every malformed or inconsistent input, naming the file and the problem.
    Warns:
        UserWarning: once, counting frames whose image file is missing (they are skipped).
    """
    downscale = check_downscale(downscale)
    path = Path(path)
    if path.is_dir():
        path = path / TRANSFORMS_FILE
    root = path.parent
    data = load_json(path)
    validate_json(data, "transforms", path)
    camera_model = _check_camera_model(data, path)
    aabb = _check_aabb(data, path)
    applied, applied_source = applied_transform_of(data, root, path)
    frames: list[dict] = data["frames"]
    _check_duplicates(frames, path)

    kept: list[tuple[int, dict, Path]] = []
    missing: list[str] = []
    for index, frame in enumerate(frames):
        image = resolve_image_path(root, frame["file_path"])
        if image is None:
            missing.append(frame["file_path"])
        else:
            kept.append((index, frame, image))
    if missing:
        listed = ", ".join(missing[:_LIST_LIMIT]) + (", ..." if len(missing) > _LIST_LIMIT else "")
        warnings.warn(
            f"{len(missing)} of {len(frames)} frames in {path.name} have no image file; skipped ({listed})",
            UserWarning,
            stacklevel=3,
        )
    if len(kept) < min_views:
        raise InputError(
            f"only {len(kept)} of {len(frames)} frames have an image file; at least {min_views} views are needed", path
        )

    c2ws, intrinsics, files, file_sizes = [], [], [], []
    sensor_files: list[SensorFiles] = []
    for index, frame, image in kept:
        pose = check_pose(frame["transform_matrix"], path, f"$.frames[{index}].transform_matrix")
        c2ws.append(opengl_to_opencv(pose))
        file_size = image_size(image)
        intr = _frame_intrinsics(data, frame, index, file_size, image, path)
        intrinsics.append(_scaled(intr, scaled_size(intr.width, intr.height, downscale)))
        files.append(_frame_files(root, frame, index, image, path))
        sensor_files.append(frame_sensor_files(root, data, frame, index, path))
        file_sizes.append(file_size)

    vocabulary = scene_classes(root, labelled=any(f.label is not None for f in files))
    images, labels, depths, alphas = [], [], [], []
    for view, file_size, intr in zip(files, file_sizes, intrinsics):
        image, label, depth, alpha = read_view(view, file_size, (intr.width, intr.height), vocabulary)
        images.append(image)
        labels.append(label)
        depths.append(depth)
        alphas.append(alpha)

    poses = np.stack(c2ws)
    if world_frame == "original" and applied is not None:
        poses = original_frame_c2w(poses, applied)
        aabb = None if aabb is None else original_frame_aabb(aabb, applied)
    cameras = Cameras.create(
        poses,
        fx=[i.fx for i in intrinsics],
        fy=[i.fy for i in intrinsics],
        cx=[i.cx for i in intrinsics],
        cy=[i.cy for i in intrinsics],
        width=[i.width for i in intrinsics],
        height=[i.height for i in intrinsics],
        distortion=np.array([i.distortion for i in intrinsics], dtype=np.float64),
        near=[i.near for i in intrinsics],
        far=[i.far for i in intrinsics],
        model=[i.model for i in intrinsics],
    )
    sensor_depths, masks, sensor_info = read_sensor_inputs(sensor_files, file_sizes, cameras, path)
    info = {
        "format": "transforms.json",
        "source": str(path),
        "image_folder": _image_folder(root, [f.image for f in files]),
        "downscale": downscale,
        "frames_listed": len(frames),
        "skipped_frames": len(missing),
        "camera_model": camera_model,
        "labelled_views": sum(label is not None for label in labels),
        "depth_views": sum(depth is not None for depth in depths),
        "class_colors": dict(vocabulary.colors),
        **sensor_info,
        "applied_transform": None if applied is None else applied.tolist(),
        "applied_transform_source": applied_source,
        "world_frame": world_frame,
    }
    return Scene(
        root=root,
        cameras=cameras,
        names=[f.name for f in files],
        images=images,
        labels=labels,
        depths=depths,
        classes=dict(vocabulary.classes),
        ignore_index=vocabulary.ignore_index,
        aabb=aabb,
        frame_id=data.get("frame_id", "world"),
        info=info,
        sensor_depths=sensor_depths,
        masks=masks,
        image_alphas=alphas_or_none(alphas),
    )


# --------------------------------------------------------------------------------------------
# the Blender-synthetic split layout: transforms_train / _val / _test.json, one scene


#: The split files of the Blender-synthetic (nerf-synthetic) layout, in the order their views are loaded.
SPLIT_FILES: dict[str, str] = {"train": "transforms_train.json", "val": "transforms_val.json", "test": "transforms_test.json"}


def split_files(folder: str | Path) -> dict[str, Path]:
    """The split files present in ``folder`` (split -> path, in SPLIT_FILES order); empty when none."""
    folder = Path(folder)
    return {split: folder / name for split, name in SPLIT_FILES.items() if (folder / name).is_file()}


def split_view_name(split: str, name: str) -> str:
    """A view's name in a split layout: ``<split>_<image stem>`` (nerf-synthetic's ``r_0`` is in
    every split), unique across splits and usable as a file name (renders/<name>.png)."""
    return f"{split}_{name}"


def split_view_parts(name: str, splits) -> tuple[str, str] | None:
    """(split, image stem) of a view named by :func:`split_view_name`, for the ``splits`` given
    (their names); None for a name of none of them."""
    for split in splits:
        if name.startswith(f"{split}_"):
            return split, name[len(split) + 1 :]
    return None


def load_transforms(path: str | Path, downscale: int = 1, world_frame: str = "transforms") -> Scene:
    """Load a transforms.json scene into scenelabel's conventions (see the module docstring).

    Args:
        path: the scene folder, or a transforms-style JSON file (e.g. nerf-synthetic's
            ``transforms_train.json``: that file alone); paths inside are relative to its folder.
            A folder with ``transforms.json`` loads that file; a folder without it but with split
            files (``transforms_train.json``, ``_val``, ``_test``) loads them all as one scene with
            ``Scene.splits`` (:func:`load_split_transforms`).
        downscale: integer factor to shrink images, labels, depths and intrinsics by.
        world_frame: "transforms" (default): the world frame is the ``transform_matrix`` frame (what
            nerfstudio's tools show); "original": poses (and ``aabb``) are taken back through the
            file's ``applied_transform`` to the frame before ``ns-process-data`` (e.g. COLMAP's),
            :mod:`scenelabel.data.io.applied_transform`. Either way ``info["applied_transform"]``
            records it (a split layout: per file).
    Returns:
        a Scene; ``info`` holds format, source, image_folder, downscale, frames_listed,
        skipped_frames, camera_model, labelled_views, depth_views, class_colors, sensor_depth_views,
        masked_views, depth_unit_scale_factors, applied_transform, applied_transform_source,
        world_frame (and for a split layout split_source and splits).
    Raises:
        InputError: for every malformed or inconsistent input, naming the file and the problem.
    Warns:
        UserWarning: once per file, counting frames whose image file is missing (they are skipped).
    """
    downscale = check_downscale(downscale)
    if world_frame not in WORLD_FRAMES:
        raise InputError(f"must be one of {', '.join(WORLD_FRAMES)}, got {world_frame!r}", field="world_frame")
    path = Path(path)
    if path.is_dir() and not (path / TRANSFORMS_FILE).is_file() and split_files(path):
        return load_split_transforms(path, downscale, world_frame)
    return _load_transforms_file(path, downscale, world_frame=world_frame)


def _frames_with_images(path: Path) -> tuple[int, int]:
    """(frames listed, frames whose image file exists) of a transforms file (validated first)."""
    data = load_json(path)
    validate_json(data, "transforms", path)
    found = sum(resolve_image_path(path.parent, frame["file_path"]) is not None for frame in data["frames"])
    return len(data["frames"]), found


def load_split_transforms(folder: str | Path, downscale: int = 1, world_frame: str = "transforms") -> Scene:
    """Load the Blender-synthetic layout: ``transforms_train.json`` and the ``_val`` / ``_test`` files
    present, as one Scene.

    Each file is read as a transforms.json of its own (its intrinsics, e.g. ``camera_angle_x``, apply
    to its frames only); views come in the order train, val, test, named ``<split>_<image stem>``
    (:func:`split_view_name`), and ``Scene.splits`` lists each split's view indices. A split file
    none of whose frames has an image file (nerf-synthetic's test images are often not shipped)
    gives an empty split and one warning; a missing val or test file, an empty split silently.

    Args:
        folder: the scene folder.
        downscale: integer factor to shrink images, labels, depths and intrinsics by.
        world_frame: as for :func:`load_transforms`, applied to each file.
    Returns:
        the Scene; ``info["split_source"]`` names the files, ``info["splits"]`` holds per split its
        file, views, frames_listed, skipped_frames and image_folder (where its images are).
    Raises:
        InputError: no ``transforms_train.json``, no training view with an image file, fewer than
            2 views in all, or any problem of a file (as :func:`load_transforms`).
    """
    downscale = check_downscale(downscale)
    folder = Path(folder)
    files = split_files(folder)
    if "train" not in files:
        found = ", ".join(p.name for p in files.values())
        raise InputError(f"split files ({found}) but no {SPLIT_FILES['train']}: the training views are missing",
                         folder / SPLIT_FILES["train"])
    parts: list[tuple[str, Scene]] = []
    counts: dict[str, dict] = {}
    for split, path in files.items():
        listed, found = _frames_with_images(path)
        if found == 0:
            if split == "train":
                raise InputError(f"none of the {listed} frames has an image file: no training view", path)
            warnings.warn(
                f"{listed} of {listed} frames in {path.name} have no image file; the {split} split is empty",
                UserWarning,
                stacklevel=3,
            )
            counts[split] = {"file": path.name, "views": 0, "frames_listed": listed, "skipped_frames": listed}
            continue
        part = _load_transforms_file(path, downscale, min_views=1, world_frame=world_frame)
        parts.append((split, part))
        counts[split] = {"file": path.name, "views": len(part), "frames_listed": listed,
                         "skipped_frames": part.info["skipped_frames"], "image_folder": part.info["image_folder"]}
    n_views = sum(len(part) for _, part in parts)
    if n_views < 2:
        raise InputError(f"only {n_views} view has an image file in {', '.join(p.name for p in files.values())}; "
                         "at least 2 views are needed", folder)
    return _concatenate_splits(folder, parts, counts)


def _per_view(parts: list[tuple[str, Scene]], key: str) -> list | None:
    """An optional per-view list (``sensor_depths``, ``masks``, ``image_alphas``) of the concatenated
    scene: None when no part has it, else None-filled for the parts without it."""
    lists = [getattr(part, key) for _, part in parts]
    if all(values is None for values in lists):
        return None
    return [v for values, (_, part) in zip(lists, parts) for v in (values if values is not None else [None] * len(part))]


def _concatenate_splits(folder: Path, parts: list[tuple[str, Scene]], counts: dict[str, dict]) -> Scene:
    """One Scene from the split files' Scenes (same folder, so the same classes.json); the explicit
    ``aabb`` is the union of the files' boxes."""
    first = parts[0][1]
    splits: dict[str, list[int]] = {split: [] for split in SPLIT_FILES}
    start = 0
    for split, part in parts:
        splits[split] = list(range(start, start + len(part)))
        start += len(part)
    cameras = Cameras(**{
        key: np.concatenate([getattr(part.cameras, key) for _, part in parts]) for key in Cameras.__dataclass_fields__
    })
    boxes = [np.asarray(part.aabb, np.float64) for _, part in parts if part.aabb is not None]
    aabb = None if not boxes else np.stack([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])
    try:  # the folder holding every split's images ('.' for nerf-synthetic's train/, val/)
        image_folder = os.path.commonpath(sorted({part.info["image_folder"] for _, part in parts})) or "."
    except ValueError:  # relative and absolute folders mixed
        image_folder = "."
    info = {
        **first.info,
        "source": str(folder),
        "image_folder": PurePosixPath(image_folder).as_posix(),
        "frames_listed": sum(c["frames_listed"] for c in counts.values()),
        "skipped_frames": sum(c["skipped_frames"] for c in counts.values()),
        **{  # per-view counts add up over the files
            key: sum(part.info.get(key, 0) for _, part in parts)
            for key in ("labelled_views", "depth_views", "sensor_depth_views", "masked_views") if key in first.info
        },
        "split_source": "input files: " + ", ".join(c["file"] for c in counts.values()),
        "splits": counts,
    }
    return Scene(
        root=folder,
        cameras=cameras,
        names=[split_view_name(split, name) for split, part in parts for name in part.names],
        images=[image for _, part in parts for image in part.images],
        labels=[label for _, part in parts for label in part.labels],
        depths=[depth for _, part in parts for depth in part.depths],
        classes=dict(first.classes),
        ignore_index=first.ignore_index,
        aabb=aabb,
        frame_id=first.frame_id,
        info=info,
        sensor_depths=_per_view(parts, "sensor_depths"),
        masks=_per_view(parts, "masks"),
        splits=splits,
        image_alphas=_per_view(parts, "image_alphas"),
    )
