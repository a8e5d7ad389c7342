"""How the depth resampler's agreement tolerance trades holes for errors on phone-like depth.

Writes the furnished room (8 views, 256x192 by default), adds phone-like depth
(scenelabel.data.synthetic.phone_depth.add_phone_depth: quarter resolution, 1.5 % noise, holes),
and for each tolerance of scenelabel.data.io.depth.resample_depth reports, over the colour pixels
that see a surface: the fraction left without depth (NaN) and the relative error of the others
against the exact ray distance. Prints a Markdown table.

    .venv/bin/python tools/bench_depth_resample.py [--width 256 --height 192 --noise 0.015]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from scenelabel.data.io import load_scene
from scenelabel.data.io.depth import (
    metric_depth_from_raw,
    ray_depth_from_z_depth,
    read_depth_raw,
    resample_depth,
)
from scenelabel.data.synthetic import write_furnished_room
from scenelabel.data.synthetic.phone_depth import add_phone_depth

TOLERANCES = (0.03, 0.05, 0.08, 0.1, 0.2, float("inf"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--noise", type=float, default=0.015)
    parser.add_argument("--scale", type=int, default=4)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = write_furnished_room(Path(tmp) / "room", n_train=7, n_test=1, width=args.width, height=args.height)
        print(f"furnished room, 8 views, {args.width}x{args.height}, depth 1/{args.scale}, noise {args.noise}")
        for edges, edge_threshold in (("holes at depth edges", 0.05), ("no holes at depth edges", 1e9)):
            add_phone_depth(root, scale=args.scale, noise=args.noise, edge_threshold=edge_threshold)
            _table(root, edges, args)


def _table(root: Path, edges: str, args) -> None:
    scene = load_scene(root)
    cams = scene.cameras
    raws = [read_depth_raw(root / "depth" / f"{name}.png") for name in scene.names]
    print(f"\n{edges}: {np.mean([np.mean(r == 0) for r in raws]):.3f} of the depth pixels are holes\n")
    print("| tolerance | surface pixels without depth | median rel. error | p99 | max |")
    print("|---|---|---|---|---|")
    for tol in TOLERANCES:
        errors, holes = [], []
        for i, (raw, truth) in enumerate(zip(raws, scene.depths)):
            z = resample_depth(metric_depth_from_raw(raw, 1e-3), args.width, args.height, tolerance=tol)
            t = ray_depth_from_z_depth(z, cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i], cams.distortion[i])
            surface = truth > 0
            ok = surface & np.isfinite(t)
            errors.append(np.abs(t[ok] / truth[ok] - 1))
            holes.append(np.mean(~np.isfinite(t[surface])))
        err = np.concatenate(errors)
        print(f"| {tol:g} | {np.mean(holes):.3f} | {np.median(err):.4f} | {np.percentile(err, 99):.4f} | {err.max():.3f} |")


if __name__ == "__main__":
    main()
