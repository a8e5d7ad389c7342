"""Depth for a capture without a depth sensor, from its room's layout: the floor, wall and ceiling
pixels of the training views get the distance to their plane (:mod:`scenelabel.geometry.layout`),
and the build trains on it as it would on sensor depth (``data.layout_depth``, docs/captures.md).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.ndimage import binary_erosion

from scenelabel.data.scene import Scene
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.layout import (
    MIN_NEAR_WALLS,
    WALL_BAND,
    RoomLayout,
    layout_class_ids,
    mounted_class_ids,
    room_layout,
)
from scenelabel.geometry.rays import rays_from_cameras

__all__ = [
    "DEPTH_SOURCE_KEY",
    "FILL_MARGIN",
    "LAYOUT_KEY",
    "LAYOUT_SOURCE",
    "MIN_LAYOUT_SHARE",
    "depth_from_layout",
    "layout_summary",
    "with_layout_depth",
]

DEPTH_SOURCE_KEY = "depth_source"
"""``Scene.info`` key naming where ``sensor_depths`` came from when no sensor measured them."""

LAYOUT_SOURCE = "room layout from the masks"
"""``info[DEPTH_SOURCE_KEY]`` of depth from the room's layout."""

LAYOUT_KEY = "layout"
"""``Scene.info`` key of the layout's one-line summary and the share of training pixels it covers."""

FILL_MARGIN = 4
"""With sensor depth, the layout fills no hole within this many pixels of a pixel of another class:
a sensor's holes at depth edges are there because a furniture edge's depth is uncertain (a
quarter-resolution depth image's hole is 4 colour pixels wide), and the masks' edges are the
least sure too; filling them with the wall behind would carve the furniture's edge."""

MIN_LAYOUT_SHARE = 0.05
"""The layout is used only when its depth covers at least this share of the training pixels."""


def layout_summary(layout: RoomLayout) -> str:
    """One line: the planes found (heights along ``up``)."""
    parts = [f"floor at {layout.floor:.3f}"]
    if layout.ceiling is not None:
        parts.append(f"ceiling at {layout.ceiling:.3f}")
    parts.append(f"{len(layout.walls)} walls")
    return ", ".join(parts) + f" (up {np.round(layout.up, 3).tolist()})"


def depth_from_layout(
    layout: RoomLayout,
    cameras: Cameras,
    index: int,
    label: np.ndarray,
    class_ids: Mapping[str, int],
    mounted: Sequence[int] = (),
) -> np.ndarray:
    """[H, W] distance along each pixel's unit ray to the layout plane of its class: the floor or
    ceiling plane for pixels labelled so, the nearest wall it meets within a wall's extent (and
    between floor and ceiling) for wall pixels and those of the ``mounted`` classes; NaN for other
    pixels and where no plane is met in front of the camera.

    Args:
        layout: the room's layout (:func:`~scenelabel.geometry.layout.room_layout`).
        cameras, index: the view's camera.
        label: [H, W] its class ids.
        class_ids: :func:`~scenelabel.geometry.layout.layout_class_ids`.
        mounted: ids of classes that hang on walls (:func:`~scenelabel.geometry.layout.mounted_class_ids`).
    """
    label = np.asarray(label)
    origins, directions = rays_from_cameras(cameras, index)
    flat = label.reshape(-1)
    depth = np.full(len(flat), np.nan)
    o_h, d_h = origins @ layout.up, directions @ layout.up
    for kind, height in (("floor", layout.floor), ("ceiling", layout.ceiling)):
        if kind in class_ids and height is not None:
            m = flat == class_ids[kind]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (height - o_h[m]) / d_h[m]
            depth[m] = np.where(np.isfinite(t) & (t > 0), t, np.nan)
    if "wall" in class_ids and layout.walls:
        m = np.nonzero(np.isin(flat, [class_ids["wall"], *mounted]))[0]
        o2, d2 = origins[m] @ layout.basis.T, directions[m] @ layout.basis.T
        low = -np.inf if layout.floor is None else layout.floor - WALL_BAND
        high = np.inf if layout.ceiling is None else layout.ceiling + WALL_BAND
        nearest = np.full(len(m), np.inf)
        for wall in layout.walls:
            with np.errstate(divide="ignore", invalid="ignore"):  # rays along a wall: t inf, no hit
                t = (wall.offset - o2[:, wall.axis]) / d2[:, wall.axis]
                along = o2[:, 1 - wall.axis] + d2[:, 1 - wall.axis] * t
                height = o_h[m] + d_h[m] * t
                hit = (np.isfinite(t) & (t > 0) & (along >= wall.extent[0]) & (along <= wall.extent[1])
                       & (height >= low) & (height <= high))
            nearest = np.where(hit & (t < nearest), t, nearest)
        depth[m] = np.where(np.isfinite(nearest), nearest, np.nan)
    return depth.reshape(label.shape)


def with_layout_depth(scene: Scene, train: list[int], mounted: bool = True) -> tuple[Scene, RoomLayout | None]:
    """``scene`` with the depth of its room layout, found from the masks of the ``train`` views
    alone, on the floor, wall and ceiling pixels of those views (held-out views get none), and with
    ``mounted`` on the pixels of classes that hang on walls (``data.layout_mounted``, a build's default).

    Without sensor depth the layout's depth becomes ``sensor_depths`` (NaN on pixels of other
    classes), ``info[DEPTH_SOURCE_KEY]`` says so and ``info[LAYOUT_KEY]`` sums the layout up. With
    sensor depth it fills the holes the sensor's range left: NaN pixels whose layout depth lies
    beyond the farthest depth the sensor gave in that view (a training view without any depth: all
    of them), at least FILL_MARGIN pixels from any other class, so that a far wall a phone's LiDAR
    does not reach still has a surface; ``info[LAYOUT_KEY]`` then says how much it filled. Holes
    within the sensor's reach (dark surfaces, edges) stay holes: filling those too made one room's
    build collapse in two runs of three (docs/captures.md).

    Unchanged (layout None) when its classes name no floor and wall, the masks show no floor-wall
    boundary, the layout puts less than :data:`~scenelabel.geometry.layout.MIN_NEAR_WALLS` of the
    boundaries within a pixel's reach of its walls (the room is not what it says), or it would give
    depth to less than MIN_LAYOUT_SHARE of the training pixels (with sensor depth: none). The
    layout takes the training photos' straight lines for its vertical (``room_layout``'s images).
    """
    ids = layout_class_ids(scene.classes)
    if "floor" not in ids or "wall" not in ids:
        return scene, None
    cameras = scene.cameras[train]
    layout = room_layout(cameras, [scene.labels[i] for i in train], ids, [scene.images[i] for i in train])
    if layout is None or layout.near_walls < MIN_NEAR_WALLS:
        return scene, None
    on_walls = mounted_class_ids(scene.classes) if mounted else []
    sensor = scene.sensor_depths
    depths: list[np.ndarray | None] = [None] * len(scene) if sensor is None else list(sensor)
    filled = covered = total = 0
    for n, i in enumerate(train):
        if scene.labels[i] is None:
            continue
        depth = depth_from_layout(layout, cameras, n, scene.labels[i], ids, on_walls).astype(np.float32)
        total += depth.size
        if sensor is None:
            depths[i] = depth
        else:  # a view the sensor missed is all holes, beyond no reach
            measured = np.full(depth.shape, np.nan, np.float32) if sensor[i] is None else sensor[i]
            reach = float(np.nanmax(measured)) if np.isfinite(measured).any() else 0.0
            fill = np.isnan(measured) & (depth > reach) & binary_erosion(np.isfinite(depth), iterations=FILL_MARGIN, border_value=1)
            depths[i] = np.where(fill, depth, measured).astype(measured.dtype)
            filled += int(fill.sum())
        covered += int(np.isfinite(depths[i]).sum())
    if sensor is None:
        if total == 0 or covered < MIN_LAYOUT_SHARE * total:
            return scene, None
        summary = f"{layout_summary(layout)}; {100.0 * covered / total:.0f} % of training pixels"
        info = {**scene.info, DEPTH_SOURCE_KEY: LAYOUT_SOURCE, LAYOUT_KEY: summary}
    else:
        if filled == 0:
            return scene, None
        summary = (f"{layout_summary(layout)}; fills {100.0 * filled / total:.1f} % of training pixels "
                   f"where the sensor gave no depth ({100.0 * covered / total:.0f} % now have depth)")
        info = {**scene.info, LAYOUT_KEY: summary}
    return dataclasses.replace(scene, sensor_depths=depths, info=info), layout
