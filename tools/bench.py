"""Benchmark presets on the synthetic scenes and write docs/benchmarks.md.

    .venv/bin/python tools/bench.py                    # the end-to-end targets: docs/benchmarks.md
    .venv/bin/python tools/bench.py --scenes toy --presets quick --out /tmp/b.md
    .venv/bin/python tools/bench.py --scenes toy room --presets quick fast dense tiny multihead paper --budgets 45 120 \
        --ablations eq5-sum eq5-max eq3-scores focal detached --ablation-budget 45 --no-queries --plot \
        --out docs/tradeoff.md
    .venv/bin/python tools/bench.py --scenes room --presets fast --ablations distortion black-bg black-bg+distortion \
        --ablation-budget 170 --out docs/geometry.md      # what the room's walls need

Each build runs in a fresh subprocess (so peak memory is its own); the numbers in the document come
from this run only. Times are wall-clock on the machine that ran it (recorded in the document).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import queue as queue_module
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENES = {
    # name: (writer, description, its boxes in scenelabel.data.synthetic: the ground truth for ray queries)
    "toy": ("write_toy_scene", "toy two-box scene, 28 train + 4 held-out views, 96x72", "TOY_BOXES"),
    "room": ("write_furnished_room", "furnished room 6x6x2.6 m, 35 train + 5 held-out views, 160x120", "ROOM_BOXES"),
}
QUERY_POINTS = 1_000_000
QUERY_RAYS = 100_000
REPEATS = 3
DEFAULT_BUDGET = 170.0  # training cap (s): with scene load and evaluation a build stays within 180 s
# Targets of the end-to-end and planner-maps issues, checked against the run (never typed by hand):
# (scene or None for every scene, description, the row key the target needs, predicate on a row)
TARGETS = (
    ("toy", "mIoU >= 0.95 with build <= 60 s", "miou", lambda r: r["miou"] >= 0.95 and r["build_seconds"] <= 60),
    (
        "room",
        "mIoU >= 0.90 and PSNR >= 28 dB with build <= 180 s",
        "miou",
        lambda r: r["miou"] >= 0.90 and r["psnr"] >= 28 and r["build_seconds"] <= 180,
    ),
    (None, "query_points >= 1M points/s", "query_points_per_second", lambda r: r["query_points_per_second"] >= 1e6),
    # the planner-maps issue
    (None, "query_points >= 2M points/s", "query_points_per_second", lambda r: r["query_points_per_second"] >= 2e6),
    (None, "query_rays (the field) >= 200k rays/s", "query_rays_per_second", lambda r: r["query_rays_per_second"] >= 2e5),
    (None, "cast_rays (the map) >= 200k rays/s", "map_rays_per_second", lambda r: r["map_rays_per_second"] >= 2e5),
    (None, "query_points (baked at the default spacing) >= 2M points/s", "baked", lambda r: r["baked"][0]["points_per_second"] >= 2e6),
    (None, "query_rays (baked at the default spacing) >= 200k rays/s", "baked", lambda r: r["baked"][0]["rays_per_second"] >= 2e5),
    ("room", "map with the visibility rule <= 10 s", "map_seconds", lambda r: r["map_seconds"] <= 10),
)

DEFAULT_PRESET = "fast"
SPEEDUP = 50.0
"""Target of the model-family issue: the default preset reaches the `paper` preset's best held-out
PSNR and mIoU at least this many times sooner (training wall time, same scene, same run)."""
PROBE_MARGIN = 0.9
"""The default preset's probe run gets this fraction of (paper's training time / SPEEDUP) as its
budget, so that the step that crosses the budget still ends within the target."""


# Ablations of the seed paper's choices (config overrides on top of the preset); "-" = the preset as is.
VARIANTS: dict[str, dict] = {
    "-": {},
    "eq5-sum": {"field": {"class_head": "density", "density_combine": "sum"}},
    "eq5-max": {"field": {"class_head": "density", "density_combine": "max"}},
    "eq3-scores": {"field": {"semantic_rendering": "scores"}},
    "focal": {"train": {"semantic_loss": "focal", "focal_gamma": 2.0}},
    "detached": {"train": {"detach_semantic_weights": True}},
    # geometry: mip-NeRF 360's distortion loss; a black background (no white to fill a ray that is
    # not opaque); both
    "distortion": {"train": {"distortion_weight": 0.002}},
    "black-bg": {"train": {"background": None}},
    "black-bg+distortion": {"train": {"background": None, "distortion_weight": 0.002}},
    # sampling: the fast preset's marching before 288 steps across the box
    "steps-192": {"sampling": {"n_steps": 192}},
    # the density grid refreshed from random points alone (the default), or also raised by training samples
    "no-grid-from-training": {"sampling": {"grid_from_training": False}},
    "grid-from-training": {"sampling": {"grid_from_training": True}},
    # the density grid's decay without depth: "auto" gives 0.8 to a build whose only depth is its room layout
    "decay-0.95": {"sampling": {"grid_decay": 0.95}},
    # the worst-coloured 1 % of each step's rays re-open their density-grid cells (sampling.grid_reopen)
    "reopen": {"sampling": {"grid_reopen": 0.01}},
    "reopen-seed-1": {"sampling": {"grid_reopen": 0.01}, "train": {"seed": 1}},
    "reopen-seed-2": {"sampling": {"grid_reopen": 0.01}, "train": {"seed": 2}},
    # ... or those whose rendered class is wrong (sampling.grid_reopen_by "labels")
    "reopen-labels": {"sampling": {"grid_reopen": 0.01, "grid_reopen_by": "labels"}},
    # each step adds N class-balanced rays that march every cell, whatever the grid holds (sampling.grid_open_rays)
    "open-16": {"sampling": {"grid_open_rays": 16}},
    "open-16-seed-1": {"sampling": {"grid_open_rays": 16}, "train": {"seed": 1}},
    "open-16-seed-2": {"sampling": {"grid_open_rays": 16}, "train": {"seed": 2}},
    # every density-grid cell marched for the first N steps (sampling.grid_warmup)
    "warmup-128": {"sampling": {"grid_warmup": 128}},
    "warmup-128-seed-1": {"sampling": {"grid_warmup": 128}, "train": {"seed": 1}},
    "warmup-128-seed-2": {"sampling": {"grid_warmup": 128}, "train": {"seed": 2}},
    # the same build with another training seed (`train.seed`, default 0: initial weights, rays drawn)
    "seed-1": {"train": {"seed": 1}},
    "seed-2": {"train": {"seed": 2}},
    "no-train-stop": {"sampling": {"train_min_trans": 0.0}},  # training marches every occupied sample
    "no-train-stop-seed-1": {"sampling": {"train_min_trans": 0.0}, "train": {"seed": 1}},
    "no-train-stop-seed-2": {"sampling": {"train_min_trans": 0.0}, "train": {"seed": 2}},
}


def _ray_accuracy(label: np.ndarray, depth: np.ndarray, truth) -> dict:
    """How often rays get the true answer (class where the true ray hits a box, FREE where it hits
    none) and the median depth error where both the truth and the answer are a class."""
    from scenelabel import FREE

    true_label = np.where(truth.hit, truth.class_id, FREE)
    both = truth.hit & (label >= 0)
    return {
        "label_accuracy": float(np.mean(label == true_label)),
        "depth_median_error": float(np.median(np.abs(depth - truth.depth)[both])) if both.any() else None,
    }


def query_inputs(field) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The benchmark's query inputs for a field: QUERY_POINTS uniform points in its bounds [N, 3],
    and QUERY_RAYS rays from the middle half of the bounds in random directions (origins,
    directions [M, 3] each); seeded, so every run and script asks the same questions."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(field.aabb[0], field.aabb[1], (QUERY_POINTS, 3))
    centre, quarter = field.aabb.mean(0), 0.25 * (field.aabb[1] - field.aabb[0])
    ray_origins = rng.uniform(centre - quarter, centre + quarter, (QUERY_RAYS, 3))
    ray_dirs = rng.normal(size=(QUERY_RAYS, 3))
    return pts, ray_origins, ray_dirs


BAKE_FRACTIONS = (1.0, 0.5)
"""Baked queries are measured with lattices at these fractions of the field's finest cell (1: a bake's default spacing)."""


def _time_baked(field, inputs, field_answers, truth) -> list[dict]:
    """Per BAKE_FRACTIONS: bake time and memory, query_points / query_rays rates (medians of
    REPEATS) and how the baked answers compare with the field's and with the truth."""
    from scenelabel import BakedField

    pts, ray_origins, ray_dirs = inputs
    field_pts, field_rays = field_answers
    out = []
    for fraction in BAKE_FRACTIONS:
        t0 = time.perf_counter()
        baked = BakedField.from_field(field, fraction * field.finest_cell())
        bake_seconds = time.perf_counter() - t0
        baked.query_points(pts[:10])  # compiled on first use (cached on disk after): not timed
        baked.query_rays(ray_origins[:10], ray_dirs[:10])
        q_times, ray_times = [], []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            baked_pts = baked.query_points(pts)
            q_times.append(time.perf_counter() - t0)
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            baked_rays = baked.query_rays(ray_origins, ray_dirs)
            ray_times.append(time.perf_counter() - t0)
        both_hit = (baked_rays.label >= 0) & (field_rays.label >= 0)  # (a ray without a hit has depth inf)
        depth_gap = np.abs(baked_rays.depth[both_hit] - field_rays.depth[both_hit])
        out.append({
            "voxel_size": baked.voxel_size,
            "vertices": int(baked.density.size),
            "megabytes": baked.nbytes / 1e6,
            "bake_seconds": bake_seconds,
            "points_per_second": QUERY_POINTS / statistics.median(q_times),
            "rays_per_second": QUERY_RAYS / statistics.median(ray_times),
            "point_labels_as_field": float(np.mean(baked_pts.label == field_pts.label)),
            "ray_labels_as_field": float(np.mean(baked_rays.label == field_rays.label)),
            "ray_depth_vs_field_median": float(np.median(depth_gap)) if depth_gap.size else None,
            "ray_depth_vs_field_p99": float(np.quantile(depth_gap, 0.99)) if depth_gap.size else None,
            "rays_truth": _ray_accuracy(baked_rays.label, baked_rays.depth, truth),
        })
    return out


def _time_queries(field, boxes) -> dict:
    """query_points, query_rays, occupancy_map and cast_rays timings of a field (medians of
    REPEATS), and the rays' answers against the scene's true boxes."""
    from scenelabel.data import synthetic

    pts, ray_origins, ray_dirs = query_inputs(field)
    q_times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        field_pts = field.query_points(pts)
        q_times.append(time.perf_counter() - t0)
    ray_times = []  # depth + label, no colour
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        field_rays = field.query_rays(ray_origins, ray_dirs, with_rgb=False)
        ray_times.append(time.perf_counter() - t0)
    m_times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        occ = field.occupancy_map()
        m_times.append(time.perf_counter() - t0)
    cast_times = []  # the same rays through the map
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        map_rays = occ.cast_rays(ray_origins, ray_dirs)
        cast_times.append(time.perf_counter() - t0)
    truth = synthetic.cast_rays(ray_origins, ray_dirs, getattr(synthetic, boxes))
    return {
        "query_points_per_second": QUERY_POINTS / statistics.median(q_times),
        "query_rays_per_second": QUERY_RAYS / statistics.median(ray_times),
        "map_seconds": statistics.median(m_times),
        "map_voxels": int(np.prod(occ.shape)),
        "map_voxel_size": occ.voxel_size,
        "map_rays_per_second": QUERY_RAYS / statistics.median(cast_times),
        "field_rays_truth": _ray_accuracy(field_rays.label, field_rays.depth, truth),
        "map_rays_truth": _ray_accuracy(map_rays.label, map_rays.depth, truth),
        "baked": _time_baked(field, (pts, ray_origins, ray_dirs), (field_pts, field_rays), truth),
    }


def _one_build(spec: dict, workdir: str, queue) -> None:
    """Child process: write the scene, build it, time queries and the map; put a result dict on queue.

    spec: {"scene", "preset", "variant", "steps" (or None), "budget" (or None)}.
    """
    import torch

    import scenelabel
    from scenelabel import SemanticField, build, preset

    torch.set_num_threads(os.cpu_count() or 1)
    scene_name, preset_name, budget = spec["scene"], spec["preset"], spec["budget"]
    writer = getattr(scenelabel, SCENES[scene_name][0])
    scene_dir = writer(Path(workdir) / scene_name)
    overrides = json.loads(json.dumps(VARIANTS[spec["variant"]]))  # a deep copy
    train = overrides.setdefault("train", {})
    if spec["steps"] is not None:
        train["steps"] = spec["steps"]
    if budget is not None:
        train["time_budget"] = budget
    overrides["output"] = {"write_map": False}
    config = preset(preset_name, overrides)
    t0 = time.perf_counter()
    try:
        result = build(scene_dir, Path(workdir) / f"{scene_name}-{preset_name}", config, progress=False)
    except Exception as error:  # e.g. a diverged build: a row that says so, and the run goes on
        queue.put({"scene": scene_name, "preset": preset_name, "variant": spec["variant"], "time_budget": budget,
                   "failed": f"{type(error).__name__}: {error}"})
        return
    build_seconds = time.perf_counter() - t0
    field: SemanticField = result.field
    queries = _time_queries(field, SCENES[scene_name][2]) if spec.get("queries", True) else {}
    m = result.metrics
    queue.put(
        {
            "scene": scene_name,
            "preset": preset_name,
            "variant": spec["variant"],
            "time_budget": budget,
            "budget_reached": budget is not None and m["train_seconds"] >= budget,
            "build_seconds": build_seconds,
            "train_seconds": m["train_seconds"],
            "steps": m["steps"],
            "steps_per_second": m["steps_per_second"],
            "psnr": m.get("psnr"),
            "ssim": m.get("ssim"),
            "miou": m.get("miou"),
            "miou_smoothed": m.get("miou_smoothed"),
            "depth_error": m.get("depth_error"),
            "render_ms": 1000 * statistics.median(v["render_seconds"] for v in m["per_view"]),
            **queries,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        }
    )


def run_in_child(target, spec: dict) -> dict:
    """``target(spec, workdir, queue)`` in a fresh spawned process with its own temporary folder
    (so peak memory is its own); returns the dict it puts on the queue."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    with tempfile.TemporaryDirectory() as workdir:
        proc = ctx.Process(target=target, args=(spec, workdir, queue))
        proc.start()
        while True:  # a child that dies (an exception, the OOM killer) puts nothing: stop, do not wait forever
            try:
                result = queue.get(timeout=5.0)
                break
            except queue_module.Empty:
                if not proc.is_alive():
                    raise RuntimeError(f"{target.__name__} died (exit code {proc.exitcode}) on {spec}") from None
        proc.join()
    return result


def run_one(spec: dict) -> dict:
    """One build's row, with the machine's speed just before it (``reference_seconds``)."""
    reference = reference_seconds()
    return {**run_in_child(_one_build, spec), "reference_seconds": reference}


REFERENCE_PASSES = 10
REFERENCE_POINTS = 16384


def reference_seconds(repeats: int = 3) -> float:
    """How fast this machine is now: seconds of a fixed workload, the best of ``repeats`` (the least
    disturbed): REFERENCE_PASSES forward and backward passes of the default preset's field (8
    classes) on REFERENCE_POINTS seeded points, on torch's default threads. The machines these
    documents run on vary in speed from day to day; the timings of two documents compare through
    the ratio of their reference times, which tools/bench_suite.py records before each build."""
    import torch

    from scenelabel.config import preset
    from scenelabel.fields.model import FieldNetwork

    generator = torch.Generator().manual_seed(0)
    model = FieldNetwork(preset("fast").field, 8, torch.tensor([[-1.0] * 3, [1.0] * 3]))
    points = torch.rand(REFERENCE_POINTS, 3, generator=generator) * 2 - 1
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(REFERENCE_PASSES):
            sigmas, h, _ = model.features(points)
            (sigmas.mean() + h.mean()).backward()
        best = min(best, time.perf_counter() - t0)
    return best


def reference_line(rows: list[dict]) -> list[str]:
    """The machine's speed over a run (rows that recorded ``reference_seconds``), as one line; none without."""
    refs = [r["reference_seconds"] for r in rows if r.get("reference_seconds") is not None]
    if not refs:
        return []
    return [f"Machine speed: a fixed workload (tools/bench.py `reference_seconds`) took {statistics.median(refs):.2f} s "
            f"before the builds (median; {min(refs):.2f}-{max(refs):.2f}); another document's timings compare with "
            "these through the ratio of its reference time to this one."]


def fmt(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def _map_cell(r: dict) -> str:
    if r.get("map_seconds") is None:
        return "n/a"
    return f"{r['map_seconds']:.2f} ({r['map_voxels']:,} @ {r['map_voxel_size']:.3f})"


def _truth_cells(r: dict) -> str:
    if r.get("field_rays_truth") is None:
        return "n/a | n/a"
    f, m = r["field_rays_truth"], r["map_rays_truth"]
    labels = f"{f['label_accuracy']:.1%} / {m['label_accuracy']:.1%}"
    return f"{labels} | {fmt(f['depth_median_error'], '.3f')} / {fmt(m['depth_median_error'], '.3f')}"


def _baked_table(rows: list[dict]) -> list[str]:
    """The baked-queries table (rows that measured queries), or nothing."""
    measured = [r for r in rows if r.get("baked")]
    if not measured:
        return []
    lines = [
        "",
        "Baked queries (`BakedField.from_field(field, voxel_size)`: the field evaluated once on a vertex lattice, "
        "then queried by trilinear interpolation in compiled loops; same points and rays as above, medians of "
        f"{REPEATS}). Lattices at {' and '.join(f'{f:g}' for f in BAKE_FRACTIONS)} x the field's finest cell (1: the default spacing). "
        "\"as the field\": the share of answers equal to the field's own `query_points` / `query_rays` labels, and "
        "the baked ray depth's distance to the field's where both hit a class (median / p99).",
        "",
        "| scene | preset | variant | budget s | bake voxel | vertices | MB | bake s | query_points pts/s | "
        "query_rays rays/s | point labels as the field | ray labels as the field | ray depth vs the field median / p99 | "
        "ray labels vs truth | ray depth error vs truth |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in measured:
        for b in r["baked"]:
            t = b["rays_truth"]
            lines.append(
                f"| {r['scene']} | {r['preset']} | {r['variant']} | {fmt(r.get('time_budget'), '.0f')} | "
                f"{b['voxel_size']:.3f} | {b['vertices']:,} | {b['megabytes']:.0f} | {b['bake_seconds']:.2f} | "
                f"{b['points_per_second']:,.0f} | {b['rays_per_second']:,.0f} | {b['point_labels_as_field']:.2%} | "
                f"{b['ray_labels_as_field']:.2%} | {fmt(b['ray_depth_vs_field_median'], '.3f')} / "
                f"{fmt(b['ray_depth_vs_field_p99'], '.3f')} | {t['label_accuracy']:.1%} | "
                f"{fmt(t['depth_median_error'], '.3f')} |"
            )
    return lines


def write_markdown(rows: list[dict], path: Path, command: str, plot: Path | None) -> None:
    """The document; builds that raised (rows with "failed") are listed apart, in no table, pick or target."""
    failed = [r for r in rows if "failed" in r]
    rows = [r for r in rows if "failed" not in r]
    lines = [
        "# Benchmarks",
        "",
        "Generated by `tools/bench.py`; every number below comes from one run of:",
        "",
        f"    {command}",
        "",
        (f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, torch {__import__('torch').__version__}, "
        f"run on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}."),
        *reference_line(rows),
        "",
        "Scenes (synthetic, exact labels and depth; held out: every 8th view):",
        "",
    ]
    lines += [f"- `{name}`: {desc}" for name, (_, desc, _) in SCENES.items() if any(r["scene"] == name for r in rows)]
    lines += [
        "",
        ("Training stops at the preset's steps or at the budget, whichever comes first (with a budget, "
        "the learning-rate schedule follows the elapsed fraction of it). "
        "Build = scene load + training + held-out evaluation (map not included). query_points: "
        f"{QUERY_POINTS:,} random points in the bounds, density + label (median of {REPEATS}). "
        f"query_rays: {QUERY_RAYS:,} rays from the middle of the bounds in random directions, depth + label "
        f"(median of {REPEATS}). "
        f"Map: `occupancy_map()` at the default voxel size, with the visibility rule (median of {REPEATS}). "
        "cast_rays: the query_rays rays cast through that map (`OccupancyMap.cast_rays`, numpy; median of "
        f"{REPEATS}). Ray answers vs truth: the fraction of those rays labelled as the scene's exact boxes say "
        "(the class hit, FREE for none), from the field (`query_rays`) / from the map (`cast_rays`), and the "
        "median depth error (world units) where both the truth and the answer are a class. "
        "Render ms/frame: the median over the held-out views of rendering one (rgb, depth, labels). Peak memory: "
        "the build process's maximum resident set."),
        "",
        "| scene | preset | variant | budget s | steps | train s | steps/s | build s | PSNR | SSIM | mIoU | "
        "mIoU smoothed | depth abs rel | render ms/frame | query_points pts/s | query_rays rays/s | map s (voxels) | "
        "cast_rays rays/s | ray labels vs truth field / map | ray depth error field / map | peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['preset']} | {r['variant']} | {fmt(r.get('time_budget'), '.0f')} | {r['steps']} | "
            f"{r['train_seconds']:.1f} | {r['steps_per_second']:.1f} | "
            f"{r['build_seconds']:.1f} | {fmt(r['psnr'], '.2f')} | {fmt(r['ssim'], '.3f')} | {fmt(r['miou'], '.3f')} | "
            f"{fmt(r['miou_smoothed'], '.3f')} | {fmt(r['depth_error'], '.4f')} | {r['render_ms']:.0f} | "
            f"{fmt(r.get('query_points_per_second'), ',.0f')} | {fmt(r.get('query_rays_per_second'), ',.0f')} | "
            f"{_map_cell(r)} | {fmt(r.get('map_rays_per_second'), ',.0f')} | {_truth_cells(r)} | {r['peak_rss_mb']:.0f} |"
        )
    lines += _baked_table(rows)
    if plot is not None:
        lines += ["", f"![mIoU and PSNR against build time, one line per preset]({plot.name})"]
    lines += ["", "Which preset to pick (best held-out mIoU among the presets as they are, per scene and budget):", ""]
    lines += [f"- {line}" for line in pick_lines(rows)]
    lines += ["", "Targets (end-to-end and planner-maps issues, 2 cores), checked against the rows above:", ""]
    lines += [f"- {line}" for line in target_lines(rows)]
    speedup = speedup_lines(rows)
    if speedup:
        lines += [
            "",
            f"`{DEFAULT_PRESET}` against the seed paper's NeRF (`paper`: coarse 64 + fine 128 samples, 8 x 256 MLP), "
            f"target {SPEEDUP:.0f}x sooner in training wall time. `paper`'s best is its longest run here; "
            f"`{DEFAULT_PRESET}` gets one more run per scene with {PROBE_MARGIN:g} x (that run's training time / "
            f"{SPEEDUP:.0f}) as its budget:",
            "",
        ]
        lines += [f"- {line}" for line in speedup]
    if failed:
        lines += ["", "Builds that failed:", ""]
        lines += [f"- {r['scene']} / {r['preset']} [{r['variant']}]: {r['failed']}" for r in failed]
    lines += ["", f"Raw results: `{path.with_suffix('.json').name}`.", ""]
    lines += _kept_sections(path)
    path.write_text("\n".join(lines))
    path.with_suffix(".json").write_text(json.dumps(rows + failed, indent=2))


KEPT_SECTIONS = ("bench_ddp", "bench_real", "bench_map_export")
"""Sections other scripts write into the same document (between ``<!-- NAME: begin -->`` and
``<!-- NAME: end -->``): kept as they are when this script rewrites it."""


def write_kept_section(doc: Path, name: str, section: str) -> None:
    """Put ``section`` (text, without its markers) into ``doc`` between ``<!-- NAME: begin -->`` and
    ``<!-- NAME: end -->``, replacing what was there, or appended at the end: the sections other
    scripts write into docs/benchmarks.md, which this script keeps (KEPT_SECTIONS)."""
    begin, end = f"<!-- {name}: begin -->", f"<!-- {name}: end -->"
    marked = f"{begin}\n{section.strip(chr(10))}\n{end}"
    text = doc.read_text() if doc.exists() else ""
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + marked + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + marked + "\n"
    doc.write_text(text)


def _kept_sections(path: Path) -> list[str]:
    text = path.read_text() if path.exists() else ""
    kept = []
    for name in KEPT_SECTIONS:
        begin, end = f"<!-- {name}: begin -->", f"<!-- {name}: end -->"
        if begin in text and end in text:
            kept += [begin + text.split(begin, 1)[1].split(end, 1)[0] + end, ""]
    return kept


def pick_lines(rows: list[dict]) -> list[str]:
    """Per scene and budget: the preset with the best held-out mIoU (variant "-" rows only)."""
    out = []
    plain = [r for r in rows if r["variant"] == "-" and r["miou"] is not None]
    for scene in dict.fromkeys(r["scene"] for r in plain):
        for budget in sorted({r["time_budget"] or 0 for r in plain if r["scene"] == scene}):
            # a run that finished before a smaller budget also stands for this one
            cands = [r for r in plain if r["scene"] == scene and (r["time_budget"] or 0) <= budget
                     and ((r["time_budget"] or 0) == budget or not r["budget_reached"])]
            best = max(cands, key=lambda r: r["miou"])
            out.append(
                f"{scene}, {f'{budget:.0f} s' if budget else 'no budget'}: `{best['preset']}` ({best['miou']:.3f} mIoU, {best['psnr']:.2f} dB "
                f"after {best['train_seconds']:.0f} s of training)"
            )
    return out


def write_plot(rows: list[dict], path: Path) -> None:
    """mIoU and PSNR against build time, one line per (scene, preset) over its budgets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    plain = [r for r in rows if r["variant"] == "-" and r["miou"] is not None]
    for (scene, name) in dict.fromkeys((r["scene"], r["preset"]) for r in plain):
        pts = sorted((r["build_seconds"], r["miou"], r["psnr"]) for r in plain if (r["scene"], r["preset"]) == (scene, name))
        style = "-o" if scene == "room" else "--s"
        for ax, k in zip(axes, (1, 2)):
            ax.plot([p[0] for p in pts], [p[k] for p in pts], style, label=f"{scene} / {name}")
    for ax, label in zip(axes, ("held-out mIoU", "held-out PSNR (dB)")):
        ax.set_xscale("log")
        ax.set_xlabel("build wall time (s, log scale)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def target_lines(rows: list[dict]) -> list[str]:
    """One line per target: met or not, and by which row."""
    out = []
    for scene, text, needs, ok in TARGETS:
        cands = [r for r in rows if (scene is None or r["scene"] == scene) and r.get(needs) is not None]
        if not cands:
            continue
        passing = [r for r in cands if ok(r)]
        if scene is None:
            verdict = "met by every row" if len(passing) == len(cands) else (
                "not met by " + ", ".join(f"{r['scene']}/{r['preset']}" for r in cands if r not in passing)
            )
        elif passing:
            best = min(passing, key=lambda r: r["build_seconds"])
            detail = (
                f"{best['miou']:.3f} mIoU, {best['psnr']:.2f} dB, build {best['build_seconds']:.0f} s"
                if needs == "miou"
                else f"{needs.replace('_', ' ')} {best[needs]:.3g}"
            )
            verdict = f"met by `{best['preset']}` ({detail})"
        else:
            verdict = "**not met**"
        out.append(f"{scene or 'all'}: {text}: {verdict}")
    return out


def _paper_best(rows: list[dict], scene: str) -> dict | None:
    """The `paper` preset's longest run on ``scene`` (variant "-"), or None."""
    paper = [r for r in rows if (r["scene"], r["preset"], r["variant"]) == (scene, "paper", "-") and r.get("miou") is not None]
    return max(paper, key=lambda r: r["train_seconds"]) if paper else None


def probe_specs(rows: list[dict], args: argparse.Namespace) -> list[dict]:
    """Per scene where `paper` ran: the default preset with PROBE_MARGIN x paper's time / SPEEDUP as budget."""
    if "paper" not in args.presets or DEFAULT_PRESET not in args.presets:
        return []
    specs = []
    for scene in args.scenes:
        best = _paper_best(rows, scene)
        if best is not None:
            budget = round(PROBE_MARGIN * best["train_seconds"] / SPEEDUP, 2)
            specs.append({"scene": scene, "preset": DEFAULT_PRESET, "variant": "-", "steps": args.steps, "budget": budget})
    return specs


def speedup_lines(rows: list[dict]) -> list[str]:
    """Per scene: when the default preset first reached `paper`'s best PSNR and mIoU, and the ratio."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        best = _paper_best(rows, scene)
        if best is None:
            continue
        head = (
            f"{scene}: `paper`'s best is {best['psnr']:.2f} dB, {best['miou']:.3f} mIoU after "
            f"{best['train_seconds']:.0f} s of training ({best['steps']} steps)"
        )
        default = [r for r in rows if (r["scene"], r["preset"], r["variant"]) == (scene, DEFAULT_PRESET, "-")]
        reached = [r for r in default if r["miou"] is not None and r["psnr"] >= best["psnr"] and r["miou"] >= best["miou"]]
        if not reached:
            out.append(f"{head}; no `{DEFAULT_PRESET}` run reached both: **not met**")
            continue
        first = min(reached, key=lambda r: r["train_seconds"])
        ratio = best["train_seconds"] / first["train_seconds"]
        verdict = "met" if ratio >= SPEEDUP else "**not met**"
        out.append(
            f"{head}; `{DEFAULT_PRESET}` had both after {first['train_seconds']:.1f} s ({first['psnr']:.2f} dB, "
            f"{first['miou']:.3f} mIoU, {first['steps']} steps): at least {ratio:.0f}x sooner: {verdict}"
        )
    return out


def plan(args: argparse.Namespace) -> list[dict]:
    """The run specs: scenes x presets x budgets, then the ablation variants."""
    budgets = sorted({b or None for b in args.budgets}, key=lambda b: b or math.inf)
    specs = [
        {"scene": scene, "preset": name, "variant": "-", "steps": args.steps, "budget": b}
        for scene in args.scenes
        for name in args.presets
        for b in budgets
    ]
    specs += [
        {"scene": scene, "preset": args.ablation_preset, "variant": v, "steps": args.steps, "budget": args.ablation_budget}
        for scene in args.ablation_scenes
        for v in args.ablations
    ]
    return specs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--presets", nargs="+", default=["quick", "fast"])
    parser.add_argument("--steps", type=int, help="override every preset's steps")
    parser.add_argument(
        "--budgets", nargs="+", type=float, default=[DEFAULT_BUDGET],
        help=f"training time caps in seconds, one run each (default {DEFAULT_BUDGET:.0f}; 0: none)",
    )
    parser.add_argument("--ablations", nargs="*", default=[], choices=[v for v in VARIANTS if v != "-"])
    parser.add_argument("--ablation-scenes", nargs="+", default=["room"], choices=list(SCENES))
    parser.add_argument("--ablation-preset", default="fast")
    parser.add_argument("--ablation-budget", type=float, default=60.0)
    parser.add_argument("--out", default=str(REPO / "docs" / "benchmarks.md"))
    parser.add_argument("--plot", action="store_true", help="also write <out>.png: mIoU and PSNR against time")
    parser.add_argument(
        "--no-queries", action="store_true",
        help="skip the query_points / query_rays / map timings (MLP presets take minutes for a map)",
    )
    args = parser.parse_args()
    command = "python tools/bench.py " + " ".join(sys.argv[1:])
    rows: list[dict] = []
    finished_early: set[tuple] = set()  # (scene, preset): a run ended before its budget
    for spec in plan(args):
        spec["queries"] = not args.no_queries
        key = (spec["scene"], spec["preset"], spec["variant"])
        if key in finished_early:
            continue  # a larger budget would repeat the same run
        row = run_one(spec)
        print(json.dumps(row), flush=True)
        rows.append(row)
        if not row.get("budget_reached", True):  # a failed build says nothing of larger budgets
            finished_early.add(key)
    for spec in probe_specs(rows, args):  # the speed-up target's run (after paper's, whose time sets its budget)
        spec["queries"] = False
        row = run_one(spec)
        print(json.dumps(row), flush=True)
        rows.append(row)
    out = Path(args.out)
    plot = out.with_suffix(".png") if args.plot else None
    if plot is not None:
        write_plot([r for r in rows if "failed" not in r], plot)
    write_markdown(rows, out, command.strip(), plot)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
