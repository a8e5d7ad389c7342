"""The web viewer's training cameras: where a build's photos are, and each camera's frustum as
line segments (:class:`scenelabel.viz.viewer.ViewerApp` draws them all as one node)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from scenelabel.data.io.transforms_json import split_view_parts

__all__ = ["PHOTO_SUFFIXES", "FRUSTUM_IMAGE_WIDTH", "find_view_images", "view_image_candidates", "frustum_segments"]

PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
"""Suffixes tried for a view's photo (its name has none)."""
FRUSTUM_IMAGE_WIDTH = 160
"""Training photos are shrunk to this width on the frusta."""


def find_view_images(candidates: list[list[Path]], max_width: int = FRUSTUM_IMAGE_WIDTH) -> list[np.ndarray | None]:
    """Per view the first readable photo among its candidate paths, shrunk to at most ``max_width`` pixels.

    Args:
        candidates: per view, paths without a suffix (``NAME.png``, ``.jpg``, ... are tried), first
            match wins (:func:`view_image_candidates`).
    Returns:
        per view an [h, w, 3] uint8 image, or None where none was found or readable.
    """
    from PIL import Image

    out: list[np.ndarray | None] = []
    for stems in candidates:
        image = None
        for path in (stem.with_name(stem.name + suffix) for stem in stems for suffix in PHOTO_SUFFIXES):
            if not path.is_file():
                continue
            try:
                with Image.open(path) as im:
                    im = im.convert("RGB")
                    if im.width > max_width:
                        im = im.resize((max_width, max(1, round(im.height * max_width / im.width))))
                    image = np.asarray(im, np.uint8)
                break
            except OSError:
                continue
        out.append(image)
    return out


def view_image_candidates(
    build_dir: Path, meta: dict, names: list[str], images: Path | None = None
) -> list[list[Path]]:
    """Where a build's training photos may be, per view name (paths without a suffix), in order:
    ``images/NAME`` when a folder is given; the image folder the checkpoint names (``scene_info``:
    the poses file and its image folder); the scene folder's ``images/`` (a build writes to
    SCENE/scenelabel by default) or ``../scene/images`` beside the build; and for the split layout
    (``scene_info["splits"]``) a view ``SPLIT_STEM``'s ``SPLIT_FOLDER/STEM``
    (:func:`scenelabel.data.io.transforms_json.split_view_parts`).
    """
    info = meta.get("scene_info") or {}
    folders = [Path(images)] if images else []
    source, image_folder = info.get("source"), info.get("image_folder") or "images"
    root = None
    if isinstance(source, str) and isinstance(image_folder, str):
        root = Path(source) if Path(source).is_dir() else Path(source).parent
        folders += [root / image_folder, root.parent / image_folder]
    parent = build_dir.resolve().parent
    folders += [parent / "images", parent / "scene" / "images"]
    splits = info.get("splits") if isinstance(info.get("splits"), dict) else {}
    out = []
    for name in names:
        stems = [folder / name for folder in folders]
        parts = split_view_parts(name, splits)
        if parts is not None and root is not None:
            split, stem = parts
            stems.append(root / str(splits[split].get("image_folder", split)) / stem)
        out.append(stems)
    return out


def frustum_segments(
    c2w: np.ndarray, fov: float, aspect: float, scale: float
) -> tuple[np.ndarray, tuple[float, float, float]]:
    """One camera's frustum as line segments, sized as viser draws ``add_camera_frustum(fov, aspect,
    scale)`` (the pyramid of depth 1 and half extents ``tan(fov / 2) * aspect``, ``tan(fov / 2)``
    rescaled to volume ``scale³``): the four edges from the centre, the image rectangle, and a small
    triangle above its top edge (OpenCV axes: up is -y).

    Args:
        c2w: [4, 4] camera-to-world (OpenCV axes).
        fov: vertical field of view, radians; aspect: width / height; scale: as viser's.
    Returns:
        segments [10, 2, 3] float32 (world), and the image rectangle's half width, half height and
        depth in the camera frame (it is centred on the optical axis).
    """
    y = math.tan(fov / 2.0)
    x, z = y * aspect, 1.0
    k = scale / math.cbrt(x * y * z / 3.0)
    x, y, z = x * k, y * k, z * k
    corners = np.array([[-x, -y, z], [x, -y, z], [x, y, z], [-x, y, z]])
    tip = np.array([0.0, -1.6 * y, z])
    local = [(np.zeros(3), c) for c in corners]
    local += [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    local += [(np.array([-0.5 * x, -y, z]), tip), (tip, np.array([0.5 * x, -y, z]))]
    pts = np.asarray(local)  # [10, 2, 3]
    world = pts @ np.asarray(c2w, np.float64)[:3, :3].T + np.asarray(c2w, np.float64)[:3, 3]
    return world.astype(np.float32), (x, y, z)
