"""Gaussian smoothing of rendered class probabilities, label colouring."""

import numpy as np

from scenelabel.postprocess import colorize_labels, side_by_side, smooth_class_probs


def test_smoothing_keeps_sum_and_removes_a_single_pixel_flip():
    probs = np.zeros((9, 9, 3))
    probs[..., 0] = 1.0
    probs[4, 4] = [0.0, 1.0, 0.0]  # one wrong pixel
    out = smooth_class_probs(probs, 1.0)
    np.testing.assert_allclose(out.sum(-1), 1.0)
    assert np.all(out.argmax(-1) == 0)


def test_sigma_zero_is_identity_copy():
    probs = np.random.default_rng(0).dirichlet(np.ones(4), size=(5, 6))
    out = smooth_class_probs(probs, 0)
    np.testing.assert_array_equal(out, probs)
    assert out is not probs


def test_colorize_and_side_by_side():
    labels = np.array([[1, -1], [255, 7]])
    img = colorize_labels(labels, {1: (10, 20, 30)}, ignore_index=255)
    assert img.dtype == np.uint8 and img.shape == (2, 2, 3)
    assert img[0, 0].tolist() == [10, 20, 30] and img[1, 0].tolist() == [0, 0, 0]
    assert img[1, 1].tolist() != img[0, 1].tolist()
    both = side_by_side([img, img], gap=3)
    assert both.shape == (2, 7, 3)
