"""Many scenes: build_many as independent jobs, one after another and on a Dask LocalCluster; the CLI."""

import json
import os
import shutil
import subprocess
import sys
import warnings

import pytest
import torch

from scenelabel import SceneOutcome, build_many, preset, write_toy_scene
from scenelabel.cli import main
from scenelabel.config import config_to_dict
from scenelabel.errors import ConfigError, InputError
from scenelabel.train.batch import LOG_NAME, SUMMARY_JSON, SUMMARY_MD, _ProgressLines, out_dirs_for, summary_table

STEPS = 6
TINY = {  # a few seconds per scene on a busy 2-core CPU
    "field": {"resolutions": (16, 32), "hidden": 16},
    "sampling": {"n_steps": 48, "grid_resolution": 16, "grid_warmup": 2, "grid_update_every": 4},
    "train": {"steps": STEPS, "batch_rays": 256},
    "output": {"write_map": False, "write_renders": False},
}
CONFIG = preset("quick", TINY)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Two small toy scenes, ``alpha`` (with labels) and ``beta`` (without: a photometric build that
    warns), and ``broken`` (a transforms.json that is not JSON)."""
    root = tmp_path_factory.mktemp("scenes")
    alpha = write_toy_scene(root / "alpha", n_train=7, n_test=1, width=24, height=18)
    beta = write_toy_scene(root / "beta", n_train=7, n_test=1, width=24, height=18, seed=1)
    shutil.rmtree(beta / "labels")
    (beta / "classes.json").unlink()
    transforms = json.loads((beta / "transforms.json").read_text())
    for frame in transforms["frames"]:
        del frame["label_path"]
    (beta / "transforms.json").write_text(json.dumps(transforms))
    broken = root / "broken"
    (broken / "images").mkdir(parents=True)
    (broken / "transforms.json").write_text('{"frames": [')
    return {"alpha": alpha, "broken": broken, "beta": beta}


@pytest.fixture(scope="module")
def serial(scenes, tmp_path_factory):
    """build_many of alpha, broken, beta in this process: (outcomes, out root).

    Trained with one torch thread, as a Dask worker does (OMP_NUM_THREADS=1): on a busy 2-core CPU
    two threads per build are many times slower."""
    out_root = tmp_path_factory.mktemp("serial") / "builds"
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        outcomes = build_many(list(scenes.values()), out_root, CONFIG)
    finally:
        torch.set_num_threads(before)
    return outcomes, out_root


@pytest.fixture(scope="module")
def on_cluster(scenes, client, tmp_path_factory):
    """The scenes of ``serial`` as tasks on the LocalCluster: (outcomes, out root)."""
    out_root = tmp_path_factory.mktemp("cluster") / "builds"
    outcomes = build_many([str(p) for p in scenes.values()], out_root, config_to_dict(CONFIG), client=client)
    return outcomes, out_root


def run_cli(*args):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # see the serial fixture
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], check=False, capture_output=True, text=True, timeout=300, env=env
    )


def test_out_dirs_are_named_after_the_scene_folders_and_never_shared(tmp_path):
    root = tmp_path / "out"
    scenes = [tmp_path / "a" / "room", tmp_path / "b" / "room", tmp_path / "hall", tmp_path / "a" / "room"]
    assert out_dirs_for(scenes, root) == [root / "room", root / "room_2", root / "hall", root / "room_3"]
    assert out_dirs_for(scenes, None) == [
        tmp_path / "a" / "room" / "scenelabel",
        tmp_path / "b" / "room" / "scenelabel",
        tmp_path / "hall" / "scenelabel",
        tmp_path / "a" / "room" / "scenelabel_2",
    ]
    assert out_dirs_for([tmp_path / "summary.json"], root) == [root / "summary.json_2"]  # the summary's name is taken


def test_progress_bar_becomes_a_few_log_lines():
    lines = []
    stream = _ProgressLines(lines.append, every=3600.0)
    for text in ("\r  0%|", "\r 50%|", "\r 90%|   ", "\r100%|\n", "\rtime budget reached\n", "\r 10%|"):
        stream.write(text)
    stream.close()
    assert lines == ["  0%|", "100%|", "time budget reached", " 10%|"]  # the first state, every finished line, the last


def test_bad_batch_arguments_fail_up_front_and_a_missing_folder_is_not_created(tmp_path):
    with pytest.raises(InputError, match="no scene folders"):
        build_many([], tmp_path / "out", CONFIG)
    with pytest.raises(ConfigError, match="unknown train config key"):
        build_many([tmp_path], tmp_path / "out", {"train": {"stepz": 3}})
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="cannot create the output folder"):
        build_many([tmp_path], tmp_path / "file" / "out", CONFIG)
    missing = tmp_path / "missing"
    [outcome] = build_many([missing], None, CONFIG)  # out dir missing/scenelabel: no folder, no log
    assert not outcome.ok and outcome.error_type == "InputError" and "scene folder not found" in outcome.error
    assert outcome.log is None and not missing.exists()
    assert "InputError: " in summary_table([outcome]) and "failed" in summary_table([outcome])


@pytest.mark.slow
def test_serial_builds_the_good_scenes_and_reports_the_broken_one(serial, scenes):
    outcomes, out_root = serial
    assert [o.scene for o in outcomes] == [str(p) for p in scenes.values()]
    assert all(isinstance(o, SceneOutcome) for o in outcomes)
    alpha, broken, beta = outcomes
    assert [o.status for o in outcomes] == ["ok", "failed", "ok"]
    assert [o.out_dir for o in outcomes] == [out_root / "alpha", out_root / "broken", out_root / "beta"]
    for good in (alpha, beta):
        assert (good.out_dir / "checkpoint.pt").is_file() and (good.out_dir / "metrics.json").is_file()
        assert not (good.out_dir / "map.zarr").exists()  # output.write_map off
        assert good.metrics["steps"] == STEPS and good.metrics["psnr"] > 5 and good.error is None
        log = (good.out_dir / LOG_NAME).read_text()
        assert f"{STEPS}/{STEPS}" in log and "finished in" in log and "Traceback" not in log
    assert 0 <= alpha.metrics["miou"] <= 1 and "miou" not in beta.metrics  # beta has no labels
    # the job's warnings go to its own log, not to the other scenes'
    assert any("no labels in the training views" in w for w in beta.warnings)
    assert "warning: UserWarning: no labels in the training views" in (beta.out_dir / LOG_NAME).read_text()
    assert not any("no labels" in w for w in alpha.warnings)
    assert "no labels" not in (alpha.out_dir / LOG_NAME).read_text()

    assert broken.error_type == "InputError" and "invalid JSON" in broken.error and "transforms.json" in broken.error
    assert broken.metrics == {} and broken.log == out_root / "broken" / LOG_NAME
    log = broken.log.read_text()
    assert "failed after" in log and "Traceback (most recent call last)" in log
    assert "scenelabel.errors.InputError:" in log and "invalid JSON" in log
    assert not (broken.out_dir / "checkpoint.pt").exists()

    summary = json.loads((out_root / SUMMARY_JSON).read_text())
    assert (summary["n_scenes"], summary["n_ok"], summary["n_failed"]) == (3, 2, 1)
    assert [s["status"] for s in summary["scenes"]] == ["ok", "failed", "ok"]
    assert summary["scenes"][1]["error_type"] == "InputError" and "invalid JSON" in summary["scenes"][1]["error"]
    assert summary["scenes"][1]["log"] == str(broken.log)
    assert summary["scenes"][0]["metrics"]["psnr"] == pytest.approx(alpha.metrics["psnr"])
    table = (out_root / SUMMARY_MD).read_text()
    assert "# scenelabel build: 2 of 3 scenes built" in table
    rows = [line for line in table.splitlines() if line.startswith("|")]
    assert [c.strip() for c in rows[0].strip("|").split("|")] == [
        "scene", "status", "steps", "train s", "PSNR", "mIoU", "out dir / error"
    ]
    cells = {row.split("|")[1].strip(): [c.strip() for c in row.strip("|").split("|")] for row in rows[2:]}
    assert cells[str(scenes["alpha"])][1:3] == ["ok", str(STEPS)]
    assert cells[str(scenes["alpha"])][4] == f"{alpha.metrics['psnr']:.2f}"
    assert cells[str(scenes["beta"])][5] == "-" and "1 warning" in cells[str(scenes["beta"])][6]
    assert cells[str(scenes["broken"])][1:6] == ["failed", "-", "-", "-", "-"]
    assert cells[str(scenes["broken"])][6].startswith("InputError: ") and str(broken.log) in cells[str(scenes["broken"])][6]


@pytest.mark.slow
def test_local_cluster_gives_the_same_outcomes_and_writes_each_checkpoint(on_cluster, serial):
    outcomes, out_root = on_cluster
    expected, _ = serial
    assert [o.scene for o in outcomes] == [o.scene for o in expected]
    assert [o.status for o in outcomes] == [o.status for o in expected] == ["ok", "failed", "ok"]
    assert [o.error_type for o in outcomes] == [None, "InputError", None]
    for got, want in zip(outcomes, expected):
        assert got.out_dir == out_root / want.out_dir.name
        assert got.log == got.out_dir / LOG_NAME and got.log.is_file()
        if want.ok:
            assert (got.out_dir / "checkpoint.pt").is_file()
            assert got.metrics["steps"] == STEPS
            # one thread in both: a build is deterministic for a seed, wherever it runs
            assert got.metrics["psnr"] == pytest.approx(want.metrics["psnr"], abs=1e-4)
        else:
            assert got.error == want.error
            assert "Traceback (most recent call last)" in got.log.read_text()
    assert any("no labels" in w for w in outcomes[2].warnings) and not outcomes[0].warnings
    summary = json.loads((out_root / SUMMARY_JSON).read_text())
    assert [s["status"] for s in summary["scenes"]] == ["ok", "failed", "ok"]


@pytest.mark.slow
def test_cli_with_several_scenes_prints_the_table_and_exits_1_when_one_failed(scenes, tmp_path):
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps({k: v for k, v in TINY.items() if k != "train"}))
    out = tmp_path / "builds"
    proc = run_cli(
        "build", scenes["alpha"], scenes["broken"], "--out", out, "--preset", "quick", "--steps", STEPS,
        "--config", config, "--quiet",
    )
    assert proc.returncode == 1, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("| scene ") and "| status |" in lines[0]
    assert any(line.startswith(f"| {scenes['alpha']} ") and "| ok " in line for line in lines)
    assert any(line.startswith(f"| {scenes['broken']} ") and "| failed " in line and "invalid JSON" in line for line in lines)
    assert lines[-1] == f"built 1 of 2 scenes, 1 failed; summary: {out / SUMMARY_MD}"
    assert (out / "alpha" / "checkpoint.pt").is_file() and (out / "broken" / LOG_NAME).is_file()
    assert json.loads((out / "alpha" / "config.json").read_text())["field"]["hidden"] == 16  # --config reached the job
    assert (out / SUMMARY_MD).read_text().count("| failed ") == 1


@pytest.mark.slow
def test_cli_workers_runs_the_scenes_on_a_local_cluster(scenes, tmp_path):
    out = tmp_path / "builds"
    proc = run_cli("build", scenes["broken"], tmp_path / "missing", "--out", out, "--workers", "1", "--quiet")
    assert proc.returncode == 1, proc.stderr
    assert proc.stdout.count("| failed ") == 2 and "scene folder not found" in proc.stdout
    assert proc.stdout.splitlines()[-1].startswith("built 0 of 2 scenes, 2 failed")
    assert (out / "missing" / LOG_NAME).is_file() and (out / SUMMARY_JSON).is_file()


@pytest.mark.slow
def test_cli_scheduler_sends_the_scenes_to_a_running_cluster(scenes, client, tmp_path):
    out = tmp_path / "builds"
    proc = run_cli("build", scenes["broken"], scenes["broken"], "--out", out, "--scheduler", client.scheduler.address)
    assert proc.returncode == 1, proc.stderr
    assert f"sent 2 scenes to the Dask cluster at {client.scheduler.address}" in proc.stderr  # progress: not --quiet
    assert proc.stdout.count("| failed ") == 2 and (out / "broken_2" / LOG_NAME).is_file()


def test_cli_user_errors_with_several_scenes_are_one_line(scenes, capsys, monkeypatch):
    import dask

    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)  # main() sets its own
    for extra, message in (
        (["--resume"], "--resume and --segmenter take one scene folder"),
        (["--segmenter", "python:x.py:seg"], "--resume and --segmenter take one scene folder"),
        (["--workers", "0"], "--workers: must be at least 1, got 0"),
    ):
        assert main(["build", str(scenes["alpha"]), str(scenes["beta"]), *extra]) == 2
        [line] = capsys.readouterr().err.strip().splitlines()  # one line, no traceback
        assert line.startswith(f"scenelabel: error: {message}")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert main(["build", str(scenes["alpha"]), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("scenelabel: error: cannot connect to the Dask scheduler at tcp://127.0.0.1:9")
    with pytest.raises(SystemExit) as exc:
        main(["build", str(scenes["alpha"]), "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"])
    assert exc.value.code == 2 and "not allowed with argument" in capsys.readouterr().err
