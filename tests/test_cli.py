"""The command line end to end (bad inputs: tests/test_bad_inputs.py)."""

import subprocess
import sys

import numpy as np
import pytest

from scenelabel import FREE, OccupancyMap
from scenelabel.data.synthetic import write_toy_scene
from scenelabel.train.pipeline import NO_DEPTH_HINT


def run_cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], check=False, capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.fixture(scope="module")
def small_build(tmp_path_factory):
    """A 20-step build of a small toy scene: (the build's CompletedProcess, its folder)."""
    root = tmp_path_factory.mktemp("cli")
    scene = write_toy_scene(root / "scene", n_train=7, n_test=1, width=24, height=18)
    out = root / "out"
    return run_cli("build", scene, "--out", out, "--steps", "20", "--preset", "quick", "--quiet"), out


@pytest.fixture()
def box_map(tmp_path):
    """A hand-made map .zarr: a floor layer and one box."""
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:4] = 3
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    occ = OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], {1: "floor", 3: "box", 5: "chair"}, 0.1)
    return occ.to_zarr(tmp_path / "box.zarr")


def test_build_and_export_smoke(small_build, tmp_path):
    proc, out = small_build
    assert proc.returncode == 0, proc.stderr
    assert "held-out" in proc.stdout and "psnr=" in proc.stdout
    proc = run_cli("export", out, tmp_path / "m.zarr", "--zarr-format", "2")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "m.zarr" / ".zgroup").exists()


def test_export_reuses_the_builds_own_map_when_it_fits(small_build, tmp_path):
    """export BUILD reads BUILD/map.zarr instead of evaluating the field again when the voxel size
    matches (or none is asked) and the map is not older than the checkpoint."""
    import os

    from scenelabel.fields.checkpoint import CHECKPOINT_NAME
    from scenelabel.query.build_outputs import CHECKPOINT_FILE
    from scenelabel.query.build_outputs import MAP_NAME as BUILD_MAP

    assert CHECKPOINT_FILE == CHECKPOINT_NAME
    _, out = small_build
    own = OccupancyMap.from_zarr(out / BUILD_MAP)
    proc = run_cli("export", out, tmp_path / "a.zarr")
    assert proc.returncode == 0 and "using the build's own map" in proc.stdout, proc.stdout + proc.stderr
    assert OccupancyMap.from_zarr(tmp_path / "a.zarr") == own
    proc = run_cli("export", out, tmp_path / "b.ply", "--voxel-size", f"{own.voxel_size:.12g}")
    assert proc.returncode == 0 and "using the build's own map" in proc.stdout
    proc = run_cli("export", out, tmp_path / "c.ply", "--voxel-size", f"{2 * own.voxel_size:g}")  # another size
    assert proc.returncode == 0 and "using the build's own map" not in proc.stdout
    checkpoint = out / "checkpoint.pt"
    stat = checkpoint.stat()
    try:  # a checkpoint newer than the map (training resumed): the field is evaluated again
        os.utime(checkpoint, (stat.st_atime, (out / BUILD_MAP).stat().st_mtime + 10))
        proc = run_cli("export", out, tmp_path / "d.ply")
        assert proc.returncode == 0 and "using the build's own map" not in proc.stdout
    finally:
        os.utime(checkpoint, (stat.st_atime, stat.st_mtime))


def test_export_every_format_from_a_build(small_build, tmp_path):
    _, out = small_build
    for fmt, target, files in (
        ("zarr", "m.zarr", ["m.zarr/zarr.json"]),
        ("ply", "points.ply", ["points.ply"]),
        ("mesh", "meshes", ["meshes"]),
        ("nav2", "plan", ["plan.pgm", "plan.yaml", "plan_labels.png"]),
    ):
        proc = run_cli("export", out, tmp_path / target, "--format", fmt, "--voxel-size", "0.2")
        assert proc.returncode == 0, (fmt, proc.stderr)
        assert proc.stdout.startswith("wrote"), proc.stdout
        for name in files:
            assert (tmp_path / name).exists(), (fmt, name)


def test_export_every_format_from_a_map(box_map, tmp_path):
    proc = run_cli("export", box_map, tmp_path / "points.ply", "--format", "ply")
    assert proc.returncode == 0, proc.stderr
    assert b"element vertex 60" in (tmp_path / "points.ply").read_bytes()  # 48 floor + 12 box voxels
    proc = run_cli("export", box_map, tmp_path / "meshes", "--format", "mesh")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "meshes").iterdir()) == ["class_1_floor.ply", "class_3_box.ply"]
    proc = run_cli("export", box_map, tmp_path / "nav" / "plan", "--format", "nav2", "--robot-height", "0.3")
    assert proc.returncode == 2 and "does not exist" in proc.stderr  # the folder nav/ is missing
    proc = run_cli("export", box_map, tmp_path / "plan", "--format", "nav2", "--robot-height", "0.3")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "plan.pgm").read_bytes().startswith(b"P5\n8 6\n255\n")
    proc = run_cli("export", box_map, tmp_path / "again.zarr")  # the format from the name
    assert proc.returncode == 0 and (tmp_path / "again.zarr" / "zarr.json").exists()
    proc = run_cli("export", box_map, tmp_path / "again.ply")
    assert proc.returncode == 0 and (tmp_path / "again.ply").read_bytes().startswith(b"ply\n")
    proc = run_cli("export", box_map, tmp_path / "map.glb")  # class meshes as one GLB, the format from the name
    assert proc.returncode == 0, proc.stderr
    assert "triangles per class: floor " in proc.stdout and ", box " in proc.stdout
    assert (tmp_path / "map.glb").read_bytes().startswith(b"glTF")


def test_export_user_errors_exit_2(box_map, tmp_path):
    proc = run_cli("export", box_map, tmp_path / "x", "--format", "obj")
    assert proc.returncode == 2 and "invalid choice: 'obj'" in proc.stderr
    proc = run_cli("export", tmp_path / "nothing", tmp_path / "x.zarr")
    assert proc.returncode == 2 and "neither a build folder" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    proc = run_cli("export", box_map, tmp_path / "x.zarr", "--voxel-size", "0.2")
    assert proc.returncode == 2 and "--voxel-size applies to a build folder" in proc.stderr
    proc = run_cli("export", box_map, tmp_path / "points.txt", "--format", "ply")
    assert proc.returncode == 2 and ".ply" in proc.stderr
    proc = run_cli("export", box_map, tmp_path / "out.ply", "--format", "zarr")  # a name that says another format
    assert proc.returncode == 2 and "--format zarr, but the name ends in .ply" in proc.stderr
    proc = run_cli("export", box_map, tmp_path / "plan")  # a name that says no format
    assert proc.returncode == 2 and "cannot tell the format" in proc.stderr and not (tmp_path / "plan").exists()
    proc = run_cli("export", box_map, tmp_path / "plan", "--format", "nav2", "--z-min", "0.3", "--z-max", "0.1")
    assert proc.returncode == 2 and "z_min < z_max" in proc.stderr


SEGMENTER_MODULE = '''
import numpy as np


class Halves:
    """Left half of every photo is class 0, right half class 5."""

    classes = {0: "left", 5: "right"}
    ignore_index = None

    def __call__(self, image):
        ids = np.zeros(image.shape[:2], np.int64)
        ids[:, image.shape[1] // 2 :] = 5
        return ids


segmenter = Halves()
'''


def test_build_with_segmenter_and_scale_records_units_in_every_export(tmp_path):
    """A scene without labels: `build --segmenter` writes labels/ first; `--scale` makes the exports metric."""
    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)
    for f in (scene / "labels").iterdir():
        f.unlink()
    (scene / "labels").rmdir()
    (scene / "classes.json").unlink()
    module = tmp_path / "my_segmenter.py"
    module.write_text(SEGMENTER_MODULE)
    out = tmp_path / "out"
    proc = run_cli(
        "build", scene, "--out", out, "--steps", "20", "--preset", "quick", "--quiet",
        "--segmenter", f"python:{module}:segmenter", "--scale", "2",
    )
    assert proc.returncode == 0, proc.stderr
    assert "wrote 8 masks" in proc.stdout and "left 50.0%, right 50.0%" in proc.stdout
    assert len(list((scene / "labels").iterdir())) == 8
    occ = OccupancyMap.from_zarr(out / "map.zarr")
    assert occ.units == "metre" and "x 2 (data.scale)" in occ.scale_source
    assert set(occ.classes) == {0, 5}
    for fmt, path in (("ply", tmp_path / "points.ply"), ("nav2", tmp_path / "plan")):
        proc = run_cli("export", out, path, "--format", fmt)
        assert proc.returncode == 0, proc.stderr
    header = (tmp_path / "points.ply").read_bytes().split(b"end_header")[0].decode()
    assert "comment frame toy_world; units metre; scale input poses x 2 (data.scale)" in header
    assert "# units: metre (scale: input poses x 2 (data.scale))" in (tmp_path / "plan.yaml").read_text()


def test_segment_refuses_to_overwrite_and_sfm_stops_on_unrelated_photos(tmp_path):
    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)
    module = tmp_path / "my_segmenter.py"
    module.write_text(SEGMENTER_MODULE)
    proc = run_cli("segment", scene, "--model", f"python:{module}:segmenter", "--quiet")
    assert proc.returncode == 2 and "scenelabel: error:" in proc.stderr and "labels" in proc.stderr
    photos = tmp_path / "photos"
    (photos / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    from PIL import Image

    for i in range(3):
        Image.fromarray(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)).save(photos / "images" / f"{i}.png")
    proc = run_cli("sfm", photos)
    assert proc.returncode == 2, proc.stderr
    assert "registered only 0 of 3 images" in proc.stderr and "matcher='sequential'" in proc.stderr


@pytest.mark.parametrize(
    "flags, steps, budget",
    [
        ([], "auto", "auto"),  # the default build: the steps and budget "auto" chooses by the capture's depth
        (["--steps", "5000"], 5000, None),  # the steps asked for, not the preset's budget
        (["--time-budget", "60"], "auto", 60.0),
        (["--steps", "5000", "--time-budget", "600"], 5000, 600.0),
    ],
)
def test_steps_and_time_budget_flags_override_the_default_budget(flags, steps, budget):
    from scenelabel import preset
    from scenelabel.cli import _overrides, make_parser

    args = make_parser().parse_args(["build", "room", *flags])
    config = preset(args.preset, _overrides(args))
    assert (config.train.steps, config.train.time_budget) == (steps, budget)


def test_build_says_its_bounds_and_training_limit_before_training(tmp_path):
    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)
    proc = run_cli("build", scene, "--out", tmp_path / "out", "--preset", "quick", "--time-budget", "60", "--steps", "5")
    assert proc.returncode == 0, proc.stderr
    plan = next(line for line in proc.stderr.splitlines() if line.startswith("bounds "))
    assert "(explicit aabb)" in plan and "training (quick): at most 5 steps or 60 s, whichever comes first" in plan
    assert NO_DEPTH_HINT in proc.stderr  # photos alone: what to expect of the geometry, and what helps


def test_build_with_sensor_depth_does_not_say_surfaces_come_out_soft(tmp_path):
    from scenelabel.data.synthetic import add_phone_depth

    scene = add_phone_depth(write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18), scale=2)
    proc = run_cli("build", scene, "--out", tmp_path / "out", "--preset", "quick", "--steps", "5")
    assert proc.returncode == 0, proc.stderr
    assert any(line.startswith("bounds ") for line in proc.stderr.splitlines())
    assert NO_DEPTH_HINT not in proc.stderr
