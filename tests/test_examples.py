"""The examples in examples/, run as a user would (subprocesses) on the shared toy build.

The toy build is the session fixture ``toy_build`` of tests/conftest.py (one training run, shared
with test_end_to_end.py). Outputs are checked against the toy scene's exact geometry
(scenelabel.data.synthetic.TOY_BOXES), its ground-truth depth and labels, and the library's own
floor plan (scenelabel.maps.exports.floor_plan).
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scenelabel import FREE, UNKNOWN, OccupancyMap
from scenelabel.data.synthetic import TOY_BOXES, TOY_CLASSES
from scenelabel.maps.exports import floor_plan

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
TOY_NAMES = {c.id: c.name for c in TOY_CLASSES}


def run_example(name, *args):
    return subprocess.run(
        [sys.executable, str(EXAMPLES / name), *map(str, args)], check=False, capture_output=True, text=True, timeout=300
    )


def box(class_id):
    return next(b for b in TOY_BOXES if b.class_id == class_id)


def waypoints_from(stdout):
    """The "x y" lines that plan_path prints after its "path:" line -> [n, 2]."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("path:"))
    rows = [line.split() for line in lines[start + 1 :] if not line.startswith("wrote")]
    return np.array(rows, dtype=float)


def min_clearance_from(stdout):
    """The path's smallest clearance that plan_path prints on its "path:" line (None: "unknown")."""
    value = stdout.split("min clearance ")[1].split()[0]
    return None if value == "unknown" else float(value)


def test_plan_path_uses_zarr_and_numpy_only():
    tree = ast.parse((EXAMPLES / "plan_path.py").read_text())
    modules = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    modules |= {node.module.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    assert "scenelabel" not in modules
    assert modules <= {"__future__", "argparse", "heapq", "math", "sys", "numpy", "zarr", "PIL"}


def test_plan_path_reports_no_path_and_blocked_ends(tmp_path):
    """A hand-made map (no training): a wall across y = 0.5 splits the room in two."""
    label = np.full((10, 10, 3), FREE, np.int16)
    label[:, :, 0] = 1  # floor
    label[:, 5, :] = 3  # wall
    label[9, 0, :] = UNKNOWN
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    path = OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], {1: "floor", 3: "wall"}, 0.1).to_zarr(tmp_path / "m.zarr")

    proc = run_example("plan_path.py", path, "--start", 0.2, 0.2, "--goal", 0.2, 0.8)
    assert proc.returncode == 1 and "no path" in proc.stderr
    proc = run_example("plan_path.py", path, "--start", 0.2, 0.2, "--goal", 0.8, 0.2)
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(waypoints_from(proc.stdout)[[0, -1]], [[0.2, 0.2], [0.8, 0.2]], atol=1e-9)
    assert min_clearance_from(proc.stdout) > 0  # the band's one layer is half a voxel below the map's top
    for start, reason in (((0.2, 0.5), "occupied by wall"), ((0.9, 0.0), "unknown"), ((5.0, 0.0), "outside")):
        proc = run_example("plan_path.py", path, "--start", *start, "--goal", 0.8, 0.2)
        assert proc.returncode == 2 and reason in proc.stderr, proc.stderr
    proc = run_example("plan_path.py", path, "--start", 0.2, 0.3, "--goal", 0.8, 0.2, "--robot-radius", 0.2)
    assert proc.returncode == 2 and "robot radius" in proc.stderr


def pillar_room(tmp_path, esdf=True):
    """A hand-made 2 x 1.2 x 0.5 map (voxels of 0.05, no training): a floor, and a pillar
    (y 0.375 to 0.775) across the straight line from (0.2, 0.6) to (1.8, 0.6), leaving a
    corridor of 0.4 on either side."""
    label = np.full((40, 24, 10), FREE, np.int16)
    label[:, :, 0] = 1  # floor
    label[18:22, 8:16, :] = 3  # pillar
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    m = OccupancyMap(label, occupancy, 0.05, [0.0, 0.0, 0.0], {1: "floor", 3: "pillar"}, 0.05, units="metre")
    return m, m.to_zarr(tmp_path / "pillar.zarr", esdf=esdf)


def test_plan_path_keeps_its_clearance_from_the_stored_esdf(tmp_path):
    m, path = pillar_room(tmp_path)
    ends = ("--start", 0.2, 0.6, "--goal", 1.8, 0.6)
    runs = {}
    options = {"shortest": ("--clearance-weight", 0), "default": (), "margin": ("--min-clearance", 0.15)}
    for name, extra in options.items():
        proc = run_example("plan_path.py", path, *ends, *extra)
        assert proc.returncode == 0, proc.stderr
        height = float(proc.stdout.split("esdf at z = ")[1].split(",")[0])
        assert height == pytest.approx(0.275)  # mid band: one voxel above the floor's top to the map's top
        points = waypoints_from(proc.stdout)
        # what the example read with zarr alone is the library's distance at the waypoints
        clearance = m.distance(np.column_stack([points, np.full(len(points), height)]))
        assert min_clearance_from(proc.stdout) == pytest.approx(clearance.min(), abs=1e-4)
        runs[name] = clearance.min(), float(proc.stdout.split("length ")[1].split()[0])
    assert 0 < runs["shortest"][0] < runs["default"][0] <= runs["margin"][0]  # the cost term keeps away
    assert runs["margin"][0] >= 0.15 - 1e-9 and runs["shortest"][1] <= runs["default"][1]
    proc = run_example("plan_path.py", path, *ends, "--min-clearance", 0.21)  # the corridors are 0.4 wide
    assert proc.returncode == 2 and "min-clearance" in proc.stderr, proc.stderr
    proc = run_example("plan_path.py", path, "--start", 0.2, 0.05, "--goal", 1.8, 0.6, "--min-clearance", 0.1)
    assert proc.returncode == 2 and "clearance 0.075" in proc.stderr, proc.stderr  # 1.5 voxels from the map's side

    _, old = pillar_room(tmp_path, esdf=False)  # as a map written before the ESDF was stored
    proc = run_example("plan_path.py", old, *ends)
    assert proc.returncode == 0 and "no esdf array" in proc.stdout and min_clearance_from(proc.stdout) is None
    proc = run_example("plan_path.py", old, *ends, "--min-clearance", 0.1)
    assert proc.returncode == 2 and "esdf" in proc.stderr


@pytest.mark.slow
def test_plan_path_on_the_toy_map_goes_around_the_boxes(toy_build, tmp_path):
    map_path = toy_build.out_dir / "map.zarr"
    start, goal = np.array([-1.2, -1.2]), np.array([1.2, 1.2])  # the straight line crosses both boxes
    png = tmp_path / "plan.png"
    proc = run_example("plan_path.py", map_path, "--start", *start, "--goal", *goal, "--png", png)
    assert proc.returncode == 0, proc.stderr
    points = waypoints_from(proc.stdout)

    plan = floor_plan(OccupancyMap.from_zarr(map_path))  # the library's floor plan, same rules
    cells, inside = plan.index_from_world(points)
    assert inside.all()
    assert np.all(plan.label[tuple(cells.T)] == FREE)  # never occupied, never unknown
    assert np.abs(np.diff(cells, axis=0)).max() == 1  # 8-connected steps
    start_cell, goal_cell = plan.index_from_world(np.stack([start, goal]))[0]
    assert cells[0].tolist() == start_cell.tolist() and cells[-1].tolist() == goal_cell.tolist()
    for class_id in (3, 7):  # no waypoint inside a box's footprint
        b = box(class_id)
        within = np.all((points >= np.array(b.lo[:2])) & (points <= np.array(b.hi[:2])), axis=1)
        assert not within.any(), TOY_NAMES[class_id]
    length = float(proc.stdout.split("length ")[1].split()[0])
    assert np.linalg.norm(goal - start) < length < 2 * np.linalg.norm(goal - start)
    # the build's map stores its ESDF: the path keeps a clearance, the library's distance there
    height = float(proc.stdout.split("esdf at z = ")[1].split(",")[0])
    clearance = OccupancyMap.from_zarr(map_path).distance(np.column_stack([points, np.full(len(points), height)]))
    assert 0 < min_clearance_from(proc.stdout) == pytest.approx(clearance.min(), abs=1e-3)
    image = Image.open(png)
    assert image.size[0] >= plan.label.shape[0] and image.mode == "RGB"


def interior_pixel(labels, class_id, margin=3):
    """(u, v) of a pixel whose (2 margin + 1)² neighbourhood is all ``class_id``."""
    h, w = labels.shape
    for v in range(margin, h - margin):
        for u in range(margin, w - margin):
            if np.all(labels[v - margin : v + margin + 1, u - margin : u + margin + 1] == class_id):
                return u, v
    raise AssertionError(f"no interior pixel of class {class_id}")


@pytest.mark.slow
@pytest.mark.parametrize("class_id", [3, 1])
def test_ar_tap_reports_class_and_depth_of_a_training_pixel(toy_build, class_id):
    scene = toy_build.out_dir.parent / "scene"
    view = 1  # a training view (every 8th view from 0 is held out)
    frame = json.loads((scene / "transforms.json").read_text())["frames"][view]
    labels = np.asarray(Image.open(scene / frame["label_path"]))
    depth = np.load(scene / frame["depth_path"])
    u, v = interior_pixel(labels, class_id)

    proc = run_example("ar_tap.py", toy_build.out_dir, "--scene", scene, "--view", view, "--u", u, "--v", v)
    assert proc.returncode == 0, proc.stderr
    hit = proc.stdout.splitlines()[-1]
    assert hit.startswith(f"hit: {TOY_NAMES[class_id]} (id {class_id}) at depth "), proc.stdout
    reported = float(hit.split("at depth ")[1].split(",")[0])
    assert abs(reported - depth[v, u]) < 0.03 * depth[v, u]  # true depth of the pixel centre


@pytest.mark.slow
@pytest.mark.parametrize("baked", [[], ["--baked"]], ids=["field", "baked"])
def test_query_points_names_the_box_inside_each_box(toy_build, baked):
    points = []
    for class_id in (3, 7):  # just below the top face, where the surface is
        b = box(class_id)
        points.append(f"{(b.lo[0] + b.hi[0]) / 2},{(b.lo[1] + b.hi[1]) / 2},{b.hi[2] - 0.01}")
    points.append("50,50,50")  # outside the modelled bounds
    proc = run_example("query_points.py", toy_build.out_dir, *points, "--json", *baked)
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert [r["name"] for r in rows] == ["box_red", "box_blue", "UNKNOWN"]
    for row, class_id in zip(rows[:2], (3, 7)):
        assert row["label"] == class_id and row["occupancy"] >= 0.5
        assert len(row["top3"]) == 3 and row["top3"][0]["id"] == class_id
        assert sum(t["prob"] for t in row["top3"]) <= 1 + 1e-9
    assert rows[2]["top3"] == [] and rows[2]["occupancy"] == 0.0

    text = run_example("query_points.py", toy_build.out_dir, points[0], *baked)
    assert text.returncode == 0 and "box_red, occupancy" in text.stdout
