"""scenelabel.train.evaluation: which held-out views a build draws, and that every held-out view is
scored while only those are drawn."""

import json

import numpy as np
import pytest

from scenelabel import build, load_scene, preset, write_toy_scene
from scenelabel.codes import FREE
from scenelabel.geometry.cameras import Cameras
from scenelabel.train.evaluation import (
    FINISH_SECONDS,
    PANEL_SECONDS,
    PANEL_VIEWS,
    RENDER_SECONDS_PER_MEGAPIXEL,
    expected_finish_seconds,
    panel_views,
)


def test_panel_views_spread_evenly_from_the_first_to_the_last():
    assert panel_views([3, 5, 9]) == [3, 5, 9]  # no more than PANEL_VIEWS: all of them
    test = list(range(0, 150, 8))  # dense-5x4's 19 held-out views
    chosen = panel_views(test)
    assert len(chosen) == PANEL_VIEWS == len(set(chosen))
    assert chosen[0] == test[0] and chosen[-1] == test[-1] and chosen == sorted(chosen)
    gaps = np.diff([test.index(v) for v in chosen])
    assert gaps.max() - gaps.min() <= 1  # evenly spread
    assert panel_views(test, 1) == [test[0]] and panel_views(test, 2) == [test[0], test[-1]]


def test_a_build_scores_every_held_out_view_and_draws_at_most_panel_views(tmp_path):
    n_test = PANEL_VIEWS + 2
    scene = write_toy_scene(tmp_path / "scene", n_train=7 * n_test, n_test=n_test, width=24, height=18)  # every 8th held out
    config = preset("quick", {"train": {"steps": 2}, "output": {"write_map": False}})
    result = build(scene, tmp_path / "out", config, progress=False)
    scored = [v["view"] for v in result.metrics["per_view"]]
    drawn = sorted(p.stem for p in (tmp_path / "out" / "renders").glob("*.png"))
    assert len(scored) == n_test and len(drawn) == PANEL_VIEWS and set(drawn) <= set(scored)
    assert scored[0] in drawn and scored[-1] in drawn
    # each class's held-out pixels: together every labelled held-out pixel; a class with some has an IoU
    loaded = load_scene(scene)
    held_out = [i for i, name in enumerate(loaded.names) if name in scored]
    classes = list(result.metrics["per_class_iou"])
    labelled = sum(int(np.isin(loaded.labels[i], [int(c) for c in classes]).sum()) for i in held_out)
    pixels = result.metrics["per_class_pixels"]
    assert list(pixels) == classes and sum(pixels.values()) == labelled > 0
    assert all(result.metrics["per_class_iou"][c] is not None for c in classes if pixels[c] > 0)


def _cameras(n: int, width: int, height: int) -> Cameras:
    return Cameras.create(np.tile(np.eye(4), (n, 1, 1)), 100.0, 100.0, width / 2, height / 2, width, height)


def test_expected_finish_seconds_count_the_pixels_rendered_and_the_panels_drawn():
    assert expected_finish_seconds(_cameras(0, 160, 120), True) == FINISH_SECONDS  # nothing held out
    three = expected_finish_seconds(_cameras(3, 160, 120), True)
    assert three == pytest.approx(FINISH_SECONDS + 3 * (RENDER_SECONDS_PER_MEGAPIXEL * 0.0192 + PANEL_SECONDS))
    assert expected_finish_seconds(_cameras(3, 160, 120), False) == pytest.approx(three - 3 * PANEL_SECONDS)
    many = expected_finish_seconds(_cameras(19, 160, 120), True)  # every view rendered, PANEL_VIEWS drawn
    assert many == pytest.approx(FINISH_SECONDS + 19 * RENDER_SECONDS_PER_MEGAPIXEL * 0.0192 + PANEL_VIEWS * PANEL_SECONDS)
    assert expected_finish_seconds(_cameras(1, 640, 480), False) == pytest.approx(FINISH_SECONDS + RENDER_SECONDS_PER_MEGAPIXEL * 0.3072)


def test_free_pixels_are_scored_as_a_class_that_rays_without_a_hit_predict(tmp_path):
    """classes.json's free_index marks the toy's backdrop FREE: the held-out scores count FREE as
    one more class ("-1"), on every backdrop pixel, and a short build leaves those rays empty."""
    scene = write_toy_scene(tmp_path / "scene", n_train=14, n_test=2, width=32, height=24)
    classes = json.loads((scene / "classes.json").read_text())
    (scene / "classes.json").write_text(json.dumps({**classes, "ignore_index": None, "free_index": 255}))
    config = preset("quick", {"train": {"steps": 300}, "output": {"write_map": False, "write_renders": False}})
    metrics = build(scene, tmp_path / "out", config, progress=False).metrics
    loaded = load_scene(scene)
    held_out = [loaded.names.index(v["view"]) for v in metrics["per_view"]]
    free_pixels = sum(int(np.sum(loaded.labels[i] == FREE)) for i in held_out)
    assert metrics["per_class_pixels"][str(FREE)] == free_pixels > 0
    assert list(metrics["per_class_iou"])[0] == str(FREE) and str(FREE) not in metrics["spurious_classes"]
    assert metrics["per_class_iou"][str(FREE)] > 0.9, metrics["per_class_iou"]
    assert metrics["miou"] > 0.85, metrics["per_class_iou"]
