"""Phone-like sensor depth for a synthetic scene folder: what a phone's LiDAR (Record3D, Polycam,
ARKit) would give, written as nerfstudio's ``depth_file_path`` images.

:func:`add_phone_depth` takes a folder written by :mod:`scenelabel.data.synthetic` (exact
ray-distance depth in ``depths/NNN.npy``, 0 = no surface) and adds, per frame::

    depth/NNN.png       16-bit PNG, z-depth (along the optical axis) in millimetres, 0 = hole

with ``frames[].depth_file_path`` and a top-level ``depth_unit_scale_factor: 0.001`` in
transforms.json, plus a ``phone_depth`` entry recording the settings (provenance). The scoring
ground truth (``depth_path``, ``depths/``) is left as it is.

What makes it phone-like, per depth pixel (``scale`` times coarser than the colour image, the same
field of view; the pixel covers the colour pixels whose centres fall in it):

- the value is the median true z-depth of those colour pixels, times ``1 + noise * N(0, 1)``;
- holes (0) where the pixel touches a depth edge: some colour pixel in it has no surface, or lies on
  a discontinuity (:func:`depth_discontinuities`: the true depth departs from a plane through its
  neighbours by more than ``edge_threshold``, relative), where the surface is dark (mean image luma
  below ``dark_threshold``: little light returns), beyond ``max_range``, and at random (``dropout``
  of the pixels). The edge rule is the same at any resolution: on a plane ``1 / z`` is affine in
  the pixel coordinates, so slanted surfaces are not edges, steps and silhouettes are.

Deterministic for a seed: one generator, drawn in frame order, the same draws whatever the holes.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from scenelabel.data.io.depth import z_depth_from_ray_depth
from scenelabel.errors import InputError

__all__ = [
    "PHONE_DEPTH_FOLDER",
    "PHONE_DEPTH_KEY",
    "PHONE_DEPTH_UNIT",
    "add_phone_depth",
    "depth_discontinuities",
    "phone_depth_size",
]

#: Folder of the depth images (as nerfstudio's Polycam conversion names it).
PHONE_DEPTH_FOLDER = "depth"

#: transforms.json key recording the settings.
PHONE_DEPTH_KEY = "phone_depth"

#: Metres per stored value: millimetres (nerfstudio's default depth_unit_scale_factor).
PHONE_DEPTH_UNIT = 1e-3

#: Largest value a 16-bit PNG stores; farther surfaces are holes.
_MAX_RAW = 65535

#: Rec. 601 luma weights of (R, G, B).
_LUMA = np.array([0.299, 0.587, 0.114])


def phone_depth_size(width: int, height: int, scale: int) -> tuple[int, int]:
    """(w, h) of the depth image of a ``width`` x ``height`` colour image: each side // scale, >= 1."""
    return max(1, width // scale), max(1, height // scale)


def depth_discontinuities(z: np.ndarray, threshold: float) -> np.ndarray:
    """[h, w] bool: pixels on a depth discontinuity of the z-depth image ``z`` (NaN = no surface).

    A pinhole sees a plane with ``1 / z`` affine in the pixel coordinates, so the second difference
    of ``1 / z`` along a row or a column vanishes on a plane. Pixel i is on a discontinuity when
    ``|1/z[i-1] - 2/z[i] + 1/z[i+1]| * z[i] > threshold`` along either axis, or when a neighbour
    along an axis has no surface (a silhouette). Pixels without a surface are not flagged; the
    image border's pixels are tested along the other axis only.
    """
    z = np.asarray(z, dtype=np.float64)
    inv = 1.0 / z
    edge = np.zeros(z.shape, bool)
    with np.errstate(invalid="ignore"):
        rel_x = np.abs(inv[:, :-2] - 2 * inv[:, 1:-1] + inv[:, 2:]) * z[:, 1:-1]
        rel_y = np.abs(inv[:-2, :] - 2 * inv[1:-1, :] + inv[2:, :]) * z[1:-1, :]
        edge[:, 1:-1] |= ~(rel_x <= threshold)  # NaN (a neighbour without surface) counts as an edge
        edge[1:-1, :] |= ~(rel_y <= threshold)
    return edge & np.isfinite(z)


def _lookup(frame: dict, data: dict, key: str, default=None):
    return frame.get(key, data.get(key, default))


def _block_index(n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``n_out`` coarse pixels, the fine pixels whose centres fall in it, padded.

    Fine pixel i belongs to coarse pixel ``floor((i + 0.5) * n_out / n_in)``. Returns
    index [n_out, k] (clipped) and valid [n_out, k] (the index is a member).
    """
    owner = np.minimum(((np.arange(n_in) + 0.5) * (n_out / n_in)).astype(np.int64), n_out - 1)
    start = np.searchsorted(owner, np.arange(n_out), side="left")
    stop = np.searchsorted(owner, np.arange(n_out), side="right")
    k = max(1, int((stop - start).max()))
    index = start[:, None] + np.arange(k)[None, :]
    valid = index < stop[:, None]
    return np.minimum(index, n_in - 1), valid


def _blocks(array: np.ndarray, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """[h_d, kr, w_d, kc] gather of a [H, W] float array over coarse blocks (NaN outside a block),
    and [h_d, kr, w_d, kc] bool: the entry is a member of its block."""
    (r_idx, r_ok), (c_idx, c_ok) = rows, cols
    out = array[r_idx[:, :, None, None], c_idx[None, None, :, :]]
    member = r_ok[:, :, None, None] & c_ok[None, None, :, :]
    return np.where(member, out, np.nan), member


def add_phone_depth(
    scene_dir: str | Path,
    scale: int = 4,
    noise: float = 0.015,
    seed: int = 0,
    edge_threshold: float = 0.05,
    dark_threshold: float = 0.08,
    dropout: float = 0.01,
    max_range: float | None = 5.0,
) -> Path:
    """Write phone-like z-depth PNGs (millimetres) for every frame of a synthetic scene folder.

    Args:
        scene_dir: a folder written by :mod:`scenelabel.data.synthetic` (or the suite): its
            transforms.json frames have ``depth_path`` (ray distance .npy, 0 = no surface).
        scale: the depth image is ``scale`` times coarser per side (:func:`phone_depth_size`).
        noise: relative standard deviation of the multiplicative Gaussian noise.
        seed: seed of the one generator (noise, dropouts).
        edge_threshold: relative departure from a plane that makes a discontinuity
            (:func:`depth_discontinuities`); a depth pixel holding one is a hole.
        dark_threshold: mean luma (0-1) of a depth pixel's colour pixels below which it is a hole.
        dropout: fraction of depth pixels dropped at random.
        max_range: z-depth (world units) beyond which a pixel is a hole; None = no limit.
    Returns:
        the folder.
    Raises:
        InputError: a frame without ``depth_path``, or an argument out of range.
    """
    if int(scale) != scale or scale < 1:
        raise InputError(f"scale must be an integer >= 1, got {scale!r}", field="scale")
    for name, value in (("noise", noise), ("edge_threshold", edge_threshold), ("dark_threshold", dark_threshold),
                        ("dropout", dropout)):
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a non-negative number, got {value!r}", field=name)
    root = Path(scene_dir)
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    rng = np.random.default_rng(seed)
    (root / PHONE_DEPTH_FOLDER).mkdir(exist_ok=True)
    sizes = set()
    for index, frame in enumerate(data["frames"]):
        if "depth_path" not in frame:
            raise InputError("frame has no depth_path (true depth) to make phone depth from", path,
                             field=f"$.frames[{index}]")
        truth = np.load(root / frame["depth_path"]).astype(np.float64)
        height, width = truth.shape
        truth[~(truth > 0)] = np.nan
        intr = [float(_lookup(frame, data, key)) for key in ("fl_x", "fl_y", "cx", "cy")]
        distortion = np.array([float(_lookup(frame, data, key, 0.0)) for key in ("k1", "k2", "p1", "p2")])
        z = z_depth_from_ray_depth(truth, *intr, distortion).astype(np.float64)
        image = np.asarray(Image.open(root / frame["file_path"]).convert("RGB"), dtype=np.float64) / 255.0
        luma = image @ _LUMA

        w_d, h_d = phone_depth_size(width, height, scale)
        sizes.add((w_d, h_d))
        rows, cols = _block_index(h_d, height), _block_index(w_d, width)
        z_blocks, member = _blocks(z, rows, cols)  # [h_d, kr, w_d, kc], NaN: no surface or not in the block
        surface = np.isfinite(z_blocks)
        full = np.all(surface | ~member, axis=(1, 3)) & np.any(surface, axis=(1, 3))  # every member hits
        on_edge = np.any(_blocks(depth_discontinuities(z, edge_threshold).astype(np.float64), rows, cols)[0] == 1,
                         axis=(1, 3))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # blocks without a surface: holes anyway
            z_median = np.nanmedian(z_blocks, axis=(1, 3))
        mean_luma = np.nanmean(_blocks(luma, rows, cols)[0], axis=(1, 3))

        gauss = rng.standard_normal((h_d, w_d))
        dropped = rng.random((h_d, w_d)) < dropout
        measured = z_median * (1.0 + noise * gauss)
        with np.errstate(invalid="ignore"):  # NaN where no surface: ~full makes those holes
            hole = ~full | on_edge | (mean_luma < dark_threshold) | dropped
            if max_range is not None:
                hole |= z_median > max_range
        raw = np.round(np.where(hole, 0.0, measured) / PHONE_DEPTH_UNIT)
        raw[~np.isfinite(raw) | (raw < 1) | (raw > _MAX_RAW)] = 0
        name = Path(frame["file_path"]).stem + ".png"
        Image.fromarray(raw.astype(np.uint16)).save(root / PHONE_DEPTH_FOLDER / name)
        frame["depth_file_path"] = f"{PHONE_DEPTH_FOLDER}/{name}"
    data["depth_unit_scale_factor"] = PHONE_DEPTH_UNIT
    data[PHONE_DEPTH_KEY] = {
        "scale": int(scale),
        "noise": float(noise),
        "seed": int(seed),
        "edge_threshold": float(edge_threshold),
        "dark_threshold": float(dark_threshold),
        "dropout": float(dropout),
        "max_range": None if max_range is None else float(max_range),
        "depth_sizes": sorted([list(s) for s in sizes]),
        "depth_kind": "z-depth along the optical axis, millimetres, 0 = hole",
    }
    path.write_text(json.dumps(data, indent=2))
    return root
