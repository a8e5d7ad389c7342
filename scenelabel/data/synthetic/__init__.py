"""Analytic scenes with exact labels and depth: the toy two-box scene and a furnished room.

Labelled axis-aligned boxes and per-class textures are rendered by one exact ray caster (no NeRF
involved) into scene folders in the ``transforms.json`` layout (docs/conventions.md).

Modules: ``geometry`` (boxes, scenes, ray casting and shading), ``textures``, ``views`` (cameras,
pixel rays, rendering one view), ``scenes`` (the two scenes, camera paths, writers, label noise) and
``phone_depth`` (phone-like sensor depth for a written scene folder, :func:`add_phone_depth`).
"""

from __future__ import annotations

from scenelabel.data.synthetic.geometry import (
    BACKGROUND_ID,
    Box,
    ClassInfo,
    RayHits,
    SyntheticScene,
    cast_rays,
    shade_hits,
)
from scenelabel.data.synthetic.phone_depth import add_phone_depth
from scenelabel.data.synthetic.scenes import (
    HOLDOUT_EVERY,
    ROOM_BOXES,
    ROOM_CLASSES,
    ROOM_HALF,
    ROOM_HEIGHT,
    TOY_BOXES,
    TOY_CLASSES,
    corrupt_labels,
    furnished_room_geometry,
    room_cameras,
    toy_cameras,
    toy_scene_geometry,
    write_furnished_room,
    write_scene,
    write_toy_scene,
)
from scenelabel.data.synthetic.views import look_at, pixel_rays, render_view

__all__ = [
    "BACKGROUND_ID",
    "HOLDOUT_EVERY",
    "ROOM_BOXES",
    "ROOM_CLASSES",
    "ROOM_HALF",
    "ROOM_HEIGHT",
    "TOY_BOXES",
    "TOY_CLASSES",
    "Box",
    "ClassInfo",
    "RayHits",
    "SyntheticScene",
    "add_phone_depth",
    "cast_rays",
    "corrupt_labels",
    "furnished_room_geometry",
    "look_at",
    "pixel_rays",
    "render_view",
    "room_cameras",
    "shade_hits",
    "toy_cameras",
    "toy_scene_geometry",
    "write_furnished_room",
    "write_scene",
    "write_toy_scene",
]
