"""Loader for COLMAP sparse models (``sparse/0/`` or ``sparse/`` + ``images/`` or ``images_N/``).

A COLMAP model is three files, all binary (``cameras.bin``, ``images.bin``, ``points3D.bin``) or
all text (``.txt``), read with ``pycolmap.Reconstruction`` (pycolmap >= 4). The model folder is
``sparse/0/`` when it exists (COLMAP's mapper output; other numbered models are ignored), else
``sparse/`` itself (``colmap image_undistorter`` output). Conversions into docs/conventions.md:

- poses: COLMAP stores world-to-camera ``cam_from_world`` (rotation quaternion + translation)
  in OpenCV camera axes (x right, y down, z forward); scenelabel's ``c2w = inverse(w2c)``
  (``R^T``, ``-R^T t``). The world frame and unit are the model's own: no recentring or rescaling.
- intrinsics: COLMAP's principal point uses scenelabel's pixel convention (the image's top-left
  corner is (0, 0), the centre of pixel (col, row) is (col + 0.5, row + 0.5)), so ``cx, cy`` are
  taken as they are. Camera models, params in COLMAP order -> (fx, fy, cx, cy, distortion) and
  ``Cameras.model`` (docs/conventions.md, "Camera models"), pinholes first:

  ===============  ==========================================  ===============================
  SIMPLE_PINHOLE   f, cx, cy                                   fx = fy = f, no distortion
  PINHOLE          fx, fy, cx, cy                              no distortion
  SIMPLE_RADIAL    f, cx, cy, k                                fx = fy = f, [k, 0, 0, 0]
  RADIAL           f, cx, cy, k1, k2                           fx = fy = f, [k1, k2, 0, 0]
  OPENCV           fx, fy, cx, cy, k1, k2, p1, p2              [k1, k2, p1, p2]
  FULL_OPENCV      fx, fy, cx, cy, k1, k2, p1, p2, k3 .. k6    [k1, k2, p1, p2] if k3..k6 are 0
  ===============  ==========================================  ===============================

  and fisheyes (OpenCV's equidistant model, ``distortion = [k1, k2, k3, k4]``):

  =====================  ================================  ====================================
  SIMPLE_RADIAL_FISHEYE  f, cx, cy, k                      fx = fy = f, [k, 0, 0, 0]
  RADIAL_FISHEYE         f, cx, cy, k1, k2                 fx = fy = f, [k1, k2, 0, 0]
  OPENCV_FISHEYE         fx, fy, cx, cy, k1, k2, k3, k4    [k1, k2, k3, k4]
  =====================  ================================  ====================================

  COLMAP's radial, radial-tangential and fisheye models are OpenCV's (in normalised coordinates),
  so the coefficients carry over unchanged. Every other model (FOV, THIN_PRISM_FISHEYE, ...) is an
  InputError: run ``colmap image_undistorter`` first and load its output folder.
- intrinsics scale with the image actually read (same continuous extent): ``fx *= w / W``,
  ``cx *= w / W``, ``fy *= h / H``, ``cy *= h / H`` for an image of w x h from a COLMAP camera of
  W x H; distortion coefficients (normalised coordinates) are unchanged.
- near / far (distance along the unit ray, per view): from the distances ``|X - C|`` between the
  camera centre ``C`` and the sparse points ``X`` the view observes (its track entries):
  ``near = NEAR_MARGIN * percentile(d, NEAR_PERCENTILE)``,
  ``far = FAR_MARGIN * percentile(d, FAR_PERCENTILE)``: 0.9 x the 0.1th and 1.1 x the 99.9th
  percentiles (LLFF's percentiles, there of z-depths, plus a 10% margin each way: the rare
  outlier points SfM leaves move neither; on the LLFF room, near is within 8% of LLFF's and far
  10-24% beyond it). A view observing fewer than MIN_OBSERVED_POINTS points uses instead every
  model point that projects into its image (in front of it, inside the image rectangle,
  a pinhole's distortion ignored, a fisheye's lens model used) when those are more; NaN ("the input does not say") only when it has no
  point at all.
- aabb: None, as for LLFF: a COLMAP model states no scene bounds; the pipeline bounds the scene
  by the camera frusta over [near, far]. The points' robust box (0.5 / 99.5 percentiles of the
  sparse points per axis, grown to hold the camera centres) is in ``info["points_aabb"]``, in the
  model's units (``Scene.scaled`` does not rescale it).

Views are the registered model images whose file exists, sorted by model image name. Image
folder for ``downscale = d``: as LLFF (:func:`scenelabel.data.io.llff.choose_image_folder`),
``images_d/`` if it exists (read as is), else ``images/`` area-resampled by d. A model image
``NAME`` is the file ``<folder>/NAME``, or else the file with the same path and stem and an
image suffix (``a.JPG`` -> ``a.png``: downsampling tools often convert to PNG). Registered images
without a file are skipped with one warning counting them; image files the model does not
register are ignored (counted in ``info["unregistered_images"]``). Labels: ``labels_N/`` beside
``images_N/`` when it exists, else ``labels/``, ``<name without suffix>.png``, at the size of the
image file they annotate; ``classes.json`` as every loader.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from scenelabel.data.io.common import (
    IMAGE_SUFFIXES,
    LABEL_SUFFIX,
    ViewFiles,
    check_downscale,
    check_pose,
    image_size,
    read_view,
    scaled_size,
    scene_classes,
    scene_from_views,
)
from scenelabel.data.io.llff import ASPECT_TOLERANCE_PX, choose_image_folder, paired_label_folder
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lens import FISHEYE, PINHOLE, pixels_from_camera_points

__all__ = [
    "SPARSE_FOLDER",
    "MODEL_FILES",
    "SUPPORTED_CAMERA_MODELS",
    "find_sparse_dir",
    "colmap_intrinsics",
    "colmap_camera_model",
    "read_colmap_cameras",
    "load_colmap",
]

#: The folder of COLMAP models in a scene folder (``sparse/0/`` or ``sparse/`` itself).
SPARSE_FOLDER = "sparse"

#: The three files of a COLMAP model (each ``.bin`` or ``.txt``).
MODEL_FILES = ("cameras", "images", "points3D")

#: COLMAP camera models that are OpenCV's equidistant fisheye (k1, k2, k3, k4 or fewer) ...
FISHEYE_CAMERA_MODELS = ("SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE")
#: ... and every model scenelabel reads: pinholes with (at most) OpenCV k1 k2 p1 p2 distortion, then those.
SUPPORTED_CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                           *FISHEYE_CAMERA_MODELS)

#: near = NEAR_MARGIN x the NEAR_PERCENTILE-th percentile of a view's point distances ...
NEAR_PERCENTILE = 0.1
NEAR_MARGIN = 0.9
#: ... and far = FAR_MARGIN x the FAR_PERCENTILE-th percentile.
FAR_PERCENTILE = 99.9
FAR_MARGIN = 1.1

#: A view observing fewer points takes its near/far from every model point in its image.
MIN_OBSERVED_POINTS = 10

#: Percentiles (per axis) of the sparse points' robust box in ``info["points_aabb"]``.
POINTS_AABB_PERCENTILES = (0.5, 99.5)

#: How many missing file names a warning lists before "...".
_LIST_LIMIT = 3

#: Smallest size in bytes of one record of each binary model file (after its uint64 record count):
#: cameras: id, model (int32), width, height (uint64); images: id (int32), qvec, tvec (8 doubles),
#: camera id (int32), an empty name (its NUL), no points2D (uint64 count); points3D: id (uint64),
#: xyz (3 doubles), rgb (3 bytes), error (double), an empty track (uint64 count).
_MIN_RECORD_BYTES = {"cameras": 24, "images": 73, "points3D": 51}

#: What pycolmap raises for unreadable or inconsistent model files (a huge count in a truncated
#: .bin is a std::bad_alloc, i.e. MemoryError).
_PYCOLMAP_ERRORS = (ValueError, RuntimeError, IndexError, KeyError, MemoryError, OSError, EOFError)

_UNDISTORT_HINT = (
    "run `colmap image_undistorter --image_path images --input_path sparse/0 --output_path OUT` "
    "first and load OUT (undistorted pinhole images in OUT/images, the model in OUT/sparse)"
)


@dataclass(frozen=True)
class _Model:
    """What the loader takes from a COLMAP model: registered images, sorted by name."""

    folder: Path
    model_format: str  # "bin" or "txt"
    names: list[str]  # model image names (relative paths with suffix)
    cameras: Cameras  # at the COLMAP cameras' resolution, near/far from the points
    camera_models: list[str]  # per view
    points: np.ndarray  # [m, 3]
    num_images: int  # images in the model, registered or not


def _pycolmap():
    """Import pycolmap, or an InputError saying how to get it."""
    try:
        import pycolmap
    except ImportError as error:
        raise InputError(f"reading COLMAP models needs pycolmap >= 4 (pip install pycolmap): {error}") from None
    return pycolmap


def find_sparse_dir(root: str | Path) -> Path | None:
    """The COLMAP model folder of a scene folder: ``sparse/0/`` if it is a folder, else ``sparse/``
    if it holds ``cameras.bin`` or ``cameras.txt``, else None."""
    sparse = Path(root) / SPARSE_FOLDER
    if (sparse / "0").is_dir():
        return sparse / "0"
    if any((sparse / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
        return sparse
    return None


def _model_format(folder: Path) -> str:
    """The format ("bin" or "txt") in which all three model files exist, binary preferred.

    Raises:
        InputError: naming the folder and the files that are missing.
    """
    if not folder.is_dir():
        raise InputError("COLMAP model folder not found", folder)
    for ext in ("bin", "txt"):
        if all((folder / f"{name}.{ext}").is_file() for name in MODEL_FILES):
            return ext
    found = sorted(p.name for p in folder.iterdir() if p.stem in MODEL_FILES and p.suffix in (".bin", ".txt"))
    missing = [name for name in MODEL_FILES if not any((folder / f"{name}.{ext}").is_file() for ext in ("bin", "txt"))]
    what = f"{' and '.join(m + '.bin / .txt' for m in missing)} missing" if missing else "the files mix .bin and .txt"
    poses = " (images holds the camera poses)" if "images" in missing else ""
    raise InputError(
        f"incomplete COLMAP model: {what}{poses}; a model is cameras, images and points3D, all .bin or all .txt "
        f"(found: {', '.join(found) or 'none'})",
        folder,
    )


def _check_binary_counts(folder: Path) -> None:
    """Reject a binary model file whose record count cannot fit in its size (a corrupt or
    truncated file, which pycolmap may spend minutes on before failing).

    Raises:
        InputError: naming the file, its record count and its size.
    """
    for name, record_bytes in _MIN_RECORD_BYTES.items():
        path = folder / f"{name}.bin"
        size = path.stat().st_size
        with path.open("rb") as file:
            header = file.read(8)
        count = int.from_bytes(header, "little") if len(header) == 8 else None
        if count is None:
            raise InputError(f"corrupt or truncated COLMAP file: {size} bytes, too short for its record count", path)
        if count * record_bytes > size - 8:
            raise InputError(
                f"corrupt or truncated COLMAP file: a count of {count} records cannot fit in its {size} bytes", path
            )


def colmap_intrinsics(
    model: str, params, camera: str = "camera", path: Path | None = None
) -> tuple[float, float, float, float, np.ndarray]:
    """A COLMAP camera's (fx, fy, cx, cy, distortion [4]) (module docstring tables): a pinhole's
    k1, k2, p1, p2 or a fisheye's k1, k2, k3, k4 (:func:`colmap_camera_model` says which).

    Args:
        model: COLMAP model name (e.g. "SIMPLE_RADIAL").
        params: the camera's parameters in COLMAP order.
        camera: how to name the camera in errors.
        path: the file to name in errors.
    Raises:
        InputError: an unsupported model (or FULL_OPENCV with non-zero k3..k6), naming the model
            and saying to run ``colmap image_undistorter`` first; a wrong number of params.
    """
    p = np.asarray(params, dtype=np.float64).ravel()
    expected = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12,
                "SIMPLE_RADIAL_FISHEYE": 4, "RADIAL_FISHEYE": 5, "OPENCV_FISHEYE": 8}
    if model not in expected:
        raise InputError(
            f"{camera} has COLMAP camera model {model}, which scenelabel does not support (supported: "
            f"{', '.join(SUPPORTED_CAMERA_MODELS)}: pinholes with at most OpenCV k1, k2, p1, p2, fisheyes with "
            f"OpenCV k1, k2, k3, k4); {_UNDISTORT_HINT}",
            path,
        )
    if len(p) != expected[model]:
        raise InputError(f"{camera}: model {model} takes {expected[model]} params, got {len(p)}", path)
    if not np.all(np.isfinite(p)):
        raise InputError(f"{camera} has non-finite params {p.tolist()}", path)
    distortion = np.zeros(4)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        distortion[: len(p) - 3] = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        distortion[: min(4, len(p) - 4)] = p[4:8]
        if np.any(p[8:] != 0):
            raise InputError(
                f"{camera} has COLMAP camera model {model} with non-zero k3..k6 {p[8:].tolist()}, which scenelabel "
                f"does not support (OpenCV k1, k2, p1, p2 only); {_UNDISTORT_HINT}",
                path,
            )
    if fx <= 0 or fy <= 0:
        raise InputError(f"{camera} has a non-positive focal length (fx={fx}, fy={fy})", path)
    return float(fx), float(fy), float(cx), float(cy), distortion


def colmap_camera_model(model: str) -> str:
    """The ``Cameras.model`` of a (supported) COLMAP camera model: "fisheye" or "pinhole"."""
    return FISHEYE if model in FISHEYE_CAMERA_MODELS else PINHOLE


def _c2w_from_cam_from_world(image, path: Path) -> np.ndarray:
    """scenelabel c2w [4, 4] of a registered pycolmap Image: the rigid inverse of its w2c."""
    pose = image.cam_from_world
    pose = pose() if callable(pose) else pose  # a method in pycolmap 4.x, a property before
    w2c = np.asarray(pose.matrix(), dtype=np.float64)  # [3, 4], OpenCV camera axes
    rotation, translation = w2c[:, :3], w2c[:, 3]
    c2w = np.eye(4)
    c2w[:3, :3] = rotation.T
    c2w[:3, 3] = -rotation.T @ translation
    return check_pose(c2w, path, f"image {image.name!r}")


def _distance_bounds(distances: np.ndarray) -> tuple[float, float]:
    """(near, far) from distances along the unit rays (module docstring); NaN when none is finite."""
    distances = distances[np.isfinite(distances)]
    if len(distances) == 0:
        return np.nan, np.nan
    low, high = np.percentile(distances, [NEAR_PERCENTILE, FAR_PERCENTILE])
    return NEAR_MARGIN * float(low), FAR_MARGIN * float(high)


def _in_image(
    points: np.ndarray, c2w: np.ndarray, fx, fy, cx, cy, width, height, distortion=None, model: str = PINHOLE
) -> np.ndarray:
    """[m] bool: points the camera's lens model projects inside the image (for a pinhole: in front
    of the camera; pass no distortion for an ideal pinhole)."""
    cam = (points - c2w[:3, 3]) @ c2w[:3, :3]  # camera-frame coordinates (R^T (X - C))
    uv = pixels_from_camera_points(cam, fx, fy, cx, cy, distortion, model)  # [m, 2], NaN: not projected
    with np.errstate(invalid="ignore"):
        return (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)


def _pinholes(intrinsics: list[tuple], sizes: list[tuple[int, int]]) -> dict[str, list]:
    """``Cameras.create`` keywords fx, fy, cx, cy, width, height from per-view (fx, fy, cx, cy, ...) and (w, h)."""
    return {
        "fx": [i[0] for i in intrinsics],
        "fy": [i[1] for i in intrinsics],
        "cx": [i[2] for i in intrinsics],
        "cy": [i[3] for i in intrinsics],
        "width": [size[0] for size in sizes],
        "height": [size[1] for size in sizes],
    }


def _read_model(folder: str | Path) -> _Model:
    """Read a COLMAP model folder (module docstring); the registered images sorted by name."""
    folder = Path(folder)
    model_format = _model_format(folder)
    cameras_file = folder / f"cameras.{model_format}"
    images_file = folder / f"images.{model_format}"
    if model_format == "bin":
        _check_binary_counts(folder)
    pycolmap = _pycolmap()
    try:
        reconstruction = pycolmap.Reconstruction(str(folder))
    except _PYCOLMAP_ERRORS as error:
        raise InputError(f"cannot read the COLMAP model ({type(error).__name__}: {error})", folder) from None

    registered = sorted((im for im in reconstruction.images.values() if im.has_pose), key=lambda im: im.name)
    if len(registered) == 0:
        raise InputError(f"the COLMAP model registers no image ({reconstruction.num_images()} images listed)", images_file)

    point_ids = list(reconstruction.points3D.keys())
    points = np.array([reconstruction.points3D[i].xyz for i in point_ids], dtype=np.float64).reshape(-1, 3)
    observed: dict[int, list[int]] = {}
    for row, point_id in enumerate(point_ids):
        for element in reconstruction.points3D[point_id].track.elements:
            observed.setdefault(element.image_id, []).append(row)

    c2ws, intrinsics, models, lenses, sizes, near, far = [], [], [], [], [], [], []
    for image in registered:
        camera = reconstruction.cameras[image.camera_id]
        model = camera.model.name
        fx, fy, cx, cy, distortion = colmap_intrinsics(
            model, camera.params, f"camera {image.camera_id} (image {image.name!r})", cameras_file
        )
        c2w = _c2w_from_cam_from_world(image, images_file)
        rows = sorted(set(observed.get(image.image_id, ())))
        lens = colmap_camera_model(model)
        if len(rows) < MIN_OBSERVED_POINTS:
            lens_distortion = distortion if lens == FISHEYE else None  # a pinhole's distortion ignored
            in_image = _in_image(points, c2w, fx, fy, cx, cy, camera.width, camera.height, lens_distortion, lens)
            in_image = np.flatnonzero(in_image).tolist()
            rows = in_image if len(in_image) > len(rows) else rows
        bounds = _distance_bounds(np.linalg.norm(points[rows] - c2w[:3, 3], axis=1))
        c2ws.append(c2w)
        intrinsics.append((fx, fy, cx, cy, distortion))
        models.append(model)
        lenses.append(lens)
        sizes.append((int(camera.width), int(camera.height)))
        near.append(bounds[0])
        far.append(bounds[1])

    cameras = Cameras.create(
        np.stack(c2ws),
        **_pinholes(intrinsics, sizes),
        distortion=np.stack([i[4] for i in intrinsics]),
        near=near,
        far=far,
        model=lenses,
    )
    return _Model(
        folder=folder,
        model_format=model_format,
        names=[image.name for image in registered],
        cameras=cameras,
        camera_models=models,
        points=points,
        num_images=int(reconstruction.num_images()),
    )


def read_colmap_cameras(sparse_dir: str | Path) -> tuple[list[str], Cameras, np.ndarray]:
    """The registered cameras and the sparse points of a COLMAP model; needs no image files.

    Args:
        sparse_dir: the model folder (cameras, images, points3D as .bin or .txt).
    Returns:
        names: [n] model image names (as in the model, e.g. "IMG_0001.JPG"), sorted;
        cameras: [n] in scenelabel's conventions at the COLMAP cameras' resolution (c2w OpenCV
            axes in the model's world frame, intrinsics, lens model and distortion, near/far
            from the points, see the module docstring);
        points: [m, 3] float64 world positions of the model's 3D points.
    Raises:
        InputError: missing or unreadable files, no registered image, an unsupported camera model.
    """
    model = _read_model(sparse_dir)
    return model.names, model.cameras, model.points


def _find_image(folder: Path, name: str) -> Path | None:
    """The file of model image ``name`` in ``folder``: exact, else same stem + an image suffix."""
    exact = folder / name
    if exact.is_file():
        return exact
    for suffix in IMAGE_SUFFIXES:
        for candidate in (exact.with_suffix(suffix), exact.with_suffix(suffix.upper())):
            if candidate.is_file():
                return candidate
    return None


def _image_files(folder: Path) -> set[Path]:
    """Image files (IMAGE_SUFFIXES, any case) in ``folder`` and its subfolders."""
    return {p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES}


def _view_name(name: str) -> str:
    """A view's name: the model image name without its suffix ("cam0/IMG_1.JPG" -> "cam0/IMG_1")."""
    return PurePosixPath(name).with_suffix("").as_posix()


def _scaled_intrinsics(
    cameras: Cameras, index: int, file_size: tuple[int, int], size: tuple[int, int], image: Path, cameras_file: Path
) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of camera ``index`` for its image resampled to ``size`` = (width, height).

    Raises:
        InputError: the image file's aspect ratio differs from its COLMAP camera's (by more than
            ASPECT_TOLERANCE_PX in height), naming the image.
    """
    cam_w, cam_h = float(cameras.width[index]), float(cameras.height[index])
    if abs(file_size[1] - cam_h * file_size[0] / cam_w) > ASPECT_TOLERANCE_PX:
        raise InputError(
            f"image size {file_size[0]}x{file_size[1]} does not have the aspect ratio of its COLMAP camera "
            f"({cam_w:g}x{cam_h:g} in {cameras_file.name})",
            image,
        )
    sx, sy = size[0] / cam_w, size[1] / cam_h
    return (
        float(cameras.fx[index] * sx),
        float(cameras.fy[index] * sy),
        float(cameras.cx[index] * sx),
        float(cameras.cy[index] * sy),
    )


def _points_aabb(points: np.ndarray, centres: np.ndarray) -> list[list[float]] | None:
    """Robust box [2, 3] of the sparse points (POINTS_AABB_PERCENTILES) holding the camera centres."""
    if len(points) == 0:
        return None
    low, high = np.percentile(points, POINTS_AABB_PERCENTILES, axis=0)
    low = np.minimum(low, centres.min(axis=0))
    high = np.maximum(high, centres.max(axis=0))
    return [low.tolist(), high.tolist()]


def load_colmap(path: str | Path, downscale: int = 1) -> Scene:
    """Load a scene folder with a COLMAP sparse model into scenelabel's conventions.

    See the module docstring for the conversions, image matching and near/far.

    Args:
        path: the scene folder, holding ``sparse/0/`` (or ``sparse/`` with the model files) and
            ``images/`` or ``images_N/``.
        downscale: integer factor; selects images_{downscale}/ or resamples images/.
    Returns:
        a Scene (aabb None, frame_id "world"), one view per registered model image with a file,
        sorted by model image name; ``names`` are model image names without suffix. ``info``
        holds format ("colmap"), source, model_format, image_folder, downscale, resize_factor,
        model_images, registered, skipped_missing, unregistered_images, points3D, points_aabb,
        camera_models, bounds, labelled_views, class_colors.
    Raises:
        InputError: for every malformed or inconsistent input, naming the file and the problem.
    Warns:
        UserWarning: once, counting registered images whose file is missing (they are skipped).
    """
    downscale = check_downscale(downscale)
    root = Path(path)
    if not root.is_dir():
        raise InputError("scene folder not found", root)
    sparse_dir = find_sparse_dir(root)
    if sparse_dir is None:
        raise InputError(
            f"no COLMAP sparse model: expected {SPARSE_FOLDER}/0/ or {SPARSE_FOLDER}/ holding cameras, images and "
            f"points3D (.bin or .txt)",
            root,
        )
    model = _read_model(sparse_dir)
    cameras_file = sparse_dir / f"cameras.{model.model_format}"
    folder, factor = choose_image_folder(root, downscale)

    kept, missing = [], []
    for index, name in enumerate(model.names):
        image = _find_image(folder, name)
        if image is None:
            missing.append(name)
        else:
            kept.append((index, image))
    if missing:
        listed = ", ".join(missing[:_LIST_LIMIT]) + (", ..." if len(missing) > _LIST_LIMIT else "")
        warnings.warn(
            f"{len(missing)} of {len(model.names)} registered images of the COLMAP model in {sparse_dir} have no "
            f"file in {folder}; skipped ({listed})",
            UserWarning,
            stacklevel=2,
        )
    if len(kept) < 2:
        raise InputError(
            f"only {len(kept)} of {len(model.names)} registered images of the COLMAP model have a file in "
            f"{folder.name}/; at least 2 views are needed",
            folder,
        )
    unregistered = len(_image_files(folder) - {image for _, image in kept})

    label_folder = paired_label_folder(root, folder)
    indices, files, file_sizes, sizes, intrinsics = [], [], [], [], []
    for index, image in kept:
        name = _view_name(model.names[index])
        label = label_folder / (name + LABEL_SUFFIX)
        files.append(ViewFiles(name=name, image=image, label=label if label.is_file() else None))
        file_size = image_size(image)
        size = scaled_size(*file_size, factor)
        intrinsics.append(_scaled_intrinsics(model.cameras, index, file_size, size, image, cameras_file))
        indices.append(index)
        file_sizes.append(file_size)
        sizes.append(size)

    vocabulary = scene_classes(root, labelled=any(f.label is not None for f in files))
    views = [read_view(f, fs, s, vocabulary) for f, fs, s in zip(files, file_sizes, sizes)]
    picked = model.cameras[np.array(indices)]
    cameras = Cameras.create(
        picked.c2w,
        **_pinholes(intrinsics, sizes),
        distortion=picked.distortion,
        near=picked.near,
        far=picked.far,
        model=picked.model,
    )
    info = {
        "format": "colmap",
        "source": str(sparse_dir),
        "model_format": model.model_format,
        "image_folder": folder.name,
        "downscale": downscale,
        "resize_factor": factor,
        "model_images": model.num_images,
        "registered": len(model.names),
        "skipped_missing": len(missing),
        "unregistered_images": unregistered,
        "points3D": len(model.points),
        "points_aabb": _points_aabb(model.points, model.cameras.centres),
        "camera_models": sorted(set(model.camera_models)),
        "bounds": (
            f"near = {NEAR_MARGIN:g} x percentile {NEAR_PERCENTILE:g}, far = {FAR_MARGIN:g} x percentile "
            f"{FAR_PERCENTILE:g} of each view's distances (along the unit ray) to the sparse points it observes"
        ),
        "labelled_views": sum(v[1] is not None for v in views),
        "class_colors": dict(vocabulary.colors),
    }
    return scene_from_views(root, cameras, files, views, vocabulary, info)
