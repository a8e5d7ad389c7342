"""Cameras -> rays: pixel centres at +0.5, OpenCV axes, distortion round trip."""

import cv2
import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.rays import (
    camera_directions_from_pixels,
    normalize_directions,
    pixel_centres,
    pixel_grid,
    rays_from_cameras,
)


def test_pixel_grid_centres_row_major():
    g = pixel_grid(3, 2)
    assert g.shape == (6, 2)
    np.testing.assert_array_equal(g[0], [0.5, 0.5])
    np.testing.assert_array_equal(g[2], [2.5, 0.5])
    np.testing.assert_array_equal(g[3], [0.5, 1.5])
    np.testing.assert_array_equal(pixel_centres(np.array([5, 0, 3]), 3), g[[5, 0, 3]])  # the rows they index


def test_principal_point_pixel_looks_forward():
    # a 4x4 image with cx = cy = 2: the corner shared by the 4 central pixels is the axis
    d = camera_directions_from_pixels(np.array([[2.0, 2.0], [3.0, 2.0]]), 2.0, 2.0, 2.0, 2.0)
    np.testing.assert_allclose(d[0], [0, 0, 1])
    np.testing.assert_allclose(d[1], np.array([0.5, 0, 1]) / np.linalg.norm([0.5, 0, 1]))


def test_world_rays_follow_c2w():
    # camera at (1, 2, 3) looking along world +x (OpenCV: z forward -> world x, y down -> world -z)
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float)
    c2w[:3, 3] = [1, 2, 3]
    cams = Cameras.create(c2w, 10.0, 10.0, 5.0, 5.0, 10, 10)
    o, d = rays_from_cameras(cams, 0, np.array([[5.0, 5.0], [5.0, 10.0]]))
    np.testing.assert_allclose(o[0], [1, 2, 3])
    np.testing.assert_allclose(d[0], [1, 0, 0], atol=1e-12)
    # bottom edge of the image (v = 10) looks down (world -z)
    np.testing.assert_allclose(d[1], np.array([1, 0, -0.5]) / np.linalg.norm([1, 0, -0.5]), atol=1e-12)


def test_distorted_pixels_round_trip_through_opencv_projection():
    K = np.array([[300.0, 0, 160], [0, 310.0, 120], [0, 0, 1]])
    dist = np.array([0.0578421, -0.0805099, -0.000980296, 0.00015575])
    rng = np.random.default_rng(0)
    pixels = rng.uniform([0, 0], [320, 240], (50, 2))
    d = camera_directions_from_pixels(pixels, 300.0, 310.0, 160.0, 120.0, dist)
    projected, _ = cv2.projectPoints(d, np.zeros(3), np.zeros(3), K, dist)
    np.testing.assert_allclose(projected.reshape(-1, 2), pixels, atol=1e-3)


def test_normalize_directions_rejects_zero_and_nan():
    unit, norms = normalize_directions(np.array([[3.0, 0, 4.0]]))
    np.testing.assert_allclose(unit, [[0.6, 0, 0.8]])
    assert norms[0] == 5.0
    with pytest.raises(InputError, match="zero-length or non-finite"):
        normalize_directions(np.array([[0.0, 0, 0], [np.nan, 0, 1]]))


def test_row_norms_match_a_float64_loop_and_numpy():
    """sqrt((x² + y²) + z²) per row, as a float64 loop sums it; within an ulp of np.linalg.norm
    (on this machine's numpy, to the bit: rays did not move when they took row_norms)."""
    import math

    from scenelabel.geometry.rays import row_norms

    rng = np.random.default_rng(0)
    vectors = rng.normal(size=(2000, 3)) * rng.uniform(1e-3, 1e3, (2000, 1))
    expected = [math.sqrt((x * x + y * y) + z * z) for x, y, z in vectors]
    np.testing.assert_array_equal(row_norms(vectors), expected)
    np.testing.assert_allclose(row_norms(vectors), np.linalg.norm(vectors, axis=-1), rtol=2e-16, atol=0)
    assert row_norms(np.zeros((0, 3))).shape == (0,)
