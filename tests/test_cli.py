"""The command line: bad inputs exit non-zero with one line naming the problem, no traceback."""

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from scenelabel.synthetic import write_toy_scene


def run_cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "scenelabel", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300
    )


def assert_clean_error(proc, *needles):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("scenelabel: error:")]
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.fixture()
def small_scene(tmp_path):
    return write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)


def test_missing_folder(tmp_path):
    assert_clean_error(run_cli("build", tmp_path / "nope"), "nope")


def test_image_label_size_mismatch(small_scene):
    label = small_scene / "labels" / "001.png"
    Image.fromarray(np.zeros((5, 5), np.uint8)).save(label)
    assert_clean_error(run_cli("build", small_scene, "--steps", "1"), "001.png")


def test_label_id_not_in_classes(small_scene):
    label = small_scene / "labels" / "002.png"
    arr = np.array(Image.open(label))
    arr[0, 0] = 42
    Image.fromarray(arr).save(label)
    assert_clean_error(run_cli("build", small_scene, "--steps", "1"), "42", "002.png")


def test_non_finite_pose(small_scene):
    path = small_scene / "transforms.json"
    data = json.loads(path.read_text())
    data["frames"][3]["transform_matrix"][0][3] = float("nan")
    path.write_text(json.dumps(data))  # writes NaN, which JSON itself does not allow
    assert_clean_error(run_cli("build", small_scene, "--steps", "1"), "transforms.json")


def test_unknown_config_key(small_scene, tmp_path):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"train": {"stepz": 3}}))
    assert_clean_error(run_cli("build", small_scene, "--config", cfg), "stepz")


def test_build_and_export_smoke(small_scene, tmp_path):
    out = tmp_path / "out"
    proc = run_cli("build", small_scene, "--out", out, "--steps", "20", "--preset", "quick", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "held-out" in proc.stdout and "psnr=" in proc.stdout
    proc = run_cli("export", out, tmp_path / "m.zarr", "--zarr-format", "2")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "m.zarr" / ".zgroup").exists()
