"""Data-parallel training (scenelabel.train.distributed, Trainer with DistributedDataParallel) on CPU, gloo."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from conftest import TOY_BUILD_STEPS

from scenelabel.train.distributed import DistContext, backend_for, init_from_env, leave

MIOU_TOLERANCE = 0.02
"""2 processes x 512 rays vs 1 process x 1024 rays per step, same steps: held-out mIoU within this."""

PSNR_TOLERANCE_DB = 1.5


def _flat_state(trainer) -> torch.Tensor:
    params = [p.detach().reshape(-1) for p in trainer.model.parameters()]
    grid = [trainer.grid.density.reshape(-1), trainer.grid.bits.reshape(-1).float()]
    return torch.cat(params + grid)


def _lockstep_worker(rank: int, world_size: int, init_file: str, scene_dir: str, steps: int, out: str) -> None:
    """One rank: train ``steps`` steps and compare parameters and grid with the other rank after each."""
    from scenelabel.config import preset
    from scenelabel.data.io import load_scene
    from scenelabel.train.pipeline import prepare_training

    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world_size)
    context = DistContext(rank=rank, world_size=world_size, owns_group=True)  # leave() ends it, as a build's
    trainer = None
    try:
        # a grid update every 4 steps from step 4 on: the grid is exercised within the few steps
        config = preset("quick", {"train": {"steps": steps, "batch_rays": 256}, "sampling": {"grid_warmup": 4, "grid_update_every": 4}})
        trainer, _, _ = prepare_training(load_scene(scene_dir), config, torch.device("cpu"), context)
        assert isinstance(trainer.render, torch.nn.parallel.DistributedDataParallel)
        assert trainer.batch_rays == 128
        identical, picks_differ = [], []
        for _ in range(steps):
            before = trainer.ray_generator.get_state()
            trainer.train_step()
            # the rays this rank drew at this step, reproduced from its stream
            picks = torch.randint(len(trainer.ray_pool), (trainer.batch_rays,), generator=torch.Generator().set_state(before))
            gathered_picks = [torch.empty_like(picks) for _ in range(world_size)]
            dist.all_gather(gathered_picks, picks)
            picks_differ.append(not torch.equal(gathered_picks[0], gathered_picks[1]))
            state = _flat_state(trainer)
            gathered = [torch.empty_like(state) for _ in range(world_size)]
            dist.all_gather(gathered, state)
            identical.append(all(torch.equal(g, gathered[0]) for g in gathered))
        Path(out).write_text(json.dumps({"identical": identical, "picks_differ": picks_differ, "steps": trainer.state.step}))
        dist.barrier()  # both ranks done before either tears gloo down (a rank leaving early can abort the other)
    finally:
        if trainer is not None:
            trainer.drop_data_parallel()
            assert not isinstance(trainer.render, torch.nn.parallel.DistributedDataParallel)
        leave(context)
        assert not dist.is_initialized()


def test_two_gloo_processes_train_in_lockstep(tmp_path):
    """Parameters and the density grid are bit-identical on both ranks after every step, while
    each rank draws different rays."""
    from scenelabel import write_toy_scene

    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=32, height=24)
    steps = 12
    outs = [str(tmp_path / f"rank{r}.json") for r in range(2)]
    ctx = mp.get_context("spawn")
    procs = [
        ctx.Process(target=_lockstep_worker, args=(r, 2, str(tmp_path / "rendezvous"), str(scene), steps, outs[r]))
        for r in range(2)
    ]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0, 0]
    results = [json.loads(Path(o).read_text()) for o in outs]
    for res in results:
        assert res["steps"] == steps
        assert all(res["identical"])  # bit-identical parameters and grid after each step
        assert all(res["picks_differ"])  # but each rank drew its own rays


def test_a_plain_process_is_world_size_one(monkeypatch):
    for name in ("WORLD_SIZE", "RANK", "LOCAL_RANK"):
        monkeypatch.delenv(name, raising=False)
    context, device = init_from_env(torch.device("cpu"))
    assert context == DistContext() and not context.distributed and context.is_main
    assert device == torch.device("cpu")
    leave(context)  # nothing to leave
    assert not dist.is_initialized()
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert init_from_env(torch.device("cpu"))[0].world_size == 1


def test_backend_follows_the_device():
    assert backend_for(torch.device("cpu")) == "gloo"
    assert backend_for(torch.device("cuda", 0)) == "nccl"


@pytest.mark.slow
def test_torchrun_build_matches_a_single_process_run(toy_build, tmp_path):
    """``torchrun --nproc-per-node 2 -m scenelabel build``: one field trained by 2 gloo processes
    (512 rays each per step) reaches the single-process build's held-out quality (1024 rays per
    step, the same steps: the same total rays) within MIOU_TOLERANCE / PSNR_TOLERANCE_DB, and only
    rank 0 writes."""
    scene = toy_build.out_dir.parent / "scene"
    out = tmp_path / "ddp"
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    cmd = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
        "-m", "scenelabel", "build", str(scene), "--preset", "quick", "--steps", str(TOY_BUILD_STEPS),
        "--out", str(out), "--quiet",
    ]
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.count("held-out") == 1  # rank 0 alone reports
    metrics = json.loads((out / "metrics.json").read_text())
    single = toy_build.metrics
    assert metrics["world_size"] == 2 and metrics["rank"] == 0
    assert metrics["steps"] == single["steps"] == TOY_BUILD_STEPS
    assert metrics["rays_per_step"] == single["rays_per_step"] == 1024
    assert abs(metrics["miou"] - single["miou"]) <= MIOU_TOLERANCE
    assert abs(metrics["psnr"] - single["psnr"]) <= PSNR_TOLERANCE_DB
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "config.json", "map.zarr", "metrics.json", "renders"]
