"""Training stops cleanly when it goes wrong, and keeps the last good checkpoint; NeRF's coarse
and fine networks train together and resume together."""

import dataclasses

import numpy as np
import pytest
import torch

from scenelabel import SemanticField, TrainingError, build, load_scene, preset, write_toy_scene
from scenelabel.codes import FREE
from scenelabel.errors import ConfigError
from scenelabel.fields.checkpoint import load_checkpoint
from scenelabel.geometry.frame import aabb_from_cameras, aabb_from_points, observed_extent
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.render.marcher import CompositeOptions
from scenelabel.render.sampling import CARVE_MARGIN
from scenelabel.train.losses import DEPTH_HUBER, total_variation
from scenelabel.train.pipeline import prepare_training
from scenelabel.train.trainer import backgrounds_for_rays, free_space_limit

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("train") / "scene", n_train=14, n_test=2, width=32, height=24)


def test_learning_rate_1000x_too_high_is_detected(scene, tmp_path):
    base = preset("quick").train
    config = preset(
        "quick",
        {
            "train": {"steps": 400, "lr_encoding": 1000 * base.lr_encoding, "lr_mlp": 1000 * base.lr_mlp, "checkpoint_every": 50},
            "output": {"write_map": False, "write_renders": False},
        },
    )
    with pytest.raises(TrainingError, match="diverged.*learning rate") as info:
        build(scene, tmp_path / "out", config, progress=False)
    assert "last checkpoint before the failure is kept" in str(info.value)
    assert load_checkpoint(tmp_path / "out").step < 400  # an earlier checkpoint, not the failed state


def test_a_run_that_diverges_for_a_while_resumes_from_its_last_good_state_at_half_the_rate(scene, tmp_path, monkeypatch):
    import scenelabel.train.trainer as train

    real_mse, real_step = train.photometric_mse, train.Trainer.train_step
    first_pass = {"step": 0, "on": True}  # until a rollback, each step is taken once

    def counted(self):
        first_pass["on"] = first_pass["on"] and self.state.step == first_pass["step"]
        first_pass["step"] += 1
        return real_step(self)

    def spiking(rgb, target, weights=None):  # from step 250 of the first pass on, far above the mean colour's error
        return real_mse(rgb, target, weights) + (1.0 if first_pass["on"] and first_pass["step"] > 250 else 0.0)

    monkeypatch.setattr(train.Trainer, "train_step", counted)
    monkeypatch.setattr(train, "photometric_mse", spiking)
    config = preset("quick", {"train": {"steps": 400}, "output": {"write_map": False, "write_renders": False}})
    metrics = build(scene, tmp_path / "out", config, progress=False).metrics
    assert metrics["steps"] == 400  # the build finished
    (rollback,) = metrics["rollbacks"]
    assert 250 <= rollback["diverged_at"] < 270  # a few steps of it tip the smoothed error over
    assert rollback["resumed_from"] == 100 and rollback["lr_factor"] == 0.5  # the older of the copies before it
    ckpt = load_checkpoint(tmp_path / "out")
    assert [g["lr_scale"] for g in ckpt.optimizer["param_groups"]] == [0.5, 0.5]  # kept for a resumed build
    assert ckpt.budget_anchor is None  # no time budget: the schedules follow the steps of the state resumed
    assert ckpt.rollbacks == metrics["rollbacks"]  # and the count, which the next rollback's rate follows
    assert metrics["miou"] > 0.8


def test_a_rollback_takes_the_schedules_back_with_the_state_and_ends_them_with_the_budget(scene):
    from scenelabel.train.divergence import Diverged

    config = preset("quick", {"train": {"steps": 100_000, "time_budget": 100.0}})
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    tc = trainer.config.train
    trainer.schedule.observe(0, tc.steps, 0.0, tc.time_budget)
    assert trainer.schedule.observe(10, tc.steps, 20.0, tc.time_budget)  # 10 steps in 20 s: the budget binds
    start = 10 / tc.steps  # the fraction anchored
    trainer.state.elapsed = 20.0
    assert trainer.progress() == pytest.approx(start)
    trainer.guard.keep(0, trainer._snapshot)  # the guard's copy (its copies are of every 100th step)
    trainer.state.step, trainer.state.elapsed = 300, 60.0
    assert trainer.progress() == pytest.approx(start + (1 - start) * 0.5)  # half way from the anchor to the budget's end
    message = trainer._roll_back(Diverged(300, 1.0))
    assert "resumed from step 0 at 0.5 times the learning rate" in message
    assert trainer.state.step == 0 and trainer.state.elapsed == 60.0  # the time spent stays spent
    assert trainer.progress() == pytest.approx(start)  # the schedules of the state resumed
    trainer.state.elapsed = 80.0  # half way from the rollback to the budget's end
    halfway = start + (1 - start) * 0.5
    assert trainer.progress() == pytest.approx(halfway)
    resumed, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    resumed.load_state_dict(trainer.state_dict())  # a build resumed from a checkpoint keeps the schedules
    assert resumed.progress() == pytest.approx(halfway)
    trainer._set_lr()
    assert trainer.optimizer.param_groups[0]["lr"] == pytest.approx(0.5 * tc.lr_encoding * tc.lr_final_ratio**halfway)
    trainer.state.elapsed = 100.0
    assert trainer.progress() == pytest.approx(1.0)
    assert resumed.guard.rollbacks == trainer.guard.rollbacks  # a resumed build knows the rollback ...
    resumed.guard.keep(0, resumed._snapshot)
    resumed.state.step = 200
    assert "at 0.25 times the learning rate" in resumed._roll_back(Diverged(200, 1.0))  # ... and lowers the rate further


def _train_on_a_clock(scene, monkeypatch, seconds_per_step, steps=200, budget=100.0):
    """A quick training run of ``steps`` steps whose step i takes seconds_per_step(i) by the trainer's
    clock, with a time budget; returns the trainer after it."""
    from types import SimpleNamespace

    from scenelabel.train import trainer as trainer_module

    calls = iter(range(10**9))
    now = {"t": 0.0}

    def perf_counter():  # called once before the first step, then once after each
        step = next(calls)
        now["t"] += seconds_per_step(step) if step > 0 else 0.0
        return now["t"]

    monkeypatch.setattr(trainer_module, "time", SimpleNamespace(perf_counter=perf_counter))
    config = preset("quick", {"train": {"steps": steps, "time_budget": budget}})
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    trainer.run(progress=False)
    return trainer


def test_the_same_seed_trains_the_same_field_on_a_slow_start_or_a_fast_one(scene, monkeypatch):
    """Two runs inside their time budget, one whose first 16 steps take 1 s each (the budget's
    fraction spent then leads the steps': 0.16 against 0.08) and one at 0.1 s a step: the schedules
    follow the steps, so the fields are the same to the bit."""
    slow_start = _train_on_a_clock(scene, monkeypatch, lambda i: 1.0 if i <= 16 else 0.05)
    even = _train_on_a_clock(scene, monkeypatch, lambda i: 0.1)
    for trainer in (slow_start, even):
        assert trainer.state.step == 200 and trainer.state.elapsed < 100.0 and trainer.schedule.anchor is None
    assert slow_start.state.elapsed != even.state.elapsed
    for name, value in slow_start.model.state_dict().items():
        assert torch.equal(value, even.model.state_dict()[name]), name


def test_a_run_its_time_budget_ends_still_ends_its_schedules(scene, monkeypatch):
    trainer = _train_on_a_clock(scene, monkeypatch, lambda i: 1.0)  # 200 steps of 1 s in a budget of 100 s
    assert trainer.state.step < 200 and trainer.state.elapsed >= 100.0
    assert trainer.schedule.anchor is not None and trainer.progress() == 1.0
    tc = trainer.config.train
    lr = trainer.optimizer.param_groups[0]["lr"]  # set by the last step, one second before the budget's end
    assert tc.lr_encoding * tc.lr_final_ratio <= lr <= 1.05 * tc.lr_encoding * tc.lr_final_ratio

def test_non_finite_loss_stops_with_a_clear_message(scene, tmp_path, monkeypatch):
    import scenelabel.train.trainer as train

    real = train.photometric_mse
    calls = {"n": 0}

    def poisoned(rgb, target, weights=None):
        calls["n"] += 1
        return real(rgb, target, weights) * (float("nan") if calls["n"] > 20 else 1.0)

    monkeypatch.setattr(train, "photometric_mse", poisoned)
    config = preset("quick", {"train": {"steps": 50, "checkpoint_every": 10}, "output": {"write_map": False}})
    with pytest.raises(TrainingError, match="non-finite at step 20") as info:
        build(scene, tmp_path / "out", config, progress=False)
    assert "last checkpoint before the failure" in str(info.value)
    assert load_checkpoint(tmp_path / "out").step == 20


HIERARCHICAL = {"sampling": {"strategy": "hierarchical", "n_coarse": 16, "n_fine": 32}, "train": {"batch_rays": 128}}


def test_hierarchical_sampling_trains_both_networks_and_resumes_them(scene):
    config = preset("quick", HIERARCHICAL)
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    assert trainer.coarse is not None
    before = [p.detach().clone() for p in (*trainer.model.parameters(), *trainer.coarse.parameters())]
    logs = [trainer.train_step() for _ in range(3)]
    after = list(trainer.model.parameters()) + list(trainer.coarse.parameters())
    assert all(not torch.equal(a, b) for a, b in zip(before, after))  # every parameter of both networks moved
    assert all(np.isfinite(log["loss"]) for log in logs)
    assert logs[-1]["samples_per_ray"] > 16 + 32  # coarse and fine samples of the rays that enter the box
    saved = trainer.state_dict()
    assert "coarse_model" in saved
    fresh, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    fresh.load_state_dict(saved)
    for a, b in zip(fresh.coarse.state_dict().values(), trainer.coarse.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert fresh.train_step()["loss"] == trainer.train_step()["loss"]  # the same next step


def test_a_hierarchical_build_renders_with_its_coarse_network(scene, tmp_path):
    config = preset("quick", {**HIERARCHICAL, "output": {"write_map": False, "write_renders": False}})
    config.train.steps = 20
    build(scene, tmp_path / "out", config, progress=False)
    field = SemanticField.load(tmp_path / "out")
    assert field.coarse is not None and field.config.sampling.strategy == "hierarchical"
    origins, directions = np.array([[0.0, 0.0, 3.0], [0.1, 0.2, 3.0]]), np.array([[0.0, 0.0, -1.0], [0.0, 0.1, -1.0]])
    first, second = field.query_rays(origins, directions), field.query_rays(origins, directions)
    np.testing.assert_array_equal(first.opacity, second.opacity)  # no jitter outside training
    np.testing.assert_array_equal(first.depth, second.depth)
    np.testing.assert_allclose(first.probs.sum(-1), 1.0, atol=1e-6)
    field.coarse = None  # the same fine network marched through the grid instead: a different answer
    assert not np.array_equal(field.query_rays(origins, directions).opacity, first.opacity)


def test_distortion_loss_gathers_the_weights_along_rays(scene):
    """With train.distortion_weight the logged distortion (mip-NeRF 360 eq. 15 of the batch's rays)
    ends lower than without it, from the same start; the loss includes it."""
    final = {}
    for weight in (0.0, 0.05):
        config = preset("quick", {"train": {"steps": 150, "distortion_weight": weight}})
        trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
        logs = [trainer.train_step() for _ in range(150)]
        assert all(np.isfinite(log["distortion"]) and log["distortion"] >= 0 for log in logs)
        if weight:
            log = logs[-1]
            assert log["loss"] > log["mse"] + config.train.semantic_weight * log["ce"]  # the term is in the loss
        final[weight] = np.mean([log["distortion"] for log in logs[-20:]])
    assert final[0.05] < final[0.0]


def test_distortion_starts_at_its_fraction_of_the_run(scene):
    """train.distortion_start: the term is out of the loss before that fraction of the steps, in it after."""
    config = preset("quick", {"train": {"steps": 40, "distortion_weight": 0.05, "distortion_start": 0.5}})
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    logs = [trainer.train_step() for _ in range(40)]
    without = [log["loss"] - (log["mse"] + config.train.semantic_weight * log["ce"]) for log in logs]
    assert max(abs(x) for x in without[:20]) < 1e-6
    assert all(x > 0 for x in without[20:])


def test_total_variation_smooths_a_dense_grid(scene):
    """train.tv_weight adds the squared total variation of the dense grid (a random slab of it) to
    the loss: from the same start, the grid ends smoother than without it."""
    final = {}
    for weight in (0.0, 1.0):
        config = preset("voxels", {"field": {"grid_resolution": 24}, "train": {"steps": 60, "tv_weight": weight}})
        trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
        logs = [trainer.train_step() for _ in range(60)]
        assert all(np.isfinite(log["loss"]) for log in logs)
        if weight:
            assert logs[-1]["loss"] > logs[-1]["mse"] + config.train.semantic_weight * logs[-1]["ce"]
        final[weight] = float(total_variation(trainer.model.encoding.grid.detach()))
    assert final[1.0] < 0.5 * final[0.0], final


def test_total_variation_needs_a_dense_grid(scene):
    with pytest.raises(ConfigError, match="dense grid"):
        prepare_training(load_scene(scene), preset("quick", {"train": {"tv_weight": 0.1}}), torch.device("cpu"))


def test_a_random_background_makes_every_training_ray_opaque(scene, tmp_path):
    """train.background "random": a ray left transparent would show a new colour every step, so
    the field fills even what the images show as background (the toy's white backdrop) with
    matter; with a white background those rays stay transparent. Renders use white."""
    loaded = load_scene(scene)
    view = 0
    background = loaded.depths[view].reshape(-1) == 0  # pixels whose ray hits no box
    origins, directions = rays_from_cameras(loaded.cameras, view)
    opacity = {}
    for name, colour in (("white", (1.0, 1.0, 1.0)), ("random", "random")):
        config = preset("quick", {"train": {"steps": 300, "background": colour}, "output": {"write_map": False, "write_renders": False}})
        field = build(scene, tmp_path / name, config, progress=False).field
        rays = field.query_rays(origins[background], directions[background])
        assert np.all(np.isfinite(rays.rgb))
        opacity[name] = float(np.median(rays.opacity))
    assert opacity["white"] < 0.5 < 0.9 < opacity["random"], opacity


# ------------------------------------------------------------------ sensor depth and masks


def _with_sensor_depth(scene, factor=1.0):
    """The loaded toy scene with its exact depth (times ``factor``) as sensor depth, NaN off the boxes."""
    return dataclasses.replace(
        scene, sensor_depths=[np.where(d > 0, d * factor, np.nan).astype(np.float32) for d in scene.depths]
    )


def test_without_sensor_depth_the_depth_weight_changes_nothing(scene):
    """The depth terms are off when no view has sensor depth: the same steps, the same losses."""
    losses = {}
    for weight in (0.0, 1.0):
        trainer, _, _ = prepare_training(load_scene(scene), preset("quick", {"train": {"depth_weight": weight}}), torch.device("cpu"))
        assert trainer.rays.depth is None
        logs = [trainer.train_step() for _ in range(5)]
        assert all(log["depth"] == 0.0 for log in logs)
        losses[weight] = [log["loss"] for log in logs]
    assert losses[0.0] == losses[1.0]


def test_sensor_depth_clears_the_fog_in_front_of_surfaces(scene):
    """From the same start, with the depth terms the training rays carry much less weight in front
    of the measured surfaces (the free-space term's quantity) than without them (no carving either
    way: the terms alone)."""
    loaded = _with_sensor_depth(load_scene(scene))
    front = {}
    for weight in (0.0, 0.1):
        config = preset("quick", {"train": {"steps": 200, "depth_weight": weight}, "sampling": {"depth_carve": False}})
        trainer, _, _ = prepare_training(loaded, config, torch.device("cpu"))
        logs = [trainer.train_step() for _ in range(200)]
        assert all(np.isfinite(log["depth"]) for log in logs) and (logs[-1]["depth"] > 0) == (weight > 0)
        r = trainer.rays
        idx = torch.nonzero(torch.isfinite(r.depth)).squeeze(1)
        with torch.no_grad():
            out, _, _ = trainer.render(
                r.origins[idx], r.directions[idx], r.t_min[idx], r.t_max[idx], torch.full((len(idx),), 0.5),
                options=CompositeOptions(free_until=free_space_limit(r.depth[idx], trainer.marching.step, trainer.free_margin)),
            )
        front[weight] = float(out.front_weight.mean())
    assert front[0.1] < 0.5 * front[0.0], front


def test_measured_rays_train_on_a_random_background_and_the_others_on_the_scenes():
    colours = torch.rand(4, 3)
    measured = torch.tensor([True, False, True, False])
    for background, expected_rest in ((torch.tensor([1.0, 1.0, 1.0]), 1.0), (None, 0.0)):
        out = backgrounds_for_rays(background, measured, colours)
        assert torch.equal(out[measured], colours[measured])
        assert torch.all(out[~measured] == expected_rest)
    per_ray = torch.rand(4, 3)  # train.background "random": one colour per ray already
    assert torch.equal(backgrounds_for_rays(per_ray, measured, colours)[~measured], per_ray[~measured])


def test_a_wall_left_transparent_pays_only_with_the_random_background_behind_measured_rays(scene):
    """White views, a transparent field: with the white background behind every ray the render
    matches every pixel, so nothing in the photometric loss asks a measured surface to be opaque
    (office-5x4-forward's walls stayed half transparent in front of it, docs/suite_depth_background.md);
    with a random colour behind the measured rays it pays for them, and only for them."""
    loaded = _with_sensor_depth(load_scene(scene))
    white = dataclasses.replace(loaded, images=[np.ones_like(image) for image in loaded.images])
    mse = {}
    for depth_background in ("scene", "random"):
        config = preset("quick", {"train": {"depth_background": depth_background}, "field": {"density_bias": -30.0}})
        trainer, _, _ = prepare_training(white, config, torch.device("cpu"))
        assert trainer.config.train.background == (1.0, 1.0, 1.0)
        mse[depth_background] = trainer.train_step()["mse"]
    measured = float(torch.isfinite(trainer.rays.depth).float().mean())
    assert 0.2 < measured < 0.9  # the toy's boxes: some rays see them, the others its backdrop
    assert mse["scene"] < 1e-8
    # E[(1 - u)^2] = 1/3 for u uniform, on the measured share of the batch
    assert 0.5 * measured / 3 < mse["random"] < 1.5 * measured / 3, (mse, measured)


def test_sensor_depth_carves_the_grid_in_front_of_the_measured_surfaces(scene):
    """With ``sampling.depth_carve`` the density grid skips, before the first step, cells that depth
    rays cross well in front of their surfaces; no measured surface point lies in a skipped cell;
    carving is on by default, off without depth, when asked, or with the depth terms off."""
    loaded = _with_sensor_depth(load_scene(scene))
    trainer, static, _ = prepare_training(loaded, preset("quick"), torch.device("cpu"))
    assert 0.05 < static["carved_by_depth"] == trainer.grid.carved.float().mean().item()
    assert not (trainer.grid.bits & trainer.grid.carved).any()
    r = trainer.rays
    measured = torch.isfinite(r.depth)
    assert trainer.grid(r.origins[measured] + r.directions[measured] * r.depth[measured, None]).all()
    halfway = r.origins[measured] + r.directions[measured] * (0.5 * r.depth[measured, None])
    assert (~trainer.grid(halfway)).float().mean() > 0.5  # most of the space in front is skipped from the start
    for scene_, overrides in (
        (load_scene(scene), {"sampling": {"depth_carve": True}}),
        (loaded, {"sampling": {"depth_carve": False}}),
        (loaded, {"sampling": {"depth_carve": True}, "train": {"depth_weight": 0.0}}),
    ):
        trainer, static, _ = prepare_training(scene_, preset("quick", overrides), torch.device("cpu"))
        assert static["carved_by_depth"] == 0.0 and trainer.grid.occupied_fraction == 1.0


def test_the_carve_border_is_handed_back_to_the_field_at_depth_carve_until(scene):
    """The carve holds until sampling.depth_carve_until of the run; then the carved cells beside
    uncarved ones are refreshed from the field (a carved cell it holds dense is occupied again) and
    the rest stay empty."""
    loaded = _with_sensor_depth(load_scene(scene))
    config = preset("quick", {"train": {"steps": 64}, "sampling": {"depth_carve": True, "depth_carve_until": 0.5, "grid_update_every": 8}})
    trainer, _, _ = prepare_training(loaded, config, torch.device("cpu"))
    carved = trainer.grid.carved.clone()
    while trainer.progress() < 0.5:
        trainer.train_step()
        assert not (trainer.grid.bits & carved).any()
    trainer.model.density = lambda p: torch.full((len(p),), 1e3)  # a field dense everywhere
    while not trainer.state.step % 8 == 1:  # up to the first refresh past half the run
        trainer.train_step()
    beside = torch.nn.functional.max_pool3d((~carved).float()[None, None], 3, stride=1, padding=1)[0, 0] > 0
    border, inner = carved & beside, carved & ~beside
    assert border.any() and inner.any()
    assert trainer.grid.bits[border].all() and not trainer.grid.bits[inner].any()
    assert torch.equal(trainer.grid.carved, inner)


def test_training_stops_marching_rays_behind_the_surfaces_it_has_made_opaque(scene):
    """``sampling.train_min_trans``: from the same start, once surfaces are opaque (the depth terms
    make them so within 300 steps; no carving, which would skip the space behind them too) the
    training render evaluates fewer samples per ray than with every occupied sample (0), and
    trains as well."""
    loaded = _with_sensor_depth(load_scene(scene))
    logs = {}
    for min_trans in (0.0, 1e-4):
        overrides = {"train": {"steps": 300}, "sampling": {"train_min_trans": min_trans, "depth_carve": False}}
        trainer, _, _ = prepare_training(loaded, preset("quick", overrides), torch.device("cpu"))
        assert trainer.render.min_trans == min_trans
        logs[min_trans] = [trainer.train_step() for _ in range(300)]
    last = {k: v[-30:] for k, v in logs.items()}
    samples = {k: np.mean([log["samples_per_ray"] for log in v]) for k, v in last.items()}
    psnr = {k: np.mean([log["psnr"] for log in v]) for k, v in last.items()}
    assert samples[1e-4] < 0.8 * samples[0.0], samples
    assert psnr[1e-4] > psnr[0.0] - 1.0, psnr


def test_depth_ray_end_ends_measured_rays_just_past_their_depth(scene):
    loaded = _with_sensor_depth(load_scene(scene))
    full, _, _ = prepare_training(loaded, preset("quick", {"sampling": {"depth_carve": True, "depth_ray_end": 0.0}}), torch.device("cpu"))
    ended, static, _ = prepare_training(
        loaded, preset("quick", {"sampling": {"depth_carve": True, "depth_ray_end": 2.0}}), torch.device("cpu")
    )
    measured = torch.isfinite(full.rays.depth)
    aabb_n = np.asarray(static["aabb_internal"])
    cell = float((aabb_n[1] - aabb_n[0]).min()) / preset("quick").sampling.grid_resolution
    expected = torch.minimum(full.rays.t_max, full.rays.depth * (1 + CARVE_MARGIN) + 2.0 * cell)
    assert full.rays.t_stop is None
    torch.testing.assert_close(ended.rays.t_stop[measured], expected[measured])
    torch.testing.assert_close(ended.rays.t_stop[~measured], full.rays.t_max[~measured])  # no depth: to the box
    torch.testing.assert_close(ended.rays.t_max, full.rays.t_max)  # the depth term's far end stays the box's


def test_a_ray_stopped_past_its_depth_still_pays_for_transparency(scene):
    """The depth term places a transparent ray's rest at the box's far side, not where marching
    stops (sampling.depth_ray_end): at the stop it would cost at most the 5 % margin, and a light
    wall could stay half transparent in front of a white background (library-7x4 lost its walls)."""
    loaded = _with_sensor_depth(load_scene(scene))
    config = preset("quick", {"sampling": {"depth_carve": True}, "field": {"density_bias": -30.0}})
    trainer, _, _ = prepare_training(loaded, config, torch.device("cpu"))  # a transparent field
    r = trainer.rays
    measured = torch.isfinite(r.depth)
    at_stop = torch.nn.functional.smooth_l1_loss(
        (r.t_stop[measured] - r.depth[measured]) / r.depth[measured], torch.zeros(int(measured.sum())),
        beta=DEPTH_HUBER, reduction="none",
    )
    logged = trainer.train_step()["depth"]
    assert logged > 2 * float(at_stop.max())  # stopped there, it could cost no more than at_stop.max()


def test_grid_refreshes_decay_by_sampling_grid_decay(scene, monkeypatch):
    """Each refresh of the density grid keeps max(sampling.grid_decay x a cell's remembered density,
    its density now)."""
    from scenelabel.render.sampling import DensityGrid

    decays = []
    real = DensityGrid.update
    monkeypatch.setattr(DensityGrid, "update", lambda self, fn, decay=0.95, **kw: (decays.append(decay), real(self, fn, decay, **kw)))
    trainer, _, _ = prepare_training(load_scene(scene), preset("quick", {"sampling": {"grid_decay": 0.5}}), torch.device("cpu"))
    sc = trainer.config.sampling
    for _ in range(sc.grid_warmup + sc.grid_update_every + 1):
        trainer.train_step()
    assert decays == [0.5, 0.5]
    before = trainer.grid.density.clone()
    monkeypatch.setattr(DensityGrid, "update", real)
    trainer.grid.update(lambda p: torch.zeros(len(p)), 0.5)  # a field emptied everywhere
    torch.testing.assert_close(trainer.grid.density, 0.5 * before)



@pytest.mark.parametrize("from_training", [True, False])
def test_training_samples_raise_the_density_grid_between_refreshes(scene, from_training):
    """With sampling.grid_from_training a step's samples raise their cells' remembered density (never
    lower it), and only in occupied cells, where samples go; without it the grid waits for its refresh."""
    config = preset("quick", {"sampling": {"grid_from_training": from_training}})
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    sc = trainer.config.sampling
    for _ in range(sc.grid_warmup + 1):  # past the first refresh: every cell's density is finite
        trainer.train_step()
    before = trainer.grid.density.clone()
    trainer.train_step()  # not a refresh step
    after = trainer.grid.density
    if not from_training:
        torch.testing.assert_close(after, before)
        return
    raised = after > before
    assert torch.all(after >= before) and raised.any()
    assert torch.all(trainer.grid.bits[raised])

def test_masked_pixels_give_no_training_rays(scene):
    loaded = load_scene(scene)
    masks = [np.zeros(im.shape[:2], bool) for im in loaded.images]
    for m in masks:
        m[:, : m.shape[1] // 2] = True  # the left half of every view is used
    masked = dataclasses.replace(loaded, masks=masks)
    full, _, _ = prepare_training(loaded, preset("quick"), torch.device("cpu"))
    half, _, _ = prepare_training(masked, preset("quick"), torch.device("cpu"))
    assert len(half.rays) * 2 == len(full.rays)
    # the rays kept are the left halves: the same rgb targets as the unmasked scene's left halves
    keep = torch.as_tensor(np.concatenate([m.reshape(-1) for i, m in enumerate(masks) if i % 8]))
    torch.testing.assert_close(half.rays.rgb, full.rays.rgb[keep])


def test_free_pixels_of_opaque_views_train_transparency(scene):
    """A FREE pixel (its ray meets nothing) of a view without alpha gets alpha 0 and no class; where a
    view has its own alpha, that alpha rules."""
    loaded = load_scene(scene)
    free = [np.where(label == 255, FREE, label) for label in loaded.labels]
    freed = dataclasses.replace(loaded, labels=free, ignore_index=None)
    train = [i for i in range(len(loaded)) if i % 8]
    data, _, _ = prepare_training(freed, preset("quick"), torch.device("cpu"))
    is_free = torch.as_tensor(np.concatenate([free[i].reshape(-1) == FREE for i in train]))
    assert is_free.any() and (~is_free).any()
    torch.testing.assert_close(data.rays.alpha, (~is_free).float())
    assert torch.all(data.rays.channels[is_free] == -1) and torch.all(data.rays.channels[~is_free] >= 0)
    own = [np.full(label.shape, 0.25, np.float32) for label in free]
    with_alpha, _, _ = prepare_training(
        dataclasses.replace(freed, image_alphas=own), preset("quick"), torch.device("cpu")
    )
    torch.testing.assert_close(with_alpha.rays.alpha, torch.full_like(with_alpha.rays.alpha, 0.25))
    full, _, _ = prepare_training(loaded, preset("quick"), torch.device("cpu"))
    assert full.rays.alpha is None  # opaque views without FREE pixels: no alpha at all


def test_sensor_depth_bounds_the_scene_without_a_coarse_fit(scene, monkeypatch):
    """No near/far and no box, but sensor depth: the bounds come from the depth, back-projected."""
    import scenelabel.train.pipeline as pipeline

    loaded = load_scene(scene)
    cameras = dataclasses.replace(loaded.cameras, near=np.full(len(loaded), np.nan), far=np.full(len(loaded), np.nan))
    bare = dataclasses.replace(_with_sensor_depth(loaded), cameras=cameras, aabb=None)

    def no_coarse_fit(*args, **kwargs):
        raise AssertionError("the coarse fit ran although the views have sensor depth")

    monkeypatch.setattr(pipeline, "observed_points", no_coarse_fit)
    _, static, _ = prepare_training(bare, preset("quick"), torch.device("cpu"))
    assert static["aabb_source"].startswith("sensor depth")
    aabb = np.asarray(static["aabb_world"])
    points = pipeline.sensor_depth_points(bare, list(range(len(bare))))
    inside = np.all((points >= aabb[0]) & (points <= aabb[1]), axis=1)
    assert inside.mean() > 0.98
    # their and the cameras' full extent inside the box is stored: the default map's box (query.mapping.map_lattice)
    # (the cameras, outside the box, clamped to it: space between them and the points was seen)
    centres = bare.cameras[[bare.names.index(n) for n in static["train_views"]]].centres
    want = observed_extent(np.concatenate([points, np.clip(centres, aabb[0], aabb[1])]), aabb)
    np.testing.assert_allclose(static["observed_bounds"], want, atol=0.05)
    assert not np.allclose(want, observed_extent(points, aabb), atol=0.05)  # the cameras widen it here
    # data.bounds_pad sets the pad around the points, and the source says it
    _, tight, _ = prepare_training(bare, preset("quick", {"data": {"bounds_pad": 0.03}}), torch.device("cpu"))
    assert "padded 3% of the longest side" in tight["aabb_source"]
    expected = aabb_from_points(points, pad=0.03)
    frusta, _ = aabb_from_cameras(bare.cameras)
    # (the build draws its own sample of the depth points: the same bounds to within a few cm)
    np.testing.assert_allclose(tight["aabb_world"], np.clip(expected, frusta[0], frusta[1]), atol=0.03)
    assert np.all(np.asarray(tight["aabb_world"])[0] >= aabb[0]) and np.all(np.asarray(tight["aabb_world"])[1] <= aabb[1])


def test_poses_of_another_unit_are_scaled_to_the_sensor_depth(scene, tmp_path):
    """Poses in half-metres (as SfM might give) with depth in metres: the build scales to metres and
    records the factor like --scale."""
    loaded = load_scene(scene)
    halved = dataclasses.replace(loaded.scaled(2.0), sensor_depths=_with_sensor_depth(loaded).sensor_depths)
    config = preset("quick", {"train": {"steps": 2}, "output": {"write_map": False, "write_renders": False}})
    result = build(halved, tmp_path / "out", config, progress=False)
    meta = result.field.meta
    assert meta["world_scale"] == pytest.approx(1.0, rel=0.01)  # 2 x (1 / 2): back in metres
    assert meta["scene_info"]["scale_source"] == "sensor depth"


def test_sensor_depth_turns_the_solid_interior_term_on(scene):
    """With sensor depth the solid-interior term runs at train.depth_solid_weight at least; without
    depth (or with the depth terms off) at train.solid_weight alone."""
    loaded = load_scene(scene)
    cases = [
        (_with_sensor_depth(loaded), {}, 0.01),
        (_with_sensor_depth(loaded), {"solid_weight": 0.05}, 0.05),
        (_with_sensor_depth(loaded), {"depth_weight": 0.0}, 0.0),
        (loaded, {}, 0.0),
    ]
    for data, train, expected in cases:
        trainer, _, _ = prepare_training(data, preset("quick", {"train": train}), torch.device("cpu"))
        assert trainer.solid_weight == expected, (train, expected)


def test_the_solid_interior_term_waits_for_the_photometric_error_to_fall(scene, monkeypatch):
    """Past SOLID_START of the run the term is on only while the smoothed photometric error is at most
    SOLID_ERROR_FRACTION of the mean colour's: in early fog it would fill the fog (hall-10x6 on a slow
    machine, docs/suite_phone_depth_rooms.md)."""
    from scenelabel.train import trainer as trainer_module

    calls = []
    real = trainer_module.solid_interior_loss
    monkeypatch.setattr(trainer_module, "solid_interior_loss", lambda *a, **k: calls.append(1) or real(*a, **k))
    config = preset("quick", {"train": {"steps": 8, "time_budget": None}, "output": {"write_map": False}})
    trainer, _, _ = prepare_training(_with_sensor_depth(load_scene(scene)), config, torch.device("cpu"))
    assert trainer.solid_weight > 0
    trainer.state.step = 4  # half the run: past SOLID_START
    assert trainer.progress() >= trainer_module.SOLID_START
    guard = trainer.guard
    for ema, on in [(None, False), (2.0 * guard.mean_colour_mse, False),
                    (0.9 * trainer_module.SOLID_ERROR_FRACTION * guard.mean_colour_mse, True)]:
        calls.clear()
        guard.mse_ema = ema
        trainer.train_step()
        assert bool(calls) == on, (ema, on)


def test_sensor_depth_on_held_out_views_only_leaves_the_bounds_to_the_coarse_fit(scene):
    """Only the held-out view 0 has sensor depth: the bounds come from the coarse fit, and say so."""
    loaded = load_scene(scene)
    cameras = dataclasses.replace(loaded.cameras, near=np.full(len(loaded), np.nan), far=np.full(len(loaded), np.nan))
    depths = [None] * len(loaded)
    depths[0] = _with_sensor_depth(loaded).sensor_depths[0]
    bare = dataclasses.replace(loaded, cameras=cameras, aabb=None, sensor_depths=depths)
    _, static, test_idx = prepare_training(bare, preset("quick"), torch.device("cpu"))
    assert 0 in test_idx
    assert static["aabb_source"].startswith("observed geometry")


def test_auto_grid_decay_steps_and_budget_follow_sensor_depth(scene):
    """sampling.grid_decay, train.steps and train.time_budget "auto": the *_WITH_DEPTH numbers where the
    training rays carry sensor depth the build trains on, the others otherwise (no depth, or
    train.depth_weight 0); a number given is kept. The trainer's config (the one training reads and
    the checkpoint saves) holds the numbers."""
    from scenelabel.config import (
        GRID_DECAY,
        GRID_DECAY_WITH_DEPTH,
        STEPS,
        TIME_BUDGET,
        time_budget_with_depth,
    )

    plain, with_depth = load_scene(scene), _with_sensor_depth(load_scene(scene))
    auto = {"steps": "auto", "time_budget": "auto"}
    cases = (
        (plain, {"train": auto}, (GRID_DECAY, STEPS, TIME_BUDGET)),
        (with_depth, {"train": auto}, (GRID_DECAY_WITH_DEPTH, STEPS, time_budget_with_depth())),
        (with_depth, {"train": {**auto, "depth_weight": 0.0}}, (GRID_DECAY, STEPS, TIME_BUDGET)),
        (with_depth, {"sampling": {"grid_decay": 0.5}, "train": {"steps": 7, "time_budget": None}}, (0.5, 7, None)),
    )
    assert GRID_DECAY != GRID_DECAY_WITH_DEPTH and TIME_BUDGET != time_budget_with_depth()
    for loaded, overrides, expected in cases:
        trainer, _, _ = prepare_training(loaded, preset("quick", overrides), torch.device("cpu"))
        tc = trainer.config.train
        assert (trainer.config.sampling.grid_decay, tc.steps, tc.time_budget) == expected


def test_the_time_budget_with_depth_is_what_the_build_leaves_after_setup_and_evaluation():
    from scenelabel.config import BUILD_SECONDS_WITH_DEPTH, MIN_TIME_BUDGET, time_budget_with_depth

    assert time_budget_with_depth() == BUILD_SECONDS_WITH_DEPTH
    assert time_budget_with_depth(7.0, 5.5) == pytest.approx(BUILD_SECONDS_WITH_DEPTH - 12.5)
    assert time_budget_with_depth(10 * BUILD_SECONDS_WITH_DEPTH, 1.0) == MIN_TIME_BUDGET  # a long setup still trains


def test_a_build_with_depth_plans_its_training_time_from_its_setup_and_held_out_views(scene, tmp_path):
    """train.time_budget "auto" with sensor depth: the checkpoint records the plan (the build's
    seconds, the setup it measured, what it expects after training) and trains with what they
    leave; a number given is kept and no plan is made."""
    from scenelabel.config import BUILD_SECONDS_WITH_DEPTH, time_budget_with_depth
    from scenelabel.train.evaluation import expected_finish_seconds
    from scenelabel.train.pipeline import choose_views

    loaded = _with_sensor_depth(load_scene(scene))
    _, test, _ = choose_views(loaded, 8)
    output = {"write_map": False, "write_renders": False}
    result = build(loaded, tmp_path / "auto", preset("quick", {"train": {"steps": 2, "time_budget": "auto"}, "output": output}),
                   progress=False)
    plan = result.field.meta["time_plan"]
    assert plan["build_seconds"] == BUILD_SECONDS_WITH_DEPTH
    assert plan["finish_seconds"] == pytest.approx(expected_finish_seconds(loaded.cameras[test], False))
    assert 0 < plan["setup_seconds"] < BUILD_SECONDS_WITH_DEPTH
    assert plan["train_seconds"] == pytest.approx(time_budget_with_depth(plan["setup_seconds"], plan["finish_seconds"]))
    assert result.field.config.train.time_budget == plan["train_seconds"]  # what training read, saved
    given = build(loaded, tmp_path / "given", preset("quick", {"train": {"steps": 2, "time_budget": 30.0}, "output": output}),
                  progress=False)
    assert "time_plan" not in given.field.meta and given.field.config.train.time_budget == 30.0


@pytest.mark.parametrize("share", [0.0, 0.25])
def test_a_step_reopens_the_grid_along_its_worst_coloured_rays(scene, share):
    """A grid emptied before the step (as a refresh emptying a thin object's cells would): with
    ``sampling.grid_reopen`` the step re-opens the cells along its rays of largest colour error, from
    their start to their rendered depth; without it the grid stays empty."""
    config = preset("quick", {
        "sampling": {"n_steps": 32, "grid_resolution": 16, "grid_reopen": share},
        "train": {"steps": 10, "batch_rays": 64},
        "output": {"write_map": False},
    })
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    trainer.grid.update(lambda p: torch.zeros(len(p)), decay=0.0)
    assert trainer.grid.occupied_fraction == 0.0
    trainer.train_step()  # step 0: before the grid's warm-up, no refresh
    opened = int(trainer.grid.bits.sum())
    if share == 0.0:
        assert opened == 0
    else:  # 16 rays' segments through a 16³ grid: at least a cell each, far from all of it
        assert 16 <= opened < 0.5 * trainer.grid.resolution**3


def test_reopen_by_labels_opens_along_the_wrongly_labelled_rays_alone(scene):
    """``sampling.grid_reopen_by`` "labels": of a step's rays, only those whose rendered class is not
    their label's re-open cells (the grid as :meth:`DensityGrid.reopen` along exactly those rays);
    where every ray's class is right, nothing re-opens, whatever the colour error."""
    from types import SimpleNamespace

    config = preset("quick", {"sampling": {"n_steps": 32, "grid_resolution": 16, "grid_reopen": 0.25, "grid_reopen_by": "labels"},
                              "train": {"steps": 10, "batch_rays": 64}})
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    r = trainer.rays
    idx = torch.nonzero(r.channels >= 0).squeeze(1)[:64]
    channels = r.channels[idx]
    n_channels = max(int(r.channels.max()) + 1, 2)
    right = torch.log_softmax(10.0 * torch.nn.functional.one_hot(channels, n_channels).float(), -1)  # every class right
    wrong = torch.tensor([3, 17, 40])
    log_probs = right.clone()
    log_probs[wrong] = right[wrong].roll(1, dims=-1)  # these three render another class
    t_stop = r.t_max[idx]
    depth = 0.5 * (r.t_min[idx] + t_stop)
    out = SimpleNamespace(rgb=torch.zeros(64, 3), depth=depth, class_log_probs=log_probs)
    empty = lambda: trainer.grid.update(lambda p: torch.zeros(len(p)), decay=0.0)  # noqa: E731

    empty()
    trainer._reopen_worst(out, torch.ones(64, 3), idx, t_stop)  # the colour error is 3 on every ray
    opened = trainer.grid.bits.clone()
    empty()
    trainer.grid.reopen(r.origins[idx][wrong], r.directions[idx][wrong], r.t_min[idx][wrong], depth[wrong])
    assert opened.any() and torch.equal(opened, trainer.grid.bits)

    empty()
    trainer._reopen_worst(SimpleNamespace(rgb=out.rgb, depth=depth, class_log_probs=right), torch.ones(64, 3), idx, t_stop)
    assert not trainer.grid.bits.any()


@pytest.mark.parametrize(("n_open", "label_weights"), [(0, "share"), (16, "share"), (16, "balanced"), (16, "geometry")])
def test_open_rays_march_a_grid_the_refreshes_emptied(scene, n_open, label_weights, monkeypatch):
    """``sampling.grid_open_rays``: through a grid emptied before the step, the step's class-balanced
    extra rays still sample (and so give the field a gradient there); without them nothing is
    sampled; past ``sampling.grid_open_until`` of the run they are no longer added. Their colour
    error counts at their class's pixel share (K x share), the regular rays' at 1; their
    cross-entropy too with ``sampling.grid_open_labels`` "share", unweighted with "balanced" and
    "geometry", which composites their classes with detached class logits (density only)."""
    import scenelabel.train.trainer as train

    config = preset("quick", {
        "sampling": {"n_steps": 32, "grid_resolution": 16, "grid_open_rays": n_open, "grid_open_until": 0.5,
                     "grid_open_labels": label_weights},
        "train": {"steps": 10, "batch_rays": 64},
        "output": {"write_map": False},
    })
    trainer, _, _ = prepare_training(load_scene(scene), config, torch.device("cpu"))
    trainer.grid.update(lambda p: torch.zeros(len(p)), decay=0.0)
    weights_seen, label_weights_seen = [], []
    real_mse, real_ce = train.photometric_mse, train.semantic_cross_entropy
    monkeypatch.setattr(train, "photometric_mse", lambda rgb, target, weights=None: weights_seen.append(weights) or real_mse(rgb, target, weights))
    monkeypatch.setattr(train, "semantic_cross_entropy", lambda lp, ch, cw=None, rw=None: label_weights_seen.append(rw) or real_ce(lp, ch, cw, rw))
    geometry_only_seen, real_render = [], train.render_rays
    monkeypatch.setattr(train, "render_rays", lambda *a: geometry_only_seen.append(a[8].geometry_only_labels) or real_render(*a))
    logged = trainer.train_step()  # step 0: before the grid's warm-up, no refresh
    if n_open == 0:
        assert weights_seen == [None] and label_weights_seen == [None]
    else:
        counts = trainer.rays_by_class[1][:, 1].double()
        shares = (len(counts) * counts / counts.sum()).float()
        weights = weights_seen[0]
        assert weights.shape == (80,) and (weights[:64] == 1).all()
        assert all(bool(torch.isclose(w, shares).any()) for w in weights[64:])
        assert torch.equal(label_weights_seen[0], weights) if label_weights == "share" else label_weights_seen == [None]
        opened = torch.arange(80) >= 64
        assert torch.equal(geometry_only_seen[0], opened) if label_weights == "geometry" else geometry_only_seen == [None]
    assert trainer.grid.occupied_fraction == 0.0
    if n_open == 0:
        assert logged["samples_per_ray"] == 0.0
    else:  # 16 of 80 rays march every step of their segment in the box
        assert 0.0 < logged["samples_per_ray"] <= 16 / 80 * trainer.marching.n_samples
    trainer.state.step = 5  # half the run
    assert trainer.train_step()["samples_per_ray"] == 0.0
