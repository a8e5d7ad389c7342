"""The scene suite: default builds on procedurally varied rooms, judged in 3D; writes docs/suite.md.

    .venv/bin/python tools/bench_suite.py                                  # every suite room, the defaults
    .venv/bin/python tools/bench_suite.py --scenes studio-3x3 --out /tmp/s.md
    .venv/bin/python tools/bench_suite.py --variants - distortion --budget 120 --out /tmp/candidates.md
    .venv/bin/python tools/bench_suite.py --rewrite                        # the document again from docs/suite.json

Each room (scenelabel.data.suite.SUITE) is written as users' files are (no near/far, no aabb) and built
as a new user would (`build` with the default preset, or a variant of it) in a fresh subprocess.
Beside held-out PSNR and mIoU every row carries 3D metrics against the exact boxes
(scenelabel.metrics): median relative ray depth error on the held-out views' pixels; labels of
points 2 cm behind the true surfaces along those pixels' rays (field, baked field, map at 0.05 m)
and of free points in front of them; precision / recall / F-score at 5 cm of the map's occupied
voxel centres against the surfaces every view sees; samples per ray at the end of training; the
modelled box against the true one. Rooms with `tuning=False` are reported apart: they stay out of
every tuning decision. All numbers in the document come from this run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from scenelabel.config import LAYOUT_OPEN_RAYS  # noqa: E402

MAP_VOXEL = 0.05
PROBE_RAYS = 20_000  # held-out pixel rays probed per room
TRUTH_POINTS = 200_000  # true surface points (all views' exact depth) for the F-score's recall
VARIANTS: dict[str, dict] = {
    "-": {},
    "live-4": {"field": {"colour_live_logit": 4.0}},
    "no-live": {"field": {"colour_live_logit": 0.0}},
    "no-layout": {"data": {"layout_depth": False}},
    "reopen": {"sampling": {"grid_reopen": 0.01}},  # the worst-coloured 1 % of each step's rays re-open their grid cells
    "reopen-labels": {"sampling": {"grid_reopen": 0.01, "grid_reopen_by": "labels"}},  # the wrongly labelled rays re-open
    "warmup-128": {"sampling": {"grid_warmup": 128}},  # every grid cell marched for the first 128 steps
    "no-open": {"sampling": {"grid_open_rays": 0}},  # no open rays ("auto" gives rooms seen from inside LAYOUT_OPEN_RAYS)
    "open-16": {"sampling": {"grid_open_rays": 16}},  # 16 class-balanced rays a step march every cell
    "open-32": {"sampling": {"grid_open_rays": 32}},
    "open-64": {"sampling": {"grid_open_rays": 64}},
    "open-share-labels": {"sampling": {"grid_open_labels": "share"}},  # their cross-entropy weighted like their colour
    "open-geometry-labels": {"sampling": {"grid_open_labels": "geometry"}},  # their labels move density only
    "distortion": {"train": {"distortion_weight": 0.002}},
    "no-distortion": {"train": {"distortion_weight": 0.0}},
    "solid": {"train": {"solid_weight": 0.01}},
    "decay-0.8": {"sampling": {"grid_decay": 0.8}},
    "decay-0.95": {"sampling": {"grid_decay": 0.95}},  # "auto" gives layout-depth builds 0.8, as sensor depth
    "voxels": {"preset": "voxels"},
    "fast": {"preset": "fast"},
    "voxels-budget": {"preset": "voxels", "train": {"time_budget": "auto"}},  # the default build's time
    "fast-box": {"preset": "fast", "sampling": {"warp": "box"}},  # a forward-facing room in uniform cells
    "class-balance": {"train": {"class_balance": True}},
    "semantic-0.1": {"train": {"semantic_weight": 0.1}},
    "semantic-0.25": {"train": {"semantic_weight": 0.25}},
    "dense": {"preset": "dense"},
    "train-3000": {"train": {"steps": 3000}},  # up to 3000 training steps, still at most 150 s of training
    "steps-384": {"sampling": {"n_steps": 384}},
    "steps-192": {"sampling": {"n_steps": 192}},  # the fast preset's marching before 288
    "no-grid-from-training": {"sampling": {"grid_from_training": False}},  # the default since docs/suite_grid.md
    "grid-from-training": {"sampling": {"grid_from_training": True}},  # the default of docs/suite_grid.md's run
    "planes-256": {"field": {"resolutions": [64, 256]}},
    "planes-64-128-256": {"field": {"resolutions": [64, 128, 256]}},  # the default since code 8d7c844
    "planes-512": {"field": {"resolutions": [64, 128, 256, 512]}},
    "planes-cubic": {"field": {"plane_cells": "cubic"}},
    "layout-mounted": {"data": {"layout_mounted": True}},  # the default since it was measured
    "no-layout-mounted": {"data": {"layout_mounted": False}},  # the default before
    "planes-64-128": {"field": {"resolutions": [64, 128]}},  # the default before it
    "grid-128": {"sampling": {"grid_resolution": 128}},
    "random-bg": {"train": {"background": "random"}},
    "distortion+random-bg": {"train": {"distortion_weight": 0.002, "background": "random"}},
    "distortion-late": {"train": {"distortion_weight": 0.002, "distortion_start": 0.3}},
    "distortion-0.0005": {"train": {"distortion_weight": 0.0005}},
    "distortion-0.01": {"train": {"distortion_weight": 0.01}},
    "margin-0.05": {"train": {"free_margin": 0.05}},  # the free-space margin layout depth had before
    "pad-0.03": {"data": {"bounds_pad": 0.03}},  # bounds 3 % of the observed points' longest side beyond them (default 10 %)
    "depth-bg-scene": {"train": {"depth_background": "scene"}},  # rays with depth on the white background, as before
    "depth-bg-random": {"train": {"depth_background": "random"}},  # a random colour behind them, whatever the cameras
    "depth-weight-0.5": {"train": {"depth_weight": 0.5}},  # the depth terms (here the layout's) 5x the default's
    "no-train-stop": {"sampling": {"train_min_trans": 0.0}},  # training evaluates every sample in an occupied cell
    # the room written with depth as a phone gives it (scenelabel.data.synthetic.add_phone_depth:
    # quarter resolution, 1.5 % noise, holes at edges, on dark surfaces and beyond 5 m): the depth terms train
    "phone-depth": {"capture": "phone-depth"},
    "phone-depth-rgbd": {"capture": "phone-depth", "preset": "rgbd"},
    "phone-depth-rgbd-1200": {"capture": "phone-depth", "preset": "rgbd", "train": {"steps": 1200, "time_budget": 80.0}},
    "phone-depth-3000": {"capture": "phone-depth", "train": {"steps": 3000}},
    "phone-depth-2000": {"capture": "phone-depth", "train": {"steps": 2000}},
    "phone-depth-1600": {"capture": "phone-depth", "train": {"steps": 1600}},
    "phone-depth-1300": {"capture": "phone-depth", "train": {"steps": 1300}},
    "phone-depth-decay-0.95": {"capture": "phone-depth", "sampling": {"grid_decay": 0.95}},
    "phone-depth-no-solid": {"capture": "phone-depth", "train": {"depth_solid_weight": 0.0}},
    "phone-depth-distortion": {"capture": "phone-depth", "train": {"distortion_weight": 0.002}},
    "phone-depth-distortion-0.01": {"capture": "phone-depth", "train": {"distortion_weight": 0.01}},
    "phone-depth-planes-256": {"capture": "phone-depth", "field": {"resolutions": [64, 256]}},
    "phone-depth-solid-2": {"capture": "phone-depth", "train": {"solid_depth_steps": 2.0}},  # the layer before
    "phone-depth-bg-random": {"capture": "phone-depth", "train": {"depth_background": "random"}},
    "phone-depth-bg-scene": {"capture": "phone-depth", "train": {"depth_background": "scene"}},
    "phone-depth-bg-scene-no-live": {"capture": "phone-depth", "field": {"colour_live_logit": 0.0},  # the default before
                                     "train": {"depth_background": "scene"}},
    "phone-depth-live-4": {"capture": "phone-depth", "field": {"colour_live_logit": 4.0}},
    "phone-depth-bg-random-live-4": {"capture": "phone-depth", "field": {"colour_live_logit": 4.0},
                                     "train": {"depth_background": "random"}},
    "phone-depth-no-carve": {"capture": "phone-depth", "sampling": {"depth_carve": False, "depth_ray_end": 0.0}},
    "phone-depth-no-fill": {"capture": "phone-depth", "data": {"layout_depth": False}},
    "phone-depth-carve": {"capture": "phone-depth", "sampling": {"depth_carve": True, "depth_carve_until": 0.5, "depth_ray_end": 2.0}},
    "phone-depth-no-train-stop": {"capture": "phone-depth", "sampling": {"train_min_trans": 0.0}},
    "phone-depth-open-16": {"capture": "phone-depth", "sampling": {"grid_open_rays": 16}},
    "phone-depth-keep-carve": {"capture": "phone-depth", "sampling": {"depth_carve": True, "depth_carve_until": 1.0, "depth_ray_end": 2.0}},
}
OPEN_NOTE = ("each training step adds {n} rays drawn class by class from the training labels that sample every marching "
             "step whatever the density grid holds, for the first half of the run, their colour error weighted back to "
             f"their class's share of the pixels (`sampling.grid_open_rays` {{n}}; default \"auto\": {LAYOUT_OPEN_RAYS} in a "
             "room seen from inside whose training depth is all the layout's, else 0)")
LIVE_NOTE = ("the colour sigmoid's gradient no less than its slope at a logit of ±4 (`field.colour_live_logit` 4, the "
             "default preset's): a colour channel driven deep in the first steps learns again")
NO_LIVE_NOTE = "the plain sigmoid's gradient for the colour (`field.colour_live_logit` 0; the default preset's is 4)"
BG_SCENE_NOTE = "rays with depth composited on the white background like every other ray (`train.depth_background` \"scene\"; the default, \"random\", puts a random colour behind them)"
BG_RANDOM_NOTE = "rays with depth composited on a random colour (`train.depth_background` \"random\", the default)"
# what a variant without depth changes, for the document's text (only the variants a run has)
NOTES: dict[str, str] = {
    "-": f"the default preset: without sensor depth the floor, wall and ceiling pixels of the training views train on the depth of the room's layout found from their masks (`data.layout_depth`), and such a room seen from inside adds {LAYOUT_OPEN_RAYS} rays a step, drawn class by class, that ignore the density grid for the first half of the run (`sampling.grid_open_rays` \"auto\")",
    "open-share-labels": "as the default, with the open rays' cross-entropy weighted like their colour error, at their class's share of the pixels (`sampling.grid_open_labels` \"share\"; default \"balanced\": unweighted, each class's labels as often as another's)",
    "open-geometry-labels": "as the default, with the open rays' cross-entropy moving density only, their samples' class logits detached (`sampling.grid_open_labels` \"geometry\"; default \"balanced\": it moves both)",
    "no-layout": "the default preset without the layout's depth (`data.layout_depth` false): colour and labels alone",
    "reopen-labels": "each training step's rays whose rendered class is wrong, up to 1 % of the step's rays (those of largest cross-entropy), re-open the density grid's cells from their start to their rendered depth, for the first half of the run (`sampling.grid_reopen` 0.01, `sampling.grid_reopen_by` \"labels\")",
    **{f"open-{n}": OPEN_NOTE.format(n=n) for n in (16, 32, 64)},
    "no-open": f"no rays that ignore the density grid (`sampling.grid_open_rays` 0; \"auto\", the default, adds {LAYOUT_OPEN_RAYS} a step to rooms seen from inside whose depth is all the layout's)",
    "warmup-128": "every density-grid cell occupied for the first 128 training steps, before the grid's first refresh (`sampling.grid_warmup` 128)",
    "reopen": "each training step's 1 % of rays with the largest colour error re-open the density grid's cells from their start to their rendered depth, for the first half of the run (`sampling.grid_reopen` 0.01, `sampling.grid_reopen_until` 0.5; default 0: off)",
    "live-4": LIVE_NOTE,
    "no-live": NO_LIVE_NOTE,
    "fast": "`--preset fast`: tri-planes and a small network (the default before `auto`)",
    "voxels-budget": "`--preset voxels` (one dense grid, no network) with the default build's training time (`train.time_budget` \"auto\")",
    "fast-box": "`--preset fast` with uniform cells over the box (`sampling.warp` box) where `auto` gives a forward-facing capture the forward warp (disparity steps)",
    "class-balance": "median-frequency class weights in the cross-entropy (`train.class_balance`): rare classes (lamps, pictures, chairs) weigh more",
    **{f"semantic-{w}": f"the cross-entropy weighing {w} beside the photometric error (`train.semantic_weight`; default 0.04): the labels pull harder on geometry, a candidate for thin objects whose pixels blend them with the wall behind" for w in ("0.1", "0.25")},
    "train-3000": "up to 3000 training steps (`train.steps` 3000; \"auto\" gives 2000), still at most 150 s of training (`train.time_budget` \"auto\" without depth)",
    "planes-256": "tri-planes of 64 and 256 cells a side (`field.resolutions` [64, 256]; default [64, 128, 256]): the default without its middle level",
    "planes-64-128-256": "tri-planes of 64, 128 and 256 cells a side (`field.resolutions` [64, 128, 256]), the default since code 8d7c844: a third, finer level, half the finest cell's size",
    "planes-512": "tri-planes of 64, 128, 256 and 512 cells a side (`field.resolutions`; default [64, 128, 256]): a fourth, finer level, half the finest cell's size",
    "planes-cubic": "tri-planes of cubic cells (`field.plane_cells` \"cubic\"; default \"square\"): each level's planes shaped by the box's sides, with the features of the square level (a long room's cells shorter along its length, longer across)",
    "layout-mounted": "pictures (and the other classes that hang flat on walls) get the depth of the wall behind them from the room's layout (`data.layout_mounted`, the default since docs/suite_layout_mounted.md)",
    "no-layout-mounted": "pictures get no depth from the room's layout (`data.layout_mounted` false; default true), the default before",
    "planes-64-128": "tri-planes of 64 and 128 cells a side (`field.resolutions` [64, 128]; default [64, 128, 256]), the default before code 8d7c844: the finest cell twice the size",
    "grid-128": "a density grid of 128 cells a side (`sampling.grid_resolution`; default 64): smaller empty cells skipped",
    "no-grid-from-training": "the density grid refreshed from its random points alone (`sampling.grid_from_training` false)",
    "grid-from-training": "the density grid also raised by each training step's samples (`sampling.grid_from_training` true)",
    "depth-bg-scene": BG_SCENE_NOTE,
    "depth-bg-random": BG_RANDOM_NOTE,
    "depth-weight-0.5": "the depth terms at 0.5 (`train.depth_weight`; default 0.1): without sensor depth, the room layout's depth and free space pull 5 times harder",
    "no-train-stop": "training evaluates every sample in an occupied cell (`sampling.train_min_trans` 0; default 1e-4: a ray's samples stop being evaluated once its transmittance is below that)",
    "margin-0.05": "the free-space term counting weight in front of 0.95 of the layout's depth (`train.free_margin` 0.05, a sensor's; \"auto\" gives layout depth 0.02)",
    "pad-0.03": "the bounds of the observed points (here the room's layout) padded by 3 % of their longest side on every face (`data.bounds_pad` 0.03; default 0.1): a smaller box, finer cells",
}
# what each phone-depth variant changes, for the document's text (only the variants a run has)
DEPTH_NOTES: dict[str, str] = {
    "phone-depth": "the default preset",
    "phone-depth-rgbd": "`--preset rgbd`",
    "phone-depth-rgbd-1200": "`--preset rgbd` with 1200 steps, at most 80 s of training",
    "phone-depth-2000": "the default preset with 2000 steps (`train.steps`; the default before \"auto\")",
    "phone-depth-3000": "the default preset with up to 3000 steps (`train.steps`): the time plan of `train.time_budget` \"auto\" ends training first",
    "phone-depth-1600": "the default preset with 1600 steps",
    "phone-depth-1300": "the default preset with 1300 steps",
    "phone-depth-decay-0.95": "the density grid's remembered density decaying 0.95 per refresh (`sampling.grid_decay`; default \"auto\": 0.8 with sensor depth, 0.95 without)",
    "phone-depth-no-solid": "without the solid-interior term (`train.depth_solid_weight` 0)",
    "phone-depth-planes-256": "tri-plane levels of 64 and 256 cells (`field.resolutions`; default 64, 128 and 256)",
    "phone-depth-distortion": "with the distortion term at 0.002 (`train.distortion_weight`; \"auto\" leaves it off where the bounds come from depth)",
    "phone-depth-distortion-0.01": "with the distortion term at 0.01",
    "phone-depth-solid-2": "the solid-interior layer 2 marching steps deep (`train.solid_depth_steps`; default 0.5)",
    "phone-depth-live-4": LIVE_NOTE,
    "phone-depth-bg-random-live-4": "as `phone-depth-bg-random`, and " + LIVE_NOTE,
    "phone-depth-bg-scene-no-live": "as `phone-depth-bg-scene`, and " + NO_LIVE_NOTE + " (the default before)",
    "phone-depth-bg-random": BG_RANDOM_NOTE,
    "phone-depth-bg-scene": BG_SCENE_NOTE,
    "phone-depth-no-carve": "no space carving (`sampling.depth_carve` false), rays to the box (`sampling.depth_ray_end` 0)",
    "phone-depth-no-fill": "the sensor's holes are not filled from the room's layout (`data.layout_depth` false)",
    "phone-depth-open-16": OPEN_NOTE.format(n=16),
    "phone-depth-carve": "space carving from the depth (`sampling.depth_carve` true, the default), its border handed back to the field at half the run (`sampling.depth_carve_until` 0.5), rays with depth ending 2 grid cells past it (`sampling.depth_ray_end` 2)",
    "phone-depth-no-train-stop": "training evaluates every sample in an occupied cell (`sampling.train_min_trans` 0; default 1e-4)",
    "phone-depth-keep-carve": "as `phone-depth-carve` with the carve kept whole to the end (`sampling.depth_carve_until` 1)",
}
# the same builds with another training seed (`train.seed`, default 0: initial weights, rays drawn):
# the spread one run per room hides
SEEDS = (1, 2)
SEEDED = ("-", "margin-0.05", "depth-bg-scene", "open-64", "planes-256", "train-3000", "phone-depth", "phone-depth-bg-random", "phone-depth-bg-random-live-4")
for _seed in SEEDS:
    for _base in SEEDED:  # the base variant's settings with train.seed added
        _name = f"seed-{_seed}" if _base == "-" else f"{_base}-seed-{_seed}"
        VARIANTS[_name] = {**VARIANTS[_base], "train": {**VARIANTS[_base].get("train", {}), "seed": _seed}}
        if _base in DEPTH_NOTES:
            DEPTH_NOTES[_name] = (f"the default preset with training seed {_seed} (`train.seed`; default 0)" if _base == "phone-depth"
                                  else f"as `{_base}` with training seed {_seed}")
        elif _base in NOTES:
            NOTES[_name] = (f"the default preset with training seed {_seed} (`train.seed`; default 0)" if _base == "-"
                            else f"as `{_base}` with training seed {_seed}")


def seed_family(variant: str) -> tuple[str, int]:
    """The variant a seed variant repeats and its seed (`phone-depth-seed-1` -> (`phone-depth`, 1),
    `seed-2` -> (`-`, 2), any other variant -> (itself, 0))."""
    head, sep, seed = variant.rpartition("seed-")
    if not sep or not seed.isdigit():
        return variant, 0
    return head.rstrip("-") or "-", int(seed)


# Targets of the scene-suite issue, for rooms at 160x120 with 30-60 views (checked from the run)
TARGETS = (
    ("build <= 180 s", lambda r: r["build_seconds"] <= 180),
    ("median relative depth error <= 3 %", lambda r: r["depth_rel_median"] <= 0.03),
    ("surface-point labels: field >= 90 %", lambda r: r["surface_field"] >= 0.90),
    ("surface-point labels: map >= 85 %", lambda r: r["surface_map"] >= 0.85),
    ("free points >= 98 % (field)", lambda r: r["free_field"] >= 0.98),
    ("F-score at 5 cm >= 0.9", lambda r: r["fscore"] >= 0.9),
    ("held-out mIoU >= 0.93", lambda r: r["miou"] >= 0.93),
    ("held-out mIoU >= 0.93 over the classes with >= 0.1 % of the pixels",
     lambda r: None if r.get("miou_common") is None else r["miou_common"] >= 0.93),
    ("held-out PSNR >= 28 dB", lambda r: r["psnr"] >= 28),
    ("samples per ray at the end <= 24", lambda r: r["samples_per_ray"] <= 24),
    ("occupancy_map(0.05) <= 10 s", lambda r: r["map_seconds"] <= 10),
    ("render 160x120 <= 0.3 s", lambda r: r["render_seconds"] <= 0.3),
)


def _probe_rays(scene, views: list[int], rng: np.random.Generator):
    """PROBE_RAYS random pixel rays of ``views`` with their exact depth and class."""
    from scenelabel.geometry.rays import rays_from_cameras

    origins, directions, depth, label = [], [], [], []
    for i in views:
        o, d = rays_from_cameras(scene.cameras, i)
        origins.append(o), directions.append(d)
        depth.append(scene.depths[i].reshape(-1)), label.append(scene.labels[i].reshape(-1))
    o, d, z, c = (np.concatenate(a) for a in (origins, directions, depth, label))
    pick = rng.choice(len(o), min(PROBE_RAYS, len(o)), replace=False)
    return o[pick], d[pick], z[pick].astype(np.float64), c[pick]


def _truth_points(scene, rng: np.random.Generator) -> np.ndarray:
    """Points of the true surfaces every view sees (exact depth), TRUTH_POINTS at most."""
    from scenelabel.geometry.rays import rays_from_cameras
    from scenelabel.metrics import surface_points_from_depth

    points = []
    for i in range(len(scene)):
        o, d = rays_from_cameras(scene.cameras, i)
        points.append(surface_points_from_depth(o, d, scene.depths[i].reshape(-1)))
    points = np.concatenate(points)
    return points[rng.choice(len(points), min(TRUTH_POINTS, len(points)), replace=False)]


def three_d_metrics(field, scene, test_idx: list[int], boxes) -> dict:
    """The 3D metrics of a built field (module docstring)."""
    from scenelabel import FREE, BakedField
    from scenelabel import metrics as M

    rng = np.random.default_rng(0)
    o, d, z, true_class = _probe_rays(scene, test_idx, rng)
    rays = field.query_rays(o, d, with_rgb=False)
    surface, free, ray_index = M.probe_points(o, d, z, rng=rng)
    surface_class = true_class[ray_index]
    t0 = time.perf_counter()
    occ = field.occupancy_map(MAP_VOXEL)
    map_seconds = time.perf_counter() - t0
    # a forward-facing capture's field (disparity steps) has no baked form: its row says n/a
    baked = BakedField.from_field(field) if field.meta["warp"]["kind"] == "box" else None
    lo, hi = M.boxes_lo_hi(boxes)
    occupied = occ.world_from_index(np.argwhere(occ.occupied))
    f = M.surface_fscore(occupied, _truth_points(scene, rng), M.FSCORE_THRESHOLD, lo, hi)
    return {
        "depth_rel_median": M.relative_depth_error(rays.depth, z),
        "surface_field": M.label_accuracy(field.query_points(surface).label, surface_class),
        "surface_baked": None if baked is None else M.label_accuracy(baked.query_points(surface).label, surface_class),
        "surface_map": M.label_accuracy(occ.label_at(surface), surface_class),
        "free_field": M.label_accuracy(field.query_points(free).label, np.full(len(free), FREE)),
        "free_map": M.label_accuracy(occ.label_at(free), np.full(len(free), FREE)),
        "precision": f["precision"],
        "recall": f["recall"],
        "fscore": f["fscore"],
        "map_seconds": map_seconds,
        "map_voxels": int(np.prod(occ.shape)),
    }


def _one_build(spec: dict, workdir: str, queue) -> None:
    """Child process: write the room, build it, measure; put a result dict on queue."""
    import torch

    from scenelabel import build, load_scene, preset
    from scenelabel.config import AUTO_PRESET
    from scenelabel.data.suite import suite_geometry, suite_spec, write_suite_scene
    from scenelabel.train.pipeline import choose_views

    torch.set_num_threads(os.cpu_count() or 1)
    room = suite_spec(spec["scene"])
    scene_dir = write_suite_scene(Path(workdir) / room.name, room)
    variant = json.loads(json.dumps(VARIANTS[spec["variant"]]))  # a deep copy
    if variant.pop("capture", None) == "phone-depth":
        from scenelabel.data.synthetic import add_phone_depth

        add_phone_depth(scene_dir)
    preset_name = variant.pop("preset", AUTO_PRESET)
    if spec["budget"] is not None:
        variant.setdefault("train", {})["time_budget"] = spec["budget"]
    if spec.get("steps") is not None:
        variant.setdefault("train", {})["steps"] = spec["steps"]
    variant["output"] = {"write_map": False}
    config = preset(preset_name, variant)
    t0 = time.perf_counter()
    try:
        result = build(scene_dir, Path(workdir) / "build", config, progress=False)
    except Exception as error:  # e.g. a diverged build: a row that says so, and the run goes on
        queue.put({"scene": room.name, "tuning": room.tuning, "variant": spec["variant"], "failed": f"{type(error).__name__}: {error}"})
        return
    build_seconds = time.perf_counter() - t0
    m = result.metrics
    scene = load_scene(scene_dir)
    _, test_idx, _ = choose_views(scene, config.train.holdout)
    geometry = suite_geometry(room)
    ckpt = result.field.meta
    aabb, true = np.asarray(ckpt["aabb_world"]), geometry.bounds
    interior = np.array([[0.0, 0.0, 0.0], list(room.size)])
    queue.put({
        "scene": room.name,
        "tuning": room.tuning,
        "variant": spec["variant"],
        "preset": m["preset"],  # the one the build chose (preset "auto": fast, or voxels for forward-facing cameras)
        "views": len(scene),
        "resolution": f"{room.width}x{room.height}",
        "build_seconds": build_seconds,
        "train_seconds": m["train_seconds"],
        "steps": m["steps"],
        "steps_per_second": m["steps_per_second"],
        "rollbacks": m.get("rollbacks", []),
        "budget_anchor": m.get("budget_anchor"),
        "samples_per_ray": float(np.mean([h["samples_per_ray"] for h in m["history"][-4:]])),
        "psnr": m.get("psnr"),
        "miou": m.get("miou"),
        "miou_common": m.get("miou_common"),
        "per_class_iou": m.get("per_class_iou"),
        "spurious_classes": m.get("spurious_classes"),
        "per_class_pixels": m.get("per_class_pixels"),
        "classes": m.get("classes"),
        "render_seconds": statistics.median(v["render_seconds"] for v in m["per_view"]),
        "aabb_source": ckpt["aabb_source"],
        "aabb": aabb.tolist(),
        "box_volume_ratio": float(np.prod(aabb[1] - aabb[0]) / np.prod(true[1] - true[0])),
        "box_holds_interior": bool(np.all(aabb[0] <= interior[0]) and np.all(aabb[1] >= interior[1])),
        "thinly_seen": ckpt["distortion"]["thinly_seen"],
        "carved_by_depth": ckpt.get("carved_by_depth"),
        "distortion_weight": ckpt["distortion"]["weight"],
        "time_plan": ckpt.get("time_plan"),
        "eval_seconds": m["eval_seconds"],
        **three_d_metrics(result.field, scene, test_idx, geometry.boxes),
    })


def run_one(spec: dict) -> dict:
    from bench import run_in_child  # tools/bench.py, beside this script

    return run_in_child(_one_build, spec)


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}"


def _fixed(x, digits: int) -> str:
    """``x`` with ``digits`` decimals; "n/a" for a figure the row's run did not record."""
    return "n/a" if x is None else f"{x:.{digits}f}"


def _weight(x) -> str:
    return "n/a" if x is None else f"{x:g}"


COLUMNS = (
    ("room", lambda r: r["scene"]),
    ("views", lambda r: f"{r['views']} @ {r['resolution']}"),
    ("variant", lambda r: r["variant"] + (f" ({r['preset']})" if r["variant"] == "-" and "preset" in r else "")),
    ("build s", lambda r: f"{r['build_seconds']:.0f}"),
    ("steps (/s)", lambda r: f"{r['steps']} ({r['steps_per_second']:.1f})"),
    ("PSNR", lambda r: f"{r['psnr']:.2f}"),
    ("mIoU (classes >= 0.1 % px)", lambda r: f"{r['miou']:.3f} ({_fixed(r.get('miou_common'), 3)})"),
    ("depth rel. err. %", lambda r: f"{100 * r['depth_rel_median']:.2f}"),
    ("surface field / baked / map %", lambda r: f"{_pct(r['surface_field'])} / {_pct(r['surface_baked'])} / {_pct(r['surface_map'])}"),
    ("free field / map %", lambda r: f"{_pct(r['free_field'])} / {_pct(r['free_map'])}"),
    ("P / R / F at 5 cm", lambda r: f"{r['precision']:.3f} / {r['recall']:.3f} / {r['fscore']:.3f}"),
    ("samples/ray", lambda r: f"{r['samples_per_ray']:.1f}"),
    ("thinly seen % / distortion", lambda r: f"{_pct(r.get('thinly_seen'))} / {_weight(r.get('distortion_weight'))}"),
    ("map s", lambda r: f"{r['map_seconds']:.1f}"),
    ("render s", lambda r: f"{r['render_seconds']:.2f}"),
    ("box / true volume", lambda r: f"{r['box_volume_ratio']:.2f}{'' if r['box_holds_interior'] else ' (cuts the room)'}"),
)

AGGREGATES = ("build_seconds", "psnr", "miou", "miou_common", "depth_rel_median", "surface_field", "surface_map",
              "free_field", "fscore", "samples_per_ray")
WORST_IS_HIGH = {"build_seconds", "depth_rel_median", "samples_per_ray"}


def _table(rows: list[dict]) -> list[str]:
    lines = ["| " + " | ".join(c for c, _ in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    return lines + ["| " + " | ".join(f(r) for _, f in COLUMNS) + " |" for r in rows]


def _aggregate(rows: list[dict], variant: str) -> list[str]:
    lines = [f"| rooms ({variant}) | " + " | ".join(AGGREGATES) + " |", "|" + "---|" * (len(AGGREGATES) + 1)]
    for group, pick in (("tuning", True), ("held out", False), ("all", None)):
        sel = [r for r in rows if r["variant"] == variant and (pick is None or r["tuning"] == pick)]
        if not sel:
            continue
        recorded = {k: [r[k] for r in sel if r.get(k) is not None] for k in AGGREGATES}  # older runs lack some
        med = [f"{statistics.median(v):.3g}" if v else "n/a" for v in recorded.values()]
        worst = [f"{(max if k in WORST_IS_HIGH else min)(v):.3g}" if v else "n/a" for k, v in recorded.items()]
        lines.append(f"| {group}: median | " + " | ".join(med) + " |")
        lines.append(f"| {group}: worst | " + " | ".join(worst) + " |")
    base = next(r["variant"] for r in rows)
    paired = {r["scene"]: r["build_seconds"] for r in rows if r["variant"] == base}
    ratios = [r["build_seconds"] / paired[r["scene"]] for r in rows if r["variant"] == variant and r["scene"] in paired]
    if variant != base and ratios:
        lines += ["", f"Build time against `{base}` on the same room: median ratio "
                  f"{statistics.median(ratios):.2f}, range {min(ratios):.2f}-{max(ratios):.2f} over {len(ratios)} rooms."]
    return lines


# Targets of the RGB-D issue for the rooms written with phone-like depth (every room)
DEPTH_TARGETS = (
    ("build <= 90 s", lambda r: r["build_seconds"] <= 90),
    ("median relative depth error <= 1 %", lambda r: r["depth_rel_median"] <= 0.01),
    ("surface-point labels: field >= 95 %", lambda r: r["surface_field"] >= 0.95),
    ("F-score at 5 cm >= 0.95", lambda r: r["fscore"] >= 0.95),
)


def _time_plans(rows: list[dict]) -> list[str]:
    """The planned training time of the builds that planned it (``train.time_budget`` "auto" with
    depth, checkpoint ``time_plan``) against what the build took: after training is the build's time
    less its setup and training (evaluation, checkpoint, field loading)."""
    planned = [r for r in rows if r.get("time_plan")]
    if not planned:
        return []
    lines = ["## Time plans (`train.time_budget` \"auto\" with depth)", "",
             "| room | variant | setup s | training planned s | trained s (steps) | after training: expected / took s | build s |",
             "|---|---|---|---|---|---|---|"]
    for r in planned:
        plan = r["time_plan"]
        after = r["build_seconds"] - plan["setup_seconds"] - r["train_seconds"]
        lines.append(f"| {r['scene']} | {r['variant']} | {plan['setup_seconds']:.1f} | {plan['train_seconds']:.1f} | "
                     f"{r['train_seconds']:.1f} ({r['steps']}) | {plan['finish_seconds']:.1f} / {after:.1f} | {r['build_seconds']:.1f} |")
    return lines + [""]


def _depth_targets(rows: list[dict]) -> list[str]:
    """The RGB-D targets on the rows with phone-like depth; mIoU against the same room's row without
    depth (with the same training seed)."""
    without = {(r["scene"], seed_family(r["variant"])[1]): r for r in rows if seed_family(r["variant"])[0] == "-"}
    lines = []
    for variant in dict.fromkeys(r["variant"] for r in rows if r["variant"].startswith("phone-depth")):
        sel = [r for r in rows if r["variant"] == variant]
        for name, ok in DEPTH_TARGETS:
            failing = [r["scene"] for r in sel if not ok(r)]
            lines.append(f"- `{variant}`: {name}: " + ("met on every room" if not failing else f"not met on {len(failing)} of {len(sel)} ({', '.join(failing)})"))
        seed = seed_family(variant)[1]
        paired = [(r, without[r["scene"], seed]) for r in sel if (r["scene"], seed) in without]
        if paired:
            lower = [f"{r['scene']} {r['miou']:.3f} < {w['miou']:.3f}" for r, w in paired if r["miou"] < w["miou"]]
            lines.append(f"- `{variant}`: mIoU no lower than the same room without depth (same seed): " + ("met on every room" if not lower else f"not met on {len(lower)} of {len(paired)} ({'; '.join(lower)})"))
    seeded = _seed_groups(rows)
    rooms = [s for (s, f), v in seeded.items() if f == "phone-depth" and len(v) > 1 and len(seeded.get((s, "-"), ())) > 1]
    if rooms:
        mean = {k: statistics.mean(r["miou"] for r in v) for k, v in seeded.items()}
        lower = [f"{s} {mean[s, 'phone-depth']:.3f} < {mean[s, '-']:.3f}" for s in rooms if mean[s, "phone-depth"] < mean[s, "-"]]
        lines.append("- `phone-depth`, mean over seeds: mIoU no lower than the same room's mean without depth: "
                     + ("met on every room" if not lower else f"not met on {len(lower)} of {len(rooms)} ({'; '.join(lower)})"))
    return lines


def _targets(rows: list[dict]) -> list[str]:
    eligible = [r for r in rows if r["resolution"] == "160x120" and 30 <= r["views"] <= 60]
    lines = []
    for variant in dict.fromkeys(r["variant"] for r in eligible):
        sel = [r for r in eligible if r["variant"] == variant]
        fast = max(r["steps_per_second"] for r in sel)
        slow = [r["scene"] for r in sel if r["steps_per_second"] < 0.5 * fast]
        lines.append(f"- `{variant}`: steps/s of every room at least half the fastest room's: " + (f"not met ({', '.join(slow)})" if slow else "met"))
        for name, ok in TARGETS:  # ok(r) None: the row's run did not record the figure
            verdicts = {r["scene"]: ok(r) for r in sel}
            failing = [scene for scene, v in verdicts.items() if v is False]
            if all(v is None for v in verdicts.values()):
                lines.append(f"- `{variant}`: {name}: not recorded by this run")
            else:
                lines.append(f"- `{variant}`: {name}: " + ("met on every room" if not failing else
                             f"not met on {len(failing)} of {len(sel)} ({', '.join(failing)})"))
    return lines


def write_plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if "failed" not in r]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    names = list(dict.fromkeys(r["scene"] for r in rows))
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    width = 0.8 / len(variants)
    for v_i, variant in enumerate(variants):
        by = {r["scene"]: r for r in rows if r["variant"] == variant}
        x = np.arange(len(names)) + v_i * width
        for ax, key, scale in ((axes[0], "build_seconds", 1), (axes[1], "surface_field", 100), (axes[2], "depth_rel_median", 100)):
            ax.bar(x, [by[n][key] * scale if n in by else 0 for n in names], width, label=variant)
    for ax, title in zip(axes, ("build (s)", "surface-point labels, field (%)", "median relative depth error (%)")):
        ax.set_title(title)
        ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2)
        ax.set_xticklabels([n + ("" if any(r["tuning"] for r in rows if r["scene"] == n) else " *") for n in names], rotation=60, ha="right", fontsize=8)
    axes[0].legend(fontsize=8)
    fig.suptitle("scene suite (* held out of tuning)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def code_version() -> str:
    """The commit the run measures, with "+changes" when the work tree differs from it."""
    import subprocess

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True).stdout.strip()

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    return commit + ("+changes" if git("status", "--porcelain", "--untracked-files=no", "scenelabel", "tools") else "")


def write_markdown(rows: list[dict], path: Path, command: str, plot: Path) -> None:
    from bench import reference_line  # tools/bench.py, beside this script

    from scenelabel.config import DISTORTION_THIN_MAX
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    failed = [r for r in rows if "failed" in r]  # builds that raised: listed apart, in no table or aggregate
    rows = [r for r in rows if "failed" not in r]
    code = ", ".join(sorted({r.get("code", "unknown") for r in rows}))
    with_depth = any(v.startswith("phone-depth") for v in variants)
    lines = [
        "# The scene suite" + (": with and without phone-like depth" if with_depth else ""),
        "",
        f"Generated by `.venv/bin/{command}` (one run, code {code}); that command regenerates it.",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}.",
        *reference_line(rows),
        "",
        "Every room is written as users' files are: transforms.json with no near/far and no aabb",
        "(the bounds are found by the build). 3D metrics are against the exact boxes",
        "(`scenelabel.metrics`): depth error is the median of |depth - true| / true over held-out pixel",
        "rays (`query_rays`); surface labels are of points 2 cm behind the true surface along those",
        "rays, free labels of points at least 0.1 m in front of it; P / R / F: the 0.05 m map's",
        "occupied voxel centres against the surfaces the views see. Samples per ray: the samples whose",
        "density a training step evaluated per ray (with `sampling.train_min_trans`, in its pass without",
        "gradients), the mean of the last logged steps. Box / true volume: the modelled box against the",
        "rooms' true bounds.",
        "Thinly seen: the share of the observed geometry (the build's coarse fit) inside fewer than 3",
        "training views' images; distortion: the weight of the distortion term the build trained with",
        f"(`train.distortion_weight` \"auto\" turns it on where at most {DISTORTION_THIN_MAX:.0%} is thinly seen; variant",
        "`distortion` forces 0.002, `no-distortion` 0).",
        "",
        *(["Variants: " + "; ".join(f"`{v}`: {NOTES[v]}" for v in variants if v in NOTES) + ".", ""]
          if any(v in NOTES for v in variants) else []),
        *(["Variants `phone-depth*`: the room also carries depth as a phone gives it",
           "(`scenelabel.data.synthetic.add_phone_depth`: z-depth PNGs at quarter resolution, 1.5 % noise, holes at",
           "depth edges, on dark surfaces, beyond 5 m and 1 % at random), which the build trains on (`train.depth_weight`,",
           "`train.depth_solid_weight`, space carving `sampling.depth_carve`). "
           + "; ".join(f"`{v}`: {DEPTH_NOTES[v]}" for v in variants if v in DEPTH_NOTES) + ".",
           ""] if with_depth else []),
        f"![suite]({plot.name})",
        "",
        "## Rooms used for tuning",
        "",
        *_table([r for r in rows if r["tuning"]]),
        "",
        "## Rooms held out of every tuning decision",
        "",
        *_table([r for r in rows if not r["tuning"]]),
        "",
        "## Aggregate and worst room",
        "",
    ]
    for variant in variants:
        lines += [*_aggregate(rows, variant), ""]
    if failed:
        lines += ["## Builds that failed", "", *(f"- {r['scene']} [{r['variant']}]: {r['failed']}" for r in failed), ""]
    lines += _rollbacks(rows)
    lines += _budget_anchors(rows)
    lines += ["## Targets (rooms at 160x120 with 30-60 views)", "", *_targets(rows), ""]
    if with_depth:
        lines += ["## Targets with phone-like depth (every room)", "", *_depth_targets(rows), ""]
    lines += _time_plans(rows)
    lines += _seed_spread(rows)
    lines += ["Bounds chosen per room: " + "; ".join(sorted({r["aabb_source"].split(" (")[0] for r in rows})) + ".", ""]
    lines += _per_class(rows)
    path.write_text("\n".join(lines) + "\n")


def _rollbacks(rows: list[dict]) -> list[str]:
    """The builds whose training diverged and resumed from an earlier state (scenelabel.train.divergence);
    nothing for rows written before builds recorded that (``--rewrite`` of an older document)."""
    if not any("rollbacks" in r for r in rows):
        return []
    rolled = [r for r in rows if r.get("rollbacks")]
    lines = ["## Rollbacks", ""]
    if not rolled:
        return [*lines, "No build that finished diverged (scenelabel.train.divergence: none resumed from an earlier state).", ""]
    for r in rolled:
        told = ", ".join(f"diverged at step {b['diverged_at']}, resumed from step {b['resumed_from']} at {b['lr_factor']:g} "
                         "times the learning rate" for b in r["rollbacks"])
        lines.append(f"- {r['scene']} [{r['variant']}]: {told}")
    return [*lines, ""]


def _budget_anchors(rows: list[dict]) -> list[str]:
    """The builds whose time budget was projected to end them before their last step, so that their
    schedules followed the clock from then on (scenelabel.train.schedule; a build whose steps then sped up
    may still reach its last step); nothing for rows written before builds recorded that."""
    if not any("budget_anchor" in r for r in rows):
        return []
    lines = ["## Builds whose schedules followed the clock", ""]
    anchored = [r for r in rows if r.get("budget_anchor")]
    if not anchored:
        return [*lines, "None: every build's schedules followed its step count (scenelabel.train.schedule).", ""]
    for r in anchored:
        fraction, seconds = r["budget_anchor"]
        lines.append(f"- {r['scene']} [{r['variant']}]: {r['steps']} steps in {r['train_seconds']:.0f} s of training; the "
                     f"schedules followed the clock from {100 * fraction:.0f} % of the run, {seconds:.0f} s in")
    return [*lines, ""]


def _seed_groups(rows: list[dict]) -> dict[tuple[str, str], list[dict]]:
    """Rows by (room, the variant a seed variant repeats): a group holds one row per seed built."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["scene"], seed_family(r["variant"])[0]), []).append(r)
    return groups


def _seed_spread(rows: list[dict]) -> list[str]:
    """Per room and variant built with several seeds: mean and range of the measures that decide."""
    groups = {k: v for k, v in _seed_groups(rows).items() if len(v) > 1}
    if not groups:
        return []
    keys = {"miou": ".3f", "psnr": ".1f", "fscore": ".3f", "surface_field": ".3f", "build_seconds": ".0f"}
    lines = ["## Spread over training seeds", "",
             "The same room and variant built with training seeds 0 (the variant's own row) and "
             + ", ".join(map(str, SEEDS)) + " (`train.seed`): mean (min-max).", "",
             "| room | variant | seeds | " + " | ".join(keys) + " |", "|---|---|---|" + "---|" * len(keys)]
    for (scene, family), sel in groups.items():
        cells = [f"{statistics.mean(r[k] for r in sel):{f}} ({min(r[k] for r in sel):{f}}-{max(r[k] for r in sel):{f}})" for k, f in keys.items()]
        lines.append(f"| {scene} | {family} | {len(sel)} | " + " | ".join(cells) + " |")
    return lines + [""]


def _per_class(rows: list[dict]) -> list[str]:
    """Per room, each class's held-out IoU per variant (mIoU is their mean over the classes the
    held-out views show), and the classes predicted where no held-out view shows them."""
    rows = [r for r in rows if r.get("per_class_iou")]
    if not rows:
        return []
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    lines = ["## Held-out IoU per class", "",
             "mIoU is the mean over the classes the held-out views show; a class predicted where none "
             "shows it (spurious: its predicted pixels) is left out of the mean (docs/conventions.md, "
             "'Labels'). Held-out px: the held-out pixels of that class (the same views for every variant).", ""]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        by_variant = {r["variant"]: r for r in rows if r["scene"] == scene}
        names = next(iter(by_variant.values())).get("classes") or {}
        ids = sorted({int(c) for r in by_variant.values() for c in r["per_class_iou"]})
        pixels = next((r["per_class_pixels"] for r in by_variant.values() if r.get("per_class_pixels")), {})
        shown = [v for v in variants if v in by_variant]
        lines += [f"**{scene}**", "", "| class | held-out px | " + " | ".join(shown) + " |",
                  "|---|---|" + "---|" * len(shown)]
        for cid in ids:
            cells = []
            for v in shown:
                iou = by_variant[v]["per_class_iou"].get(str(cid))
                spurious = (by_variant[v].get("spurious_classes") or {}).get(str(cid))
                cells.append("-" if iou is None else f"{iou:.3f}" + (f" (spurious: {spurious} px)" if spurious else ""))
            name = f"{cid} {names.get(str(cid), '')}"
            lines.append(f"| {name} | {pixels.get(str(cid), '-')} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def main() -> None:
    from scenelabel.data.suite import SUITE

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=[s.name for s in SUITE])
    parser.add_argument("--variants", nargs="+", default=["-"], choices=sorted(VARIANTS))
    parser.add_argument("--budget", type=float, default=None, help="training seconds per build (default: none, as a user's build)")
    parser.add_argument("--steps", type=int, default=None, help="training steps per build (default: the preset's)")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "suite.md")
    parser.add_argument("--rewrite", action="store_true", help="rewrite the document and plot from the rows of OUT's .json")
    args = parser.parse_args()
    if args.rewrite:  # the rows of a run (e.g. one stopped part way), the command that makes exactly them
        rows = json.loads(args.out.with_suffix(".json").read_text())["rows"]
        names = list(dict.fromkeys(r["scene"] for r in rows))
        command = "python tools/bench_suite.py --variants " + " ".join(dict.fromkeys(r["variant"] for r in rows))
        if names != [s.name for s in SUITE]:
            command += " --scenes " + " ".join(names)
        if rows[0].get("budget") is not None:
            command += f" --budget {rows[0]['budget']:g}"
        if rows[0].get("steps_asked") is not None:
            command += f" --steps {rows[0]['steps_asked']}"
        if args.out != parser.get_default("out"):
            command += f" --out {args.out.relative_to(REPO) if args.out.is_relative_to(REPO) else args.out}"
        plot = args.out.with_suffix(".png")
        write_plot(rows, plot)
        write_markdown(rows, args.out, command, plot)
        print(f"wrote {args.out}")
        return
    from bench import reference_seconds  # tools/bench.py, beside this script: a fixed workload's seconds now

    command = "python tools/bench_suite.py " + " ".join(sys.argv[1:])
    code = code_version()
    rows = []
    for name in args.scenes:  # a room's variants back to back: their timings see the same machine load
        for variant in args.variants:
            reference = reference_seconds()  # the machine's speed just before the build
            t0 = time.perf_counter()
            row = run_one({"scene": name, "variant": variant, "budget": args.budget, "steps": args.steps})
            row["budget"], row["steps_asked"], row["code"] = args.budget, args.steps, code
            row["reference_seconds"] = reference
            rows.append(row)
            print(f"{name} [{variant}]: {time.perf_counter() - t0:.0f} s: " + ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
            args.out.with_suffix(".json").write_text(json.dumps({"command": command, "rows": rows}, indent=2))
    plot = args.out.with_suffix(".png")
    write_plot(rows, plot)
    write_markdown(rows, args.out, command, plot)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
