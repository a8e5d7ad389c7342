"""Scene loaders: one module per input format, one entry point.

``load_scene(path, downscale)`` looks at the scene folder and dispatches:

- ``transforms.json`` present -> :func:`scenelabel.data.io.transforms_json.load_transforms`
  (nerfstudio / instant-ngp; a path to any transforms-style ``.json`` file works too);
- else ``poses_bounds.npy`` present -> :func:`scenelabel.data.io.llff.load_llff`;
- else a COLMAP sparse model, ``sparse/0/`` or ``sparse/cameras.(bin|txt)`` ->
  :func:`scenelabel.data.io.colmap.load_colmap`;
- else at least 2 photos in ``images/`` -> structure from motion (:func:`scenelabel.data.sfm.run_sfm`,
  pycolmap; the model is cached in ``sparse/0/`` so the next load reads it) then ``load_colmap``;
- else InputError.

Every loader returns a :class:`scenelabel.Scene` in the conventions of docs/conventions.md (c2w in
OpenCV camera axes, the input's world frame and units, images float32 RGB in [0, 1], labels int64
external class ids, depth along the unit ray). Scene folder layout: ``images/`` (PNG/JPEG),
optional ``labels/<image stem>.png`` (single-channel 8/16-bit class ids; a view without one is used
photometrically only) and ``classes.json`` (required when there are labels).
"""

from __future__ import annotations

import warnings
from pathlib import Path

from scenelabel.data.io.colmap import SPARSE_FOLDER, find_sparse_dir, load_colmap
from scenelabel.data.io.common import check_downscale, list_images
from scenelabel.data.io.label_map import LABEL_MAP_FILE, apply_label_map, read_label_map
from scenelabel.data.io.llff import POSES_BOUNDS_FILE, load_llff
from scenelabel.data.io.transforms_json import TRANSFORMS_FILE, load_transforms
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError

__all__ = ["load_scene", "load_transforms", "load_llff", "load_colmap", "read_label_map", "apply_label_map"]


def load_scene(path: str | Path, downscale: int = 1) -> Scene:
    """Load a scene folder, whatever its format, and apply its ``label_map.json`` when present.

    Args:
        path: the scene folder, or a transforms ``.json`` / ``poses_bounds.npy`` file inside one.
            A folder with a COLMAP ``sparse/`` model (and none of those files) loads with
            :func:`scenelabel.data.io.colmap.load_colmap`.
        downscale: integer factor (>= 1) to shrink images, labels, depths and intrinsics by.
    Returns:
        the Scene, ``info["format"]`` naming the format read; labels and classes in the target
        vocabulary of ``label_map.json`` (:mod:`scenelabel.data.io.label_map`) when the folder has one.
    Raises:
        InputError: missing folder, no recognised pose file, or any problem in the files.
    """
    scene = _load_poses_format(path, downscale)
    label_map_path = Path(scene.root) / LABEL_MAP_FILE
    if label_map_path.is_file():
        scene = apply_label_map(scene, read_label_map(label_map_path))
    return scene


def _load_poses_format(path: str | Path, downscale: int) -> Scene:
    """Dispatch on the files present (see the module docstring)."""
    downscale = check_downscale(downscale)
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".json":
            return load_transforms(path, downscale)
        if path.name == POSES_BOUNDS_FILE:
            return load_llff(path.parent, downscale)
        raise InputError(f"not a scene file: expected a folder, a transforms .json or {POSES_BOUNDS_FILE}", path)
    if not path.is_dir():
        raise InputError("scene folder not found", path)
    if (path / TRANSFORMS_FILE).is_file():
        return load_transforms(path, downscale)
    if (path / POSES_BOUNDS_FILE).is_file():
        return load_llff(path, downscale)
    if find_sparse_dir(path) is not None:
        return load_colmap(path, downscale)
    if (path / "images").is_dir() and len(list_images(path / "images")) >= 2:
        from scenelabel.data.sfm import run_sfm

        result = run_sfm(path)  # caches sparse/0/ in the folder, or raises InputError (too few registered)
        warnings.warn(f"no poses in {path}: {result.summary()}", stacklevel=3)
        return load_colmap(path, downscale)
    others = sorted(p.name for p in path.glob("transforms*.json"))
    hint = f"; found {', '.join(others)}: pass that file's path to load it" if others else ""
    raise InputError(
        f"no poses found: expected {TRANSFORMS_FILE} (nerfstudio / instant-ngp), {POSES_BOUNDS_FILE} (LLFF), a "
        f"COLMAP sparse model ({SPARSE_FOLDER}/0/ or {SPARSE_FOLDER}/ with cameras, images, points3D .bin/.txt) "
        f"or at least 2 photos in images/ (poses from structure from motion) in this folder{hint}",
        path,
    )
