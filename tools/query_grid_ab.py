"""Where query time goes on the furnished room: the density grid's share of the box, and an A/B of grids.

    .venv/bin/python tools/query_grid_ab.py                      # builds the room (fast, 170 s), prints the tables
    .venv/bin/python tools/query_grid_ab.py --build DIR          # an existing build folder of the room instead

One field, five grids, the same points and rays (those of tools/bench.py: 1M uniform points in the
bounds; 100k rays from the middle of the bounds in random directions, depth + label, no colour):

- ``as trained``: the grid saved with the build (rebuilt from the final field, border cells looked at again);
- ``rebuild, no border pass`` / ``rebuild, border 1``: ``DensityGrid.rebuild`` of the same field;
- ``every cell``: nothing skipped (the reference the others are compared with);
- ``as trained, behind the walls dropped``: cells more than WALL_CELLS cells beyond the walls' inner
  faces (space no camera sees) dropped as well: what skipping unobserved space would give (not a
  rule the library has).

Also the share of cells above the grid's threshold in the room and behind its walls, by how
far above (the density of a cell over the density that makes one marching step alpha_threshold
opaque). Medians of 3 timings; every number comes from this run. Two rows that are the same grid
("as trained" and "rebuild, border 1") show the machine's timing noise.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from bench import (  # tools/ is on sys.path when run as a script
    QUERY_POINTS,
    QUERY_RAYS,
    REPEATS,
    _ray_accuracy,
    query_inputs,
)

from scenelabel import SemanticField, build, preset, write_furnished_room
from scenelabel.data import synthetic

WALL_CELLS = 2
"""Cells within this many cells beyond the walls' inner faces count as the room (they hold the walls' density)."""


def _cell_centres_world(field: SemanticField) -> np.ndarray:
    """World centres of the density grid's cells, [R³, 3] in the grid's flat order."""
    grid = field.occupancy
    u = (torch.arange(grid.resolution) + 0.5) / grid.resolution * 2.0 - 1.0
    unit = torch.stack(torch.meshgrid(u, u, u, indexing="ij"), -1).reshape(-1, 3)
    return field.frame.to_world(grid.warp.inverse(unit).numpy())


def _in_room(xyz: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Points inside the room's walls (interior [-3, 3]² x [0, 2.6]) grown by ``margin`` [3]."""
    h, top = synthetic.ROOM_HALF, synthetic.ROOM_HEIGHT
    return (np.abs(xyz[:, 0]) < h + margin[0]) & (np.abs(xyz[:, 1]) < h + margin[1]) & (xyz[:, 2] > -margin[2]) & (
        xyz[:, 2] < top + margin[2]
    )


def _median_seconds(fn) -> tuple[float, object]:
    times, out = [], None
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build", help="an existing build folder of the furnished room (default: build one)")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--budget", type=float, default=170.0, help="training seconds when building (default: 170)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as tmp:
        if args.build:
            field = SemanticField.load(args.build)
            print(f"field: {args.build}")
        else:
            scene = write_furnished_room(Path(tmp) / "room")
            config = preset(args.preset, {"train": {"time_budget": args.budget}, "output": {"write_map": False}})
            result = build(scene, Path(tmp) / "build", config, progress=False)
            field = result.field
            m = result.metrics
            print(f"field: room, preset {args.preset}, {m['steps']} steps in {m['train_seconds']:.0f} s, "
                  f"held-out PSNR {m['psnr']:.2f} dB, mIoU {m['miou']:.3f}")
        report(field)


def report(field: SemanticField) -> None:
    grid = field.occupancy
    r = grid.resolution
    centres = _cell_centres_world(field)
    room = _in_room(centres, WALL_CELLS * (field.aabb[1] - field.aabb[0]) / r).reshape(r, r, r)
    ratio = (grid.density / grid.sigma_threshold).numpy()
    print(f"\ngrid {r}³; cells of the room (inside the walls, grown by {WALL_CELLS} cells): {room.mean():.1%} of the box")
    print("| cells with density / threshold above | in the room | behind its walls |")
    print("|---|---|---|")
    for q in (1, 3, 10, 30, 100):
        print(f"| {q} | {(ratio[room] > q).mean():.1%} | {(ratio[~room] > q).mean():.1%} |")

    points, origins, directions = query_inputs(field)
    truth = synthetic.cast_rays(origins, directions, synthetic.ROOM_BOXES)

    trained = grid.bits.clone()
    density = field.model.density

    def use(name: str) -> None:
        if name == "as trained":
            grid.bits = trained
        elif name == "every cell":
            grid.bits = torch.ones_like(trained)
        elif name == "as trained, behind the walls dropped":
            grid.bits = trained & torch.as_tensor(room)
        else:
            grid.rebuild(density, border=0 if name.endswith("no border pass") else 1)

    names = ("every cell", "as trained", "rebuild, no border pass", "rebuild, border 1", "as trained, behind the walls dropped")
    rows, answers = [], {}
    for name in names:
        use(name)
        point_s, pq = _median_seconds(lambda: field.query_points(points))
        ray_s, rq = _median_seconds(lambda: field.query_rays(origins, directions, with_rgb=False))
        answers[name] = (pq, rq)
        scored = _ray_accuracy(rq.label, rq.depth, truth)
        rows.append((name, grid.occupied_fraction, QUERY_POINTS / point_s, QUERY_RAYS / ray_s,
                     scored["label_accuracy"], scored["depth_median_error"]))
    ref_p, ref_r = answers["every cell"]
    print("\n| grid | cells occupied | query_points pts/s | query_rays rays/s | ray labels vs truth | ray depth error "
          "(median) | point labels as every cell | ray labels as every cell | ray depth vs every cell: p99 / max |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (name, occ, pts_s, rays_s, acc, derr) in rows:
        pq, rq = answers[name]
        diff = np.abs(rq.depth - ref_r.depth)
        print(f"| {name} | {occ:.1%} | {pts_s:,.0f} | {rays_s:,.0f} | {acc:.2%} | {derr:.3f} | "
              f"{np.mean(pq.label == ref_p.label):.2%} | {np.mean(rq.label == ref_r.label):.2%} | "
              f"{np.quantile(diff, 0.99):.3f} / {diff.max():.3f} |")


if __name__ == "__main__":
    main()
