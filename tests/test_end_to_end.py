"""The toy two-box scene built end to end: metrics, queries, map, zarr, CLI."""

import json

import numpy as np
import pytest
import torch
import zarr
from conftest import TOY_BUILD_STEPS

from scenelabel import FREE, UNKNOWN, OccupancyMap, SemanticField, build, preset, write_toy_scene
from scenelabel.data.synthetic import TOY_BOXES
from scenelabel.maps import validate_attributes

pytestmark = pytest.mark.slow

# toy_build (tests/conftest.py): the toy scene built once per session with the quick preset.


def box_by_class(class_id):
    return next(b for b in TOY_BOXES if b.class_id == class_id)


def test_held_out_targets(toy_build):
    m = toy_build.metrics
    assert m["n_test_views"] == 4
    assert m["miou"] >= 0.95, m["per_class_iou"]
    assert m["psnr"] >= 28.0
    assert np.isfinite(m["ssim"]) and m["ssim"] > 0.8
    assert m["depth_error"] < 0.05  # mean relative depth error on hit pixels


def test_outputs_written(toy_build):
    out = toy_build.out_dir
    for name in ("checkpoint.pt", "config.json", "metrics.json", "map.zarr"):
        assert (out / name).exists(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert {"psnr", "ssim", "miou", "depth_error", "per_view", "per_class_iou"} <= set(metrics)
    renders = sorted((out / "renders").glob("*.png"))
    assert len(renders) == 4
    config = json.loads((out / "config.json").read_text())
    assert config["train"]["steps"] == TOY_BUILD_STEPS


def test_only_present_classes_get_channels(toy_build):
    field = SemanticField.load(toy_build.out_dir)
    # classes.json lists chair (5), which never appears: no channel for it
    assert field.class_ids.tolist() == [1, 3, 7]


def test_query_points_inside_boxes_and_above(toy_build):
    field = SemanticField.load(toy_build.out_dir)
    for class_id in (3, 7):
        box = box_by_class(class_id)
        lo, hi = np.array(box.lo), np.array(box.hi)
        centre = 0.5 * (lo + hi)
        # points just inside the top face, where the surface is
        top = np.array([[centre[0] + dx, centre[1] + dy, hi[2] - 0.01] for dx in (-0.1, 0, 0.1) for dy in (-0.1, 0, 0.1)])
        q = field.query_points(top)
        assert np.mean(q.label == class_id) >= 0.8, q.label
        np.testing.assert_allclose(q.probs.sum(-1), 1.0, atol=1e-6)
        above = np.array([centre[0], centre[1], hi[2] + 0.1])  # still inside the modelled bounds
        assert field.query_points(above[None]).label[0] == FREE
    far_away = field.query_points(np.array([[50.0, 50.0, 50.0]]))
    assert far_away.label[0] == UNKNOWN and far_away.density[0] == 0.0


def test_outside_the_bounds_what_a_training_camera_saw_through_is_free(toy_build):
    """query_points outside the modelled bounds: FREE halfway between a training camera and where
    its optical axis enters the bounds; everywhere outside, FREE exactly where seen_before_bounds
    says (the rest UNKNOWN)."""
    from scenelabel.geometry.boxes import ray_box_distances
    from scenelabel.maps.visibility import seen_before_bounds

    field = SemanticField.load(toy_build.out_dir)
    cams = field.training_cameras()
    centres, axes = cams.c2w[:, :3, 3], cams.c2w[:, :3, 2]
    t_enter, t_exit = ray_box_distances(centres, axes, *field.aabb)
    looking_in = (t_exit >= t_enter) & (t_enter > 0.5)
    assert looking_in.sum() >= 3  # the toy's cameras stand outside the bounds
    halfway = centres[looking_in] + 0.5 * t_enter[looking_in, None] * axes[looking_in]
    assert np.all(field.query_points(halfway).label == FREE)
    pts = np.random.default_rng(6).uniform(field.aabb[0] - 2.0, field.aabb[1] + 2.0, (20000, 3))
    outside = ~field._inside(pts)
    seen = seen_before_bounds(pts[outside], cams, field.aabb)
    np.testing.assert_array_equal(field.query_points(pts[outside]).label, np.where(seen, FREE, UNKNOWN))
    assert 0 < seen.sum() < len(seen)


def test_query_rays_depth_and_label(toy_build):
    field = SemanticField.load(toy_build.out_dir)
    box = box_by_class(3)
    centre = 0.5 * (np.array(box.lo) + np.array(box.hi))
    origin = np.array([[centre[0], centre[1], 2.0]])
    r = field.query_rays(origin, np.array([[0.0, 0.0, -5.0]]))  # non-unit direction on purpose
    assert r.label[0] == 3
    assert abs(r.depth[0] - (2.0 - box.hi[2])) < 0.05
    miss = field.query_rays(np.array([[10.0, 10.0, 10.0]]), np.array([[1.0, 0, 0]]))
    assert miss.label[0] == UNKNOWN


def test_the_final_grid_skips_space_without_changing_what_rays_hit(toy_build):
    """The density grid rebuilt from the final field (DensityGrid.rebuild) against evaluating
    the field at every sample: the same labels and depths, with most of the box skipped."""
    field = SemanticField.load(toy_build.out_dir)
    rng = np.random.default_rng(0)
    origins = rng.uniform(field.aabb[0], field.aabb[1], (4000, 3))
    directions = rng.normal(size=(4000, 3))
    with_grid = field.query_rays(origins, directions, with_rgb=False)
    occupied = field.occupancy.occupied_fraction
    field.occupancy.bits = torch.ones_like(field.occupancy.bits)
    everywhere = field.query_rays(origins, directions, with_rgb=False)
    hit = everywhere.opacity >= 0.5  # the depth of a ray through faint haze only means little
    assert occupied < 0.5
    assert (with_grid.label == everywhere.label).mean() >= 0.99
    assert hit.mean() > 0.3 and np.quantile(np.abs(with_grid.depth[hit] - everywhere.depth[hit]), 0.99) < 0.01


def test_occupancy_map_zarr_round_trip_and_schema(toy_build, tmp_path):
    field = SemanticField.load(toy_build.out_dir)
    occ = field.occupancy_map(voxel_size=0.05)
    path = occ.to_zarr(tmp_path / "toy.zarr")
    again = OccupancyMap.from_zarr(path)
    assert again == occ
    group = zarr.open_group(str(path), mode="r")
    validate_attributes(dict(group.attrs))
    # planners read it with zarr alone: the red box's centre voxel carries its id
    box = box_by_class(3)
    attrs = group.attrs
    point = np.array([0.5 * (box.lo[0] + box.hi[0]), 0.5 * (box.lo[1] + box.hi[1]), box.hi[2] - 0.02])
    i, j, k = np.floor((point - np.array(attrs["origin"])) / attrs["voxel_size"] + 0.5).astype(int)
    assert group["label"][i, j, k] == 3
    labels = set(np.unique(group["label"][:]).tolist())
    assert {FREE, 1, 3, 7} <= labels


def test_build_folder_map_matches_default_voxel(toy_build):
    occ = OccupancyMap.from_zarr(toy_build.out_dir / "map.zarr")
    assert occ.voxel_size == pytest.approx(toy_build.metrics["map"]["voxel_size"])
    assert occ.occupied.any()


def test_deterministic_for_a_seed(tmp_path):
    scene = write_toy_scene(tmp_path / "scene", n_train=14, n_test=2, width=32, height=24)
    config = preset("quick", {"train": {"steps": 30}, "output": {"write_map": False, "write_renders": False}})
    a = build(scene, tmp_path / "a", config, progress=False)
    b = build(scene, tmp_path / "b", config, progress=False)
    assert a.metrics["history"][-1]["loss"] == b.metrics["history"][-1]["loss"]
    pts = np.random.default_rng(0).uniform(-1, 1, (100, 3))
    np.testing.assert_array_equal(a.field.query_points(pts).density, b.field.query_points(pts).density)


def test_loaded_grid_keeps_the_training_threshold(toy_build):
    """The grid a loaded field rebuilds from its own density is the one training left (same
    marching step, so the same opacity threshold per cell)."""
    field = SemanticField.load(toy_build.out_dir)
    stored = field.occupancy.bits.clone()
    field.occupancy.rebuild(field.model.density)
    assert torch.equal(field.occupancy.bits, stored)


def test_one_ray_contract_for_the_field_the_baked_field_and_the_map(toy_build):
    """The same rays through SemanticField.query_rays, BakedField.query_rays and
    OccupancyMap.cast_rays (docs/conventions.md, "Rays"): a hit has its class and a finite
    depth, a ray that crosses the bounds without one is FREE at depth inf, a ray that never
    enters them is UNKNOWN at depth inf."""
    from scenelabel import BakedField

    field = SemanticField.load(toy_build.out_dir)
    occ = field.occupancy_map(visibility=False)  # UNKNOWN only outside the bounds, as the field's queries
    top = max(b.hi[2] for b in TOY_BOXES)
    hits = [(0.5 * (np.array(b.lo) + np.array(b.hi)), b.class_id, b.hi[2]) for b in TOY_BOXES]
    origins = [[c[0], c[1], top + 0.05] for c, _, _ in hits] + [[0.0, 0.0, top + 0.05], field.aabb[1] + 1.0]
    directions = [[0.0, 0.0, -1.0]] * len(hits) + [[1.0, 0.3, 0.0], [1.0, 1.0, 1.0]]
    want_label = [cid for _, cid, _ in hits] + [FREE, UNKNOWN]
    want_depth = [top + 0.05 - z for _, _, z in hits]
    answers = {
        "field": field.query_rays(origins, directions, with_rgb=False),
        "baked": BakedField.from_field(field).query_rays(origins, directions),
        "map": occ.cast_rays(origins, directions),
    }
    for name, answer in answers.items():
        assert answer.label.tolist() == want_label, name
        np.testing.assert_allclose(answer.depth[: len(hits)], want_depth, atol=1.5 * occ.voxel_size, err_msg=name)
        assert np.all(answer.depth[len(hits) :] == np.inf), name
