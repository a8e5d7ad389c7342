"""Triangle meshes of a map: one surface at the occupancy threshold, split by class and decimated.

:func:`class_meshes` runs marching cubes once on the map's continuous ``occupancy`` at its
``occupancy_threshold`` (one closed surface for the whole map, the voxels beyond the grid and the
UNKNOWN voxels counted as outside, inside voxels seen as at least :data:`INSIDE_MARGIN` above the
threshold so that none gives a sheet of zero thickness), gives every triangle the class of the nearest labelled voxel,
splits the surface into one mesh per class and decimates each (quadric edge collapses,
fast-simplification). :func:`write_class_meshes` writes them as PLY with per-vertex colour,
normal and ``label``; :mod:`~scenelabel.maps.exports.glb` as one GLB. :func:`class_surface` is the
older per-class surface (marching cubes on a class's 0/1 voxels, terraced), kept for comparison
(tools/bench_meshes.py).

Every step works in voxel index units (decimation thresholds do not depend on the world unit);
outputs are world positions. trimesh and fast-simplification are imported inside the functions
that need them.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.lattice import world_from_index
from scenelabel.maps.codes import UNKNOWN
from scenelabel.maps.exports.palette import class_palette
from scenelabel.maps.exports.ply import frame_comments, write_ply
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "AGGRESSIVENESS",
    "DEFAULT_REDUCTION",
    "FLAT_TOLERANCE",
    "INSIDE_MARGIN",
    "MIN_DECIMATED_FACES",
    "ClassMesh",
    "class_meshes",
    "class_surface",
    "decimate",
    "face_labels",
    "mesh_file_name",
    "occupancy_surface",
    "vertex_normals",
    "write_class_meshes",
]

DEFAULT_REDUCTION = 0.95
"""Default fraction of a class mesh's marching-cubes triangles that :func:`decimate` removes (the
flat regions collapse first, which may remove more). Chosen on the furnished room
(tools/bench_meshes.py, docs/meshes.md): 0.9 gives about 10x fewer triangles than the label-mask
meshes, 0.95 about 20x at a smaller median distance to the true surface."""
MIN_DECIMATED_FACES = 64
""":func:`decimate` never targets fewer triangles than this: a class mesh a few voxels across (a box
of marching cubes' cut edges needs ~45 once its flat faces collapsed) keeps its shape."""
FLAT_TOLERANCE = 1e-3
"""Pass 1 of :func:`decimate` makes every collapse whose quadric error is below this squared (length
units, i.e. voxels): the ones that leave flat regions and straight edges where they are."""
AGGRESSIVENESS = 5.0
"""fast-simplification's ``agg`` in pass 2 of :func:`decimate`: its threshold grows as
``1e-9 * (iteration + 3) ** 5``, up to ~11 (voxels²) in its 100 iterations; slower than its default 7
(cheapest collapses first more strictly; on the furnished room, tools/bench_meshes.py, the same
count with less loss), yet fast enough to reach the count."""
INSIDE_MARGIN = 0.05
"""Marching cubes sees an inside voxel's occupancy as at least ``threshold + INSIDE_MARGIN``: a voxel at
exactly the threshold (the visibility rule raises the voxels a camera's surface lies in to it) would
otherwise put the surface through its centre from both sides, a sheet of zero thickness. With the
margin the crossing lies about a tenth of a voxel out (towards a neighbour at occupancy ~0)."""


class ClassMesh(NamedTuple):
    """The mesh of one class, world frame.

    vertices: [V, 3] float64 world positions.
    faces: [F, 3] int32 vertex indices, counter-clockwise seen from outside (outside = where the
        occupancy is below the threshold).
    normals: [V, 3] float32 unit outward vertex normals (area-weighted face normals).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


# --------------------------------------------------------------------------------------------
# The old per-class surface (label masks)
# --------------------------------------------------------------------------------------------


def class_surface(mask: np.ndarray, origin: Any, voxel_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed surface around the voxels of ``mask``: marching cubes at level 0.5 on the 0/1 volume.

    The surface :func:`write_class_meshes` wrote before the continuous one (terraced: a tilted or
    noisy plane becomes steps of voxel faces, thousands of triangles); kept for comparison.
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


# --------------------------------------------------------------------------------------------
# One surface at the threshold, labelled
# --------------------------------------------------------------------------------------------


def _surface_in_index_units(occ_map: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes on ``occupancy``: vertices [V, 3] float64 in voxel index units (fractional
    [i, j, k]), faces [F, 3] int32 counter-clockwise seen from outside; both empty when no voxel
    reaches the threshold."""
    from skimage.measure import marching_cubes

    occupancy = occ_map.occupancy
    threshold = occ_map.occupancy_threshold
    inside = np.argwhere(occupancy >= threshold)  # [N, 3]
    if len(inside) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    # Crop to the inside voxels and one neighbour (their occupancy places the crossing).
    lo = np.maximum(inside.min(0) - 1, 0)
    hi = np.minimum(inside.max(0) + 2, occ_map.shape)
    crop = occupancy[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    # skimage works in float32: march ``occupancy - threshold`` (exact near 0) at a level a quarter
    # of a float32 step below 0, so that inside <=> occupancy >= threshold exactly (a voxel raised
    # to the threshold is inside) and no voxel sits on the level.
    volume = crop.astype(np.float64) - threshold
    volume = np.where(volume >= 0, np.maximum(volume, INSIDE_MARGIN), volume).astype(np.float32)
    level = -max(float(np.spacing(np.float32(threshold))) / 4.0, 1e-30)
    # Pad by one voxel outside: the border voxel mirrored about the level when it is inside (the
    # crossing falls on the grid's boundary face), itself when it is outside (no crossing).
    volume = np.pad(volume, 1, mode="edge")
    shell = np.ones(volume.shape, dtype=bool)
    shell[1:-1, 1:-1, 1:-1] = False
    volume[shell] = np.minimum(volume[shell], np.float32(2.0 * level) - volume[shell])
    verts, faces, _, _ = marching_cubes(volume, level=level, allow_degenerate=True)
    # skimage winds triangles clockwise seen from outside (its normals point down the gradient,
    # outwards): flip to counter-clockwise.
    return verts.astype(np.float64) + (lo - 1), np.ascontiguousarray(faces[:, ::-1], dtype=np.int32)


def occupancy_surface(occ_map: OccupancyMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map's surface: marching cubes on ``occupancy`` at ``occupancy_threshold``, one closed mesh.

    Inside is ``occupancy >= occupancy_threshold`` (the map's occupied voxels); the crossing
    between a voxel inside and one outside is placed by linear interpolation of their occupancies
    (sub-voxel), an inside voxel's taken as at least ``threshold + INSIDE_MARGIN`` (a voxel at
    exactly the threshold would put both sides of the surface through its centre).

    UNKNOWN voxels have occupancy 0 and count as outside: a surface seen from one side closes just
    behind the observed voxels instead of enclosing the unobserved region (the inside of a wall,
    the space outside the modelled bounds), which would put walls around everything no camera saw.
    Beyond the grid counts as outside too; there the surface closes on the grid's boundary faces.

    Args:
        occ_map: the map.
    Returns:
        vertices: [V, 3] float64 world positions.
        faces: [F, 3] int32 vertex indices, counter-clockwise seen from outside.
        normals: [V, 3] float32 unit outward normals (area-weighted face normals).
        All empty (V = F = 0) when no voxel reaches the threshold.
    """
    verts, faces = _surface_in_index_units(occ_map)
    vertices = world_from_index(verts, occ_map.origin, occ_map.voxel_size)
    return vertices, faces, vertex_normals(vertices, faces)


def face_labels(occ_map: OccupancyMap, vertices: Any, faces: Any) -> np.ndarray:
    """Class of each triangle: the label of the labelled voxel (``label >= 0``) nearest its centroid.

    A triangle of the map's surface lies in one marching-cubes cell (eight voxel centres), at
    least one of them occupied: the nearest of the cell's labelled voxels wins. A triangle whose
    cell holds no labelled voxel (a map whose labels and occupancy disagree, or any other mesh)
    gets the nearest labelled voxel of the whole map (Euclidean distance transform).

    Args:
        occ_map: the map (at least one voxel with ``label >= 0``).
        vertices: [V, 3] world positions.
        faces: [F, 3] vertex indices.
    Returns:
        [F] int64 class ids.
    Raises:
        InputError: the map has no labelled voxel while ``faces`` is not empty.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    labelled = occ_map.label >= 0
    if not labelled.any():
        raise InputError("the map has no labelled voxel (label >= 0): no class for the triangles", field="label")
    ijk = (np.asarray(vertices, np.float64) - occ_map.origin) / occ_map.voxel_size  # [V, 3] index units
    centroid = ijk[faces].mean(1)  # [F, 3]
    shape = np.asarray(occ_map.shape)
    base = np.floor(centroid).astype(np.int64)  # [F, 3] lower corner of the cell
    offsets = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])  # [8, 3]
    corners = base[:, None, :] + offsets  # [F, 8, 3]
    valid = np.all((corners >= 0) & (corners < shape), axis=-1)  # [F, 8]
    clipped = np.clip(corners, 0, shape - 1)
    labels = np.where(valid, occ_map.label[tuple(np.moveaxis(clipped, -1, 0))], UNKNOWN)  # [F, 8]
    d2 = np.where(labels >= 0, ((corners - centroid[:, None, :]) ** 2).sum(-1), np.inf)  # [F, 8]
    best = d2.argmin(1)
    out = labels[np.arange(len(faces)), best].astype(np.int64)
    missing = ~np.isfinite(d2[np.arange(len(faces)), best])
    if missing.any():
        from scipy.ndimage import distance_transform_edt

        nearest = distance_transform_edt(~labelled, return_distances=False, return_indices=True)  # [3, nx, ny, nz]
        voxel = np.clip(np.rint(centroid[missing]).astype(np.int64), 0, shape - 1)  # [M, 3]
        source = nearest[(slice(None),) + tuple(voxel.T)]  # [3, M]
        out[missing] = occ_map.label[tuple(source)]
    return out


# --------------------------------------------------------------------------------------------
# Decimation, normals
# --------------------------------------------------------------------------------------------


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop degenerate faces (a repeated vertex) and unused vertices; renumber."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(-1, 3).astype(np.int32)


def _aggressiveness(tolerance: float) -> float:
    """fast-simplification's ``agg`` whose last threshold is ``tolerance ** 2``: its collapse threshold
    (the largest quadric error, in squared length units, a collapse may have) is
    ``1e-9 * (iteration + 3) ** agg`` over at most 100 iterations."""
    return math.log(tolerance**2 / 1e-9) / math.log(102.0)


def decimate(
    vertices: Any, faces: Any, reduction: float = DEFAULT_REDUCTION, *, preserve_border: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Fewer triangles for the same shape: quadric edge collapses (fast-simplification).

    Two passes, each collapsing the cheapest edges first (quadric error: the sum of squared
    distances from the new vertex to the planes of the original triangles it replaces):

    1. every collapse that moves the surface by less than :data:`FLAT_TOLERANCE` (flat regions and
       straight edges collapse, whatever ``reduction``);
    2. when more than ``(1 - reduction) * F`` triangles remain, collapses down to that count (never
       below :data:`MIN_DECIMATED_FACES`; a collapse of quadric error above ~11 length units²
       is never made, so a count may stay unreached).

    Collapses keep the winding (none flips a triangle) and never make slivers, so a flat rectangle
    keeps a few dozen triangles rather than two. The errors are absolute: give vertices in voxel
    units so that the result does not depend on the world unit.

    Args:
        vertices: [V, 3] positions (voxel units).
        faces: [F, 3] vertex indices.
        reduction: in [0, 1): the fraction of the F triangles to remove (0: pass 1 only).
        preserve_border: never move the vertices of open borders (where a class mesh meets another
            class), so that neighbouring class meshes keep sharing their border exactly.
    Returns:
        vertices: [V', 3] float64.
        faces: [F', 3] int32 (no unused vertex, no face with a repeated vertex).
    Raises:
        InputError: ``reduction`` outside [0, 1).
    """
    import fast_simplification

    if not 0.0 <= reduction < 1.0:
        raise InputError(f"reduction must be in [0, 1), got {reduction}", field="reduction")
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    n_faces = len(faces)
    if n_faces <= 4:
        return _compact(vertices, faces)
    centre = vertices.mean(0)  # quadrics near the origin: float64 keeps small errors exact
    points = np.ascontiguousarray(vertices - centre)
    points, faces = fast_simplification.simplify(
        points, faces, target_count=4, agg=_aggressiveness(FLAT_TOLERANCE), preserve_border=preserve_border
    )
    target = max(round((1.0 - reduction) * n_faces), MIN_DECIMATED_FACES)
    for _ in range(3):  # each call restarts its threshold schedule; stop when a call changes nothing
        before = len(faces)
        if before <= target:
            break
        points, faces = fast_simplification.simplify(
            points, faces, target_count=target, agg=AGGRESSIVENESS, preserve_border=preserve_border
        )
        if len(faces) == before:
            break
    return _compact(np.asarray(points, np.float64) + centre, np.asarray(faces, np.int64))


def vertex_normals(vertices: Any, faces: Any) -> np.ndarray:
    """Unit vertex normals: the sum of the adjacent faces' normals weighted by their area.

    Args:
        vertices: [V, 3] positions.
        faces: [F, 3] vertex indices, counter-clockwise seen from the side the normals point to.
    Returns:
        [V, 3] float32 unit normals ((0, 0, 0) for a vertex of no face or of zero area only).
    """
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    tri = vertices[faces]  # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # [F, 3], |cross| = 2 * area
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], cross)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0, length, 1.0)).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Class meshes
# --------------------------------------------------------------------------------------------


def class_meshes(
    occ_map: OccupancyMap, reduction: float = DEFAULT_REDUCTION, *, preserve_border: bool = True
) -> dict[int, ClassMesh]:
    """One mesh per class: the map's surface (:func:`occupancy_surface`), split by
    :func:`face_labels`, each part decimated (:func:`decimate`, in voxel units).

    Together the meshes form the map's one closed surface; each alone is open where its class
    touches another (a box standing on the floor has no bottom: the contact is inside the
    occupied volume). With ``preserve_border`` the meshes keep their shared borders exactly.

    Args:
        occ_map: the map.
        reduction: see :func:`decimate` (0: only the collapses that leave the shape as it is).
        preserve_border: see :func:`decimate`.
    Returns:
        class id -> :class:`ClassMesh`, ascending by id, for the classes that own at least one
        triangle; empty when no voxel reaches the threshold.
    Raises:
        InputError: ``reduction`` outside [0, 1).
    """
    if not 0.0 <= reduction < 1.0:
        raise InputError(f"reduction must be in [0, 1), got {reduction}", field="reduction")
    verts, faces = _surface_in_index_units(occ_map)
    if len(faces) == 0 or not (occ_map.label >= 0).any():
        return {}
    labels = face_labels(occ_map, world_from_index(verts, occ_map.origin, occ_map.voxel_size), faces)
    meshes: dict[int, ClassMesh] = {}
    for cid in np.unique(labels).tolist():
        part_vertices, part_faces = _compact(verts, faces[labels == cid])
        part_vertices, part_faces = decimate(part_vertices, part_faces, reduction, preserve_border=preserve_border)
        if len(part_faces) == 0:
            continue
        world = world_from_index(part_vertices, occ_map.origin, occ_map.voxel_size)
        meshes[int(cid)] = ClassMesh(world, part_faces, vertex_normals(world, part_faces))
    return meshes


def mesh_file_name(class_id: int, name: str, suffix: str = ".ply") -> str:
    """``class_{id}_{name}{suffix}``, the name with characters other than letters, digits, ``_`` and
    ``-`` replaced by ``_``."""
    safe = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "class"
    return f"class_{class_id}_{safe}{suffix}"


def write_class_meshes(
    occ_map: OccupancyMap,
    out_dir: str | Path,
    reduction: float = DEFAULT_REDUCTION,
    *,
    meshes: dict[int, ClassMesh] | None = None,
) -> dict[int, Path]:
    """One mesh per class (:func:`class_meshes`), ``out_dir/class_{id}_{name}.ply``.

    Each PLY (binary little-endian) has vertex properties ``x y z`` double (world), ``nx ny nz``
    float (outward normal), ``red green blue`` uchar (the class colour) and ``label`` int (the
    class id), and triangle faces (``vertex_indices``, counter-clockwise seen from outside).
    Classes without a triangle get no file; a map with no occupied voxel writes none.

    Args:
        occ_map: the map.
        out_dir: folder to write into (created if missing; existing files of the same name are
            replaced).
        reduction: see :func:`decimate`.
        meshes: the class meshes, when already made by :func:`class_meshes` (then ``reduction``
            is unused).
    Returns:
        class id -> path written, ascending by id.
    Raises:
        InputError: ``out_dir`` exists and is not a folder, or ``reduction`` outside [0, 1).
    """
    out_dir = Path(out_dir).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a folder", path=out_dir)
    if meshes is None:
        meshes = class_meshes(occ_map, reduction)
    out_dir.mkdir(parents=True, exist_ok=True)
    palette = class_palette(occ_map.classes, occ_map.class_colors)
    written: dict[int, Path] = {}
    for cid in sorted(meshes):
        vertices, faces, normals = meshes[cid]
        n = len(vertices)
        rgb = np.broadcast_to(np.asarray(palette[cid], np.uint8), (n, 3))
        written[cid] = write_ply(
            out_dir / mesh_file_name(cid, occ_map.classes[cid]),
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
