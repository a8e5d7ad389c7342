"""Scene loaders: one module per input format, one entry point.

``load_scene(path, downscale)`` looks at the scene folder and dispatches:

- ``transforms.json`` present -> :func:`scenelabel.data.io.transforms_json.load_transforms`
  (nerfstudio / instant-ngp; a path to any transforms-style ``.json`` file works too, loading that
  file alone);
- else the Blender-synthetic split files ``transforms_train.json`` (+ ``_val``, ``_test``) ->
  :func:`scenelabel.data.io.transforms_json.load_split_transforms`: one scene, ``Scene.splits``
  from the files;
- else ``poses_bounds.npy`` present -> :func:`scenelabel.data.io.llff.load_llff`;
- else a COLMAP sparse model, ``sparse/0/`` or ``sparse/cameras.(bin|txt)`` ->
  :func:`scenelabel.data.io.colmap.load_colmap`;
- else a video: a ``.mp4 .mov .avi .mkv .m4v`` file, a folder with the ``video.json`` of an earlier
  extraction, or a folder holding one video and no ``images/`` nor COLMAP model ->
  :func:`scenelabel.data.video.prepare_video_scene` (sharp frames into ``images/`` of the scene
  folder, ``clip/`` beside ``clip.mp4``, cached in ``video.json``), then structure from motion with
  sequential matching (cached in ``sparse/0/``) and ``load_colmap``. A folder holding both photos in
  ``images/`` (not extracted from a video) and a video uses the photos;
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
from scenelabel.data.io.transforms_json import TRANSFORMS_FILE, load_split_transforms, load_transforms, split_files
from scenelabel.data.scene import Scene
from scenelabel.data.video import VIDEO_FILE, VIDEO_SUFFIXES, find_video
from scenelabel.errors import InputError

__all__ = ["load_scene", "load_transforms", "load_split_transforms", "load_llff", "load_colmap", "read_label_map", "apply_label_map"]


def load_scene(
    path: str | Path,
    downscale: int = 1,
    video_frames_per_second: float | None = None,
    video_max_frames: int | None = None,
    progress: bool = False,
) -> Scene:
    """Load a scene folder, whatever its format, and apply its ``label_map.json`` when present.

    Args:
        path: the scene folder, or a transforms ``.json`` / ``poses_bounds.npy`` file inside one
            (a split file such as ``transforms_train.json`` loads that split alone).
            A folder with a COLMAP ``sparse/`` model (and none of those files) loads with
            :func:`scenelabel.data.io.colmap.load_colmap`.
        downscale: integer factor (>= 1) to shrink images, labels, depths and intrinsics by.
        video_frames_per_second, video_max_frames: for a video, the frame choice
            (:func:`scenelabel.data.video.frames_from_video`); None: the earlier extraction's when
            there is one (any frames cached are reused), else the defaults (3 per second, at most 150).
        progress: for a video, progress bars and lines on stderr (frames, structure from motion).
    Returns:
        the Scene, ``info["format"]`` naming the format read; labels and classes in the target
        vocabulary of ``label_map.json`` (:mod:`scenelabel.data.io.label_map`) when the folder has one.
    Raises:
        InputError: missing folder, no recognised pose file, or any problem in the files.
    """
    video = {"frames_per_second": video_frames_per_second, "max_frames": video_max_frames, "progress": progress}
    scene = _load_poses_format(path, downscale, video)
    label_map_path = Path(scene.root) / LABEL_MAP_FILE
    if label_map_path.is_file():
        scene = apply_label_map(scene, read_label_map(label_map_path))
    return scene


def _load_poses_format(path: str | Path, downscale: int, video: dict | None = None) -> Scene:
    """Dispatch on the files present (see the module docstring)."""
    downscale = check_downscale(downscale)
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".json":
            return load_transforms(path, downscale)
        if path.name == POSES_BOUNDS_FILE:
            return load_llff(path.parent, downscale)
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return _load_video(path, downscale, video or {})
        raise InputError(
            f"not a scene file: expected a folder, a transforms .json, {POSES_BOUNDS_FILE} or a video "
            f"({' '.join(VIDEO_SUFFIXES)})",
            path,
        )
    if not path.is_dir():
        raise InputError("video not found" if path.suffix.lower() in VIDEO_SUFFIXES else "scene folder not found", path)
    if (path / TRANSFORMS_FILE).is_file():
        return load_transforms(path, downscale)
    if split_files(path):
        return load_split_transforms(path, downscale)
    if (path / POSES_BOUNDS_FILE).is_file():
        return load_llff(path, downscale)
    if (path / VIDEO_FILE).is_file():  # frames extracted from a video before: check it is unchanged
        return _load_video(path, downscale, video or {})
    if find_sparse_dir(path) is not None:
        return load_colmap(path, downscale)
    if not (path / "images").is_dir() and find_video(path) is not None:
        return _load_video(path, downscale, video or {})
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
        f"or at least 2 photos in images/ or a video (poses from structure from motion) in this folder{hint}",
        path,
    )


def _load_video(path: Path, downscale: int, video: dict) -> Scene:
    """A video file or folder: frames (cached), structure from motion with sequential matching
    (cached), then the COLMAP loader on the scene folder; ``info["video"]`` says what was chosen."""
    import sys

    from scenelabel.data.sfm import SPARSE_MODEL, run_sfm
    from scenelabel.data.video import prepare_video_scene

    progress = bool(video.get("progress"))
    frames = prepare_video_scene(path, video.get("frames_per_second"), video.get("max_frames"), progress)
    scene_dir = frames.scene_dir
    if progress and not (scene_dir / SPARSE_MODEL).is_dir():
        print(f"sfm: camera poses of {len(frames.names)} frames by structure from motion (sequential matching)",
              file=sys.stderr, flush=True)
    result = run_sfm(scene_dir, matcher="sequential")  # caches sparse/0/; InputError when too few register
    if progress:
        print(f"sfm: {result.summary()}", file=sys.stderr, flush=True)
    scene = load_colmap(scene_dir, downscale)
    scene.info["video"] = {
        "source": str(frames.video),
        "fps": frames.fps,
        "decoded": frames.n_decoded,
        "chosen": len(frames.indices),
        "blurred": len(frames.blurred),
        "frames_per_second": frames.frames_per_second,
        "max_frames": frames.max_frames,
        "sfm_registered": result.n_registered,
        "sfm_seconds": result.seconds,
    }
    return scene
