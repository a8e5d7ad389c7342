"""Metric scale from sensor depth: poses of arbitrary scale recovered against depth in metres."""

import dataclasses

import numpy as np
import pytest

from scenelabel import load_scene, write_toy_scene
from scenelabel.geometry.depth_scale import scale_from_depth


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return load_scene(write_toy_scene(tmp_path_factory.mktemp("scale") / "s", n_train=14, n_test=2, width=64, height=48))


def _noisy(scene, noise=0.015, seed=0):
    rng = np.random.default_rng(seed)
    return [np.where(d > 0, d * (1 + noise * rng.standard_normal(d.shape)), np.nan) for d in scene.depths]


@pytest.mark.parametrize("factor", [1.0, 0.37, 25.0, 1e-3])
def test_scale_of_shrunk_or_grown_poses_is_recovered_from_noisy_depth(scene, factor):
    depths = _noisy(scene)  # metres: the scene as written
    s = scale_from_depth(scene.scaled(factor).cameras, depths)
    assert s is not None and s * factor == pytest.approx(1.0, rel=0.01)


def test_holes_do_not_bias_the_scale(scene):
    rng = np.random.default_rng(1)
    depths = [np.where(rng.random(d.shape) < 0.4, np.nan, d) for d in _noisy(scene)]  # 40 % holes
    depths[3] = None  # and a view without depth
    s = scale_from_depth(scene.scaled(3.0).cameras, depths)
    assert s * 3.0 == pytest.approx(1.0, rel=0.01)


def test_a_few_pairs_of_a_long_sequence_still_recover_the_scale(scene):
    # the search is capped at max_pairs view pairs (MAX_PAIRS for long captures): 3 of the toy's 32
    s = scale_from_depth(scene.scaled(0.37).cameras, _noisy(scene), max_pairs=3)
    assert s * 0.37 == pytest.approx(1.0, rel=0.01)


def test_cameras_that_only_rotate_cannot_tell_the_scale(scene):
    c2w = scene.cameras.c2w.copy()
    c2w[:, :3, 3] = c2w[0, :3, 3]
    assert scale_from_depth(dataclasses.replace(scene.cameras, c2w=c2w), _noisy(scene)) is None


def test_fewer_than_two_views_with_depth_give_no_answer(scene):
    depths = [None] * len(scene)
    assert scale_from_depth(scene.cameras, depths) is None
    depths[0] = scene.depths[0]
    assert scale_from_depth(scene.cameras, depths) is None
