"""The class meshes as one GLB (binary glTF 2.0): a node, a mesh and a material per class.

glTF is Y-up (+Y up, +Z forward, metres); scenelabel's maps are in the input's world frame, whose
z axis is up for the floor plan and the synthetic scenes. :func:`write_glb` keeps the vertex
buffers in world coordinates and puts the rotation that turns world +z into glTF +Y
(:data:`GLTF_FROM_WORLD`) on one parent node, ``world``, so viewers show the map upright and a
reader that undoes that node's matrix gets world coordinates back exactly. The file's scene
``extras`` (``scenelabel``) records the rotation, the frame, the units and the class of each node.
trimesh is imported inside :func:`write_glb`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenelabel._version import __version__
from scenelabel.errors import InputError
from scenelabel.maps.exports.meshes import DEFAULT_REDUCTION, ClassMesh, class_meshes
from scenelabel.maps.exports.palette import class_palette
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "GLB_FORMAT",
    "GLTF_FROM_WORLD",
    "WORLD_NODE",
    "node_names",
    "write_glb",
]

GLTF_FROM_WORLD = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""[4, 4] rotation from the Z-up world to glTF's Y-up axes: ``(x, y, z) -> (x, z, -y)`` (-90° about x)."""
WORLD_NODE = "world"
"""Name of the node that carries :data:`GLTF_FROM_WORLD`; the class nodes are its children."""
GLB_FORMAT = "scenelabel.class_meshes"
"""``extras.scenelabel.format`` of the GLBs :func:`write_glb` writes."""


def node_names(classes: dict[int, str]) -> dict[int, str]:
    """Node (and mesh, material) name of each class: its name, or ``class_{id}`` when the name is
    empty, ``world`` or shared with another class.

    Args:
        classes: class id -> name.
    Returns:
        class id -> unique node name.
    """
    names = list(classes.values())
    return {
        cid: name if name and name != WORLD_NODE and names.count(name) == 1 else f"class_{cid}"
        for cid, name in classes.items()
    }


def write_glb(
    occ_map: OccupancyMap,
    path: str | Path,
    reduction: float = DEFAULT_REDUCTION,
    *,
    meshes: dict[int, ClassMesh] | None = None,
    y_up: bool = True,
) -> Path:
    """One GLB of the class meshes (:func:`~scenelabel.maps.exports.class_meshes`).

    Per class that has a mesh: a node named after the class (:func:`node_names`), child of the node
    ``world``, holding a triangle mesh (positions, outward normals; counter-clockwise seen from
    outside, as glTF wants) with one PBR material whose base colour is the class colour
    (:func:`~scenelabel.maps.exports.class_palette`, opaque, not metallic, rough). The mesh's
    ``extras`` hold ``class_id`` and ``class_name``. The node ``world`` carries
    :data:`GLTF_FROM_WORLD` (``y_up``) or the identity; vertex buffers are world coordinates.
    The scene's ``extras.scenelabel``: ``format``, ``version``, ``frame_id``, ``units``,
    ``scale_source``, ``up`` (which world axis is glTF's +Y), ``gltf_from_world`` ([4, 4], row
    major), ``voxel_size``, ``occupancy_threshold``, ``classes`` (node name -> class id).

    Args:
        occ_map: the map.
        path: the ``.glb`` file to write (replaced if present; its folder must exist).
        reduction: see :func:`~scenelabel.maps.exports.decimate`.
        meshes: the class meshes, when already made by ``class_meshes`` (then ``reduction`` is
            unused).
        y_up: rotate world +z to glTF +Y (viewers show the map upright); False keeps world axes.
    Returns:
        the path written.
    Raises:
        InputError: the name does not end in ``.glb``, its folder is missing, or the map has no
            surface (no voxel reaches ``occupancy_threshold``): a GLB needs at least one mesh.
    """
    import trimesh

    path = Path(path).expanduser()
    if path.suffix.lower() != ".glb":
        raise InputError("a GLB file name must end in .glb", path=path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    if meshes is None:
        meshes = class_meshes(occ_map, reduction)
    if not meshes:
        raise InputError(
            f"the map has no surface (no voxel with occupancy >= {occ_map.occupancy_threshold:g}): no mesh to write",
            path=path,
        )
    palette = class_palette(occ_map.classes, occ_map.class_colors)
    names = node_names(occ_map.classes)
    gltf_from_world = GLTF_FROM_WORLD if y_up else np.eye(4)
    scene = trimesh.Scene(base_frame="root")
    scene.graph.update(frame_from="root", frame_to=WORLD_NODE, matrix=gltf_from_world)
    for cid in sorted(meshes):
        vertices, faces, normals = meshes[cid]
        material = trimesh.visual.material.PBRMaterial(
            name=names[cid],
            baseColorFactor=[*palette[cid], 255],
            metallicFactor=0.0,
            roughnessFactor=1.0,
        )
        mesh = trimesh.Trimesh(
            vertices=np.asarray(vertices, np.float64),
            faces=np.asarray(faces, np.int64),
            vertex_normals=np.asarray(normals, np.float64),
            visual=trimesh.visual.TextureVisuals(material=material),
            process=False,
            metadata={"class_id": int(cid), "class_name": occ_map.classes[cid]},
        )
        scene.add_geometry(mesh, node_name=names[cid], geom_name=names[cid], parent_node_name=WORLD_NODE)
    scene.metadata["scenelabel"] = {
        "format": GLB_FORMAT,
        "version": __version__,
        "frame_id": occ_map.frame_id,
        "units": occ_map.units,
        "scale_source": occ_map.scale_source,
        "up": "world +z" if y_up else "world +y (no rotation)",
        "gltf_from_world": gltf_from_world.tolist(),
        "voxel_size": occ_map.voxel_size,
        "occupancy_threshold": occ_map.occupancy_threshold,
        "classes": {names[cid]: int(cid) for cid in sorted(meshes)},
    }
    path.write_bytes(scene.export(file_type="glb", include_normals=True))
    return path
