"""The same training steps, two versions of the code: milliseconds per step on suite rooms.

    .venv/bin/python tools/bench_step_ab.py --base HEAD                     # docs/step_ab.md and .json
    .venv/bin/python tools/bench_step_ab.py --base HEAD~1 --scenes office-5x4 --captures - --out /tmp/ab.md
    .venv/bin/python tools/bench_step_ab.py --rewrite                       # the document again from its .json

Each suite room (scenelabel.data.suite) is written once, as it is (capture `-`) and with depth as a
phone gives it (`phone-depth`: scenelabel.data.synthetic.add_phone_depth). Then, ROUNDS times, the
code of ``--base`` (a git worktree put first on ``PYTHONPATH``) and the working tree, one after the
other in fresh processes, prepare the `fast` preset's training of the room for WARMUP + STEPS steps
(same seed, the same rays drawn), take WARMUP steps and time the last STEPS one by one: the end of
a short run, where the density grid has emptied what the field has. A step's time is the median
over its version's STEPS x ROUNDS steps; the ratio base / new compares medians taken in the same
run. Samples per ray (their mean over the timed steps) show that both did the same work.
Training is driven by steps alone here (no time budget), so the machine's load changes the
times, never the steps. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_map_ab import base_worktree, generated_by, run_with, short_rev  # noqa: E402  (tools/, beside this script)

ROUNDS = 3
WARMUP = 300
STEPS = 100
DEFAULT_SCENES = ("office-5x4", "living-6x5")
CAPTURES = ("-", "phone-depth")

MEASURE = r'''
import json, time
import torch
torch.set_num_threads({threads})
from scenelabel import load_scene, preset
from scenelabel.train.pipeline import prepare_training

config = preset("fast", {{"train": {{"steps": {total}, "time_budget": None}}}})
trainer, _, _ = prepare_training(load_scene({scene_dir!r}), config, torch.device("cpu"))
for _ in range({warmup}):
    trainer.train_step()
seconds, samples = [], []
for _ in range({steps}):
    t0 = time.perf_counter()
    log = trainer.train_step()
    seconds.append(time.perf_counter() - t0)
    samples.append(log["samples_per_ray"])
print(json.dumps({{"seconds": seconds, "samples_per_ray": sum(samples) / len(samples)}}))
'''


def write_room(name: str, capture: str, workdir: Path) -> Path:
    """Suite room ``name`` written under ``workdir``, with phone-like depth for capture `phone-depth`."""
    from scenelabel.data.suite import suite_spec, write_suite_scene
    from scenelabel.data.synthetic import add_phone_depth

    scene_dir = write_suite_scene(workdir / f"{name}{'' if capture == '-' else '_' + capture}", suite_spec(name))
    if capture == "phone-depth":
        add_phone_depth(scene_dir)
    return scene_dir


def measure(code_root: Path, scene_dir: Path) -> dict:
    """Step times (s) and samples per ray with the package at ``code_root``, in a fresh process."""
    code = MEASURE.format(threads=os.cpu_count() or 1, scene_dir=str(scene_dir), total=WARMUP + STEPS,
                          warmup=WARMUP, steps=STEPS)
    return run_with(code_root, code, scene_dir.name)


def summarise(runs: list[dict]) -> dict:
    """The median step (ms) over all timed steps of a version's rounds, and its mean samples per ray."""
    return {"step_ms": 1000.0 * float(np.median(np.concatenate([r["seconds"] for r in runs]))),
            "samples_per_ray": float(np.mean([r["samples_per_ray"] for r in runs]))}


def write_markdown(r: dict, path: Path, command: str) -> None:
    lines = [
        "# Training-step code A/B on the same rooms",
        "",
        f"{generated_by(command)} The `fast` preset's training of each room for "
        f"{WARMUP + STEPS} steps, by the code of **{r['base']}** (base) and of **{r['new']}** (new), {ROUNDS} rounds "
        f"of the two one after the other, each in a fresh process: {WARMUP} steps, then the last {STEPS} timed. "
        f"Step: the median over a version's {ROUNDS * STEPS} timed steps; samples per ray: their mean (the same "
        "work). Capture `phone-depth`: the room with depth as a phone gives it (scenelabel.data.synthetic."
        "add_phone_depth), which the build trains on.",
        "",
        "| room | capture | step base → new (ms) | base / new | samples per ray base → new |",
        "|---|---|---|---|---|",
    ]
    for row in r["rows"]:
        b, n = row["base"], row["new"]
        lines.append(
            f"| {row['scene']} | {row['capture']} | {b['step_ms']:.1f} → {n['step_ms']:.1f} "
            f"| {b['step_ms'] / n['step_ms']:.2f}x | {b['samples_per_ray']:.1f} → {n['samples_per_ray']:.1f} |"
        )
    ratios = [row["base"]["step_ms"] / row["new"]["step_ms"] for row in r["rows"]]
    lines += ["", f"Median ratio base / new over the rows: {float(np.median(ratios)):.2f}x "
              f"(range {min(ratios):.2f}-{max(ratios):.2f}x)."]
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="HEAD", help="the git revision to compare the working tree with")
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    parser.add_argument("--captures", nargs="+", default=list(CAPTURES), choices=CAPTURES)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "step_ab.md")
    parser.add_argument("--rewrite", action="store_true", help="rewrite the document from the rows of OUT's .json")
    args = parser.parse_args()
    if args.rewrite:
        result = json.loads(args.out.with_suffix(".json").read_text())
        write_markdown(result, args.out, result["command"])
        print(f"wrote {args.out}")
        return
    from bench_suite import code_version

    command = " ".join(["python tools/bench_step_ab.py", *sys.argv[1:]])
    result = {"base": short_rev(args.base), "new": code_version(), "command": command, "rows": []}
    with tempfile.TemporaryDirectory() as workdir:
        work = Path(workdir)
        with base_worktree(args.base, work / "base") as base_tree:
            for scene in args.scenes:
                for capture in args.captures:
                    scene_dir = write_room(scene, capture, work)
                    runs: dict[str, list[dict]] = {"base": [], "new": []}
                    for _ in range(ROUNDS):
                        runs["base"].append(measure(base_tree, scene_dir))
                        runs["new"].append(measure(REPO, scene_dir))
                    row = {"scene": scene, "capture": capture, **{k: summarise(v) for k, v in runs.items()}}
                    print(f"{scene} [{capture}]: {row}", flush=True)
                    result["rows"].append(row)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    write_markdown(result, args.out, command)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
