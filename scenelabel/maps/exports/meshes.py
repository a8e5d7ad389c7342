"""One closed surface mesh per class (marching cubes on the class's voxels), written as PLY with
per-vertex colour, normal and ``label``."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.lattice import world_from_index
from scenelabel.maps.exports.palette import class_palette
from scenelabel.maps.exports.ply import frame_comments, write_ply
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "class_surface",
    "write_class_meshes",
]

# --------------------------------------------------------------------------------------------
# Meshes
# --------------------------------------------------------------------------------------------


def class_surface(mask: np.ndarray, origin: Any, voxel_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed surface around the voxels of ``mask``: marching cubes at level 0.5 on the 0/1 volume.

    The volume is cropped to the mask's bounding box and padded by one empty voxel on every side,
    so surfaces at the grid's border close. Vertices lie half-way between a voxel centre inside
    and one outside, i.e. on the voxels' faces: the surface encloses exactly the mask's voxels
    (each covering its centre ± voxel_size / 2), with edges and corners cut by marching cubes.
    Triangles wind counter-clockwise seen from outside; normals point outwards.

    Args:
        mask: [nx, ny, nz] bool, the voxels of one class.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
    Returns:
        vertices: [V, 3] float64 world positions.
        faces: [F, 3] int32 vertex indices.
        normals: [V, 3] float32 unit outward normals.
    Raises:
        InputError: ``mask`` is not 3D or holds no voxel.
    """
    from skimage.measure import marching_cubes

    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 3:
        raise InputError(f"mask must be 3D [nx, ny, nz], got shape {mask.shape}", field="mask")
    ijk = np.argwhere(mask)
    if len(ijk) == 0:
        raise InputError("mask holds no voxel: no surface", field="mask")
    lo, hi = ijk.min(0), ijk.max(0) + 1
    volume = np.pad(mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]], 1).astype(np.float32)
    verts, faces, normals, _ = marching_cubes(volume, level=0.5)
    vertices = world_from_index(verts.astype(np.float64) + (lo - 1), origin, voxel_size)  # pad: -1
    # skimage winds triangles clockwise seen from outside (its normals point outwards): flip.
    return vertices, np.ascontiguousarray(faces[:, ::-1], dtype=np.int32), normals.astype(np.float32)


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "class"


def write_class_meshes(occ_map: OccupancyMap, out_dir: str | Path) -> dict[int, Path]:
    """One closed surface mesh per class, ``out_dir/class_{id}_{name}.ply`` (see :func:`class_surface`).

    Each PLY (binary little-endian) has vertex properties ``x y z`` double (world), ``nx ny nz``
    float (outward normal), ``red green blue`` uchar (the class colour) and ``label`` int (the
    class id), and triangle faces (``vertex_indices``). Classes with no occupied voxel get no file.

    Args:
        occ_map: the map.
        out_dir: folder to write into (created if missing; existing files of the same name are
            replaced).
    Returns:
        class id -> path written, ascending by id.
    """
    out_dir = Path(out_dir).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a folder", path=out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    palette = class_palette(occ_map.classes, occ_map.class_colors)
    present = set(np.unique(occ_map.label[occ_map.label >= 0]).tolist())
    written: dict[int, Path] = {}
    for cid, name in occ_map.classes.items():
        if cid not in present:
            continue
        vertices, faces, normals = class_surface(occ_map.label == cid, occ_map.origin, occ_map.voxel_size)
        n = len(vertices)
        rgb = np.broadcast_to(np.asarray(palette[cid], np.uint8), (n, 3))
        written[cid] = write_ply(
            out_dir / f"class_{cid}_{_safe_name(name)}.ply",
            {
                "x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2],
                "nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2],
                "red": rgb[:, 0], "green": rgb[:, 1], "blue": rgb[:, 2],
                "label": np.full(n, cid, np.int32),
            },
            faces,
            comments=frame_comments(occ_map),
        )
    return written
