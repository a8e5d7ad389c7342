"""``build``: a scene folder in; a checkpoint, metrics, renders and an occupancy map out.

Orchestration on top of io, train, semantic_field and maps. Writes into the output folder:

- ``checkpoint.pt``: weights + resolved config + class map + bounds + world transform + training
  cameras (what the maps' unknown rule needs)
- ``config.json``: the resolved config (human-readable copy)
- ``metrics.json``: held-out ``psnr``, ``ssim``, ``miou``, ``depth_error`` + per-view / per-class details
- ``renders/<view>.png``: captioned panels of up to 8 held-out views (:mod:`scenelabel.train.evaluation`)
- ``map.zarr``: the semantic occupancy map
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from scenelabel._cores import share_summary, sharing_cores, update_share
from scenelabel._files import atomic_write_bytes
from scenelabel._version import __version__
from scenelabel.config import (
    AUTO,
    BUILD_SECONDS_WITH_DEPTH,
    BuildConfig,
    config_from_dict,
    config_to_dict,
    preset,
    resolve_for_layout,
    time_budget_with_depth,
)
from scenelabel.data.io import load_scene
from scenelabel.data.layout_depth import DEPTH_SOURCE_KEY, LAYOUT_KEY, LAYOUT_SOURCE, with_layout_depth
from scenelabel.data.scene import SILHOUETTE_ALPHA, ClassMap, Scene
from scenelabel.errors import CheckpointError, InputError, TrainingError, TrainingInterrupted
from scenelabel.fields.checkpoint import CHECKPOINT_NAME, Checkpoint, load_checkpoint, save_checkpoint
from scenelabel.fields.encodings import cubic_plane_vertices
from scenelabel.fields.model import FieldNetwork
from scenelabel.geometry.cameras import cameras_to_dict
from scenelabel.geometry.coverage import shows_whole, thinly_seen_fraction, visual_hull_points
from scenelabel.geometry.depth_scale import scale_from_depth
from scenelabel.geometry.frame import SceneFrame, aabb_from_cameras, observed_extent
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.geometry.warps import choose_warp
from scenelabel.metrics import surface_points_from_depth
from scenelabel.query.build_outputs import MAP_NAME
from scenelabel.query.field import TRAIN_CAMERAS_KEY, SemanticField
from scenelabel.render.sampling import CARVE_MARGIN, DensityGrid, free_cells_from_depth, march
from scenelabel.render.volume import depth_at_transmittance, depth_of_max_weight, weights_from_density
from scenelabel.train.choices import (
    box_warp,
    reaching_cameras,
    resolve_distortion,
    resolve_free_margin,
    resolve_open_rays,
    resolve_preset,
)
from scenelabel.train.distributed import DistContext, broadcast_array, init_from_env, leave
from scenelabel.train.evaluation import evaluate, expected_finish_seconds
from scenelabel.train.rays import rays_for_views
from scenelabel.train.trainer import Trainer

__all__ = [
    "build", "BuildResult", "split_views", "choose_views", "default_voxel_size", "resume_config", "resolve_preset",
]

VOXEL_FOOTPRINT_PIXELS = 2.0
"""The default map voxel spans this many training pixels at the typical viewing distance."""

VOXEL_FINEST_CELLS = 2.0
"""The default map voxel, also the slab of a point's occupancy (``occupancy_delta``), spans at least
this many of the field's finest cells: interpolated over cells of length h, the field's narrowest
density bump is 2h wide, and a thinner slab reads a surface as less opaque than it is
(docs/models.md, the third tri-plane level)."""


@dataclass
class BuildResult:
    field: SemanticField | None  # None on data-parallel ranks other than 0 (they write nothing)
    metrics: dict
    out_dir: Path


def split_views(n_views: int, holdout: int) -> tuple[list[int], list[int]]:
    """(train, test) indices: every ``holdout``-th view (0, h, 2h, ...) is held out; 0 = none.

    Raises InputError when fewer than one training view would remain.
    """
    if n_views < 2:
        raise InputError(f"a scene needs at least 2 views, got {n_views}")
    test = [i for i in range(n_views) if holdout and i % holdout == 0]
    train = [i for i in range(n_views) if i not in set(test)]
    if not train:
        raise InputError(f"holdout {holdout} leaves no training view among {n_views}")
    return train, test


def choose_views(scene: Scene, holdout: int) -> tuple[list[int], list[int], str]:
    """(train, test) view indices of a build and the rule that chose them (the checkpoint's ``split``).

    The input's own splits (``scene.splits``, e.g. transforms_train / _val / _test.json) when it has
    them: train on ``train``, hold out ``test``, or ``val`` when the test split is empty
    (``holdout`` is not used); else every ``holdout``-th view (:func:`split_views`).

    Raises InputError when no training view would remain, or fewer than 2 views in all.
    """
    if scene.splits is None:
        train, test = split_views(len(scene), holdout)
        if not holdout:
            return train, test, "train.holdout = 0: none held out"
        return train, test, f"train.holdout = {holdout}: views 0, {holdout}, {2 * holdout}, ... held out"
    if len(scene) < 2:
        raise InputError(f"a scene needs at least 2 views, got {len(scene)}")
    train = list(scene.splits.get("train", []))
    if not train:
        raise InputError("the input's train split is empty: no training view")
    held_out = "test" if scene.splits.get("test") else "val"
    test = list(scene.splits.get(held_out, []))
    return train, test, f"input files: train, {held_out} held out" if test else "input files: train, none held out"


def default_voxel_size(scene: Scene, train: list[int], aabb: np.ndarray, finest_cell: float) -> float:
    """What the images can resolve: VOXEL_FOOTPRINT_PIXELS pixels at the median distance from the
    training cameras to the scene centre, and never finer than VOXEL_FINEST_CELLS of the field's
    finest cells (what the field can hold)."""
    cams = scene.cameras[train]
    dist = np.linalg.norm(cams.centres - 0.5 * (aabb[0] + aabb[1]), axis=-1)
    footprint = np.median(dist / np.sqrt(cams.fx * cams.fy))
    return float(max(VOXEL_FOOTPRINT_PIXELS * footprint, VOXEL_FINEST_CELLS * finest_cell))


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _finest_cell(config: BuildConfig, aabb: np.ndarray, cube_extent: tuple[float, float, float]) -> float:
    """World length of the encoding's finest cell along the scene box's longest side (the warp's
    cube sides ``cube_extent`` shape tri-planes of cubic cells)."""
    fc = config.field
    cells = {
        "triplane": max(fc.resolutions) - 1,
        "dense": fc.grid_resolution - 1,
        "positional": 2**fc.pe_frequencies - 1,  # half a period of the highest frequency, in cells
    }[fc.encoding]
    if fc.encoding == "triplane" and fc.plane_cells == "cubic":
        cells = cubic_plane_vertices(max(fc.resolutions), cube_extent)[int(np.argmax(cube_extent))] - 1
    return float((aabb[1] - aabb[0]).max() / cells)


def _class_colors(scene: Scene) -> dict[int, list[int]]:
    colors = scene.info.get("class_colors") or {}
    return {int(k): [int(c) for c in v] for k, v in colors.items()}


def _resume(trainer: Trainer, ckpt_path: Path, static: dict) -> None:
    """Load a previous checkpoint of the same scene and config into ``trainer``."""
    ckpt = load_checkpoint(ckpt_path)
    for key in ("class_map", "aabb_world", "train_views"):
        if ckpt.meta.get(key) != json.loads(json.dumps(static[key])):  # as the checkpoint's JSON holds it
            raise CheckpointError(f"{ckpt_path}: cannot resume: the checkpoint's {key} differs from this scene's")
    for key in ("distortion", "preset_choice"):  # why the first run chose its weight and its preset
        static[key] = ckpt.meta.get(key, static[key])
    trainer.load_state_dict(ckpt.training_state())


def resume_config(out_dir: str | Path, steps: int | None = None, time_budget: float | None = None) -> BuildConfig:
    """The config saved with the checkpoint in ``out_dir``, with an optional new step count or budget
    (a step count alone lifts the saved budget)."""
    config = config_from_dict(load_checkpoint(out_dir).meta["config"])
    if steps is not None:
        config.train.steps = steps
        config.train.time_budget = None
    if time_budget is not None:
        config.train.time_budget = time_budget
    return config


def _class_map(scene: Scene, train_idx: list[int]) -> ClassMap:
    """Channels for the classes in the training masks; one "unlabelled" channel when there are none."""
    if all(scene.labels[i] is None for i in train_idx):
        warnings.warn(
            "no labels in the training views: building geometry and colour only (every surface is class 0, "
            "'unlabelled'); write labels/ with `scenelabel segment` for semantics",
            stacklevel=3,
        )
        return ClassMap.unlabelled()
    return ClassMap.from_labels([scene.labels[i] for i in train_idx], scene.classes, scene.ignore_index)


BOUNDS_PRESET = "voxels"
"""The coarse field fitted to find a scene's bounds when its input gives none (:func:`observed_points`):
a direct grid (no network) places surfaces within a hundred steps, where the network presets
still leave fog in front of far walls."""

BOUNDS_OVERRIDES = {
    "field": {"grid_resolution": 64},
    "sampling": {"n_steps": 64},
    "train": {"steps": 100, "batch_rays": 2048},
}
"""The coarse field: a 64-cell grid marched in 64 steps, 100 steps of 2048 rays (about 6 s on 2
CPU cores for a 40-view room at 160x120)."""

BOUNDS_RAYS = 20000
"""Training rays whose ends (where the coarse field is opaque) are the observed points."""


def _trainer(
    scene: Scene, train_idx: list[int], class_map: ClassMap, aabb: np.ndarray, config: BuildConfig,
    device: torch.device, context: DistContext = DistContext(),
) -> tuple[Trainer, SceneFrame, torch.Tensor]:
    """A trainer for a field over ``aabb`` (world): its frame, warp, model, density grid and rays."""
    frame = SceneFrame.from_aabb(aabb)
    aabb_n = torch.as_tensor(frame.to_normalised(aabb), dtype=torch.float32)
    warp = choose_warp(config.sampling.warp, scene.cameras[train_idx], frame, aabb_n)
    model = FieldNetwork(config.field, class_map.num_classes, aabb_n, warp)
    hierarchical = config.sampling.strategy == "hierarchical"  # NeRF's coarse network: the same architecture
    coarse = FieldNetwork(config.field, class_map.num_classes, aabb_n, warp) if hierarchical else None
    sc = config.sampling
    grid = DensityGrid.for_march(warp, aabb_n, sc.grid_resolution, sc.n_steps, sc.alpha_threshold)
    rays = rays_for_views(scene, train_idx, frame, class_map, aabb_n)
    if rays.depth is not None and sc.depth_carve and config.train.depth_weight > 0 and warp.spacing == "uniform":
        cell = float((aabb_n[1] - aabb_n[0]).min()) / sc.grid_resolution
        generator = torch.Generator().manual_seed(config.train.seed)  # every data-parallel rank carves alike
        grid.carve(free_cells_from_depth(
            warp, sc.grid_resolution, rays.origins, rays.directions, rays.t_min, rays.t_max, rays.depth, cell, generator
        ))
        if sc.depth_ray_end > 0:  # a measured ray ends a little past its surface: behind it is never seen
            end = rays.depth * (1.0 + CARVE_MARGIN) + sc.depth_ray_end * cell
            rays.t_stop = torch.where(torch.isfinite(rays.depth), torch.minimum(rays.t_max, end), rays.t_max)
    return Trainer(model, grid, rays, config, device, context, coarse), frame, aabb_n


def observed_points(
    scene: Scene, train_idx: list[int], class_map: ClassMap, config: BuildConfig, device: torch.device, progress: bool = False
) -> np.ndarray:
    """Where the training rays end in a short coarse fit: the geometry the cameras observe.

    A BOUNDS_PRESET field with BOUNDS_OVERRIDES (and ``config``'s warp, background and seed) is
    trained over the camera frusta (:func:`scenelabel.geometry.frame.aabb_from_cameras`); then
    BOUNDS_RAYS random training rays are marched through it; each ray that gets at least half
    opaque gives one point, at the farther of where its transmittance falls to 0.5
    (:func:`scenelabel.render.volume.depth_at_transmittance`, the surface as the maps define it) and
    its largest weight (:func:`scenelabel.render.volume.depth_of_max_weight`): a young field's fog in
    front of a far wall moves the first (and the expected depth) short of the wall, and a faint
    wall behind fog moves the second. Rays whose image shows them meeting nothing (alpha below 0.5:
    an RGBA image's background, a FREE label) are not marched. For inputs without near/far or a box
    (a nerfstudio transforms.json never carries them), whose frusta reach far past the scene.

    Returns:
        [k, 3] world points.
    """
    tc = config.train
    coarse_config = preset(
        BOUNDS_PRESET,
        {
            "field": BOUNDS_OVERRIDES["field"],
            "sampling": {**BOUNDS_OVERRIDES["sampling"], "warp": config.sampling.warp},
            "train": {**BOUNDS_OVERRIDES["train"], "seed": tc.seed, "background": tc.background, "holdout": tc.holdout},
        },
    )
    frusta, _ = aabb_from_cameras(scene.cameras)
    trainer, frame, _ = _trainer(scene, train_idx, class_map, frusta, coarse_config, device)
    if progress:
        print(
            f"bounds: the input has no near/far or aabb: fitting them to what the cameras see ({coarse_config.train.steps} coarse steps)",
            file=sys.stderr,
        )
    trainer.run(progress=progress)
    generator = torch.Generator().manual_seed(tc.seed)
    pool = trainer.ray_pool
    if trainer.rays.alpha is not None:  # a ray its image shows meeting nothing (alpha, FREE) observes nothing
        seen = pool[trainer.rays.alpha[pool] >= SILHOUETTE_ALPHA]
        pool = seen if len(seen) else pool
    pick = pool[torch.randint(len(pool), (BOUNDS_RAYS,), generator=generator).to(device)]
    o, d, model = trainer.rays.origins[pick], trainer.rays.directions[pick], trainer.model
    with torch.no_grad():
        t_min, t_max = model.warp.clip(o, d, trainer.rays.t_min[pick], trainer.rays.t_max[pick])
        t_starts, t_ends = march(model.warp.spacing, t_min, t_max, trainer.marching.step, trainer.marching.n_samples)
        points = o[:, None] + 0.5 * (t_starts + t_ends)[..., None] * d[:, None]
        sigmas = model.density(points.reshape(-1, 3)).reshape(t_starts.shape) * trainer.grid(points)
        median = depth_at_transmittance(sigmas, t_starts, t_ends)
        mode = depth_of_max_weight(weights_from_density(sigmas, t_ends - t_starts)[0], t_starts, t_ends)
        depth = torch.maximum(median, mode)  # inf where the ray never gets half opaque
    hit = torch.isfinite(depth)
    return frame.to_world((o[hit] + depth[hit, None] * d[hit]).cpu().numpy())


SCALE_TOLERANCE = 0.03
"""Poses whose scale, measured against the sensor depth (:func:`scaled_to_sensor_depth`), is within
this fraction of the depth's are taken as metric already (a phone's ARKit poses): left unchanged."""


def scaled_to_sensor_depth(scene: Scene, progress: bool = False) -> Scene:
    """The scene in the sensor depth's unit (metres): camera centres, near/far, scoring depths and box
    multiplied by :func:`scenelabel.geometry.depth_scale.scale_from_depth` (the sensor depths stay),
    recorded as ``info["world_scale"]`` like ``--scale`` and ``info["scale_source"]``. Unchanged when
    the poses already agree with the depth (SCALE_TOLERANCE) or the views cannot tell (cameras that
    only rotate; a warning says so)."""
    factor = scale_from_depth(scene.cameras, scene.sensor_depths)
    if factor is None:
        warnings.warn(
            "the sensor depth cannot tell the poses' scale (too little camera motion or overlap): "
            "the poses' unit is kept; give --scale if it is not metres",
            UserWarning,
            stacklevel=2,
        )
        return scene
    if abs(math.log(factor)) <= math.log1p(SCALE_TOLERANCE):
        return scene
    if progress:
        print(f"scale: the poses are {factor:.4g} x the sensor depth's unit: scaled to metres", file=sys.stderr)
    scaled = scene.scaled(factor)
    return dataclasses.replace(
        scaled, sensor_depths=scene.sensor_depths, info={**scaled.info, "scale_source": "sensor depth"}
    )


SENSOR_POINTS = 200_000
"""At most this many back-projected sensor-depth pixels bound a scene (:func:`sensor_depth_points`)."""


def sensor_depth_points(scene: Scene, train_idx: list[int], seed: int = 0) -> np.ndarray | None:
    """The training views' sensor depths back-projected (at most SENSOR_POINTS, a seeded random
    subset): the geometry the cameras observe, measured, so no coarse fit is needed for the bounds.

    Returns:
        [k, 3] world points, or None when no training view has sensor depth.
    """
    if scene.sensor_depths is None or all(scene.sensor_depths[i] is None for i in train_idx):
        return None
    points = []
    for i in train_idx:
        depth = scene.sensor_depths[i]
        if depth is not None:
            origins, directions = rays_from_cameras(scene.cameras, i)
            points.append(surface_points_from_depth(origins, directions, depth.reshape(-1)))
    points = np.concatenate(points)
    if len(points) > SENSOR_POINTS:
        points = points[np.random.default_rng(seed).choice(len(points), SENSOR_POINTS, replace=False)]
    return points


def silhouette_points(scene: Scene, train_idx: list[int]) -> np.ndarray | None:
    """An object capture's bounds without a coarse fit: where every training view has a silhouette
    (:meth:`Scene.silhouettes`: the images' alpha or FREE labels) that shows its object whole
    (:func:`scenelabel.geometry.coverage.shows_whole`), their visual hull in the camera frusta
    (:func:`scenelabel.geometry.coverage.visual_hull_points`).

    Returns:
        [k, 3] world points, or None (not every view shows an object whole, or nothing is left).
    """
    masks = scene.silhouettes(train_idx)
    if not all(m is not None and shows_whole(m) for m in masks):
        return None
    frusta, _ = aabb_from_cameras(scene.cameras)
    return visual_hull_points(scene.cameras[train_idx], masks, frusta)


def prepare_training(
    scene: Scene, config: BuildConfig, device: torch.device, context: DistContext = DistContext(), progress: bool = False
) -> tuple[Trainer, dict, list[int]]:
    """A loaded scene -> its trainer (field, grid, rays), the checkpoint's fixed record and the held-out views.

    Seeds every random generator with ``config.train.seed`` first, so every data-parallel rank
    starts from the same field. Bounds: the input's box; else, where the input has no near/far,
    the observed geometry: sensor depth (:func:`sensor_depth_points`), else the silhouettes' hull
    (:func:`silhouette_points`), else a coarse fit (:func:`observed_points`), bounded by
    :func:`scenelabel.geometry.frame.aabb_from_cameras`; else the camera frusta over near/far.
    Data-parallel ranks take rank 0's bounds.
    """
    _seed_everything(config.train.seed)

    train_idx, test_idx, split_rule = choose_views(scene, config.train.holdout)
    train_cameras = scene.cameras[train_idx]
    class_map = _class_map(scene, train_idx)
    points, seen_by, thinly_seen = None, scene.info.get(DEPTH_SOURCE_KEY, "sensor depth"), None
    if scene.aabb is None and not np.all(np.isfinite(scene.cameras.far)):
        points = sensor_depth_points(scene, train_idx)
        if points is None:  # no training view has sensor depth: the silhouettes' hull, else a coarse fit
            points, seen_by = silhouette_points(scene, train_idx), "silhouettes (visual hull)"
            if points is None:
                points = observed_points(scene, train_idx, class_map, config, device, progress and context.is_main)
                seen_by = "observed geometry"
            thinly_seen = thinly_seen_fraction(train_cameras, points)
            if context.distributed:  # every rank trains with rank 0's choice
                thinly_seen = float(broadcast_array(np.array([thinly_seen]), device)[0])
            _seed_everything(config.train.seed)  # the field starts as it would with given bounds
    config, distortion = resolve_distortion(config, thinly_seen)
    from_layout = scene.info.get(DEPTH_SOURCE_KEY) == LAYOUT_SOURCE
    config = resolve_free_margin(config, from_layout)
    config = resolve_open_rays(config, train_cameras, from_layout)
    aabb, aabb_source = aabb_from_cameras(scene.cameras, scene.aabb, points, seen_by, config.data.bounds_pad)
    if points is not None and seen_by == LAYOUT_SOURCE and box_warp(config, train_cameras):
        reached = reaching_cameras(aabb, train_cameras.centres)
        if not np.array_equal(reached, aabb):
            aabb, aabb_source = reached, aabb_source + ", reaching the cameras"
    if context.distributed:
        aabb = broadcast_array(aabb, device)
    trainer, frame, aabb_n = _trainer(scene, train_idx, class_map, aabb, config, device, context)
    config = trainer.config  # with what the trainer resolved (sampling.grid_decay): the checkpoint saves it
    finest = _finest_cell(config, aabb, trainer.model.warp.cube_extent())
    # what the training views saw lies between their cameras and the points (a room's layout holds no
    # furniture: before a forward rig, the furniture nearer than the nearest floor in view); in the box,
    # between the points and the cameras clamped to it
    seen_from = np.clip(train_cameras.centres, aabb[0], aabb[1])
    observed = None if points is None else observed_extent(np.concatenate([points, seen_from]), aabb)
    static = {
        "config": config_to_dict(config),
        "class_map": class_map.to_dict(),
        "classes": {str(k): v for k, v in scene.classes.items()},
        "class_colors": _class_colors(scene),
        "frame": frame.to_dict(),
        "aabb_world": aabb.tolist(),
        "aabb_source": aabb_source,
        # the observed space's extent: a map's default box (scenelabel.query.mapping.map_lattice)
        "observed_bounds": None if observed is None else observed.tolist(),
        "aabb_internal": aabb_n.tolist(),
        "warp": trainer.model.warp.to_dict(),
        "frame_id": scene.frame_id,
        "world_scale": float(scene.info.get("world_scale", 1.0)),
        "finest_cell": finest,
        "default_voxel_size": default_voxel_size(scene, train_idx, aabb, finest),
        "train_views": [scene.names[i] for i in train_idx],
        "test_views": [scene.names[i] for i in test_idx],
        "split": split_rule,
        "distortion": distortion,
        "carved_by_depth": float(trainer.grid.carved.float().mean()),  # grid cells sensor depth showed empty
        TRAIN_CAMERAS_KEY: cameras_to_dict(train_cameras),  # world frame, for the maps' unknown rule
        "scene_info": {k: v for k, v in scene.info.items() if k != "class_colors"},
    }
    return trainer, static, test_idx


NO_DEPTH_HINT = (
    "no sensor depth: the geometry comes from the photos alone, so surfaces come out soft and the map misses "
    "part of them (docs/depth_suite.md, its `-` rows); depth from an RGB-D camera or a phone's LiDAR makes "
    "them solid (docs/captures.md)"
)
"""Said before training when the training rays carry no sensor depth."""


def _plan_time_budget(trainer: Trainer, static: dict, setup_seconds: float, finish_seconds: float) -> None:
    """``train.time_budget`` "auto" with sensor depth: what a build of BUILD_SECONDS_WITH_DEPTH leaves
    after ``setup_seconds`` and the ``finish_seconds`` expected after training
    (:func:`scenelabel.config.time_budget_with_depth`), into the trainer's config and the
    checkpoint's record (``static``: "config", and "time_plan" with the figures)."""
    budget = time_budget_with_depth(setup_seconds, finish_seconds)
    budget = float(broadcast_array(np.array([budget]), trainer.device)[0])  # every rank stops with rank 0
    trainer.config = dataclasses.replace(trainer.config, train=dataclasses.replace(trainer.config.train, time_budget=budget))
    static["config"] = config_to_dict(trainer.config)
    static["time_plan"] = {
        "build_seconds": BUILD_SECONDS_WITH_DEPTH,
        "setup_seconds": setup_seconds,
        "finish_seconds": finish_seconds,
        "train_seconds": budget,
    }


def _training_plan(config: BuildConfig, static: dict) -> str:
    """One line said before training: the bounds, and how long training will take at most."""
    tc = config.train
    limit = f"{tc.steps} steps" if tc.time_budget is None else f"at most {tc.steps} steps or {tc.time_budget:.3g} s, whichever comes first"
    if "time_plan" in static:
        plan = static["time_plan"]
        limit += f" (a build of {plan['build_seconds']:g} s less {plan['setup_seconds']:.3g} s of setup and {plan['finish_seconds']:.3g} s expected after training)"
    aabb = np.asarray(static["aabb_world"])
    size = " x ".join(f"{x:.3g}" for x in aabb[1] - aabb[0])
    distortion = static["distortion"]
    choice = f", {static['preset_choice']}" if static["preset_choice"] else ""
    return (
        f"bounds {size} ({static['aabb_source']}); training ({config.preset}{choice}): {limit}; "
        f"distortion term {distortion['weight']:g} ({distortion['why']}); {share_summary()}"
    )


def _training_metrics(trainer: Trainer) -> dict:
    """What a rank knows after training: steps, time, rate, and the data-parallel layout."""
    state, context = trainer.state, trainer.dist
    return {
        "scenelabel_version": __version__,
        "preset": trainer.config.preset,
        "steps": state.step,
        "train_seconds": state.elapsed,
        "steps_per_second": state.step / max(state.elapsed, 1e-9),
        # each time the run diverged and resumed from an earlier state (scenelabel.train.divergence)
        "rollbacks": trainer.guard.rollbacks,
        # (fraction, seconds) from which the schedules followed the clock: the budget was going to end the run (train.schedule)
        "budget_anchor": trainer.schedule.anchor,
        "world_size": context.world_size,
        "rank": context.rank,
        "rays_per_step": context.world_size * trainer.batch_rays,
    }


@sharing_cores()
def build(
    scene_path: str | Path | Scene,
    out_dir: str | Path | None = None,
    config: BuildConfig | None = None,
    progress: bool = True,
    device: str | None = None,
    resume: bool = False,
) -> BuildResult:
    """Train a semantic field on a scene folder and write checkpoint, metrics, renders and map.

    Args:
        scene_path: a scene folder (see docs/formats.md), a video file, or an already loaded Scene.
        out_dir: output folder (default: <scene>/scenelabel; for ``clip.mp4``, ``clip/scenelabel``).
        config: the config (default: the preset "auto"; :func:`resolve_preset` chooses for it).
        progress: show a progress bar.
        device: 'cpu', 'cuda' or None (CUDA when available).
        resume: continue from the checkpoint in ``out_dir`` (same scene; pass its config, see
            :func:`resume_config`). Checkpoints are written atomically every
            ``train.checkpoint_every`` steps, at the end, and on Ctrl-C.
    Under ``torchrun`` (``WORLD_SIZE`` > 1) every process trains the same field data-parallel
    (:mod:`scenelabel.train.distributed`); rank 0 alone writes the checkpoint, evaluates, and writes
    metrics, renders and map; the other ranks return after training.
    While it runs, the build shares the cores with the other scenelabel jobs on the machine
    (:func:`scenelabel._cores.sharing_cores`).

    Returns:
        BuildResult with the loaded SemanticField and the metrics (other ranks: no field, and
        only the training figures).
    """
    started = time.perf_counter()  # a build with depth plans its training time from here
    config = config or preset()
    if isinstance(scene_path, Scene):
        scene = scene_path
    else:  # a video input chooses its frames by config.data.video_* (scenelabel.data.video)
        d = config.data
        scene = load_scene(scene_path, d.downscale, d.video_frames_per_second, d.video_max_frames, progress=progress)
    if config.data.scale is not None:
        scene = scene.scaled(config.data.scale)
    elif scene.sensor_depths is not None:
        scene = scaled_to_sensor_depth(scene, progress)
    train_views = choose_views(scene, config.train.holdout)[0]
    layout, sensed = None, scene.sensor_depths is not None
    if config.data.layout_depth:  # the room's layout: the depth of a capture without, the holes of one with
        scene, layout = with_layout_depth(scene, train_views, config.data.layout_mounted)
        if layout is not None and progress:
            print(f"layout: {scene.info.get(DEPTH_SOURCE_KEY, 'sensor depth')}: {scene.info[LAYOUT_KEY]}", file=sys.stderr)
    config, preset_choice = resolve_preset(config, scene.cameras[train_views], room=layout is not None)
    if layout is not None and not sensed:  # the layout is the only depth: the settings of resolve_for_layout
        config = resolve_for_layout(config)
    out_dir = Path(out_dir) if out_dir is not None else Path(scene.root) / "scenelabel"
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create the output folder: {err.strerror or err}", path=out_dir) from None
    if not os.access(out_dir, os.W_OK):
        raise InputError("the output folder is not writable", path=out_dir)
    dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    context, dev = init_from_env(dev)
    ckpt_path = out_dir / CHECKPOINT_NAME
    trainer = None
    try:
        trainer, static, test_idx = prepare_training(scene, config, dev, context, progress)
        static["preset_choice"] = preset_choice
        if config.train.time_budget == AUTO and trainer.with_depth:
            finish = expected_finish_seconds(scene.cameras[test_idx], config.output.write_renders)
            _plan_time_budget(trainer, static, time.perf_counter() - started, finish)
        config = trainer.config  # "auto" settings resolved

        def payload(t: Trainer) -> Checkpoint:
            return Checkpoint(**t.state_dict(), meta=static)

        if resume:
            _resume(trainer, ckpt_path, static)
        if progress and context.is_main:
            print(_training_plan(config, static), file=sys.stderr)
            if not trainer.with_depth:
                print(NO_DEPTH_HINT, file=sys.stderr)
        state = trainer.run(on_checkpoint=lambda t: save_checkpoint(ckpt_path, payload(t)), progress=progress)
    except TrainingInterrupted as err:
        raise TrainingInterrupted(
            f"{err}; checkpoint saved to {ckpt_path}; continue with: scenelabel build {scene.root} --out {out_dir} --resume"
        ) from None
    except TrainingError as err:
        kept = f"; the last checkpoint before the failure is kept at {ckpt_path}" if ckpt_path.exists() else ""
        raise TrainingError(f"{err}{kept}") from None
    finally:
        if trainer is not None:
            trainer.drop_data_parallel()
        leave(context)
    if not context.is_main:  # rank 0 alone evaluates and writes
        return BuildResult(field=None, metrics=_training_metrics(trainer), out_dir=out_dir)
    save_checkpoint(ckpt_path, payload(trainer))
    atomic_write_bytes(out_dir / "config.json", json.dumps(config_to_dict(config), indent=2).encode())

    update_share()  # evaluation and the map run on this job's share of the cores too
    field = SemanticField.load(out_dir, device=str(dev))
    renders_dir = None
    if config.output.write_renders and test_idx:
        renders_dir = out_dir / "renders"
        renders_dir.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    metrics = evaluate(field, scene, test_idx, config.output.smooth_sigma, renders_dir)
    eval_seconds = time.perf_counter() - t0
    metrics.update(
        {
            **_training_metrics(trainer),
            "eval_seconds": eval_seconds,
            "n_train_views": len(static["train_views"]),
            "classes": {str(k): v for k, v in field.classes.items()},
            "history": state.history,
        }
    )
    if config.output.write_map:
        t0 = time.perf_counter()
        occ_map = field.occupancy_map(config.output.map_voxel_size)
        occ_map.to_zarr(out_dir / MAP_NAME)
        metrics["map"] = {
            "path": MAP_NAME,
            "voxel_size": occ_map.voxel_size,
            "shape": list(occ_map.shape),
            "seconds": time.perf_counter() - t0,
        }
    atomic_write_bytes(out_dir / "metrics.json", json.dumps(metrics, indent=2, default=float).encode())
    return BuildResult(field=field, metrics=metrics, out_dir=out_dir)
