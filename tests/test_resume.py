"""Nothing lost: a killed build resumes to the same step count; Ctrl-C saves and says how to resume."""

import json
import signal
import subprocess
import sys
import time

import pytest

from scenelabel import SemanticField
from scenelabel.data.synthetic import write_toy_scene
from scenelabel.fields.checkpoint import load_checkpoint

pytestmark = pytest.mark.slow

TOTAL_STEPS = 120
CHECKPOINT_EVERY = 10
WAIT_SECONDS = 240


def start_build(scene, out, *extra):
    args = [sys.executable, "-m", "scenelabel", "build", str(scene), "--out", str(out), "--quiet", *extra]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_checkpoint(proc, path, min_step=1):
    deadline = time.monotonic() + WAIT_SECONDS
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        if path.exists():
            try:
                if load_checkpoint(path).step >= min_step:
                    return
            except Exception:  # being replaced right now: try again
                pass
        time.sleep(0.05)
    raise AssertionError("no checkpoint appeared")


@pytest.fixture()
def scene_and_config(tmp_path):
    scene = write_toy_scene(tmp_path / "scene", n_train=14, n_test=2, width=32, height=24)
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"train": {"checkpoint_every": CHECKPOINT_EVERY}}))
    return scene, cfg


def test_sigkill_then_resume_finishes_with_the_same_step_count(scene_and_config, tmp_path):
    scene, cfg = scene_and_config
    out = tmp_path / "out"
    proc = start_build(scene, out, "--preset", "quick", "--steps", str(TOTAL_STEPS), "--config", str(cfg))
    wait_for_checkpoint(proc, out / "checkpoint.pt", min_step=2 * CHECKPOINT_EVERY)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    killed_at = load_checkpoint(out).step
    assert 0 < killed_at < TOTAL_STEPS
    done = subprocess.run(
        [sys.executable, "-m", "scenelabel", "build", str(scene), "--out", str(out), "--resume", "--quiet"],
        capture_output=True,
        text=True,
        timeout=WAIT_SECONDS,
    )
    assert done.returncode == 0, done.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == TOTAL_STEPS
    assert load_checkpoint(out).step == TOTAL_STEPS
    field = SemanticField.load(out)
    assert field.query_points([[0.0, 0.0, 0.1]]).label.shape == (1,)


def test_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(scene_and_config, tmp_path):
    scene, cfg = scene_and_config
    out = tmp_path / "out"
    proc = start_build(scene, out, "--preset", "quick", "--steps", "100000", "--config", str(cfg))
    wait_for_checkpoint(proc, out / "checkpoint.pt")
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=WAIT_SECONDS)
    assert proc.returncode == 130, stderr
    assert "checkpoint saved" in stderr and "--resume" in stderr and "Traceback" not in stderr
    saved = load_checkpoint(out).step
    assert f"interrupted at step {saved}" in stderr
