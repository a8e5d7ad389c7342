"""Class meshes before and after (issue: meshes worth opening): write docs/meshes.md and docs/meshes.json.

    .venv/bin/python tools/bench_meshes.py                          # train the room (fast preset), and the exact map
    .venv/bin/python tools/bench_meshes.py --steps 2000             # train for exactly 2000 steps (no time budget)
    .venv/bin/python tools/bench_meshes.py --build B1 B2            # existing builds of the furnished room
    .venv/bin/python tools/bench_meshes.py --exact-only --out /tmp/meshes   # quick: the map from the exact geometry

On the furnished room (:func:`scenelabel.data.synthetic.furnished_room_geometry`, axis-aligned
boxes, so the true surface is known exactly) two kinds of mesh per class are compared:

- **label-mask** (what ``write_class_meshes`` wrote before): marching cubes on each class's 0/1
  voxels (:func:`scenelabel.maps.exports.class_surface`), terraced;
- **decimated** (what it writes now): one marching-cubes surface on the continuous occupancy at the
  map's threshold, labelled per triangle, split per class and decimated
  (:func:`scenelabel.maps.exports.class_meshes`).

Maps: ``trained`` (``scenelabel build`` on the room with the default preset, then
``SemanticField.load(BUILD).occupancy_map()``), and ``exact`` (each voxel's occupancy is the fraction
of it the boxes cover, its label the class covering most of it: a map without any training error).

Measured per class and in total: triangles; **accuracy**: the median and 90th percentile distance
from points sampled uniformly on the mesh (area-weighted, the same count on both meshes of a class)
to the true surface (the boundary of the union of the boxes, exact point-to-rectangle distances);
**completeness**: the median distance from points sampled on the true surface that faces the room's
interior (what the cameras can see) to the mesh of the same class (approximated by dense samples on
the mesh, spacing below a tenth of a voxel). Distances in the room's unit (metres) and in voxels.
The issue's target: at least 10x fewer triangles in total at no larger median accuracy distance.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ACCURACY_SAMPLES = 20_000  # points per mesh (the same on both meshes of a class)
COMPLETENESS_SAMPLES = 20_000  # points per class on the true surface
PROBE = 1e-6  # how far beyond a box face a point is tested for cover by another box
SWEEP = (0.9, 0.95, 0.98, 0.99)


# --------------------------------------------------------------------------------------------
# The true surface: the boundary of the union of the boxes, as axis-aligned rectangles


def true_rectangles(scene) -> dict[str, np.ndarray]:
    """The boundary of the union of ``scene``'s boxes as rectangles (degenerate boxes).

    Every box face is cut along every other box's planes; a cell is kept when the point just
    beyond it (outside its box) lies in no box. Returns lo [R, 3], hi [R, 3] (lo == hi on the
    rectangle's normal axis), class_id [R], interior [R] bool (the outward side faces the room's
    interior, where the cameras are).
    """
    from scenelabel.data.synthetic import ROOM_HALF, ROOM_HEIGHT

    box_lo = np.array([b.lo for b in scene.boxes], np.float64)
    box_hi = np.array([b.hi for b in scene.boxes], np.float64)
    los, his, ids, interior = [], [], [], []
    room_lo, room_hi = np.array([-ROOM_HALF, -ROOM_HALF, 0.0]), np.array([ROOM_HALF, ROOM_HALF, ROOM_HEIGHT])
    for b, box in enumerate(scene.boxes):
        for axis in range(3):
            u, v = [a for a in range(3) if a != axis]
            cuts = []
            for a in (u, v):
                planes = np.concatenate([box_lo[:, a], box_hi[:, a]])
                inner = planes[(planes > box_lo[b, a]) & (planes < box_hi[b, a])]
                cuts.append(np.unique(np.concatenate([[box_lo[b, a], box_hi[b, a]], inner])))
            for side, c in ((-1.0, box_lo[b, axis]), (1.0, box_hi[b, axis])):
                for u0, u1 in zip(cuts[0][:-1], cuts[0][1:]):
                    for v0, v1 in zip(cuts[1][:-1], cuts[1][1:]):
                        probe = np.empty(3)
                        probe[axis], probe[u], probe[v] = c + side * PROBE, (u0 + u1) / 2, (v0 + v1) / 2
                        if np.any(np.all((probe >= box_lo) & (probe <= box_hi), axis=1)):
                            continue  # covered by a box: not on the surface
                        lo, hi = np.empty(3), np.empty(3)
                        lo[axis] = hi[axis] = c
                        lo[u], hi[u], lo[v], hi[v] = u0, u1, v0, v1
                        los.append(lo), his.append(hi), ids.append(box.class_id)
                        interior.append(bool(np.all((probe > room_lo) & (probe < room_hi))))
    return {"lo": np.array(los), "hi": np.array(his), "class_id": np.array(ids), "interior": np.array(interior)}


def distance_to_rectangles(points: np.ndarray, rects: dict[str, np.ndarray], chunk: int = 2048) -> np.ndarray:
    """Exact distance [N] from points [N, 3] to the nearest rectangle (lo == hi on its normal axis)."""
    out = np.empty(len(points))
    lo, hi = rects["lo"][None], rects["hi"][None]  # [1, R, 3]
    for s in range(0, len(points), chunk):
        p = points[s : s + chunk, None, :]  # [n, 1, 3]
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)  # [n, R, 3]
        out[s : s + chunk] = np.sqrt((gap**2).sum(-1).min(1))
    return out


def sample_rectangles(rects: dict[str, np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 3] points uniform (by area) on the rectangles."""
    extent = rects["hi"] - rects["lo"]  # [R, 3], one zero column per row
    area = np.prod(np.where(extent > 0, extent, 1.0), axis=1) * (np.count_nonzero(extent > 0, axis=1) == 2)
    pick = rng.choice(len(area), n, p=area / area.sum())
    return rects["lo"][pick] + rng.random((n, 3)) * extent[pick]


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 3] points uniform (by area) on a triangle mesh."""
    tri = vertices[faces]  # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(faces), n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    t = tri[pick]
    return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])


def rectangles_area(rects: dict[str, np.ndarray]) -> float:
    extent = rects["hi"] - rects["lo"]
    return float(
        (np.prod(np.where(extent > 0, extent, 1.0), axis=1) * (np.count_nonzero(extent > 0, axis=1) == 2)).sum()
    )


def weighted_quantile(parts: list[tuple[np.ndarray, float]], q: float) -> float:
    """Quantile of samples pooled from several surfaces, each part's samples weighted by its area."""
    if not parts:
        return float("nan")
    d = np.concatenate([p[0] for p in parts])
    w = np.concatenate([np.full(len(p[0]), p[1] / len(p[0])) for p in parts])
    order = np.argsort(d)
    cdf = np.cumsum(w[order]) / w.sum()
    return float(d[order][min(np.searchsorted(cdf, q), len(d) - 1)])


def mesh_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


# --------------------------------------------------------------------------------------------
# Maps


def exact_map(scene, voxel_size: float):
    """The room's map without training error: occupancy = the fraction of each voxel the boxes cover
    (clipped to 1), label = the class covering most of it where occupied, else FREE."""
    from scenelabel import FREE, OccupancyMap
    from scenelabel.geometry.lattice import lattice

    origin, shape = lattice(scene.aabb[0], scene.aabb[1], voxel_size)
    centres = [origin[a] + voxel_size * np.arange(shape[a]) for a in range(3)]
    ids = sorted({b.class_id for b in scene.boxes})
    cover = np.zeros(tuple(shape) + (len(ids),), np.float64)
    for box in scene.boxes:
        per_axis = [
            np.clip(
                np.minimum(centres[a] + voxel_size / 2, box.hi[a]) - np.maximum(centres[a] - voxel_size / 2, box.lo[a]),
                0,
                None,
            )
            / voxel_size
            for a in range(3)
        ]
        cover[..., ids.index(box.class_id)] += np.einsum("i,j,k->ijk", *per_axis)
    occupancy = np.clip(cover.sum(-1), 0.0, 1.0).astype(np.float32)
    label = np.where(occupancy >= 0.5, np.asarray(ids)[cover.argmax(-1)], FREE).astype(np.int16)
    classes = {c.id: c.name for c in scene.classes}
    colors = {c.id: c.color for c in scene.classes}
    return OccupancyMap(
        label, occupancy, voxel_size, origin, classes, voxel_size, class_colors=colors, frame_id=scene.frame_id
    )


def train_room(work: Path, steps: int | None) -> tuple[Path, list[str]]:
    """``scenelabel toy --room`` and ``scenelabel build`` (default preset; ``--steps`` when given) into ``work``."""
    exe = str(Path(sys.executable).with_name("scenelabel"))
    build = [exe, "build", str(work / "room"), "--out", str(work / "build"), "--quiet"]
    commands = [[exe, "toy", "--room", str(work / "room")], build + (["--steps", str(steps)] if steps else [])]
    for cmd in commands:
        subprocess.run(cmd, check=True)
    return work / "build", [" ".join(["scenelabel"] + c[1:]) for c in commands]


# --------------------------------------------------------------------------------------------
# Measurement


def measure(occ_map, rects, reduction: float, seed: int) -> dict:
    """Triangles, accuracy and completeness of both kinds of mesh, per class and in total."""
    from scipy.spatial import cKDTree

    from scenelabel.maps.exports import class_meshes, class_surface

    vs = occ_map.voxel_size
    t0 = time.perf_counter()
    old = {
        cid: class_surface(occ_map.label == cid, occ_map.origin, vs)[:2]
        for cid in occ_map.classes
        if (occ_map.label == cid).any()
    }
    t_old = time.perf_counter() - t0
    t0 = time.perf_counter()
    new = {cid: (m.vertices, m.faces) for cid, m in class_meshes(occ_map, reduction).items()}
    t_new = time.perf_counter() - t0
    rows: dict[str, dict] = {}
    pooled: dict[str, list] = {"label-mask": [], "decimated": []}
    pooled_truth: dict[str, list] = {"label-mask": [], "decimated": []}
    for cid in sorted(set(old) | set(new) | (set(rects["class_id"].tolist()) & set(occ_map.classes))):
        name = occ_map.classes[cid]
        truth = {k: v[(rects["class_id"] == cid) & rects["interior"]] for k, v in rects.items()}
        rng = np.random.default_rng(seed + cid)
        truth_points = sample_rectangles(truth, COMPLETENESS_SAMPLES, rng) if len(truth["lo"]) else None
        truth_area = rectangles_area(truth)
        row = {"class_id": cid}
        for kind, meshes in (("label-mask", old), ("decimated", new)):
            if cid not in meshes:
                row[kind] = {"triangles": 0}
                continue
            vertices, faces = meshes[cid]
            rng = np.random.default_rng(seed + 1000 + cid)
            d = distance_to_rectangles(sample_mesh(vertices, faces, ACCURACY_SAMPLES, rng), rects)
            pooled[kind].append((d, mesh_area(vertices, faces)))
            entry = {"triangles": len(faces), "median": float(np.median(d)), "p90": float(np.percentile(d, 90))}
            if truth_points is not None:
                dense = int(min(max(mesh_area(vertices, faces) / (vs / 10) ** 2, ACCURACY_SAMPLES), 2_000_000))
                tree = cKDTree(sample_mesh(vertices, faces, dense, rng))
                completeness = tree.query(truth_points)[0]
                pooled_truth[kind].append((completeness, truth_area))
                entry["completeness_median"] = float(np.median(completeness))
            row[kind] = entry
        rows[name] = row
    total = {}
    for kind, parts in pooled.items():
        # totals: every class's samples weighted by its area (one surface, sampled uniformly)
        total[kind] = {
            "triangles": int(sum(r[kind]["triangles"] for r in rows.values())),
            "median": weighted_quantile(parts, 0.5),
            "p90": weighted_quantile(parts, 0.9),
            "completeness_median": weighted_quantile(pooled_truth[kind], 0.5),
        }
    return {
        "voxel_size": vs,
        "shape": list(occ_map.shape),
        "reduction": reduction,
        "seconds": {"label-mask": round(t_old, 2), "decimated": round(t_new, 2)},
        "classes": rows,
        "total": total,
    }


def verdict(result: dict) -> dict:
    old, new = result["total"]["label-mask"], result["total"]["decimated"]
    ratio = old["triangles"] / max(new["triangles"], 1)
    return {"triangle_ratio": ratio, "met": bool(ratio >= 10 and new["median"] <= old["median"])}


# --------------------------------------------------------------------------------------------
# Report


def _fmt(d: float, vs: float) -> str:
    return f"{1000 * d:.1f} mm ({d / vs:.2f} vx)"


def table(result: dict) -> list[str]:
    vs = result["voxel_size"]
    lines = [
        (
            "| class | triangles label-mask | triangles decimated | ratio | median label-mask | median decimated "
            "| p90 label-mask | p90 decimated | completeness label-mask | completeness decimated |"
        ),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, row in list(result["classes"].items()) + [("**total**", result["total"])]:
        old, new = row["label-mask"], row["decimated"]
        cells = [
            name,
            str(old["triangles"]),
            str(new["triangles"]),
            f"{old['triangles'] / new['triangles']:.1f}x" if new["triangles"] else "-",
        ]
        for key in ("median", "p90", "completeness_median"):
            cells += [_fmt(m[key], vs) if key in m else "-" for m in (old, new)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


DESCRIPTION = (
    "Scene: the furnished room (scenelabel.data.synthetic, axis-aligned boxes). *label-mask*: marching cubes on "
    "each class's 0/1 voxels (the meshes `write_class_meshes` wrote before). *decimated*: marching cubes once on "
    "the continuous occupancy at the threshold, triangles labelled by the nearest labelled voxel, split per class, "
    "decimated (`class_meshes`, reduction as given). *median / p90*: distance from points sampled uniformly on "
    f"the mesh ({ACCURACY_SAMPLES} per mesh) to the true surface (the boundary of the union of the boxes, exact). "
    "*completeness*: median distance from points on the true surface facing the room's interior "
    f"({COMPLETENESS_SAMPLES} per class) to the class's mesh. Totals: triangles summed; distances over all "
    "meshes, each weighted by its area. Target (issue): total triangles at least 10x fewer at no larger median "
    "distance."
)


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=False).stdout.strip()


def _section(source: str, result: dict) -> list[str]:
    vs, total, build = result["voxel_size"], result["total"], result.get("build") or {}
    v = verdict(result)
    nan = float("nan")
    if build:
        budget = f"time budget {build['time_budget']:g} s" if build.get("time_budget") else "no time budget"
        about = (
            f"Build: preset {build.get('preset')}, {budget}: {build.get('steps')} steps in "
            f"{build.get('train_seconds', 0):.0f} s; held-out PSNR "
            f"{build.get('psnr', nan):.1f} dB, mIoU {build.get('miou', nan):.3f}, "
            f"depth error (abs rel) {build.get('depth_error', nan):.3f}."
        )
    else:
        about = "Occupancy: the fraction of each voxel the boxes cover; label: the class covering most of it."
    summary = (
        f"Total: {v['triangle_ratio']:.1f}x fewer triangles; median distance "
        f"{_fmt(total['label-mask']['median'], vs)} -> {_fmt(total['decimated']['median'], vs)}; completeness "
        f"{_fmt(total['label-mask']['completeness_median'], vs)} -> "
        f"{_fmt(total['decimated']['completeness_median'], vs)}. "
        f"Target **{'met' if v['met'] else 'not met'}**. Mesh time: label-mask "
        f"{result['seconds']['label-mask']} s, decimated {result['seconds']['decimated']} s."
    )
    title = f"## {source} map: voxel {vs:g}, shape {result['shape']}, reduction {result['reduction']:g}"
    return [title, "", about, "", *table(result), "", summary, ""]


def _sweep_rows(sweeps: dict) -> list[str]:
    lines = [
        "## Reduction sweep (totals)",
        "",
        "| map | reduction | triangles | median | p90 | completeness | ratio to label-mask |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for key, result in sweeps.items():
        t, vs = result["total"], result["voxel_size"]
        new, old = t["decimated"], t["label-mask"]
        ratio = old["triangles"] / max(new["triangles"], 1)
        cells = [key.split(":")[1], f"{result['reduction']:g}", str(new["triangles"])]
        cells += [_fmt(new["median"], vs), _fmt(new["p90"], vs), _fmt(new["completeness_median"], vs), f"{ratio:.1f}x"]
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def _command_line() -> str:
    """This run's command, the ``--note`` text left out (it follows in the report)."""
    args = list(sys.argv[1:])
    for i, arg in enumerate(args[:-1]):
        if arg == "--note":
            args[i + 1] = "..."
    return shlex.join([".venv/bin/python", "tools/bench_meshes.py", *args])


def write_report(results: dict, commands: list[str], out: Path, note: str = "") -> None:
    code = _git("rev-parse", "--short", "HEAD") + (" + uncommitted changes" if _git("status", "--porcelain") else "")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    lines = [
        "# Class meshes: label-mask marching cubes vs one decimated surface",
        "",
        f"Made by `{_command_line()}` at code {code}",
        f"({time.strftime('%Y-%m-%d')}; machine: {machine}).",
        "One run, one seed. " + ("Training: `" + "`, `".join(commands) + "`. " if commands else "") + note,
        "",
        DESCRIPTION,
        "",
    ]
    for source, result in results.items():
        if not source.startswith("sweep"):
            lines += _section(source, result)
    sweeps = {k: v for k, v in results.items() if k.startswith("sweep")}
    if sweeps:
        lines += _sweep_rows(sweeps)
    out.with_suffix(".md").write_text("\n".join(lines))
    payload = {"code": code, "command": sys.argv[1:], "training": commands, "note": note, "results": results}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1))
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.json')}")


def main() -> None:
    from scenelabel.data.synthetic import furnished_room_geometry
    from scenelabel.maps.exports import DEFAULT_REDUCTION

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--build", type=Path, nargs="+", help="existing builds of the furnished room (default: train one)"
    )
    parser.add_argument(
        "--steps", type=int, help="training steps when training here (default: the preset's time budget)"
    )
    parser.add_argument("--exact-only", action="store_true", help="only the map from the exact geometry (quick)")
    parser.add_argument("--voxel-size", type=float, help="map voxel (default: the build's; exact map: 0.05)")
    parser.add_argument("--reduction", type=float, default=DEFAULT_REDUCTION, help="decimation (default: %(default)s)")
    parser.add_argument("--sweep", action="store_true", help=f"also the totals at reductions {SWEEP}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--note", default="", help="a line for the report, e.g. how the --build folders were made")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "meshes", help="report stem (.md, .json)")
    args = parser.parse_args()

    scene = furnished_room_geometry()
    rects = true_rectangles(scene)
    maps, commands = {}, []
    if not args.exact_only:
        from scenelabel.query.field import SemanticField

        builds = args.build
        if builds is None:
            build, commands = train_room(Path(tempfile.mkdtemp(prefix="bench_meshes_")), args.steps)
            builds = [build]
        for build in builds:
            metrics = json.loads((build / "metrics.json").read_text()) if (build / "metrics.json").is_file() else {}
            meta = {k: metrics[k] for k in ("steps", "train_seconds", "psnr", "miou", "depth_error") if k in metrics}
            if (build / "config.json").is_file():
                config = json.loads((build / "config.json").read_text())
                meta |= {"preset": config.get("preset"), "time_budget": config.get("train", {}).get("time_budget")}
            steps = f", {meta['steps']} steps" if "steps" in meta else ""
            name = f"trained ({build.name}{steps})"
            maps[name] = (SemanticField.load(build).occupancy_map(args.voxel_size), meta)
    first = next(iter(maps.values()), None)
    maps["exact"] = (exact_map(scene, args.voxel_size or (first[0].voxel_size if first else 0.05)), {})
    results = {}
    for source, (occ_map, meta) in maps.items():
        results[source] = measure(occ_map, rects, args.reduction, args.seed) | {"build": meta}
        print(source, json.dumps(results[source]["total"]), verdict(results[source]), flush=True)
        if args.sweep:
            for r in SWEEP:
                results[f"sweep:{source}:{r}"] = measure(occ_map, rects, r, args.seed)
                print(source, r, json.dumps(results[f"sweep:{source}:{r}"]["total"]), flush=True)
    write_report(results, commands, args.out, args.note)


if __name__ == "__main__":
    main()
