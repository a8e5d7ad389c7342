"""The semantic occupancy map: the :class:`OccupancyMap` container, its zarr store, rays, pyramid.

Numpy only (no torch). Conventions (docs/conventions.md, "Occupancy grids"):

- Arrays are indexed ``[i, j, k]`` along world **x, y, z**.
- ``origin`` is the world position of the **centre** of voxel ``[0, 0, 0]``; voxel ``[i, j, k]``
  has centre ``origin + voxel_size * (i, j, k)`` and covers that centre ± ``voxel_size / 2``
  (half-open: ``[centre - voxel_size / 2, centre + voxel_size / 2)`` on each axis).
- ``label`` is int16: class id >= 0 (external ids of classes.json), :data:`FREE` = -1,
  :data:`UNKNOWN` = -2 (not observed: outside the modelled bounds, and with ``unknown_rule``
  "visibility" also seen by no training camera).
- ``occupancy`` is float32 in [0, 1]: ``1 - exp(-sigma * occupancy_delta)`` where the field was
  evaluated (raised to the threshold in voxels a training camera's surface lies in, with
  ``unknown_rule`` "visibility"), and 0 where the label is UNKNOWN.
- Optional ``probs``: uint8 [nx, ny, nz, C], the class distribution quantised (code / 255),
  channel c for the c-th class of ``classes`` (ascending id); 0 where UNKNOWN.
- Optional ``confidence``: uint8 [nx, ny, nz], ``1 - entropy / log C`` quantised (code / 255);
  0 where UNKNOWN.
- The ESDF (:meth:`OccupancyMap.esdf`) is derived from ``label``, not a field: :meth:`OccupancyMap.to_zarr`
  stores it (rule "occupied") as the ``esdf`` array of every level and :meth:`OccupancyMap.from_zarr`
  starts from that array when present.
- A pyramid level ``L`` halves the resolution ``L`` times (:meth:`OccupancyMap.downsample`,
  :func:`pool_labels`): occupied if any child is occupied, FREE only if every child is FREE,
  UNKNOWN otherwise (conservative for planners).

The zarr layout is documented in docs/formats.md and its group attributes are described by
``scenelabel/schemas/occupancy_map.schema.json``.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scenelabel._version import __version__
from scenelabel.errors import InputError
from scenelabel.geometry.boxes import ray_box_distances
from scenelabel.geometry.lattice import index_from_world, positive, vec3, world_from_grid_matrix, world_from_index
from scenelabel.maps.codes import (
    CONFIDENCE_ARRAY,
    DEFAULT_CHUNKS,
    DEFAULT_FRAME_ID,
    DEFAULT_SCALE_SOURCE,
    DEFAULT_UNITS,
    DEFAULT_UNKNOWN_RULE,
    DIMENSION_NAMES,
    ESDF_ARRAY,
    ESDF_DTYPE,
    ESDF_UNKNOWN,
    FORMAT_NAME,
    FORMAT_VERSION,
    FREE,
    FREE_WORD,
    INDEX_ORDER,
    LABEL_ARRAY,
    LABEL_DTYPE,
    LEVELS_GROUP,
    OCCUPANCY_ARRAY,
    OCCUPANCY_DTYPE,
    OCCUPANCY_ENCODING,
    OCCUPIED_THRESHOLD,
    PROBS_ARRAY,
    PROBS_DIMENSION_NAMES,
    PYRAMID_FACTOR,
    QUANTISATION_STEPS,
    QUANTISED_DTYPE,
    UNKNOWN,
    UNKNOWN_RULES,
    UNKNOWN_WORD,
)
from scenelabel.maps.esdf import distance_at, distance_gradient_at, signed_distance
from scenelabel.maps.pyramid import check_factor, check_levels, pool_block
from scenelabel.maps.raycast import MapRayQuery, first_voxel_hits, leap_lengths, ray_limits
from scenelabel.maps.validation import (
    check_classes,
    check_colors,
    check_label,
    check_occupancy,
    check_quantised,
    read_only,
)
from scenelabel.maps.zarr_io import (
    array_chunks,
    check_target,
    checked_attributes,
    esdf_array_attributes,
    esdf_group_attributes,
    level_group,
    root_attributes,
    staged_group,
    stored_esdf,
)

__all__ = ["OccupancyMap"]


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
        probs: [nx, ny, nz, C] uint8 or None: class probabilities quantised (code / 255),
            channel c for the c-th id of ``classes`` (ascending); 0 wherever label is UNKNOWN.
            Floats in [0, 1] are accepted and quantised.
        confidence: [nx, ny, nz] uint8 or None: ``1 - entropy / log C`` of the class
            distribution, quantised (code / 255); 0 wherever label is UNKNOWN. Floats in [0, 1]
            are accepted and quantised.
        unknown_rule: what UNKNOWN means: "bounds" (outside the modelled bounds) or
            "visibility" (also: observed by no training camera).

    Arrays are converted (copy-free when already right) and checked on construction, and kept
    as read-only views: the instance and its arrays are frozen (copy an array to edit it). The
    ESDF (:meth:`esdf`) is derived from ``label``, not a field, and takes no part in ``==``.
    """

    label: np.ndarray
    occupancy: np.ndarray
    voxel_size: float
    origin: np.ndarray
    classes: dict[int, str]
    occupancy_delta: float
    class_colors: dict[int, tuple[int, int, int]] | None = None
    frame_id: str = DEFAULT_FRAME_ID
    occupancy_threshold: float = OCCUPIED_THRESHOLD
    scale_source: str = DEFAULT_SCALE_SOURCE
    units: str = DEFAULT_UNITS
    version: str = __version__
    probs: np.ndarray | None = None
    confidence: np.ndarray | None = None
    unknown_rule: str = DEFAULT_UNKNOWN_RULE

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

        classes = check_classes(self.classes)
        label = check_label(label, classes)
        occupancy = check_occupancy(occupancy.astype(OCCUPANCY_DTYPE, copy=False), label)
        set_("label", read_only(label))
        set_("occupancy", read_only(occupancy))
        set_("probs", check_quantised(self.probs, label, label.shape + (len(classes),), PROBS_ARRAY))
        set_("confidence", check_quantised(self.confidence, label, label.shape, CONFIDENCE_ARRAY))
        if self.unknown_rule not in UNKNOWN_RULES:
            raise InputError(f"unknown_rule must be one of {list(UNKNOWN_RULES)}, got {self.unknown_rule!r}", field="unknown_rule")
        set_("classes", classes)
        set_("class_colors", check_colors(self.class_colors, classes))
        set_("voxel_size", positive(self.voxel_size, "voxel_size"))
        set_("origin", vec3(self.origin, "origin"))
        set_("occupancy_delta", positive(self.occupancy_delta, "occupancy_delta"))
        threshold = float(self.occupancy_threshold)
        if not 0.0 <= threshold <= 1.0:
            raise InputError(f"occupancy_threshold must be in [0, 1], got {threshold}", field="occupancy_threshold")
        set_("occupancy_threshold", threshold)
        for name in ("frame_id", "scale_source", "units", "version"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise InputError(f"{name} must be a non-empty string, got {value!r}", field=name)

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
    def class_ids(self) -> np.ndarray:
        """[C] int64 class ids, ascending: the channel order of ``probs``."""
        return np.fromiter(self.classes, dtype=np.int64, count=len(self.classes))

    @property
    def T_world_from_grid(self) -> np.ndarray:
        """[4, 4] affine from voxel index to world centre: ``[x, y, z, 1] = T @ [i, j, k, 1]``."""
        return world_from_grid_matrix(self.origin, self.voxel_size)

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

    def esdf(self, unknown: str = "occupied") -> np.ndarray:
        """The map's Euclidean signed distance field [nx, ny, nz] float32, world units: distance of
        each voxel centre to the nearest obstacle face, negative inside obstacles; UNKNOWN voxels and
        the map's outside count as obstacles (``unknown="occupied"``) or UNKNOWN as free space
        (``"free"``). :mod:`scenelabel.maps.esdf` has the rule; computed once per rule (read-only), or
        for a map read by :meth:`from_zarr` read from the store's ``esdf`` array (rule "occupied") on
        the first call (InputError when it does not match ``label``)."""
        cache = self.__dict__.setdefault("_esdf", {})
        if unknown not in cache:
            stored = self.__dict__.get("_stored_esdf")
            values = stored.read(self.label) if stored is not None and stored.rule == unknown else None
            if values is None:
                values = read_only(signed_distance(self.label, self.voxel_size, unknown))
            cache[unknown] = values
        return cache[unknown]

    def distance(self, xyz: Any, unknown: str = "occupied") -> np.ndarray:
        """ESDF at world points [N, 3] -> [N] float64, trilinear between voxel centres (:meth:`esdf`)."""
        return distance_at(self.esdf(unknown), self.origin, self.voxel_size, xyz)

    def distance_gradient(self, xyz: Any, unknown: str = "occupied") -> np.ndarray:
        """Gradient of :meth:`distance` at world points [N, 3] -> [N, 3] float64 (the direction
        away from the nearest obstacle, for gradient-based planners)."""
        return distance_gradient_at(self.esdf(unknown), self.origin, self.voxel_size, xyz)

    def cast_rays(self, origins: Any, directions: Any, near: Any = None, far: Any = None) -> MapRayQuery:
        """What each ray meets first in the map, and how far: numpy only, no field needed.

        A ray stops at the first voxel it enters (exact voxel traversal,
        :func:`first_voxel_hits`) whose label is a class (occupied) or UNKNOWN (unobserved
        space is not known to be free). The depth is where the ray enters that voxel, so it is exact
        for the map and within a voxel of the surface the map was made from.

        Args:
            origins: [N, 3] world ray origins.
            directions: [N, 3] world directions (need not be unit length; no zero vector).
            near, far: optional [N] or scalar limits, distances along the unit direction.
        Returns:
            MapRayQuery (depth, label, index).
        """
        origins, directions = (np.asarray(x, dtype=np.float64) for x in (origins, directions))
        if origins.ndim != 2 or origins.shape[-1] != 3 or directions.shape != origins.shape:
            raise InputError(
                f"origins and directions must both be [N, 3], got {origins.shape} and {directions.shape}",
                field="directions",
            )
        norms = np.linalg.norm(directions, axis=-1, keepdims=True)
        if not np.all(np.isfinite(origins)) or not np.all(np.isfinite(norms) & (norms > 0)):
            raise InputError("origins must be finite and directions finite and non-zero", field="directions")
        directions = directions / norms
        stop, leaps = self._stop_leaps()
        depth, index = first_voxel_hits(origins, directions, stop, self.origin, self.voxel_size, near, far, leaps=leaps)
        hit = index[:, 0] >= 0
        miss = ~hit  # FREE where the ray crossed the map within [near, far], UNKNOWN where it never entered it
        lo, hi = self.bounds
        t_enter, t_exit = ray_box_distances(origins[miss], directions[miss], lo, hi)
        near_n, far_n = ray_limits(len(origins), near, far)
        label = np.empty(len(origins), LABEL_DTYPE)
        label[miss] = np.where(np.minimum(t_exit, far_n[miss]) > np.maximum(t_enter, near_n[miss]), FREE, UNKNOWN)
        label[hit] = self.label[tuple(index[hit].T)]
        return MapRayQuery(depth=depth, label=label, index=index)

    def _stop_leaps(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The voxels that stop :meth:`cast_rays`' rays (label != FREE, [nx, ny, nz] bool) and their
        :func:`leap_lengths` (None when there are none), computed once per map."""
        cache = self.__dict__.get("_ray_stops")
        if cache is None:
            stop = self.label != FREE
            cache = self.__dict__["_ray_stops"] = (stop, leap_lengths(stop) if stop.any() else None)
        return cache

    # ---- pyramid ----

    def downsample(self, factor: int = PYRAMID_FACTOR) -> OccupancyMap:
        """The map at 1 / ``factor`` the resolution: each coarse voxel pools ``factor``³ children.

        Rules (:func:`pool_labels`, :func:`pool_probs`, :func:`pool_occupancy`): occupied if any
        child is occupied, with the argmax class of the occupied children's summed probabilities;
        FREE only if every child is FREE; UNKNOWN otherwise (a FREE / UNKNOWN mix is UNKNOWN).
        Occupancy is the children's max (same ``occupancy_delta``); confidence is recomputed from
        the pooled probabilities (None when the map has no probs). The coarse grid starts at the
        same min corner and has ``ceil(n / factor)`` voxels per axis; children beyond the fine
        grid count as UNKNOWN.

        Args:
            factor: children per axis, an integer >= 1 (1 returns this map).
        Returns:
            a new OccupancyMap with ``voxel_size * factor``.
        """
        factor = check_factor(factor)
        if factor == 1:
            return self
        label, occupancy, probs, confidence = pool_block(self.label, self.occupancy, self.probs, factor, self.class_ids)
        voxel_size = self.voxel_size * factor
        return dataclasses.replace(
            self,
            label=label,
            occupancy=occupancy,
            voxel_size=voxel_size,
            origin=self.origin_corner + voxel_size / 2.0,
            probs=probs,
            confidence=confidence,
        )

    def pyramid(self, levels: int | None = None) -> list[OccupancyMap]:
        """Levels 0 (this map), 1, ..., ``levels - 1``; level L is ``downsample(2 ** L)``.

        Args:
            levels: number of levels >= 1; None: :func:`default_levels` of the shape.
        """
        return [self.downsample(PYRAMID_FACTOR**level) for level in range(check_levels(levels, self.shape))]

    # ---- comparison ----

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OccupancyMap):
            return NotImplemented
        return (
            np.array_equal(self.label, other.label)
            and np.array_equal(self.occupancy, other.occupancy)
            and _same_optional(self.probs, other.probs)
            and _same_optional(self.confidence, other.confidence)
            and self.attributes() == other.attributes()
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        lo, hi = self.bounds
        occupied, unknown = int((self.label >= 0).sum()), int((self.label == UNKNOWN).sum())
        return (
            f"OccupancyMap(shape={self.shape}, voxel_size={self.voxel_size:g}, bounds={np.round(lo, 3).tolist()} to "
            f"{np.round(hi, 3).tolist()} {self.units}, classes={len(self.classes)}, occupied={occupied}, "
            f"unknown={unknown} ({self.unknown_rule}), probs={self.probs is not None})"
        )

    # ---- zarr ----

    def attributes(self) -> dict[str, Any]:
        """The map's own zarr group attributes (JSON-ready; see the schema).

        :meth:`to_zarr` adds the layout ones: ``level`` and ``n_levels`` on every level's group,
        and the OME-NGFF metadata (:func:`ngff_multiscales`) on the root.
        """
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
            "occupancy_encoding": OCCUPANCY_ENCODING,
            "unknown_rule": self.unknown_rule,
            "T_world_from_grid": self.T_world_from_grid.tolist(),
        }

    def to_zarr(
        self,
        path: str | Path,
        zarr_format: int = 3,
        chunks: tuple[int, int, int] = DEFAULT_CHUNKS,
        *,
        overwrite: bool = True,
        levels: int | None = None,
        esdf: bool = True,
    ) -> Path:
        """Write the map and its pyramid as a zarr group (directory store), atomically.

        Layout (docs/formats.md): level 0's arrays at the root (``label``, ``occupancy``,
        ``probs`` / ``confidence`` when the map has them, and ``esdf``: each level's own
        :meth:`esdf` with the rule "occupied", float32), level L >= 1 in the sub-group
        ``levels/L`` with the same arrays and its own map attributes (:meth:`pyramid`); the
        root also carries OME-NGFF multiscales metadata (``multiscales``, NGFF 0.4, in zarr
        format 2; ``ome``, NGFF 0.5, in zarr format 3).

        The group is written into a hidden sibling ``.{name}.tmp-{pid}`` and renamed into place;
        an existing map at ``path`` is renamed aside first and removed once the new one is in
        place. The root group attributes (among them ``format``) are written last, so a temp
        folder left by a killed process is never taken for a complete map.

        Args:
            path: the target directory (conventionally ``*.zarr``).
            zarr_format: 3 (default) or 2.
            chunks: spatial chunk shape of every array (clipped to each level's shape; ``probs``
                keeps all classes in one chunk).
            overwrite: replace an existing zarr group at ``path``; otherwise raise.
            levels: pyramid levels to write, level 0 included; None: :func:`default_levels`.
            esdf: also write the ``esdf`` arrays (and the ``esdf`` group attributes).
        Returns:
            the absolute path written.
        Raises:
            InputError: bad zarr_format / chunks / levels, or ``path`` exists and is not a zarr
                group (it is never deleted then) or overwrite is False.
        """
        import zarr

        zarr_format, chunks, path = check_target(path, zarr_format, chunks, overwrite)
        pyramid = self.pyramid(levels)
        with staged_group(path) as tmp:
            root = zarr.open_group(str(tmp), mode="w", zarr_format=zarr_format)
            for level, level_map in enumerate(pyramid):
                group = root if level == 0 else level_group(root, level)
                level_map.write_arrays(group, zarr_format, chunks, esdf=esdf)
                if level:
                    group.attrs.update(level_map.group_attributes(level, len(pyramid), esdf=esdf))
            # last: marks the map complete
            root.attrs.update(root_attributes(pyramid, zarr_format, esdf=esdf))
        return path

    def group_attributes(self, level: int, n_levels: int, esdf: bool = True) -> dict[str, Any]:
        """Attributes of the group holding this map as pyramid level ``level`` of ``n_levels``
        (with the ``esdf`` attribute when the group holds the ``esdf`` array)."""
        extra = esdf_group_attributes(self.units) if esdf else {}
        return {**self.attributes(), "level": level, "n_levels": n_levels, **extra}

    def write_arrays(self, group: Any, zarr_format: int, chunks: tuple[int, int, int], esdf: bool = True) -> None:
        """Write this map's arrays into a zarr group (no group attributes); ``esdf``: :meth:`esdf` too."""
        for name, array in self.create_arrays(group, zarr_format, chunks, self.shape, esdf=esdf).items():
            array[...] = self.esdf(ESDF_UNKNOWN) if name == ESDF_ARRAY else getattr(self, name)

    def create_arrays(
        self, group: Any, zarr_format: int, chunks: tuple[int, int, int], shape: tuple[int, int, int], esdf: bool = True
    ) -> dict[str, Any]:
        """Create (unfilled) the arrays of a map of this one's classes, with ``probs`` /
        ``confidence`` when this map has them, ``esdf`` when asked, and ``shape``, in a zarr group.

        Returns:
            name -> zarr array; spatial chunks ``chunks`` clipped to ``shape`` (:func:`array_chunks`).
        """
        chunks = array_chunks(chunks, shape)
        n_classes = len(self.classes)
        scaled = {"scale_factor": 1.0 / QUANTISATION_STEPS, "add_offset": 0.0}  # CF: value = code * scale_factor
        names = [UNKNOWN_WORD, FREE_WORD] + [_flag_word(cid, name) for cid, name in self.classes.items()]
        arrays = [
            (LABEL_ARRAY, LABEL_DTYPE, shape, UNKNOWN, {
                "description": "class id >= 0, FREE = -1, UNKNOWN = -2",
                "flag_values": [UNKNOWN, FREE, *self.classes],  # CF: flag_values / flag_meanings
                "flag_meanings": " ".join(names),
            }),
            (OCCUPANCY_ARRAY, OCCUPANCY_DTYPE, shape, 0.0, {
                "description": "occupancy = 1 - exp(-sigma * occupancy_delta), in [0, 1]",
            }),
        ]
        if self.probs is not None:
            arrays.append((PROBS_ARRAY, QUANTISED_DTYPE, (*shape, n_classes), 0, {
                "description": "class probabilities quantised: p = code / 255; channel c is class_ids[c]; 0 where UNKNOWN",
                "class_ids": self.class_ids.tolist(),
                **scaled,
            }))
        if self.confidence is not None:
            arrays.append((CONFIDENCE_ARRAY, QUANTISED_DTYPE, shape, 0, {
                "description": "1 - entropy / log(C) of the class distribution, quantised: code / 255; 0 where UNKNOWN",
                **scaled,
            }))
        if esdf:
            arrays.append((ESDF_ARRAY, ESDF_DTYPE, shape, 0.0, esdf_array_attributes(self.units)))
        created = {}
        for name, dtype, array_shape, fill, array_attrs in arrays:
            dims = PROBS_DIMENSION_NAMES if len(array_shape) == 4 else DIMENSION_NAMES
            extra: dict[str, Any] = {}
            if zarr_format == 3:
                extra["dimension_names"] = list(dims)
            else:  # v2 has no dimension names: the xarray convention
                array_attrs["_ARRAY_DIMENSIONS"] = list(dims)
            created[name] = group.create_array(
                name, shape=array_shape, dtype=dtype, chunks=chunks + tuple(array_shape[3:]), fill_value=fill,
                attributes=array_attrs, **extra,
            )
        return created

    @staticmethod
    def from_zarr(path: str | Path, level: int = 0) -> "OccupancyMap":
        """Read a map written by :meth:`to_zarr` (zarr format 2 or 3; map format 1 or 2).

        Args:
            path: the map's root group (a ``levels/L`` sub-group also reads, as a map of its own).
            level: pyramid level to read (0: full resolution; see the root's ``n_levels``).
        Returns:
            the map; when the group has an ``esdf`` array, :meth:`esdf` reads it on its first call
            for its rule (checked against ``label`` then: InputError naming the path when it does
            not match) instead of computing it.
        Raises:
            InputError naming the path and the attribute or array at fault: not a zarr group,
            not a scenelabel map, a newer format_version, an invalid or missing attribute, a
            missing or malformed array, a level the map does not have.
        """
        path = Path(path).expanduser()
        if not path.exists():
            raise InputError("no occupancy map here (path does not exist)", path=path)
        import zarr

        try:
            group = zarr.open_group(str(path), mode="r")
        except Exception as exc:  # zarr raises several types for "not a group"
            raise InputError(f"not a zarr group ({type(exc).__name__}: {exc})", path=path) from None
        attrs = checked_attributes(group, path)
        if level != 0:
            n_levels = int(attrs.get("n_levels", 1))
            if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, np.integer)) or not 0 < level < n_levels:
                raise InputError(
                    f"no level {level!r} in this map: it has levels 0 to {n_levels - 1}", path=path, field="level"
                )
            try:
                group = group[f"{LEVELS_GROUP}/{int(level)}"]
            except KeyError:
                raise InputError(f"missing group '{LEVELS_GROUP}/{level}'", path=path, field="level") from None
            path = path / LEVELS_GROUP / str(int(level))
            attrs = checked_attributes(group, path)

        arrays = {}
        for name, dtype, required in (
            (LABEL_ARRAY, LABEL_DTYPE, True),
            (OCCUPANCY_ARRAY, OCCUPANCY_DTYPE, True),
            (PROBS_ARRAY, QUANTISED_DTYPE, False),
            (CONFIDENCE_ARRAY, QUANTISED_DTYPE, False),
            (ESDF_ARRAY, ESDF_DTYPE, False),
        ):
            try:
                node = group[name]
            except KeyError:
                if required:
                    raise InputError(f"missing array {name!r}", path=path, field=name) from None
                continue
            if not isinstance(node, zarr.Array):
                raise InputError(f"{name!r} is not an array", path=path, field=name)
            if node.dtype != dtype:
                raise InputError(f"array {name!r} has dtype {node.dtype}, expected {dtype}", path=path, field=name)
            if name != ESDF_ARRAY:  # the ESDF is read on its first use (esdf())
                arrays[name] = np.asarray(node[...])
            elif (stored := stored_esdf(group, path)) is not None:
                arrays[name] = stored

        classes = {int(c["id"]): str(c["name"]) for c in attrs["classes"]}
        colors = {int(c["id"]): tuple(c["color"]) for c in attrs["classes"] if c.get("color") is not None}
        try:
            occ_map = OccupancyMap(
                label=arrays[LABEL_ARRAY],
                occupancy=arrays[OCCUPANCY_ARRAY],
                voxel_size=float(attrs["voxel_size"]),
                origin=np.asarray(attrs["origin"], np.float64),
                classes=classes,
                occupancy_delta=float(attrs["occupancy_delta"]),
                class_colors=colors or None,
                frame_id=attrs["frame_id"],
                occupancy_threshold=float(attrs["occupancy_threshold"]),
                scale_source=attrs["scale_source"],
                units=attrs["units"],
                version=attrs["scenelabel_version"],
                probs=arrays.get(PROBS_ARRAY),
                confidence=arrays.get(CONFIDENCE_ARRAY),
                unknown_rule=attrs.get("unknown_rule", DEFAULT_UNKNOWN_RULE),  # version 1: bounds
            )
            if ESDF_ARRAY in arrays:  # maps written before it have none: esdf() computes it then
                occ_map.__dict__["_stored_esdf"] = arrays[ESDF_ARRAY]
        except InputError as exc:
            raise InputError(exc.problem, path=path, field=exc.field) from None
        return occ_map


def _flag_word(class_id: int, name: str) -> str:
    """A class name as one CF flag_meanings word (whitespace -> '_'; empty -> class_ID)."""
    word = "_".join(name.split())
    return word or f"class_{class_id}"


def _same_optional(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or equal arrays."""
    if a is None or b is None:
        return a is None and b is None
    return np.array_equal(a, b)
