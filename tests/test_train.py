"""Training stops cleanly when it goes wrong, and keeps the last good checkpoint."""

import pytest

from scenelabel import TrainingError, build, preset, write_toy_scene
from scenelabel.checkpoint import load_checkpoint

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
    assert load_checkpoint(tmp_path / "out")["step"] < 400  # an earlier checkpoint, not the failed state


def test_non_finite_loss_stops_with_a_clear_message(scene, tmp_path, monkeypatch):
    import scenelabel.train as train

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
    assert load_checkpoint(tmp_path / "out")["step"] == 20
