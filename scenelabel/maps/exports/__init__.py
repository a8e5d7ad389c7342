"""Exports of a semantic occupancy map for other tools: point cloud, per-class meshes, 2D floor plan.

Pure functions: an :class:`~scenelabel.maps.OccupancyMap` (numpy arrays) in, files out. The file
layouts are documented in docs/formats.md ("Exports"); the conventions in docs/conventions.md.

- :func:`write_point_cloud`: occupied voxel centres as a coloured PLY point cloud with a per-point
  ``label`` (class id) and ``occupancy``.
- :func:`write_class_meshes`: one closed surface mesh per class (marching cubes on the class's
  voxels), PLY with per-vertex colour, normal and ``label``.
- :func:`floor_plan` / :func:`write_nav2`: a height band of the grid flattened to a 2D occupancy
  grid and label image, written as a ROS ``map_server`` / Nav2 map (PGM + YAML) plus a colour PNG.

Which voxels count as occupied: those with a class (``label >= 0``). In the maps scenelabel
writes that is exactly ``occupancy >= occupancy_threshold``; FREE (-1) is known empty space and
UNKNOWN (-2) was never observed or lies outside the modelled bounds.

Modules: :mod:`~scenelabel.maps.exports.ply` (point cloud, the PLY writer),
:mod:`~scenelabel.maps.exports.meshes`, :mod:`~scenelabel.maps.exports.floorplan` (floor plan
rules, Nav2), :mod:`~scenelabel.maps.exports.palette` (class colours); their names are re-exported here.
"""

from __future__ import annotations

from scenelabel.maps.exports.floorplan import (
    CEILING_NAMES,
    DENSE_LAYER_FRACTION,
    FLOOR_NAMES,
    FREE_RGB,
    NAV2_FREE,
    NAV2_FREE_THRESH,
    NAV2_OCCUPIED,
    NAV2_OCCUPIED_THRESH,
    NAV2_UNKNOWN,
    UNKNOWN_RGB,
    FloorPlan,
    colors_from_plan,
    floor_plan,
    floor_plan_from_grid,
    height_band,
    image_from_plan,
    layers_in_band,
    nav2_pixels_from_plan,
    write_nav2,
)
from scenelabel.maps.exports.meshes import (
    class_surface,
    write_class_meshes,
)
from scenelabel.maps.exports.palette import (
    class_palette,
    default_color,
)
from scenelabel.maps.exports.ply import (
    occupied_voxels,
    write_ply,
    write_point_cloud,
)

__all__ = [
    "default_color",
    "FREE_RGB",
    "NAV2_FREE",
    "NAV2_OCCUPIED",
    "NAV2_UNKNOWN",
    "UNKNOWN_RGB",
    "FloorPlan",
    "class_palette",
    "class_surface",
    "colors_from_plan",
    "floor_plan",
    "floor_plan_from_grid",
    "height_band",
    "image_from_plan",
    "layers_in_band",
    "nav2_pixels_from_plan",
    "occupied_voxels",
    "write_class_meshes",
    "write_nav2",
    "write_ply",
    "write_point_cloud",
    "NAV2_OCCUPIED_THRESH",
    "NAV2_FREE_THRESH",
    "FLOOR_NAMES",
    "CEILING_NAMES",
    "DENSE_LAYER_FRACTION",
]
