"""A map of at least 100M voxels, four ways: wall time and peak memory of each.

    .venv/bin/python tools/bench_map_export.py                     # docs/map_export.md and .json
    .venv/bin/python tools/bench_map_export.py --build DIR --min-voxels 2e7 --out /tmp/e.md   # a quick look

The bench room (tools/bench.py's ``room``, the ``fast`` preset) is built once (or ``--build`` is
used), then its map at the voxel size that gives at least MIN_VOXELS voxels over the field's
bounds is made by, each in a fresh process:

- ``occupancy_map``: ``SemanticField.occupancy_map(v)`` in memory, then ``to_zarr`` (the Python API;
  past its guard against maps larger than ``MAX_MAP_VOXELS``, which this one is);
- ``export``: ``scenelabel export BUILD OUT.zarr --voxel-size v``, the chunked writer in one process;
- ``export --workers 1`` and ``--workers 2``: the same on a local Dask cluster of 1 or 2 worker
  processes (one thread each).

Peak memory is the largest sum of the resident set sizes of the process and all its children,
sampled every SAMPLE_SECONDS (pages shared between processes count once per process). Wall time
includes starting Python and loading the field. The four stores are checked to hold the same
labels. Run it on an otherwise idle machine: every mode uses both cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from bench_planner import build_bench_room  # tools/bench_planner.py, beside this script

REPO = Path(__file__).resolve().parents[1]
MIN_VOXELS = 100_000_000
SAMPLE_SECONDS = 0.1

IN_MEMORY = (
    "import sys, torch\ntorch.set_num_threads({threads})\nfrom scenelabel import SemanticField\n"
    "from scenelabel.query.mapping import occupancy_map\nfield = SemanticField.load({build!r})\n"
    "occupancy_map(field, {voxel!r}, max_voxels={max_voxels}).to_zarr({out!r})\n"
)
"""``SemanticField.occupancy_map(v).to_zarr(...)``, past its MAX_MAP_VOXELS guard (this map is larger)."""


def voxel_size_for(aabb: np.ndarray, min_voxels: float) -> float:
    """The largest voxel size (a multiple of 0.1 mm) whose lattice over ``aabb`` has at least ``min_voxels`` voxels."""
    from scenelabel.maps import lattice

    size = float(np.floor(1e4 * (np.prod(aabb[1] - aabb[0]) / min_voxels) ** (1 / 3)) / 1e4)
    while int(np.prod(lattice(aabb[0], aabb[1], size)[1])) < min_voxels:
        size -= 1e-4
    return round(size, 4)


def run_measured(command: list[str]) -> dict:
    """Run ``command``; its wall time and the peak of its process tree's summed resident memory."""
    import psutil

    start = time.perf_counter()
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    peak = 0
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.extend(proc.stdout), daemon=True)
    reader.start()
    root = psutil.Process(proc.pid)
    while proc.poll() is None:
        total = 0
        try:
            for p in [root, *root.children(recursive=True)]:
                try:
                    total += p.memory_info().rss
                except psutil.Error:
                    pass
        except psutil.Error:
            pass
        peak = max(peak, total)
        time.sleep(SAMPLE_SECONDS)
    seconds = time.perf_counter() - start
    reader.join()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{''.join(output)[-3000:]}")
    return {"seconds": seconds, "peak_bytes": peak}


def measure(build_dir: Path, workdir: Path, min_voxels: float) -> dict:
    from scenelabel import SemanticField

    field = SemanticField.load(build_dir)
    voxel = voxel_size_for(field.aabb, min_voxels)
    from scenelabel.query.mapping import map_lattice

    shape = map_lattice(field, voxel, max_voxels=1 << 40)[2]
    del field
    export = [sys.executable, "-m", "scenelabel", "export", str(build_dir)]
    stores = ["memory.zarr", "chunked.zarr", "w1.zarr", "w2.zarr"]
    chunked = [[*export, str(workdir / store), "--voxel-size", str(voxel), "--quiet"] for store in stores[1:]]
    in_memory = IN_MEMORY.format(threads=os.cpu_count() or 1, build=str(build_dir), voxel=voxel,
                                 max_voxels=int(np.prod(shape)), out=str(workdir / stores[0]))
    modes = {
        "occupancy_map + to_zarr (in memory)": [sys.executable, "-c", in_memory],
        "export (chunked, one process)": chunked[0],
        "export --workers 1": [*chunked[1], "--workers", "1"],
        "export --workers 2": [*chunked[2], "--workers", "2"],
    }
    results = {}
    for name, command in modes.items():
        print(f"{name} ...", flush=True)
        results[name] = run_measured(command)
        print(f"  {results[name]['seconds']:.0f} s, peak {results[name]['peak_bytes'] / 2**30:.2f} GiB", flush=True)
    same = same_labels([workdir / s for s in stores])
    return {"voxel_size": voxel, "shape": list(shape), "voxels": int(np.prod(shape)), "modes": results,
            "same_labels": same}


def same_labels(paths: list[Path]) -> bool:
    """Whether every store's level-0 ``label`` equals the first's (read slab by slab)."""
    import zarr

    arrays = [zarr.open_group(str(p), mode="r")["label"] for p in paths]
    step = 16
    for i in range(0, arrays[0].shape[0], step):
        first = arrays[0][i : i + step]
        if any(not np.array_equal(first, a[i : i + step]) for a in arrays[1:]):
            return False
    return True


BENCHMARKS = REPO / "docs" / "benchmarks.md"


def write_section(doc: Path, markdown: Path) -> None:
    """The document ``markdown`` as the "bench_map_export" section of ``doc`` (docs/benchmarks.md,
    whose generator keeps it), its title one level down."""
    from bench import write_kept_section  # tools/bench.py, beside this script

    body = markdown.read_text().replace("# ", "## ", 1).rstrip("\n")
    write_kept_section(doc, "bench_map_export", f"{body}\n\nIts own page: [{markdown.name}]({markdown.name}).")


def write_markdown(r: dict, path: Path, command: str) -> None:
    from bench_suite import code_version  # tools/bench_suite.py, beside this script

    first = next(iter(r["modes"].values()))
    lines = [
        f"# A map of {r['voxels'] / 1e6:.0f}M voxels: in memory, chunked, and on a local Dask cluster",
        "",
        f"Generated by `{command}` (code {code_version()}), {time.strftime('%Y-%m-%d')}, on {platform.machine()} with "
        f"{os.cpu_count()} CPU cores, Python {platform.python_version()}; one run of each mode, each in a fresh "
        "process.",
        "",
        f"The bench room's build ({r['build']}), its map at {r['voxel_size']:g} m: "
        f"{' x '.join(map(str, r['shape']))} = {r['voxels'] / 1e6:.1f}M voxels, with the visibility rule, "
        "the pyramid and the ESDF. Peak memory: the largest sum of the resident memory of the process and its "
        "children (Dask's scheduler and workers), sampled every "
        f"{SAMPLE_SECONDS:g} s. Wall time includes starting Python and loading the field.",
        "",
        "| mode | wall time | vs in memory | peak memory |",
        "|---|---|---|---|",
    ]
    for name, m in r["modes"].items():
        lines.append(f"| {name} | {m['seconds']:.0f} s | {m['seconds'] / first['seconds']:.2f}x "
                     f"| {m['peak_bytes'] / 2**30:.2f} GiB |")
    lines += ["", f"The four stores hold the same labels: {'yes' if r['same_labels'] else '**no**'}."]
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build", type=Path, help="a build folder (default: build the bench room)")
    parser.add_argument("--min-voxels", type=float, default=MIN_VOXELS)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "map_export.md")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as workdir:
        work = Path(workdir)
        build_dir = args.build or build_bench_room(work).out_dir
        result = measure(Path(build_dir), work, args.min_voxels)
    result["build"] = "given" if args.build else "the fast preset, all its steps, built by this run"
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    write_markdown(result, args.out, " ".join(["python tools/bench_map_export.py", *sys.argv[1:]]))
    print(f"wrote {args.out}")
    if args.out.resolve() == (REPO / "docs" / "map_export.md").resolve():  # a quick look elsewhere leaves the docs
        write_section(BENCHMARKS, args.out)
        print(f"wrote its section of {BENCHMARKS}")


if __name__ == "__main__":
    main()
