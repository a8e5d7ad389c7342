"""Depth for a capture without a depth sensor, from its room's layout: the floor, wall and ceiling
pixels of the training views get the distance to their plane (:mod:`scenelabel.geometry.layout`),
and the build trains on it as it would on sensor depth (``data.layout_depth``, docs/captures.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from scenelabel.data.scene import Scene
from scenelabel.geometry.layout import MIN_ON_WALLS, RoomLayout, depth_from_layout, layout_class_ids, room_layout

__all__ = ["DEPTH_SOURCE_KEY", "LAYOUT_KEY", "LAYOUT_SOURCE", "MIN_LAYOUT_SHARE", "layout_summary", "with_layout_depth"]

DEPTH_SOURCE_KEY = "depth_source"
"""``Scene.info`` key naming where ``sensor_depths`` came from when no sensor measured them."""

LAYOUT_SOURCE = "room layout from the masks"
"""``info[DEPTH_SOURCE_KEY]`` of depth from the room's layout."""

LAYOUT_KEY = "layout"
"""``Scene.info`` key of the layout's one-line summary and the share of training pixels it covers."""

MIN_LAYOUT_SHARE = 0.05
"""The layout is used only when its depth covers at least this share of the training pixels."""


def layout_summary(layout: RoomLayout) -> str:
    """One line: the planes found (heights along ``up``)."""
    parts = [f"floor at {layout.floor:.3f}"]
    if layout.ceiling is not None:
        parts.append(f"ceiling at {layout.ceiling:.3f}")
    parts.append(f"{len(layout.walls)} walls")
    return ", ".join(parts) + f" (up {np.round(layout.up, 3).tolist()})"


def with_layout_depth(scene: Scene, train: list[int]) -> tuple[Scene, RoomLayout | None]:
    """``scene`` with the depth of its room layout, found from the masks of the ``train`` views
    alone, as ``sensor_depths`` of those views (NaN on pixels of other classes; held-out views have
    none), ``info[DEPTH_SOURCE_KEY]`` saying so and ``info[LAYOUT_KEY]`` summing the layout up.

    Unchanged (layout None) when the scene has sensor depth, its classes name no floor and wall,
    the masks show no floor-wall boundary, the layout puts less than
    :data:`~scenelabel.geometry.layout.MIN_ON_WALLS` of the boundaries on its walls (the room is
    not what it says), or its depth covers less than MIN_LAYOUT_SHARE of the training pixels.
    """
    ids = layout_class_ids(scene.classes)
    if scene.sensor_depths is not None or "floor" not in ids or "wall" not in ids:
        return scene, None
    cameras = scene.cameras[train]
    layout = room_layout(cameras, [scene.labels[i] for i in train], ids)
    if layout is None or layout.on_walls < MIN_ON_WALLS:
        return scene, None
    depths: list[np.ndarray | None] = [None] * len(scene)
    covered = total = 0
    for n, i in enumerate(train):
        if scene.labels[i] is None:
            continue
        depth = depth_from_layout(layout, cameras, n, scene.labels[i], ids).astype(np.float32)
        depths[i] = depth
        covered += int(np.isfinite(depth).sum())
        total += depth.size
    if total == 0 or covered < MIN_LAYOUT_SHARE * total:
        return scene, None
    summary = f"{layout_summary(layout)}; {100.0 * covered / total:.0f} % of training pixels"
    info = {**scene.info, DEPTH_SOURCE_KEY: LAYOUT_SOURCE, LAYOUT_KEY: summary}
    return dataclasses.replace(scene, sensor_depths=depths, info=info), layout
