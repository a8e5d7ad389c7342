"""What a build chooses from the scene before it trains (config and geometry only; the pipeline
calls them): what the preset "auto" becomes, the distortion term's weight, the free-space term's
margin, the rays that ignore the density grid, and how far a box of uniform cells fitted to a
room's layout reaches.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from scenelabel.config import (
    AUTO,
    AUTO_PRESET,
    DISTORTION_AUTO_WEIGHT,
    DISTORTION_THIN_MAX,
    LAYOUT_FREE_MARGIN,
    LAYOUT_OPEN_RAYS,
    SENSOR_FREE_MARGIN,
    BuildConfig,
    with_preset,
)
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.coverage import THIN_VIEWS
from scenelabel.geometry.frame import looking_one_way
from scenelabel.geometry.warps import capture_reference

__all__ = [
    "FORWARD_PRESET",
    "INWARD_PRESET",
    "resolve_preset",
    "resolve_distortion",
    "resolve_free_margin",
    "resolve_open_rays",
    "reaching_cameras",
    "box_warp",
]


FORWARD_PRESET, INWARD_PRESET = "voxels", "fast"
"""What the preset "auto" becomes (:func:`resolve_preset`): a dense grid without a network where the
training cameras are forward-facing and no room layout bounds what they see (docs/real.md: fern),
tri-planes and a small network otherwise (docs/suite_capacity.md: on rooms seen from inside, the
dense grid is far behind in the same time; docs/suite_forward_layout.md: forward-facing rooms)."""


def resolve_preset(config: BuildConfig, cameras: Cameras, room: bool = False) -> tuple[BuildConfig, str | None]:
    """``config`` with the preset "auto" (:data:`scenelabel.config.AUTO_PRESET`) made FORWARD_PRESET where
    the training ``cameras`` are forward-facing (:func:`scenelabel.geometry.warps.capture_reference`)
    and no ``room`` layout bounds what they see, else INWARD_PRESET, with the settings given on top of
    "auto" (:func:`scenelabel.config.with_preset`); any other preset as it is. Forward-facing cameras
    before a room (its layout found from the masks, :mod:`scenelabel.data.layout_depth`) get
    INWARD_PRESET in uniform cells over the box (``sampling.warp`` "box" unless given): the room ends
    at its walls, so the disparity steps of the forward warp (made for scenes that reach far past
    the cameras, as LLFF's) only coarsen its far half (docs/suite_forward_layout.md).

    Returns:
        (the config, why: said before training and saved with the checkpoint as "preset_choice";
        None for a preset given by name).
    """
    if config.preset != AUTO_PRESET:
        return config, None
    forward = capture_reference(cameras) is not None
    why = f"preset {AUTO_PRESET}: the training cameras are {'' if forward else 'not '}forward-facing"
    if not forward:
        return with_preset(config, INWARD_PRESET), why
    if not room:
        return with_preset(config, FORWARD_PRESET), why
    resolved = with_preset(config, INWARD_PRESET)
    if resolved.sampling.warp == AUTO:
        resolved = dataclasses.replace(resolved, sampling=dataclasses.replace(resolved.sampling, warp="box"))
    return resolved, why + ", before a room whose layout the masks give: uniform cells over its box"


def resolve_distortion(config: BuildConfig, thinly_seen: float | None) -> tuple[BuildConfig, dict]:
    """``config`` with ``train.distortion_weight`` a number, and the record of the choice.

    ``"auto"`` becomes DISTORTION_AUTO_WEIGHT when the build measured the observed geometry and at
    most DISTORTION_THIN_MAX of it is seen by fewer than THIN_VIEWS training views
    (``thinly_seen``, :func:`scenelabel.geometry.coverage.thinly_seen_fraction`), else 0: an input that
    gives its bounds (or sensor depth) has no observed geometry measured. A number stays as given.

    Returns:
        (the config, {"weight", "thinly_seen" (None: not measured), "why"}).
    """
    tc = config.train
    if tc.distortion_weight != AUTO:
        weight, why = float(tc.distortion_weight), "as configured"
    elif thinly_seen is None:
        weight, why = 0.0, "off: no observed geometry measured (the input gives its bounds or sensor depth)"
    else:
        on = thinly_seen <= DISTORTION_THIN_MAX
        weight = DISTORTION_AUTO_WEIGHT if on else 0.0
        why = (
            f"{'on' if on else 'off'}: {thinly_seen:.0%} of the observed geometry is seen by fewer than "
            f"{THIN_VIEWS} training views ({'at most' if on else 'more than'} {DISTORTION_THIN_MAX:.0%})"
        )
    resolved = dataclasses.replace(config, train=dataclasses.replace(tc, distortion_weight=weight))
    return resolved, {"weight": weight, "thinly_seen": thinly_seen, "why": why}


def resolve_free_margin(config: BuildConfig, from_layout: bool) -> BuildConfig:
    """``config`` with ``train.free_margin`` a number: ``"auto"`` becomes LAYOUT_FREE_MARGIN where all
    the training depth comes from the room's layout (``from_layout``), else SENSOR_FREE_MARGIN; a number
    stays as given."""
    tc = config.train
    if tc.free_margin != AUTO:
        return config
    margin = LAYOUT_FREE_MARGIN if from_layout else SENSOR_FREE_MARGIN
    return dataclasses.replace(config, train=dataclasses.replace(tc, free_margin=margin))


def resolve_open_rays(config: BuildConfig, cameras: Cameras, from_layout: bool) -> BuildConfig:
    """``config`` with ``sampling.grid_open_rays`` "auto" made LAYOUT_OPEN_RAYS where all the training
    depth comes from the room's layout (``from_layout``) and the training ``cameras`` do not all look
    one way (:func:`scenelabel.geometry.frame.looking_one_way`), else 0; a number stays as given.
    Where it was measured, the suite's rooms seen from inside, the open rays kept the thin objects
    that the density grid had emptied before the field learnt them (docs/suite_open_share.md);
    with a sensor's depth or a forward-facing rig they were not measured."""
    sc = config.sampling
    if sc.grid_open_rays != AUTO:
        return config
    n_open = LAYOUT_OPEN_RAYS if from_layout and not looking_one_way(cameras) else 0
    return dataclasses.replace(config, sampling=dataclasses.replace(sc, grid_open_rays=n_open))


def reaching_cameras(aabb: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``aabb`` [2, 3] grown to hold the camera ``centres`` [n, 3]. Bounds from a room's layout
    (:mod:`scenelabel.data.layout_depth`) see only the floor, wall and ceiling pixels; whatever the
    other pixels show lies between their camera and the layout behind it, so a box of uniform cells
    must reach the cameras. Inside a room that changes nothing; a forward-facing capture's cameras
    stand before the part of the room they see, with furniture nearer than the nearest floor in
    view. (A forward warp keeps the layout's box: its disparity steps start at the box's nearest
    depth, and a box holding the cameras would start them at the cameras, coarsening the far
    half of the room: docs/suite_forward_reach.md.)"""
    return np.stack([np.minimum(aabb[0], centres.min(0)), np.maximum(aabb[1], centres.max(0))])


def box_warp(config: BuildConfig, cameras: Cameras) -> bool:
    """Whether the field will have uniform cells over its box (:func:`scenelabel.geometry.warps.choose_warp`)."""
    warp = config.sampling.warp
    return warp == "box" or (warp == AUTO and capture_reference(cameras) is None)
