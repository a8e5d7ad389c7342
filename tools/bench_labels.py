"""Noisy and sparse training labels, and Gaussian smoothing of rendered masks: write docs/labels.md.

    .venv/bin/python tools/bench_labels.py                       # toy scene, quick preset
    .venv/bin/python tools/bench_labels.py --scene room --preset fast --budget 120 --out /tmp/labels.md

Each build trains on the scene with its *training* label files altered (held-out labels stay clean):

- noise: random discs of wrong classes over 10-50% of each training mask
  (:func:`scenelabel.data.synthetic.corrupt_labels`);
- sparse: labels kept on only a fraction of the training views (the others train colour only).

Reported per build: the mIoU of the (corrupted) input masks against the clean masks of the same
training views, next to the mIoU of the field's rendered labels for those views against the same
clean masks (multi-view fusion repairs noise when the second is higher), and the held-out mIoU.
Then, for every build, a sweep of the smoothing σ applied to the rendered class probabilities
(held-out views): mIoU and boundary F1 (2 px tolerance). All numbers come from this run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
SIGMAS = (0.0, 0.5, 1.0, 2.0, 4.0)
BOUNDARY_TOLERANCE = 2.0


def _miou(pred_labels, true_labels, class_ids, ignore) -> float:
    from scenelabel.metrics import confusion_matrix, miou

    conf = sum(confusion_matrix(p, t, class_ids, ignore) for p, t in zip(pred_labels, true_labels))
    return float(miou(conf)[0])


def _alter_labels(src: Path, dst: Path, noise: float, label_fraction: float, seed: int) -> None:
    """Copy the scene folder and corrupt / drop its training label files (every 8th view held out)."""
    from scenelabel import load_scene
    from scenelabel.data.synthetic import corrupt_labels

    shutil.copytree(src, dst)
    scene = load_scene(dst)
    rng = np.random.default_rng(seed)
    tf = json.loads((dst / "transforms.json").read_text())
    train = [i for i in range(len(scene)) if i % 8]
    keep = set(rng.choice(train, max(1, round(label_fraction * len(train))), replace=False).tolist())
    ids = sorted(scene.classes)
    for i in train:
        path = dst / tf["frames"][i]["label_path"]
        if i not in keep:  # an unlabelled view: no label file, no label_path
            path.unlink()
            del tf["frames"][i]["label_path"]
            continue
        if noise > 0:
            noisy = corrupt_labels(scene.labels[i], noise, ids, rng, scene.ignore_index)
            Image.fromarray(noisy.astype(np.uint8)).save(path)
    (dst / "transforms.json").write_text(json.dumps(tf, indent=2))


def run_case(scene_dir: Path, work: Path, case: dict, preset_name: str, train_overrides: dict) -> dict:
    from scenelabel import build, load_scene, preset
    from scenelabel.metrics import boundary_f1

    altered = work / case["name"]
    _alter_labels(scene_dir, altered, case["noise"], case["label_fraction"], seed=1)
    clean = load_scene(scene_dir)
    noisy = load_scene(altered)
    train = [i for i in range(len(clean)) if i % 8]
    test = [i for i in range(len(clean)) if i % 8 == 0]
    overrides = {"output": {"write_map": False, "write_renders": False}, "train": train_overrides}
    t0 = time.perf_counter()
    result = build(altered, work / f"{case['name']}-out", preset(preset_name, overrides), progress=False)
    seconds = time.perf_counter() - t0
    field = result.field
    ids, ignore = field.class_ids, clean.ignore_index
    labelled = [i for i in train if noisy.labels[i] is not None]
    input_miou = _miou([noisy.labels[i] for i in labelled], [clean.labels[i] for i in labelled], ids, ignore)
    rendered_train = [field.render_camera(clean.cameras, i).label for i in labelled]
    fused_miou = _miou(rendered_train, [clean.labels[i] for i in labelled], ids, ignore)
    renders = [field.render_camera(clean.cameras, i) for i in test]
    sweep = []
    from scenelabel.query.postprocess import smooth_class_probs

    for sigma in SIGMAS:
        labels = []
        for out in renders:
            smoothed = smooth_class_probs(out.probs, sigma or None).argmax(-1)
            labels.append(np.where(out.label >= 0, field.class_map.ids_from_channels(smoothed), out.label))
        sweep.append(
            {
                "sigma": sigma,
                "miou": _miou(labels, [clean.labels[i] for i in test], ids, ignore),
                "boundary_f1": float(
                    np.mean([boundary_f1(p, clean.labels[i], BOUNDARY_TOLERANCE, ignore) for p, i in zip(labels, test)])
                ),
            }
        )
    return {
        **case,
        "build_seconds": seconds,
        "labelled_train_views": len(labelled),
        "input_miou": input_miou,
        "rendered_train_miou": fused_miou,
        "held_out_miou": result.metrics["miou"],
        "held_out_psnr": result.metrics["psnr"],
        "smoothing": sweep,
    }


def write_markdown(rows: list[dict], path: Path, command: str, scene: str, preset_name: str, budget) -> None:
    lines = [
        "# Noisy and sparse labels, and smoothing",
        "",
        "Generated by `tools/bench_labels.py`; every number below comes from one run of:",
        "",
        f"    {command}",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"run on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}. Scene `{scene}`, preset `{preset_name}`"
        + (f", {budget:.0f} s training budget." if budget else "."),
        "",
        "Training masks are altered, held-out masks stay clean. *Input mIoU*: the altered training masks "
        "against the clean ones. *Rendered mIoU*: the field's labels rendered at the same training views "
        "against the clean masks (the repair by multi-view fusion is the difference). *Held-out*: clean "
        "held-out views.",
        "",
        "| case | label noise | labelled train views | input mIoU | rendered mIoU (train views) | repair | held-out mIoU | held-out PSNR | build s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['name']} | {r['noise']:.0%} | {r['labelled_train_views']} | {r['input_miou']:.3f} | "
            f"{r['rendered_train_miou']:.3f} | {r['rendered_train_miou'] - r['input_miou']:+.3f} | "
            f"{r['held_out_miou']:.3f} | {r['held_out_psnr']:.2f} | {r['build_seconds']:.0f} |"
        )
    lines += [
        "",
        f"Gaussian smoothing of the rendered class probabilities (σ in pixels; 0 = none), held-out views: "
        f"mIoU / boundary F1 ({BOUNDARY_TOLERANCE:g} px tolerance).",
        "",
        "| case | " + " | ".join(f"σ = {s:g}" for s in SIGMAS) + " |",
        "|---|" + "---|" * len(SIGMAS),
    ]
    for r in rows:
        cells = [f"{s['miou']:.3f} / {s['boundary_f1']:.3f}" for s in r["smoothing"]]
        lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    lines += ["", f"Raw results: `{path.with_suffix('.json').name}`.", ""]
    path.write_text("\n".join(lines))
    path.with_suffix(".json").write_text(json.dumps(rows, indent=2))


CASES = (
    {"name": "clean", "noise": 0.0, "label_fraction": 1.0},
    {"name": "noise-10", "noise": 0.1, "label_fraction": 1.0},
    {"name": "noise-30", "noise": 0.3, "label_fraction": 1.0},
    {"name": "noise-50", "noise": 0.5, "label_fraction": 1.0},
    {"name": "sparse-25", "noise": 0.0, "label_fraction": 0.25},
    {"name": "sparse-10", "noise": 0.0, "label_fraction": 0.1},
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["toy", "room"], default="toy")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--budget", type=float, default=None, help="training time budget per build (s)")
    parser.add_argument("--steps", type=int, default=None, help="override the preset's steps")
    parser.add_argument("--cases", nargs="+", default=[c["name"] for c in CASES], choices=[c["name"] for c in CASES])
    parser.add_argument("--out", default=str(REPO / "docs" / "labels.md"))
    args = parser.parse_args()
    import torch

    from scenelabel import write_furnished_room, write_toy_scene

    torch.set_num_threads(os.cpu_count() or 1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        writer = write_toy_scene if args.scene == "toy" else write_furnished_room
        scene_dir = writer(work / "scene")
        for case in CASES:
            if case["name"] in args.cases:
                train = {"time_budget": args.budget} if args.budget else {}
                if args.steps:
                    train["steps"] = args.steps
                row = run_case(scene_dir, work, case, args.preset, train)
                print(json.dumps(row), flush=True)
                rows.append(row)
    command = "python tools/bench_labels.py " + " ".join(sys.argv[1:])
    write_markdown(rows, Path(args.out), command.strip(), args.scene, args.preset, args.budget)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
