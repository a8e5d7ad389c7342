"""Per-pixel sensor inputs of a capture: depth images (RGB-D cameras, phone LiDAR) and masks.

nerfstudio's ``transforms.json`` (written by ``ns-process-data`` for Polycam, COLMAP with
``--use-sfm-depth``, or by hand for Record3D / ARKit exports) names them per frame:

- ``depth_file_path``: a depth image, 16-bit or 8-bit PNG, float EXR (half or full float, read
  with the OpenEXR bindings), float TIFF, or ``.npy``. ``value = raw * depth_unit_scale_factor`` for every
  format (nerfstudio multiplies ``.npy`` too); the factor is read per frame, else at the top
  level, else nerfstudio's default 0.001 (millimetres to metres). Raw values that are zero,
  negative, NaN or infinite are holes (NaN). The file holds **z-depth** (along the camera's optical
  axis); scenelabel converts it to the distance along the unit ray of each colour pixel
  (docs/conventions.md), through the colour camera's own intrinsics and distortion.
- ``mask_path``: a single-channel image, 0 = ignore the pixel, non-zero = use it.

Either may have a lower resolution than the colour image (a phone's LiDAR: 256x192 for 1920x1440)
with the same field of view: depth pixel centre (u, v) is colour pixel coordinate
(u * W / w, v * H / h), pixel centres at +0.5 (so any resolution with the same aspect works,
within :data:`ASPECT_TOLERANCE_PIXELS`). Depth is resampled with :func:`resample_depth`
(bilinear only where the four nearest samples are valid and agree, NaN otherwise: depth edges and
holes are never smeared into wrong values), masks nearest. Both land at the colour image's
training resolution.

Every problem a user can cause raises :class:`scenelabel.errors.InputError` naming the file.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from PIL import Image

from scenelabel.data.io.common import resize_nearest
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lens import PINHOLE
from scenelabel.geometry.rays import camera_directions_from_pixels, pixel_grid

__all__ = [
    "DEFAULT_DEPTH_UNIT_SCALE",
    "DEPTH_AGREEMENT_TOLERANCE",
    "ASPECT_TOLERANCE_PIXELS",
    "WEIGHT_EPS",
    "MIN_DIRECTION_Z",
    "DEPTH_FILE_SUFFIXES",
    "SensorFiles",
    "check_depth_scale",
    "check_same_aspect",
    "frame_sensor_files",
    "read_depth_raw",
    "metric_depth_from_raw",
    "resample_depth",
    "ray_depth_from_z_depth",
    "z_depth_from_ray_depth",
    "read_sensor_depth",
    "read_mask",
    "read_sensor_inputs",
]

#: nerfstudio's default ``depth_unit_scale_factor``: raw depth in millimetres -> metres.
DEFAULT_DEPTH_UNIT_SCALE = 1e-3

#: Largest relative spread ``(max - min) / min`` of the (up to) four depth samples a resampled
#: pixel is interpolated from. Above it the samples straddle a depth edge and the pixel becomes NaN
#: rather than a blend of foreground and background, so no blended value is off by more than this.
#: It must pass a sensor's noise: four samples of one surface with 1.5 % noise (a phone) often
#: spread over 5 %. Measured on phone-like depth of the furnished room at 256x192 (quarter-resolution
#: depth, 1.5 % noise; tools/bench_depth_resample.py): 0.05 leaves 25 % more of the surface pixels
#: without depth than 0.1 (rejecting noise, not edges); on depth without holes at its edges, 0.1
#: keeps the 99th-percentile error at 2.7 % where no check gives 13 %.
DEPTH_AGREEMENT_TOLERANCE = 0.1

#: A depth image or mask must have the colour image's aspect: ``|w - W * h / H| <= 1`` and
#: ``|h - H * w / W| <= 1`` (one pixel of rounding at its own resolution).
ASPECT_TOLERANCE_PIXELS = 1.0

#: Bilinear weights at or below this do not take part in a resampled pixel (exact alignment: a
#: colour pixel centre on a depth pixel centre takes that sample alone, whatever its neighbours).
WEIGHT_EPS = 1e-9

#: A ray whose unit camera-frame direction has z at most this has no z-depth (a fisheye's rays at
#: or past 90° from the axis): its depth is NaN.
MIN_DIRECTION_Z = 1e-6

#: Depth file suffixes (compared case-insensitively).
DEPTH_FILE_SUFFIXES: tuple[str, ...] = (".png", ".exr", ".tif", ".tiff", ".npy")

#: Float depth read with the default (millimetre) scale whose median comes out below this many
#: world units looks like metres: a warning says to set ``depth_unit_scale_factor: 1``.
_IMPLAUSIBLY_SMALL_DEPTH = 0.05

#: Rows resampled at once (bounds the temporaries of :func:`resample_depth` on large images).
_ROW_CHUNK = 256

#: Errors PIL raises for unreadable, truncated or oversized files.
_PIL_ERRORS = (OSError, SyntaxError, ValueError, Image.DecompressionBombError)

#: PIL modes of single-channel images a mask may be.
_MASK_MODES = frozenset({"1", "L", "P", "I", "I;16", "I;16L", "I;16B", "I;16N", "F"})


# --------------------------------------------------------------------------------------------
# which files


@dataclass(frozen=True)
class SensorFiles:
    """One view's sensor inputs: a depth image and its unit scale, and a mask (each optional).

    Attributes:
        depth: the depth file, or None.
        depth_scale: world units per raw depth unit (``depth_unit_scale_factor``).
        depth_scale_given: whether the file said so (else nerfstudio's default was taken).
        mask: the mask image, or None.
    """

    depth: Path | None = None
    depth_scale: float = DEFAULT_DEPTH_UNIT_SCALE
    depth_scale_given: bool = False
    mask: Path | None = None


def check_depth_scale(value: Any, path: Path | None = None, field: str | None = None) -> float:
    """``depth_unit_scale_factor`` as a positive finite float, else InputError."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
        np.isfinite(value) and value > 0
    ):
        raise InputError(
            f"depth_unit_scale_factor must be a positive number (world units per raw depth unit; "
            f"0.001 reads millimetres), got {value!r}",
            path,
            field=field,
        )
    return float(value)


def frame_sensor_files(root: Path, data: dict, frame: dict, index: int, path: Path) -> SensorFiles:
    """A transforms.json frame's ``depth_file_path``, ``depth_unit_scale_factor`` and ``mask_path``.

    Paths are relative to ``root``; the scale factor is the frame's, else the top level's, else
    :data:`DEFAULT_DEPTH_UNIT_SCALE`.

    Raises:
        InputError: a named file is missing, or the scale factor is not positive.
    """
    field = f"$.frames[{index}]"
    if "depth_unit_scale_factor" in frame:
        scale = check_depth_scale(frame["depth_unit_scale_factor"], path, field + ".depth_unit_scale_factor")
        given = True
    elif "depth_unit_scale_factor" in data:
        scale = check_depth_scale(data["depth_unit_scale_factor"], path, "$.depth_unit_scale_factor")
        given = True
    else:
        scale, given = DEFAULT_DEPTH_UNIT_SCALE, False
    depth = mask = None
    if "depth_file_path" in frame:
        depth = root / frame["depth_file_path"]
        if not depth.is_file():
            raise InputError(
                f"depth file {frame['depth_file_path']!r} not found", path, field=field + ".depth_file_path"
            )
    if "mask_path" in frame:
        mask = root / frame["mask_path"]
        if not mask.is_file():
            raise InputError(f"mask file {frame['mask_path']!r} not found", path, field=field + ".mask_path")
    return SensorFiles(depth=depth, depth_scale=scale, depth_scale_given=given, mask=mask)


def check_same_aspect(size: tuple[int, int], image_size: tuple[int, int], path: Path, what: str) -> None:
    """Raise InputError unless ``size`` = (w, h) has the aspect of ``image_size`` = (W, H).

    Within :data:`ASPECT_TOLERANCE_PIXELS` of rounding at the file's own resolution:
    ``|w - W h / H| <= 1`` and ``|h - H w / W| <= 1``.
    """
    (w, h), (big_w, big_h) = size, image_size
    if abs(w - big_w * h / big_h) > ASPECT_TOLERANCE_PIXELS or abs(h - big_h * w / big_w) > ASPECT_TOLERANCE_PIXELS:
        raise InputError(
            f"{what} size {w}x{h} does not have the aspect of its image ({big_w}x{big_h}); a {what} must cover the "
            f"image's field of view, at any resolution",
            path,
        )


# --------------------------------------------------------------------------------------------
# depth


EXR_DEPTH_CHANNELS = ("Z", "depth", "Y")
"""The channel a multi-channel EXR's depth is read from, the first one present (``Z`` is OpenEXR's
depth channel); an EXR with none of them needs one channel, or all its channels equal."""


def read_exr_channel(path: Path) -> np.ndarray:
    """An EXR depth image's values, [h, w] float32 (half floats widened), with the OpenEXR bindings:
    its only channel, else the first of :data:`EXR_DEPTH_CHANNELS` it has, else its channels when
    they are all equal (a grey image stored as R, G, B).

    Raises:
        InputError: unreadable, or several different channels none of which is named for depth.
    """
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = {name: np.asarray(channel.pixels) for name, channel in exr.channels().items()}
    except Exception as error:  # the bindings raise RuntimeError (and others) for files they cannot read
        raise InputError(f"cannot read the EXR depth ({type(error).__name__}: {error})", path) from None
    named = [channels[name] for name in EXR_DEPTH_CHANNELS if name in channels]
    values = list(channels.values())
    if named:
        raw = named[0]
    elif values and all(np.array_equal(values[0], v, equal_nan=True) for v in values[1:]):
        raw = values[0]
    else:
        raise InputError(
            f"depth EXR files need one channel or one named {', '.join(EXR_DEPTH_CHANNELS)}; this one has "
            f"{', '.join(sorted(channels)) or 'none'}",
            path,
        )
    return raw.astype(np.float32) if raw.dtype == np.float16 else raw


def read_depth_raw(path: Path) -> np.ndarray:
    """A depth file's raw values as stored, [h, w] (its own dtype: uint8, uint16, float32, ...).

    PNG (8 or 16 bit) and TIFF are read with OpenCV (``IMREAD_UNCHANGED``, so 16-bit values stay
    true); EXR with the OpenEXR bindings (:func:`read_exr_channel`; the OpenCV wheels are built
    without OpenEXR); ``.npy`` with ``np.load`` (no pickle).

    Raises:
        InputError: missing, unsupported suffix, unreadable, not real-valued or not single-channel.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in DEPTH_FILE_SUFFIXES:
        raise InputError(f"depth files must be {', '.join(DEPTH_FILE_SUFFIXES)}; got {suffix or 'no suffix'!r}", path)
    if not path.is_file():
        raise InputError("depth file not found", path)
    if suffix == ".npy":
        try:
            raw = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as error:
            raise InputError(f"cannot read the depth .npy ({error})", path) from None
        if not (np.issubdtype(raw.dtype, np.floating) or np.issubdtype(raw.dtype, np.integer)) or raw.dtype == bool:
            raise InputError(f"depth must be a real-valued array, got dtype {raw.dtype}", path)
    elif suffix == ".exr":
        raw = read_exr_channel(path)
    else:
        import cv2

        try:
            raw = cv2.imdecode(np.fromfile(path, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as error:
            message = str(error).strip().splitlines()[-1] if str(error).strip() else type(error).__name__
            raise InputError(f"cannot read the depth image (OpenCV: {message})", path) from None
        if raw is None:
            raise InputError("cannot read the depth image (unreadable or truncated file)", path)
    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[..., 0]
    if raw.ndim == 3:
        raise InputError(f"depth images must have one channel, got {raw.shape[2]}", path)
    if raw.ndim != 2 or raw.size == 0:
        raise InputError(f"depth must be an [h, w] array, got shape {list(raw.shape)}", path)
    return raw


def metric_depth_from_raw(raw: np.ndarray, scale: float) -> np.ndarray:
    """``raw * scale`` as float32 [h, w], with holes (raw <= 0, NaN, inf) set to NaN.

    Args:
        raw: [h, w] raw depth values (any real dtype).
        scale: world units per raw unit (``depth_unit_scale_factor``).
    """
    depth = np.asarray(raw, dtype=np.float64) * float(scale)
    depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return depth.astype(np.float32)


def resample_depth(
    depth: np.ndarray, width: int, height: int, tolerance: float = DEPTH_AGREEMENT_TOLERANCE
) -> np.ndarray:
    """Resample a depth image to [height, width] with the same field of view, never blending edges.

    Output pixel (col, row) has centre (col + 0.5, row + 0.5); in the input's pixel-centre index
    space (centres at integers) that is ``x = (col + 0.5) * w / width - 0.5`` (same for y), clamped
    to ``[0, w - 1]`` (border pixels take the edge samples). Its value is the bilinear blend of the
    four nearest samples when every sample with a weight above :data:`WEIGHT_EPS` is finite and
    their relative spread ``(max - min) / min`` is at most ``tolerance``; NaN otherwise. Works for
    up- and downsampling; an unchanged size returns the input (as float32).

    Args:
        depth: [h, w] depth, NaN = no measurement.
        width, height: output size.
        tolerance: largest relative spread of blended samples (see DEPTH_AGREEMENT_TOLERANCE).
    Returns:
        [height, width] float32.
    """
    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    if (h, w) == (height, width):
        return depth.astype(np.float32)
    x0, x1, fx = _bilinear_taps(width, w)
    out = np.empty((height, width), dtype=np.float32)
    for start in range(0, height, _ROW_CHUNK):
        rows = np.arange(start, min(start + _ROW_CHUNK, height))
        y0, y1, fy = _bilinear_taps(height, h, rows)
        fy = fy[:, None]
        values = [depth[y0[:, None], x0], depth[y0[:, None], x1], depth[y1[:, None], x0], depth[y1[:, None], x1]]
        weights = [(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx]  # each [r, width]
        used = [w > WEIGHT_EPS for w in weights]
        finite = [np.isfinite(v) for v in values]
        safe = [np.where(u & f, v, np.nan) for u, f, v in zip(used, finite, values)]
        # the taps summed one after another, as numpy sums a last axis of four: the same bits as
        # stacking them and reducing that axis, without the [r, width, 4] stacks
        every = (finite[0] | ~used[0]) & (finite[1] | ~used[1]) & (finite[2] | ~used[2]) & (finite[3] | ~used[3])
        with np.errstate(invalid="ignore", divide="ignore"):
            lo = np.fmin(np.fmin(np.fmin(safe[0], safe[1]), safe[2]), safe[3])
            hi = np.fmax(np.fmax(np.fmax(safe[0], safe[1]), safe[2]), safe[3])
            agree = every & ((hi - lo) <= tolerance * lo)
            kept = [np.where(u, w, 0.0) for u, w in zip(used, weights)]
            total = ((kept[0] + kept[1]) + kept[2]) + kept[3]
            part = [np.where(u & f, w * v, 0.0) for u, f, w, v in zip(used, finite, weights, values)]
            blended = (((part[0] + part[1]) + part[2]) + part[3]) / total
        out[rows] = np.where(agree, blended, np.nan)
    return out


def _bilinear_taps(n_out: int, n_in: int, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input taps i0, i1 [k] and fraction f [k] of output pixels ``index`` (all when None) along one axis."""
    index = np.arange(n_out) if index is None else index
    x = np.clip((index + 0.5) * (n_in / n_out) - 0.5, 0.0, n_in - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), max(n_in - 2, 0))
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, x - i0


def _direction_z(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float, distortion, model: str
) -> np.ndarray:
    """[height, width] z-component of each pixel centre's unit camera-frame ray direction; NaN where
    it is at most :data:`MIN_DIRECTION_Z` (a fisheye's rays at or past 90°: no z-depth there)."""
    dirs = camera_directions_from_pixels(pixel_grid(width, height), fx, fy, cx, cy, distortion, model)
    dz = dirs[:, 2].reshape(height, width)
    return np.where(dz > MIN_DIRECTION_Z, dz, np.nan)


def ray_depth_from_z_depth(
    z: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion: np.ndarray | None = None,
    model: str = PINHOLE,
) -> np.ndarray:
    """Z-depth (along the optical axis) -> distance along each pixel centre's unit ray.

    ``t = z / d_z``, ``d_z`` the z-component of the unit camera-frame direction through the pixel
    centre (:func:`scenelabel.geometry.rays.camera_directions_from_pixels`, so lens distortion is
    undone first). NaN stays NaN; pixels whose ray has ``d_z <= MIN_DIRECTION_Z`` become NaN.

    Args:
        z: [h, w] z-depth at the camera's own resolution (the intrinsics are for [h, w]).
        fx, fy, cx, cy: intrinsics in pixels; distortion: [4] the model's coefficients or None.
        model: the camera model (``"pinhole"`` or ``"fisheye"``, scenelabel.geometry.lens).
    Returns:
        [h, w] float32.
    """
    z = np.asarray(z, dtype=np.float64)
    dz = _direction_z(z.shape[1], z.shape[0], fx, fy, cx, cy, distortion, model)
    return (z / dz).astype(np.float32)


def z_depth_from_ray_depth(
    t: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion: np.ndarray | None = None,
    model: str = PINHOLE,
) -> np.ndarray:
    """Distance along each pixel centre's unit ray -> z-depth: ``z = t * d_z`` (inverse of
    :func:`ray_depth_from_z_depth`, same arguments). [h, w] -> [h, w] float32."""
    t = np.asarray(t, dtype=np.float64)
    dz = _direction_z(t.shape[1], t.shape[0], fx, fy, cx, cy, distortion, model)
    return (t * dz).astype(np.float32)


def read_sensor_depth(
    path: Path,
    scale: float,
    image_size: tuple[int, int],
    size: tuple[int, int],
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion: np.ndarray | None = None,
    model: str = PINHOLE,
) -> np.ndarray:
    """One depth file -> [h, w] float32 distance along the unit ray of each colour pixel, NaN = none.

    Args:
        path: the depth file (z-depth, :func:`read_depth_raw`).
        scale: ``depth_unit_scale_factor``.
        image_size: (W, H) of the colour image file (the depth must have its aspect).
        size: (w, h) of the colour image as trained on; fx, fy, cx, cy, distortion, model are for it.
    """
    raw = read_depth_raw(path)
    check_same_aspect((raw.shape[1], raw.shape[0]), image_size, path, "depth")
    z = resample_depth(metric_depth_from_raw(raw, scale), *size)
    return ray_depth_from_z_depth(z, fx, fy, cx, cy, distortion, model)


# --------------------------------------------------------------------------------------------
# masks


def read_mask(path: Path, image_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """A mask image -> [h, w] bool at ``size`` (True = use the pixel), nearest-resampled.

    Args:
        path: single-channel image (PNG, or JPEG: then prefer 0 / 255, as compression noise in a
            black area reads as "use"); 0 = ignore the pixel, non-zero = use it (nerfstudio's rule).
        image_size: (W, H) of the colour image file (the mask must have its aspect).
        size: (w, h) wanted (the colour image's training size).
    Raises:
        InputError: missing, unreadable, not single-channel, or another aspect than the image's.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("mask file not found", path)
    try:
        image = Image.open(path)
        image.load()
    except _PIL_ERRORS as error:
        raise InputError(f"cannot read the mask (unreadable or truncated file: {error})", path) from None
    if image.mode not in _MASK_MODES:
        raise InputError(
            f"masks must be single-channel images (0 = ignore the pixel, non-zero = use it); got mode {image.mode} "
            f"({len(image.getbands())} channels)",
            path,
        )
    check_same_aspect(image.size, image_size, path, "mask")
    mask = np.asarray(image) != 0
    return np.ascontiguousarray(resize_nearest(mask, *size))


# --------------------------------------------------------------------------------------------
# a whole scene


def read_sensor_inputs(
    files: Sequence[SensorFiles], image_sizes: Sequence[tuple[int, int]], cameras: Cameras, source: Path | None = None
) -> tuple[list[np.ndarray | None] | None, list[np.ndarray | None] | None, dict]:
    """Every view's sensor depth and mask, at its camera's (training) size.

    Args:
        files: per view, what :func:`frame_sensor_files` found.
        image_sizes: per view, (W, H) of the colour image file.
        cameras: the views' cameras at training resolution (their intrinsics align the depth).
        source: the file naming them (for the warning).
    Returns:
        sensor_depths (None when no view has a depth file), masks (None when no view has a mask),
        and info: ``sensor_depth_views``, ``masked_views``, ``depth_unit_scale_factors`` (the
        distinct factors of the views with depth).
    Warns:
        UserWarning: once, when float depth files read with the default (millimetre) factor come out
            implausibly small (metres stored as floats: set ``depth_unit_scale_factor: 1``); once,
            when depth files give no valid pixel at the training resolution.
    """
    depths: list[np.ndarray | None] = []
    masks: list[np.ndarray | None] = []
    small: list[str] = []
    empty: list[str] = []
    for i, (f, image_size) in enumerate(zip(files, image_sizes)):
        size = (int(cameras.width[i]), int(cameras.height[i]))
        depth = mask = None
        if f.depth is not None:
            depth = read_sensor_depth(
                f.depth, f.depth_scale, image_size, size,
                cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i],
                cameras.distortion[i], str(cameras.model[i]),
            )
            if not np.any(np.isfinite(depth)):
                empty.append(f.depth.name)
            elif not f.depth_scale_given and f.depth.suffix.lower() != ".png":
                if float(np.nanmedian(depth)) < _IMPLAUSIBLY_SMALL_DEPTH:
                    small.append(f.depth.name)
        if f.mask is not None:
            mask = read_mask(f.mask, image_size, size)
        depths.append(depth)
        masks.append(mask)
    if small:
        warnings.warn(
            f"{len(small)} float depth files (e.g. {small[0]}) were read as millimetres (nerfstudio's default "
            f"depth_unit_scale_factor {DEFAULT_DEPTH_UNIT_SCALE}) and give a median depth below "
            f"{_IMPLAUSIBLY_SMALL_DEPTH}; if they hold metres, add \"depth_unit_scale_factor\": 1.0 to "
            f"{source.name if source is not None else 'transforms.json'}",
            UserWarning,
            stacklevel=3,
        )
    if empty:
        warnings.warn(
            f"{len(empty)} depth files (e.g. {empty[0]}) give no valid depth at the training resolution: all holes, "
            f"or sparse depth (SfM points) lost in resampling, which blends only where every nearby sample is "
            f"valid (load at full resolution to keep isolated samples)",
            UserWarning,
            stacklevel=3,
        )
    n_depth = sum(d is not None for d in depths)
    n_mask = sum(m is not None for m in masks)
    info = {
        "sensor_depth_views": n_depth,
        "masked_views": n_mask,
        "depth_unit_scale_factors": sorted({f.depth_scale for f in files if f.depth is not None}),
    }
    return (depths if n_depth else None), (masks if n_mask else None), info
