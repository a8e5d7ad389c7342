"""Zarr pieces of an occupancy map store (docs/formats.md): chunk shapes, the pyramid's level groups,
the root attributes and their OME-NGFF multiscales metadata, checks of a write's target, the
atomic staged write, a group's attributes checked on read, and the stored ESDF (its attributes,
its write from a group's ``label`` array, its check on read).

Used by :meth:`OccupancyMap.to_zarr` / :meth:`OccupancyMap.from_zarr` and by
:func:`scenelabel.query.map_writer.write_occupancy_map`, which write the same store. Maps are
passed in (``list[Any]``: :class:`OccupancyMap` levels, level 0 first); only their metadata is read.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.lattice import iter_chunks, shape3, world_from_grid_matrix
from scenelabel.maps.codes import (
    CONFIDENCE_ARRAY,
    DIMENSION_NAMES,
    ESDF_ARRAY,
    ESDF_UNKNOWN,
    FORMAT_NAME,
    FORMAT_VERSION,
    LABEL_ARRAY,
    LEVELS_GROUP,
    NGFF_METRE_UNITS,
    NGFF_VERSION_V2,
    NGFF_VERSION_V3,
    OCCUPANCY_ARRAY,
)
from scenelabel.maps.esdf import UNKNOWN_AS, signed_distance_blocks
from scenelabel.maps.pyramid import LABEL_POOLING_RULE
from scenelabel.maps.schema import validate_attributes
from scenelabel.maps.validation import check_esdf

__all__ = [
    "array_chunks",
    "level_group",
    "root_attributes",
    "check_target",
    "staged_group",
    "checked_attributes",
    "ngff_multiscales",
    "esdf_group_attributes",
    "esdf_array_attributes",
    "write_esdf",
    "StoredEsdf",
    "stored_esdf",
]

_ESDF_LEVEL_RULE = "recomputed from the level's own labels (not pooled): obstacles are classes, UNKNOWN and the outside"

# Relative tolerance for origin_corner == origin - voxel_size / 2 on read.
_CORNER_RTOL = 1e-9


def array_chunks(chunks: Any, shape: Any) -> tuple[int, int, int]:
    """The spatial chunk shape :meth:`OccupancyMap.to_zarr` gives a level of ``shape``: ``chunks``
    clipped to it per axis."""
    return tuple(min(c, n) for c, n in zip(shape3(chunks, "chunks"), shape3(shape)))  # type: ignore[return-value]


def level_group(root: Any, level: int) -> Any:
    """The group of pyramid level ``level`` >= 1 (``levels/L``), created when missing."""
    return root.require_group(LEVELS_GROUP).require_group(str(level))


def root_attributes(pyramid: list[Any], zarr_format: int, esdf: bool = True) -> dict[str, Any]:
    """The root group's attributes of a written pyramid: level 0's map attributes, ``level``,
    ``n_levels``, ``esdf`` (when the levels have the array) and the OME-NGFF metadata. (Only
    metadata of the levels is used, never their arrays.)"""
    return {
        **pyramid[0].group_attributes(0, len(pyramid), esdf=esdf),
        **ngff_multiscales(pyramid, zarr_format, esdf=esdf),
    }


def esdf_group_attributes(units: str) -> dict[str, Any]:
    """The group attribute ``esdf`` of a level whose group holds the ``esdf`` array: the rule it was
    computed with (:data:`ESDF_UNKNOWN`) and the unit of its values (the map's ``units``)."""
    return {ESDF_ARRAY: {"unknown": ESDF_UNKNOWN, "units": units}}


def esdf_array_attributes(units: str) -> dict[str, Any]:
    """The attributes of an ``esdf`` array (besides its dimension names)."""
    return {
        "description": (
            "signed Euclidean distance of the voxel centre to the nearest face between an obstacle voxel and "
            "a free one, world units: positive in free space, negative inside obstacles; obstacles are the "
            "voxels with a class, UNKNOWN voxels and the map's outside (unknown = occupied); computed from "
            "this level's label"
        ),
        **esdf_group_attributes(units)[ESDF_ARRAY],
    }


def write_esdf(group: Any, voxel_size: float) -> None:
    """Fill a map group's ``esdf`` array from its ``label`` array (:data:`ESDF_UNKNOWN` rule), both
    read and written chunk by chunk.

    Memory: the whole grid's obstacle mask (1 byte per voxel) and the distance transform
    (:func:`scenelabel.maps.esdf.signed_distance_of_mask`: about 19 bytes per voxel at its peak,
    the mask and the float32 result included), in this process; never the label grid itself.

    Args:
        group: a zarr group with ``label`` and an (unfilled) ``esdf`` array of the same shape.
        voxel_size: the level's voxel edge, world units.
    """
    label, target = group[LABEL_ARRAY], group[ESDF_ARRAY]
    blocks = ((block, label[block]) for block in iter_chunks(label.shape, label.chunks))
    esdf = signed_distance_blocks(blocks, label.shape, voxel_size, ESDF_UNKNOWN)
    for block in iter_chunks(target.shape, target.chunks):
        target[block] = esdf[block]


@dataclass(frozen=True)
class StoredEsdf:
    """The ``esdf`` array of a map's store, read when the map's ESDF is first asked for
    (:meth:`OccupancyMap.esdf`): loading a map reads only what every query needs.

    Attributes:
        path: the map's group folder (the array is its ``esdf``).
        rule: the array's ``unknown`` attribute, the rule it was computed with.
    """

    path: Path
    rule: str

    def read(self, label: np.ndarray) -> np.ndarray | None:
        """The array's values checked against the map's ``label`` [nx, ny, nz] (:func:`check_esdf`),
        read-only; None when the store no longer holds the array (the ESDF, derived data, is then
        computed from ``label``).

        Raises:
            InputError (field ``esdf``, naming the path): values that do not match ``label``.
        """
        import zarr

        try:
            values = np.asarray(zarr.open_group(str(self.path), mode="r")[ESDF_ARRAY][...])
        except Exception:  # noqa: BLE001 - moved or deleted since the map was read: zarr raises several types
            return None
        try:
            return check_esdf(values, label, self.rule)
        except InputError as exc:
            raise InputError(exc.problem, path=self.path, field=exc.field) from None


def stored_esdf(group: Any, path: Path) -> StoredEsdf | None:
    """The ESDF a map read from ``group`` (at ``path``) starts with: its ``esdf`` array, to read
    on first use; None when the array's rule (attribute ``unknown``) is not one this version knows
    (the ESDF is then computed on demand)."""
    rule = group[ESDF_ARRAY].attrs.get("unknown")
    return StoredEsdf(Path(path), rule) if rule in UNKNOWN_AS else None


def check_target(path: Any, zarr_format: Any, chunks: Any, overwrite: bool) -> tuple[int, tuple[int, int, int], Path]:
    """Checks of :meth:`OccupancyMap.to_zarr`'s arguments before anything is written.

    Returns:
        zarr_format, chunks (3 ints), the absolute target path.
    Raises:
        InputError: bad zarr_format or chunks; ``path`` exists and is not a zarr group or
            overwrite is False; its parent folder does not exist.
    """
    if zarr_format not in (2, 3):
        raise InputError(f"zarr_format must be 2 or 3, got {zarr_format!r}", field="zarr_format")
    chunks = shape3(chunks, "chunks")
    path = Path(path).expanduser().absolute()
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise InputError("already exists (pass overwrite=True to replace it)", path=path)
        if not _is_replaceable(path):
            raise InputError("exists and is not a zarr group; refusing to replace it", path=path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    return int(zarr_format), chunks, path


@contextlib.contextmanager
def staged_group(path: Path) -> Iterator[Path]:
    """Write a map atomically: yields the hidden sibling ``.{name}.tmp-{pid}`` to write into;
    when the block ends without an error, moves it into place at ``path`` (an existing map is
    renamed aside first and removed once the new one is in place); on any error removes it and
    re-raises (``path`` untouched)."""
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    _remove(tmp)
    try:
        yield tmp
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


def checked_attributes(group: Any, path: Path) -> dict[str, Any]:
    """A map group's attributes, checked: format, version, schema, origin_corner, T_world_from_grid."""
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
    derived = {"origin_corner": origin - voxel_size / 2.0}
    if "T_world_from_grid" in attrs:
        derived["T_world_from_grid"] = world_from_grid_matrix(origin, voxel_size)
    for name, expected in derived.items():
        if not np.allclose(
            np.asarray(attrs[name], np.float64), expected, rtol=_CORNER_RTOL, atol=_CORNER_RTOL * voxel_size
        ):
            raise InputError(f"{name} {attrs[name]} does not match origin and voxel_size", path=path, field=name)
    return attrs


def ngff_multiscales(levels: list[Any], zarr_format: int, esdf: bool = True) -> dict[str, Any]:
    """OME-NGFF multiscales metadata of a pyramid written by :meth:`OccupancyMap.to_zarr`.

    One multiscale per spatial array (``label``, ``occupancy``, ``confidence`` when present,
    ``esdf`` when written; ``probs`` is channel-last, which NGFF does not allow, so it is not
    listed). Axes x, y, z of type "space" (unit "meter" when the map is metric, none otherwise);
    each level's dataset maps an index to the world with ``scale = voxel_size`` then
    ``translation = origin`` (the centre of voxel [0, 0, 0] of that level).

    Args:
        levels: the pyramid, level 0 first (:meth:`OccupancyMap.pyramid`).
        zarr_format: 2 -> ``{"multiscales": [...]}`` (NGFF 0.4); 3 -> ``{"ome": {"version":
            "0.5", "multiscales": [...]}}`` (NGFF 0.5).
        esdf: the levels have an ``esdf`` array.
    Returns:
        the group attributes to add.
    """
    base = levels[0]
    unit = {"unit": "meter"} if base.units in NGFF_METRE_UNITS else {}
    axes = [{"name": name, "type": "space", **unit} for name in DIMENSION_NAMES]
    entries = []
    for name, method, rule in (
        (LABEL_ARRAY, "scenelabel.pool_labels", LABEL_POOLING_RULE),
        (OCCUPANCY_ARRAY, "max", "max over the children; 0 where the coarse label is UNKNOWN"),
        (CONFIDENCE_ARRAY, "scenelabel.pool_probs", "1 - entropy / log C of the pooled class probabilities"),
        (ESDF_ARRAY, "scenelabel.signed_distance", _ESDF_LEVEL_RULE),
    ):
        present = esdf if name == ESDF_ARRAY else getattr(base, name) is not None
        if not present:
            continue
        datasets = [
            {
                "path": name if level == 0 else f"{LEVELS_GROUP}/{level}/{name}",
                "coordinateTransformations": [
                    {"type": "scale", "scale": [m.voxel_size] * 3},
                    {"type": "translation", "translation": m.origin.tolist()},
                ],
            }
            for level, m in enumerate(levels)
        ]
        entries.append({"name": name, "axes": axes, "datasets": datasets, "type": method, "metadata": {"method": rule}})
    if zarr_format == 2:
        return {"multiscales": [{"version": NGFF_VERSION_V2, **entry} for entry in entries]}
    return {"ome": {"version": NGFF_VERSION_V3, "multiscales": entries}}


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
