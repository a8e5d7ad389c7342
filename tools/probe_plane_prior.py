"""Would depth on the planar classes alone (floor, wall, ceiling) make a room's field solid, and can
a field trained without depth supply it? (A candidate of the scene-suite issue: a Manhattan-style
plane prior from the 2D labels.) Writes docs/plane_prior.md.

    .venv/bin/python tools/probe_plane_prior.py
    .venv/bin/python tools/probe_plane_prior.py --scenes studio-3x3 --out /tmp/p.md

For each suite room (written as a build sees it: no near/far, no box, no depth) four default builds:

- ``none``: no depth (the default build of docs/suite.md);
- ``exact planes``: the exact depth of every training pixel labelled floor, wall or ceiling, given
  as sensor depth (millimetre z-depth PNGs, full resolution, no noise); other pixels have none;
- ``planes 1 % behind``: the same depths times 1.01, as a plane fitted 1 % too far would give;
- ``fitted planes``: planes fitted to the ``none`` field: each training view's rays at a quarter of
  its resolution are marched (1 cm steps) to where their transmittance falls to FRONT_LEVEL (the
  front of a soft surface); the points of each planar class give planes by RANSAC with a
  least-squares refit on the inliers (threshold PLANE_THRESHOLD of the points' extent), one after
  another while a plane holds at least MIN_SHARE of the class's points. A pixel of the class gets
  the first of its class's planes its ray meets, when that is within GUESS_TOLERANCE of the
  field's front depth there.

The pseudo-depth columns score the depth given to the training pixels against the exact depth; the
other columns are tools/bench_suite.py's.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PLANAR = ("floor", "wall", "ceiling")
FRONT_LEVEL = 0.9
PLANE_THRESHOLD = 0.005
MIN_SHARE = 0.05
GUESS_TOLERANCE = 0.1
QUARTER = 4
MARCH_STEP = 0.01  # metres
VARIANTS = ("none", "exact planes", "planes 1 % behind", "fitted planes")


def _front_depths(field, cameras, index: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origins, directions and the distance where transmittance falls to FRONT_LEVEL (NaN: never)."""
    from scenelabel.geometry.rays import rays_from_cameras

    origins, directions = rays_from_cameras(cameras, index, pixels)
    lo, hi = (np.asarray(b) for b in field.meta["aabb_world"])
    t = np.arange(MARCH_STEP, float(np.linalg.norm(hi - lo)), MARCH_STEP)
    out = np.full(len(origins), np.nan)
    for a in range(0, len(origins), 200):
        p = origins[a : a + 200, None] + t[None, :, None] * directions[a : a + 200, None]
        inside = np.all((p >= lo) & (p <= hi), -1)
        sigma = np.zeros(p.shape[:2])
        sigma[inside] = field.query_points(p[inside]).density
        trans = np.exp(-np.cumsum(sigma * MARCH_STEP, 1))
        crossed = (trans < FRONT_LEVEL).any(1)
        first = np.minimum((trans >= FRONT_LEVEL).sum(1), len(t) - 1)
        out[a : a + 200] = np.where(crossed, t[first], np.nan)
    return origins, directions, out


def _fit_planes(points: np.ndarray, threshold: float, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """Planes (unit normal n, offset c with n.x + c = 0) found one after another by RANSAC."""
    planes, left, need = [], points, max(100, MIN_SHARE * len(points))
    while len(left) >= need:
        best = None
        for _ in range(500):
            s = left[rng.choice(len(left), 3, replace=False)]
            n = np.cross(s[1] - s[0], s[2] - s[0])
            if np.linalg.norm(n) < 1e-12:
                continue
            n = n / np.linalg.norm(n)
            inliers = np.abs((left - s[0]) @ n) < threshold
            if best is None or inliers.sum() > best.sum():
                best = inliers
        if best is None or best.sum() < need:
            break
        for _ in range(3):  # least squares on the inliers
            centre = left[best].mean(0)
            n = np.linalg.svd(left[best] - centre)[2][-1]
            best = np.abs((left - centre) @ n) < threshold
        planes.append((n, float(-n @ centre)))
        left = left[~best]
    return planes


def _fitted_depths(field, scene, train_idx: list[int], planar_ids: list[int]) -> dict[int, np.ndarray]:
    """Ray depth [h, w] per training view from planes fitted to ``field`` (module docstring); NaN: none."""
    from scenelabel.geometry.rays import pixel_grid, rays_from_cameras

    cams = scene.cameras
    rng = np.random.default_rng(0)
    guesses, points, labels = {}, [], []
    for i in train_idx:
        w, h = int(cams.width[i]), int(cams.height[i])
        pixels = pixel_grid(w // QUARTER, h // QUARTER) * QUARTER
        o, d, depth = _front_depths(field, cams, i, pixels)
        label = scene.labels[i][pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
        ok = np.isfinite(depth)
        points.append(o[ok] + depth[ok, None] * d[ok])
        labels.append(label[ok])
        guesses[i] = depth.reshape(h // QUARTER, w // QUARTER)
    points, labels = np.concatenate(points), np.concatenate(labels)
    threshold = PLANE_THRESHOLD * float(np.max(np.ptp(points, 0)))
    planes = {c: _fit_planes(points[labels == c], threshold, rng) for c in planar_ids}
    out = {}
    for i in train_idx:
        o, d = rays_from_cameras(cams, i)
        label = scene.labels[i].reshape(-1)
        guess = np.repeat(np.repeat(guesses[i], QUARTER, 0), QUARTER, 1)
        guess = np.pad(guess, [(0, scene.labels[i].shape[0] - guess.shape[0]), (0, scene.labels[i].shape[1] - guess.shape[1])],
                       mode="edge").reshape(-1)
        depth = np.full(len(o), np.nan)
        for c, pl in planes.items():
            m = np.flatnonzero(label == c)
            if not pl or not len(m):
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                ts = np.stack([-(o[m] @ n + off) / (d[m] @ n) for n, off in pl], 1)
            ts[~(ts > 0)] = np.inf
            first = ts.min(1)
            good = np.isfinite(first) & (np.abs(first - guess[m]) < GUESS_TOLERANCE * guess[m])
            depth[m[good]] = first[good]
        out[i] = depth.reshape(scene.labels[i].shape)
    return out


def _with_depth(src: Path, dst: Path, scene, depths: dict[int, np.ndarray]) -> dict:
    """A copy of the room folder whose training frames carry ``depths`` as millimetre z-depth PNGs;
    returns the pseudo depth's coverage and error against the exact depth."""
    from PIL import Image

    from scenelabel.data.synthetic.phone_depth import z_depth_from_ray_depth

    shutil.copytree(src, dst)
    data = json.loads((dst / "transforms.json").read_text())
    (dst / "pseudo_depth").mkdir()
    errors, covered = [], []
    cams = scene.cameras
    for k, frame in enumerate(data["frames"]):
        ray = depths.get(k, np.full(scene.labels[k].shape, np.nan))
        z = z_depth_from_ray_depth(ray, cams.fx[k], cams.fy[k], cams.cx[k], cams.cy[k], cams.distortion[k])
        raw = np.where(np.isfinite(z), np.round(z / 0.001), 0).astype(np.uint16)
        name = Path(frame["file_path"]).stem + ".png"
        Image.fromarray(raw).save(dst / "pseudo_depth" / name)
        frame["depth_file_path"] = f"pseudo_depth/{name}"
        if k in depths:
            truth = scene.depths[k]
            covered.append(np.isfinite(ray).mean())
            errors.append((np.abs(ray - truth) / truth)[np.isfinite(ray)])
    data["depth_unit_scale_factor"] = 0.001
    (dst / "transforms.json").write_text(json.dumps(data))
    errors = np.concatenate(errors)
    return {
        "pseudo_coverage": float(np.mean(covered)),
        "pseudo_rel_median": float(np.median(errors)) if len(errors) else None,
        "pseudo_rel_p90": float(np.percentile(errors, 90)) if len(errors) else None,
    }


def _build(scene_dir: Path, work: Path, room, steps: int | None) -> tuple[dict, object]:
    from bench_suite import three_d_metrics

    from scenelabel import build, load_scene, preset
    from scenelabel.data.suite import suite_geometry
    from scenelabel.train.pipeline import choose_views

    train = {} if steps is None else {"steps": steps, "time_budget": None}
    config = preset("fast", {"train": train, "output": {"write_map": False}})
    t0 = time.perf_counter()
    result = build(scene_dir, work / "build", config, progress=False)
    seconds = time.perf_counter() - t0
    scene = load_scene(scene_dir)
    _, test_idx, _ = choose_views(scene, config.train.holdout)
    m = result.metrics
    row = {
        "build_seconds": seconds, "steps": m["steps"], "psnr": m["psnr"], "miou": m["miou"],
        "samples_per_ray": float(np.mean([h["samples_per_ray"] for h in m["history"][-4:]])),
        **three_d_metrics(result.field, scene, test_idx, suite_geometry(room).boxes),
    }
    return row, result.field


def probe_room(name: str, steps: int | None = None) -> list[dict]:
    from scenelabel import load_scene
    from scenelabel.data.suite import suite_spec, write_suite_scene
    from scenelabel.train.pipeline import choose_views

    room = suite_spec(name)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = write_suite_scene(tmp / room.name, room)
        scene = load_scene(src)
        train_idx, _, _ = choose_views(scene, 8)
        planar_ids = [cid for cid, cname in scene.classes.items() if cname in PLANAR]
        row, field = _build(src, tmp / "none", room, steps)
        rows.append({"scene": name, "variant": "none", **row})
        exact = {i: np.where(np.isin(scene.labels[i], planar_ids), scene.depths[i], np.nan) for i in train_idx}
        sources = {
            "exact planes": exact,
            "planes 1 % behind": {i: 1.01 * d for i, d in exact.items()},
            "fitted planes": _fitted_depths(field, scene, train_idx, planar_ids),
        }
        for variant, depths in sources.items():
            folder = tmp / variant.replace(" ", "_").replace("%", "pc")
            pseudo = _with_depth(src, folder / "room", scene, depths)
            row, _ = _build(folder / "room", folder, room, steps)
            rows.append({"scene": name, "variant": variant, **pseudo, **row})
            print(rows[-1], flush=True)
    return rows


def _pct(x, digits: int = 1) -> str:
    return "n/a" if x is None else f"{100 * x:.{digits}f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["office-5x4", "studio-3x3"])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "plane_prior.md")
    parser.add_argument("--steps", type=int, default=None, help="training steps of every build, no budget (a smoke run)")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO / "tools"))
    from bench_suite import code_version

    rows = [row for name in args.scenes for row in probe_room(name, args.steps)]
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1, default=float))
    command = "tools/probe_plane_prior.py" + ("" if args.scenes == parser.get_default("scenes") else " --scenes " + " ".join(args.scenes))
    command += "" if args.steps is None else f" --steps {args.steps}"
    lines = [
        "# Depth on the planar classes only: the upper bound of a plane prior, and planes fitted without depth",
        "",
        f"Generated by `.venv/bin/python {command}` (one run, code {code_version()}); that command regenerates it. "
        f"Machine: {platform.machine()}, Python {platform.python_version()}, 2 cores.",
        "",
        *__doc__.split("\n\n", 2)[2].strip().splitlines(),
        "",
        "| room | depth given | pixels with depth % | its median / p90 rel. error % | build s | steps | PSNR | mIoU "
        "| depth rel. err. % | surface field / map % | free field % | P / R / F at 5 cm | samples/ray |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        pseudo = "-" if "pseudo_coverage" not in r else _pct(r["pseudo_coverage"])
        err = "-" if "pseudo_coverage" not in r else f"{_pct(r['pseudo_rel_median'], 2)} / {_pct(r['pseudo_rel_p90'], 1)}"
        lines.append(
            f"| {r['scene']} | {r['variant']} | {pseudo} | {err} | {r['build_seconds']:.0f} | {r['steps']} | {r['psnr']:.2f} "
            f"| {r['miou']:.3f} | {_pct(r['depth_rel_median'], 2)} | {_pct(r['surface_field'])} / {_pct(r['surface_map'])} "
            f"| {_pct(r['free_field'])} | {r['precision']:.3f} / {r['recall']:.3f} / {r['fscore']:.3f} | {r['samples_per_ray']:.1f} |"
        )
    by_variant = {v: [r for r in rows if r["variant"] == v] for v in VARIANTS}
    lines += ["", "Median over the rooms:", "", "| depth given | depth rel. err. % | surface field % | F |", "|---|---|---|---|"]
    for v, rs in by_variant.items():
        if rs:
            lines.append(
                f"| {v} | {_pct(statistics.median(r['depth_rel_median'] for r in rs), 2)} "
                f"| {_pct(statistics.median(r['surface_field'] for r in rs))} | {statistics.median(r['fscore'] for r in rs):.3f} |"
            )
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
