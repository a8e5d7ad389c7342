"""Scene loaders: one module per input format, one entry point.

``load_scene(path, downscale)`` looks at the scene folder and dispatches:

- ``transforms.json`` present -> :func:`scenelabel.io.transforms_json.load_transforms`
  (nerfstudio / instant-ngp; a path to any transforms-style ``.json`` file works too);
- else ``poses_bounds.npy`` present -> :func:`scenelabel.io.llff.load_llff`;
- else InputError. (COLMAP ``sparse/0`` and images-only folders are a later issue.)

Every loader returns a :class:`scenelabel.Scene` in the conventions of docs/conventions.md (c2w in
OpenCV camera axes, the input's world frame and units, images float32 RGB in [0, 1], labels int64
external class ids, depth along the unit ray). Scene folder layout: ``images/`` (PNG/JPEG),
optional ``labels/<image stem>.png`` (single-channel 8/16-bit class ids; a view without one is used
photometrically only) and ``classes.json`` (required when there are labels).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..scene import Scene
from .common import check_downscale
from .label_map import LABEL_MAP_FILE, apply_label_map, read_label_map
from .llff import POSES_BOUNDS_FILE, load_llff
from .transforms_json import TRANSFORMS_FILE, load_transforms

__all__ = ["load_scene", "load_transforms", "load_llff", "read_label_map", "apply_label_map"]


def load_scene(path: str | Path, downscale: int = 1) -> Scene:
    """Load a scene folder, whatever its format, and apply its ``label_map.json`` when present.

    Args:
        path: the scene folder, or a transforms ``.json`` / ``poses_bounds.npy`` file inside one.
        downscale: integer factor (>= 1) to shrink images, labels, depths and intrinsics by.
    Returns:
        the Scene, ``info["format"]`` naming the format read; labels and classes in the target
        vocabulary of ``label_map.json`` (:mod:`scenelabel.io.label_map`) when the folder has one.
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
    others = sorted(p.name for p in path.glob("transforms*.json"))
    hint = f"; found {', '.join(others)}: pass that file's path to load it" if others else ""
    raise InputError(
        f"no poses found: expected {TRANSFORMS_FILE} (nerfstudio / instant-ngp) or {POSES_BOUNDS_FILE} (LLFF) "
        f"in this folder (COLMAP sparse models and images-only folders are not supported yet){hint}",
        path,
    )
