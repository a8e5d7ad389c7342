"""Checkpoints (format 2): a dataclass saved as tensors + JSON, read without running pickled code;
format-1 (pickled) files are refused with the command that converts them, which converts them."""

import math
import pathlib

import numpy as np
import pytest
import torch

from scenelabel import CheckpointError, SemanticField, build, preset, write_toy_scene
from scenelabel.cli import main
from scenelabel.fields.checkpoint import (
    CHECKPOINT_NAME,
    FORMAT,
    FORMAT_VERSION,
    Checkpoint,
    load_checkpoint,
    save_checkpoint,
)


def assert_same(a, b, where="checkpoint"):
    """Equal, tensors included (same dtype, same values), containers compared entry by entry."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype, where
        torch.testing.assert_close(a, b, rtol=0, atol=0, msg=where)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b)), where


def small_checkpoint() -> Checkpoint:
    torch.manual_seed(0)
    model, coarse = torch.nn.Linear(3, 4), torch.nn.Linear(3, 2)
    optimizer = torch.optim.Adam([*model.parameters(), *coarse.parameters()], lr=1e-2, betas=(0.9, 0.99))
    model(torch.ones(2, 3)).sum().backward()
    optimizer.step()
    generator = torch.Generator().manual_seed(3)
    torch.rand(5, generator=generator)
    return Checkpoint(
        model=model.state_dict(),
        occupancy={"density": torch.rand(4, 4, 4), "mask": torch.rand(4, 4, 4) > 0.5},
        meta={
            "config": {"train": {"steps": 5, "time_budget": None}, "preset": "quick"},
            "class_map": {"ids": [1, 3], "names": ["floor", "box"], "ignore_index": None},
            "aabb_world": [[-1.0, -1.0, 0.0], [1.0, 1.0, 0.5]],
            "warp": {"kind": "forward", "near": 0.1, "far": math.inf},
            "class_colors": {"1": [190, 170, 130]},
            "train_views": ["a", "b"],
        },
        coarse_model=coarse.state_dict(),
        optimizer=optimizer.state_dict(),
        step=7,
        elapsed=1.25,
        history=[{"step": 5, "loss": 0.5, "psnr": 12.0, "time": 1.0}],
        generator=generator.get_state(),
    )


def test_round_trip_gives_every_field_back(tmp_path):
    ckpt = small_checkpoint()
    path = save_checkpoint(tmp_path / "build" / CHECKPOINT_NAME, ckpt)
    assert sorted(p.name for p in path.parent.iterdir()) == [CHECKPOINT_NAME]  # no temp file left
    got = load_checkpoint(tmp_path / "build")
    assert isinstance(got, Checkpoint)
    for name in ckpt.__dataclass_fields__:
        assert_same(getattr(ckpt, name), getattr(got, name), name)
    # what the file holds: tensors, plain data and one JSON string, under the format header
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == FORMAT and raw["format_version"] == FORMAT_VERSION == 2
    assert isinstance(raw["json"], str) and "meta" not in raw
    # optional entries may be left out
    bare = Checkpoint(model=ckpt.model, occupancy=ckpt.occupancy)
    got = load_checkpoint(save_checkpoint(tmp_path / "bare.pt", bare))
    assert got.coarse_model is None and got.optimizer is None and got.generator is None and got.meta == {}
    assert set(got.training_state()) == {"model", "occupancy", "step", "elapsed", "history"}


class TouchesAFile:
    """Pickled, it asks the unpickler to create ``marker`` (any code could run the same way)."""

    def __init__(self, marker):
        self.marker = pathlib.Path(marker)

    def __reduce__(self):
        return (pathlib.Path.touch, (self.marker,))


def test_a_file_whose_pickle_runs_code_is_refused_and_nothing_runs(tmp_path):
    marker = tmp_path / "marker"
    path = tmp_path / CHECKPOINT_NAME
    torch.save({"format": FORMAT, "format_version": FORMAT_VERSION, "json": TouchesAFile(marker)}, path)
    with pytest.raises(CheckpointError, match="refused") as info:
        load_checkpoint(tmp_path)
    assert not marker.exists()
    assert "\n" not in str(info.value)
    with pytest.raises(CheckpointError, match="refused"):
        SemanticField.load(path)
    assert not marker.exists()
    # a file that is no torch file at all, and one that lacks entries
    path.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="unreadable") as info:
        load_checkpoint(path)
    assert "\n" not in str(info.value)
    torch.save({"format": FORMAT, "format_version": FORMAT_VERSION, "step": 1}, path)
    with pytest.raises(CheckpointError, match="incomplete"):
        load_checkpoint(path)


@pytest.fixture(scope="module")
def tiny_build(tmp_path_factory):
    root = tmp_path_factory.mktemp("ckpt")
    scene = write_toy_scene(root / "scene", n_train=6, n_test=1, width=16, height=12)
    config = preset("quick", {"train": {"steps": 5}, "output": {"write_map": False, "write_renders": False}})
    return build(scene, root / "out", config, progress=False)


def write_format_1(ckpt: Checkpoint, path, **extra) -> None:
    """A checkpoint as scenelabel wrote it before format 2: one pickled dict (int class-colour keys)."""
    meta = dict(ckpt.meta, class_colors={int(k): v for k, v in ckpt.meta["class_colors"].items()}, **extra)
    torch.save({"format": FORMAT, "format_version": 1, "scenelabel_version": "0.1.0", **meta, **ckpt.training_state()}, path)


@pytest.mark.slow
def test_a_format_1_checkpoint_names_the_upgrade_and_the_upgrade_converts_it(tiny_build, tmp_path, capsys):
    current = load_checkpoint(tiny_build.out_dir)
    old = tmp_path / "old"
    old.mkdir()
    write_format_1(current, old / CHECKPOINT_NAME)
    with pytest.raises(CheckpointError, match="format version 1") as info:
        load_checkpoint(old)
    message = str(info.value)
    assert f"scenelabel upgrade-checkpoint {old / CHECKPOINT_NAME}" in message and "\n" not in message

    assert main(["upgrade-checkpoint", str(old)]) == 0
    assert "converted" in capsys.readouterr().out
    got = load_checkpoint(old)
    for name in current.__dataclass_fields__:
        assert_same(getattr(current, name), getattr(got, name), name)
    assert sorted(p.name for p in old.iterdir()) == [CHECKPOINT_NAME]  # rewritten in place, atomically
    field = SemanticField.load(old, device="cpu")
    points = np.array([[0.0, 0.0, 0.1], [0.3, -0.2, 0.2]])
    np.testing.assert_array_equal(field.query_points(points).density, tiny_build.field.query_points(points).density)
    assert field.meta["class_colors"] == tiny_build.field.meta["class_colors"]
    # once more: nothing to do
    assert main(["upgrade-checkpoint", str(old / CHECKPOINT_NAME)]) == 0
    assert "nothing to do" in capsys.readouterr().out


@pytest.mark.slow
def test_a_format_1_checkpoint_with_numpy_values_is_refused_then_converted(tiny_build, tmp_path, capsys):
    """Format 1 could hold numpy values, which the restricted unpickler refuses: the message still
    names the upgrade, and the upgrade turns them into JSON."""
    current = load_checkpoint(tiny_build.out_dir)
    path = tmp_path / CHECKPOINT_NAME
    write_format_1(current, path, world_scale=np.float64(2.0), points_aabb=np.zeros((2, 3)))
    with pytest.raises(CheckpointError, match="refused.*scenelabel upgrade-checkpoint"):
        load_checkpoint(path)
    assert main(["upgrade-checkpoint", str(path)]) == 0
    got = load_checkpoint(path)
    assert got.meta["world_scale"] == 2.0 and got.meta["points_aabb"] == [[0.0] * 3] * 2
    assert got.step == current.step


def test_upgrade_refuses_what_it_does_not_convert(tmp_path, capsys):
    torch.save({"format": FORMAT, "format_version": 999}, tmp_path / CHECKPOINT_NAME)
    assert main(["upgrade-checkpoint", str(tmp_path)]) == 2
    assert "only format 1 is converted" in capsys.readouterr().err
    assert main(["upgrade-checkpoint", str(tmp_path / "missing")]) == 2
    assert "no checkpoint" in capsys.readouterr().err
