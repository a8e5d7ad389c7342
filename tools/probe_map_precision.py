"""Where a map's surface precision goes: the occupied voxels of a default build's 0.05 m map that lie
farther than 5 cm from every true surface, sorted by where they are. Writes docs/map_precision.md.

    .venv/bin/python tools/probe_map_precision.py                         # hall-10x6, three depth captures
    .venv/bin/python tools/probe_map_precision.py --room office-5x4 --captures phone --out /tmp/p.md
    .venv/bin/python tools/probe_map_precision.py --room living-6x5 --captures none --variants depth-bg-scene - \
        --steps 1800 --out docs/map_precision_background.md                 # no depth: the two backgrounds
    .venv/bin/python tools/probe_map_precision.py --rewrite                # the document again from its .json

Each capture is the suite room written as users' files are, with depth as
scenelabel.data.synthetic.add_phone_depth makes it (`phone`: its defaults; `phone-no-noise`: noise 0;
`phone-no-range`: no 5 m range limit) or without depth (`none`: the build trains on the room layout
found from its masks), built with the default preset in a fresh subprocess (the build of
tools/bench_suite.py), changed by a variant of tools/bench_suite.py (`-`: none), for the time
budget or, with `--steps`, that many steps. Precision is tools/bench_suite.py's: the share of the map's occupied
voxel centres within 5 cm of the exact boxes' surfaces (scenelabel.metrics.surface_fscore). A
false positive (farther) is *inside* a true box (deeper than 5 cm in matter), *beyond the room*
(outside the floor, ceiling and wall slabs: space no camera can see), or *in the room* (free space
in front of a surface); for the last, how far it is from the nearest surface and which box that is.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

CAPTURES: dict[str, dict | None] = {
    "none": None,  # no depth file
    "phone": {},
    "phone-no-noise": {"noise": 0.0},
    "phone-no-range": {"max_range": None},
}


def _classify(pts: np.ndarray, boxes, size) -> dict:
    """Precision of occupied voxel centres ``pts`` [n, 3] and where its false positives lie."""
    from scenelabel import metrics as M
    from scenelabel.data.suite import SLAB

    lo, hi = M.boxes_lo_hi(boxes)
    dist = M.box_surface_distance(pts, lo, hi)
    inside = np.zeros(len(pts), bool)
    for l, h in zip(lo, hi):
        inside |= np.all((pts >= l) & (pts <= h), axis=1)
    envelope = np.all((pts >= -SLAB) & (pts <= np.asarray(size) + SLAB), axis=1)
    false = dist > M.FSCORE_THRESHOLD
    in_room = false & ~inside & envelope
    nearest = Counter()
    if in_room.any():
        per_box = np.stack([M.box_surface_distance(pts[in_room], lo[i : i + 1], hi[i : i + 1]) for i in range(len(lo))], 1)
        nearest = Counter(boxes[i].part.split("#")[0] for i in per_box.argmin(1))
    return {
        "occupied": int(len(pts)),
        "precision": float(1 - false.mean()),
        "inside": int(np.sum(false & inside)),
        "beyond": int(np.sum(false & ~envelope)),
        "in_room": int(in_room.sum()),
        "in_room_distance_quantiles": np.quantile(dist[in_room], [0.1, 0.5, 0.9]).tolist() if in_room.any() else None,
        "nearest": dict(nearest.most_common(5)),
    }


def _one(spec: dict, workdir: str, queue) -> None:
    """Child process: write the room with the capture's depth, build it, classify its map."""
    import torch
    from bench_suite import VARIANTS, _truth_points  # tools/bench_suite.py: variants, the F-score's true points

    from scenelabel import build, load_scene, preset
    from scenelabel import metrics as M
    from scenelabel.data.suite import suite_geometry, suite_spec, write_suite_scene
    from scenelabel.data.synthetic import add_phone_depth

    torch.set_num_threads(os.cpu_count() or 1)
    room = suite_spec(spec["room"])
    scene_dir = write_suite_scene(Path(workdir) / room.name, room)
    if CAPTURES[spec["capture"]] is not None:
        add_phone_depth(scene_dir, **CAPTURES[spec["capture"]])
    overrides = json.loads(json.dumps(VARIANTS[spec["variant"]]))  # a deep copy; preset() refuses a key not a config stage
    t0 = time.perf_counter()
    if spec.get("steps"):  # the same work on a machine of any speed
        overrides.setdefault("train", {}).update(steps=spec["steps"], time_budget=None)
    config = preset("fast", {**overrides, "output": {"write_map": False}})
    result = build(scene_dir, Path(workdir) / "build", config, progress=False)
    seconds = time.perf_counter() - t0
    occ = result.field.occupancy_map(0.05)
    pts = occ.world_from_index(np.argwhere(occ.occupied))
    geometry = suite_geometry(room)
    lo, hi = M.boxes_lo_hi(geometry.boxes)
    f = M.surface_fscore(pts, _truth_points(load_scene(scene_dir), np.random.default_rng(0)), M.FSCORE_THRESHOLD, lo, hi)
    queue.put({**spec, "build_seconds": seconds, "steps": result.metrics["steps"], "recall": f["recall"],
               "fscore": f["fscore"], **_classify(pts, geometry.boxes, room.size)})


def write_markdown(rows: list[dict], path: Path, command: str) -> None:
    lines = [
        "# Where the map's surface precision goes",
        "",
        f"Generated by `.venv/bin/{command}` (one run, code {', '.join(sorted({r['code'] for r in rows}))}); that command regenerates it.",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}.",
        "",
        (__doc__ or "").split("\n\n", 2)[2].strip(),
        "",
        "| room | capture | variant | build s (steps) | occupied voxels | precision / recall / F | false: inside a box / beyond the room / in the room | in the room: distance to a surface, 10/50/90 % (m) | in the room: nearest box |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        q = r["in_room_distance_quantiles"]
        lines.append(
            f"| {r['room']} | {r['capture']} | {r.get('variant', '-')} | {r['build_seconds']:.0f} ({r['steps']}) | {r['occupied']} | "
            f"{r['precision']:.3f} / {r['recall']:.3f} / {r['fscore']:.3f} | {r['inside']} / {r['beyond']} / {r['in_room']} | "
            + ("-" if q is None else " / ".join(f"{v:.3f}" for v in q)) + " | "
            + ", ".join(f"{k} {v}" for k, v in r["nearest"].items()) + " |"
        )
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--room", default="hall-10x6")
    parser.add_argument("--captures", nargs="+", default=[c for c in CAPTURES if c != "none"], choices=list(CAPTURES))
    parser.add_argument("--variants", nargs="+", default=["-"], help="tools/bench_suite.py variants that change the config")
    parser.add_argument("--steps", type=int, help="train this many steps, no time budget (default: the preset's budget)")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "map_precision.md")
    parser.add_argument("--rewrite", action="store_true", help="rewrite the document from the rows of OUT's .json")
    args = parser.parse_args()
    from bench import run_in_child  # tools/bench.py, beside this script
    from bench_suite import code_version

    data = {"command": " ".join(["python tools/probe_map_precision.py", *sys.argv[1:]]), "rows": []}
    if args.rewrite:
        data = json.loads(args.out.with_suffix(".json").read_text())
    else:
        for capture, variant in [(c, v) for c in args.captures for v in args.variants]:
            row = run_in_child(_one, {"room": args.room, "capture": capture, "variant": variant, "steps": args.steps})
            data["rows"].append({**row, "code": code_version()})
            print(json.dumps(row), flush=True)
            args.out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    write_markdown(data["rows"], args.out, data["command"])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
