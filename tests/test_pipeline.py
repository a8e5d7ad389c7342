"""Build orchestration helpers: view split, default voxel size."""

import json
import shutil
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from scenelabel import SemanticField, build, preset, write_toy_scene
from scenelabel.config import AUTO, DISTORTION_AUTO_WEIGHT, DISTORTION_THIN_MAX
from scenelabel.data.io import load_scene
from scenelabel.data.synthetic import look_at, toy_scene_geometry, write_scene
from scenelabel.errors import InputError
from scenelabel.fields.encodings import cubic_plane_vertices
from scenelabel.geometry.cameras import Cameras, opengl_to_opencv
from scenelabel.geometry.frame import SceneFrame, aabb_from_cameras, frustum_points, near_far_or_fallback
from scenelabel.geometry.warps import BoxWarp, ForwardWarp, choose_warp, warp_from_dict
from scenelabel.render.sampling import cell_steps
from scenelabel.train.choices import resolve_preset
from scenelabel.train.pipeline import default_voxel_size, resume_config, split_views


def test_every_eighth_view_held_out():
    train, test = split_views(20, 8)
    assert test == [0, 8, 16]
    assert sorted(train + test) == list(range(20))


def test_holdout_zero_trains_on_all():
    train, test = split_views(5, 0)
    assert train == list(range(5)) and test == []


def test_too_few_views():
    with pytest.raises(InputError, match="at least 2 views"):
        split_views(1, 8)
    with pytest.raises(InputError, match="no training view"):
        split_views(2, 1)


def test_default_voxel_is_two_pixel_footprints_never_under_two_finest_cells():
    """docs/conventions.md, "Density and occupancy": the slab and the map's voxel are two pixel
    footprints at the median distance from the training cameras to the box's centre, floored at
    two of the field's finest cells (the narrowest density bump it holds)."""
    aabb = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    c2w = opengl_to_opencv(np.stack([look_at(eye, [0.0, 0.0, 0.0]) for eye in ([0.0, -4.0, 0.0], [4.0, 0.0, 0.0])]))
    scene = SimpleNamespace(cameras=Cameras.create(c2w, 100.0, 100.0, 16.0, 12.0, 32, 24))  # a pixel: 4 m / 100
    assert default_voxel_size(scene, [0, 1], aabb, 0.01) == pytest.approx(0.08)  # the images bind
    assert default_voxel_size(scene, [0, 1], aabb, 0.05) == pytest.approx(0.10)  # the field's cell binds


# ------------------------------------------------------------------ builds without labels, warps


def _small_config(steps=40, holdout=4, **sampling):
    config = preset("quick", {"sampling": {"n_steps": 48, "grid_resolution": 16, **sampling}})
    config.train.steps = steps
    config.train.batch_rays = 128
    config.train.holdout = holdout
    config.train.log_every = 10
    config.output.write_map = False
    config.output.write_renders = False
    return config


@pytest.fixture(scope="module")
def small_toy(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("pipeline_toy") / "scene", n_train=7, n_test=1, width=32, height=24)


def _forward_c2ws_opengl(n=5):
    """n OpenGL cameras side by side at y = -3, all looking +y at the toy scene (an LLFF-like rig)."""
    xs = np.linspace(-0.4, 0.4, n)
    return np.stack([look_at([x, -3.0, 1.0 + 0.05 * np.sin(3 * i)], [0.3 * x, 0.0, 0.2]) for i, x in enumerate(xs)])


def _forward_cameras():
    c2w_cv = opengl_to_opencv(_forward_c2ws_opengl())
    return Cameras.create(c2w_cv, 30.0, 30.0, 16.0, 12.0, 32, 24, near=1.5, far=5.0)


def _frame_and_box(cameras, explicit=None):
    aabb, _ = aabb_from_cameras(cameras, explicit)
    frame = SceneFrame.from_aabb(aabb)
    return frame, torch.as_tensor(frame.to_normalised(aabb), dtype=torch.float32)


def test_build_without_labels_is_photometric_only(small_toy, tmp_path):
    scene = tmp_path / "scene"
    shutil.copytree(small_toy, scene)
    shutil.rmtree(scene / "labels")
    (scene / "classes.json").unlink()
    transforms = json.loads((scene / "transforms.json").read_text())
    for frame in transforms["frames"]:
        del frame["label_path"]
    (scene / "transforms.json").write_text(json.dumps(transforms))
    with pytest.warns(UserWarning, match="no labels"):
        result = build(scene, tmp_path / "out", _small_config(steps=30), progress=False)
    assert result.field.classes == {0: "unlabelled"}
    field = SemanticField.load(tmp_path / "out", device="cpu")
    assert field.classes == {0: "unlabelled"} and field.class_ids.tolist() == [0]
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["n_test_views"] == 2 and np.isfinite(metrics["psnr"])
    assert "miou" not in metrics and "per_class_iou" not in metrics
    assert metrics["classes"] == {"0": "unlabelled"}
    assert all(np.isfinite(h["loss"]) for h in metrics["history"])
    q = field.query_points(np.array([[0.0, 0.0, 0.1], [0.4, 0.2, 0.2]]))
    np.testing.assert_allclose(q.probs[np.isin(q.label, [0])].sum(-1), 1.0)
    assert set(q.label.tolist()) <= {0, -1, -2}


def test_build_with_labels_does_not_warn(small_toy, tmp_path):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message="no labels")
        result = build(small_toy, tmp_path / "out", _small_config(steps=20), progress=False)
    assert 0 not in result.field.classes and "miou" in result.metrics


def test_cubic_plane_cells_build_saves_their_finest_cell_and_loads(small_toy, tmp_path):
    """A build with tri-planes of cubic cells: the planes follow the box's sides, the checkpoint's
    finest cell is the box's longest side over that axis's cells, and the saved field loads into
    the same planes (its queries equal the trained field's)."""
    config = _small_config(steps=20)
    config.field.plane_cells = "cubic"
    result = build(small_toy, tmp_path / "out", config, progress=False)
    field = SemanticField.load(tmp_path / "out", device="cpu")
    aabb = np.asarray(field.meta["aabb_world"])
    sides = aabb[1] - aabb[0]
    vertices = cubic_plane_vertices(max(config.field.resolutions), tuple(sides))
    assert field.finest_cell() == pytest.approx(sides.max() / (vertices[int(np.argmax(sides))] - 1), rel=1e-4)
    shapes = [tuple(p.shape[1:]) for p in field.model.encoding.planes][-3:]  # the finest level's xy, xz, yz planes
    assert shapes == [(vertices[1], vertices[0]), (vertices[2], vertices[0]), (vertices[2], vertices[1])]
    points = aabb[0] + np.random.default_rng(0).random((50, 3)) * sides
    np.testing.assert_array_equal(field.query_points(points).label, result.field.query_points(points).label)


def test_choose_warp_on_an_orbit(small_toy):
    scene = load_scene(small_toy)
    frame, aabb_n = _frame_and_box(scene.cameras, scene.aabb)
    box = choose_warp("box", scene.cameras, frame, aabb_n)
    assert isinstance(box, BoxWarp) and torch.equal(box.aabb, aabb_n)
    assert isinstance(choose_warp("auto", scene.cameras, frame, aabb_n), BoxWarp)
    with pytest.raises(InputError, match="not forward-facing"):
        choose_warp("forward", scene.cameras, frame, aabb_n)
    sc = _small_config().sampling
    steps = cell_steps(box, aabb_n, sc.grid_resolution, sc.n_steps)
    assert isinstance(steps, float)
    assert steps == pytest.approx(float(torch.linalg.norm(aabb_n[1] - aabb_n[0])) / _small_config().sampling.n_steps)


def test_choose_warp_on_a_forward_facing_rig():
    cams = _forward_cameras()
    frame, aabb_n = _frame_and_box(cams)
    config = _small_config()
    for kind in ("auto", "forward"):
        warp = choose_warp(kind, cams, frame, aabb_n)
        assert isinstance(warp, ForwardWarp) and warp.spacing == "disparity"
        again = warp_from_dict(json.loads(json.dumps(warp.to_dict())))
        assert isinstance(again, ForwardWarp)
        for key in ("centre", "rotation", "tan_xy", "inv_range"):
            torch.testing.assert_close(getattr(again, key), getattr(warp, key), atol=0, rtol=1e-6)
        # the warp holds every training frustum (normalised frame)
        near, far = near_far_or_fallback(cams)
        pts_n = torch.as_tensor(frame.to_normalised(frustum_points(cams, near, far)), dtype=torch.float32)
        assert bool((warp(pts_n).abs() <= 1.0).all())
        # near / far scaled into the normalised frame
        assert warp.to_dict()["near"] < 1.5 * frame.scale and warp.to_dict()["far"] > 5.0 * frame.scale * 0.99
    assert isinstance(choose_warp("box", cams, frame, aabb_n), BoxWarp)
    # per-slice steps grow with depth and sum to (about) a ray from near to far
    steps = cell_steps(warp, aabb_n, config.sampling.grid_resolution, config.sampling.n_steps)
    r, n_steps = config.sampling.grid_resolution, config.sampling.n_steps
    assert steps.shape == (r,) and torch.all(steps[1:] > steps[:-1]) and torch.all(steps > 0)
    inv_near, inv_far = warp.inv_range.tolist()
    t_mid = 1.0 / (inv_near - ((torch.arange(r) + 0.5) / r) * (inv_near - inv_far))
    torch.testing.assert_close(steps, t_mid**2 * (inv_near - inv_far) / n_steps, rtol=1e-5, atol=0)


@pytest.fixture(scope="module")
def forward_scene(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("forward") / "scene", toy_scene_geometry(), _forward_c2ws_opengl(5), 32, 24)


def test_forward_warp_build_loads_and_answers(forward_scene, tmp_path):
    config = _small_config(steps=30, holdout=4, warp="forward")
    result = build(forward_scene, tmp_path / "out", config, progress=False)
    assert all(np.isfinite(h["loss"]) for h in result.metrics["history"])
    assert np.isfinite(result.metrics["psnr"])
    field = SemanticField.load(tmp_path / "out", device="cpu")
    assert isinstance(field.model.warp, ForwardWarp) and isinstance(field.occupancy.warp, ForwardWarp)
    assert field.meta["warp"]["kind"] == "forward" and field.config.sampling.warp == "forward"
    rng = np.random.default_rng(0)
    lo, hi = field.aabb
    pts = np.concatenate([rng.uniform(lo, hi, (300, 3)), [[0.0, 0.0, 0.1], [0.0, -3.0, 1.0], [50.0, 50.0, 50.0]]])
    q = field.query_points(pts)
    for name in ("density", "occupancy", "probs"):
        assert np.isfinite(getattr(q, name)).all(), name
    assert np.all(q.density >= 0)
    inside = np.all((pts >= lo) & (pts <= hi), -1)
    np.testing.assert_allclose(q.probs[inside].sum(-1), 1.0, atol=1e-9)
    scene = load_scene(forward_scene)
    out = field.render_camera(scene.cameras, 1)
    assert out.rgb.shape == (24, 32, 3)
    for name in ("rgb", "depth", "opacity", "probs"):
        assert np.isfinite(getattr(out, name)).all(), name
    r = field.query_rays(np.array([[0.0, -3.0, 1.0]]), np.array([[0.0, 1.0, -0.25]]))
    assert np.isfinite(r.depth).all() and np.isfinite(r.rgb).all()


# ------------------------------------------------------------------ the preset "auto"


def test_preset_auto_is_voxels_for_forward_facing_cameras_and_fast_otherwise(small_toy):
    given = {"train": {"time_budget": 480.0, "seed": 3}, "output": {"write_map": False}}
    config, why = resolve_preset(preset("auto", given), _forward_cameras())
    assert config == preset("voxels", given) and why == "preset auto: the training cameras are forward-facing"
    config, why = resolve_preset(preset("auto", given), load_scene(small_toy).cameras)  # an orbit
    assert config == preset("fast", given) and why == "preset auto: the training cameras are not forward-facing"
    # the default build keeps its time plan (train.time_budget "auto"), whichever it chooses
    assert resolve_preset(preset(), _forward_cameras())[0] == preset("voxels", {"train": {"time_budget": AUTO}})
    assert resolve_preset(preset(), load_scene(small_toy).cameras)[0] == preset("fast")
    for name in ("fast", "voxels", "quick"):  # a named preset is as given
        assert resolve_preset(preset(name), _forward_cameras()) == (preset(name), None)
        assert resolve_preset(preset(name), _forward_cameras(), room=True) == (preset(name), None)


def test_open_rays_auto_only_where_the_layout_gives_all_the_depth_and_the_cameras_look_around(small_toy):
    """resolve_open_rays: "auto" is LAYOUT_OPEN_RAYS with layout depth and cameras seen from inside,
    0 with a sensor's depth or a forward-facing rig; a number stays; a trainer made without the
    build (scenelabel.config.resolve_by_depth) takes 0."""
    from scenelabel.config import LAYOUT_OPEN_RAYS, resolve_by_depth
    from scenelabel.train.choices import resolve_open_rays

    def chosen(config, cameras, from_layout):
        return resolve_open_rays(config, cameras, from_layout).sampling.grid_open_rays

    orbit = load_scene(small_toy).cameras
    assert preset().sampling.grid_open_rays == AUTO and LAYOUT_OPEN_RAYS > 0
    assert chosen(preset(), orbit, True) == LAYOUT_OPEN_RAYS
    assert chosen(preset(), orbit, False) == 0
    assert chosen(preset(), _forward_cameras(), True) == 0
    assert chosen(preset("fast", {"sampling": {"grid_open_rays": 4}}), _forward_cameras(), False) == 4
    assert resolve_by_depth(preset(), False).sampling.grid_open_rays == 0


def test_a_room_seen_from_inside_trains_with_open_rays_and_a_forward_rig_without(tmp_path):
    """With the layout's depth (what a build adds to a room's masks), studio-3x3 seen from inside
    trains with LAYOUT_OPEN_RAYS open rays and its pool grouped by label; office-5x4-forward's
    cameras all look one way, so none."""
    import dataclasses

    from scenelabel.config import LAYOUT_OPEN_RAYS
    from scenelabel.data.layout_depth import with_layout_depth
    from scenelabel.data.suite import suite_spec, write_suite_scene
    from scenelabel.train.pipeline import choose_views, prepare_training

    for name, n_open in (("studio-3x3", LAYOUT_OPEN_RAYS), ("office-5x4-forward", 0)):
        scene = load_scene(write_suite_scene(tmp_path / name, dataclasses.replace(suite_spec(name), n_views=12)))
        scene, layout = with_layout_depth(scene, choose_views(scene, 8)[0])
        assert layout is not None
        trainer, _, _ = prepare_training(scene, preset("quick"), torch.device("cpu"))
        assert trainer.config.sampling.grid_open_rays == n_open
        assert (trainer.rays_by_class is not None) == (n_open > 0)


def test_preset_auto_gives_forward_facing_cameras_before_a_room_fast_in_uniform_cells(small_toy):
    """A room's layout bounds what a forward-facing rig sees: the fast preset over a box (warp
    "box"), unless the warp is given; cameras seen from inside are as without a room."""
    config, why = resolve_preset(preset(), _forward_cameras(), room=True)
    assert config == preset("fast", {"sampling": {"warp": "box"}})
    assert why.startswith("preset auto: the training cameras are forward-facing, before a room")
    given = preset("auto", {"sampling": {"warp": "forward"}, "train": {"seed": 3}})
    assert resolve_preset(given, _forward_cameras(), room=True)[0] == preset("fast", {"sampling": {"warp": "forward"}, "train": {"seed": 3}})
    inside = load_scene(small_toy).cameras
    assert resolve_preset(preset(), inside, room=True) == resolve_preset(preset(), inside)


def test_a_default_build_of_a_forward_facing_capture_trains_voxels_and_resumes_so(forward_scene, tmp_path):
    small = {
        "field": {"grid_resolution": 24},
        "sampling": {"n_steps": 48, "grid_resolution": 16},
        "train": {"steps": 20, "batch_rays": 128, "holdout": 4},
        "output": {"write_map": False, "write_renders": False},
    }
    result = build(forward_scene, tmp_path / "out", preset("auto", small), progress=False)
    field = result.field
    assert result.metrics["preset"] == "voxels" and field.config.preset == "voxels"
    assert field.config.field.head == "direct" and field.config.field.grid_resolution == 24  # the given size kept
    assert field.meta["preset_choice"] == "preset auto: the training cameras are forward-facing"
    assert json.loads((tmp_path / "out" / "config.json").read_text())["preset"] == "voxels"
    assert np.isfinite(result.metrics["psnr"]) and all(np.isfinite(h["loss"]) for h in result.metrics["history"])
    again = resume_config(tmp_path / "out", steps=30)
    resumed = build(forward_scene, tmp_path / "out", again, progress=False, resume=True)
    assert resumed.metrics["steps"] == 30 and resumed.field.config.preset == "voxels"
    assert resumed.field.meta["preset_choice"] == field.meta["preset_choice"]  # why the first run chose it


# ------------------------------------------------------------------ bounds from the observed geometry


def test_a_room_without_near_far_or_aabb_is_bounded_by_what_its_cameras_see(tmp_path):
    """A nerfstudio-style room (no near/far, no aabb): the coarse fit bounds the room itself, not
    the camera frusta out to a guessed far plane (a box many times the room's volume)."""
    from scenelabel.data.synthetic import furnished_room_geometry, room_cameras
    from scenelabel.train.pipeline import prepare_training

    room = furnished_room_geometry()
    path = write_scene(tmp_path / "room", room, room_cameras(24, seed=0), 64, 48, bounds_in_file=False)
    scene = load_scene(path)
    assert scene.aabb is None and np.all(np.isnan(scene.cameras.far))
    frusta, _ = aabb_from_cameras(scene.cameras)
    _, static, _ = prepare_training(scene, preset("quick"), torch.device("cpu"))
    aabb = np.asarray(static["aabb_world"])
    assert static["aabb_source"].startswith("observed geometry")
    interior = np.array([[-3.0, -3.0, 0.0], [3.0, 3.0, 2.6]])  # the walls', floor's and ceiling's inner faces
    assert np.all(aabb[0] <= interior[0]) and np.all(aabb[1] >= interior[1])
    observed = np.asarray(static["observed_bounds"])  # the default map's box, before its pad
    assert np.all(observed[0] >= aabb[0]) and np.all(observed[1] <= aabb[1])
    assert np.all(observed[0] <= interior[0] + 0.1) and np.all(observed[1] >= interior[1] - 0.1)
    volume = np.prod(aabb[1] - aabb[0])
    assert volume < 4.0 * np.prod(room.bounds[1] - room.bounds[0])
    assert volume < 0.2 * np.prod(frusta[1] - frusta[0])
    _, again, _ = prepare_training(scene, preset("quick"), torch.device("cpu"))
    assert again["aabb_world"] == static["aabb_world"]  # deterministic for a seed
    # the distortion term's "auto" is decided on the observed geometry, and the number is saved
    distortion = static["distortion"]
    assert 0.0 <= distortion["thinly_seen"] <= 1.0
    expected = DISTORTION_AUTO_WEIGHT if distortion["thinly_seen"] <= DISTORTION_THIN_MAX else 0.0
    assert distortion["weight"] == expected == static["config"]["train"]["distortion_weight"]


def test_auto_distortion_follows_how_well_the_views_see_the_scene():
    """resolve_distortion: a number stays; "auto" is on only where little of the observed geometry
    is thinly seen, and off where nothing was measured (an input with its own bounds)."""
    from scenelabel.train.choices import resolve_distortion

    auto = preset("quick")
    assert auto.train.distortion_weight == AUTO
    cases = [(None, 0.0), (0.0, DISTORTION_AUTO_WEIGHT), (DISTORTION_THIN_MAX, DISTORTION_AUTO_WEIGHT), (0.6, 0.0)]
    for thinly_seen, weight in cases:
        config, record = resolve_distortion(auto, thinly_seen)
        assert config.train.distortion_weight == record["weight"] == weight
        assert record["thinly_seen"] == thinly_seen and record["why"].startswith("on" if weight else "off")
    fixed = preset("quick", {"train": {"distortion_weight": 0.01}})
    config, record = resolve_distortion(fixed, 0.9)
    assert config.train.distortion_weight == 0.01 and record["why"] == "as configured"


def test_auto_free_margin_follows_where_the_depth_comes_from():
    """resolve_free_margin: "auto" is LAYOUT_FREE_MARGIN where all the depth is the layout's, else
    SENSOR_FREE_MARGIN; a number stays. A trainer made without the build takes a sensor's."""
    from scenelabel.config import LAYOUT_FREE_MARGIN, SENSOR_FREE_MARGIN
    from scenelabel.train.choices import resolve_free_margin

    auto = preset("quick")
    assert auto.train.free_margin == AUTO and LAYOUT_FREE_MARGIN < SENSOR_FREE_MARGIN
    assert resolve_free_margin(auto, True).train.free_margin == LAYOUT_FREE_MARGIN
    assert resolve_free_margin(auto, False).train.free_margin == SENSOR_FREE_MARGIN
    fixed = preset("quick", {"train": {"free_margin": 0.1}})
    assert resolve_free_margin(fixed, True).train.free_margin == 0.1


def test_an_object_capture_without_bounds_is_bounded_by_its_silhouettes(tmp_path):
    """The toy's two boxes without the floor, no near/far, no aabb, the backdrop labelled FREE
    (classes.json's free_index): every view shows the object whole, so the bounds are the
    silhouettes' visual hull (no coarse fit): the boxes, all of them, in a box little larger."""
    import dataclasses

    from scenelabel.data.synthetic import toy_cameras
    from scenelabel.train.pipeline import prepare_training, silhouette_points

    boxes = dataclasses.replace(toy_scene_geometry(), boxes=toy_scene_geometry().boxes[1:])
    path = write_scene(tmp_path / "boxes", boxes, toy_cameras(16, 0), 48, 36, bounds_in_file=False)
    classes = json.loads((path / "classes.json").read_text())
    (path / "classes.json").write_text(json.dumps({**classes, "ignore_index": None, "free_index": 255}))
    scene = load_scene(path)
    _, static, _ = prepare_training(scene, preset("quick"), torch.device("cpu"))
    assert static["aabb_source"].startswith("silhouettes (visual hull)")
    aabb, exact = np.asarray(static["aabb_world"]), boxes.bounds
    assert np.all(aabb[0] <= exact[0]) and np.all(aabb[1] >= exact[1])
    assert np.prod(aabb[1] - aabb[0]) < 4.0 * np.prod(exact[1] - exact[0])
    # an image's alpha is its silhouette before its labels; a view cut by the image edge: no hull
    with_alpha = dataclasses.replace(scene, image_alphas=[None] * (len(scene) - 1) + [np.ones((36, 48))])
    masks = with_alpha.silhouettes([0, len(scene) - 1])
    assert np.array_equal(masks[0], scene.labels[0] != -1) and masks[1].all()
    cut = [np.where(np.arange(48) < 24, 3, label) for label in scene.labels]  # the left half shows box_red
    assert silhouette_points(dataclasses.replace(scene, labels=cut), list(range(len(scene)))) is None


def test_a_build_beside_another_job_trains_on_its_share_of_the_cores(small_toy, tmp_path, monkeypatch, capsys):
    """Another running scenelabel job (a sleeping process registered as one): the build trains on half
    its threads, says so in its plan, logs them, and gives them back at the end (scenelabel._cores)."""
    import os
    import subprocess
    import sys

    import psutil

    from scenelabel import _cores

    registry = tmp_path / "jobs"
    registry.mkdir()
    monkeypatch.setattr(_cores, "default_registry", lambda: registry)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        (registry / str(other.pid)).write_text(repr(psutil.Process(other.pid).create_time()))
        result = build(small_toy, tmp_path / "out", _small_config(), progress=True)
        assert {h["threads"] for h in result.metrics["history"]} == {1}
        assert torch.get_num_threads() == 2  # given back
        assert not (registry / str(os.getpid())).exists()
        assert "; 1 thread, sharing the cores with 1 other scenelabel job" in capsys.readouterr().err  # the plan
    finally:
        other.kill()
        other.wait()
        torch.set_num_threads(before)
