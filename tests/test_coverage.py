"""geometry.coverage: how many views see each point, against a float64 loop and known values."""

from __future__ import annotations

import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.coverage import THIN_VIEWS, thinly_seen_fraction, views_seeing_points
from scenelabel.geometry.lens import FISHEYE, PINHOLE


def _camera(centre, forward, model=PINHOLE, distortion=(0.0, 0.0, 0.0, 0.0)) -> Cameras:
    """One 64x48 camera at ``centre`` looking along ``forward`` (OpenCV axes, world z up)."""
    z = np.asarray(forward, float) / np.linalg.norm(forward)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = centre
    return Cameras.create(c2w, 40.0, 40.0, 32.0, 24.0, 64, 48, distortion=np.asarray(distortion)[None], model=model)


def _cameras(*cams: Cameras) -> Cameras:
    fields = ("c2w", "fx", "fy", "cx", "cy", "width", "height", "distortion", "near", "far", "model")
    return Cameras(**{f: np.concatenate([getattr(c, f) for c in cams]) for f in fields})


def _reference(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """A float64 loop over points and pinhole cameras: in front, inside [0, w) x [0, h)."""
    out = np.zeros(len(points), int)
    for k, p in enumerate(points):
        for i in range(len(cameras)):
            cam = np.linalg.inv(cameras.c2w[i]) @ np.append(p, 1.0)
            if cam[2] <= 0:
                continue
            a, b = cam[0] / cam[2], cam[1] / cam[2]
            k1, k2, p1, p2 = cameras.distortion[i]
            r2 = a * a + b * b
            radial = 1 + k1 * r2 + k2 * r2 * r2
            a, b = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a), b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
            u, v = cameras.fx[i] * a + cameras.cx[i], cameras.fy[i] * b + cameras.cy[i]
            out[k] += (0 <= u < cameras.width[i]) and (0 <= v < cameras.height[i])
    return out


def test_views_seeing_points_known_values():
    """Two cameras facing each other along x: a point between them is in both images, one
    beside the line of sight in neither, one behind a camera only in the other's image."""
    cams = _cameras(_camera([0.0, 0, 0], [1.0, 0, 0]), _camera([4.0, 0, 0], [-1.0, 0, 0]))
    points = np.array([[2.0, 0.0, 0.0], [2.0, 5.0, 0.0], [-1.0, 0.0, 0.0], [5.0, 0.0, 0.1]])
    assert views_seeing_points(cams, points).tolist() == [2, 0, 1, 1]


def test_views_seeing_points_matches_a_float64_loop():
    rng = np.random.default_rng(0)
    cams = _cameras(*[
        _camera(rng.uniform(-1, 1, 3), rng.normal(size=3) * [1, 1, 0.2], distortion=(0.05 * rng.normal(), 0.01, 0.0, 0.0))
        for _ in range(6)
    ])
    points = rng.uniform(-4, 4, (500, 3))
    got = views_seeing_points(cams, points)
    np.testing.assert_array_equal(got, _reference(cams, points))
    assert 0 < got.sum() < 6 * len(points)


def test_a_fisheye_sees_behind_its_image_plane():
    """A 190-degree fisheye (equidistant, theta_d = theta; the image circle fits 64x48 for fx 10)
    sees a point 95 degrees off its axis; a pinhole looking the same way does not."""
    fisheye = _cameras(Cameras.create(np.eye(4), 10.0, 10.0, 32.0, 24.0, 64, 48, model=FISHEYE))
    pinhole = _cameras(Cameras.create(np.eye(4), 10.0, 10.0, 32.0, 24.0, 64, 48))
    angle = np.deg2rad(95.0)
    point = np.array([[np.sin(angle), 0.0, np.cos(angle)]])
    assert views_seeing_points(fisheye, point).tolist() == [1]
    assert views_seeing_points(pinhole, point).tolist() == [0]


def test_thinly_seen_fraction_and_extremes():
    cams = _cameras(*[_camera([0.0, 0.1 * i, 0], [1.0, 0, 0]) for i in range(THIN_VIEWS)])
    seen_by_all = np.array([[3.0, 0.1, 0.0]])
    seen_by_none = np.array([[-3.0, 0.0, 0.0]])
    assert thinly_seen_fraction(cams, seen_by_all) == 0.0
    assert thinly_seen_fraction(cams, np.concatenate([seen_by_all, seen_by_none])) == 0.5
    assert thinly_seen_fraction(cams, np.zeros((0, 3))) == 1.0
    far = np.array([[1e12, 0.0, 0.0], [1e-9, 0.0, 0.0]])  # very far and very near on the axis: in the image
    assert views_seeing_points(cams[[0]], far).tolist() == [1, 1]
    with pytest.raises(InputError, match=r"points must have shape \[k, 3\]"):
        views_seeing_points(cams, np.zeros((4, 2)))
