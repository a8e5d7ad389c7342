"""A build as a rerun recording (``.rrd``): the map, its meshes, the views and the training curves.

:func:`log_rerun` logs into a file (``scenelabel export BUILD out.rrd``; open it with
``rerun out.rrd``) or into a :class:`rerun.RecordingStream` of your own. Entities (docs/formats.md,
"Exports"):

==============================================  ====================================================
``/``                                           AnnotationContext: class id -> name and colour, and
                                                the codes without a class (:data:`RERUN_FREE`, ...)
``/world``                                      ViewCoordinates RIGHT_HAND_Z_UP (the world is Z-up)
``/world/bounds``                               Boxes3D: the field's modelled bounds (a build)
``/world/map``                                  Points3D: occupied voxel centres, ``class_ids``,
                                                radius half a voxel
``/world/meshes/<class>``                       Mesh3D per class (:func:`scenelabel.maps.exports.class_meshes`)
``/world/views/{train,held_out}/<view>``        Transform3D: camera-to-world
``.../<view>/image``                            Pinhole (OpenCV axes: ViewCoordinates RDF)
``.../<view>/image/photo``, ``.../mask``        Image (RGBA with the photo's alpha), SegmentationImage:
                                                the scene's photo and mask
``.../image/{depth,sensor_depth}``              DepthImage: the scene's true depth and its sensor
                                                depth, where it has them
``.../<view>/image/render/{rgb,labels,depth}``  Image, SegmentationImage, DepthImage: the field's
                                                render of a held-out view
``/training/<key>``                             Scalars of the build's training ``history`` on the
                                                ``step`` timeline (loss, psnr, ...)
``/metrics``                                    TextDocument: the held-out metrics
==============================================  ====================================================

Everything but the training curves is static. rerun's Pinhole has no lens distortion, so a view's
images are resampled to the ideal pinhole with its fx, fy, cx, cy
(:func:`scenelabel.geometry.lens.ideal_pinhole_image`; bilinear for colour, nearest for labels and
depth, unchanged for a camera without distortion): what the view shows lines up with the 3D
scene through the Pinhole drawn, a fisheye's view up to the pinhole's field of view.

Segmentation images hold ``uint16`` class ids (rerun's class ids are unsigned): FREE, UNKNOWN and
the masks' ``ignore_index`` become :data:`RERUN_FREE`, :data:`RERUN_UNKNOWN` and
:data:`RERUN_IGNORED`, each annotated. Depth images hold rerun's z-depth (along the camera's
optical axis, world units, ``meter=1``), converted from scenelabel's depth along each pixel's ray
(through the camera's lens model); 0 where the render hit nothing, the depth has a hole, or (a
fisheye) the pixel looks 90° or more off the axis. rerun is imported inside the functions.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scenelabel.codes import CODE_NAMES
from scenelabel.data.io.depth import z_depth_from_ray_depth
from scenelabel.errors import InputError
from scenelabel.geometry.lens import ideal_pinhole_image
from scenelabel.maps.codes import FREE
from scenelabel.maps.exports.meshes import class_meshes
from scenelabel.maps.exports.palette import class_palette
from scenelabel.maps.exports.ply import occupied_voxels
from scenelabel.maps.occupancy_map import OccupancyMap
from scenelabel.query.build_outputs import own_map
from scenelabel.query.postprocess import IGNORE_COLOR, NO_CLASS_COLOR
from scenelabel.viz.pictures import UNKNOWN_COLOR

__all__ = [
    "RERUN_FREE",
    "RERUN_UNKNOWN",
    "RERUN_IGNORED",
    "RecordingSummary",
    "log_rerun",
    "rerun_class_ids",
]

RERUN_FREE = 65535
"""Class id of FREE pixels (nothing hit) in segmentation images."""
RERUN_UNKNOWN = 65534
"""Class id of UNKNOWN pixels in segmentation images."""
RERUN_IGNORED = 65533
"""Class id of a mask's ``ignore_index`` (unlabelled) pixels."""
_CODE_NAMES = {RERUN_FREE: "FREE", RERUN_UNKNOWN: "UNKNOWN", RERUN_IGNORED: "unlabelled"}
IMAGE_PLANE_FRACTION = 0.05
"""Pinholes draw their image plane at this fraction of the scene box's diagonal from the camera."""


class RecordingSummary(NamedTuple):
    """What :func:`log_rerun` logged.

    path: the .rrd written, or None when logging into a given recording.
    entity_paths: every entity logged, sorted.
    n_points: map points (occupied voxels).
    n_meshes: class meshes.
    n_views: views (training and held-out cameras).
    n_renders: held-out views rendered.
    n_steps: training history rows.
    """

    path: Path | None
    entity_paths: list[str]
    n_points: int
    n_meshes: int
    n_views: int
    n_renders: int
    n_steps: int


def rerun_class_ids(label: np.ndarray, ignore_index: int | None = None) -> np.ndarray:
    """scenelabel labels -> rerun class ids: [...] int -> [...] uint16.

    Class ids stay; FREE -> :data:`RERUN_FREE`, UNKNOWN (and any other negative code) ->
    :data:`RERUN_UNKNOWN`, ``ignore_index`` -> :data:`RERUN_IGNORED`.

    Raises:
        InputError: a class id above 65532 (rerun's ids are 16-bit; the top three are taken).
    """
    label = np.asarray(label, np.int64)
    out = np.where(label == FREE, RERUN_FREE, np.where(label < 0, RERUN_UNKNOWN, label))
    if ignore_index is not None:
        out = np.where(label == ignore_index, RERUN_IGNORED, out)
    is_class = (label >= 0) if ignore_index is None else (label >= 0) & (label != ignore_index)
    if is_class.any() and int(label[is_class].max()) >= RERUN_IGNORED:
        raise InputError(
            f"class id {int(label[is_class].max())} does not fit a rerun class id (at most {RERUN_IGNORED - 1})",
            field="label",
        )
    return out.astype(np.uint16)


# --------------------------------------------------------------------------------------------
# Sources
# --------------------------------------------------------------------------------------------


class _Sources(NamedTuple):
    field: Any  # SemanticField or None
    occ_map: OccupancyMap | None
    build_dir: Path | None


def _open(source: Any) -> _Sources:
    """A build folder, checkpoint, map .zarr, SemanticField or OccupancyMap -> what it holds."""
    if isinstance(source, OccupancyMap):
        return _Sources(None, source, None)
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if (path / "checkpoint.pt").is_file() or (path.is_file() and path.suffix == ".pt"):
            from scenelabel.query.field import SemanticField

            return _Sources(SemanticField.load(path), None, path if path.is_dir() else path.parent)
        if path.is_dir() and ((path / "zarr.json").is_file() or (path / ".zgroup").is_file()):
            return _Sources(None, OccupancyMap.from_zarr(path), None)
        raise InputError("neither a build folder (with checkpoint.pt) nor an occupancy map (.zarr folder)", path=path)
    if hasattr(source, "render_camera") and hasattr(source, "class_map"):  # a SemanticField
        return _Sources(source, None, None)
    raise InputError(
        f"log_rerun needs a build folder, a map .zarr, a SemanticField or an OccupancyMap, got {type(source).__name__}",
        field="source",
    )


def _build_map(sources: _Sources) -> OccupancyMap | None:
    """The map of a build: its own ``map.zarr`` when that fits (:func:`own_map`), else the field's."""
    occ = None if sources.build_dir is None else own_map(sources.build_dir)
    if occ is None and sources.field is not None:
        occ = sources.field.occupancy_map()
    return occ


def _load_scene(scene: Any, field: Any, guessed: bool):
    """A Scene, loaded as the build loaded it (downscale, scale); None for a guess that does not load."""
    from scenelabel.data.io import load_scene
    from scenelabel.data.scene import Scene

    if scene is None or isinstance(scene, Scene):
        return scene
    data = None if field is None else field.config.data
    try:
        loaded = load_scene(scene, 1 if data is None else data.downscale)
    except InputError:
        if guessed:
            return None
        raise
    if data is not None and data.scale is not None:
        loaded = loaded.scaled(data.scale)
    return loaded


def _guess_scene(build_dir: Path | None) -> Path | None:
    """``BUILD/..`` when BUILD is where ``build`` writes by default (``SCENE/scenelabel``)."""
    if build_dir is None:
        return None
    parent = build_dir.resolve().parent
    return parent if (parent / "images").is_dir() else None


def _read_metrics(metrics: Any, build_dir: Path | None) -> dict:
    if isinstance(metrics, Mapping):
        return dict(metrics)
    path = Path(metrics) if metrics is not None else (None if build_dir is None else build_dir / "metrics.json")
    if path is None or not path.is_file():
        if metrics is not None:
            raise InputError("no such metrics file", path=path)
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(f"cannot read the metrics ({err})", path=path) from None


# --------------------------------------------------------------------------------------------
# Logging
# --------------------------------------------------------------------------------------------


class _Logger:
    """Logs into one recording and remembers the entity paths."""

    def __init__(self, rec: Any):
        import rerun as rr

        self.rr, self.rec, self.paths = rr, rec, set()

    def log(self, path: str, *archetypes: Any) -> None:
        self.rec.log(path, *archetypes, static=True)
        self.paths.add("/" + path.strip("/"))

    def part(self, name: str) -> str:
        return self.rr.escape_entity_path_part(str(name))


def _annotation(log: _Logger, classes: Mapping[int, str], class_colors: Mapping[int, Any]) -> None:
    rr = log.rr
    palette = class_palette(classes, class_colors)
    infos = [rr.AnnotationInfo(id=int(cid), label=classes[cid], color=palette[cid]) for cid in sorted(classes)]
    infos += [
        rr.AnnotationInfo(id=RERUN_FREE, label=_CODE_NAMES[RERUN_FREE], color=NO_CLASS_COLOR),
        rr.AnnotationInfo(id=RERUN_UNKNOWN, label=_CODE_NAMES[RERUN_UNKNOWN], color=UNKNOWN_COLOR),
        rr.AnnotationInfo(id=RERUN_IGNORED, label=_CODE_NAMES[RERUN_IGNORED], color=IGNORE_COLOR),
    ]
    log.log("/", rr.AnnotationContext(infos))


def _log_map(log: _Logger, occ_map: OccupancyMap) -> int:
    ijk, label = occupied_voxels(occ_map)
    points = occ_map.world_from_index(ijk).astype(np.float32)
    class_ids = rerun_class_ids(label)
    log.log("world/map", log.rr.Points3D(points, class_ids=class_ids, radii=np.float32(occ_map.voxel_size / 2)))
    return len(points)


def _log_meshes(log: _Logger, occ_map: OccupancyMap, palette: Mapping[int, tuple[int, int, int]]) -> int:
    n = 0
    for cid, (vertices, faces, normals) in class_meshes(occ_map).items():
        if len(faces) == 0:
            continue
        name = occ_map.classes.get(cid, f"class_{cid}")
        color = palette.get(cid, (200, 200, 200))
        log.log(
            f"world/meshes/{log.part(f'{cid}_{name}')}",
            log.rr.Mesh3D(
                vertex_positions=vertices.astype(np.float32),
                triangle_indices=faces.astype(np.uint32),
                vertex_normals=normals.astype(np.float32),
                albedo_factor=(*color, 255),
                class_ids=np.full(len(vertices), cid, np.uint16),
            ),
        )
        n += 1
    return n


def _uint8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    return image if image.dtype == np.uint8 else (np.clip(image, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)


def _log_camera(log: _Logger, base: str, cameras: Any, index: int, plane: float) -> None:
    rr = log.rr
    cam = cameras[index]
    c2w = np.asarray(cam.c2w[0], np.float64)
    log.log(base, rr.Transform3D(translation=c2w[:3, 3], mat3x3=c2w[:3, :3]))
    # rerun's Pinhole has no lens distortion: it is the ideal pinhole with the camera's fx, fy, cx,
    # cy, and every image logged under it is resampled to that pinhole (_pinhole_view)
    k = np.array([[cam.fx[0], 0.0, cam.cx[0]], [0.0, cam.fy[0], cam.cy[0]], [0.0, 0.0, 1.0]])
    log.log(
        f"{base}/image",
        rr.Pinhole(image_from_camera=k, resolution=[int(cam.width[0]), int(cam.height[0])],
                   camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=plane),
    )


def _pinhole_view(
    cameras: Any, index: int, image: np.ndarray, nearest: bool = False, fill: float = 0.0
) -> np.ndarray:
    """``image`` of camera ``index`` as its Pinhole in the recording shows it
    (:func:`scenelabel.geometry.lens.ideal_pinhole_image`: unchanged for an undistorted pinhole)."""
    cam = cameras[index]
    lens = (cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0], cam.distortion[0], str(cam.model[0]))
    return ideal_pinhole_image(image, *lens, nearest=nearest, fill=fill)


def _z_depth_image(cameras: Any, index: int, depth: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """A depth along each pixel's ray -> the recording's z-depth image [h, w] float32 (under the
    view's Pinhole; 0 where ``valid`` is False, the depth is not finite, or z <= 0)."""
    cam = cameras[index]
    z = z_depth_from_ray_depth(depth, cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0], cam.distortion[0], str(cam.model[0]))
    keep = np.isfinite(z) & (z > 0) & (True if valid is None else valid)  # NaN: a fisheye's pixels past 90° have no z
    return _pinhole_view(cameras, index, np.where(keep, z, 0.0).astype(np.float32), nearest=True)


def _log_render(log: _Logger, base: str, field: Any, cameras: Any, index: int) -> None:
    rr = log.rr
    out = field.render_camera(cameras, index)
    labels = _pinhole_view(cameras, index, rerun_class_ids(out.label), nearest=True, fill=RERUN_UNKNOWN)
    log.log(f"{base}/image/render/rgb", rr.Image(_pinhole_view(cameras, index, _uint8(out.rgb))))
    log.log(f"{base}/image/render/labels", rr.SegmentationImage(labels))
    depth = _z_depth_image(cameras, index, out.depth, out.label >= 0)
    log.log(f"{base}/image/render/depth", rr.DepthImage(depth, meter=1.0))


def _log_scene_view(log: _Logger, base: str, scene: Any, index: int) -> None:
    """A scene's photo (RGBA where it has an alpha channel), mask, true depth and sensor depth."""
    rr, cams = log.rr, scene.cameras
    photo = _uint8(scene.images[index])
    alphas = scene.image_alphas
    if alphas is not None and alphas[index] is not None:
        photo = np.concatenate([photo, _uint8(alphas[index])[..., None]], -1)
    log.log(f"{base}/image/photo", rr.Image(_pinhole_view(cams, index, photo)))
    if scene.labels[index] is not None:
        mask = rerun_class_ids(scene.labels[index], scene.ignore_index)
        mask = _pinhole_view(cams, index, mask, nearest=True, fill=RERUN_IGNORED)
        log.log(f"{base}/image/mask", rr.SegmentationImage(mask))
    for name, depths in (("depth", scene.depths), ("sensor_depth", scene.sensor_depths)):
        if depths is not None and depths[index] is not None:
            log.log(f"{base}/image/{name}", rr.DepthImage(_z_depth_image(cams, index, depths[index]), meter=1.0))


def _log_views(log: _Logger, field: Any, scene: Any, render: bool, plane: float) -> tuple[int, int]:
    """Training and held-out views: cameras, photos and masks (with a scene), renders of held-out
    views (with a field and a scene). Returns (views, renders)."""
    meta = {} if field is None else field.meta
    train_names, test_names = list(meta.get("train_views", [])), set(meta.get("test_views", []))
    if scene is None:
        cameras = None if field is None else field.training_cameras()
        if cameras is None:
            return 0, 0
        names = train_names if len(train_names) == len(cameras) else [f"{i:04d}" for i in range(len(cameras))]
        for i, name in enumerate(names):
            _log_camera(log, f"world/views/train/{log.part(name)}", cameras, i, plane)
        return len(names), 0
    if field is not None:
        missing = sorted((set(train_names) | test_names) - set(scene.names))
        if missing:
            raise InputError(f"the scene lacks views the build was trained or evaluated on: {', '.join(missing[:5])}",
                             path=scene.root)
    n_renders = 0
    for i, name in enumerate(scene.names):
        held_out = name in test_names
        if field is not None and not held_out and name not in train_names:
            continue
        base = f"world/views/{'held_out' if held_out else 'train'}/{log.part(name)}"
        _log_camera(log, base, scene.cameras, i, plane)
        _log_scene_view(log, base, scene, i)
        if held_out and render and field is not None:
            _log_render(log, base, field, scene.cameras, i)
            n_renders += 1
    return len(scene), n_renders


def _log_history(log: _Logger, history: list[dict]) -> int:
    rr = log.rr
    rows = [h for h in history if isinstance(h, Mapping) and isinstance(h.get("step"), (int, float))]
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    keys = sorted({k for h in rows for k, v in h.items() if k != "step" and number(v)})
    for key in keys:
        kept = [h for h in rows if isinstance(h.get(key), (int, float)) and np.isfinite(h[key])]
        if not kept:
            continue
        path = f"training/{log.part(key)}"
        log.log(path, rr.SeriesLines(names=key))
        log.rec.send_columns(
            path,
            indexes=[rr.TimeColumn("step", sequence=np.array([int(h["step"]) for h in kept], np.int64))],
            columns=rr.Scalars.columns(scalars=np.array([float(h[key]) for h in kept], np.float64)),
        )
    return len(rows)


def _metrics_text(metrics: Mapping[str, Any], classes: Mapping[int, str]) -> str:
    lines = ["# Held-out metrics", ""]
    for key in ("psnr", "ssim", "miou", "miou_common", "miou_smoothed", "depth_error", "n_test_views", "steps",
                "train_seconds"):
        if key in metrics:
            value = metrics[key]
            lines.append(f"- **{key}**: {value:.4g}" if isinstance(value, float) else f"- **{key}**: {value}")
    per_class = metrics.get("per_class_iou") or {}
    if per_class:
        lines += ["", "| class | IoU |", "|---|---|"]
        for cid, iou in per_class.items():
            name = CODE_NAMES.get(int(cid)) or classes.get(int(cid), cid)  # FREE: held-out pixels that see nothing
            lines.append(f"| {name} | {'-' if iou is None else f'{iou:.3f}'} |")
    return "\n".join(lines)


def _scene_box(field: Any, occ_map: OccupancyMap | None, scene: Any) -> np.ndarray | None:
    if field is not None:
        return np.asarray(field.aabb, np.float64)
    if occ_map is not None:
        return np.stack(occ_map.bounds)
    if scene is not None:
        centres = scene.cameras.centres
        return np.stack([centres.min(0), centres.max(0)])
    return None


def _vocabulary(field: Any, occ_map: OccupancyMap | None, scene: Any) -> tuple[dict[int, str], dict[int, Any]]:
    """Every class that may appear (the scene's vocabulary, the field's, the map's) and their colours."""
    classes: dict[int, str] = {}
    colors: dict[int, Any] = {}
    if scene is not None:
        classes.update(scene.classes)
        colors.update({int(k): v for k, v in (scene.info.get("class_colors") or {}).items()})
    if field is not None:
        classes.update({int(k): v for k, v in (field.meta.get("classes") or {}).items()})
        classes.update(field.classes)
        colors.update({int(k): v for k, v in (field.meta.get("class_colors") or {}).items()})
    if occ_map is not None:
        classes.update(occ_map.classes)
        colors.update(occ_map.class_colors or {})
    return classes, {k: v for k, v in colors.items() if k in classes}


def _log_all(
    log: _Logger, sources: _Sources, occ_map: OccupancyMap | None, scene: Any, options: dict
) -> RecordingSummary:
    rr, field = log.rr, sources.field
    classes, colors = _vocabulary(field, occ_map, scene)
    _annotation(log, classes, colors)
    log.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
    box = _scene_box(field, occ_map, scene)
    plane = 0.1 if box is None else max(IMAGE_PLANE_FRACTION * float(np.linalg.norm(box[1] - box[0])), 1e-3)
    if field is not None:
        log.log("world/bounds", rr.Boxes3D(mins=box[0], sizes=box[1] - box[0], labels="modelled bounds"))
    n_points = n_meshes = 0
    if occ_map is not None:
        n_points = _log_map(log, occ_map)
        if options["meshes"]:
            n_meshes = _log_meshes(log, occ_map, class_palette(classes, colors))
    n_views, n_renders = _log_views(log, field, scene, options["render"], plane)
    metrics = options["metrics"]
    n_steps = _log_history(log, list(metrics.get("history") or []))
    if any(k in metrics for k in ("psnr", "miou", "per_class_iou")):
        log.log("metrics", rr.TextDocument(_metrics_text(metrics, classes), media_type=rr.MediaType.MARKDOWN))
    return RecordingSummary(None, sorted(log.paths), n_points, n_meshes, n_views, n_renders, n_steps)


def log_rerun(
    source: Any,
    path_or_recording: Any,
    *,
    scene: Any = None,
    occ_map: OccupancyMap | None = None,
    metrics: Any = None,
    meshes: bool = True,
    render: bool = True,
    application_id: str = "scenelabel",
) -> RecordingSummary:
    """Log a build (or a map) into a rerun recording: entities in the module docstring.

    Args:
        source: a build folder (or its checkpoint.pt), a map ``.zarr`` folder, a
            :class:`~scenelabel.query.field.SemanticField` or an :class:`~scenelabel.maps.OccupancyMap`.
        path_or_recording: the ``.rrd`` file to write (replaced atomically), or a
            ``rerun.RecordingStream`` to log into (left open).
        scene: the scene folder (or a loaded Scene) of the views' photos and masks; for a build
            it is loaded as the build loaded it (its ``downscale`` and ``scale``). Default: the
            build folder's parent when the build is in its default place (``SCENE/scenelabel``);
            else none: the training cameras alone, from the checkpoint.
        occ_map: the map to log (default: the source's map: a build's own ``map.zarr``, else its
            field's at the default voxel size).
        metrics: the build's metrics (a dict or a ``metrics.json`` path; default: the build
            folder's), for the training curves and the held-out figures.
        meshes: log one mesh per class (marching cubes on the map; seconds on a large map).
        render: render the held-out views (needs a field and a scene).
        application_id: the recording's application id (a written file).
    Returns:
        :class:`RecordingSummary`.
    Raises:
        InputError: a source or scene that cannot be read, or a scene without the build's views.
    """
    import rerun as rr

    sources = _open(source)
    guessed = scene is None
    scene = _load_scene(_guess_scene(sources.build_dir) if guessed else scene, sources.field, guessed)
    if guessed and scene is not None and sources.field is not None:
        wanted = set(sources.field.meta.get("train_views", [])) | set(sources.field.meta.get("test_views", []))
        scene = scene if wanted <= set(scene.names) else None  # a parent folder that is another scene
    if occ_map is None:
        occ_map = sources.occ_map if sources.occ_map is not None else _build_map(sources)
    options = {"meshes": meshes, "render": render, "metrics": _read_metrics(metrics, sources.build_dir)}
    if not isinstance(path_or_recording, (str, os.PathLike)):
        return _log_all(_Logger(path_or_recording), sources, occ_map, scene, options)
    path = Path(path_or_recording).expanduser()
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    partial = path.with_name(path.name + ".partial")
    rec = rr.RecordingStream(application_id)
    rec.save(partial)
    try:
        summary = _log_all(_Logger(rec), sources, occ_map, scene, options)
        rec.flush()
    except BaseException:
        rec.disconnect()
        partial.unlink(missing_ok=True)
        raise
    rec.disconnect()
    os.replace(partial, path)
    return summary._replace(path=path)
