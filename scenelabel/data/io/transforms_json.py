"""Loader for ``transforms.json`` scenes (nerfstudio / instant-ngp / nerf-synthetic).

The file is validated against scenelabel/schemas/transforms.schema.json (which documents every key
and scenelabel's extensions: ``frames[].label_path``, ``frames[].depth_path``, ``near``, ``far``,
``aabb``, ``frame_id``). Conversions into docs/conventions.md:

- ``transform_matrix`` is camera-to-world in OpenGL camera axes (x right, y up, looking down -z);
  scenelabel's ``c2w = T @ diag(1, -1, -1, 1)`` (OpenCV axes: x right, y down, z forward).
- intrinsics: global ``fl_x fl_y cx cy w h`` with per-frame overrides; ``fl_x`` falls back to
  ``camera_angle_x`` (``fl_x = w / (2 tan(camera_angle_x / 2))``), ``fl_y`` to ``camera_angle_y``
  then ``fl_x``, ``cx``/``cy`` to ``w/2``/``h/2``, ``w``/``h`` to the image file's size.
- distortion: OpenCV ``k1 k2 p1 p2``; fisheye or other models are rejected.
- ``downscale = d``: images area-resampled, labels and depths nearest, to ``(w // d, h // d)``;
  intrinsics scale by new_size / old_size per axis (pixel centres at +0.5, so ``cx' = cx * sx``).
- near / far: distances along the unit ray, NaN where the file does not say.

Frames are kept in file order. Frames whose image file is missing are skipped with one warning.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from scenelabel.data.io.common import (
    LABEL_SUFFIX,
    ViewFiles,
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
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, opengl_to_opencv

__all__ = [
    "TRANSFORMS_FILE",
    "SUPPORTED_CAMERA_MODELS",
    "load_transforms",
]

#: The file this loader reads from a scene folder.
TRANSFORMS_FILE = "transforms.json"

#: nerfstudio / COLMAP camera models that are a pinhole with (at most) OpenCV k1 k2 p1 p2.
SUPPORTED_CAMERA_MODELS = frozenset({"PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "RADIAL", "SIMPLE_RADIAL"})

#: Distortion keys scenelabel's cameras carry (Cameras.distortion order) ...
DISTORTION_KEYS = ("k1", "k2", "p1", "p2")
#: ... and keys of higher-order models that must be absent or zero.
UNSUPPORTED_DISTORTION_KEYS = ("k3", "k4", "k5", "k6")

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


def _lookup(frame: dict, data: dict, key: str) -> Any:
    """Per-frame value of ``key``, else the global one, else None (nerfstudio overrides)."""
    return frame[key] if key in frame else data.get(key)


def _check_camera_model(data: dict, path: Path) -> str | None:
    """Reject fisheye / non-radial-tangential models; return the model name (or None)."""
    if data.get("is_fisheye"):
        raise InputError("fisheye cameras are not supported (is_fisheye is true)", path, field="$.is_fisheye")
    model = data.get("camera_model")
    if model is not None and model.upper() not in SUPPORTED_CAMERA_MODELS:
        raise InputError(
            f"camera_model {model!r} is not supported: scenelabel handles pinhole cameras with OpenCV "
            f"radial-tangential distortion (k1, k2, p1, p2) only; supported: {sorted(SUPPORTED_CAMERA_MODELS)}",
            path,
            field="$.camera_model",
        )
    return model


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
    for key in UNSUPPORTED_DISTORTION_KEYS:
        if _lookup(frame, data, key):
            raise InputError(
                f"distortion coefficient {key} is non-zero; only OpenCV k1, k2, p1, p2 are supported",
                path,
                field=f"{field}.{key}" if key in frame else f"$.{key}",
            )
    distortion = tuple(float(_lookup(frame, data, key) or 0.0) for key in DISTORTION_KEYS)
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
    )


def _image_folder(root: Path, images: list[Path]) -> str:
    """The folder (relative to root, POSIX) holding all the images, e.g. 'images'."""
    common = os.path.commonpath([str(p.parent) for p in images])
    try:
        return PurePosixPath(Path(common).relative_to(root)).as_posix()
    except ValueError:
        return common


def load_transforms(path: str | Path, downscale: int = 1) -> Scene:
    """Load a transforms.json scene into scenelabel's conventions (see the module docstring).

    Args:
        path: the scene folder (holding ``transforms.json``) or the JSON file itself
            (e.g. nerf-synthetic's ``transforms_train.json``); paths inside are relative to its folder.
        downscale: integer factor to shrink images, labels, depths and intrinsics by.
    Returns:
        a Scene; ``info`` holds format, source, image_folder, downscale, frames_listed,
        skipped_frames, camera_model, labelled_views, depth_views, class_colors.
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
    if len(kept) < 2:
        raise InputError(
            f"only {len(kept)} of {len(frames)} frames have an image file; at least 2 views are needed", path
        )

    c2ws, intrinsics, files, file_sizes = [], [], [], []
    for index, frame, image in kept:
        pose = check_pose(frame["transform_matrix"], path, f"$.frames[{index}].transform_matrix")
        c2ws.append(opengl_to_opencv(pose))
        file_size = image_size(image)
        intr = _frame_intrinsics(data, frame, index, file_size, image, path)
        intrinsics.append(_scaled(intr, scaled_size(intr.width, intr.height, downscale)))
        files.append(_frame_files(root, frame, index, image, path))
        file_sizes.append(file_size)

    vocabulary = scene_classes(root, labelled=any(f.label is not None for f in files))
    images, labels, depths = [], [], []
    for view, file_size, intr in zip(files, file_sizes, intrinsics):
        image, label, depth = read_view(view, file_size, (intr.width, intr.height), vocabulary)
        images.append(image)
        labels.append(label)
        depths.append(depth)

    cameras = Cameras.create(
        np.stack(c2ws),
        fx=[i.fx for i in intrinsics],
        fy=[i.fy for i in intrinsics],
        cx=[i.cx for i in intrinsics],
        cy=[i.cy for i in intrinsics],
        width=[i.width for i in intrinsics],
        height=[i.height for i in intrinsics],
        distortion=np.array([i.distortion for i in intrinsics], dtype=np.float64),
        near=[i.near for i in intrinsics],
        far=[i.far for i in intrinsics],
    )
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
    )
