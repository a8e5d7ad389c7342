"""Occupied voxels as a coloured PLY point cloud, and the binary PLY writer every export uses.

PLY files are written by :func:`write_ply` (numpy, binary little-endian) and read back by open3d
(tests/test_exports.py): open3d's own writers drop custom vertex attributes of triangle meshes,
refuse empty point clouds and have no int16, so they are not used here.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from scenelabel._files import atomic_write_bytes
from scenelabel.errors import InputError
from scenelabel.maps.codes import unit_from_uint8
from scenelabel.maps.exports.palette import class_palette, color_lookup
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "occupied_voxels",
    "write_point_cloud",
    "frame_comments",
    "write_ply",
]

# numpy dtype -> PLY property type (binary little-endian)
_PLY_TYPES = {
    np.dtype(np.float64): "double",
    np.dtype(np.float32): "float",
    np.dtype(np.uint8): "uchar",
    np.dtype(np.int8): "char",
    np.dtype(np.uint16): "ushort",
    np.dtype(np.int16): "short",
    np.dtype(np.uint32): "uint",
    np.dtype(np.int32): "int",
}


def occupied_voxels(occ_map: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """Indices and class ids of the occupied voxels (``label >= 0``), in C order.

    Returns:
        ijk: [N, 3] int64 voxel indices.
        label: [N] int16 class ids.
    """
    ijk = np.argwhere(occ_map.label >= 0)  # [N, 3]
    return ijk, occ_map.label[tuple(ijk.T)]


def _ply_path(path: str | Path) -> Path:
    path = Path(path).expanduser()
    if path.suffix.lower() != ".ply":
        raise InputError("a PLY file name must end in .ply", path=path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    return path


# --------------------------------------------------------------------------------------------
# Point cloud
# --------------------------------------------------------------------------------------------


def write_point_cloud(occ_map: OccupancyMap, path: str | Path) -> Path:
    """Occupied voxel centres as a coloured point cloud (binary little-endian PLY).

    Per point (vertex properties, in this order): ``x y z`` double (world centre of the voxel),
    ``red green blue`` uchar (the class colour, :func:`class_palette`), ``label`` int (class id),
    ``occupancy`` float and, when the map has it, ``confidence`` float in [0, 1] (1 - normalised
    entropy of the voxel's class probabilities, :func:`scenelabel.maps.confidence_from_probs`,
    as quantised in the map). open3d's tensor API reads every property back
    (``open3d.t.io.read_point_cloud(path).point.label``); other PLY readers see standard coloured
    points. A map with no occupied voxel gives a valid PLY with 0 points.

    Args:
        occ_map: the map.
        path: the ``.ply`` file to write (replaced if present).
    Returns:
        the path written.
    Raises:
        InputError: ``path`` does not end in .ply or its folder does not exist.
    """
    ijk, label = occupied_voxels(occ_map)
    xyz = occ_map.world_from_index(ijk)  # [N, 3] float64
    rgb = color_lookup(class_palette(occ_map.classes, occ_map.class_colors), label)  # [N, 3] uint8
    properties = {
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "red": rgb[:, 0],
        "green": rgb[:, 1],
        "blue": rgb[:, 2],
        "label": label.astype(np.int32),
        "occupancy": occ_map.occupancy[tuple(ijk.T)].astype(np.float32),
    }
    if occ_map.confidence is not None:
        properties["confidence"] = unit_from_uint8(occ_map.confidence[tuple(ijk.T)]).astype(np.float32)
    return write_ply(path, properties, comments=frame_comments(occ_map))


def frame_comments(occ_map: OccupancyMap) -> tuple[str, ...]:
    """Header lines that say which frame and unit an export's coordinates are in."""
    return (f"frame {occ_map.frame_id}; units {occ_map.units}; scale {occ_map.scale_source}",)


def write_ply(
    path: str | Path, vertex: Mapping[str, np.ndarray], faces: np.ndarray | None = None, comments: tuple[str, ...] = ()
) -> Path:
    """Write a binary little-endian PLY: a ``vertex`` element and optionally triangle ``face``s.

    Args:
        path: the ``.ply`` file to write (replaced if present).
        vertex: property name -> [V] array (float64, float32, uint8, int8, uint16, int16,
            uint32 or int32), written in this order (e.g. x, y, z, nx, ny, nz, red, green, blue).
        faces: [F, 3] vertex indices (written as ``list uchar int vertex_indices``), or None.
        comments: extra header ``comment`` lines (one line each, ASCII).
    Returns:
        the path written.
    """
    path = _ply_path(path)
    columns = {name: np.asarray(values) for name, values in vertex.items()}
    lengths = {len(v) for v in columns.values()}
    if len(lengths) != 1 or any(v.ndim != 1 for v in columns.values()):
        raise InputError("vertex properties must be 1D arrays of one length", field="vertex")
    for name, values in columns.items():
        if values.dtype not in _PLY_TYPES:
            raise InputError(f"vertex property {name!r} has dtype {values.dtype}, not a PLY type", field=name)
    n = lengths.pop()
    records = np.empty(n, dtype=[(name, values.dtype.newbyteorder("<")) for name, values in columns.items()])
    for name, values in columns.items():
        records[name] = values
    header = ["ply", "format binary_little_endian 1.0", "comment written by scenelabel"]
    header += [f"comment {' '.join(c.split())}" for c in comments] + [f"element vertex {n}"]
    header += [f"property {_PLY_TYPES[values.dtype]} {name}" for name, values in columns.items()]
    body = [records.tobytes()]
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise InputError(f"faces must have shape [F, 3], got {faces.shape}", field="faces")
        if faces.size and (faces.min() < 0 or faces.max() >= n):
            raise InputError(f"faces index vertices outside [0, {n})", field="faces")
        tris = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        tris["n"] = 3
        tris["v"] = faces
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        body.append(tris.tobytes())
    return atomic_write_bytes(path, "\n".join(header + ["end_header"]).encode("ascii") + b"\n" + b"".join(body))
