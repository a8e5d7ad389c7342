"""Structure from motion for images-only scene folders (pycolmap 4.x, CPU).

``run_sfm(scene_dir)`` recovers camera poses and intrinsics for a folder that holds ``images/``
and nothing to say where the cameras were. Steps (pycolmap's COLMAP pipeline):

1. SIFT features on the CPU, images shrunk to at most ``max_image_size`` pixels on their longer
   side for detection (keypoints are scaled back, so the cameras refer to the full-size files).
   One camera shared by all images when they all have the same size and the same EXIF camera
   (make, model, focal length; or no EXIF at all), else one camera per image.
2. Matching: ``"exhaustive"`` (every pair; unordered photo sets), ``"sequential"`` (each image with
   its next neighbours by file name; ordered video frames), or ``"auto"``: exhaustive up to
   :data:`EXHAUSTIVE_MAX_IMAGES` images, above that sequential when one camera took every image
   (a video) and exhaustive otherwise.
3. Incremental mapping; the reconstruction with the most registered images is kept.

Results are cached in the scene folder (a second call reuses them unless ``force=True``)::

    sparse/0/{cameras,images,points3D}.bin   the COLMAP model: world-to-camera poses (OpenCV
                                             axes), the camera model fitted (SIMPLE_RADIAL by
                                             default), full-resolution pixel coordinates
    sfm/database.db                          COLMAP's features and matches
    sfm/report.json                          what ran and what registered (SfmResult fields)
    sfm/transforms.json                      the same cameras in nerfstudio form, to inspect
    sfm/undistorted/                         with undistort=True: pinhole images + model
                                             (images/, sparse/) and their transforms.json

``sfm/transforms.json`` lives in ``sfm/`` (not next to ``images/``) so that the loader dispatch,
which reads ``<scene>/transforms.json`` first, keeps loading the scene through the COLMAP model
(labels in ``labels/`` refer to the original images). Its ``file_path`` entries are relative to
``sfm/`` (``../images/<name>``); ``transform_matrix`` is camera-to-world in OpenGL axes
(scenelabel's ``c2w @ diag(1, -1, -1, 1)``); intrinsics ``fl_x fl_y cx cy w h`` and OpenCV
distortion ``k1 k2 p1 p2`` (SIMPLE_RADIAL's ``k`` is OpenCV's ``k1``); one global camera, or
per-frame intrinsics when there are several.

The world frame is COLMAP's (arbitrary origin, orientation and scale; docs/conventions.md keeps
the input's frame). COLMAP's pixel coordinates put the centre of the top-left pixel at (0.5, 0.5),
as scenelabel does, so intrinsics carry over unchanged.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image

from scenelabel.data.io.common import image_size, list_images
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import opencv_to_opengl

__all__ = [
    "quiet_colmap",
    "MATCHERS",
    "CAMERA_MODELS",
    "EXHAUSTIVE_MAX_IMAGES",
    "SFM_FOLDER",
    "SPARSE_MODEL",
    "SfmResult",
    "run_sfm",
    "default_min_registered",
    "read_sfm_poses",
    "write_sfm_transforms",
]

logger = logging.getLogger(__name__)

#: Accepted values of ``run_sfm(matcher=...)``.
MATCHERS = ("auto", "exhaustive", "sequential")
#: COLMAP camera models run_sfm fits: all are a pinhole with (at most) OpenCV k1 k2 p1 p2.
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
#: ``matcher="auto"`` matches every pair up to this many images.
EXHAUSTIVE_MAX_IMAGES = 50
#: Folder (in the scene folder) for the database, the report and the inspectable transforms.json.
SFM_FOLDER = "sfm"
#: The kept reconstruction, relative to the scene folder (what a COLMAP loader reads).
SPARSE_MODEL = "sparse/0"
DATABASE_FILE = "database.db"
REPORT_FILE = "report.json"
TRANSFORMS_FILE = "transforms.json"
UNDISTORTED_FOLDER = "undistorted"
IMAGES_FOLDER = "images"

#: Right-multiplying an OpenCV-axes camera-to-world by this gives OpenGL axes (and back).
_MODEL_FILES = ("cameras", "images", "points3D")
# EXIF tags: Make, Model, and in the Exif IFD FocalLength, FocalLengthIn35mmFilm
_EXIF_MAKE, _EXIF_MODEL, _EXIF_IFD, _EXIF_FOCAL, _EXIF_FOCAL_35MM = 271, 272, 0x8769, 37386, 41989


@dataclass(frozen=True)
class SfmResult:
    """What structure from motion recovered for a scene folder.

    Attributes:
        scene_dir: the scene folder.
        model_dir: the kept COLMAP model (``scene_dir/sparse/0``).
        n_images: images in ``scene_dir/images``.
        registered: names (file names in images/) of the images with a recovered pose, sorted.
        unregistered: names of the images left out, sorted.
        n_points3D: triangulated points in the model.
        mean_reprojection_error: mean reprojection error of the points' observations, pixels.
        matcher: "exhaustive" or "sequential" (what ran; "unknown" for a model run_sfm did not make).
        camera_mode: "single" (one shared camera) or "per_image".
        camera_model: the COLMAP camera model fitted (e.g. "SIMPLE_RADIAL").
        seconds: wall time of the SfM run (of the original run when ``cached``).
        cached: True when the model was reused from the scene folder rather than recomputed.
        transforms_path: ``sfm/transforms.json`` (nerfstudio form, for inspection), or None when
            the camera model has no OpenCV k1 k2 p1 p2 equivalent.
        undistorted_dir: ``sfm/undistorted`` with pinhole images and model, or None.
    """

    scene_dir: Path
    model_dir: Path
    n_images: int
    registered: tuple[str, ...]
    unregistered: tuple[str, ...]
    n_points3D: int
    mean_reprojection_error: float
    matcher: str
    camera_mode: str
    camera_model: str
    seconds: float
    cached: bool = False
    transforms_path: Path | None = None
    undistorted_dir: Path | None = None

    @property
    def n_registered(self) -> int:
        """Number of images with a recovered pose."""
        return len(self.registered)

    def summary(self) -> str:
        """One line for logs and the CLI."""
        source = "cached" if self.cached else f"{self.seconds:.1f} s"
        return (
            f"registered {self.n_registered} of {self.n_images} images, {self.n_points3D} points, "
            f"mean reprojection error {self.mean_reprojection_error:.2f} px "
            f"({self.matcher} matching, {self.camera_mode.replace('_', '-')} {self.camera_model} camera; {source})"
        )


def default_min_registered(n_images: int) -> int:
    """Fewest registered images accepted by default: max(3, half the images), at most all of them."""
    return min(n_images, max(3, math.ceil(0.5 * n_images)))


# --------------------------------------------------------------------------------------------
# pycolmap helpers


def _pycolmap():
    """Import pycolmap, or an InputError saying how to get it."""
    try:
        import pycolmap
    except ImportError as error:  # pragma: no cover - a dependency in pyproject.toml
        raise InputError(f"structure from motion needs pycolmap >= 4 (pip install pycolmap): {error}") from None
    return pycolmap


@contextmanager
def quiet_colmap(pycolmap):
    """Silence COLMAP's INFO/WARNING log lines (glog) while inside; errors still show."""
    previous = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous


def _model_exists(model_dir: Path) -> bool:
    """A COLMAP model (binary or text) is in ``model_dir``."""
    return all((model_dir / f"{name}.bin").is_file() or (model_dir / f"{name}.txt").is_file() for name in _MODEL_FILES)


def _read_model(model_dir: Path):
    """Read a COLMAP model as a pycolmap.Reconstruction; InputError naming the folder if unreadable."""
    pycolmap = _pycolmap()
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as error:  # pycolmap raises plain RuntimeError / ValueError
        raise InputError(f"cannot read the COLMAP model ({error}); pass force=True to recompute it", model_dir) from None


def read_sfm_poses(model_dir: str | Path) -> dict[str, np.ndarray]:
    """Camera-to-world poses of the registered images of a COLMAP model.

    Args:
        model_dir: a COLMAP model folder (e.g. ``scene/sparse/0``).
    Returns:
        {image name: [4, 4] float64 camera-to-world, OpenCV axes}, sorted by name.
    """
    reconstruction = _read_model(Path(model_dir))
    return _poses(reconstruction)


def _poses(reconstruction) -> dict[str, np.ndarray]:
    """{name: [4, 4] c2w (OpenCV axes)} of the registered images, sorted by name."""
    poses = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        poses[image.name] = np.linalg.inv(w2c)
    return dict(sorted(poses.items()))


# --------------------------------------------------------------------------------------------
# choices made before running


def _exif_camera(path: Path) -> tuple:
    """(make, model, focal length, 35 mm focal length) from EXIF; Nones where absent."""
    try:
        with Image.open(path) as image:
            exif = image.getexif()
            sub = exif.get_ifd(_EXIF_IFD)
    except Exception:  # an unreadable EXIF block just means "no EXIF"
        return (None, None, None, None)
    focal = sub.get(_EXIF_FOCAL)
    return (exif.get(_EXIF_MAKE), exif.get(_EXIF_MODEL), None if focal is None else float(focal), sub.get(_EXIF_FOCAL_35MM))


def _single_camera(images: list[Path]) -> tuple[bool, str]:
    """(share one camera?, why): yes when every image has the same size and EXIF camera."""
    sizes = {image_size(p) for p in images}
    if len(sizes) > 1:
        return False, f"{len(sizes)} different image sizes"
    cameras = {_exif_camera(p) for p in images}
    if len(cameras) > 1:
        return False, f"{len(cameras)} different EXIF cameras / focal lengths"
    (camera,) = cameras
    return True, "same size, same EXIF camera" if any(v is not None for v in camera) else "same size, no EXIF"


def _choose_matcher(matcher: str, n_images: int, single_camera: bool) -> str:
    """The matcher to run for ``matcher`` ("auto" resolved; see the module docstring)."""
    if matcher != "auto":
        return matcher
    if n_images <= EXHAUSTIVE_MAX_IMAGES or not single_camera:
        return "exhaustive"
    return "sequential"


def _check_arguments(matcher: str, max_image_size, camera_model: str, max_num_features) -> None:
    if matcher not in MATCHERS:
        raise InputError(f"unknown matcher {matcher!r}; choose one of {', '.join(MATCHERS)}", field="matcher")
    for name, value in (("max_image_size", max_image_size), ("max_num_features", max_num_features)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 16:
            raise InputError(f"must be an integer >= 16, got {value!r}", field=name)
    if camera_model not in CAMERA_MODELS:
        raise InputError(
            f"camera model {camera_model!r} is not supported; choose one of {', '.join(CAMERA_MODELS)} "
            "(pinhole cameras with OpenCV k1 k2 p1 p2 at most)",
            field="camera_model",
        )


# --------------------------------------------------------------------------------------------
# the run


def run_sfm(
    scene_dir: str | Path,
    matcher: str = "auto",
    max_image_size: int = 1600,
    *,
    camera_model: str = "SIMPLE_RADIAL",
    single_camera: bool | None = None,
    max_num_features: int = 8192,
    min_registered: int | None = None,
    undistort: bool = False,
    force: bool = False,
    seed: int = 0,
) -> SfmResult:
    """Recover camera poses for an images-only scene folder and cache them in it.

    Args:
        scene_dir: folder holding ``images/`` (PNG/JPEG; other files there are ignored).
        matcher: "auto", "exhaustive" (unordered photo sets) or "sequential" (ordered video
            frames, matched with their neighbours by file name).
        max_image_size: longer image side, in pixels, for feature detection (speed; the model
            still refers to the full-size images).
        camera_model: COLMAP camera model to fit, one of :data:`CAMERA_MODELS`.
        single_camera: share one camera among all images; None decides from image sizes and EXIF.
        max_num_features: SIFT features kept per image.
        min_registered: fewest registered images accepted; default
            :func:`default_min_registered` (max(3, half the images)).
        undistort: also write pinhole-undistorted images and model to ``sfm/undistorted/``.
        force: recompute even when ``sparse/0`` already holds a model.
        seed: COLMAP's random seed (repeatable runs).
    Returns:
        the :class:`SfmResult`; the model is in ``scene_dir/sparse/0``.
    Raises:
        InputError: no ``images/`` or fewer than 2 images in it, a bad argument, or fewer than
            ``min_registered`` images registered (the message says how many and what to try;
            nothing is written to ``sparse/0`` then).
    """
    pycolmap = _pycolmap()
    _check_arguments(matcher, max_image_size, camera_model, max_num_features)
    scene_dir = Path(scene_dir)
    image_dir = scene_dir / IMAGES_FOLDER
    if not scene_dir.is_dir():
        raise InputError("scene folder not found", scene_dir)
    if not image_dir.is_dir():
        raise InputError("no images/ folder: structure from motion needs the photos in <scene>/images/", scene_dir)
    images = list_images(image_dir)
    if len(images) < 2:
        raise InputError(f"structure from motion needs at least 2 images (.png, .jpg, .jpeg), found {len(images)}", image_dir)
    names = [p.name for p in images]
    minimum = default_min_registered(len(names)) if min_registered is None else int(min_registered)

    sfm_dir = scene_dir / SFM_FOLDER
    model_dir = scene_dir / SPARSE_MODEL
    if _model_exists(model_dir) and not force:
        cached = _cached_result(scene_dir, names, undistort)
        if cached is not None:
            logger.info("sfm: reusing the model in %s (force=True recomputes): %s", model_dir, cached.summary())
            _check_registered(cached, minimum, max_image_size)
            return cached

    start = time.perf_counter()
    if single_camera is None:
        single_camera, why = _single_camera(images)
    else:
        why = "as asked"
        if single_camera and len({image_size(p) for p in images}) > 1:
            raise InputError("single_camera=True but the images have different sizes", image_dir, field="single_camera")
    camera_mode = "single" if single_camera else "per_image"
    used_matcher = _choose_matcher(matcher, len(names), single_camera)
    sfm_dir.mkdir(parents=True, exist_ok=True)
    database = sfm_dir / DATABASE_FILE
    database.unlink(missing_ok=True)

    with quiet_colmap(pycolmap):
        logger.info(
            "sfm: SIFT features of %d images (longer side <= %d px, %s %s camera: %s)",
            len(names), max_image_size, camera_mode.replace("_", "-"), camera_model, why,
        )
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = camera_model
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.max_image_size = int(max_image_size)
        extraction.use_gpu = False
        extraction.sift.max_num_features = int(max_num_features)
        pycolmap.extract_features(
            database,
            image_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        logger.info("sfm: %s matching", used_matcher)
        matching = pycolmap.FeatureMatchingOptions()
        matching.use_gpu = False
        if used_matcher == "exhaustive":
            pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
        else:
            pycolmap.match_sequential(database, matching_options=matching, device=pycolmap.Device.cpu)
        logger.info("sfm: incremental mapping")
        options = pycolmap.IncrementalPipelineOptions()
        options.min_model_size = 3  # keep small models: the largest one is chosen below
        options.random_seed = int(seed)
        options.mapper.random_seed = int(seed)
        options.triangulation.random_seed = int(seed)
        work = sfm_dir / "models.tmp"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        try:
            reconstructions = pycolmap.incremental_mapping(database, image_dir, work, options)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    seconds = time.perf_counter() - start

    best = max(reconstructions.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()), default=None)
    result = _result(
        scene_dir, names, best, matcher=used_matcher, camera_mode=camera_mode, camera_model=camera_model, seconds=seconds
    )
    logger.info("sfm: %s", result.summary())
    _check_registered(result, minimum, max_image_size)

    # only a good model reaches sparse/0 (where loaders look for poses)
    staging = model_dir.with_name(model_dir.name + ".tmp")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    best.write(str(staging))
    shutil.rmtree(model_dir, ignore_errors=True)
    staging.rename(model_dir)
    result = _write_outputs(result, best, undistort, max_image_size, max_num_features)
    return result


def _check_registered(result: SfmResult, minimum: int, max_image_size: int) -> None:
    """InputError when fewer than ``minimum`` images registered, saying what to try."""
    if result.n_registered >= minimum:
        return
    other = "sequential" if result.matcher == "exhaustive" else "exhaustive"
    advice = (
        "video frames in order: try matcher='sequential'"
        if other == "sequential"
        else "an unordered photo set: try matcher='exhaustive'"
    )
    left_out = ", ".join(result.unregistered[:5]) + (", ..." if len(result.unregistered) > 5 else "")
    raise InputError(
        f"structure from motion registered only {result.n_registered} of {result.n_images} images "
        f"(at least {minimum} needed) with {result.matcher} matching; not training on these poses. "
        f"For {advice}; otherwise the photos need more overlap (more views, smaller steps between them) "
        f"or more detail for features (a larger max_image_size than {max_image_size}). "
        f"Not registered: {left_out or 'none'}",
        result.scene_dir / IMAGES_FOLDER,
        field="sfm",
    )


def _result(scene_dir: Path, names: list[str], reconstruction, **run) -> SfmResult:
    """The SfmResult of ``reconstruction`` (None: nothing registered) over the images ``names``;
    ``run``: the remaining SfmResult fields (matcher, camera_mode, camera_model, seconds, ...)."""
    poses = {} if reconstruction is None else _poses(reconstruction)
    registered = tuple(sorted(n for n in poses if n in set(names)))
    return SfmResult(
        scene_dir=scene_dir,
        model_dir=scene_dir / SPARSE_MODEL,
        n_images=len(names),
        registered=registered,
        unregistered=tuple(sorted(set(names) - set(registered))),
        n_points3D=0 if reconstruction is None else reconstruction.num_points3D(),
        mean_reprojection_error=(
            math.nan if reconstruction is None else float(reconstruction.compute_mean_reprojection_error())
        ),
        **run,
    )


def _cached_result(scene_dir: Path, names: list[str], undistort: bool) -> SfmResult | None:
    """The SfmResult of the model already in ``sparse/0``, or None when it is stale.

    Stale: our own report lists a different set of images than images/ holds now.
    """
    model_dir = scene_dir / SPARSE_MODEL
    report_path = scene_dir / SFM_FOLDER / REPORT_FILE
    report = {}
    if report_path.is_file():
        try:
            report = json.loads(report_path.read_text())
        except (OSError, ValueError):
            report = {}
        if sorted(report.get("images", [])) != sorted(names):
            logger.info("sfm: images/ changed since %s was computed; recomputing", model_dir)
            return None
    reconstruction = _read_model(model_dir)
    models = {camera.model_name for camera in reconstruction.cameras.values()}
    result = _result(
        scene_dir,
        names,
        reconstruction,
        matcher=report.get("matcher", "unknown"),
        camera_mode=report.get("camera_mode", "single" if reconstruction.num_cameras() == 1 else "per_image"),
        camera_model=report.get("camera_model", ",".join(sorted(models))),
        seconds=float(report.get("seconds", math.nan)),
        cached=True,
    )
    transforms = scene_dir / SFM_FOLDER / TRANSFORMS_FILE
    undistorted = scene_dir / SFM_FOLDER / UNDISTORTED_FOLDER
    if not transforms.is_file() or (undistort and not (undistorted / TRANSFORMS_FILE).is_file()):
        return _write_outputs(result, reconstruction, undistort, report.get("max_image_size"), report.get("max_num_features"))
    return replace(
        result,
        transforms_path=transforms,
        undistorted_dir=undistorted if (undistorted / TRANSFORMS_FILE).is_file() else None,
    )


def _write_outputs(result: SfmResult, reconstruction, undistort: bool, max_image_size, max_num_features) -> SfmResult:
    """Write sfm/transforms.json, sfm/report.json and (undistort) sfm/undistorted/."""
    sfm_dir = result.scene_dir / SFM_FOLDER
    sfm_dir.mkdir(parents=True, exist_ok=True)
    transforms_path = None
    try:
        transforms_path = write_sfm_transforms(reconstruction, sfm_dir / TRANSFORMS_FILE, Path("..") / IMAGES_FOLDER)
    except InputError as error:
        logger.warning("sfm: no %s written: %s", TRANSFORMS_FILE, error)
    undistorted_dir = None
    if undistort:
        undistorted_dir = _undistort(result, sfm_dir / UNDISTORTED_FOLDER)
    result = replace(result, transforms_path=transforms_path, undistorted_dir=undistorted_dir)
    report = {
        key: (str(value) if isinstance(value, Path) else list(value) if isinstance(value, tuple) else value)
        for key, value in asdict(result).items()
        if key not in ("cached",)
    }
    report["images"] = sorted(result.registered + result.unregistered)
    report["max_image_size"] = max_image_size
    report["max_num_features"] = max_num_features
    if not math.isfinite(report["mean_reprojection_error"]):
        report["mean_reprojection_error"] = None
    (sfm_dir / REPORT_FILE).write_text(json.dumps(report, indent=2) + "\n")
    return result


def _undistort(result: SfmResult, out_dir: Path) -> Path:
    """Pinhole images and model in ``out_dir`` (images/, sparse/) plus its transforms.json."""
    pycolmap = _pycolmap()
    logger.info("sfm: undistorting %d images to pinhole in %s", result.n_registered, out_dir)
    shutil.rmtree(out_dir, ignore_errors=True)
    with quiet_colmap(pycolmap):
        pycolmap.undistort_images(
            str(out_dir), str(result.model_dir), str(result.scene_dir / IMAGES_FOLDER), output_type="COLMAP"
        )
    # keep images/ and sparse/; the multi-view-stereo workspace COLMAP adds is not needed here
    shutil.rmtree(out_dir / "stereo", ignore_errors=True)
    for script in out_dir.glob("run-colmap-*.sh"):
        script.unlink()
    write_sfm_transforms(_read_model(out_dir / "sparse"), out_dir / TRANSFORMS_FILE, Path(IMAGES_FOLDER))
    return out_dir


# --------------------------------------------------------------------------------------------
# transforms.json


def _opencv_intrinsics(camera) -> dict:
    """nerfstudio intrinsics of a COLMAP camera (fl_x fl_y cx cy w h k1 k2 p1 p2)."""
    name = camera.model_name
    p = [float(v) for v in camera.params]
    if name == "SIMPLE_PINHOLE":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (0.0, 0.0, 0.0, 0.0)
    elif name == "PINHOLE":
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], (0.0, 0.0, 0.0, 0.0)
    elif name == "SIMPLE_RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (p[3], 0.0, 0.0, 0.0)
    elif name == "RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (p[3], p[4], 0.0, 0.0)
    elif name == "OPENCV":
        fx, fy, cx, cy = p[:4]
        dist = tuple(p[4:8])
    else:
        raise InputError(f"camera model {name} has no OpenCV k1 k2 p1 p2 equivalent", field="camera_model")
    return {
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": int(camera.width), "h": int(camera.height),
        "k1": dist[0], "k2": dist[1], "p1": dist[2], "p2": dist[3],
    }


def write_sfm_transforms(reconstruction, path: str | Path, image_prefix: str | Path) -> Path:
    """Write a COLMAP reconstruction's registered cameras as a nerfstudio transforms.json.

    Args:
        reconstruction: a pycolmap.Reconstruction, or the folder of a COLMAP model.
        path: the JSON file to write.
        image_prefix: folder of the images relative to ``path``'s folder (``file_path`` is
            ``<prefix>/<image name>``, POSIX).
    Returns:
        ``path``. Frames are sorted by image name; ``transform_matrix`` is camera-to-world in
        OpenGL axes (``c2w_opencv @ diag(1, -1, -1, 1)``); intrinsics are global when all frames
        share one camera, per frame otherwise.
    Raises:
        InputError: a camera model beyond pinhole + OpenCV k1 k2 p1 p2.
    """
    if isinstance(reconstruction, (str, Path)):
        reconstruction = _read_model(Path(reconstruction))
    path = Path(path)
    poses = _poses(reconstruction)
    by_name = {image.name: image for image in reconstruction.images.values()}
    intrinsics = {cid: _opencv_intrinsics(cam) for cid, cam in reconstruction.cameras.items()}
    used = sorted({by_name[name].camera_id for name in poses})
    data: dict = {"camera_model": "OPENCV"}
    if len(used) == 1:
        data.update(intrinsics[used[0]])
    frames = []
    for name, c2w in poses.items():
        frame = {
            "file_path": (Path(image_prefix) / name).as_posix(),
            "transform_matrix": opencv_to_opengl(c2w).tolist(),
            "colmap_image_id": int(by_name[name].image_id),
        }
        if len(used) > 1:
            frame.update(intrinsics[by_name[name].camera_id])
        frames.append(frame)
    data["frames"] = frames
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")
    return path
