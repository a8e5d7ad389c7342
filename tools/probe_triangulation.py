"""Would sparse depth from triangulated features help the suite's rooms? (DS-NeRF's depth prior,
a candidate of the scene-suite issue.) Writes docs/triangulation.md.

    .venv/bin/python tools/probe_triangulation.py
    .venv/bin/python tools/probe_triangulation.py --scenes studio-3x3 den-5x5 --out /tmp/t.md

For each suite room (written as a build sees it) the training views' photos get SIFT features and
exhaustive matches (pycolmap, CPU, COLMAP's defaults), and points are triangulated with the given
poses and intrinsics held fixed (``pycolmap.triangulate_points``). Each observation of a point seen
by at least 3 views is a sparse depth: its distance from the camera centre, compared with the exact
ray depth of the pixel holding the keypoint. The table says how many depths a view would get and how
good they are; a sparse-depth term is only worth adding where there are enough of them and they are right.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MIN_TRACK = 3  # views that see a point before its depth counts


def triangulated_depths(scene, views: list[int], work: Path):
    """Per view in ``views``: [k] keypoint pixel (col, row) int and [k] distance from the camera
    centre of the points triangulated with the scene's own cameras (track >= MIN_TRACK), and the
    number of keypoints extracted per view."""
    import pycolmap
    from PIL import Image

    images = work / "images"
    images.mkdir(parents=True)
    cams = scene.cameras
    for i in views:
        Image.fromarray((np.clip(scene.images[i], 0, 1) * 255).round().astype(np.uint8)).save(images / f"{i:05d}.png")
    database = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    pycolmap.extract_features(database, images, reader_options=reader, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    reconstruction = pycolmap.Reconstruction()
    with pycolmap.Database.open(database) as db:
        records = db.read_all_images()
        keypoints = {int(Path(im.name).stem): db.num_keypoints_for_image(im.image_id) for im in records}
    for im in records:
        i = int(Path(im.name).stem)
        camera = pycolmap.Camera(model="PINHOLE", width=int(cams.width[i]), height=int(cams.height[i]),
                                 params=[cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i]], camera_id=im.camera_id)
        reconstruction.add_camera_with_trivial_rig(camera)
        image = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=im.image_id)
        reconstruction.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(cams.c2w[i])[:3, :4]))
    (work / "model").mkdir()
    reconstruction = pycolmap.triangulate_points(reconstruction, database, images, work / "model")
    out = {i: (np.zeros((0, 2), int), np.zeros(0)) for i in views}
    for im in reconstruction.images.values():
        i = int(Path(im.name).stem)
        pixels, depths = [], []
        for p in im.points2D:
            if p.has_point3D() and reconstruction.points3D[p.point3D_id].track.length() >= MIN_TRACK:
                pixels.append(np.floor(p.xy).astype(int))
                depths.append(float(np.linalg.norm(reconstruction.points3D[p.point3D_id].xyz - cams.c2w[i][:3, 3])))
        if pixels:
            out[i] = (np.array(pixels), np.array(depths))
    return out, keypoints


def probe_room(name: str) -> dict:
    import pycolmap

    from scenelabel import load_scene
    from scenelabel.data.sfm import quiet_colmap
    from scenelabel.data.suite import write_suite_scene
    from scenelabel.train.pipeline import choose_views

    with tempfile.TemporaryDirectory() as tmp, quiet_colmap(pycolmap):
        scene_dir = write_suite_scene(Path(tmp) / name, name)
        scene = load_scene(scene_dir)
        train, _, _ = choose_views(scene, 8)
        frames = json.loads((scene_dir / "transforms.json").read_text())["frames"]
        found, keypoints = triangulated_depths(scene, train, Path(tmp) / "sfm")
        errors, per_view = [], []
        for i, (pixels, depths) in found.items():
            true = np.load(scene_dir / frames[i]["depth_path"])
            inside = (pixels[:, 0] < true.shape[1]) & (pixels[:, 1] < true.shape[0]) & (pixels >= 0).all(1)
            t = true[pixels[inside, 1], pixels[inside, 0]]
            ok = t > 0
            errors += list(np.abs(depths[inside][ok] - t[ok]) / t[ok])
            per_view.append(int(inside.sum()))
        pixels_per_view = int(scene.images[train[0]].shape[0] * scene.images[train[0]].shape[1])
    errors = np.asarray(errors)
    return {
        "scene": name,
        "views": len(train),
        "keypoints": statistics.median(keypoints.values()),
        "depths_per_view": statistics.median(per_view),
        "depths_min": min(per_view),
        "depths_total": int(sum(per_view)),
        "ray_share": statistics.median(per_view) / pixels_per_view,
        "error_median": float(np.median(errors)) if len(errors) else None,
        "error_over_5pct": float(np.mean(errors > 0.05)) if len(errors) else None,
    }


def _pct(x, digits: int) -> str:
    return "n/a" if x is None else f"{100 * x:.{digits}f} %"


def main(argv: list[str] | None = None) -> int:
    from scenelabel.data.suite import SUITE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=[s.name for s in SUITE if s.width == 160])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "triangulation.md")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO / "tools"))
    from bench_suite import code_version

    rows = []
    for name in args.scenes:
        rows.append(probe_room(name))
        print(rows[-1], flush=True)
    lines = [
        "# Sparse depth from triangulated features on the scene suite",
        "",
        f"Generated by `.venv/bin/python tools/probe_triangulation.py` (one run, code {code_version()}); that command "
        f"regenerates it. Machine: {platform.machine()}, Python {platform.python_version()}.",
        "",
        "DS-NeRF supervises depth at the keypoints that structure from motion triangulates. Here the",
        "training views' features (SIFT with COLMAP's default settings, exhaustive matching, pycolmap) are",
        f"triangulated with the rooms' own poses held fixed; a point seen by at least {MIN_TRACK} views gives each of",
        "its observations a depth, compared with the exact depth of the keypoint's pixel.",
        "",
        "Keypoints and depths per view are medians over the training views.",
        "",
        "| room | training views | keypoints / view | depths / view (fewest) | depths, all views | share of pixel rays | median rel. error | error > 5 % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['views']} | {r['keypoints']:.0f} | {r['depths_per_view']:.0f} ({r['depths_min']}) | {r['depths_total']} | "
            f"{_pct(r['ray_share'], 2)} | {_pct(r['error_median'], 1)} | {_pct(r['error_over_5pct'], 0)} |"
        )
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
