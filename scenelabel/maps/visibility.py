"""Which world points the training cameras observed: projection into low-resolution depth maps.

Numpy only (no torch). Conventions (docs/conventions.md): cameras are :class:`scenelabel.Cameras`
with OpenCV axes (x right, y down, z forward) in the world frame; pixel (col, row) covers
[col, col + 1) x [row, row + 1), its centre at (col + 0.5, row + 0.5); depth is the distance along
the unit ray from the camera centre, and so are ``near`` and ``far``.

The rule (docs/conventions.md, "Observed space"): a point ``p`` is *seen* by camera ``c`` when

1. its camera's lens model projects it (:func:`scenelabel.geometry.lens.pixels_from_camera_points`:
   a pinhole needs ``z > 0``, a fisheye an angle from its axis it models) inside the image
   rectangle: ``0 <= u < width``, ``0 <= v < height``; for an ideal pinhole
   ``(u, v) = (fx x / z + cx, fy y / z + cy)`` (:func:`scaled_cameras` drops a pinhole's
   distortion, keeps a fisheye's model: the depth maps' rays and the projection agree),
2. its distance ``d = |p - centre|`` lies in the camera's ``[near, far]`` (unknown limits: 0, inf),
3. it is not behind the first surface of the pixel it projects to:
   ``d <= depth[row, col] + margin + pixel_margin * d / min(fx, fy)``, where ``depth`` is the
   camera's depth map (``inf`` where the ray hits nothing) and the last term is ``pixel_margin``
   pixel footprints at that distance (the depth maps are coarse).

A point seen by no camera is unobserved. ``visible_from_cameras`` applies the rule to many points
at once: for pinholes in compiled loops (:mod:`scenelabel.maps.visibility_kernels`, numba,
imported on first use, the points split over the cores, each point's cameras tried until one
sees it), for fisheyes vectorised over points, one pass per camera.

For a map, the surfaces are the map's own: :func:`camera_surfaces` casts each (shrunk,
:func:`scaled_cameras`) camera's pixel rays through the map's per-voxel opacities to where their
transmittance falls to 0.5 (what a volume renderer draws there); the voxels those surfaces lie in
are occupied besides the opaque ones (a field's surfaces are often a few voxels of fog, none
opaque alone), and :func:`observed_voxels` applies the rule twice (docs/conventions.md,
"Observed space"): an *occupied* voxel is observed against :func:`back_depth` of each depth map
(on a smooth surface half a pixel's step past the pixel's own depth: the surface's far edge over
the pixel) with ``margin = SQRT3 * voxel_size`` and one pixel footprint (a surface voxel's centre
may lie up to that far behind where the surface is); a *transparent* voxel only when its centre
is in front of the surface, with no margin, against :func:`front_depth` of each depth map (so a
voxel just behind a silhouette or a surface is never taken for observed free space)::

    small = scaled_cameras(train_cameras, DEPTH_MAP_WIDTH)
    observed, occupied = observed_voxels(occupancy, origin, voxel_size, small)   # [nx, ny, nz] bool each
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from scenelabel.errors import InputError
from scenelabel.geometry.boxes import ray_box_distances
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.lattice import voxel_centers
from scenelabel.geometry.lens import FISHEYE, inside_image, project_points
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.maps.codes import OCCUPIED_THRESHOLD, uint8_from_unit
from scenelabel.maps.raycast import leap_lengths, transmittance_crossings

__all__ = [
    "CameraSurfaces",
    "DEPTH_MAP_WIDTH",
    "PIXEL_MARGIN",
    "SQRT3",
    "camera_surfaces",
    "back_depth",
    "front_depth",
    "max_depth_over_neighbours",
    "min_depth_over_neighbours",
    "observed_centres",
    "observed_voxels",
    "project_points",
    "scaled_cameras",
    "seen_before_bounds",
    "smooth_pixels",
    "surface_mask",
    "visible_from_cameras",
]

DEPTH_MAP_WIDTH = 80
"""Visibility depth maps are rendered at most this many pixels wide (height keeps the aspect)."""

PIXEL_MARGIN = 1.0
"""Extra depth tolerance, in pixel footprints of the depth map at the point's distance."""

SMOOTH_BEND = 0.1
"""A depth-map pixel is on a smooth surface when, for each pair of opposite neighbours (a, b)
around its depth d, |a + b - 2 d| <= SMOOTH_BEND x d: a plane seen at a grazing angle bends far
less (its depth grows by a few percent a pixel), a silhouette's jump far more."""

SQRT3 = math.sqrt(3.0)
"""A voxel's diagonal over its edge: maps use ``margin = SQRT3 * voxel_size``."""




def scaled_cameras(cameras: Cameras, max_width: int = DEPTH_MAP_WIDTH) -> Cameras:
    """The same cameras with images shrunk to at most ``max_width`` pixels wide (never enlarged).

    Per camera ``w' = max(1, round(w * s))``, ``h' = max(1, round(h * s))`` with
    ``s = min(1, max_width / w)``; intrinsics scale per axis by ``w' / w`` and ``h' / h``, so the
    image rectangle covers the same rays (pixel centres stay at +0.5 of the new pixels).
    A pinhole's distortion is dropped (the small images are ideal pinholes); a fisheye keeps its
    model and coefficients (they act on normalised coordinates; as a pinhole its rays would be
    far off).

    Args:
        cameras: n cameras.
        max_width: widest image allowed, pixels (>= 1).
    Returns:
        n cameras: same poses, near / far and models, pinholes without distortion.
    """
    if int(max_width) < 1:
        raise InputError(f"max_width must be >= 1, got {max_width}", field="max_width")
    width = cameras.width.astype(np.float64)
    height = cameras.height.astype(np.float64)
    s = np.minimum(1.0, int(max_width) / width)  # [n]
    new_w = np.maximum(1, np.round(width * s)).astype(np.int64)
    new_h = np.maximum(1, np.round(height * s)).astype(np.int64)
    sx, sy = new_w / width, new_h / height  # [n] each
    return Cameras(
        c2w=cameras.c2w.copy(),
        fx=cameras.fx * sx,
        fy=cameras.fy * sy,
        cx=cameras.cx * sx,
        cy=cameras.cy * sy,
        width=new_w,
        height=new_h,
        distortion=np.where((cameras.model == FISHEYE)[:, None], cameras.distortion, 0.0),
        near=cameras.near.copy(),
        far=cameras.far.copy(),
        model=cameras.model.copy(),
    )


def _check_inputs(points: Any, cameras: Cameras, depth_maps: Sequence[np.ndarray], margin: float) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {points.shape}", field="points")
    if len(depth_maps) != len(cameras):
        raise InputError(f"{len(cameras)} cameras but {len(depth_maps)} depth maps", field="depth_maps")
    for i, depth in enumerate(depth_maps):
        expected = (int(cameras.height[i]), int(cameras.width[i]))
        if np.shape(depth) != expected:
            raise InputError(
                f"depth map {i} has shape {np.shape(depth)}, expected [height, width] = {list(expected)}",
                field="depth_maps",
            )
    if not (math.isfinite(float(margin)) and float(margin) >= 0):
        raise InputError(f"margin must be a finite number >= 0, got {margin!r}", field="margin")
    return points


def visible_from_cameras(
    points: Any,
    cameras: Cameras,
    depth_maps: Sequence[np.ndarray],
    margin: float,
    pixel_margin: float = PIXEL_MARGIN,
) -> np.ndarray:
    """Which points at least one camera saw (the rule of the module docstring).

    Args:
        points: [N, 3] world points.
        cameras: n cameras; camera i's image is ``depth_maps[i]`` (sizes must match).
        depth_maps: n arrays [height_i, width_i]: distance along each pixel's unit ray to the
            first surface, ``inf`` where the ray hits nothing.
        margin: depth tolerance behind the surface, world units (maps: one voxel diagonal).
        pixel_margin: extra tolerance in pixel footprints at the point's distance.
    Returns:
        [N] bool, True where some camera saw the point.
    """
    points = _check_inputs(points, cameras, depth_maps, margin)
    if len(points) and not np.any(cameras.model == FISHEYE):
        return _visible_compiled(np.ascontiguousarray(points), cameras, depth_maps, float(margin), float(pixel_margin))
    seen = np.zeros(len(points), dtype=bool)
    for i in range(len(cameras)):
        todo = np.flatnonzero(~seen)  # only points no camera has seen yet
        if todo.size == 0:
            break
        uv, dist, in_view = _in_view(points[todo], cameras, i)
        hits = np.flatnonzero(in_view)
        cols = np.floor(uv[hits, 0]).astype(np.int64)
        rows = np.floor(uv[hits, 1]).astype(np.int64)
        surface = np.asarray(depth_maps[i], np.float64)[rows, cols]  # [n_hits]
        tolerance = margin + pixel_margin * dist[hits] / min(cameras.fx[i], cameras.fy[i])
        seen[todo[hits[dist[hits] <= surface + tolerance]]] = True
    return seen


def _in_view(points: np.ndarray, cameras: Cameras, i: int, use_near: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera ``i``'s view of points [N, 3]: uv [N, 2] and distance [N] (:func:`project_points`), and
    [N] bool where rules 1 and 2 hold: inside the image, within ``[near, far]`` (unknown limits: 0,
    inf; without ``use_near`` only ``far`` limits)."""
    uv, _, dist = project_points(
        points, cameras.c2w[i], cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i],
        cameras.distortion[i], str(cameras.model[i]),
    )
    near = cameras.near[i] if use_near and np.isfinite(cameras.near[i]) else 0.0
    far = cameras.far[i] if np.isfinite(cameras.far[i]) else np.inf
    with np.errstate(invalid="ignore"):
        in_view = inside_image(uv, int(cameras.width[i]), int(cameras.height[i])) & (dist >= near) & (dist <= far)
    return uv, dist, in_view


def _visible_compiled(
    points: np.ndarray, cameras: Cameras, depth_maps: Sequence[np.ndarray], margin: float, pixel_margin: float
) -> np.ndarray:
    """:func:`visible_from_cameras` for pinholes in compiled loops
    (:func:`scenelabel.maps.visibility_kernels.visibility_kernel`, over the cores)."""
    from scenelabel.maps import raycast_kernels, visibility_kernels  # numba: imported on first use

    n = len(cameras)
    distortion = np.asarray(cameras.distortion, np.float64).reshape(n, 4)
    lens = np.column_stack([cameras.fx, cameras.fy, cameras.cx, cameras.cy, distortion])
    limits = np.column_stack([
        np.where(np.isfinite(cameras.near), cameras.near, 0.0),
        np.where(np.isfinite(cameras.far), cameras.far, np.inf),
        cameras.width,
        cameras.height,
    ]).astype(np.float64)
    flat = [np.ascontiguousarray(d, np.float64).reshape(-1) for d in depth_maps]
    offsets = np.concatenate([[0], np.cumsum([len(d) for d in flat])[:-1]]).astype(np.int64)
    depth = np.concatenate(flat)
    c2w = np.ascontiguousarray(cameras.c2w, np.float64)
    margins = np.array([margin, pixel_margin])
    seen = np.empty(len(points), dtype=bool)

    def run(rows: slice) -> None:
        visibility_kernels.visibility_kernel(points[rows], c2w, lens, limits, depth, offsets, margins, seen[rows])

    raycast_kernels.in_threads(run, len(points))
    return seen


def seen_before_bounds(points: Any, cameras: Cameras, aabb: Any) -> np.ndarray:
    """Which points outside the modelled box some camera saw through on its way into the box
    (docs/conventions.md, "Observed space outside the bounds").

    The box holds the geometry the cameras observe, so the stretch of a camera's ray before it
    enters the box crosses no surface: free space that camera saw. A point ``p`` outside the box
    is seen free by camera ``c`` when rule 1 of the module docstring holds (``p`` projects into
    ``c``'s image), its distance ``d`` is at most ``c``'s ``far`` (nearer than ``near`` is free too:
    the camera's near bound says nothing lies there), and the ray from ``c``'s centre through ``p``
    enters the box beyond it: ``d < t_enter``. A ray that misses the box gives
    nothing (what it saw lies outside every observed surface's box: unknown), nor does a camera
    inside the box (its rays leave the box before they reach ``p``).

    Args:
        points: [N, 3] world points.
        cameras: the training cameras (world frame, OpenCV axes).
        aabb: [2, 3] the box (min corner, max corner).
    Returns:
        [N] bool; False for points inside the box (the field answers there).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = np.asarray(aabb, dtype=np.float64)
    seen = np.zeros(len(points), dtype=bool)
    todo = np.flatnonzero(~np.all((points >= lo) & (points <= hi), axis=1))
    for i in range(len(cameras)):
        if todo.size == 0:
            break
        _, dist, in_view = _in_view(points[todo], cameras, i, use_near=False)
        centre = cameras.c2w[i, :3, 3]
        t_enter, t_exit = ray_box_distances(np.broadcast_to(centre, (todo.size, 3)), points[todo] - centre, lo, hi)
        # directions p - c are not unit: t is in units of d, so the box starts beyond p where t_enter > 1
        hit = in_view & (dist > 0) & (t_exit >= t_enter) & (t_enter > 1.0)
        seen[todo[hit]] = True
        todo = todo[~hit]
    return seen


def min_depth_over_neighbours(depth: np.ndarray, size: int = 3) -> np.ndarray:
    """Each pixel's smallest depth over the ``size`` x ``size`` pixels around it (edges repeated).

    Args:
        depth: [h, w] depth map (``inf`` = no surface).
        size: window edge, pixels (odd, >= 1).
    Returns:
        [h, w] float64, never larger than ``depth``.
    """
    from scipy.ndimage import minimum_filter

    return _over_neighbours(minimum_filter, depth, size)


def max_depth_over_neighbours(depth: np.ndarray, size: int = 3) -> np.ndarray:
    """Each pixel's largest depth over the ``size`` x ``size`` pixels around it (edges repeated):
    :func:`min_depth_over_neighbours`' counterpart (``inf`` = no surface, so a pixel beside one
    that sees nothing gets ``inf``).

    Args:
        depth: [h, w] depth map (``inf`` = no surface).
        size: window edge, pixels (odd, >= 1).
    Returns:
        [h, w] float64, never smaller than ``depth``.
    """
    from scipy.ndimage import maximum_filter

    return _over_neighbours(maximum_filter, depth, size)


def _over_neighbours(window_filter, depth: np.ndarray, size: int) -> np.ndarray:
    """``window_filter`` (scipy.ndimage's minimum or maximum filter) of ``depth`` [h, w] over
    ``size`` x ``size`` pixels, edges repeated, as float64; ``size`` must be odd and >= 1."""
    if int(size) < 1 or int(size) % 2 == 0:
        raise InputError(f"size must be an odd integer >= 1, got {size!r}", field="size")
    return window_filter(np.asarray(depth, dtype=np.float64), size=int(size), mode="nearest")


def smooth_pixels(depth: np.ndarray) -> np.ndarray:
    """[h, w] bool: the pixels on a smooth surface, where for each pair of opposite neighbours
    (a, b) around the pixel's finite depth d (edges repeated), |a + b - 2 d| <= SMOOTH_BEND x d.
    Silhouettes, creases, pixels that see nothing (``inf``) and those bordering them are not."""
    depth = np.asarray(depth, dtype=np.float64)
    padded = np.pad(depth, 1, mode="edge")
    h, w = depth.shape
    smooth = np.isfinite(depth)
    with np.errstate(invalid="ignore"):  # inf - inf: not smooth
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = padded[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            b = padded[1 - dr : 1 - dr + h, 1 - dc : 1 - dc + w]
            smooth &= np.abs(a + b - 2.0 * depth) <= SMOOTH_BEND * depth
    return smooth


def front_depth(depth: np.ndarray) -> np.ndarray:
    """Each pixel's depth that a voxel centre falling in it must lie in front of to be observed free
    space (docs/conventions.md, "Observed space", rule 5): on a smooth surface
    (:func:`smooth_pixels`) the mean of its own depth and :func:`min_depth_over_neighbours` (the
    surface's nearest depth over the pixel's footprint, about half a pixel's step nearer than its
    centre's); elsewhere (silhouettes, creases, pixels that see nothing or border them) the
    smallest over the 3 x 3 pixels, so that space just behind a silhouette is never taken for free.
    The smallest alone marks the voxels just above a floor seen at a grazing angle as unobserved: a
    coarse pixel's step there exceeds the voxel's height over the floor.

    Args:
        depth: [h, w] depth map (``inf`` = no surface).
    Returns:
        [h, w] float64, between :func:`min_depth_over_neighbours` and ``depth``.
    """
    depth = np.asarray(depth, dtype=np.float64)
    low = min_depth_over_neighbours(depth)
    return np.where(smooth_pixels(depth), 0.5 * (depth + low), low)


def back_depth(depth: np.ndarray) -> np.ndarray:
    """Each pixel's depth that an occupied voxel's centre falling in it is measured from
    (docs/conventions.md, "Observed space", rule 4): on a smooth surface (:func:`smooth_pixels`)
    the mean of its own depth and :func:`max_depth_over_neighbours` (the surface's farthest depth
    over the pixel's footprint, about half a pixel's step farther than its centre's); elsewhere
    (silhouettes, creases, pixels that see nothing or border them) its own depth, so that nothing
    behind a silhouette is taken for seen. :func:`front_depth`'s counterpart: a surface seen at a
    grazing angle (a floor or ceiling across the room, from a forward-facing rig) moves by tens of
    centimetres over one coarse pixel, far more than a voxel, and with the pixel's own depth alone
    the voxels holding that surface were unobserved wherever it lay in the far half of a pixel.

    Args:
        depth: [h, w] depth map (``inf`` = no surface).
    Returns:
        [h, w] float64, between ``depth`` and :func:`max_depth_over_neighbours`.
    """
    depth = np.asarray(depth, dtype=np.float64)
    return np.where(smooth_pixels(depth), 0.5 * (depth + max_depth_over_neighbours(depth)), depth)


@dataclass(frozen=True)
class CameraSurfaces:
    """The surface along every pixel ray of some (small) cameras: what the visibility rule needs
    besides the voxel centres (:func:`camera_surfaces`; a few small arrays, picklable).

    Attributes:
        cameras: n cameras (their lens models are used: rays and projection agree).
        depth: n arrays [h_i, w_i] float64: distance along each pixel's unit ray to its surface,
            ``inf`` where the ray meets none.
        front: n arrays [h_i, w_i]: :func:`front_depth` of ``depth``.
        back: n arrays [h_i, w_i]: :func:`back_depth` of ``depth``.
        voxels: [S, 3] int64, the distinct grid voxels those surfaces lie in (surfaces from
            ``occluder_depth``, outside the grid, are not voxels of it).
    """

    cameras: Cameras
    depth: list[np.ndarray]
    front: list[np.ndarray]
    back: list[np.ndarray]
    voxels: np.ndarray


def camera_surfaces(
    occupancy: np.ndarray,
    origin: Any,
    voxel_size: float,
    cameras: Cameras,
    occluder_depth: Sequence[np.ndarray] | None = None,
) -> CameraSurfaces:
    """Cast each camera's pixel rays through a grid of per-voxel opacities, within the camera's
    near / far: each ray's surface is where its transmittance falls to 0.5
    (:func:`scenelabel.maps.transmittance_crossings`, the median termination depth of volume
    rendering). The first step of :func:`observed_voxels`, the one that needs the whole grid.

    Args:
        occupancy: [nx, ny, nz] per-voxel opacity in [0, 1] (a map's ``occupancy``), or its uint8
            codes; a bool grid is a grid of opaque voxels.
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        cameras: n cameras (use small ones, :func:`scaled_cameras`).
        occluder_depth: optional n depth maps [h_i, w_i] of surfaces the grid does not hold (e.g.
            outside its box); each pixel's surface is the nearer of the two.
    Returns:
        CameraSurfaces.
    """
    occupancy = np.asarray(occupancy)
    codes = occupancy if occupancy.dtype == np.uint8 else uint8_from_unit(occupancy)  # quantised once
    matter = codes > 0
    leaps = leap_lengths(matter) if matter.any() else None  # the rays' leaps through the grid, once for every camera
    depth, voxels = [], []
    for i in range(len(cameras)):
        origins, directions = rays_from_cameras(cameras, i)  # [h w, 3] each, row-major pixels
        hit, index = transmittance_crossings(
            origins, directions, codes, origin, voxel_size, cameras.near[i], cameras.far[i], leaps=leaps
        )
        if occluder_depth is not None:
            outside = np.asarray(occluder_depth[i], np.float64).reshape(-1)
            occluded = outside < hit  # the pixel's surface lies outside the grid
            hit, index = np.where(occluded, outside, hit), index[~occluded]
        voxels.append(index[index[:, 0] >= 0])
        depth.append(hit.reshape(int(cameras.height[i]), int(cameras.width[i])))
    voxels = np.unique(np.concatenate(voxels), axis=0) if voxels else np.zeros((0, 3), np.int64)
    return CameraSurfaces(cameras, depth, [front_depth(d) for d in depth], [back_depth(d) for d in depth], voxels.reshape(-1, 3))


def surface_mask(surfaces: CameraSurfaces, block: tuple[slice, slice, slice]) -> np.ndarray:
    """[bi, bj, bk] bool: which voxels of a block of the grid hold a camera surface.

    Args:
        surfaces: from :func:`camera_surfaces`.
        block: (slice_i, slice_j, slice_k) with explicit start and stop.
    """
    start = np.array([s.start for s in block])
    stop = np.array([s.stop for s in block])
    mask = np.zeros(tuple(stop - start), dtype=bool)
    inside = np.all((surfaces.voxels >= start) & (surfaces.voxels < stop), axis=1)
    mask[tuple((surfaces.voxels[inside] - start).T)] = True
    return mask


def observed_centres(centres: Any, occupied: Any, voxel_size: float, surfaces: CameraSurfaces) -> np.ndarray:
    """Which voxels some camera observed, given their centres (the second step of
    :func:`observed_voxels`, voxel by voxel, so any block of a grid at a time).

    An occupied voxel is observed when some camera sees its centre (:func:`visible_from_cameras`)
    against its pixel's :func:`back_depth` (``surfaces.back``) with ``margin = SQRT3 * voxel_size``
    and one pixel footprint, a free voxel when some camera sees its centre in front of its pixel's
    :func:`front_depth` (``surfaces.front``, no margin).

    Args:
        centres: [V, 3] world voxel centres.
        occupied: [V] bool, which of them are occupied.
        voxel_size: voxel edge, world units.
        surfaces: from :func:`camera_surfaces` over the whole grid.
    Returns:
        [V] bool.
    """
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    occ = np.asarray(occupied, dtype=bool).reshape(-1)
    if len(occ) != len(centres):
        raise InputError(f"{len(centres)} centres but {len(occ)} occupied flags", field="occupied")
    seen = np.empty(len(centres), dtype=bool)
    seen[occ] = visible_from_cameras(centres[occ], surfaces.cameras, surfaces.back, SQRT3 * voxel_size)
    seen[~occ] = visible_from_cameras(centres[~occ], surfaces.cameras, surfaces.front, 0.0, pixel_margin=0.0)
    return seen


def observed_voxels(
    occupancy: np.ndarray,
    origin: Any,
    voxel_size: float,
    cameras: Cameras,
    occluder_depth: Sequence[np.ndarray] | None = None,
    chunk: int = 32,
) -> tuple[np.ndarray, np.ndarray]:
    """Which voxels of a grid are occupied, and which the cameras observed (the rule of a map,
    docs/conventions.md, "Observed space").

    Each camera's pixel rays (use small cameras, :func:`scaled_cameras`) are cast through the
    grid's opacities (:func:`camera_surfaces`). A voxel is occupied when its opacity is at least
    :data:`scenelabel.maps.OCCUPIED_THRESHOLD` (code >= 128) or a camera's surface lies
    in it; then every voxel is classified (:func:`observed_centres`): an occupied voxel is
    observed when some camera sees its centre (:func:`visible_from_cameras`) against its pixel's
    :func:`back_depth` with ``margin = SQRT3 * voxel_size`` and one pixel footprint, a free voxel
    when some camera sees its centre in front of its pixel's :func:`front_depth` (no margin).

    Args:
        occupancy: [nx, ny, nz] per-voxel opacity in [0, 1], its uint8 codes, or bool (opaque voxels).
        origin: [3] world centre of voxel [0, 0, 0].
        voxel_size: voxel edge, world units.
        cameras: n cameras (their lens models are used: rays and projection agree).
        occluder_depth: optional n depth maps [h_i, w_i] of surfaces the grid does not hold (e.g.
            outside its box); each pixel's surface is the nearer of the two.
        chunk: voxels per block edge (bounds the memory).
    Returns:
        observed [nx, ny, nz] bool, occupied [nx, ny, nz] bool.
    """
    occupancy = np.asarray(occupancy)
    if occupancy.ndim != 3:
        raise InputError(f"need occupancy [nx, ny, nz], got {occupancy.shape}", field="occupancy")
    codes = occupancy if occupancy.dtype == np.uint8 else uint8_from_unit(occupancy)
    surfaces = camera_surfaces(codes, origin, voxel_size, cameras, occluder_depth)
    occupied = codes >= uint8_from_unit(OCCUPIED_THRESHOLD)
    occupied[tuple(surfaces.voxels.T)] = True
    observed = np.zeros(codes.shape, dtype=bool)
    for sl, centres in voxel_centers(origin, voxel_size, codes.shape, chunk):
        observed[sl] = observed_centres(centres, occupied[sl], voxel_size, surfaces).reshape(occupied[sl].shape)
    return observed, occupied
