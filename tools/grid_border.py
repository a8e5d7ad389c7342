"""The density grid a build leaves behind: every cell beside an occupied one marked occupied, or looked at again.

    .venv/bin/python tools/grid_border.py                                  # every suite room; writes docs/grid_border.md
    .venv/bin/python tools/grid_border.py --scenes studio-3x3 --out /tmp/g.md

When training ends the density grid is rebuilt from the final field (``DensityGrid.rebuild``: the
largest density at 3³ points per cell). What the coarse lattice passes between lies next to what it
finds, so the cells beside an occupied one need care. Two rules, on the same trained field:

- ``blanket``: every cell within one of an occupied cell is occupied (the earlier rule);
- ``second look``: those cells are evaluated again at 6³ points and occupied where that finds density
  above the threshold (``REBUILD_BORDER_SAMPLES``; the default).

Each suite room is built once with the default preset, as tools/bench_suite.py builds it (a fresh
subprocess, the room written as users' files are); then for each grid: held-out PSNR, mIoU and
render time (`scenelabel.train.evaluation.evaluate`: the median over the held-out views of one
160x120 render each), tools/bench_suite.py's 3D metrics (depth error, surface and free labels,
F-score of the 0.05 m map, the map's time) and the share of the grid's cells occupied. The two
grids are one field's: differences in quality are the grids', differences in time the grids' and the
machine's noise. Rooms with ``tuning=False`` are reported apart. Every number comes from this run.
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

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
GRIDS = ("blanket", "second look")


def _one_room(spec: dict, workdir: str, queue) -> None:
    """Child process: write the room, build it, measure both grids; put a result dict on queue."""
    import torch
    from bench_suite import three_d_metrics  # tools/, beside this script

    from scenelabel import build, load_scene, preset
    from scenelabel.config import AUTO_PRESET
    from scenelabel.data.suite import suite_geometry, suite_spec, write_suite_scene
    from scenelabel.render.sampling import _dilated
    from scenelabel.train.evaluation import evaluate
    from scenelabel.train.pipeline import choose_views

    torch.set_num_threads(os.cpu_count() or 1)
    room = suite_spec(spec["scene"])
    scene_dir = write_suite_scene(Path(workdir) / room.name, room)
    config = preset(AUTO_PRESET, {"output": {"write_map": False, "write_renders": False}})
    result = build(scene_dir, Path(workdir) / "build", config, progress=False)
    field, scene = result.field, load_scene(scene_dir)
    _, test_idx, _ = choose_views(scene, config.train.holdout)
    grid = field.occupancy
    rows = []
    for name in GRIDS:
        t0 = time.perf_counter()
        if name == "blanket":
            grid.rebuild(field.model.density, border=0)
            grid.bits = _dilated(grid.bits) & ~grid.carved
        else:
            grid.rebuild(field.model.density)
        rebuild_seconds = time.perf_counter() - t0
        ev = evaluate(field, scene, test_idx, config.output.smooth_sigma, None)
        rows.append({
            "scene": room.name, "tuning": room.tuning, "grid": name, "steps": result.metrics["steps"],
            "occupied": grid.occupied_fraction, "rebuild_seconds": rebuild_seconds,
            "psnr": ev["psnr"], "miou": ev["miou"],
            "render_seconds": statistics.median(v["render_seconds"] for v in ev["per_view"]),
            **three_d_metrics(field, scene, test_idx, suite_geometry(room).boxes),
        })
    queue.put({"rows": rows})


COLUMNS = [
    ("room", lambda r: r["scene"]),
    ("grid", lambda r: r["grid"]),
    ("occupied cells %", lambda r: f"{100 * r['occupied']:.1f}"),
    ("rebuild s", lambda r: f"{r['rebuild_seconds']:.1f}"),
    ("render s", lambda r: f"{r['render_seconds']:.3f}"),
    ("map s", lambda r: f"{r['map_seconds']:.1f}"),
    ("PSNR", lambda r: f"{r['psnr']:.2f}"),
    ("mIoU", lambda r: f"{r['miou']:.4f}"),
    ("depth rel. err. %", lambda r: f"{100 * r['depth_rel_median']:.2f}"),
    ("surface field / baked / map %", lambda r: " / ".join(f"{100 * r[k]:.1f}" for k in ("surface_field", "surface_baked", "surface_map"))),
    ("free field / map %", lambda r: f"{100 * r['free_field']:.1f} / {100 * r['free_map']:.1f}"),
    ("F at 5 cm", lambda r: f"{r['fscore']:.3f}"),
]


def _pairs(rows: list[dict]) -> list[tuple[dict, dict]]:
    by = {(r["scene"], r["grid"]): r for r in rows}
    return [(by[s, GRIDS[0]], by[s, GRIDS[1]]) for s in dict.fromkeys(r["scene"] for r in rows)]


def _summary(pairs: list[tuple[dict, dict]]) -> list[str]:
    """Medians over rooms of the second look against the blanket (ratios and differences), and the worst room."""
    if not pairs:
        return []

    def med(f):
        return statistics.median(f(a, b) for a, b in pairs)

    worst = lambda key, g: min(p[g][key] for p in pairs)  # noqa: E731
    return [
        f"- render time, second look / blanket: median ratio {med(lambda a, b: b['render_seconds'] / a['render_seconds']):.2f};"
        f" slowest room {max(p[0]['render_seconds'] for p in pairs):.3f} s against {max(p[1]['render_seconds'] for p in pairs):.3f} s",
        f"- map time ratio: median {med(lambda a, b: b['map_seconds'] / a['map_seconds']):.2f};"
        f" rebuild time ratio: median {med(lambda a, b: b['rebuild_seconds'] / a['rebuild_seconds']):.2f}",
        f"- mIoU: median difference {med(lambda a, b: b['miou'] - a['miou']):+.4f}; worst room {worst('miou', 0):.4f} (blanket)"
        f" and {worst('miou', 1):.4f} (second look); largest drop {max(a['miou'] - b['miou'] for a, b in pairs):+.4f}",
        f"- surface labels of the field: median difference {100 * med(lambda a, b: b['surface_field'] - a['surface_field']):+.2f} points;"
        f" of the map {100 * med(lambda a, b: b['surface_map'] - a['surface_map']):+.2f}; F-score"
        f" {med(lambda a, b: b['fscore'] - a['fscore']):+.4f}; depth error {100 * med(lambda a, b: b['depth_rel_median'] - a['depth_rel_median']):+.3f} points",
    ]


def write_markdown(rows: list[dict], path: Path, command: str) -> None:
    from bench import reference_line  # tools/bench.py, beside this script
    from bench_suite import code_version

    code = code_version()
    header = ["| " + " | ".join(c for c, _ in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines = [
        "# The density grid's border cells: marked occupied, or looked at again",
        "",
        f"Generated by `.venv/bin/{command}` (one run, code {code}); that command regenerates it.",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}.",
        *reference_line(rows),
        "",
        *__doc__.split("\n\n")[2:],
        "",
    ]
    for title, tuning in (("Rooms used for tuning", True), ("Rooms held out of every tuning decision", False)):
        part = [r for r in rows if r["tuning"] == tuning]
        if part:
            lines += [f"## {title}", "", *header, *("| " + " | ".join(f(r) for _, f in COLUMNS) + " |" for r in part), ""]
            lines += _summary(_pairs(part)) + [""]
    path.write_text("\n".join(lines))


def main() -> None:
    from bench import reference_seconds, run_in_child  # tools/bench.py, beside this script

    from scenelabel.data.suite import SUITE

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=[s.name for s in SUITE])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "grid_border.md")
    args = parser.parse_args()
    command = "python tools/grid_border.py " + " ".join(sys.argv[1:])
    rows = []
    for name in args.scenes:
        reference = reference_seconds()
        t0 = time.perf_counter()
        for row in run_in_child(_one_room, {"scene": name})["rows"]:
            rows.append({**row, "reference_seconds": reference})
            print(f"{name} [{row['grid']}]: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
        print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)
        args.out.with_suffix(".json").write_text(json.dumps({"command": command, "rows": rows}, indent=2))
    write_markdown(rows, args.out, command)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
