"""How well a room's layout comes out of its masks and poses: the planes of
scenelabel.geometry.layout.room_layout against the exact rooms, and the depth it gives the floor,
wall and ceiling pixels (what `data.layout_depth` trains on) against the exact depth. Writes
docs/layout.md (+ .json).

    .venv/bin/python tools/probe_layout.py                      # every suite room, the layout pool, the bench room, tilted and coarse cases
    .venv/bin/python tools/probe_layout.py --rooms office-5x4 --out /tmp/layout.md
    .venv/bin/python tools/probe_layout.py --rewrite            # the document again from its .json

Each room is written as the suite writes it (tools/bench_suite.py), with its training views only
(every 8th view held out, as a default build) entering the layout. Set: `tuning` and `held out`
are the suite's rooms (held out: out of every tuning decision); `pool`: forward-facing rooms that
only this probe writes (`scenelabel.data.suite.LAYOUT_POOL`), on which the layout's choices for
forward rigs are made. `tilted`: the same room with
its world turned 3 degrees about x (so "up" is not a world axis and not the cameras' mean up).
`bench room`: tools/bench.py's furnished room at 160x120 and at 80x60. Up error: the angle between
the layout's up and the true one (in brackets: the vertical of the photos' straight lines alone,
`scenelabel.geometry.vanishing`; none: too few segments agree); without lines: the layout as it is
found without the photos (from the cameras' up and the nearest world axis); floor, ceiling: the planes' heights against the true ones; walls:
how many were found and their largest offset error against the nearest true interior face; on
walls: the share of boundary cuts within 3 cm of the walls (`RoomLayout.on_walls`), and within a
pixel's reach of them (`RoomLayout.near_walls`; below `MIN_NEAR_WALLS` a build does not use the
layout); depth: over the training views' floor, wall and
ceiling pixels, |layout depth - true| / true, and the share of those pixels it covers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TILT_DEGREES = 3.0


def _rotation_x(degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])


def _interior(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The room's interior box (lo, hi) in its own frame."""
    if name.startswith("bench room"):
        from scenelabel.data.synthetic.scenes import ROOM_HALF, ROOM_HEIGHT

        return np.array([-ROOM_HALF, -ROOM_HALF, 0.0]), np.array([ROOM_HALF, ROOM_HALF, ROOM_HEIGHT])
    from scenelabel.data.suite import suite_spec

    return np.zeros(3), np.asarray(suite_spec(name.split(" ")[0]).size, np.float64)


def room_set(name: str) -> str:
    """"tuning", "held out" (a suite room out of every tuning decision) or "pool" (scenelabel.data.suite.LAYOUT_POOL's
    forward-facing rooms, which no suite run holds); tools/bench_map_ab.py labels its rows with it too."""
    from scenelabel.data.suite import LAYOUT_POOL, suite_spec

    room = name.split(" ")[0]
    if name.startswith("bench room"):
        return "tuning"
    if room in {s.name for s in LAYOUT_POOL}:
        return "pool"
    return "tuning" if suite_spec(room).tuning else "held out"


def _row(name: str, scene_dir: Path, tilt: float) -> dict:
    import dataclasses

    from scenelabel import load_scene
    from scenelabel.data.layout_depth import depth_from_layout, with_layout_depth
    from scenelabel.geometry.layout import layout_class_ids, room_layout
    from scenelabel.geometry.vanishing import vertical_from_images
    from scenelabel.train.pipeline import split_views

    scene = load_scene(scene_dir)
    rotation = _rotation_x(tilt)
    c2w = scene.cameras.c2w.copy()
    c2w[:, :3, :] = rotation @ c2w[:, :3, :]
    cams = dataclasses.replace(scene.cameras, c2w=c2w)
    train, _ = split_views(len(scene), 8)
    ids = layout_class_ids(scene.classes)
    labels, images = [scene.labels[i] for i in train], [scene.images[i] for i in train]
    t0 = time.perf_counter()
    layout = room_layout(cams[train], labels, ids, images)
    seconds = time.perf_counter() - t0
    without_lines = room_layout(cams[train], labels, ids)
    start = -cams[train].c2w[:, :3, 1].mean(axis=0)
    vertical = vertical_from_images(cams[train], images, start / np.linalg.norm(start))
    lo, hi = _interior(name)
    up = rotation @ np.array([0.0, 0.0, 1.0])
    wall_errors = []
    for wall in layout.walls:
        normal = rotation.T @ layout.basis[wall.axis]  # in the room's own frame
        axis = int(np.argmax(np.abs(normal[:2])))
        offset = wall.offset * np.sign(normal[axis])
        wall_errors.append(min(abs(offset - lo[axis]), abs(offset - hi[axis])))
    errors, covered, planar_total = [], 0, 0
    for n, i in enumerate(train):
        depth = depth_from_layout(layout, cams[train], n, scene.labels[i], ids)
        planar = np.isin(scene.labels[i], list(ids.values()))
        ok = np.isfinite(depth) & planar & (scene.depths[i] > 0)
        errors.append(np.abs(depth[ok] - scene.depths[i][ok]) / scene.depths[i][ok])
        covered += int(ok.sum())
        planar_total += int(planar.sum())
    errors = np.concatenate(errors)
    pixels = sum(int(np.prod(scene.labels[i].shape)) for i in train)
    used = with_layout_depth(dataclasses.replace(scene, cameras=cams), train)[1] is not None  # a build's own decision
    def degrees_off(direction: np.ndarray | None) -> float | None:
        return None if direction is None else float(np.degrees(np.arccos(min(1.0, float(direction @ up)))))

    return {
        "room": name,
        "set": room_set(name),
        "views": len(train),
        "resolution": f"{scene.images[0].shape[1]}x{scene.images[0].shape[0]}",
        "seconds": seconds,
        "up_error_degrees": degrees_off(layout.up),
        "lines_up_error_degrees": degrees_off(vertical),
        "without_lines_up_error_degrees": degrees_off(without_lines.up),
        "without_lines_floor_error": float(without_lines.floor - lo[2]),
        "without_lines_on_walls": without_lines.on_walls,
        "without_lines_near_walls": without_lines.near_walls,
        "floor_error": float(layout.floor - lo[2]),
        "ceiling_error": None if layout.ceiling is None else float(layout.ceiling - hi[2]),
        "walls": len(layout.walls),
        "wall_error_max": float(max(wall_errors)) if wall_errors else None,
        "on_walls": layout.on_walls,
        "near_walls": layout.near_walls,
        "used": used,
        "depth_rel_median": float(np.median(errors)),
        "depth_rel_p90": float(np.percentile(errors, 90)),
        "within_1pct": float(np.mean(errors < 0.01)),
        "coverage": covered / max(planar_total, 1),
        "planar_share": planar_total / pixels,
    }


def _cases(rooms: list[str]) -> list[tuple[str, str, float]]:
    """(name, what to write, tilt) per row."""
    cases = [(room, room, 0.0) for room in rooms]
    if "office-5x4" in rooms:
        cases.append((f"office-5x4 tilted {TILT_DEGREES:g} deg", "office-5x4", TILT_DEGREES))
    cases += [("bench room 160x120", "bench:160x120", 0.0), ("bench room 80x60", "bench:80x60", 0.0)]
    return cases


def _write(what: str, folder: Path) -> Path:
    if what.startswith("bench:"):
        from scenelabel import write_furnished_room

        width, height = (int(v) for v in what.split(":")[1].split("x"))
        return write_furnished_room(folder, width=width, height=height)
    from scenelabel.data.suite import suite_spec, write_suite_scene

    return write_suite_scene(folder, suite_spec(what))


def _document(rows: list[dict], command: str, code: str) -> str:
    lines = [
        "# A room's layout from its masks",
        "",
        f"Generated by `.venv/bin/{command}` (one run, code {code}); that command regenerates it.",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}.",
        "",
        *__doc__.split("\n\n")[2].split("\n"),
        "",
        "| room | set | training views | search s | up error deg (lines' vertical) | floor / ceiling error cm | walls (largest error cm) | on / near walls | used | without lines: up error deg, floor cm, on / near walls | depth error median / p90 % | within 1 % | covered | floor, wall, ceiling pixels |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ceiling = "-" if r["ceiling_error"] is None else f"{100 * r['ceiling_error']:+.1f}"
        walls = f"{r['walls']} ({100 * r['wall_error_max']:.1f})" if r["wall_error_max"] is not None else "0"
        lines_up = "none" if r["lines_up_error_degrees"] is None else f"{r['lines_up_error_degrees']:.3f}"
        lines.append(
            f"| {r['room']} | {r['set']} | {r['views']} @ {r['resolution']} | {r['seconds']:.1f} | {r['up_error_degrees']:.3f} ({lines_up}) | "
            f"{100 * r['floor_error']:+.1f} / {ceiling} | {walls} | {r['on_walls']:.2f} / {r['near_walls']:.2f} | {'yes' if r['used'] else 'no'} | "
            f"{r['without_lines_up_error_degrees']:.3f}, {100 * r['without_lines_floor_error']:+.1f}, {r['without_lines_on_walls']:.2f} / {r['without_lines_near_walls']:.2f} | "
            f"{100 * r['depth_rel_median']:.2f} / {100 * r['depth_rel_p90']:.2f} | {100 * r['within_1pct']:.1f} % | "
            f"{100 * r['coverage']:.0f} % | {100 * r['planar_share']:.0f} % |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    from scenelabel.data.suite import FORWARD_SUITE, LAYOUT_POOL, SUITE

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rooms", nargs="+", default=[s.name for s in SUITE + FORWARD_SUITE + LAYOUT_POOL])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "layout.md")
    parser.add_argument("--rewrite", action="store_true", help="rewrite the document from OUT's .json")
    args = parser.parse_args()
    if args.rewrite:
        data = json.loads(args.out.with_suffix(".json").read_text())
    else:
        code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()
        if subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "scenelabel"], cwd=REPO).returncode:
            code += "+changes"
        command = "python " + " ".join([Path(sys.argv[0]).relative_to(REPO).as_posix() if Path(sys.argv[0]).is_absolute() else sys.argv[0], *sys.argv[1:]])
        data = {"command": command, "code": code, "rows": []}
        with tempfile.TemporaryDirectory() as tmp:
            written: dict[str, Path] = {}
            for name, what, tilt in _cases(args.rooms):
                if what not in written:
                    written[what] = _write(what, Path(tmp) / what.replace(":", "_"))
                row = _row(name, written[what], tilt)
                data["rows"].append(row)
                print(json.dumps(row), flush=True)
        args.out.with_suffix(".json").write_text(json.dumps(data, indent=2))
    args.out.write_text(_document(data["rows"], data["command"], data["code"]))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
