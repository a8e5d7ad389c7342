"""How sharp a built field's surfaces are: density and occupancy along held-out pixel rays around
the true surface, and how long a stretch of each ray carries its weight.

    .venv/bin/python tools/surface_profile.py SCENE BUILD            # e.g. a suite room and its build
    .venv/bin/python tools/surface_profile.py SCENE BUILD --rays 3000 --seed 0

SCENE must carry exact depth (depths/*.npy: the synthetic scenes and the scene suite). For each
offset d from the true surface along the ray (negative: in front of it) it prints the median and
25th percentile of the field's occupancy (``query_points``) at that point, the share of points
with occupancy >= 0.5 and the median density (per world unit); then, from a fine march of the
field's density along the same rays (step --step), the median length of the stretch that holds
the middle 80 % of each ray's weight (10th to 90th percentile), beside the median true depth, and
the signed depth error of ``query_rays``. A solid field has occupancy near 1 from d = 0 on and a
stretch of a few centimetres; a soft one spreads its weight over tens of centimetres.
"""

from __future__ import annotations

import argparse

import numpy as np

OFFSETS = (-0.2, -0.1, -0.05, -0.02, 0.0, 0.02, 0.05, 0.1, 0.2)


def main() -> None:
    from scenelabel import SemanticField, load_scene
    from scenelabel.geometry.rays import rays_from_cameras
    from scenelabel.train.pipeline import choose_views

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("build")
    parser.add_argument("--rays", type=int, default=3000)
    parser.add_argument("--step", type=float, default=0.005, help="march step (world units) of the weight stretch")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    scene, field = load_scene(args.scene), SemanticField.load(args.build)
    _, test, _ = choose_views(scene, field.config.train.holdout)
    parts = [(*rays_from_cameras(scene.cameras, i), scene.depths[i].reshape(-1)) for i in test]
    o, d, z = (np.concatenate([p[k] for p in parts]) for k in range(3))
    hit = z > 0
    pick = np.random.default_rng(args.seed).choice(np.flatnonzero(hit), min(args.rays, int(hit.sum())), replace=False)
    o, d, z = o[pick], d[pick], z[pick].astype(np.float64)
    print(f"{len(o)} held-out pixel rays of {len(test)} views; occupancy_delta {field.occupancy_delta:.4f}")
    print("offset m | occupancy median / p25 | occupied share | density median /m")
    for off in OFFSETS:
        q = field.query_points(o + (z + off)[:, None] * d)
        print(
            f"{off:+8.2f} | {np.median(q.occupancy):.3f} / {np.percentile(q.occupancy, 25):.3f} | "
            f"{np.mean(q.occupancy >= 0.5):.3f} | {np.median(q.density):.1f}"
        )
    ts = np.arange(0.5 * args.step, float(z.max()) + 0.5, args.step)  # sample middles
    widths = []
    for rows in np.array_split(np.arange(len(o)), max(1, len(o) // 200)):
        sig = field.query_points((o[rows, None, :] + ts[None, :, None] * d[rows, None, :]).reshape(-1, 3)).density
        sig = sig.reshape(len(rows), -1)
        tau = np.cumsum(sig * args.step, 1)
        w = np.exp(-(tau - sig * args.step)) * -np.expm1(-sig * args.step)  # NeRF's weights (eq. 3)
        c = np.cumsum(w, 1) / np.maximum(w.sum(1, keepdims=True), 1e-12)
        widths.append(ts[np.argmax(c > 0.9, 1)] - ts[np.argmax(c > 0.1, 1)])
    depth_error = field.query_rays(o, d, with_rgb=False).depth - z
    print(f"weight stretch (10-90 %) median {np.median(np.concatenate(widths)):.3f} m; true depth median {np.median(z):.3f} m")
    print(
        f"query_rays depth - true depth: median {np.median(depth_error):+.3f} m, p10 {np.percentile(depth_error, 10):+.3f}, "
        f"p90 {np.percentile(depth_error, 90):+.3f}; median relative error {np.median(np.abs(depth_error) / z):.4f}"
    )


if __name__ == "__main__":
    main()
