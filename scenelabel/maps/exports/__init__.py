"""Exports of a semantic occupancy map for other tools: point cloud, per-class meshes, 2D floor plan.

Pure functions: an :class:`~scenelabel.maps.OccupancyMap` (numpy arrays) in, files out. The file
layouts are documented in docs/formats.md ("Exports"); the conventions in docs/conventions.md.

- :func:`write_point_cloud`: occupied voxel centres as a coloured PLY point cloud with a per-point
  ``label`` (class id) and ``occupancy``.
- :func:`class_meshes`: one marching-cubes surface on the continuous occupancy at the map's
  threshold, each triangle given the class of the nearest labelled voxel, split per class and
  decimated (:func:`decimate`); :func:`write_class_meshes` writes them as PLY (per-vertex colour,
  normal, ``label``), :func:`write_glb` as one GLB (a node and a material per class, Y-up).
  :func:`occupancy_surface`, :func:`face_labels`, :func:`vertex_normals` are the steps;
  :func:`class_surface` the older terraced per-class surface (marching cubes on 0/1 voxels).
- :func:`floor_plan` / :func:`write_nav2`: a height band of the grid flattened to a 2D occupancy
  grid and label image, written as a ROS ``map_server`` / Nav2 map (PGM + YAML) plus a colour PNG.
- :func:`write_octomap`: the grid as an OctoMap file (pyoctomap): ``.bt`` a binary occupancy
  OcTree, ``.ot`` a ColorOcTree with log-odds from the occupancy and class colours; UNKNOWN voxels
  get no node, the tree is pruned. :func:`read_octomap` reads one back.

Which voxels count as occupied: those with a class (``label >= 0``). In the maps scenelabel
writes that is exactly ``occupancy >= occupancy_threshold``; FREE (-1) is known empty space and
UNKNOWN (-2) was never observed or lies outside the modelled bounds.

Modules: :mod:`~scenelabel.maps.exports.ply` (point cloud, the PLY writer),
:mod:`~scenelabel.maps.exports.meshes` (class meshes, PLY), :mod:`~scenelabel.maps.exports.glb` (GLB),
:mod:`~scenelabel.maps.exports.floorplan` (floor plan rules, Nav2), :mod:`~scenelabel.maps.exports.octomap`,
:mod:`~scenelabel.maps.exports.palette` (class colours); their names are re-exported here.
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
from scenelabel.maps.exports.glb import (
    GLB_FORMAT,
    GLTF_FROM_WORLD,
    WORLD_NODE,
    node_names,
    write_glb,
)
from scenelabel.maps.exports.meshes import (
    AGGRESSIVENESS,
    DEFAULT_REDUCTION,
    FLAT_TOLERANCE,
    INSIDE_MARGIN,
    MIN_DECIMATED_FACES,
    ClassMesh,
    class_meshes,
    class_surface,
    decimate,
    face_labels,
    mesh_file_name,
    occupancy_surface,
    vertex_normals,
    write_class_meshes,
)
from scenelabel.maps.exports.octomap import (
    read_octomap,
    write_octomap,
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
    "class_meshes",
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
    "write_glb",
    "ClassMesh",
    "DEFAULT_REDUCTION",
    "MIN_DECIMATED_FACES",
    "AGGRESSIVENESS",
    "FLAT_TOLERANCE",
    "INSIDE_MARGIN",
    "GLTF_FROM_WORLD",
    "GLB_FORMAT",
    "WORLD_NODE",
    "node_names",
    "decimate",
    "face_labels",
    "mesh_file_name",
    "occupancy_surface",
    "vertex_normals",
    "write_nav2",
    "write_octomap",
    "read_octomap",
    "write_ply",
    "write_point_cloud",
    "NAV2_OCCUPIED_THRESH",
    "NAV2_FREE_THRESH",
    "FLOOR_NAMES",
    "CEILING_NAMES",
    "DENSE_LAYER_FRACTION",
]
