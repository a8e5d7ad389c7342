"""scenelabel.geometry.vanishing: the vertical from the photos' straight lines."""

from __future__ import annotations

import numpy as np
import pytest

from scenelabel import load_scene, write_furnished_room
from scenelabel.data.synthetic.views import look_at
from scenelabel.geometry.cameras import Cameras, opengl_to_opencv
from scenelabel.geometry.lens import project_points
from scenelabel.geometry.vanishing import (
    MAX_SIDE,
    MIN_VERTICAL_SEGMENTS,
    MIN_VERTICAL_VIEWS,
    line_segments,
    segment_normals,
    segments_at_most,
    vertical_from_images,
    vertical_from_normals,
)

W, H, F = 160, 120, 140.0


def _degrees(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def _cameras(n: int, up: np.ndarray, rng: np.random.Generator, distortion=None) -> Cameras:
    """n cameras near the origin looking at random points 3 m away, pitched up to 15 degrees, with
    ``up`` as the world's vertical."""
    c2w = []
    for _ in range(n):
        eye = rng.uniform(-0.5, 0.5, 3)
        az = rng.uniform(0, 2 * np.pi)
        target = eye + 3.0 * np.array([np.cos(az), np.sin(az), np.tan(np.radians(rng.uniform(-15, 15)))])
        c2w.append(opengl_to_opencv(look_at(eye, target)))
    c2w = np.stack(c2w)
    rotation = _rotation_taking_z_to(up)
    c2w[:, :3, :] = rotation @ c2w[:, :3, :]
    return Cameras.create(c2w, F, F, W / 2, H / 2, W, H, distortion=distortion)


def _rotation_taking_z_to(up: np.ndarray) -> np.ndarray:
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, up)
    s, c = np.linalg.norm(axis), float(z @ up)
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def _segments_of(cameras: Cameras, index: int, lines: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """[k, 4] the world segments ``lines`` (endpoint pairs) as projected by camera ``index``, where
    both endpoints land in its image."""
    out = []
    cam = cameras[index]
    for a, b in lines:
        uv, z, _ = project_points(np.stack([a, b]), cam.c2w[0], F, F, W / 2, H / 2, cam.distortion[0])
        if (z > 0.1).all() and np.isfinite(uv).all() and ((uv >= 0) & (uv <= [W, H])).all():
            out.append(uv.ravel())
    return np.array(out).reshape(-1, 4)


def test_line_segments_finds_an_edge_at_its_pixel_coordinates():
    """A dark square on a light ground, its left edge at u = 40 (the boundary between columns 39
    and 40, pixel centres at + 0.5): one segment along it, within a quarter pixel, about as long."""
    image = np.full((H, W, 3), 0.9)
    image[30:90, 40:100] = 0.1
    segments = line_segments(image)
    vertical = segments[np.abs(segments[:, 0] - segments[:, 2]) < 1.0]
    near = vertical[np.abs(vertical[:, 0] - 40.0) < 0.25]  # at whole-number centres it would be 39.5
    assert len(near) == 1
    assert np.abs(np.sort(near[0, [1, 3]]) - [30.0, 90.0]).max() < 2.0
    assert line_segments(np.full((H, W), 0.5)).shape == (0, 4)  # flat: none


def test_a_large_photos_segments_are_found_shrunk_and_given_in_its_own_pixels():
    """The same square at 1280x960 (its left edge at u = 320): found in the photo shrunk to
    MAX_SIDE, given back within half a pixel of the edge at full size, about as long."""
    image = np.full((960, 1280, 3), 0.9)
    image[240:720, 320:800] = 0.1
    segments = segments_at_most(image)
    assert MAX_SIDE < 1280
    left = segments[(np.abs(segments[:, 0] - segments[:, 2]) < 2.0) & (np.abs(segments[:, 0] - 320.0) < 0.5)]
    assert len(left) == 1 and np.abs(np.sort(left[0, [1, 3]]) - [240.0, 720.0]).max() < 6.0
    corner = image[200:440, 280:600]  # 320 pixels wide, a corner of the square: as it is
    assert len(line_segments(corner)) >= 2 and np.array_equal(segments_at_most(corner), line_segments(corner))


def test_segment_normals_match_a_naive_cross_product():
    rng = np.random.default_rng(0)
    cameras = _cameras(3, np.array([0.0, 0.0, 1.0]), rng)
    segments = [rng.uniform([0, 0, 0, 0], [W, H, W, H], (5, 4)) for _ in range(3)]
    segments[1] = np.zeros((0, 4))  # a view without segments
    normals, weights, views = segment_normals(cameras, segments)
    assert normals.shape == (10, 3) and list(views) == [0] * 5 + [2] * 5
    k = 0
    for i in (0, 2):
        K_inv = np.linalg.inv(np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]]))
        for s in segments[i]:
            a = cameras.c2w[i, :3, :3] @ (K_inv @ np.array([s[0], s[1], 1.0]))
            b = cameras.c2w[i, :3, :3] @ (K_inv @ np.array([s[2], s[3], 1.0]))
            n = np.cross(a, b)
            assert _degrees(normals[k], n) < 1e-9 and abs(weights[k] - np.hypot(s[2] - s[0], s[3] - s[1])) < 1e-9
            k += 1


@pytest.mark.parametrize("distortion", [None, [-0.2, 0.05, 0.001, -0.001]])
def test_vertical_from_normals_finds_the_lines_vertical_among_others(distortion):
    """Vertical lines about the cameras and three times as many in random directions, seen by 8
    cameras whose world is tilted 7 degrees (their mean up is several degrees off): the vertical
    within 0.05 degrees, with and without lens distortion (the segments' endpoints go through the
    lens model both ways)."""
    rng = np.random.default_rng(1)
    up = np.array([np.sin(np.radians(7.0)), 0.0, np.cos(np.radians(7.0))])
    cameras = _cameras(8, up, rng, distortion)
    rotation = _rotation_taking_z_to(up)
    lines = []
    for _ in range(120):
        foot = np.array([*rng.uniform(-4, 4, 2), rng.uniform(-1.5, 0.0)])
        lines.append((rotation @ foot, rotation @ (foot + [0, 0, rng.uniform(0.8, 2.0)])))
    for _ in range(360):
        start = rng.uniform(-4, 4, 3)
        lines.append((start, start + rng.normal(size=3)))
    segments = [_segments_of(cameras, i, lines) for i in range(len(cameras))]
    start = -cameras.c2w[:, :3, 1].mean(axis=0)
    start /= np.linalg.norm(start)
    found = vertical_from_normals(*segment_normals(cameras, segments), start)
    assert found is not None and found @ up > 0
    assert _degrees(found, up) < 0.05


def test_vertical_needs_enough_segments_from_enough_views():
    """Exact vertical segments: found from MIN_VERTICAL_SEGMENTS of them in MIN_VERTICAL_VIEWS
    views; None from one fewer segment, from one view fewer, or from none."""
    rng = np.random.default_rng(2)
    up = np.array([0.0, 0.0, 1.0])
    normals = np.cross(up, rng.normal(size=(MIN_VERTICAL_SEGMENTS, 3)))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    weights = np.full(len(normals), 20.0)
    views = np.arange(len(normals)) % MIN_VERTICAL_VIEWS
    start = np.array([0.1, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 1.0])
    assert _degrees(vertical_from_normals(normals, weights, views, start), up) < 1e-6
    assert vertical_from_normals(normals[1:], weights[1:], views[1:], start) is None
    assert vertical_from_normals(normals, weights, views % (MIN_VERTICAL_VIEWS - 1), start) is None
    assert vertical_from_normals(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), start) is None


def test_vertical_keeps_the_longest_segments_past_the_cap(monkeypatch):
    """Past MAX_SEGMENTS (here 150) the longest vote: 100 long vertical segments and 1000 short
    ones of another direction, whose length all together is twice theirs; the vertical wins only
    because the short ones past the cap do not vote."""
    from scenelabel.geometry import vanishing

    rng = np.random.default_rng(3)
    up = np.array([0.0, 0.0, 1.0])
    other_up = np.array([np.sin(np.radians(5.0)), 0.0, np.cos(np.radians(5.0))])
    normals = np.concatenate([np.cross(up, rng.normal(size=(100, 3))), np.cross(other_up, rng.normal(size=(1000, 3)))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    weights = np.concatenate([np.full(100, 50.0), np.full(1000, 10.0)])
    views = np.arange(len(normals)) % 4
    assert _degrees(vertical_from_normals(normals, weights, views, up), other_up) < 0.01
    monkeypatch.setattr(vanishing, "MAX_SEGMENTS", 150)
    assert _degrees(vertical_from_normals(normals, weights, views, up), up) < 0.01


def test_vertical_from_the_photos_of_a_furnished_room(tmp_path):
    """The furnished room's 40 photos at 160x120: within 0.2 degrees of its vertical."""
    room = load_scene(write_furnished_room(tmp_path / "room"))
    start = -room.cameras.c2w[:, :3, 1].mean(axis=0)
    found = vertical_from_images(room.cameras, room.images, start / np.linalg.norm(start))
    assert found is not None and _degrees(found, np.array([0.0, 0.0, 1.0])) < 0.2
