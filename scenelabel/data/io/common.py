"""Reading helpers shared by every scene loader: images, labels, depths, classes.json, JSON Schema
validation and pose checks.

Everything here converts into scenelabel's conventions (docs/conventions.md):

- images: float32 RGB in [0, 1], shape [h, w, 3]; grayscale is replicated to three channels; 16-bit
  images are scaled by 1/65535. An alpha channel (RGBA, LA, a palette with transparency) is kept
  beside the colour as float32 [h, w] in [0, 1] (:func:`read_image_alpha`, ``Scene.image_alphas``), not
  composited: training composites it on the build's background.
- labels: int64 external class ids, shape [h, w]; 8- or 16-bit single-channel PNG, true values.
- depths: float32 [h, w], distance along the unit ray direction, world units.
- poses: c2w 4x4 with a rigid, right-handed rotation.
- resizing by ``downscale`` treats pixel (col, row) as covering [col, col + 1) x [row, row + 1):
  the resized image covers the same continuous extent, so intrinsics scale by new_size / old_size
  (``fx *= sx``, ``cx *= sx``).

Every problem a user can cause raises :class:`scenelabel.errors.InputError` naming the file and
the field or problem; nothing here lets a raw KeyError / OSError / traceback through.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import cv2
import numpy as np
from PIL import Image

from scenelabel.codes import FREE
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras

__all__ = [
    "IMAGE_SUFFIXES",
    "LABEL_SUFFIX",
    "ROTATION_TOLERANCE",
    "ClassesFile",
    "load_schema",
    "load_json",
    "validate_json",
    "read_classes",
    "check_downscale",
    "scaled_size",
    "resize_area",
    "resize_nearest",
    "image_size",
    "read_image",
    "read_image_alpha",
    "resize_premultiplied",
    "read_label",
    "read_depth",
    "check_label_ids",
    "check_pose",
    "list_images",
    "resolve_image_path",
    "scene_classes",
    "ViewFiles",
    "ViewData",
    "read_view",
    "alphas_or_none",
]

#: Image file suffixes a loader accepts (compared case-insensitively), in the order tried when a
#: transforms.json ``file_path`` has no extension.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg")

#: Label maps are PNGs (lossless): ``labels/<image stem>.png``.
LABEL_SUFFIX = ".png"

#: Largest accepted max-abs entry of R^T R - I for a rotation (float32-written files reach ~1e-6;
#: anything above 1e-3 is a scaled, sheared or corrupt matrix).
ROTATION_TOLERANCE = 1e-3

#: Tolerance on the bottom row of a 4x4 pose, which must be [0, 0, 0, 1].
BOTTOM_ROW_TOLERANCE = 1e-6

#: Full scale of 8-bit and 16-bit image samples.
_MAX_8BIT = 255.0
_MAX_16BIT = 65535.0

#: PIL modes of single-channel integer images (labels); "1" is a 1-bit mask (values 0/1).
_LABEL_MODES = frozenset({"1", "L", "P", "I", "I;16", "I;16L", "I;16B", "I;16N"})
_SIXTEEN_BIT_MODES = frozenset({"I", "I;16", "I;16L", "I;16B", "I;16N"})

#: Below this resampled alpha a pixel's colour is the plain area average instead of the
#: alpha-weighted one (:func:`read_image_alpha`): the pixel is (almost) fully transparent, so its
#: colour is (almost) invisible, and dividing by a near-zero alpha would amplify rounding noise.
ALPHA_EPS = 1e-6

#: Errors PIL raises for unreadable, truncated or oversized files.
_PIL_ERRORS = (OSError, SyntaxError, ValueError, Image.DecompressionBombError)


# --------------------------------------------------------------------------------------------
# JSON and schemas


@lru_cache(maxsize=None)
def load_schema(name: str) -> dict:
    """The JSON Schema ``scenelabel/schemas/<name>.schema.json`` (shipped with the package)."""
    text = resources.files("scenelabel").joinpath("schemas", f"{name}.schema.json").read_text("utf-8")
    return json.loads(text)


def load_json(path: Path) -> Any:
    """Parse a JSON file; a missing file or a syntax error is an InputError with line/column."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"cannot read the file ({error})", path) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(f"invalid JSON: {error.msg} at line {error.lineno}, column {error.colno}", path) from None


def _json_path(parts: Sequence[Any]) -> str:
    """JSONPath string of a path given as keys and indices, e.g. ``$.frames[3].fl_x``."""
    out = "$"
    for part in parts:
        out += f"[{part}]" if isinstance(part, int) else f".{part}"
    return out


def _first_non_finite(data: Any, parts: tuple = ()) -> tuple | None:
    """Path of the first NaN/Infinity number in parsed JSON (Python's json accepts them)."""
    if isinstance(data, float) and not math.isfinite(data):
        return parts
    if isinstance(data, dict):
        items = data.items()
    elif isinstance(data, list):
        items = enumerate(data)
    else:
        return None
    for key, value in items:
        found = _first_non_finite(value, parts + (key,))
        if found is not None:
            return found
    return None


def validate_json(data: Any, schema_name: str, path: Path) -> None:
    """Validate parsed JSON against a shipped schema (Draft 2020-12).

    Raises:
        InputError: naming ``path`` and the JSON path of the most relevant error
            (``jsonschema.exceptions.best_match``), or of the first non-finite number.
    """
    from jsonschema import Draft202012Validator
    from jsonschema.exceptions import best_match

    error = best_match(Draft202012Validator(load_schema(schema_name)).iter_errors(data))
    if error is not None:
        raise InputError(error.message, path, field=error.json_path)
    bad = _first_non_finite(data)
    if bad is not None:
        raise InputError("non-finite number (NaN or Infinity)", path, field=_json_path(bad))


# --------------------------------------------------------------------------------------------
# classes.json


@dataclass(frozen=True)
class ClassesFile:
    """The content of classes.json.

    Attributes:
        classes: external class id -> name (the full vocabulary).
        ignore_index: label value of unlabelled pixels, or None.
        colors: external class id -> (r, g, b) for the classes that give one.
        free_index: label value of pixels whose ray meets nothing (read as FREE), or None.
    """

    classes: dict[int, str]
    ignore_index: int | None
    colors: dict[int, tuple[int, int, int]]
    free_index: int | None = None


def read_classes(path: Path) -> ClassesFile:
    """Read and validate classes.json (scenelabel/schemas/classes.schema.json).

    Raises:
        InputError: schema violations, duplicate ids, or ignore_index equal to a class id.
    """
    path = Path(path)
    data = load_json(path)
    validate_json(data, "classes", path)
    return classes_from_json(data, path)


def classes_from_json(data: dict, path: Path) -> ClassesFile:
    """The vocabulary of validated classes.json-style data (``classes``, optional ``ignore_index`` and
    ``free_index``).

    Raises:
        InputError: duplicate ids, ignore_index or free_index equal to a class id, or to each other.
    """
    classes: dict[int, str] = {}
    colors: dict[int, tuple[int, int, int]] = {}
    for index, entry in enumerate(data["classes"]):
        class_id = int(entry["id"])
        if class_id in classes:
            raise InputError(f"class id {class_id} appears twice", path, field=f"$.classes[{index}].id")
        classes[class_id] = entry["name"]
        if "color" in entry:
            colors[class_id] = tuple(int(c) for c in entry["color"])  # type: ignore[assignment]
    ignore_index = data.get("ignore_index")
    if ignore_index is not None and ignore_index in classes:
        raise InputError(f"ignore_index {ignore_index} is also a class id", path, field="$.ignore_index")
    free_index = data.get("free_index")
    if free_index is not None and (free_index in classes or free_index == ignore_index):
        what = "a class id" if free_index in classes else "the ignore_index"
        raise InputError(f"free_index {free_index} is also {what}", path, field="$.free_index")
    return ClassesFile(classes=classes, ignore_index=ignore_index, colors=colors, free_index=free_index)


# --------------------------------------------------------------------------------------------
# resizing


def check_downscale(downscale: Any) -> int:
    """``downscale`` as an int >= 1, else InputError."""
    if isinstance(downscale, bool) or not isinstance(downscale, (int, np.integer)) or downscale < 1:
        raise InputError(f"must be an integer >= 1, got {downscale!r}", field="downscale")
    return int(downscale)


def scaled_size(width: int, height: int, downscale: int) -> tuple[int, int]:
    """(width, height) after dividing by ``downscale``, rounded down, at least 1 pixel."""
    return max(1, width // downscale), max(1, height // downscale)


def resize_area(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-resample [h, w, c] float32 to [height, width, c] (same continuous extent)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA).reshape(height, width, -1)


def resize_nearest(array: np.ndarray, width: int, height: int) -> np.ndarray:
    """Nearest-neighbour resample of [h, w] (any dtype) to [height, width].

    Output pixel j takes the input pixel containing its centre: ``floor((j + 0.5) * w / width)``,
    consistent with pixel centres at +0.5 and with :func:`resize_area`.
    """
    h, w = array.shape[:2]
    if (h, w) == (height, width):
        return array
    rows = np.minimum(((np.arange(height) + 0.5) * (h / height)).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * (w / width)).astype(np.int64), w - 1)
    return array[rows[:, None], cols[None, :]]


# --------------------------------------------------------------------------------------------
# images, labels, depths


def _open(path: Path, what: str) -> Image.Image:
    """Open and fully decode an image file; any failure is an InputError naming the file."""
    if not path.is_file():
        raise InputError(f"{what} file not found", path)
    try:
        image = Image.open(path)
        image.load()
    except _PIL_ERRORS as error:
        raise InputError(f"cannot read the {what} (unreadable or truncated file: {error})", path) from None
    return image


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file from its header, without decoding the pixels."""
    try:
        with Image.open(path) as image:
            return image.size
    except _PIL_ERRORS as error:
        raise InputError(f"cannot read the image (unreadable file: {error})", path) from None


def read_image(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image as float32 RGB in [0, 1], shape [h, w, 3], ignoring any alpha channel.

    Grayscale is replicated to RGB; 16-bit grayscale is divided by 65535. EXIF orientation is
    *not* applied: pixels are used as stored, which is what poses and intrinsics from NeRF tools
    refer to. Scene loaders use :func:`read_image_alpha`, which keeps the alpha.

    Args:
        path: PNG or JPEG file.
        size: (width, height) to area-resample to, or None to keep the file's size.
    """
    return read_image_alpha(path, size)[0]


def _has_alpha(image: Image.Image) -> bool:
    """Whether a PIL image carries transparency: an alpha band, or a palette / colour key."""
    return "A" in image.getbands() or "transparency" in image.info


def resize_premultiplied(rgb: np.ndarray, alpha: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-resample an RGBA image so that compositing commutes with resampling.

    The alpha is area-averaged; the colour is the alpha-weighted average
    ``area(rgb * alpha) / area(alpha)`` (the plain average where the averaged alpha is below
    ALPHA_EPS). So ``rgb' * alpha' + bg * (1 - alpha')`` equals the area average of the full
    resolution composite ``rgb * alpha + bg * (1 - alpha)`` for every background ``bg``.

    Args:
        rgb: [h, w, 3] float32; alpha: [h, w] float32 in [0, 1].
    Returns:
        rgb [height, width, 3] float32 in [0, 1], alpha [height, width] float32 in [0, 1].
    """
    small_alpha = resize_area(alpha[..., None], width, height)[..., 0]
    premultiplied = resize_area(rgb * alpha[..., None], width, height)
    plain = resize_area(rgb, width, height)
    seen = small_alpha[..., None] >= ALPHA_EPS
    small_rgb = np.where(seen, premultiplied / np.maximum(small_alpha[..., None], ALPHA_EPS), plain)
    return np.clip(small_rgb, 0.0, 1.0).astype(np.float32), np.clip(small_alpha, 0.0, 1.0).astype(np.float32)


def read_image_alpha(path: Path, size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image as float32 RGB in [0, 1], shape [h, w, 3], and its alpha channel.

    As :func:`read_image` for the colour (which is not composited onto anything: a transparent
    pixel keeps the colour stored under it). The alpha of RGBA, LA and palette-with-transparency
    images is float32 [h, w] in [0, 1]; an image without one, or whose alpha is 1 everywhere, gives
    None (opaque). Resampling keeps compositing exact (:func:`resize_premultiplied`).

    Args:
        path: PNG or JPEG file.
        size: (width, height) to area-resample to, or None to keep the file's size.
    Returns:
        (rgb [h, w, 3], alpha [h, w] or None).
    """
    path = Path(path)
    image = _open(path, "image")
    alpha = None
    if image.mode in _SIXTEEN_BIT_MODES:
        gray = np.asarray(image, dtype=np.float32) / _MAX_16BIT
        rgb = np.repeat(gray[..., None], 3, axis=2)
    else:
        try:
            if _has_alpha(image):
                rgba = np.asarray(image.convert("RGBA"), dtype=np.float32) / _MAX_8BIT
                rgb, alpha = rgba[..., :3], rgba[..., 3]
            else:
                rgb = np.asarray(image.convert("RGB"), dtype=np.float32) / _MAX_8BIT
        except _PIL_ERRORS as error:
            raise InputError(f"cannot convert image mode {image.mode} to RGB ({error})", path) from None
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if alpha is not None and bool(np.all(alpha == 1.0)):
        alpha = None  # an opaque image that happens to carry an alpha band
    if alpha is not None:
        alpha = np.ascontiguousarray(alpha, dtype=np.float32)
        if size is not None:
            rgb, alpha = resize_premultiplied(rgb, alpha, *size)
    elif size is not None:
        rgb = resize_area(rgb, *size)
    return rgb, alpha


def read_label(path: Path, expected_size: tuple[int, int], size: tuple[int, int] | None = None) -> np.ndarray:
    """Read a label PNG of external class ids as int64 [h, w] (true 8- or 16-bit values).

    Args:
        path: single-channel PNG (8-bit L or palette P: the index is the id; 16-bit I;16).
        expected_size: (width, height) of the image the label annotates, at file resolution.
        size: (width, height) to nearest-resample to, or None.
    Raises:
        InputError: not a PNG, not single-channel, or a size differing from ``expected_size``.
    """
    path = Path(path)
    image = _open(path, "label")
    if image.format != "PNG":
        raise InputError(f"labels must be PNG files (lossless); got {image.format}", path)
    if image.mode not in _LABEL_MODES:
        raise InputError(
            f"labels must be single-channel 8- or 16-bit PNGs of class ids; got mode {image.mode} "
            f"({len(image.getbands())} channels)",
            path,
        )
    if image.size != tuple(expected_size):
        raise InputError(
            f"label size {image.size[0]}x{image.size[1]} differs from the image size "
            f"{expected_size[0]}x{expected_size[1]}",
            path,
        )
    label = np.asarray(image).astype(np.int64)
    if label.min(initial=0) < 0:
        raise InputError("label has negative values", path)
    if size is not None:
        label = resize_nearest(label, *size)
    return np.ascontiguousarray(label)


def read_depth(path: Path, expected_size: tuple[int, int], size: tuple[int, int] | None = None) -> np.ndarray:
    """Read a ground-truth depth .npy as float32 [h, w] (distance along the unit ray).

    Args:
        path: .npy with a real-valued array [h, w] (or [h, w, 1]) at the image's file resolution.
        expected_size: (width, height) of the image.
        size: (width, height) to nearest-resample to, or None.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("depth file not found", path)
    try:
        depth = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(f"cannot read the depth .npy ({error})", path) from None
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[..., 0]
    if not (np.issubdtype(depth.dtype, np.floating) or np.issubdtype(depth.dtype, np.integer)):
        raise InputError(f"depth must be a real-valued array, got dtype {depth.dtype}", path)
    width, height = expected_size
    if depth.shape != (height, width):
        raise InputError(
            f"depth shape {list(depth.shape)} does not match the image: expected [{height}, {width}] ([h, w])", path
        )
    depth = depth.astype(np.float32)
    if size is not None:
        depth = resize_nearest(depth, *size)
    return np.ascontiguousarray(depth)


def check_label_ids(label: np.ndarray, vocabulary: ClassesFile, path: Path) -> None:
    """Raise InputError naming ``path`` and the ids if ``label`` has ids not in classes.json (its
    classes, ignore_index or free_index)."""
    present = set(np.unique(label).tolist()) - {vocabulary.ignore_index, vocabulary.free_index}
    classes = vocabulary.classes
    unknown = sorted(present - set(classes))
    if unknown:
        shown = unknown[:20]
        more = f" (and {len(unknown) - len(shown)} more)" if len(unknown) > len(shown) else ""
        raise InputError(f"label ids {shown}{more} are not in classes.json", path)


# --------------------------------------------------------------------------------------------
# poses


def check_pose(c2w: np.ndarray, path: Path | None, frame: str, what: str = "pose") -> np.ndarray:
    """Check a rigid transform (a camera-to-world matrix, or ``what`` names another) and return it
    as float64 [4, 4].

    Accepts [4, 4] or [3, 4] (bottom row [0, 0, 0, 1] added). The rotation must be rigid and
    right-handed: ``max|R^T R - I| <= ROTATION_TOLERANCE`` and ``det R > 0`` (no scale, no mirror).

    Raises:
        InputError: naming ``path`` and ``frame`` (the JSON field) for a wrong shape, a non-finite
            entry, a wrong bottom row or a non-rigid rotation.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if c2w.shape != (4, 4):
        raise InputError(f"{what} must be 4x4 or 3x4, got shape {list(c2w.shape)}", path, field=frame)
    if not np.all(np.isfinite(c2w)):
        raise InputError(f"{what} has non-finite entries (NaN or Inf)", path, field=frame)
    if np.max(np.abs(c2w[3] - [0.0, 0.0, 0.0, 1.0])) > BOTTOM_ROW_TOLERANCE:
        raise InputError(f"{what} bottom row must be [0, 0, 0, 1], got {c2w[3].tolist()}", path, field=frame)
    rotation = c2w[:3, :3]
    error = float(np.max(np.abs(rotation.T @ rotation - np.eye(3))))
    det = float(np.linalg.det(rotation))
    if error > ROTATION_TOLERANCE or det <= 0:
        raise InputError(
            f"{what} rotation is not rigid (max|R^T R - I| = {error:.3g}, det R = {det:.3g}); "
            f"expected an orthonormal rotation with det +1",
            path,
            field=frame,
        )
    return c2w


# --------------------------------------------------------------------------------------------
# files


def list_images(folder: Path) -> list[Path]:
    """Image files (IMAGE_SUFFIXES, any case) directly in ``folder``, sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def resolve_image_path(root: Path, file_path: str) -> Path | None:
    """The image file a transforms.json ``file_path`` names, or None when it does not exist.

    ``file_path`` is relative to ``root``; without an image extension (nerf-synthetic's
    ``./train/r_0``), IMAGE_SUFFIXES are tried in lower and upper case.
    """
    path = root / file_path
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return path if path.is_file() else None
    for suffix in IMAGE_SUFFIXES:
        for candidate in (path.with_name(path.name + suffix), path.with_name(path.name + suffix.upper())):
            if candidate.is_file():
                return candidate
    return path if path.is_file() else None


def scene_classes(root: Path, labelled: bool) -> ClassesFile:
    """The scene's classes.json, or an empty vocabulary when there is none and no labels.

    Args:
        root: the scene folder.
        labelled: whether any view has a label file.
    Raises:
        InputError: labels exist but ``root/classes.json`` does not.
    """
    path = Path(root) / "classes.json"
    if path.is_file():
        return read_classes(path)
    if labelled:
        raise InputError(
            "label files were found but classes.json is missing; it lists the class ids the labels use "
            '({"classes": [{"id": 0, "name": "floor"}, ...], "ignore_index": 255})',
            path,
        )
    return ClassesFile(classes={}, ignore_index=None, colors={})


@dataclass(frozen=True)
class ViewFiles:
    """The files of one view: an image, and optionally a label PNG and a depth .npy."""

    name: str
    image: Path
    label: Path | None = None
    depth: Path | None = None


class ViewData(NamedTuple):
    """What :func:`read_view` read of one view."""

    image: np.ndarray  # [h, w, 3] float32 in [0, 1]
    label: np.ndarray | None  # [h, w] int64 external class ids, FREE where classes.json's free_index
    depth: np.ndarray | None  # [h, w] float32 ground-truth depth along the unit ray
    alpha: np.ndarray | None  # [h, w] float32 in [0, 1]; None: opaque


def read_view(view: ViewFiles, file_size: tuple[int, int], size: tuple[int, int], vocabulary: ClassesFile) -> ViewData:
    """Read one view's image (with its alpha), label and depth, resampled to ``size``.

    Args:
        view: the files.
        file_size: (width, height) of the image file; label and depth must have this size.
        size: (width, height) wanted: images and alpha are area-resampled
            (:func:`read_image_alpha`), labels and depths nearest.
        vocabulary: classes.json; label ids must be among its classes (or its ignore_index or
            free_index).
    Returns:
        ViewData: image [h, w, 3] float32 in [0, 1]; label [h, w] int64 (free_index read as FREE) or
        None; depth [h, w] float32 or None; alpha [h, w] float32 or None.
    """
    target = None if tuple(size) == tuple(file_size) else size
    image, alpha = read_image_alpha(view.image, target)
    label = None
    if view.label is not None:
        label = read_label(view.label, file_size)
        # check at file resolution: nearest resampling could hide a stray id
        check_label_ids(label, vocabulary, view.label)
        if target is not None:
            label = np.ascontiguousarray(resize_nearest(label, *target))
        if vocabulary.free_index is not None:
            label[label == vocabulary.free_index] = FREE
    depth = None if view.depth is None else read_depth(view.depth, file_size, target)
    return ViewData(image, label, depth, alpha)


def alphas_or_none(alphas: Sequence[np.ndarray | None]) -> list[np.ndarray | None] | None:
    """``Scene.image_alphas`` from per-view alphas: None when every view is opaque."""
    return None if all(a is None for a in alphas) else list(alphas)


def scene_from_views(
    root: Path, cameras: Cameras, files: list[ViewFiles], views: list[ViewData], vocabulary: ClassesFile, info: dict
) -> Scene:
    """A Scene (no explicit aabb, frame "world") from per-view files and what :func:`read_view` read."""
    return Scene(
        root=root,
        cameras=cameras,
        names=[f.name for f in files],
        images=[v.image for v in views],
        labels=[v.label for v in views],
        depths=[v.depth for v in views],
        classes=dict(vocabulary.classes),
        ignore_index=vocabulary.ignore_index,
        aabb=None,
        frame_id="world",
        info=info,
        image_alphas=alphas_or_none([v.alpha for v in views]),
    )
