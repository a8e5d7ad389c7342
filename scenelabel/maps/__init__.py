"""Semantic occupancy maps, numpy in and out (no torch or OpenCV; numba only once a ray is cast or
the visibility rule applied): the :class:`OccupancyMap` container, its zarr store, rays through it,
its pyramid. This is the package's public face; the code lives in its modules:

- :mod:`scenelabel.maps.occupancy_map`: :class:`OccupancyMap` (the conventions, in its docstring);
- :mod:`scenelabel.maps.codes`: label codes (FREE, UNKNOWN), format constants, uint8 quantisation;
- :mod:`scenelabel.maps.raycast`: rays through voxel grids (their compiled loops:
  :mod:`scenelabel.maps.raycast_kernels`, imported on first use); :mod:`scenelabel.maps.pyramid`: pooling;
- :mod:`scenelabel.maps.schema`, :mod:`scenelabel.maps.zarr_io`: the store's attributes and zarr pieces;
- :mod:`scenelabel.maps.validation`: checks of a map's fields on construction;
- :mod:`scenelabel.maps.visibility` (observed space; its compiled loop:
  :mod:`scenelabel.maps.visibility_kernels`) and :mod:`scenelabel.maps.exports` (PLY,
  meshes, floor plans), imported on their own;
- the lattice helpers (:func:`lattice`, :func:`voxel_centers`, ...) are
  :mod:`scenelabel.geometry.lattice`'s, re-exported here.

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

from scenelabel.geometry.boxes import ray_box_distances
from scenelabel.geometry.lattice import (
    DEFAULT_CHUNKS,
    block_centers,
    index_from_world,
    iter_chunks,
    lattice,
    voxel_centers,
    world_from_grid_matrix,
    world_from_index,
)
from scenelabel.maps.codes import (
    CONFIDENCE_ARRAY,
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
    MAX_CLASS_ID,
    MAX_LEVELS,
    MIN_COARSE_EDGE,
    NGFF_METRE_UNITS,
    NGFF_VERSION_V2,
    NGFF_VERSION_V3,
    OCCUPANCY_ARRAY,
    OCCUPANCY_DTYPE,
    OCCUPANCY_ENCODING,
    OCCUPIED_THRESHOLD,
    PROBS_ARRAY,
    PROBS_DIMENSION_NAMES,
    PYRAMID_FACTOR,
    QUANTISATION_STEPS,
    QUANTISED_DTYPE,
    SCHEMA_FILE,
    UNKNOWN,
    UNKNOWN_RULES,
    UNKNOWN_WORD,
    confidence_from_probs,
    uint8_from_unit,
    unit_from_uint8,
)
from scenelabel.maps.occupancy_map import (
    OccupancyMap,
)
from scenelabel.maps.pyramid import (
    LABEL_POOLING_RULE,
    default_levels,
    pool_block,
    pool_labels,
    pool_occupancy,
    pool_probs,
)
from scenelabel.maps.raycast import (
    MapRayQuery,
    first_voxel_hits,
    transmittance_crossings,
)
from scenelabel.maps.schema import (
    load_schema,
    validate_attributes,
)
from scenelabel.maps.zarr_io import (
    array_chunks,
    ngff_multiscales,
)

__all__ = [
    "FREE",
    "UNKNOWN",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "INDEX_ORDER",
    "DEFAULT_CHUNKS",
    "OCCUPIED_THRESHOLD",
    "OccupancyMap",
    "lattice",
    "iter_chunks",
    "voxel_centers",
    "block_centers",
    "index_from_world",
    "world_from_index",
    "ray_box_distances",
    "first_voxel_hits",
    "transmittance_crossings",
    "MapRayQuery",
    "validate_attributes",
    "load_schema",
    "OCCUPANCY_ENCODING",
    "UNKNOWN_RULES",
    "uint8_from_unit",
    "unit_from_uint8",
    "confidence_from_probs",
    "world_from_grid_matrix",
    "pool_probs",
    "pool_labels",
    "pool_occupancy",
    "pool_block",
    "array_chunks",
    "default_levels",
    "ngff_multiscales",
    "DIMENSION_NAMES",
    "DEFAULT_UNITS",
    "DEFAULT_SCALE_SOURCE",
    "DEFAULT_FRAME_ID",
    "LABEL_ARRAY",
    "OCCUPANCY_ARRAY",
    "PROBS_ARRAY",
    "CONFIDENCE_ARRAY",
    "ESDF_ARRAY",
    "ESDF_DTYPE",
    "ESDF_UNKNOWN",
    "LEVELS_GROUP",
    "LABEL_DTYPE",
    "OCCUPANCY_DTYPE",
    "QUANTISED_DTYPE",
    "QUANTISATION_STEPS",
    "PROBS_DIMENSION_NAMES",
    "UNKNOWN_WORD",
    "FREE_WORD",
    "DEFAULT_UNKNOWN_RULE",
    "NGFF_VERSION_V2",
    "NGFF_VERSION_V3",
    "NGFF_METRE_UNITS",
    "PYRAMID_FACTOR",
    "MIN_COARSE_EDGE",
    "MAX_LEVELS",
    "MAX_CLASS_ID",
    "SCHEMA_FILE",
    "LABEL_POOLING_RULE",
]
