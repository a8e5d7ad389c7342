"""Semantic occupancy maps: the :class:`OccupancyMap` container, lattice helpers and zarr I/O.

Numpy only (no torch). Conventions (docs/conventions.md, "Occupancy grids"):

- Arrays are indexed ``[i, j, k]`` along world **x, y, z**.
- ``origin`` is the world position of the **centre** of voxel ``[0, 0, 0]``; voxel ``[i, j, k]``
  has centre ``origin + voxel_size * (i, j, k)`` and covers that centre ± ``voxel_size / 2``
  (half-open: ``[centre - voxel_size / 2, centre + voxel_size / 2)`` on each axis).
- ``label`` is int16: class id >= 0 (external ids of classes.json), :data:`FREE` = -1,
  :data:`UNKNOWN` = -2 (outside the modelled bounds, never evaluated).
- ``occupancy`` is float32 in [0, 1]: ``1 - exp(-sigma * occupancy_delta)`` where the field was
  evaluated, and 0 where the label is UNKNOWN.

The zarr layout is documented in docs/formats.md and its group attributes are described by
``scenelabel/schemas/occupancy_map.schema.json``.

Typical use by an exporter that evaluates a field in bounded memory::

    origin, shape = lattice(aabb_min, aabb_max, voxel_size)
    label = np.full(shape, UNKNOWN, np.int16); occupancy = np.zeros(shape, np.float32)
    for slices, centres in voxel_centers(origin, voxel_size, shape, chunk=64):
        occ, lab = evaluate(centres)                 # [n] each, n = centres.shape[0]
        block = tuple(s.stop - s.start for s in slices)
        occupancy[slices] = occ.reshape(block); label[slices] = lab.reshape(block)
    OccupancyMap(label, occupancy, voxel_size, origin, classes, occupancy_delta=delta).to_zarr(path)
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from ._version import __version__
from .errors import InputError

__all__ = [
    "FREE",
    "UNKNOWN",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "INDEX_ORDER",
    "DEFAULT_CHUNKS",
    "DEFAULT_OCCUPANCY_THRESHOLD",
    "OccupancyMap",
    "lattice",
    "iter_chunks",
    "voxel_centers",
    "index_from_world",
    "world_from_index",
    "validate_attributes",
    "load_schema",
]

FREE = -1
"""Label code of space modelled as empty."""
UNKNOWN = -2
"""Label code of space outside the modelled bounds (never evaluated)."""

FORMAT_NAME = "scenelabel.occupancy_map"
FORMAT_VERSION = 1
INDEX_ORDER = "ijk=xyz"
DIMENSION_NAMES = ("x", "y", "z")
DEFAULT_CHUNKS = (64, 64, 64)
DEFAULT_OCCUPANCY_THRESHOLD = 0.5
DEFAULT_UNITS = "input"
DEFAULT_SCALE_SOURCE = "input"
DEFAULT_FRAME_ID = "world"

LABEL_ARRAY = "label"
OCCUPANCY_ARRAY = "occupancy"
LABEL_DTYPE = np.dtype(np.int16)
OCCUPANCY_DTYPE = np.dtype(np.float32)
MAX_CLASS_ID = int(np.iinfo(np.int16).max)
SCHEMA_FILE = "occupancy_map.schema.json"

# Points farther than this many voxels from the origin get clamped before the int cast (no overflow).
_MAX_INDEX_MAGNITUDE = 2.0**52
# Relative slack so that a box of exactly n voxels (up to float noise) gets n voxels, not n + 1.
_LATTICE_REL_TOL = 1e-6
# Elements per pass when checking label values (bounds the temporary memory of the check).
_CHECK_BLOCK = 1 << 24
# Relative tolerance for origin_corner == origin - voxel_size / 2 on read.
_CORNER_RTOL = 1e-9


# --------------------------------------------------------------------------------------------
# Pure lattice helpers
# --------------------------------------------------------------------------------------------


def _vec3(value: Any, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"{name} must be 3 numbers [x, y, z], got shape {arr.shape}", field=name)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr.tolist()}", field=name)
    return arr


def _positive(value: Any, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}", field=name) from None
    if not (math.isfinite(out) and out > 0):
        raise InputError(f"{name} must be a finite number > 0, got {value!r}", field=name)
    return out


def _shape3(shape: Any, name: str = "shape") -> tuple[int, int, int]:
    try:
        out = tuple(int(n) for n in shape)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 integers, got {shape!r}", field=name) from None
    if len(out) != 3 or any(n < 1 for n in out):
        raise InputError(f"{name} must be 3 integers >= 1, got {shape!r}", field=name)
    return out  # type: ignore[return-value]


def lattice(
    bounds_min: Any,
    bounds_max: Any,
    voxel_size: float,
    max_voxels: int | None = None,
) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A voxel grid that covers the box ``[bounds_min, bounds_max]``, centred on it.

    Per axis the grid has ``n = max(1, ceil(extent / voxel_size))`` voxels (up to a 1e-6 relative
    slack against float noise), so the covered volume ``n * voxel_size`` contains the box and
    every voxel centre lies inside the box (on a degenerate axis: at the box's centre).

    Args:
        bounds_min, bounds_max: [3] world min and max corners of the box to cover.
        voxel_size: voxel edge, world units, > 0.
        max_voxels: raise InputError when the grid would have more voxels than this.
    Returns:
        origin: [3] float64 world centre of voxel [0, 0, 0].
        shape: (nx, ny, nz).
    """
    lo = _vec3(bounds_min, "bounds_min")
    hi = _vec3(bounds_max, "bounds_max")
    voxel_size = _positive(voxel_size, "voxel_size")
    if np.any(hi < lo):
        raise InputError(f"bounds_max {hi.tolist()} is below bounds_min {lo.tolist()}", field="bounds")
    counts = np.ceil((hi - lo) / voxel_size * (1.0 - _LATTICE_REL_TOL))
    counts = np.maximum(counts, 1.0)
    total = float(np.prod(counts))
    if max_voxels is not None and total > max_voxels:
        raise InputError(
            f"a {voxel_size:g} voxel grid over {(hi - lo).tolist()} needs {counts.astype(np.int64).tolist()} "
            f"= {total:.3g} voxels, more than the limit {max_voxels}; use a larger voxel size",
            field="voxel_size",
        )
    centre = (lo + hi) / 2.0
    origin = centre - (counts - 1.0) / 2.0 * voxel_size
    return origin, _shape3(counts.astype(np.int64))


def iter_chunks(shape: Any, chunk: int | tuple[int, int, int] = DEFAULT_CHUNKS) -> Iterator[tuple[slice, slice, slice]]:
    """Slices that tile a 3D grid, each block at most ``chunk`` voxels per axis, in C order.

    Every index of ``shape`` is in exactly one block; blocks at the upper ends are smaller.

    Args:
        shape: (nx, ny, nz).
        chunk: block edge (int) or per-axis block edges.
    Yields:
        (slice_i, slice_j, slice_k) with explicit start and stop.
    """
    shape = _shape3(shape)
    chunks = _shape3((chunk,) * 3 if np.isscalar(chunk) else chunk, "chunk")
    for i in range(0, shape[0], chunks[0]):
        for j in range(0, shape[1], chunks[1]):
            for k in range(0, shape[2], chunks[2]):
                yield (
                    slice(i, min(i + chunks[0], shape[0])),
                    slice(j, min(j + chunks[1], shape[1])),
                    slice(k, min(k + chunks[2], shape[2])),
                )


def world_from_index(ijk: Any, origin: Any, voxel_size: float) -> np.ndarray:
    """World centres of voxels: ``origin + voxel_size * ijk``.

    Args:
        ijk: [..., 3] voxel indices (any numeric dtype; fractional indices interpolate).
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
    Returns:
        [..., 3] float64 world points.
    """
    ijk = np.asarray(ijk, dtype=np.float64)
    if ijk.shape[-1:] != (3,):
        raise InputError(f"ijk must have shape [..., 3], got {ijk.shape}", field="ijk")
    return np.asarray(origin, np.float64) + float(voxel_size) * ijk


def index_from_world(
    xyz: Any, origin: Any, voxel_size: float, shape: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The voxel containing each world point: ``floor((xyz - origin) / voxel_size + 0.5)``.

    That is the nearest voxel centre; a point exactly on the face between two voxels goes to
    the higher index (voxels are half-open boxes).

    Args:
        xyz: [..., 3] world points.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        shape: (nx, ny, nz) of the grid.
    Returns:
        idx: [..., 3] int64 voxel indices, not clipped (they may lie outside the grid);
            -1 on every axis for non-finite points.
        inside: [...] bool, the point falls in a voxel of the grid.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.shape[-1:] != (3,):
        raise InputError(f"xyz must have shape [..., 3], got {xyz.shape}", field="xyz")
    shape_arr = np.asarray(_shape3(shape), dtype=np.int64)
    finite = np.all(np.isfinite(xyz), axis=-1)
    f = np.floor((xyz - np.asarray(origin, np.float64)) / float(voxel_size) + 0.5)
    f = np.where(finite[..., None], f, -1.0)
    idx = np.clip(f, -_MAX_INDEX_MAGNITUDE, _MAX_INDEX_MAGNITUDE).astype(np.int64)
    inside = finite & np.all((idx >= 0) & (idx < shape_arr), axis=-1)
    return idx, inside


def voxel_centers(
    origin: Any, voxel_size: float, shape: Any, chunk: int | tuple[int, int, int] = DEFAULT_CHUNKS
) -> Iterator[tuple[tuple[slice, slice, slice], np.ndarray]]:
    """World centres of a grid's voxels, block by block (bounded memory).

    Args:
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        shape: (nx, ny, nz).
        chunk: block edge (int) or per-axis block edges, as in :func:`iter_chunks`.
    Yields:
        slices: the block, (slice_i, slice_j, slice_k).
        centres: [bi * bj * bk, 3] float64 world centres in C order of the block, so that
            ``values.reshape(block_shape)`` fits ``grid[slices]``.
    """
    origin = _vec3(origin, "origin")
    voxel_size = _positive(voxel_size, "voxel_size")
    for slices in iter_chunks(shape, chunk):
        ii, jj, kk = np.meshgrid(*(np.arange(s.start, s.stop) for s in slices), indexing="ij")
        ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=-1)
        yield slices, world_from_index(ijk, origin, voxel_size)


# --------------------------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("scenelabel").joinpath("schemas", SCHEMA_FILE).read_text(encoding="utf-8")


def load_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the map's zarr group attributes (a fresh copy)."""
    return json.loads(_schema_text())


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema

    schema = load_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def validate_attributes(attrs: Mapping[str, Any], path: str | Path | None = None) -> None:
    """Check a map's group attributes against ``schemas/occupancy_map.schema.json``.

    Beyond the schema, class ids must be unique. Unknown extra attributes are allowed.

    Args:
        attrs: the zarr group attributes (a JSON-like dict).
        path: the map's path, used in the error message.
    Raises:
        InputError naming the path and the first offending attribute.
    """
    import jsonschema

    attrs = dict(attrs)
    error = jsonschema.exceptions.best_match(_validator().iter_errors(attrs))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path)
        if error.validator == "required":
            # error.message is "'voxel_size' is a required property"; name the attribute itself.
            missing = [k for k in error.validator_value if k not in error.instance]
            where = "/".join([where, missing[0]]) if where and missing else (missing[0] if missing else where)
            problem = f"missing required attribute {missing[0]!r}" if missing else error.message
        else:
            problem = f"invalid attribute: {error.message}"
        raise InputError(problem, path=path, field=where or None)
    ids = [c["id"] for c in attrs["classes"]]
    if len(set(ids)) != len(ids):
        raise InputError(f"class ids must be unique, got {ids}", path=path, field="classes")


# --------------------------------------------------------------------------------------------
# The map
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A semantic occupancy grid in the world frame (see the module docstring for conventions).

    Attributes:
        label: [nx, ny, nz] int16, indexed [i, j, k] along world x, y, z: class id >= 0,
            FREE (-1) or UNKNOWN (-2).
        occupancy: [nx, ny, nz] float32 in [0, 1] (no NaN); 0 wherever label is UNKNOWN.
        voxel_size: voxel edge, world units.
        origin: [3] float64 world centre of voxel [0, 0, 0].
        classes: external class id -> name, the classes that may appear in ``label``.
        occupancy_delta: δ (world units) in ``occupancy = 1 - exp(-σ δ)``.
        class_colors: external class id -> (r, g, b) 0-255, or None.
        frame_id: name of the world frame.
        occupancy_threshold: a voxel is occupied when ``occupancy >= occupancy_threshold``.
        scale_source: where the world scale comes from ("input": the input's poses).
        units: unit of lengths: "metre" when known metric, else "input" (the input's unit).
        version: scenelabel version that made the map.

    Arrays are converted (copy-free when already right) and checked on construction, and kept
    as read-only views: the instance and its arrays are frozen (copy an array to edit it).
    """

    label: np.ndarray
    occupancy: np.ndarray
    voxel_size: float
    origin: np.ndarray
    classes: dict[int, str]
    occupancy_delta: float
    class_colors: dict[int, tuple[int, int, int]] | None = None
    frame_id: str = DEFAULT_FRAME_ID
    occupancy_threshold: float = DEFAULT_OCCUPANCY_THRESHOLD
    scale_source: str = DEFAULT_SCALE_SOURCE
    units: str = DEFAULT_UNITS
    version: str = __version__

    def __post_init__(self) -> None:
        set_ = functools.partial(object.__setattr__, self)

        label = np.asarray(self.label)
        if label.ndim != 3:
            raise InputError(f"label must be a 3D array [nx, ny, nz], got shape {label.shape}", field="label")
        if not np.issubdtype(label.dtype, np.integer):
            raise InputError(f"label must hold integers (int16), got dtype {label.dtype}", field="label")
        occupancy = np.asarray(self.occupancy)
        if occupancy.shape != label.shape:
            raise InputError(
                f"occupancy shape {occupancy.shape} differs from label shape {label.shape}", field="occupancy"
            )
        if not (np.issubdtype(occupancy.dtype, np.floating) or np.issubdtype(occupancy.dtype, np.integer)):
            raise InputError(f"occupancy must hold floats (float32), got dtype {occupancy.dtype}", field="occupancy")

        classes = self._check_classes(self.classes)
        label = self._check_label(label, classes)
        occupancy = self._check_occupancy(occupancy.astype(OCCUPANCY_DTYPE, copy=False), label)
        set_("label", _read_only(label))
        set_("occupancy", _read_only(occupancy))
        set_("classes", classes)
        set_("class_colors", self._check_colors(self.class_colors, classes))
        set_("voxel_size", _positive(self.voxel_size, "voxel_size"))
        set_("origin", _vec3(self.origin, "origin"))
        set_("occupancy_delta", _positive(self.occupancy_delta, "occupancy_delta"))
        threshold = float(self.occupancy_threshold)
        if not 0.0 <= threshold <= 1.0:
            raise InputError(f"occupancy_threshold must be in [0, 1], got {threshold}", field="occupancy_threshold")
        set_("occupancy_threshold", threshold)
        for name in ("frame_id", "scale_source", "units", "version"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise InputError(f"{name} must be a non-empty string, got {value!r}", field=name)

    # ---- validation pieces ----

    @staticmethod
    def _check_classes(classes: Mapping[int, str]) -> dict[int, str]:
        if not isinstance(classes, Mapping):
            raise InputError(f"classes must be a dict id -> name, got {type(classes).__name__}", field="classes")
        out: dict[int, str] = {}
        for key, name in classes.items():
            if isinstance(key, (bool, np.bool_)) or not isinstance(key, (int, np.integer)):
                raise InputError(f"class id {key!r} is not an integer", field="classes")
            if not 0 <= int(key) <= MAX_CLASS_ID:
                raise InputError(f"class id {key} is outside [0, {MAX_CLASS_ID}]", field="classes")
            if not isinstance(name, str):
                raise InputError(f"class {key} name must be a string, got {name!r}", field="classes")
            out[int(key)] = name
        return dict(sorted(out.items()))

    @staticmethod
    def _check_label(label: np.ndarray, classes: dict[int, str]) -> np.ndarray:
        if label.size and (label.min() < UNKNOWN or label.max() > MAX_CLASS_ID):
            raise InputError(
                f"label values must be in [{UNKNOWN}, {MAX_CLASS_ID}], got [{label.min()}, {label.max()}]",
                field="label",
            )
        label = label.astype(LABEL_DTYPE, copy=False)
        # Which values occur, counted in blocks to bound the memory of the check.
        present = np.zeros(MAX_CLASS_ID + 1 - UNKNOWN, dtype=bool)
        flat = label.reshape(-1)
        for start in range(0, flat.size, _CHECK_BLOCK):
            counts = np.bincount(flat[start : start + _CHECK_BLOCK].astype(np.int64) - UNKNOWN)
            present[: counts.size] |= counts > 0
        ids = (np.flatnonzero(present) + UNKNOWN).tolist()
        stray = [i for i in ids if i >= 0 and i not in classes]
        if stray:
            raise InputError(f"label holds class ids {stray[:10]} that are not in classes", field="label")
        return label

    @staticmethod
    def _check_occupancy(occupancy: np.ndarray, label: np.ndarray) -> np.ndarray:
        if occupancy.size:
            if np.isnan(occupancy).any():
                raise InputError("occupancy holds NaN; store 0 where the field was not evaluated", field="occupancy")
            lo, hi = float(occupancy.min()), float(occupancy.max())
            if lo < 0.0 or hi > 1.0:
                raise InputError(f"occupancy must be in [0, 1], got [{lo}, {hi}]", field="occupancy")
            if np.any(occupancy[label == UNKNOWN] != 0):
                raise InputError("occupancy must be 0 where label is UNKNOWN (-2)", field="occupancy")
        return occupancy

    @staticmethod
    def _check_colors(
        colors: Mapping[int, Any] | None, classes: dict[int, str]
    ) -> dict[int, tuple[int, int, int]] | None:
        if colors is None or len(colors) == 0:
            return None
        out: dict[int, tuple[int, int, int]] = {}
        for key, rgb in colors.items():
            if int(key) not in classes:
                raise InputError(f"class_colors has id {key}, which is not in classes", field="class_colors")
            try:
                rgb_arr = np.asarray(rgb, dtype=np.float64)
            except (TypeError, ValueError):
                rgb_arr = np.full(1, np.nan)
            if (
                rgb_arr.shape != (3,)
                or not np.all(np.isfinite(rgb_arr))
                or np.any(rgb_arr != np.round(rgb_arr))
                or rgb_arr.min() < 0
                or rgb_arr.max() > 255
            ):
                raise InputError(f"colour of class {key} must be 3 integers in 0-255, got {rgb!r}", field="class_colors")
            out[int(key)] = tuple(int(c) for c in rgb_arr.tolist())  # type: ignore[assignment]
        return dict(sorted(out.items()))

    # ---- geometry ----

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz)."""
        return tuple(int(n) for n in self.label.shape)  # type: ignore[return-value]

    @property
    def origin_corner(self) -> np.ndarray:
        """[3] world min corner of voxel [0, 0, 0] (= origin - voxel_size / 2)."""
        return self.origin - self.voxel_size / 2.0

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """([3] min corner, [3] max corner) of the volume the grid covers, world units."""
        lo = self.origin_corner
        return lo, lo + self.voxel_size * np.asarray(self.shape, dtype=np.float64)

    @property
    def occupied(self) -> np.ndarray:
        """[nx, ny, nz] bool: occupancy >= occupancy_threshold."""
        return self.occupancy >= self.occupancy_threshold

    def index_from_world(self, xyz: Any) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index of world points; see :func:`index_from_world`.

        Args:
            xyz: [N, 3] (or [..., 3]) world points.
        Returns:
            idx [N, 3] int64 (unclipped), inside [N] bool.
        """
        return index_from_world(xyz, self.origin, self.voxel_size, self.shape)

    def world_from_index(self, ijk: Any) -> np.ndarray:
        """World centres [N, 3] float64 of voxel indices [N, 3]."""
        return world_from_index(ijk, self.origin, self.voxel_size)

    def label_at(self, xyz: Any) -> np.ndarray:
        """Label of the voxel containing each world point [N, 3] -> [N] int16; UNKNOWN outside."""
        idx, inside = self.index_from_world(xyz)
        out = np.full(inside.shape, UNKNOWN, dtype=LABEL_DTYPE)
        out[inside] = self.label[tuple(idx[inside].T)]
        return out

    def occupancy_at(self, xyz: Any) -> np.ndarray:
        """Occupancy of the voxel containing each world point [N, 3] -> [N] float32; 0 outside."""
        idx, inside = self.index_from_world(xyz)
        out = np.zeros(inside.shape, dtype=OCCUPANCY_DTYPE)
        out[inside] = self.occupancy[tuple(idx[inside].T)]
        return out

    # ---- comparison ----

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OccupancyMap):
            return NotImplemented
        return (
            np.array_equal(self.label, other.label)
            and np.array_equal(self.occupancy, other.occupancy)
            and self.attributes() == other.attributes()
        )

    __hash__ = None  # type: ignore[assignment]

    # ---- zarr ----

    def attributes(self) -> dict[str, Any]:
        """The zarr group attributes of this map (JSON-ready; see the schema)."""
        colors = self.class_colors or {}
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "scenelabel_version": self.version,
            "voxel_size": self.voxel_size,
            "origin": self.origin.tolist(),
            "origin_corner": self.origin_corner.tolist(),
            "index_order": INDEX_ORDER,
            "units": self.units,
            "frame_id": self.frame_id,
            "free_label": FREE,
            "unknown_label": UNKNOWN,
            "classes": [
                {"id": cid, "name": name, "color": list(colors[cid]) if cid in colors else None}
                for cid, name in self.classes.items()
            ],
            "occupancy_threshold": self.occupancy_threshold,
            "occupancy_delta": self.occupancy_delta,
            "scale_source": self.scale_source,
        }

    def to_zarr(
        self,
        path: str | Path,
        zarr_format: int = 3,
        chunks: tuple[int, int, int] = DEFAULT_CHUNKS,
        *,
        overwrite: bool = True,
    ) -> Path:
        """Write the map as a zarr group (directory store), atomically.

        The group is written into a hidden sibling ``.{name}.tmp-{pid}`` and renamed into place;
        an existing map at ``path`` is renamed aside first and removed once the new one is in
        place. The group attributes (among them ``format``) are written last, so a temp folder
        left by a killed process is never taken for a complete map.

        Args:
            path: the target directory (conventionally ``*.zarr``).
            zarr_format: 3 (default) or 2.
            chunks: chunk shape of both arrays (clipped to the grid shape).
            overwrite: replace an existing zarr group at ``path``; otherwise raise.
        Returns:
            the absolute path written.
        Raises:
            InputError: bad zarr_format / chunks, or ``path`` exists and is not a zarr group
                (it is never deleted then) or overwrite is False.
        """
        import zarr

        if zarr_format not in (2, 3):
            raise InputError(f"zarr_format must be 2 or 3, got {zarr_format!r}", field="zarr_format")
        chunks = _shape3(chunks, "chunks")
        chunks = tuple(min(c, n) for c, n in zip(chunks, self.shape))
        path = Path(path).expanduser().absolute()
        if path.exists() or path.is_symlink():
            if not overwrite:
                raise InputError("already exists (pass overwrite=True to replace it)", path=path)
            if not _is_replaceable(path):
                raise InputError("exists and is not a zarr group; refusing to replace it", path=path)
        if not path.parent.is_dir():
            raise InputError("the parent folder does not exist", path=path.parent)

        tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
        _remove(tmp)
        try:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=zarr_format)
            for name, data, fill, description in (
                (LABEL_ARRAY, self.label, UNKNOWN, "class id >= 0, FREE = -1, UNKNOWN = -2"),
                (OCCUPANCY_ARRAY, self.occupancy, 0.0, "occupancy = 1 - exp(-sigma * occupancy_delta), in [0, 1]"),
            ):
                array_attrs: dict[str, Any] = {"description": description}
                extra: dict[str, Any] = {}
                if zarr_format == 3:
                    extra["dimension_names"] = list(DIMENSION_NAMES)
                else:  # v2 has no dimension names: the xarray convention
                    array_attrs["_ARRAY_DIMENSIONS"] = list(DIMENSION_NAMES)
                array = group.create_array(
                    name, shape=self.shape, dtype=data.dtype, chunks=chunks, fill_value=fill,
                    attributes=array_attrs, **extra,
                )
                array[...] = data
            group.attrs.update(self.attributes())  # last: marks the group complete
        except BaseException:
            _remove(tmp)
            raise

        aside = path.parent / f".{path.name}.old-{os.getpid()}"
        if path.exists() or path.is_symlink():
            _remove(aside)
            os.replace(path, aside)
        try:
            os.replace(tmp, path)
        except BaseException:
            if aside.exists() and not path.exists():
                os.replace(aside, path)
            _remove(tmp)
            raise
        _remove(aside)
        return path

    @staticmethod
    def from_zarr(path: str | Path) -> "OccupancyMap":
        """Read a map written by :meth:`to_zarr` (zarr format 2 or 3).

        Raises:
            InputError naming the path and the attribute or array at fault: not a zarr group,
            not a scenelabel map, a newer format_version, an invalid or missing attribute, a
            missing or malformed array.
        """
        import zarr

        path = Path(path).expanduser()
        if not path.exists():
            raise InputError("no occupancy map here (path does not exist)", path=path)
        try:
            group = zarr.open_group(str(path), mode="r")
        except Exception as exc:  # zarr raises several types for "not a group"
            raise InputError(f"not a zarr group ({type(exc).__name__}: {exc})", path=path) from None
        attrs = dict(group.attrs.asdict())
        if "format" not in attrs:
            raise InputError(
                "missing attribute 'format': not a scenelabel occupancy map, or an incomplete write",
                path=path, field="format",
            )
        if attrs["format"] != FORMAT_NAME:
            raise InputError(f"format is {attrs['format']!r}, expected {FORMAT_NAME!r}", path=path, field="format")
        version = attrs.get("format_version")
        if isinstance(version, int) and version > FORMAT_VERSION:
            raise InputError(
                f"format_version {version} is newer than this scenelabel reads ({FORMAT_VERSION}); upgrade scenelabel",
                path=path, field="format_version",
            )
        validate_attributes(attrs, path=path)
        voxel_size = float(attrs["voxel_size"])
        origin = np.asarray(attrs["origin"], np.float64)
        if not np.allclose(
            np.asarray(attrs["origin_corner"], np.float64), origin - voxel_size / 2.0,
            rtol=_CORNER_RTOL, atol=_CORNER_RTOL * voxel_size,
        ):
            raise InputError(
                f"origin_corner {attrs['origin_corner']} is not origin - voxel_size / 2", path=path, field="origin_corner"
            )

        arrays = {}
        for name, dtype in ((LABEL_ARRAY, LABEL_DTYPE), (OCCUPANCY_ARRAY, OCCUPANCY_DTYPE)):
            try:
                node = group[name]
            except KeyError:
                raise InputError(f"missing array {name!r}", path=path, field=name) from None
            if not isinstance(node, zarr.Array):
                raise InputError(f"{name!r} is not an array", path=path, field=name)
            if node.dtype != dtype:
                raise InputError(f"array {name!r} has dtype {node.dtype}, expected {dtype}", path=path, field=name)
            arrays[name] = np.asarray(node[...])

        classes = {int(c["id"]): str(c["name"]) for c in attrs["classes"]}
        colors = {int(c["id"]): tuple(c["color"]) for c in attrs["classes"] if c.get("color") is not None}
        try:
            return OccupancyMap(
                label=arrays[LABEL_ARRAY],
                occupancy=arrays[OCCUPANCY_ARRAY],
                voxel_size=voxel_size,
                origin=origin,
                classes=classes,
                occupancy_delta=float(attrs["occupancy_delta"]),
                class_colors=colors or None,
                frame_id=attrs["frame_id"],
                occupancy_threshold=float(attrs["occupancy_threshold"]),
                scale_source=attrs["scale_source"],
                units=attrs["units"],
                version=attrs["scenelabel_version"],
            )
        except InputError as exc:
            raise InputError(exc.problem, path=path, field=exc.field) from None


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array`` (the caller's array itself stays writeable)."""
    view = array.view()
    view.flags.writeable = False
    return view


def _is_replaceable(path: Path) -> bool:
    """An existing path that to_zarr may replace: an empty folder or a zarr group folder."""
    if path.is_symlink() or not path.is_dir():
        return False
    return (path / "zarr.json").is_file() or (path / ".zgroup").is_file() or not any(path.iterdir())


def _remove(path: Path) -> None:
    """Remove a folder (or file) if present."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)
