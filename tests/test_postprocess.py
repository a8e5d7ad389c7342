"""Gaussian smoothing of rendered class probabilities, label colouring."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from scenelabel.errors import InputError
from scenelabel.query.postprocess import (
    IGNORE_COLOR,
    NO_CLASS_COLOR,
    colorize_labels,
    default_color,
    side_by_side,
    smooth_class_probs,
)


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


def test_smoothing_of_a_distribution_is_the_plain_filter():
    probs = np.random.default_rng(5).dirichlet(np.ones(3), size=(10, 12))  # sums to 1 already
    out = smooth_class_probs(probs, 1.5)
    for c in range(3):
        np.testing.assert_allclose(out[..., c], gaussian_filter(probs[..., c], 1.5, mode="nearest"), atol=1e-12)


def test_smoothing_keeps_dtype_and_sum_for_unnormalised_input():
    probs = np.random.default_rng(6).uniform(size=(7, 8, 4)).astype(np.float32)
    out = smooth_class_probs(probs, 2.0)
    assert out.dtype == np.float32 and out.shape == probs.shape
    np.testing.assert_allclose(out.sum(-1), 1.0, atol=1e-6)


def test_per_axis_sigma_and_none():
    probs = np.zeros((5, 9, 2))
    probs[..., 0] = 1.0
    probs[:, 4] = [0.0, 1.0]  # a vertical line of class 1
    along_cols_only = smooth_class_probs(probs, (0.0, 1.0))
    np.testing.assert_allclose(along_cols_only, along_cols_only[:1].repeat(5, 0))  # rows untouched
    along_rows_only = smooth_class_probs(probs, (1.0, 0.0))
    np.testing.assert_allclose(along_rows_only, probs)  # constant along rows: unchanged
    np.testing.assert_array_equal(smooth_class_probs(probs, None), probs)
    with pytest.raises(InputError):
        smooth_class_probs(probs, -1.0)
    with pytest.raises(InputError):
        smooth_class_probs(probs[..., 0], 1.0)


def test_colorize_codes_and_default_palette():
    labels = np.array([[-1, -2, 255, 3, 4, 12]])
    img = colorize_labels(labels, {"12": (1, 2, 3)}, ignore_index=255)  # JSON-style str key
    assert img[0, 0].tolist() == list(NO_CLASS_COLOR) and img[0, 1].tolist() == list(NO_CLASS_COLOR)
    assert img[0, 2].tolist() == list(IGNORE_COLOR)
    assert img[0, 3].tolist() == list(default_color(3)) and img[0, 5].tolist() == [1, 2, 3]
    assert default_color(3) == default_color(3)
    assert len({default_color(i) for i in range(20)}) == 20


def test_side_by_side_pads_and_checks():
    a = np.zeros((4, 3, 3), np.uint8)
    b = np.full((2, 5), 7, np.uint8)  # grey, shorter
    out = side_by_side([a, b], gap=1)
    assert out.shape == (4, 9, 3) and out.dtype == np.uint8
    assert np.all(out[:, 3] == 255) and np.all(out[2:, 4:] == 255) and np.all(out[:2, 4:] == 7)
    with pytest.raises(InputError):
        side_by_side([])
    with pytest.raises(InputError):
        side_by_side([a.astype(np.float32)])
