"""A height band of a map flattened to a 2D occupancy grid and label image (:func:`floor_plan`),
written as a ROS ``map_server`` / Nav2 map (PGM + YAML) plus a colour PNG (:func:`write_nav2`).

Floor plan rules (the conservative ones a planner needs: unknown space is never reported free):

- a cell is **occupied** when any voxel of its column inside the band has a class; its label is
  the class of the **highest** such voxel (what a top-down view sees);
- a cell is **free** only when every voxel of its column inside the band is FREE;
- otherwise (no class, at least one UNKNOWN voxel) it is **unknown**.

The band holds the voxel layers whose centre z lies in ``[z_min, z_max]`` (see :func:`height_band`
for the defaults: from one voxel above the floor's top to below the ceiling, or the map's top).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scenelabel._files import atomic_write_bytes
from scenelabel.errors import InputError
from scenelabel.geometry.lattice import index_from_world
from scenelabel.maps.codes import FREE, UNKNOWN
from scenelabel.maps.exports.palette import class_palette, color_lookup
from scenelabel.maps.occupancy_map import OccupancyMap

__all__ = [
    "NAV2_OCCUPIED",
    "NAV2_FREE",
    "NAV2_UNKNOWN",
    "NAV2_OCCUPIED_THRESH",
    "NAV2_FREE_THRESH",
    "FREE_RGB",
    "UNKNOWN_RGB",
    "FLOOR_NAMES",
    "CEILING_NAMES",
    "DENSE_LAYER_FRACTION",
    "FloorPlan",
    "height_band",
    "layers_in_band",
    "floor_plan_from_grid",
    "floor_plan",
    "image_from_plan",
    "nav2_pixels_from_plan",
    "colors_from_plan",
    "write_nav2",
]

NAV2_OCCUPIED = 0
"""PGM value of an occupied cell (ROS map_server trinary convention, negate 0)."""
NAV2_FREE = 254
"""PGM value of a free cell."""
NAV2_UNKNOWN = 205
"""PGM value of an unknown cell."""
NAV2_OCCUPIED_THRESH = 0.65
NAV2_FREE_THRESH = 0.196

FREE_RGB = (NAV2_FREE,) * 3
"""Colour of free cells in label images (the PGM's free grey)."""
UNKNOWN_RGB = (NAV2_UNKNOWN,) * 3
"""Colour of unknown cells in label images (the PGM's unknown grey)."""
FLOOR_NAMES = ("floor", "ground")
CEILING_NAMES = ("ceiling",)
# A layer belongs to the floor (ceiling) slab when it holds at least this fraction of the voxels
# of the class's fullest layer: a few stray voxels above the floor do not lift it.
DENSE_LAYER_FRACTION = 0.5


# --------------------------------------------------------------------------------------------
# Floor plan
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FloorPlan:
    """A height band of a map flattened to 2D (rules in the module docstring).

    Attributes:
        label: [nx, ny] int16 indexed [i, j] along world x, y: class id of the highest occupied
            voxel of the column in the band, FREE (-1) or UNKNOWN (-2).
        origin: [2] float64 world (x, y) of the centre of cell [0, 0] (the map's origin[:2]).
        voxel_size: cell edge, world units.
        z_min, z_max: the height band, world z; it holds voxel layers ``k_lo <= k < k_hi``.
        k_lo, k_hi: the voxel layers flattened.
        classes: class id -> name.
        class_colors: class id -> (r, g, b) 0-255, or None.
        frame_id: name of the world frame.
        units, scale_source: the map's length unit and where its scale comes from.
    """

    label: np.ndarray
    origin: np.ndarray
    voxel_size: float
    z_min: float
    z_max: float
    k_lo: int
    k_hi: int
    classes: dict[int, str]
    class_colors: dict[int, tuple[int, int, int]] | None = None
    frame_id: str = "world"
    units: str = "input"
    scale_source: str = "input"

    @property
    def occupied(self) -> np.ndarray:
        """[nx, ny] bool."""
        return self.label >= 0

    @property
    def free(self) -> np.ndarray:
        """[nx, ny] bool."""
        return self.label == FREE

    @property
    def unknown(self) -> np.ndarray:
        """[nx, ny] bool."""
        return self.label == UNKNOWN

    @property
    def origin_corner(self) -> np.ndarray:
        """[2] world (x, y) of the min corner of cell [0, 0] (= origin - voxel_size / 2)."""
        return self.origin - self.voxel_size / 2.0

    def index_from_world(self, xy: Any) -> tuple[np.ndarray, np.ndarray]:
        """Cell [i, j] containing each world point: ``floor((xy - origin) / voxel_size + 0.5)``.

        Args:
            xy: [N, 2] world (x, y).
        Returns:
            ij [N, 2] int64 (unclipped), inside [N] bool.
        """
        xy = np.asarray(xy, np.float64)
        if xy.shape[-1:] != (2,):
            raise InputError(f"xy must have shape [..., 2], got {xy.shape}", field="xy")
        xyz = np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1)  # the plan as a one-layer grid
        ijk, inside = index_from_world(xyz, [*self.origin.tolist(), 0.0], self.voxel_size, (*self.label.shape, 1))
        return ijk[..., :2], inside


def _dense_layer(counts: np.ndarray, highest: bool) -> int:
    """The highest (or lowest) layer holding at least DENSE_LAYER_FRACTION of the fullest layer.

    Args:
        counts: [nz] voxels of a class per layer (not all zero).
    """
    dense = np.flatnonzero(counts >= DENSE_LAYER_FRACTION * counts.max())
    return int(dense.max() if highest else dense.min())


def _class_layer_counts(label: np.ndarray, classes: Mapping[int, str], names: tuple[str, ...]) -> np.ndarray | None:
    """[nz] voxels per layer of the classes named ``names`` (case-insensitive); None if none."""
    ids = [cid for cid, name in classes.items() if name.strip().lower() in names]
    if not ids:
        return None
    counts = np.isin(label, ids).sum(axis=(0, 1))
    return counts if counts.any() else None


def height_band(
    occ_map: OccupancyMap,
    z_min: float | None = None,
    z_max: float | None = None,
    robot_height: float | None = None,
) -> tuple[float, float]:
    """The height band (world z) that :func:`floor_plan` flattens, with its defaults.

    The floor's top layer: the highest layer holding at least half as many voxels of a class named
    ``floor`` (or ``ground``) as its fullest layer; without such a class, the lowest layer with any
    occupied voxel. Defaults:

    - ``z_min`` = top face of the floor's top layer + one voxel (one voxel of clearance absorbs
      floor noise); the bottom of the map when nothing is occupied.
    - ``z_max`` = floor top + ``robot_height`` when given; else, with a class named ``ceiling``,
      the bottom face of the ceiling's lowest dense layer - one voxel; else the top of the map.

    Args:
        occ_map: the map.
        z_min, z_max: explicit band limits (world z), overriding the defaults.
        robot_height: height of the robot above the floor's top, world units (> 0).
    Returns:
        (z_min, z_max), world z.
    Raises:
        InputError: z_min >= z_max, or robot_height <= 0.
    """
    label, vs = occ_map.label, occ_map.voxel_size
    z0 = float(occ_map.origin[2])  # centre z of layer 0
    bottom, top = float(occ_map.bounds[0][2]), float(occ_map.bounds[1][2])
    floor_counts = _class_layer_counts(label, occ_map.classes, FLOOR_NAMES)
    if floor_counts is not None:
        floor_k: int | None = _dense_layer(floor_counts, highest=True)
    else:
        occupied_layers = np.flatnonzero((label >= 0).any(axis=(0, 1)))
        floor_k = int(occupied_layers[0]) if len(occupied_layers) else None
    floor_top = bottom if floor_k is None else z0 + vs * (floor_k + 0.5)
    if z_min is None:
        z_min = bottom if floor_k is None else floor_top + vs
    if z_max is None:
        if robot_height is not None:
            if not (np.isfinite(robot_height) and robot_height > 0):
                raise InputError(f"robot_height must be a number > 0, got {robot_height}", field="robot_height")
            z_max = floor_top + float(robot_height)
        else:
            ceiling_counts = _class_layer_counts(label, occ_map.classes, CEILING_NAMES)
            if ceiling_counts is not None:
                z_max = z0 + vs * (_dense_layer(ceiling_counts, highest=False) - 0.5) - vs
            else:
                z_max = top
    z_min, z_max = float(z_min), float(z_max)
    if not (np.isfinite(z_min) and np.isfinite(z_max) and z_min < z_max):
        raise InputError(f"the height band needs z_min < z_max, got [{z_min:g}, {z_max:g}]", field="z_min")
    return z_min, z_max


def layers_in_band(origin_z: float, voxel_size: float, nz: int, z_min: float, z_max: float) -> tuple[int, int]:
    """Voxel layers whose centre z (``origin_z + voxel_size * k``) lies in ``[z_min, z_max]``.

    Returns:
        (k_lo, k_hi): layers ``k_lo <= k < k_hi``.
    Raises:
        InputError: no layer of the grid lies in the band.
    """
    k = np.arange(nz)
    z = origin_z + voxel_size * k
    inside = k[(z >= z_min) & (z <= z_max)]
    if len(inside) == 0:
        raise InputError(
            f"the height band [{z_min:g}, {z_max:g}] holds no voxel layer of the map "
            f"(layer centres from {z[0]:g} to {z[-1]:g})",
            field="z_min",
        )
    return int(inside[0]), int(inside[-1]) + 1


def floor_plan_from_grid(label: np.ndarray) -> np.ndarray:
    """Flatten a band of a label grid along z (rules in the module docstring).

    Args:
        label: [nx, ny, nb] int class id >= 0, FREE (-1), UNKNOWN (-2): the band's layers.
    Returns:
        [nx, ny] int16: the class of the highest voxel with a class in the column; else FREE when
        every voxel is FREE; else UNKNOWN.
    """
    label = np.asarray(label)
    if label.ndim != 3 or label.shape[2] == 0:
        raise InputError(f"label must be [nx, ny, nb] with nb >= 1, got shape {label.shape}", field="label")
    has_class = label >= 0  # [nx, ny, nb]
    highest = label.shape[2] - 1 - np.argmax(has_class[:, :, ::-1], axis=2)  # [nx, ny]
    top_class = np.take_along_axis(label, highest[:, :, None], axis=2)[:, :, 0]
    all_free = np.all(label == FREE, axis=2)
    out = np.where(has_class.any(axis=2), top_class, np.where(all_free, FREE, UNKNOWN))
    return out.astype(np.int16)


def floor_plan(
    occ_map: OccupancyMap,
    z_min: float | None = None,
    z_max: float | None = None,
    robot_height: float | None = None,
) -> FloorPlan:
    """A height band of the map flattened to a 2D occupancy grid with labels.

    Args:
        occ_map: the map.
        z_min, z_max, robot_height: the band, see :func:`height_band` (defaults there).
    Returns:
        FloorPlan on the map's x-y lattice (cell [i, j] = column [i, j, :] of the map).
    """
    z_min, z_max = height_band(occ_map, z_min, z_max, robot_height)
    k_lo, k_hi = layers_in_band(float(occ_map.origin[2]), occ_map.voxel_size, occ_map.shape[2], z_min, z_max)
    return FloorPlan(
        label=floor_plan_from_grid(occ_map.label[:, :, k_lo:k_hi]),
        origin=occ_map.origin[:2].copy(),
        voxel_size=occ_map.voxel_size,
        z_min=z_min,
        z_max=z_max,
        k_lo=k_lo,
        k_hi=k_hi,
        classes=dict(occ_map.classes),
        class_colors=occ_map.class_colors,
        frame_id=occ_map.frame_id,
        units=occ_map.units,
        scale_source=occ_map.scale_source,
    )


# --------------------------------------------------------------------------------------------
# Nav2 / map_server
# --------------------------------------------------------------------------------------------


def image_from_plan(grid: np.ndarray) -> np.ndarray:
    """A plan's [nx, ny, ...] array as an image [ny, nx, ...]: row 0 = max y, column 0 = min x.

    Pixel (row r, column c) shows cell [i, j] = [c, ny - 1 - r]: the image is the map seen from
    above (+z) with x to the right and y up, as ROS map_server draws it.
    """
    grid = np.asarray(grid)
    return np.ascontiguousarray(np.swapaxes(grid, 0, 1)[::-1])


def nav2_pixels_from_plan(plan_label: np.ndarray) -> np.ndarray:
    """PGM values of a plan: [nx, ny] label codes -> [ny, nx] uint8 image (:func:`image_from_plan`).

    Occupied (class >= 0) -> 0, FREE -> 254, UNKNOWN -> 205 (map_server trinary, negate 0).
    """
    plan_label = np.asarray(plan_label)
    values = np.where(plan_label >= 0, NAV2_OCCUPIED, np.where(plan_label == FREE, NAV2_FREE, NAV2_UNKNOWN))
    return image_from_plan(values.astype(np.uint8))


def colors_from_plan(plan: FloorPlan) -> np.ndarray:
    """Colour image of a plan's labels: [ny, nx, 3] uint8, oriented as :func:`image_from_plan`.

    Occupied cells get their class colour (:func:`class_palette`), free cells FREE_RGB and unknown
    cells UNKNOWN_RGB (the PGM's greys).
    """
    palette = class_palette(plan.classes, plan.class_colors)
    rgb = np.empty(plan.label.shape + (3,), np.uint8)  # [nx, ny, 3]
    rgb[...] = UNKNOWN_RGB
    rgb[plan.free] = FREE_RGB
    occupied = plan.occupied
    rgb[occupied] = color_lookup(palette, plan.label[occupied])
    return image_from_plan(rgb)


def _nav2_yaml(image_name: str, plan: FloorPlan) -> str:
    x, y = plan.origin_corner.tolist()
    return "\n".join(
        [
            (
                f"# scenelabel floor plan: frame {plan.frame_id!r}, voxel layers {plan.k_lo}..{plan.k_hi - 1} "
                f"(z band [{plan.z_min:.6g}, {plan.z_max:.6g}])"
            ),
            "# origin: world (x, y, yaw) of the lower-left corner of the lower-left pixel; row 0 of the image is max y",
            f"# units: {plan.units} (scale: {plan.scale_source})",
            f"image: {image_name}",
            "mode: trinary",
            f"resolution: {plan.voxel_size!r}",
            f"origin: [{x!r}, {y!r}, 0.0]",
            "negate: 0",
            f"occupied_thresh: {NAV2_OCCUPIED_THRESH}",
            f"free_thresh: {NAV2_FREE_THRESH}",
            "",
        ]
    )


def write_nav2(
    occ_map: OccupancyMap,
    path_stem: str | Path,
    z_min: float | None = None,
    z_max: float | None = None,
    robot_height: float | None = None,
) -> dict[str, Path]:
    """Write the floor plan as a ROS map_server / Nav2 map plus a colour label image.

    Files (see docs/formats.md, "Exports"):

    - ``<stem>.pgm``: binary PGM (P5), nx x ny pixels, 0 occupied, 254 free, 205 unknown; row 0 =
      max y, column 0 = min x (:func:`image_from_plan`).
    - ``<stem>.yaml``: ``image`` (the PGM's file name), ``mode: trinary``, ``resolution`` (the
      voxel size), ``origin: [x, y, 0.0]`` = world position of the lower-left **corner** of the
      lower-left pixel (cell [0, 0]), ``negate: 0``, ``occupied_thresh: 0.65``,
      ``free_thresh: 0.196``.
    - ``<stem>_labels.png``: RGB, same size and orientation, class colours on occupied cells.

    Args:
        occ_map: the map.
        path_stem: output path without suffix (a trailing .yaml or .pgm is dropped).
        z_min, z_max, robot_height: the band, see :func:`height_band`.
    Returns:
        {"pgm": path, "yaml": path, "labels": path}.
    """
    from PIL import Image

    stem = Path(path_stem).expanduser()
    if stem.suffix.lower() in (".yaml", ".yml", ".pgm"):
        stem = stem.with_suffix("")
    if not stem.parent.is_dir():
        raise InputError("the parent folder does not exist", path=stem.parent)
    plan = floor_plan(occ_map, z_min, z_max, robot_height)
    pixels = nav2_pixels_from_plan(plan.label)  # [ny, nx]
    paths = {
        "pgm": stem.with_name(stem.name + ".pgm"),
        "yaml": stem.with_name(stem.name + ".yaml"),
        "labels": stem.with_name(stem.name + "_labels.png"),
    }
    height, width = pixels.shape
    atomic_write_bytes(paths["pgm"], f"P5\n{width} {height}\n255\n".encode("ascii") + pixels.tobytes())
    png = io.BytesIO()
    Image.fromarray(colors_from_plan(plan)).save(png, format="PNG")
    atomic_write_bytes(paths["labels"], png.getvalue())
    # the YAML names the PGM and is what map servers load: written last
    atomic_write_bytes(paths["yaml"], _nav2_yaml(paths["pgm"].name, plan).encode("utf-8"))
    return paths
