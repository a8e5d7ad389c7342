"""Loader for LLFF scenes (``poses_bounds.npy`` + ``images/`` or ``images_N/``).

``poses_bounds.npy`` is float [n, 17]: per view a 3x5 matrix ``[R | t | hwf]`` flattened row-major,
then ``near, far``. ``R | t`` is camera-to-world with camera axes [down, right, back]; ``hwf`` is
(height, width, focal) of the *full-resolution* images. Conversions into docs/conventions.md:

- ``c2w`` columns ``[right, down, forward] = [col1, col0, -col2]``, translation unchanged
  (OpenCV axes: x right, y down, z forward). The world frame is the file's own: no recentring or
  rescaling (that is what NeRF's ``load_llff_data`` adds on top, and scenelabel does not).
- intrinsics scaled to the image actually read: ``fx = f * width / hwf_w``,
  ``fy = f * height / hwf_h`` (equal for an aspect-preserving resize), ``cx = width / 2``,
  ``cy = height / 2``, no distortion.
- near / far are the file's bounds, unchanged. LLFF computes them from camera z-depths of the
  sparse points, so ``near`` is also a valid lower bound along the unit ray, while points near the
  image corners can lie slightly beyond ``far`` along their ray.

Views are the image files sorted by name (the LLFF convention), one per row of the file.
Image folder for ``downscale = d``: ``images_d/`` if it exists (read as is); else ``images/``
area-resampled by d. With ``d = 1`` and no ``images/``, the smallest-factor ``images_N/`` is used
(with a warning). Labels: ``labels_N/`` beside ``images_N/`` when it exists, else ``labels/``,
``<image stem>.png``, at the size of the image file they annotate.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from scenelabel.data.io.common import (
    LABEL_SUFFIX,
    ViewFiles,
    check_downscale,
    check_pose,
    image_size,
    list_images,
    read_view,
    scaled_size,
    scene_classes,
    scene_from_views,
)
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras

__all__ = ["POSES_BOUNDS_FILE", "llff_to_opencv", "read_poses_bounds", "choose_image_folder", "load_llff"]

#: The file this loader reads from a scene folder.
POSES_BOUNDS_FILE = "poses_bounds.npy"

#: Columns per row of poses_bounds.npy: a 3x5 [R | t | hwf] matrix (15) plus near and far (2).
ROW_LENGTH = 17

#: Largest accepted mismatch, in pixels, between an image's height and the height the full-res
#: hwf aspect ratio predicts from its width (official LLFF downsamples round to whole pixels).
ASPECT_TOLERANCE_PX = 1.0

_DOWNSCALED_FOLDER = re.compile(r"^images_(\d+)$")


def llff_to_opencv(pose: np.ndarray) -> np.ndarray:
    """LLFF 3x4 (or 3x5) camera-to-world with axes [down, right, back] -> OpenCV 4x4 c2w.

    Columns ``[right, down, forward, t] = [col1, col0, -col2, col3]``; works on [..., 3, >=4].
    """
    pose = np.asarray(pose, dtype=np.float64)
    c2w = np.zeros(pose.shape[:-2] + (4, 4))
    c2w[..., :3, 0] = pose[..., :3, 1]
    c2w[..., :3, 1] = pose[..., :3, 0]
    c2w[..., :3, 2] = -pose[..., :3, 2]
    c2w[..., :3, 3] = pose[..., :3, 3]
    c2w[..., 3, 3] = 1.0
    return c2w


def read_poses_bounds(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read and check poses_bounds.npy.

    Returns:
        c2w [n, 4, 4] float64 in OpenCV axes (checked rigid), hwf [n, 3] (full-res height,
        width, focal), bounds [n, 2] (near, far).
    Raises:
        InputError: unreadable file, wrong shape, non-finite values, non-positive hwf,
            near >= far, or a non-rigid rotation (naming the row).
    """
    path = Path(path)
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(f"cannot read the file ({error})", path) from None
    if array.ndim != 2 or array.shape[1] != ROW_LENGTH or array.shape[0] == 0:
        raise InputError(f"expected shape [n, {ROW_LENGTH}] (3x5 pose + near, far per view), got {list(array.shape)}", path)
    if not np.issubdtype(array.dtype, np.number):
        raise InputError(f"expected a float array, got dtype {array.dtype}", path)
    array = array.astype(np.float64)
    poses = array[:, :15].reshape(-1, 3, 5)
    hwf, bounds = poses[:, :, 4], array[:, 15:]
    for row in range(len(array)):
        field = f"row {row}"
        if not np.all(np.isfinite(array[row])):
            raise InputError("non-finite values (NaN or Inf)", path, field=field)
        if np.any(hwf[row] <= 0):
            raise InputError(f"height, width and focal must be positive, got {hwf[row].tolist()}", path, field=field)
        if not 0 <= bounds[row, 0] < bounds[row, 1]:
            raise InputError(f"bounds must satisfy 0 <= near < far, got near={bounds[row, 0]}, far={bounds[row, 1]}", path, field=field)
    c2w = np.stack([check_pose(m, path, f"row {row}") for row, m in enumerate(llff_to_opencv(poses))])
    return c2w, hwf.copy(), bounds.copy()


def _downscaled_folders(root: Path) -> dict[int, Path]:
    """{N: root/images_N} for the images_N folders (N >= 1) that exist."""
    found = {}
    for child in root.iterdir() if root.is_dir() else ():
        match = _DOWNSCALED_FOLDER.match(child.name)
        if match and child.is_dir() and int(match.group(1)) >= 1:
            found[int(match.group(1))] = child
    return found


def choose_image_folder(root: str | Path, downscale: int) -> tuple[Path, int]:
    """Pick the image folder for ``downscale`` and the factor still to resample it by.

    ``images_{downscale}/`` (factor 1) if present, else ``images/`` (factor ``downscale``). With
    ``downscale == 1`` and no ``images/``, the smallest-N ``images_N/`` (factor 1, with a warning).

    Raises:
        InputError: no suitable folder, naming the folders that exist.
    """
    root = Path(root)
    folders = _downscaled_folders(root)
    if downscale in folders:
        return folders[downscale], 1
    full = root / "images"
    if full.is_dir():
        return full, downscale
    if downscale == 1 and folders:
        smallest = min(folders)
        warnings.warn(
            f"{root} has no images/ folder; using {folders[smallest].name}/ (1/{smallest} resolution), "
            f"intrinsics scaled to it",
            UserWarning,
            stacklevel=4,
        )
        return folders[smallest], 1
    available = ", ".join(sorted(f"{p.name}/" for p in folders.values())) or "none"
    raise InputError(
        f"no image folder for downscale={downscale}: expected images_{downscale}/ or images/ "
        f"(found image folders: {available})",
        root,
    )


def paired_label_folder(root: Path, image_folder: Path) -> Path:
    """labels_N/ beside images_N/ when it exists, else labels/."""
    match = _DOWNSCALED_FOLDER.match(image_folder.name)
    if match:
        paired = root / f"labels_{match.group(1)}"
        if paired.is_dir():
            return paired
    return root / "labels"


def _intrinsics(hwf: np.ndarray, size: tuple[int, int], image: Path, poses_path: Path) -> tuple[float, float]:
    """(fx, fy) for an image of ``size`` = (width, height) given full-res hwf; checks the aspect."""
    full_h, full_w, focal = hwf
    width, height = size
    predicted_height = full_h * width / full_w
    if abs(height - predicted_height) > ASPECT_TOLERANCE_PX:
        raise InputError(
            f"image size {width}x{height} does not have the aspect ratio of the full-resolution size "
            f"{full_w:g}x{full_h:g} in {poses_path.name}",
            image,
        )
    return focal * width / full_w, focal * height / full_h


def load_llff(path: str | Path, downscale: int = 1) -> Scene:
    """Load an LLFF scene folder into scenelabel's conventions (see the module docstring).

    Args:
        path: the scene folder (holding poses_bounds.npy), or poses_bounds.npy itself.
        downscale: integer factor; selects images_{downscale}/ or resamples images/.
    Returns:
        a Scene (no aabb, frame_id "world"); ``info`` holds format, source, image_folder,
        downscale, resize_factor, bounds, labelled_views, class_colors.
    Raises:
        InputError: for every malformed or inconsistent input, naming the file and the problem.
    """
    downscale = check_downscale(downscale)
    path = Path(path)
    root = path.parent if path.name == POSES_BOUNDS_FILE and path.is_file() else path
    poses_path = root / POSES_BOUNDS_FILE
    if not poses_path.is_file():
        raise InputError("file not found", poses_path)
    c2w, hwf, bounds = read_poses_bounds(poses_path)

    folder, factor = choose_image_folder(root, downscale)
    images = list_images(folder)
    if not images:
        raise InputError("no image files (.png, .jpg, .jpeg) in the image folder", folder)
    if len(images) != len(c2w):
        raise InputError(
            f"{len(images)} images in {folder.name}/ but {len(c2w)} poses in {POSES_BOUNDS_FILE}; "
            f"LLFF pairs sorted image names with rows one to one",
            folder,
        )
    if len(images) < 2:
        raise InputError(f"only {len(images)} view; at least 2 views are needed", poses_path)

    label_folder = paired_label_folder(root, folder)
    files, file_sizes, sizes, fx, fy = [], [], [], [], []
    for view, image in enumerate(images):
        label = label_folder / (image.stem + LABEL_SUFFIX)
        files.append(ViewFiles(name=image.stem, image=image, label=label if label.is_file() else None))
        file_size = image_size(image)
        size = scaled_size(*file_size, factor)
        fx_view, fy_view = _intrinsics(hwf[view], size, image, poses_path)
        file_sizes.append(file_size)
        sizes.append(size)
        fx.append(fx_view)
        fy.append(fy_view)

    vocabulary = scene_classes(root, labelled=any(f.label is not None for f in files))
    views = [read_view(f, fs, s, vocabulary) for f, fs, s in zip(files, file_sizes, sizes)]
    widths = np.array([s[0] for s in sizes])
    heights = np.array([s[1] for s in sizes])
    cameras = Cameras.create(
        c2w,
        fx=fx,
        fy=fy,
        cx=widths / 2.0,
        cy=heights / 2.0,
        width=widths,
        height=heights,
        near=bounds[:, 0],
        far=bounds[:, 1],
    )
    info = {
        "format": "llff",
        "source": str(poses_path),
        "image_folder": folder.name,
        "downscale": downscale,
        "resize_factor": factor,
        "bounds": "near/far from poses_bounds.npy (LLFF camera z-depth bounds, unchanged)",
        "labelled_views": sum(v[1] is not None for v in views),
        "class_colors": dict(vocabulary.colors),
    }
    return scene_from_views(root, cameras, files, views, vocabulary, info)
