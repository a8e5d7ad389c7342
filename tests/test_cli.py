"""The command line end to end (bad inputs: tests/test_bad_inputs.py)."""

import subprocess
import sys

import pytest

from scenelabel.synthetic import write_toy_scene


def run_cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.fixture()
def small_scene(tmp_path):
    return write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)


def test_build_and_export_smoke(small_scene, tmp_path):
    out = tmp_path / "out"
    proc = run_cli("build", small_scene, "--out", out, "--steps", "20", "--preset", "quick", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "held-out" in proc.stdout and "psnr=" in proc.stdout
    proc = run_cli("export", out, tmp_path / "m.zarr", "--zarr-format", "2")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "m.zarr" / ".zgroup").exists()
