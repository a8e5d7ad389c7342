"""geometry.coverage: how many views see each point, against a float64 loop and known values."""

from __future__ import annotations

import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.coverage import (
    THIN_VIEWS,
    shows_whole,
    thinly_seen_fraction,
    views_seeing_points,
    visual_hull_points,
)
from scenelabel.geometry.lens import FISHEYE, PINHOLE
from scenelabel.geometry.rays import rays_from_cameras


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


def _pixel(cameras: Cameras, i: int, p: np.ndarray) -> tuple[float, float] | None:
    """Camera i's continuous pixel (u, v) of world point p, a float64 pinhole with OpenCV k1 k2 p1 p2;
    None behind the camera."""
    cam = np.linalg.inv(cameras.c2w[i]) @ np.append(p, 1.0)
    if cam[2] <= 0:
        return None
    a, b = cam[0] / cam[2], cam[1] / cam[2]
    k1, k2, p1, p2 = cameras.distortion[i]
    r2 = a * a + b * b
    radial = 1 + k1 * r2 + k2 * r2 * r2
    a, b = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a), b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return cameras.fx[i] * a + cameras.cx[i], cameras.fy[i] * b + cameras.cy[i]


def _inside(cameras: Cameras, i: int, uv: tuple[float, float] | None) -> bool:
    return uv is not None and 0 <= uv[0] < cameras.width[i] and 0 <= uv[1] < cameras.height[i]


def _reference(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """A float64 loop over points and pinhole cameras: in front, inside [0, w) x [0, h)."""
    return np.array([sum(_inside(cameras, i, _pixel(cameras, i, p)) for i in range(len(cameras))) for p in points])


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


# ------------------------------------------------------------------ the visual hull of silhouettes


def _ring(n: int, radius: float = 4.0, height: float = 1.5) -> Cameras:
    """n cameras on a ring around the origin, above it, each looking at it."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return _cameras(*[
        _camera([radius * np.cos(a), radius * np.sin(a), height], [-np.cos(a), -np.sin(a), -height / radius])
        for a in angles
    ])


def _sphere_silhouettes(cameras: Cameras, centre, radius: float) -> list[np.ndarray]:
    """Each camera's pixels whose centre's ray passes within ``radius`` of ``centre``."""
    out = []
    for i in range(len(cameras)):
        origins, directions = rays_from_cameras(cameras, i)
        to_centre = np.asarray(centre) - origins
        along = np.sum(to_centre * directions, -1)
        miss = np.linalg.norm(to_centre - along[:, None] * directions, axis=-1)
        out.append(((miss <= radius) & (along > 0)).reshape(cameras.height[i], cameras.width[i]))
    return out


def test_the_visual_hull_of_a_sphere_bounds_it_and_little_more():
    centre, radius = np.array([0.2, -0.1, 0.3]), 0.5
    cams = _ring(12)
    silhouettes = _sphere_silhouettes(cams, centre, radius)
    assert all(shows_whole(s) for s in silhouettes)
    box = np.array([[-6.0, -6.0, -4.0], [6.0, 6.0, 5.0]])
    points = visual_hull_points(cams, silhouettes, box)
    lo, hi = points.min(0), points.max(0)
    footprint = 4.5 / 40.0  # a pixel's width at the sphere: the silhouettes' resolution
    assert np.all(lo <= centre - radius + footprint) and np.all(hi >= centre + radius - footprint)  # the sphere
    assert np.all(lo >= centre - 1.5 * radius) and np.all(hi <= centre + 1.5 * radius)  # and not much more
    assert np.all(np.linalg.norm(points - centre, axis=1) < 2 * radius)


def test_visual_hull_points_match_a_float64_loop():
    """One pass of 10³ cells against a loop over cells and views: a cell survives where every view
    sees its centre on a pixel of the silhouette."""
    cams = _ring(5, radius=3.0)
    rng = np.random.default_rng(1)
    silhouettes = [rng.random((48, 64)) < 0.9 for _ in range(5)]
    box = np.array([[-1.0, -1.2, -0.8], [1.1, 0.9, 1.0]])
    got = visual_hull_points(cams, silhouettes, box, cells=10, passes=1)
    size = (box[1] - box[0]) / 10
    expected = []
    for idx in np.ndindex(10, 10, 10):
        p = box[0] + (np.array(idx) + 0.5) * size
        pixels = [_pixel(cams, i, p) for i in range(5)]
        if all(_inside(cams, i, uv) and silhouettes[i][int(np.floor(uv[1])), int(np.floor(uv[0]))]
               for i, uv in enumerate(pixels)):
            expected.append(p)
    assert len(expected) > 0
    np.testing.assert_allclose(got, np.array(expected), atol=1e-12)


def test_a_silhouette_cut_by_the_image_edge_does_not_show_its_object_whole():
    whole = np.zeros((48, 64), bool)
    whole[10:30, 20:40] = True
    assert shows_whole(whole) and not shows_whole(np.ones((48, 64), bool))
    cut = whole.copy()
    cut[10:30, 0:40] = True  # reaches the left edge along 20 of 220 border pixels
    assert not shows_whole(cut)
    with pytest.raises(InputError, match="2 silhouettes for 12 cameras"):
        visual_hull_points(_ring(12), [whole, whole], np.array([[-1.0] * 3, [1.0] * 3]))
    nothing = [np.zeros((48, 64), bool)] * 12
    assert visual_hull_points(_ring(12), nothing, np.array([[-1.0] * 3, [1.0] * 3])) is None
