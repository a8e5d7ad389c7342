"""Rerun recordings (scenelabel.viz.rerun_log, `scenelabel export ... OUT.rrd`), read back with
rerun's own reader (rerun.chunk.RrdReader)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from scenelabel import FREE, UNKNOWN, OccupancyMap, build, log_rerun, preset, write_toy_scene
from scenelabel.cli import export_format
from scenelabel.data.io.depth import z_depth_from_ray_depth
from scenelabel.errors import InputError
from scenelabel.maps.exports import class_palette
from scenelabel.viz.rerun_log import RERUN_FREE, RERUN_IGNORED, RERUN_UNKNOWN, rerun_class_ids

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

CLASSES = {1: "floor", 3: "box", 5: "chair"}
HISTORY = [{"step": 10, "loss": 1.0, "psnr": 12.0}, {"step": 20, "loss": 0.5, "psnr": 15.0, "note": "text"}]


def read_rrd(path) -> dict[str, dict[str, list]]:
    """entity path -> component column -> its rows, over every chunk of the recording."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if name.startswith("rerun.") or name in ("log_time", "log_tick"):
                continue
            entity.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def _box_map() -> OccupancyMap:
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:4] = 3
    label[7, :, :] = UNKNOWN
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    return OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], dict(CLASSES), 0.1, class_colors={3: (10, 200, 30)})


def _annotations(record) -> dict[int, tuple[str, int]]:
    ((context,),) = record["/"]["AnnotationContext:context"]  # one row of one AnnotationContext
    infos = [e["class_description"]["info"] for e in context]
    return {info["id"]: (info["label"], info["color"]) for info in infos}


def test_a_map_recording_holds_points_meshes_classes_and_curves(tmp_path):
    occ = _box_map()
    summary = log_rerun(occ, tmp_path / "map.rrd", metrics={"history": HISTORY})
    assert summary.path == tmp_path / "map.rrd" and not (tmp_path / "map.rrd.partial").exists()
    record = read_rrd(summary.path)
    assert set(summary.entity_paths) <= set(record)
    assert {"/", "/world", "/world/map", "/world/meshes/1_floor", "/world/meshes/3_box", "/training/loss",
            "/training/psnr"} <= set(record)
    assert "/training/note" not in record  # not a number

    (positions,) = record["/world/map"]["Points3D:positions"]
    (class_ids,) = record["/world/map"]["Points3D:class_ids"]
    n_occupied = int(occ.occupied.sum())
    assert len(positions) == len(class_ids) == summary.n_points == n_occupied == int((occ.label >= 0).sum())
    np.testing.assert_array_equal(np.bincount(class_ids, minlength=4)[[1, 3]], [48 - 6, 12])  # floor minus x = 7
    np.testing.assert_allclose(record["/world/map"]["Points3D:radii"], [[0.05]])
    centres = occ.world_from_index(np.argwhere(occ.label >= 0))
    np.testing.assert_allclose(np.sort(np.asarray(positions), axis=0), np.sort(centres, axis=0), atol=1e-6)

    annotations = _annotations(record)
    palette = class_palette(CLASSES, {3: (10, 200, 30)})
    assert {k: v[0] for k, v in annotations.items()} == {
        1: "floor", 3: "box", 5: "chair", RERUN_FREE: "FREE", RERUN_UNKNOWN: "UNKNOWN", RERUN_IGNORED: "unlabelled"}
    r, g, b = palette[3]
    assert annotations[3][1] == (r << 24) | (g << 16) | (b << 8) | 255  # rerun's 0xRRGGBBAA
    assert record["/world"]["ViewCoordinates:xyz"]

    assert record["/training/loss"]["step"] == [10, 20]
    assert record["/training/loss"]["Scalars:scalars"] == [[1.0], [0.5]]
    assert summary.n_steps == 2 and summary.n_meshes == 2 and summary.n_views == 0


def test_log_into_a_recording_stream_of_ones_own(tmp_path):
    rec = rr.RecordingStream("mine")
    rec.save(tmp_path / "mine.rrd")
    summary = log_rerun(_box_map(), rec, meshes=False)
    rec.log("extra", rr.Points3D([[0, 0, 0]]))
    rec.disconnect()
    record = read_rrd(tmp_path / "mine.rrd")
    assert summary.path is None and "/world/map" in record and "/extra" in record
    assert not any(p.startswith("/world/meshes") for p in record)


def test_class_ids_and_depth_for_rerun():
    label = np.array([[0, 7, FREE], [UNKNOWN, 255, 3]])
    np.testing.assert_array_equal(rerun_class_ids(label, 255), [[0, 7, RERUN_FREE], [RERUN_UNKNOWN, RERUN_IGNORED, 3]])
    assert rerun_class_ids(label).dtype == np.uint16
    with pytest.raises(InputError, match="rerun class id"):
        rerun_class_ids(np.array([70000]))
    depth = np.full((2, 2), 2.0)  # along the rays; the pixel centres sit at (±1, ±1) / f from the axis
    np.testing.assert_allclose(z_depth_from_ray_depth(depth, 2.0, 2.0, 1.0, 1.0), np.full((2, 2), 2.0 / np.sqrt(0.25**2 * 2 + 1)))


def test_sources_that_are_no_build_or_map(tmp_path):
    with pytest.raises(InputError, match="neither a build folder"):
        log_rerun(tmp_path, tmp_path / "x.rrd")
    with pytest.raises(InputError, match="parent folder"):
        log_rerun(_box_map(), tmp_path / "missing" / "x.rrd")
    assert export_format(None, tmp_path / "x.rrd") == "rrd"


@pytest.fixture(scope="module")
def tiny_build(tmp_path_factory):
    """A 20-step build of a small toy scene (7 training views, 1 held out) with its map: (scene, build folder)."""
    root = tmp_path_factory.mktemp("rerun")
    scene = write_toy_scene(root / "scene", n_train=7, n_test=1, width=32, height=24)
    config = preset("quick", {"sampling": {"n_steps": 48, "grid_resolution": 16}})
    config.train.steps, config.train.batch_rays, config.train.log_every = 20, 128, 5
    config.output.write_renders = False
    return scene, build(scene, root / "out", config, progress=False).out_dir


@pytest.mark.slow
def test_a_build_recording_holds_every_view_and_the_held_out_renders(tiny_build, tmp_path):
    scene, out = tiny_build
    summary = log_rerun(out, tmp_path / "build.rrd", scene=scene)
    record = read_rrd(summary.path)
    occ = OccupancyMap.from_zarr(out / "map.zarr")
    assert len(record["/world/map"]["Points3D:positions"][0]) == summary.n_points == int((occ.label >= 0).sum())
    assert summary.n_views == 8 and summary.n_renders == 1 and summary.n_steps == 4
    held = "/world/views/held_out/000"
    for suffix in ("", "/image", "/image/photo", "/image/mask", "/image/depth", "/image/render/rgb", "/image/render/labels",
                   "/image/render/depth"):
        assert held + suffix in record, suffix
    assert {f"/world/views/train/{i:03d}/image/photo" for i in range(1, 8)} <= set(record)
    pinhole = record[held + "/image"]
    assert pinhole["Pinhole:resolution"] == [[[32.0, 24.0]]] and pinhole["Pinhole:camera_xyz"]
    from scenelabel.data.io import load_scene

    loaded = load_scene(scene)
    cameras = loaded.cameras
    np.testing.assert_allclose(record[held]["Transform3D:translation"][0][0], cameras.c2w[0, :3, 3], atol=1e-5)
    np.testing.assert_allclose(np.asarray(record[held]["Transform3D:mat3x3"][0][0]).reshape(3, 3, order="F"),
                               cameras.c2w[0, :3, :3], atol=1e-5)
    assert "/training/loss" in record and "/metrics" in record and "/world/bounds" in record
    assert {k: v[0] for k, v in _annotations(record).items() if k < RERUN_IGNORED} == loaded.classes

    # no scene: the training cameras from the checkpoint, no photos, no renders
    bare = log_rerun(out, tmp_path / "bare.rrd", meshes=False)
    assert bare.n_views == 7 and bare.n_renders == 0
    assert not any(p.endswith("/photo") for p in bare.entity_paths)


@pytest.mark.slow
def test_export_rrd_from_the_command_line(tiny_build, tmp_path):
    scene, out = tiny_build
    run = [sys.executable, "-m", "scenelabel", "export"]
    proc = subprocess.run([*run, str(out), str(tmp_path / "b.rrd"), "--scene", str(scene)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "using the build's own map" in proc.stdout and "8 views (1 rendered)" in proc.stdout
    assert "/world/views/held_out/000/image/render/depth" in read_rrd(tmp_path / "b.rrd")
    proc = subprocess.run([*run, str(out / "map.zarr"), str(tmp_path / "m.rrd")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "/world/map" in read_rrd(tmp_path / "m.rrd")
    proc = subprocess.run([*run, str(out / "map.zarr"), str(tmp_path / "v.rrd"), "--voxel-size", "0.2"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "--voxel-size applies to a build folder" in proc.stderr


def test_views_of_a_distorted_camera_are_resampled_to_the_pinhole_logged(tmp_path):
    """rerun's Pinhole has no distortion: photo, mask and depth are logged as its ideal pinhole sees them."""
    import dataclasses

    from scenelabel.data.io import load_scene
    from scenelabel.geometry.lens import ideal_pinhole_image

    scene = load_scene(write_toy_scene(tmp_path / "scene", n_train=2, n_test=1, width=32, height=24))
    distortion = np.tile([0.25, -0.05, 0.01, 0.0], (len(scene), 1))
    scene = dataclasses.replace(scene, cameras=dataclasses.replace(scene.cameras, distortion=distortion))
    summary = log_rerun(_box_map(), tmp_path / "d.rrd", scene=scene, meshes=False)
    record = read_rrd(summary.path)
    base = f"/world/views/train/{scene.names[0]}/image"
    cam = scene.cameras
    args = (cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0], distortion[0], "pinhole")
    photo = np.frombuffer(bytes(record[base + "/photo"]["Image:buffer"][0][0]), np.uint8).reshape(24, 32, 3)
    expected = ideal_pinhole_image((np.clip(scene.images[0], 0, 1) * 255 + 0.5).astype(np.uint8), *args)
    np.testing.assert_array_equal(photo, expected)
    assert (photo[0, 0] == 0).all() and not np.array_equal(photo, expected * 0)  # pincushion: corners not imaged
    mask = np.frombuffer(bytes(record[base + "/mask"]["SegmentationImage:buffer"][0][0]), np.uint16).reshape(24, 32)
    assert mask[0, 0] == RERUN_IGNORED
    np.testing.assert_array_equal(mask, ideal_pinhole_image(rerun_class_ids(scene.labels[0], scene.ignore_index), *args, nearest=True,
                                                            fill=RERUN_IGNORED))
    depth = np.frombuffer(bytes(record[base + "/depth"]["DepthImage:buffer"][0][0]), np.float32).reshape(24, 32)
    true_z = ideal_pinhole_image(z_depth_from_ray_depth(scene.depths[0], *args), *args, nearest=True)
    np.testing.assert_allclose(depth, true_z, rtol=1e-6)
    assert depth[12, 16] > 0 and depth[0, 0] == 0
