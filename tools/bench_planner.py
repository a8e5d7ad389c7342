"""The planner's side of a build, measured: what a process that only reads the outputs pays.

    .venv/bin/python tools/bench_planner.py                 # docs/planner.md and docs/planner.json
    .venv/bin/python tools/bench_planner.py --steps 300 --out /tmp/p.md   # a quick look

One build of the bench room (tools/bench.py's "room", the default preset, all its steps: no time
budget, so the same field whatever the machine's load), then:

- **in this process**: the ESDF of the map at MAP_VOXEL (0.05 m), ``distance`` and
  ``distance_gradient`` rates, ``occupancy_map(MAP_VOXEL)`` with the visibility rule, and the baked
  field's ``query_points`` / ``query_rays`` and the map's ``cast_rays`` rates (medians of REPEATS);
- **in fresh processes** (median of PROCESS_REPEATS each), as a planner would run: ``import
  scenelabel``; loading the map (``OccupancyMap.from_zarr``) and answering QUERY_POINTS points
  (``label_at``, ``occupancy_at``, ``distance``); loading a saved BakedField and answering
  QUERY_RAYS rays; each with torch importable and with torch (and OpenCV) made unimportable, the
  way they behave where torch is not installed.

The issue's targets are checked against the run (never typed by hand). Times are wall-clock on the
machine that ran it (recorded in the document); run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MAP_VOXEL = 0.05
QUERY_POINTS = 1_000_000
QUERY_RAYS = 100_000
REPEATS = 3
PROCESS_REPEATS = 5

BLOCK_TORCH = (
    "import sys\n"
    "class _Blocked:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] in ('torch', 'cv2'):\n"
    "            raise ImportError(name + ' is not installed (blocked by bench_planner)')\n"
    "sys.meta_path.insert(0, _Blocked())\n"
)
"""Prepended to a fresh process's code: torch and OpenCV cannot be imported, as where they are not installed."""

# Each snippet prints one JSON line of seconds; {map}, {baked}, {n} are filled in.
SNIPPETS = {
    "import": (
        "import time, json, sys\nt0 = time.perf_counter()\nimport scenelabel\n"
        "print(json.dumps({{'import': time.perf_counter() - t0, 'torch_loaded': 'torch' in sys.modules}}))\n"
    ),
    "map": (
        "import time, json, sys\nimport numpy as np\nt0 = time.perf_counter()\n"
        "from scenelabel.maps import OccupancyMap\nm = OccupancyMap.from_zarr({map!r})\nt1 = time.perf_counter()\n"
        "lo, hi = m.bounds\nxyz = np.random.default_rng(0).uniform(lo, hi, ({n}, 3))\nt2 = time.perf_counter()\n"
        "m.label_at(xyz); m.occupancy_at(xyz)\nt3 = time.perf_counter()\nm.distance(xyz)\nt4 = time.perf_counter()\n"
        "print(json.dumps({{'load': t1 - t0, 'label_occupancy': t3 - t2, 'distance': t4 - t3, "
        "'torch_loaded': 'torch' in sys.modules}}))\n"
    ),
    "baked": (
        "import time, json, sys\nimport numpy as np\nt0 = time.perf_counter()\n"
        "from scenelabel import BakedField\nb = BakedField.load({baked!r})\nt1 = time.perf_counter()\n"
        "rng = np.random.default_rng(0)\no = rng.uniform(b.aabb[0], b.aabb[1], ({n}, 3))\nd = rng.normal(size=({n}, 3))\n"
        "t2 = time.perf_counter()\nb.query_rays(o, d)\nt3 = time.perf_counter()\nb.query_rays(o, d)\n"
        "t4 = time.perf_counter()\n"
        "print(json.dumps({{'load': t1 - t0, 'first_rays': t3 - t2, 'rays': t4 - t3, "
        "'torch_loaded': 'torch' in sys.modules}}))\n"
    ),
}

TARGETS = (
    ("ESDF of the room at 0.05 m <= 1 s", lambda r: r["esdf_seconds"] <= 1.0),
    ("distance(xyz) >= 10M points/s", lambda r: r["distance_points_per_second"] >= 1e7),
    ("occupancy_map(0.05) with visibility <= 3 s", lambda r: r["map_seconds"] <= 3.0),
    ("baked query_points >= 10M points/s", lambda r: r["baked_points_per_second"] >= 1e7),
    ("baked query_rays >= 500k rays/s", lambda r: r["baked_rays_per_second"] >= 5e5),
    ("cast_rays >= 1M rays/s", lambda r: r["cast_rays_per_second"] >= 1e6),
    ("import scenelabel <= 0.5 s", lambda r: r["fresh"]["with torch"]["import"]["import"] <= 0.5),
    ("loading a map <= 0.2 s", lambda r: r["fresh"]["with torch"]["map"]["load"] <= 0.2),
    ("loading a saved baked field <= 0.2 s", lambda r: r["fresh"]["with torch"]["baked"]["load"] <= 0.2),
)


def _median_seconds(call, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _fresh(kind: str, paths: dict, block_torch: bool) -> dict:
    """Median over PROCESS_REPEATS fresh interpreters of the snippet ``kind``'s seconds."""
    n = QUERY_POINTS if kind == "map" else QUERY_RAYS
    code = SNIPPETS[kind].format(map=str(paths["map"]), baked=str(paths["baked"]), n=n)
    if block_torch:
        code = BLOCK_TORCH + code
    runs = []
    for _ in range(PROCESS_REPEATS):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return {k: (statistics.median(r[k] for r in runs) if k != "torch_loaded" else any(r[k] for r in runs)) for k in runs[0]}


def build_bench_room(workdir: Path, steps: int | None = None):
    """The bench room (tools/bench.py's "room") built under ``workdir`` with the ``fast`` preset and
    all its steps (``steps`` instead, when given), whatever the machine's load (no time budget): the
    same field every run. Returns the build's result (``out_dir``, ``field``)."""
    import torch

    from scenelabel import build, preset, write_furnished_room

    torch.set_num_threads(os.cpu_count() or 1)
    scene = write_furnished_room(workdir / "room")
    config = preset("fast", {"train": {"time_budget": 1e9}, "output": {"write_map": False, "write_renders": False}})
    if steps is not None:
        config.train.steps = steps
    return build(scene, workdir / "build", config, progress=False)


def measure(workdir: Path, steps: int | None) -> dict:
    """Build the bench room, then every measurement of the module docstring."""
    from scenelabel import BakedField
    from scenelabel.maps.esdf import distance_at, distance_gradient_at, signed_distance

    t0 = time.perf_counter()
    field = build_bench_room(workdir, steps).field
    build_seconds = time.perf_counter() - t0
    field.occupancy_map(MAP_VOXEL)  # warm (compiled kernels, caches): not timed
    map_seconds = _median_seconds(lambda: field.occupancy_map(MAP_VOXEL))
    occ = field.occupancy_map(MAP_VOXEL)
    esdf_seconds = _median_seconds(lambda: signed_distance(occ.label, occ.voxel_size))
    esdf = occ.esdf()
    lo, hi = occ.bounds
    rng = np.random.default_rng(0)
    xyz = rng.uniform(lo, hi, (QUERY_POINTS, 3))
    distance_seconds = _median_seconds(lambda: distance_at(esdf, occ.origin, occ.voxel_size, xyz))
    gradient_seconds = _median_seconds(lambda: distance_gradient_at(esdf, occ.origin, occ.voxel_size, xyz))
    baked = BakedField.from_field(field)
    origins = rng.uniform(field.aabb[0], field.aabb[1], (QUERY_RAYS, 3))
    directions = rng.normal(size=(QUERY_RAYS, 3))
    baked.query_points(xyz[:10])  # compile (or load the compiled cache): not timed
    baked.query_rays(origins[:10], directions[:10])
    points_seconds = _median_seconds(lambda: baked.query_points(xyz))
    rays_seconds = _median_seconds(lambda: baked.query_rays(origins, directions))
    cast_seconds = _median_seconds(lambda: occ.cast_rays(origins, directions))
    paths = {"map": occ.to_zarr(workdir / "map.zarr"), "baked": baked.save(workdir / "baked.zarr")}
    fresh = {
        label: {kind: _fresh(kind, paths, block) for kind in SNIPPETS}
        for label, block in (("with torch", False), ("torch not importable", True))
    }
    return {
        "build_seconds": build_seconds,
        "map_voxel_size": occ.voxel_size,
        "map_shape": list(occ.shape),
        "map_seconds": map_seconds,
        "esdf_seconds": esdf_seconds,
        "distance_points_per_second": QUERY_POINTS / distance_seconds,
        "gradient_points_per_second": QUERY_POINTS / gradient_seconds,
        "baked_voxel_size": baked.voxel_size,
        "baked_megabytes": baked.nbytes / 1e6,
        "baked_points_per_second": QUERY_POINTS / points_seconds,
        "baked_rays_per_second": QUERY_RAYS / rays_seconds,
        "cast_rays_per_second": QUERY_RAYS / cast_seconds,
        "fresh": fresh,
    }


def write_markdown(r: dict, path: Path, command: str) -> None:
    """docs/planner.md from one run's result ``r``."""
    from bench_suite import code_version  # tools/bench_suite.py, beside this script

    lines = [
        "# The planner's side: loading and answering from a build's outputs",
        "",
        f"Generated by `{command}` (code {code_version()}), {time.strftime('%Y-%m-%d')}, on {platform.machine()} "
        f"with {os.cpu_count()} CPU cores, Python {platform.python_version()}. One run; rates are medians of "
        f"{REPEATS} calls, fresh-process times medians of {PROCESS_REPEATS} processes.",
        "",
        f"The bench room (tools/bench.py's `room`) built with the `fast` preset (all its steps) in {r['build_seconds']:.0f} s; "
        f"its map at {r['map_voxel_size']:g} m is {' x '.join(map(str, r['map_shape']))} voxels; the baked "
        f"field's lattice spacing is {r['baked_voxel_size']:.4g} m ({r['baked_megabytes']:.1f} MB).",
        "",
        "## In the process that holds the field",
        "",
        "| measure | value |",
        "|---|---|",
        f"| `occupancy_map({MAP_VOXEL:g})` with the visibility rule | {r['map_seconds']:.2f} s |",
        f"| ESDF of that map | {r['esdf_seconds']:.3f} s |",
        f"| `distance(xyz)`, {QUERY_POINTS:,} points | {r['distance_points_per_second'] / 1e6:.1f} M points/s |",
        f"| `distance_gradient(xyz)` | {r['gradient_points_per_second'] / 1e6:.1f} M points/s |",
        f"| baked `query_points` | {r['baked_points_per_second'] / 1e6:.1f} M points/s |",
        f"| baked `query_rays`, {QUERY_RAYS:,} rays | {r['baked_rays_per_second'] / 1e3:.0f} k rays/s |",
        f"| map `cast_rays`, the same rays | {r['cast_rays_per_second'] / 1e3:.0f} k rays/s |",
        "",
        "## A fresh planner process (seconds)",
        "",
        "| | `import scenelabel` | load the map | label + occupancy at 1M points | distance at 1M points "
        "| load a saved BakedField | its first 100k rays (compiled code from the cache) | 100k rays again | torch loaded |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, f in r["fresh"].items():
        loaded = f["import"]["torch_loaded"] or f["map"]["torch_loaded"] or f["baked"]["torch_loaded"]
        lines.append(
            f"| {label} | {f['import']['import']:.3f} | {f['map']['load']:.3f} | {f['map']['label_occupancy']:.3f} "
            f"| {f['map']['distance']:.3f} | {f['baked']['load']:.3f} | {f['baked']['first_rays']:.3f} "
            f"| {f['baked']['rays']:.3f} | {'yes' if loaded else 'no'} |"
        )
    lines += ["", "## The issue's targets, checked against this run", ""]
    for name, check in TARGETS:
        lines.append(f"- {name}: {'met' if check(r) else '**not met**'}")
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, help="train this many steps instead of the preset's (a quick look)")
    parser.add_argument("--out", default=str(REPO / "docs" / "planner.md"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as workdir:
        result = measure(Path(workdir), args.steps)
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    write_markdown(result, out, " ".join(["python tools/bench_planner.py", *sys.argv[1:]]))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
