"""Training stops cleanly when it goes wrong, and keeps the last good checkpoint; NeRF's coarse
and fine networks train together and resume together."""

import numpy as np
import pytest
import torch

from scenelabel import SemanticField, TrainingError, build, load_scene, preset, write_toy_scene
from scenelabel.errors import ConfigError
from scenelabel.fields.checkpoint import load_checkpoint
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.train.losses import total_variation
from scenelabel.train.pipeline import prepare_training

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("train") / "scene", n_train=14, n_test=2, width=32, height=24)


def test_learning_rate_100x_too_high_is_detected(scene, tmp_path):
    base = preset("quick").train
    config = preset(
        "quick",
        {
            "train": {"steps": 400, "lr_encoding": 100 * base.lr_encoding, "lr_mlp": 100 * base.lr_mlp, "checkpoint_every": 50},
            "output": {"write_map": False, "write_renders": False},
        },
    )
    with pytest.raises(TrainingError, match="diverged.*learning rate") as info:
        build(scene, tmp_path / "out", config, progress=False)
    assert "last checkpoint before the failure is kept" in str(info.value)
    assert load_checkpoint(tmp_path / "out").step < 400  # an earlier checkpoint, not the failed state


def test_non_finite_loss_stops_with_a_clear_message(scene, tmp_path, monkeypatch):
    import scenelabel.train.trainer as train

    real = train.photometric_mse
    calls = {"n": 0}

    def poisoned(rgb, target):
        calls["n"] += 1
        return real(rgb, target) * (float("nan") if calls["n"] > 20 else 1.0)

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
