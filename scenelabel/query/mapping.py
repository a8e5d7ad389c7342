"""From a field to a map: the lattice, the evaluation of a block of it, the visibility rule's
inputs and its application, and the map's metadata — in one place, used by
:meth:`SemanticField.occupancy_map <scenelabel.query.field.SemanticField.occupancy_map>` (the whole map in
memory) and :func:`scenelabel.query.map_writer.write_occupancy_map` (chunk by chunk into zarr). The
rule itself: docs/conventions.md, "Density and occupancy" and "Observed space".
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.maps import (
    FREE,
    UNKNOWN,
    OccupancyMap,
    block_centers,
    confidence_from_probs,
    iter_chunks,
    lattice,
    ray_box_distances,
    uint8_from_unit,
)
from scenelabel.maps.visibility import DEPTH_MAP_WIDTH, observed_voxels, scaled_cameras
from scenelabel.query.answers import OCCUPIED_THRESHOLD, checked_array, inside_bounds, softmax64

if TYPE_CHECKING:
    from scenelabel.query.field import SemanticField

__all__ = [
    "MAX_MAP_VOXELS",
    "MAX_SUBSAMPLES",
    "REFINE_OCCUPANCY",
    "occupancy_map",
    "map_lattice",
    "evaluate_map_block",
    "subsample_offsets",
    "densest_subsample",
    "map_visibility_inputs",
    "occluders_outside",
    "map_metadata",
    "mark_surfaces",
    "clear_unseen",
]

MAX_MAP_VOXELS = 256**3 * 4
"""occupancy_map refuses grids larger than this (67M voxels) unless told otherwise: a map held
whole, then written with ``to_zarr``, peaks at several times the memory of writing it chunk by
chunk (docs/map_export.md measures both); ask for a larger voxel size, or write the map chunk by
chunk (:func:`scenelabel.query.map_writer.write_occupancy_map`)."""

MAX_SUBSAMPLES = 4
"""At most this many sub-samples per voxel axis when evaluating a map."""

REFINE_OCCUPANCY = 0.25
"""A map voxel is read at its sub-samples only where its centre or a neighbour's centre has at
least this occupancy (:func:`evaluate_map_block`), half the threshold 0.5: the field varies over
its finest cell, about a voxel, so a surface between two centres raises theirs. It was 0.1 (a
fifth of the threshold); docs/map_ab.md measures the change (with the density-only sub-samples of
:func:`densest_subsample`) on five suite rooms: the same surface, free-space and F-score figures,
1.2-1.4x faster."""


OBSERVED_MAP_PAD = 0.03
"""A map's default box reaches this fraction of the observed geometry's longest side past it on
every face (:func:`map_lattice`): the surface voxels at its extremes and a margin. The modelled
bounds reach 10 % past (``data.bounds_pad``), which training needs (a tighter box left
hall-10x6's walls half transparent: docs/suite_pad.md); the map need not cover that space, most
of it behind the walls and UNKNOWN. docs/map_ab_observed.md, six suite rooms, each build mapped
whole and cut: the same surface, free-space and F-score figures, UNKNOWN voxels 38-56 % -> 10-22 %,
maps 1.1-1.7x faster."""


def occupancy_map(
    field: "SemanticField",
    voxel_size: float | None = None,
    bounds=None,
    chunk: int = 32,
    visibility: bool = True,
    max_voxels: int = MAX_MAP_VOXELS,
) -> OccupancyMap:
    """The whole map of ``field`` in memory: :meth:`SemanticField.occupancy_map` (the rule and the
    other arguments are documented there); ``max_voxels``: refuse larger lattices (InputError)."""
    voxel_size, origin, shape = map_lattice(field, voxel_size, bounds, max_voxels)
    label = np.full(shape, UNKNOWN, dtype=np.int16)
    occupancy = np.zeros(shape, dtype=np.float32)
    probs = np.zeros((*shape, field.class_map.num_classes), dtype=np.uint8)
    confidence = np.zeros(shape, dtype=np.uint8)
    for sl in iter_chunks(shape, chunk):
        label[sl], occupancy[sl], probs[sl], confidence[sl] = evaluate_map_block(field, origin, voxel_size, sl)
    inputs = map_visibility_inputs(field, origin, voxel_size, shape) if visibility else None
    if inputs is not None:
        cameras, occluders = inputs
        observed, occupied = observed_voxels(occupancy, origin, voxel_size, cameras, occluders, chunk)  # [nx, ny, nz]
        mark_surfaces((label, occupancy, probs), occupied & (label == FREE), field.class_map.ids)
        clear_unseen((label, occupancy, probs, confidence), ~observed & (label != UNKNOWN))
    return OccupancyMap(
        label=label,
        occupancy=occupancy,
        voxel_size=voxel_size,
        origin=origin,
        probs=probs,
        confidence=confidence,
        **map_metadata(field, voxel_size, "visibility" if inputs is not None else "bounds"),
    )


def map_lattice(
    field: "SemanticField", voxel_size: float | None = None, bounds=None, max_voxels: int = MAX_MAP_VOXELS
) -> tuple[float, np.ndarray, tuple[int, int, int]]:
    """The voxel lattice of a map (:func:`scenelabel.maps.lattice` over ``bounds``).

    Args:
        voxel_size: voxel edge in world units (default: :meth:`SemanticField.default_voxel_size`).
        bounds: (2, 3) world box to cover. Default: the modelled bounds' lattice, cut to the
            voxels that meet the observed geometry's extent (``observed_bounds``, where the build
            found its bounds from observed points) padded by OBSERVED_MAP_PAD of its longest side:
            the same voxels as the whole lattice's, without the space beyond the room's walls.
        max_voxels: refuse (InputError) a lattice of more voxels than this.
    Returns:
        voxel_size (float), origin [3] (world centre of voxel [0, 0, 0]), shape (nx, ny, nz).
    """
    voxel_size = field.default_voxel_size() if voxel_size is None else float(voxel_size)
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be a positive number, got {voxel_size}", field="voxel_size")
    box, within, observed = field.aabb, None, field.observed_bounds
    if bounds is not None:
        box = checked_array(bounds, "bounds", 3)
    elif observed is not None:
        pad = OBSERVED_MAP_PAD * float((observed[1] - observed[0]).max())
        within = (observed[0] - pad, observed[1] + pad)
    origin, shape = lattice(box[0], box[1], voxel_size, max_voxels, within)
    return voxel_size, origin, shape


def evaluate_map_block(
    field: "SemanticField", origin: np.ndarray, voxel_size: float, block: tuple[slice, slice, slice]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate one block of a map's lattice (the rule of :func:`occupancy_map`, before the
    visibility rule): label, occupancy, probs and confidence of its voxels.

    Coarse to fine: the field is first read at the voxel centres of the block and a one-voxel
    halo around it; a voxel is then read at its n³ sub-samples (:func:`subsample_offsets`) only
    where its centre or a neighbour's (26-neighbourhood) has occupancy >= REFINE_OCCUPANCY and
    not all 27 of those centres are occupied (>= OCCUPIED_THRESHOLD), and keeps its centre's
    reading elsewhere. Sub-samples find the surfaces that pass between centres; a voxel enclosed
    by occupied centres lies inside a solid, its centre already reads occupied, and most such
    voxels end UNKNOWN behind the surface (docs/map_ab_enclosed.md: on four suite rooms the same
    surface, free-space and F-score figures; the hall's map 1.12x faster, the smaller rooms'
    within the run's noise). The halo makes a block's answer independent of how the lattice is
    split into blocks.

    Args:
        origin: [3] world centre of voxel [0, 0, 0] of the lattice.
        voxel_size: voxel edge, world units.
        block: (slice_i, slice_j, slice_k) with explicit start and stop (:func:`iter_chunks`).
    Returns:
        label [bi, bj, bk] int16 (class id, FREE, or UNKNOWN outside the modelled bounds),
        occupancy [bi, bj, bk] float32, probs [bi, bj, bk, C] uint8, confidence [bi, bj, bk]
        uint8 (0 where UNKNOWN).
    """
    offsets = subsample_offsets(field, voxel_size)  # [S, 3]
    n_classes = field.class_map.num_classes
    shape = tuple(s.stop - s.start for s in block)
    centres = block_centers(origin, voxel_size, block)  # [V, 3]
    inside = inside_bounds(centres, field.aabb)  # [V]
    if len(offsets) == 1:
        sig_n, logits = field.sigmas_and_logits_n(field.frame.to_normalised(centres[inside]))
    else:
        halo = tuple(slice(s.start - 1, s.stop + 1) for s in block)
        halo_centres = block_centers(origin, voxel_size, halo)
        halo_inside = inside_bounds(halo_centres, field.aabb)
        halo_sig = np.zeros(len(halo_centres))
        halo_logits = np.zeros((len(halo_centres), n_classes), dtype=np.float32)
        halo_sig[halo_inside], halo_logits[halo_inside] = field.sigmas_and_logits_n(
            field.frame.to_normalised(halo_centres[halo_inside])
        )
        halo_occ = -np.expm1(-halo_sig * field.frame.scale * voxel_size).reshape(tuple(n + 2 for n in shape))
        core = (slice(1, -1),) * 3
        # (thresholds first: the filters of boolean arrays are the same answer, cheaper)
        near_surface = maximum_filter(halo_occ >= REFINE_OCCUPANCY, size=3, mode="constant")
        enclosed = minimum_filter(halo_occ >= OCCUPIED_THRESHOLD, size=3, mode="constant")
        refine = (near_surface & ~enclosed)[core].reshape(-1)[inside]
        sig_n = halo_sig.reshape(halo_occ.shape)[core].reshape(-1)[inside]  # [K], K voxels inside the bounds
        logits = halo_logits.reshape(*halo_occ.shape, n_classes)[core].reshape(len(centres), n_classes)[inside]
        sig_n[refine], logits[refine] = densest_subsample(field, centres[inside][refine], offsets)
    occ = -np.expm1(-sig_n * field.frame.scale * voxel_size)  # [K]
    p = softmax64(logits)
    label = np.full(len(centres), UNKNOWN, dtype=np.int16)
    occupancy = np.zeros(len(centres), dtype=np.float32)
    probs = np.zeros((len(centres), n_classes), dtype=np.uint8)
    confidence = np.zeros(len(centres), dtype=np.uint8)
    label[inside] = np.where(occ >= OCCUPIED_THRESHOLD, field.class_map.ids_from_channels(p.argmax(-1)), FREE)
    occupancy[inside] = occ
    probs[inside] = uint8_from_unit(p)
    confidence[inside] = uint8_from_unit(confidence_from_probs(p))
    return label.reshape(shape), occupancy.reshape(shape), probs.reshape(*shape, n_classes), confidence.reshape(shape)


def subsample_offsets(field: "SemanticField", voxel_size: float) -> np.ndarray:
    """[n³, 3] world offsets from a voxel's centre of its sub-samples: a regular n x n x n
    pattern, n = ceil(voxel_size / the field's finest cell) clipped to [1, MAX_SUBSAMPLES], so the
    field is read at least once per finest cell (one sample, the centre, when n = 1): a density
    bump is two cells wide at its base, so along each axis some sub-sample lies within half a cell
    of its peak and reads at least half of it."""
    n_sub = int(np.clip(np.ceil(voxel_size / field.finest_cell()), 1, MAX_SUBSAMPLES))
    offsets = (np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n_sub - 0.5
    return offsets * voxel_size


def densest_subsample(
    field: "SemanticField", centres: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """σ (normalised units) [K] and class logits [K, C] of each voxel at its densest sub-sample:
    the density at every sub-sample (:meth:`SemanticField.sigmas_n`, no class work), the class
    logits at the densest one only.

    Args:
        centres: [K, 3] world voxel centres.
        offsets: [S, 3] world sub-sample offsets (:func:`subsample_offsets`).
    """
    pts = centres[:, None, :] + offsets[None]  # [K, S, 3]
    sig_n = field.sigmas_n(field.frame.to_normalised(pts.reshape(-1, 3))).reshape(len(centres), len(offsets))
    rows, densest = np.arange(len(centres)), sig_n.argmax(-1)  # [K] each
    _, logits = field.sigmas_and_logits_n(field.frame.to_normalised(pts[rows, densest]))
    return sig_n[rows, densest], logits


def map_visibility_inputs(
    field: "SemanticField", origin: np.ndarray, voxel_size: float, shape: tuple[int, int, int]
) -> tuple[Cameras, list[np.ndarray] | None] | None:
    """What the visibility rule of a map needs from the field, besides the map itself.

    Args:
        origin: [3] world centre of voxel [0, 0, 0] of the map's lattice.
        voxel_size: voxel edge, world units.
        shape: (nx, ny, nz).
    Returns:
        None when the checkpoint stores no training cameras (the map falls back to the
        "bounds" rule); else the training cameras shrunk to depth-map size
        (:func:`scenelabel.maps.visibility.scaled_cameras`) and, when the lattice does not cover
        the modelled bounds, their depth maps of the field's surfaces outside it
        (:func:`occluders_outside`, n arrays [h_i, w_i]; None when it covers them).
    """
    cameras = field.training_cameras()
    if cameras is None:
        return None
    small = scaled_cameras(cameras, DEPTH_MAP_WIDTH)
    lo = origin - voxel_size / 2.0
    hi = lo + voxel_size * np.asarray(shape)
    covers_bounds = bool(np.all(lo <= field.aabb[0]) and np.all(hi >= field.aabb[1]))
    return small, None if covers_bounds else occluders_outside(field, small, lo, hi)


def map_metadata(field: "SemanticField", voxel_size: float, unknown_rule: str) -> dict:
    """The :class:`OccupancyMap` fields of this field's maps other than the arrays, ``origin``
    and ``voxel_size``: classes, colours, frame, threshold, δ, units, ``unknown_rule``."""
    colors = field.meta.get("class_colors") or {}
    return {
        "classes": field.classes,
        "occupancy_delta": voxel_size,
        "class_colors": {i: tuple(colors[i]) for i in field.class_map.ids.tolist() if i in colors} or None,
        "frame_id": field.meta.get("frame_id", "world"),
        "occupancy_threshold": OCCUPIED_THRESHOLD,
        "unknown_rule": unknown_rule,
        **field.scale_record(),
    }


def occluders_outside(field: "SemanticField", cameras: Cameras, lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """The field's surfaces that a map covering only the box [lo, hi] does not hold.

    Per camera, the distance along each pixel ray to where its transmittance through the field
    falls to 0.5 (:meth:`SemanticField.surface_distances_n`) *before the ray enters the box* (surfaces past the box hide
    nothing in it), within the camera's near / far; ``inf`` where there is none.

    Args:
        cameras: n cameras (pinholes, world frame).
        lo, hi: [3] the map's box.
    Returns:
        n arrays [h_i, w_i] float64, world units.
    """
    rays = [rays_from_cameras(cameras, i) for i in range(len(cameras))]  # n x ([h w, 3], [h w, 3])
    counts = [len(o) for o, _ in rays]
    origins = np.concatenate([o for o, _ in rays])  # [R, 3]
    directions = np.concatenate([d for _, d in rays])
    near = np.repeat(np.where(np.isfinite(cameras.near), cameras.near, 0.0), counts)  # [R]
    far = np.repeat(np.where(np.isfinite(cameras.far), cameras.far, np.inf), counts)
    t_enter, t_exit = ray_box_distances(origins, directions, lo, hi)
    far = np.where(t_exit >= np.maximum(t_enter, 0.0), np.minimum(far, t_enter), near)  # a miss: nothing to march
    scale = field.frame.scale
    depth = field.surface_distances_n(field.frame.to_normalised(origins), directions, near * scale, far * scale) / scale
    parts = np.split(depth, np.cumsum(counts)[:-1])
    return [d.reshape(int(h), int(w)) for d, h, w in zip(parts, cameras.height, cameras.width)]


def mark_surfaces(arrays: tuple[np.ndarray, np.ndarray, np.ndarray], surface: np.ndarray, class_ids: np.ndarray) -> None:
    """The visibility rule's surface voxels (a camera's surface lies in them, their occupancy is
    below the threshold), in place: occupied, with the class of their most probable ``probs``
    channel, occupancy raised to OCCUPIED_THRESHOLD (so that a label >= 0 keeps occupancy >= the
    threshold).

    Args:
        arrays: (label, occupancy, probs) of a block, [..] int16, [..] float32, [.., C] uint8.
        surface: [..] bool, the voxels to mark.
        class_ids: [C] external class id of each probs channel.
    """
    label, occupancy, probs = arrays
    label[surface] = np.asarray(class_ids)[probs[surface].argmax(-1)]
    occupancy[surface] = OCCUPIED_THRESHOLD


def clear_unseen(arrays: tuple[np.ndarray, ...], unseen: np.ndarray) -> None:
    """Voxels no training camera observed, in place: label UNKNOWN, every other array 0 there.

    Args:
        arrays: (label, occupancy, probs, confidence) of a block (probs [.., C]).
        unseen: [..] bool.
    """
    label, *others = arrays
    label[unseen] = UNKNOWN
    for values in others:
        values[unseen] = 0
