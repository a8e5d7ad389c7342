"""The same builds, two versions of the query code: map time and the map's 3D metrics, render time.

    .venv/bin/python tools/bench_map_ab.py --base HEAD                      # docs/map_ab.md and .json
    .venv/bin/python tools/bench_map_ab.py --base HEAD~2 --scenes office-5x4 --out /tmp/ab.md

Suite rooms (scenelabel.data.suite) are built once with the working tree's code (the default
preset, ``auto``, with STEPS steps: a fixed step count, so the machine's load does not change the
build), then each build's ``occupancy_map(0.05)`` is made and scored by the code of ``--base`` (a
git worktree, put first on ``PYTHONPATH``) and by the working tree, each in a fresh process: the map's time
(the faster of REPEATS calls after a warm-up), and against the room's exact geometry, as
tools/bench_suite.py scores it, the labels of points 2 cm behind true surfaces and of free points
in front of them, the F-score at 5 cm, and the UNKNOWN fraction; and the time of a render of each
held-out view (median; 160x120 in the suite) and of a 320x240 render (the viewer's "render this
view") of the first, the faster of REPEATS, each version with its own default ray chunk
(``SamplingConfig.chunk_rays``: the build's config stores the chunk of the code that built it).
Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
STEPS = 2000
REPEATS = 2
DEFAULT_SCENES = ("office-5x4", "gallery-8x5", "den-5x5")

MEASURE = r'''
import json, sys, time
import numpy as np, torch
sys.path.insert(0, {tools!r})
torch.set_num_threads({threads})
from bench_suite import MAP_VOXEL, _probe_rays, _truth_points
from scenelabel import FREE, SemanticField, load_scene
from scenelabel import metrics as M
from scenelabel.data.suite import suite_geometry, suite_spec
from scenelabel.train.pipeline import choose_views

room = suite_spec({scene!r})
scene = load_scene({scene_dir!r})
field = SemanticField.load({build_dir!r})
_, test_idx, _ = choose_views(scene, field.config.train.holdout)
rng = np.random.default_rng(0)
o, d, z, true_class = _probe_rays(scene, test_idx, rng)
surface, free, ray_index = M.probe_points(o, d, z, rng=rng)
field.occupancy_map(MAP_VOXEL)
times = []
for _ in range({repeats}):
    t0 = time.perf_counter()
    occ = field.occupancy_map(MAP_VOXEL)
    times.append(time.perf_counter() - t0)
geometry = suite_geometry(room)
lo, hi = M.boxes_lo_hi(geometry.boxes)
occupied = occ.world_from_index(np.argwhere(occ.occupied))
f = M.surface_fscore(occupied, _truth_points(scene, rng), M.FSCORE_THRESHOLD, lo, hi)
import dataclasses, statistics
from scenelabel.config import SamplingConfig
sampling = dataclasses.replace(field.config.sampling, chunk_rays=SamplingConfig().chunk_rays)
field.config = dataclasses.replace(field.config, sampling=sampling)
render_times = []
for i in [test_idx[0], *test_idx]:  # the first again: a warm-up
    t0 = time.perf_counter()
    field.render_camera(scene.cameras, i)
    render_times.append(time.perf_counter() - t0)
cam = scene.cameras[test_idx[0]]
viewer_times = []
for _ in range({repeats}):
    t0 = time.perf_counter()
    field.render(cam.c2w[0], 2 * int(cam.width[0]), 2 * int(cam.height[0]), (2 * cam.fx[0], 2 * cam.fy[0]))
    viewer_times.append(time.perf_counter() - t0)
print(json.dumps({{
    "render_seconds": statistics.median(render_times[1:]),
    "render_size": [int(cam.width[0]), int(cam.height[0])],
    "viewer_render_seconds": min(viewer_times),
    "map_seconds": min(times),
    "surface_map": M.label_accuracy(occ.label_at(surface), true_class[ray_index]),
    "free_map": M.label_accuracy(occ.label_at(free), np.full(len(free), FREE)),
    "fscore": f["fscore"],
    "unknown": float((occ.label == -2).mean()),
}}))
'''


def build_room(name: str, workdir: Path) -> tuple[Path, Path, str]:
    """(scene folder, build folder, set) of suite room ``name``, built with STEPS steps; set as
    tools/probe_layout.py's ``room_set``: "tuning", "held out" or "pool"."""
    from probe_layout import room_set  # tools/probe_layout.py, beside this script

    from scenelabel import build, preset
    from scenelabel.config import AUTO_PRESET
    from scenelabel.data.suite import suite_spec, write_suite_scene

    room = suite_spec(name)
    scene_dir = write_suite_scene(workdir / room.name, room)
    config = preset(AUTO_PRESET, {"train": {"steps": STEPS, "time_budget": 1e9},
                                  "output": {"write_map": False, "write_renders": False}})
    build(scene_dir, workdir / f"{room.name}_build", config, progress=False)
    return scene_dir, workdir / f"{room.name}_build", room_set(room.name)


def measure(code_root: Path, scene: str, scene_dir: Path, build_dir: Path) -> dict:
    """The map's time and metrics with the package at ``code_root``, in a fresh process."""
    code = MEASURE.format(tools=str(REPO / "tools"), threads=os.cpu_count() or 1, scene=scene, scene_dir=str(scene_dir),
                          build_dir=str(build_dir), repeats=REPEATS)
    return run_with(code_root, code, scene)


def run_with(code_root: Path, code: str, what: str) -> dict:
    """Run Python ``code`` in a fresh process with the package at ``code_root`` first on the path;
    the JSON object its last line prints."""
    env = {**os.environ, "PYTHONPATH": str(code_root)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=code_root, env=env)
    if out.returncode != 0:
        raise RuntimeError(f"{what} with {code_root}:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def generated_by(command: str) -> str:
    """The first sentence of an A/B document: its command, the date and the machine."""
    return (f"Generated by `{command}`, {time.strftime('%Y-%m-%d')}, on {platform.machine()} with {os.cpu_count()} "
            f"CPU cores, Python {platform.python_version()}; one run.")


def short_rev(rev: str) -> str:
    """The abbreviated commit of git revision ``rev``."""
    return subprocess.run(["git", "rev-parse", "--short", rev], capture_output=True, text=True, cwd=REPO,
                          check=True).stdout.strip()


@contextlib.contextmanager
def base_worktree(rev: str, path: Path):
    """A detached git worktree of ``rev`` at ``path`` for the duration (removed after)."""
    subprocess.run(["git", "worktree", "add", "--detach", str(path), rev], cwd=REPO, check=True, capture_output=True)
    try:
        yield path
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(path)], cwd=REPO, capture_output=True)


def write_markdown(r: dict, path: Path, command: str) -> None:
    lines = [
        "# Query code A/B on the same builds: maps and renders",
        "",
        f"{generated_by(command)} Each room built once ({STEPS} steps, the default "
        f"preset); its `occupancy_map(0.05)` made by the code of **{r['base']}** (base) and of **{r['new']}** "
        f"(new), each in a fresh process; map time: the faster of {REPEATS} calls. Metrics as tools/bench_suite.py "
        "computes them, against the room's exact geometry. Render: the median over the held-out views "
        f"(at the suite's image size), and a view at twice that size (the viewer's 320x240), the faster of {REPEATS}.",
        "",
        "| room | set | map time base → new | surface labels (map) | free points (map) | F-score at 5 cm "
        "| UNKNOWN voxels | render base → new | 2x render base → new |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in r["rows"]:
        b, n = row["base"], row["new"]
        lines.append(
            f"| {row['scene']} | {row['set']} | {b['map_seconds']:.1f} → "
            f"{n['map_seconds']:.1f} s ({b['map_seconds'] / n['map_seconds']:.2f}x) "
            f"| {100 * b['surface_map']:.1f} → {100 * n['surface_map']:.1f} % "
            f"| {100 * b['free_map']:.2f} → {100 * n['free_map']:.2f} % "
            f"| {b['fscore']:.3f} → {n['fscore']:.3f} | {100 * b['unknown']:.1f} → {100 * n['unknown']:.1f} % "
            f"| {_ratio(b, n, 'render_seconds')} | {_ratio(b, n, 'viewer_render_seconds')} |"
        )
    path.write_text("\n".join(lines) + "\n")


def _ratio(base: dict, new: dict, key: str) -> str:
    """``base → new s (ratio)`` of a time both rows carry."""
    return f"{base[key]:.3f} → {new[key]:.3f} s ({base[key] / new[key]:.2f}x)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="HEAD", help="the git revision to compare the working tree with")
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "map_ab.md")
    args = parser.parse_args()
    from bench_suite import code_version  # tools/bench_suite.py, beside this script

    result = {"base": short_rev(args.base), "new": code_version(), "rows": []}
    with tempfile.TemporaryDirectory() as workdir:
        work = Path(workdir)
        with base_worktree(args.base, work / "base") as base_tree:
            for scene in args.scenes:
                print(f"{scene}: building ...", flush=True)
                scene_dir, build_dir, which = build_room(scene, work)
                row = {"scene": scene, "set": which,
                       "base": measure(base_tree, scene, scene_dir, build_dir),
                       "new": measure(REPO, scene, scene_dir, build_dir)}
                print(f"  {row}", flush=True)
                result["rows"].append(row)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    write_markdown(result, args.out, " ".join(["python tools/bench_map_ab.py", *sys.argv[1:]]))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
