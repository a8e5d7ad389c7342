"""Plan a 2D path on a scenelabel occupancy map with zarr and numpy alone (no scenelabel import).

Run on the toy scene::

    scenelabel toy toy_scene && scenelabel build toy_scene --preset quick
    python examples/plan_path.py toy_scene/scenelabel/map.zarr --start -1.2 -1.2 --goal 1.2 1.2 --png plan.png

What it does, in the map's world frame and units (docs/formats.md):

1. Reads the ``label`` array [nx, ny, nz] (class id >= 0, FREE = -1, UNKNOWN = -2; indexed along
   world x, y, z) and the group attributes ``voxel_size`` and ``origin`` (centre of voxel [0, 0, 0]).
2. Flattens a height band to a 2D floor plan, with the same rules as ``scenelabel export --format
   nav2``: a cell is occupied when any voxel of its column in the band has a class, free only when
   every voxel in the band is FREE, unknown otherwise. The band holds the layers whose centre z is
   in [z_min, z_max]; by default from one voxel above the floor's top (the highest layer holding at
   least half as many ``floor`` voxels as the fullest floor layer, else the lowest occupied layer)
   to below the ``ceiling`` (else the map's top), or floor top + --robot-height.
3. Reads the clearance of each cell from the map's ``esdf`` array (float32 [nx, ny, nz]: signed
   distance in world units to the nearest obstacle, negative inside; unknown space and the map's
   outside count as obstacles): its value at the cell centre's x, y and the clearance height
   (--clearance-height, default the middle of the band), linear between the two nearest layers.
   That is the room a spherical robot centred there has, in 3D.
4. Blocks occupied and unknown cells (never drives into space nobody has seen), inflated by
   --robot-radius, and cells with less clearance than --min-clearance, and runs A* (8-connected,
   octile distance, no cutting corners). A step costs its length times ``1 + w * max(0, 1 - c /
   D)`` (the mean over its two cells), c the cell's clearance, D = --clearance (default 5 voxels),
   w = --clearance-weight: the path keeps away from obstacles where that costs little.
5. Prints the waypoints (cell centres, world x y), the path length and its smallest clearance at
   the waypoints; --png draws the path over the label image (row 0 = max y, as in the Nav2 export).

Maps written before scenelabel stored the ``esdf`` array plan without clearance (the example says
so; --min-clearance then refuses to run).

Exit status: 0 with a path, 1 when no path exists, 2 for bad input (start or goal outside the map,
occupied, unknown or too close to an obstacle).
"""

from __future__ import annotations

import argparse
import heapq
import math
import sys

import numpy as np
import zarr

FLOOR_NAMES = ("floor", "ground")
CEILING_NAMES = ("ceiling",)
DENSE_LAYER_FRACTION = 0.5
FREE_RGB, UNKNOWN_RGB, INFLATED_RGB = (254, 254, 254), (205, 205, 205), (215, 225, 245)
NEIGHBOURS = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]


def default_color(class_id: int) -> tuple[int, int, int]:
    """scenelabel's colour of a class without one (golden-ratio hues; the same as in its renders
    and exports), written out here so that this example needs zarr and numpy only."""
    hue = (class_id * 0.618033988749895) % 1.0
    x = 1 - abs(hue * 6 % 2 - 1)
    rgb = [(1, x, 0), (x, 1, 0), (0, 1, x), (0, x, 1), (x, 0, 1), (1, 0, x)][int(hue * 6) % 6]
    return tuple(int(40 + 200 * c) for c in rgb)


class PlanError(Exception):
    """Bad input (exit status 2)."""


# ---------------------------------------------------------------------------------------------
# The floor plan
# ---------------------------------------------------------------------------------------------


def class_layer_counts(label, classes, names):
    """[nz] voxels per layer of the classes called one of ``names``; None when there are none."""
    ids = [c["id"] for c in classes if c["name"].strip().lower() in names]
    counts = np.isin(label, ids).sum(axis=(0, 1)) if ids else None
    return counts if counts is not None and counts.any() else None


def dense_layer(counts, highest):
    """Highest (lowest) layer holding at least half as many voxels as the fullest layer."""
    dense = np.flatnonzero(counts >= DENSE_LAYER_FRACTION * counts.max())
    return int(dense.max() if highest else dense.min())


def height_band(label, classes, origin_z, voxel_size, z_min=None, z_max=None, robot_height=None):
    """(z_min, z_max) world z of the band, defaults as in the module docstring."""
    nz = label.shape[2]
    bottom, top = origin_z - voxel_size / 2, origin_z + voxel_size * (nz - 0.5)
    floor = class_layer_counts(label, classes, FLOOR_NAMES)
    if floor is not None:
        floor_k = dense_layer(floor, highest=True)
    else:
        layers = np.flatnonzero((label >= 0).any(axis=(0, 1)))
        floor_k = int(layers[0]) if len(layers) else None
    floor_top = bottom if floor_k is None else origin_z + voxel_size * (floor_k + 0.5)
    if z_min is None:
        z_min = bottom if floor_k is None else floor_top + voxel_size
    if z_max is None:
        ceiling = class_layer_counts(label, classes, CEILING_NAMES)
        if robot_height is not None:
            z_max = floor_top + robot_height
        elif ceiling is not None:
            z_max = origin_z + voxel_size * (dense_layer(ceiling, highest=False) - 0.5) - voxel_size
        else:
            z_max = top
    if not z_min < z_max:
        raise PlanError(f"the height band needs z_min < z_max, got [{z_min:g}, {z_max:g}]")
    return z_min, z_max


def floor_plan(label, z_min, z_max, origin_z, voxel_size):
    """[nx, ny] int: class of the highest voxel with a class in the band, else -1 (all FREE) or -2."""
    z = origin_z + voxel_size * np.arange(label.shape[2])
    band = label[:, :, (z >= z_min) & (z <= z_max)]  # [nx, ny, nb]
    if band.shape[2] == 0:
        raise PlanError(f"the height band [{z_min:g}, {z_max:g}] holds no voxel layer (centres {z[0]:g}..{z[-1]:g})")
    has_class = band >= 0
    highest = band.shape[2] - 1 - np.argmax(has_class[:, :, ::-1], axis=2)
    top_class = np.take_along_axis(band, highest[:, :, None], axis=2)[:, :, 0]
    return np.where(has_class.any(axis=2), top_class, np.where(np.all(band == -1, axis=2), -1, -2))


def clearance_map(group, shape, origin_z, voxel_size, height):
    """[nx, ny] float: the stored ESDF at each cell centre's x, y and world z = ``height``, linear
    between the two nearest layers of voxel centres (clamped to the map); None when the map has no
    ``esdf`` array (or one of another rule than unknown space as obstacles)."""
    if "esdf" not in group or group["esdf"].attrs.get("unknown") != "occupied":
        return None
    nz = shape[2]
    u = min(max((height - origin_z) / voxel_size, 0.0), nz - 1.0)  # continuous layer index
    k0 = min(math.floor(u), max(nz - 2, 0))
    layers = np.asarray(group["esdf"][:, :, k0 : k0 + 2], dtype=np.float64)  # [nx, ny, 1 or 2]: 2 layers read
    if layers.shape[2] == 1:
        return layers[:, :, 0]
    t = u - k0
    return (1 - t) * layers[:, :, 0] + t * layers[:, :, 1]


def step_costs(clearance, preferred, weight):
    """[nx, ny] cost factor >= 1 of a cell: ``1 + weight * max(0, 1 - clearance / preferred)``."""
    if clearance is None or weight <= 0 or preferred <= 0:
        return None
    return 1.0 + weight * np.clip(1.0 - clearance / preferred, 0.0, 1.0)


def inflate(blocked, radius_cells):
    """[nx, ny] bool: cells within ``radius_cells`` (centre to centre) of a blocked cell."""
    r = math.floor(radius_cells)
    out = blocked.copy()
    nx, ny = blocked.shape
    for di in range(-r, r + 1):
        for dj in range(-r, r + 1):
            if (di, dj) == (0, 0) or di * di + dj * dj > radius_cells * radius_cells:
                continue
            src = blocked[max(0, -di) : nx - max(0, di), max(0, -dj) : ny - max(0, dj)]
            out[max(0, di) : nx - max(0, -di), max(0, dj) : ny - max(0, -dj)] |= src
    return out


# ---------------------------------------------------------------------------------------------
# A*
# ---------------------------------------------------------------------------------------------


def octile(a, b):
    di, dj = abs(a[0] - b[0]), abs(a[1] - b[1])
    return max(di, dj) + (math.sqrt(2) - 1) * min(di, dj)


def astar(blocked, start, goal, cost=None):
    """Cheapest 8-connected path of cells from start to goal avoiding ``blocked``; None if none.

    A step costs its length (1 or sqrt 2 cells) times the mean ``cost`` factor (>= 1, so the
    octile distance stays an admissible heuristic) of its two cells; ``cost`` None: its length.
    A diagonal step is allowed only when both cells beside it are free (no cutting corners).
    """
    nx, ny = blocked.shape
    best = {start: 0.0}
    came_from = {}
    heap = [(octile(start, goal), 0.0, start)]
    while heap:
        _, g, cell = heapq.heappop(heap)
        if cell == goal:
            path = [cell]
            while cell in came_from:
                cell = came_from[cell]
                path.append(cell)
            return path[::-1]
        if g > best[cell]:
            continue  # a stale entry
        i, j = cell
        for di, dj in NEIGHBOURS:
            ni, nj = i + di, j + dj
            if not (0 <= ni < nx and 0 <= nj < ny) or blocked[ni, nj]:
                continue
            if di and dj and (blocked[i + di, j] or blocked[i, j + dj]):
                continue
            step = math.sqrt(2) if di and dj else 1.0
            if cost is not None:
                step *= 0.5 * (cost[i, j] + cost[ni, nj])
            new_cost = g + step
            if new_cost < best.get((ni, nj), math.inf):
                best[(ni, nj)] = new_cost
                came_from[(ni, nj)] = cell
                heapq.heappush(heap, (new_cost + octile((ni, nj), goal), new_cost, (ni, nj)))
    return None


# ---------------------------------------------------------------------------------------------
# Drawing
# ---------------------------------------------------------------------------------------------


def draw_png(path_png, plan, blocked, classes, cells):
    """The label image (row 0 = max y) scaled up, with the path, start (green) and goal (magenta).

    Free cells closer than the robot radius to an obstacle (blocked by inflation) are tinted blue.
    """
    from PIL import Image, ImageDraw

    palette = {c["id"]: tuple(c["color"]) if c.get("color") else default_color(c["id"]) for c in classes}
    nx, ny = plan.shape
    rgb = np.empty((nx, ny, 3), np.uint8)
    rgb[plan == -2] = UNKNOWN_RGB
    rgb[plan == -1] = FREE_RGB
    rgb[(plan == -1) & blocked] = INFLATED_RGB
    for cid, colour in palette.items():
        rgb[plan == cid] = colour
    image = np.swapaxes(rgb, 0, 1)[::-1]  # [ny, nx, 3]: row 0 = max y, column 0 = min x
    scale = max(1, 600 // max(nx, ny))
    img = Image.fromarray(np.ascontiguousarray(image)).resize((nx * scale, ny * scale), Image.NEAREST)

    def pixel(cell):  # centre of cell (i, j) in the scaled image
        return ((cell[0] + 0.5) * scale, (ny - 1 - cell[1] + 0.5) * scale)

    draw = ImageDraw.Draw(img)
    draw.line([pixel(c) for c in cells], fill=(0, 0, 0), width=max(2, scale // 2))
    for cell, colour in ((cells[0], (0, 170, 0)), (cells[-1], (200, 0, 200))):
        x, y = pixel(cell)
        r = max(3, scale)
        draw.ellipse([x - r, y - r, x + r, y + r], fill=colour, outline=(0, 0, 0))
    img.save(path_png)


# ---------------------------------------------------------------------------------------------


def cell_of(name, xy, origin, voxel_size, plan, blocked, free_before_inflation, names, clearance, min_clearance):
    """The plan cell of a world (x, y), checked to be inside, free and not too close to obstacles
    (``clearance`` [nx, ny] or None: see :func:`clearance_map`)."""
    i, j = (int(v) for v in np.floor((np.asarray(xy) - origin[:2]) / voxel_size + 0.5))
    if not (0 <= i < plan.shape[0] and 0 <= j < plan.shape[1]):
        raise PlanError(f"{name} ({xy[0]:g}, {xy[1]:g}) is outside the map")
    if plan[i, j] >= 0:
        raise PlanError(f"{name} ({xy[0]:g}, {xy[1]:g}) is occupied by {names.get(int(plan[i, j]), plan[i, j])}")
    if plan[i, j] == -2:
        raise PlanError(f"{name} ({xy[0]:g}, {xy[1]:g}) is in unknown space")
    if clearance is not None and clearance[i, j] < min_clearance:
        raise PlanError(
            f"{name} ({xy[0]:g}, {xy[1]:g}) has clearance {clearance[i, j]:.3f}, "
            f"less than --min-clearance {min_clearance:g}"
        )
    if blocked[i, j] and free_before_inflation[i, j]:
        raise PlanError(f"{name} ({xy[0]:g}, {xy[1]:g}) is closer than the robot radius to an obstacle")
    return i, j


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("map", help="occupancy map .zarr folder (scenelabel build or export)")
    parser.add_argument("--start", nargs=2, type=float, required=True, metavar=("X", "Y"), help="world x y")
    parser.add_argument("--goal", nargs=2, type=float, required=True, metavar=("X", "Y"), help="world x y")
    parser.add_argument("--robot-radius", type=float, default=0.0, help="inflate obstacles by this (world units)")
    parser.add_argument("--z-min", type=float, help="bottom of the height band (world z)")
    parser.add_argument("--z-max", type=float, help="top of the height band (world z)")
    parser.add_argument("--robot-height", type=float, help="band top = floor top + this")
    parser.add_argument("--clearance-height", type=float, help="world z at which the esdf is read (default: mid band)")
    parser.add_argument("--clearance", type=float, help="preferred clearance D, world units (default: 5 voxels)")
    parser.add_argument("--clearance-weight", type=float, default=1.0, help="w of the clearance cost (0: shortest)")
    parser.add_argument("--min-clearance", type=float, default=0.0, help="never closer than this to an obstacle")
    parser.add_argument("--png", help="draw the path over the label image into this PNG")
    args = parser.parse_args(argv)

    try:
        group = zarr.open_group(args.map, mode="r")
        attrs = group.attrs.asdict()
        label = np.asarray(group["label"][...])  # [nx, ny, nz]
        voxel_size, origin, classes = float(attrs["voxel_size"]), np.asarray(attrs["origin"], float), attrs["classes"]
    except Exception as exc:  # noqa: BLE001 - any failure here means "not a readable map"
        print(f"plan_path: error: {args.map}: not a scenelabel occupancy map ({type(exc).__name__}: {exc})", file=sys.stderr)
        return 2
    names = {c["id"]: c["name"] for c in classes}
    units = attrs.get("units", "")
    try:
        z_min, z_max = height_band(label, classes, origin[2], voxel_size, args.z_min, args.z_max, args.robot_height)
        plan = floor_plan(label, z_min, z_max, origin[2], voxel_size)  # [nx, ny]
        free = plan == -1
        blocked = inflate(~free, args.robot_radius / voxel_size)  # occupied and unknown cells block
        height = 0.5 * (z_min + z_max) if args.clearance_height is None else args.clearance_height
        clearance = clearance_map(group, label.shape, origin[2], voxel_size, height)  # [nx, ny] or None
        if clearance is None and args.min_clearance > 0:
            raise PlanError("--min-clearance needs the map's esdf array (an older map has none: export it again)")
        if clearance is not None:
            blocked |= clearance < args.min_clearance
        ends = (origin, voxel_size, plan, blocked, free, names, clearance, args.min_clearance)
        start = cell_of("start", args.start, *ends)
        goal = cell_of("goal", args.goal, *ends)
    except PlanError as err:
        print(f"plan_path: error: {err}", file=sys.stderr)
        return 2
    print(f"floor plan: {plan.shape[0]} x {plan.shape[1]} cells of {voxel_size:g}, z band [{z_min:.3f}, {z_max:.3f}], "
          f"{int((plan >= 0).sum())} occupied, {int(free.sum())} free, {int((plan == -2).sum())} unknown")
    preferred = 5 * voxel_size if args.clearance is None else args.clearance
    if clearance is None:
        print("clearance: the map has no esdf array (an older map): planning without it")
    else:
        print(f"clearance: esdf at z = {height:.3f}, preferred {preferred:g}, weight {args.clearance_weight:g}, "
              f"minimum {args.min_clearance:g}")

    cells = astar(blocked, start, goal, step_costs(clearance, preferred, args.clearance_weight))
    if cells is None:
        print(f"plan_path: no path from {tuple(args.start)} to {tuple(args.goal)} through free space", file=sys.stderr)
        return 1
    waypoints = origin[:2] + voxel_size * np.asarray(cells, float)  # [n, 2] cell centres
    length = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
    unit = f" {units}" if units else ""
    if clearance is None:
        lowest = "unknown"
    else:
        lowest = f"{min(clearance[c] for c in cells):.4f}{unit}"
    print(f"path: {len(cells)} waypoints, length {length:.3f}{unit}, min clearance {lowest}")
    for x, y in waypoints:
        print(f"{x:.4f} {y:.4f}")
    if args.png:
        draw_png(args.png, plan, blocked, classes, cells)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
