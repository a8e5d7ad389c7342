"""Tests of scenelabel.maps.visibility: projection, shrunk cameras, the observed-space rule (numpy only)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenelabel.data.synthetic import look_at
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, cameras_from_dict, cameras_to_dict, opengl_to_opencv
from scenelabel.geometry.rays import camera_directions_from_pixels, rays_from_cameras
from scenelabel.maps.visibility import (
    SQRT3,
    back_depth,
    camera_surfaces,
    front_depth,
    max_depth_over_neighbours,
    min_depth_over_neighbours,
    observed_voxels,
    project_points,
    scaled_cameras,
    seen_before_bounds,
    surface_mask,
    visible_from_cameras,
)


def cv_look_at(eye, target) -> np.ndarray:
    """[4, 4] OpenCV camera-to-world looking from eye at target (world z up)."""
    return opengl_to_opencv(look_at(np.asarray(eye, float), np.asarray(target, float)))


def three_cameras() -> Cameras:
    """Three hand-built cameras around the origin, different intrinsics and limits."""
    c2w = np.stack([cv_look_at((4, 0, 1), (0, 0, 0)), cv_look_at((0, -3, 2), (0, 0, 0.5)), cv_look_at((-2, 2, 3), (0, 0, 0))])
    return Cameras.create(
        c2w, fx=[40.0, 25.0, 30.0], fy=[40.0, 30.0, 30.0], cx=[16.0, 10.0, 12.5], cy=[12.0, 8.0, 9.0],
        width=[32, 20, 24], height=[24, 16, 18], near=[0.5, np.nan, 1.0], far=[8.0, np.nan, 4.5],
    )


def naive_projection(cameras, i, p, use_near=True):
    """Camera i's pixel (u, v) of point p and its distance d, or None where the rule's steps 1-2
    reject it (without ``use_near``: only the far limit); plain Python."""
    R, t = cameras.c2w[i, :3, :3], cameras.c2w[i, :3, 3]
    rel = [p[a] - t[a] for a in range(3)]
    cam = [sum(R[r, c] * rel[r] for r in range(3)) for c in range(3)]  # R^T (p - t)
    if cam[2] <= 0:
        return None
    a, b = cam[0] / cam[2], cam[1] / cam[2]
    k1, k2, p1, p2 = cameras.distortion[i]  # OpenCV's projectPoints, four coefficients
    r2 = a * a + b * b
    radial = 1.0 + k1 * r2 + k2 * r2 * r2
    a, b = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a), b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    u = cameras.fx[i] * a + cameras.cx[i]
    v = cameras.fy[i] * b + cameras.cy[i]
    if not (0 <= u < cameras.width[i] and 0 <= v < cameras.height[i]):
        return None
    d = math.sqrt(sum(x * x for x in rel))
    near = cameras.near[i] if math.isfinite(cameras.near[i]) and use_near else 0.0
    far = cameras.far[i] if math.isfinite(cameras.far[i]) else math.inf
    return (u, v, d) if near <= d <= far else None


def naive_visible(points, cameras, depth_maps, margin, pixel_margin=1.0):
    """The rule of scenelabel.maps.visibility, one point and one camera at a time, plain Python."""
    out = []
    for p in points:
        seen = False
        for i in range(len(cameras)):
            hit = naive_projection(cameras, i, p)
            if hit is None:
                continue
            u, v, d = hit
            surface = depth_maps[i][math.floor(v), math.floor(u)]
            if d <= surface + margin + pixel_margin * d / min(cameras.fx[i], cameras.fy[i]):
                seen = True
                break
        out.append(seen)
    return np.array(out, dtype=bool)


def naive_seen_before_bounds(points, cameras, lo, hi):
    """seen_before_bounds one point and one camera at a time: the line c + s (p - c) clipped to
    the box slab by slab (plain Python); p is seen free when the line enters the box at s > 1."""
    out = []
    for p in points:
        seen = False
        if not all(lo[a] <= p[a] <= hi[a] for a in range(3)):
            for i in range(len(cameras)):
                if naive_projection(cameras, i, p, use_near=False) is None:
                    continue
                c = cameras.c2w[i, :3, 3]
                s_in, s_out = -math.inf, math.inf
                for a in range(3):
                    step = p[a] - c[a]
                    if step == 0:
                        if not lo[a] <= c[a] <= hi[a]:
                            s_in, s_out = math.inf, -math.inf
                        continue
                    s0, s1 = (lo[a] - c[a]) / step, (hi[a] - c[a]) / step
                    s_in, s_out = max(s_in, min(s0, s1)), min(s_out, max(s0, s1))
                if s_out >= s_in and s_in > 1.0:
                    seen = True
                    break
        out.append(seen)
    return np.array(out, dtype=bool)


def test_project_points_known_values():
    c2w = np.eye(4)  # camera at the origin looking down +z (OpenCV)
    uv, z, dist = project_points(np.array([[1.0, 2.0, 4.0], [0.0, 0.0, -1.0]]), c2w, 100.0, 50.0, 32.0, 24.0)
    np.testing.assert_allclose(uv[0], [100 * 1 / 4 + 32, 50 * 2 / 4 + 24])
    np.testing.assert_allclose(z, [4.0, -1.0])
    np.testing.assert_allclose(dist, [math.sqrt(21.0), 1.0])
    assert np.all(np.isnan(uv[1]))  # behind the camera


def test_project_points_inverts_pixel_rays():
    """A point on the ray through a pixel centre projects back to that pixel centre (+0.5 rule)."""
    cams = three_cameras()
    for i in range(len(cams)):
        pix = np.array([[0.5, 0.5], [3.5, 7.5], [cams.width[i] - 0.5, cams.height[i] - 0.5]])
        dirs = camera_directions_from_pixels(pix, cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i]) @ cams.c2w[i, :3, :3].T
        pts = cams.c2w[i, :3, 3] + 2.5 * dirs
        uv, z, dist = project_points(pts, cams.c2w[i], cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i])
        np.testing.assert_allclose(uv, pix, atol=1e-9)
        np.testing.assert_allclose(dist, 2.5)  # depth = distance along the unit ray
        assert np.all(z > 0)


def test_scaled_cameras_keep_the_rays():
    cams = Cameras.create(np.eye(4), fx=150.0, fy=140.0, cx=80.0, cy=60.0, width=160, height=120, distortion=[0.1, 0, 0, 0])
    small = scaled_cameras(cams, 80)
    assert (int(small.width[0]), int(small.height[0])) == (80, 60)
    np.testing.assert_allclose([small.fx[0], small.fy[0], small.cx[0], small.cy[0]], [75.0, 70.0, 40.0, 30.0])
    assert not small.has_distortion.any()
    # small pixel centre (0.5, 0.5) covers big continuous coordinate (1, 1): same ray
    a = camera_directions_from_pixels(np.array([[0.5, 0.5]]), small.fx[0], small.fy[0], small.cx[0], small.cy[0])
    b = camera_directions_from_pixels(np.array([[1.0, 1.0]]), 150.0, 140.0, 80.0, 60.0)
    np.testing.assert_allclose(a, b)
    same = scaled_cameras(cams, 1000)  # never enlarged
    assert int(same.width[0]) == 160 and same.fx[0] == 150.0
    with pytest.raises(InputError, match="max_width"):
        scaled_cameras(cams, 0)


def test_hand_built_rule():
    """One camera at the origin looking down +z; a flat 'surface' 5 units along every ray."""
    cams = Cameras.create(np.eye(4), fx=10.0, fy=10.0, cx=5.0, cy=5.0, width=10, height=10, near=1.0, far=20.0)
    depth = [np.full((10, 10), 5.0)]
    margin = 0.1
    # seen while d <= 5 + margin + d / fx (one pixel footprint at the point's own distance d)
    limit = (5.0 + margin) / (1.0 - 1.0 / 10.0)
    pts = np.array([
        [0.0, 0.0, 3.0],                        # in front of the surface: seen
        [0.0, 0.0, limit - 1e-6],               # just within the tolerance: seen
        [0.0, 0.0, limit + 1e-6],               # just beyond it: behind the surface
        [0.0, 0.0, 0.5],                        # nearer than near
        [0.0, 0.0, -3.0],                       # behind the camera
        [4.0, 0.0, 3.0],                        # u = 10 * 4 / 3 + 5 > width: outside the image
    ])
    np.testing.assert_array_equal(visible_from_cameras(pts, cams, depth, margin), [True, True, False, False, False, False])
    # a ray that hits nothing (inf) sees everything up to far
    far_pts = np.array([[0.0, 0.0, 15.0], [0.0, 0.0, 25.0]])
    np.testing.assert_array_equal(visible_from_cameras(far_pts, cams, [np.full((10, 10), np.inf)], margin), [True, False])


def test_vectorised_matches_naive_loop():
    rng = np.random.default_rng(3)
    cams = three_cameras()
    depth_maps = []
    for i in range(len(cams)):
        d = rng.uniform(1.5, 6.0, (int(cams.height[i]), int(cams.width[i])))
        d[rng.random(d.shape) < 0.2] = np.inf  # some rays hit nothing
        depth_maps.append(d)
    pts = rng.uniform(-3, 3, (2000, 3))
    fast = visible_from_cameras(pts, cams, depth_maps, margin=0.1)
    slow = naive_visible(pts, cams, depth_maps, margin=0.1)
    np.testing.assert_array_equal(fast, slow)
    assert 0.05 < fast.mean() < 0.95  # a meaningful mix


def test_distorted_pinholes_match_naive_loop_across_threads():
    """Lens distortion, and a batch large enough to be split over the cores (compiled path)."""
    rng = np.random.default_rng(4)
    cams = three_cameras()
    cams = Cameras.create(
        cams.c2w, fx=cams.fx, fy=cams.fy, cx=cams.cx, cy=cams.cy, width=cams.width, height=cams.height,
        near=cams.near, far=cams.far, distortion=[[0.1, -0.05, 0.01, -0.02], [0.0] * 4, [-0.2, 0.03, 0.0, 0.005]],
    )
    depth_maps = [rng.uniform(1.5, 6.0, (int(h), int(w))) for h, w in zip(cams.height, cams.width)]
    pts = rng.uniform(-3, 3, (20_000, 3))
    fast = visible_from_cameras(pts, cams, depth_maps, margin=0.05, pixel_margin=0.5)
    np.testing.assert_array_equal(fast, naive_visible(pts, cams, depth_maps, margin=0.05, pixel_margin=0.5))
    assert 0.05 < fast.mean() < 0.95


def _edge_depths_naive(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rules 4 and 5 of docs/conventions.md "Observed space", pixel by pixel in float64: each
    pixel's back depth (occupied voxels) and front depth (transparent ones)."""
    h, w = depth.shape
    front, back = np.empty((h, w)), np.empty((h, w))
    for r in range(h):
        for c in range(w):
            def at(rr, cc):
                return depth[min(max(rr, 0), h - 1), min(max(cc, 0), w - 1)]
            around = [at(r + i, c + j) for i in (-1, 0, 1) for j in (-1, 0, 1)]
            d = depth[r, c]
            smooth = np.isfinite(d)
            for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
                a, b = at(r + dr, c + dc), at(r - dr, c - dc)
                smooth = smooth and np.isfinite(a) and np.isfinite(b) and abs(a + b - 2 * d) <= 0.1 * d
            front[r, c] = 0.5 * (d + min(around)) if smooth else min(around)
            back[r, c] = 0.5 * (d + max(around)) if smooth else d
    return front, back


def test_seen_before_bounds_hand_built():
    """A camera 2 m in front of the unit box looking at it: the stretch before the box is seen
    free; the box, what lies behind it, beside the image and behind the camera is not; a
    camera inside the box sees nothing outside it as free."""
    lo, hi = np.zeros(3), np.ones(3)
    cams = Cameras.create(cv_look_at((0.5, -2.0, 0.5), (0.5, 0.5, 0.5))[None], fx=[20.0], fy=[20.0], cx=[10.0], cy=[10.0],
                          width=[20], height=[20], near=[0.1], far=[np.nan])
    points = np.array([
        [0.5, -1.0, 0.5],   # between the camera and the box: seen free
        [0.5, -0.01, 0.5],  # just before the box face
        [0.5, 0.5, 0.5],    # inside the box: the field answers
        [0.5, 2.0, 0.5],    # behind the box
        [0.5, -2.05, 0.5],  # behind the camera
        [0.5, -1.95, 0.5],  # in front of the camera, closer than near: free too
        [3.0, -1.0, 0.5],   # outside the image
        [1.2, -0.5, 1.2],   # in the image, but its ray passes beside the box
        [0.5, -1.0, 0.6],   # seen free, but beyond far (below)
    ])
    np.testing.assert_array_equal(seen_before_bounds(points, cams, np.stack([lo, hi])),
                                  [True, True, False, False, False, True, False, False, True])
    cams.far[:] = 0.9
    assert seen_before_bounds(points, cams, np.stack([lo, hi])).tolist() == [False, False, False, False, False, True,
                                                                              False, False, False]
    inside = Cameras.create(cv_look_at((0.5, 0.5, 0.5), (0.5, 2.0, 0.5))[None], fx=[20.0], fy=[20.0], cx=[10.0], cy=[10.0],
                            width=[20], height=[20], near=[np.nan], far=[np.nan])
    assert not seen_before_bounds(np.array([[0.5, 1.5, 0.5]]), inside, np.stack([lo, hi])).any()


def test_seen_before_bounds_matches_naive_loop():
    cams = three_cameras()
    rng = np.random.default_rng(3)
    lo, hi = np.array([-0.6, -0.5, -0.4]), np.array([0.7, 0.5, 0.9])
    # on lines from each camera to points of the box (before, in and beyond it), and anywhere
    centres = cams.c2w[rng.integers(0, len(cams), 2000), :3, 3]
    targets = rng.uniform(lo, hi, (2000, 3))
    points = np.concatenate([centres + rng.uniform(0.05, 1.6, (2000, 1)) * (targets - centres), rng.uniform(-5, 5, (1000, 3))])
    points[:20, 0] = lo[0]  # on a face (inside) and just beside one
    points[20:40, 0] = hi[0] + 1e-9
    got = seen_before_bounds(points, cams, np.stack([lo, hi]))
    np.testing.assert_array_equal(got, naive_seen_before_bounds(points, cams, lo, hi))
    assert 300 < got.sum() < len(points) - 300  # both answers occur


def test_front_depth_on_a_grazing_floor_a_silhouette_and_the_sky():
    """A floor seen at a grazing angle (depth growing about 6 % a row): the mean of a pixel's own
    depth and its neighbours' smallest, nearer than its own and farther than the smallest; a box's
    silhouette in front of it and rows that see nothing: the smallest; against a naive loop."""
    rows = np.arange(12, dtype=np.float64)
    depth = np.repeat((1.4 / np.sin(np.radians(20.0 - 0.75 * rows)))[:, None], 10, axis=1)  # a floor, far at the top
    depth = depth[::-1].copy()
    depth[:2] = np.inf  # above the horizon: nothing
    depth[6:9, 3:6] = 1.0  # a box much nearer than the floor behind it
    front, low = front_depth(depth), min_depth_over_neighbours(depth)
    np.testing.assert_allclose(front, _edge_depths_naive(depth)[0], rtol=1e-12)
    assert np.all(front >= low) and np.all(front <= depth)
    floor = np.zeros_like(depth, bool)
    floor[3:11, 8:] = True  # away from the box and the sky; not the nearest row (its own depth is the smallest)
    floor[10, :] = True
    assert np.all(front[floor] > low[floor]) and np.all(front[floor] < depth[floor])
    np.testing.assert_array_equal(front[5:10, 2:7], low[5:10, 2:7])  # the box and the floor around its silhouette
    np.testing.assert_array_equal(front[:3], low[:3])  # the sky and the row beside it


def test_back_depth_on_a_grazing_floor_a_silhouette_and_the_sky():
    """The same floor: the mean of a pixel's own depth and its neighbours' largest, farther than
    its own and nearer than the largest; the box, the floor around its silhouette and the rows
    that see nothing or border them: the pixel's own depth; against a naive loop."""
    rows = np.arange(12, dtype=np.float64)
    depth = np.repeat((1.4 / np.sin(np.radians(20.0 - 0.75 * rows)))[:, None], 10, axis=1)[::-1].copy()
    depth[:2] = np.inf
    depth[6:9, 3:6] = 1.0
    back, high = back_depth(depth), max_depth_over_neighbours(depth)
    np.testing.assert_allclose(back, _edge_depths_naive(depth)[1], rtol=1e-12)
    assert np.all(back >= depth) and np.all(back <= high)
    floor = np.zeros_like(depth, bool)
    floor[3:11, 8:] = True  # away from the box and the sky; not the farthest row of the floor
    assert np.all(back[floor] > depth[floor]) and np.all(back[floor] < high[floor])
    np.testing.assert_array_equal(back[5:10, 2:7], depth[5:10, 2:7])
    np.testing.assert_array_equal(back[:3], depth[:3])
    assert np.isfinite(back[2:]).all() and np.isinf(back[:2]).all()


def test_max_depth_over_neighbours():
    depth = np.full((5, 6), 1.0)
    depth[2, 3] = 2.0
    depth[4, 5] = np.inf
    out = max_depth_over_neighbours(depth)
    expected = np.full((5, 6), 1.0)
    expected[1:4, 2:5] = 2.0
    expected[3:5, 4:6] = np.inf
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(max_depth_over_neighbours(depth, size=1), depth)
    with pytest.raises(InputError, match="size"):
        max_depth_over_neighbours(depth, size=4)


def test_min_depth_over_neighbours():
    depth = np.full((5, 6), np.inf)
    depth[2, 3] = 2.0
    depth[0, 0] = 1.0
    out = min_depth_over_neighbours(depth)
    expected = np.full((5, 6), np.inf)
    expected[1:4, 2:5] = 2.0
    expected[0:2, 0:2] = 1.0
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(min_depth_over_neighbours(depth, size=1), depth)
    assert np.all(out <= depth)
    with pytest.raises(InputError, match="size"):
        min_depth_over_neighbours(depth, size=2)


# A 10^3 grid of 0.1 voxels covering [0, 1]^3 with an occupied wall at x in [0.5, 0.6).
GRID_ORIGIN = np.array([0.05, 0.05, 0.05])
GRID_VOXEL = 0.1


def wall_grid() -> np.ndarray:
    occupied = np.zeros((10, 10, 10), bool)
    occupied[5] = True
    return occupied


def test_camera_surfaces_of_opaque_and_foggy_walls():
    """Axis-aligned rays: an opaque wall's surface is its face; a wall of three fog layers (opacity
    0.3 each) is crossed at T = 0.5 inside its second layer, log 2 / sigma past its face; beyond
    far or with no wall there is none."""
    cams = Cameras.create(cv_look_at((-1.0, 0.5, 0.5), (0.0, 0.5, 0.5)), fx=2.0, fy=2.0, cx=1.0, cy=1.0, width=2, height=2)
    _, directions = rays_from_cameras(cams, 0)
    x = directions[:, 0]  # [4] the rays' x components (unit directions)
    opaque = camera_surfaces(wall_grid(), GRID_ORIGIN, GRID_VOXEL, cams)
    np.testing.assert_allclose(opaque.depth[0].reshape(-1), 1.5 / x)  # the face at x = 0.5
    assert set(map(tuple, opaque.voxels[:, :1].tolist())) == {(5,)}
    fog = np.zeros((10, 10, 10))
    fog[5:8] = 0.3
    sigma = -math.log1p(-round(0.3 * 255) / 255) / GRID_VOXEL
    foggy = camera_surfaces(fog, GRID_ORIGIN, GRID_VOXEL, cams)
    np.testing.assert_allclose(foggy.depth[0].reshape(-1), 1.5 / x + math.log(2) / sigma)
    assert set(foggy.voxels[:, 0].tolist()) == {6}
    assert not np.any(fog >= 0.5)  # no voxel of it would be occupied alone
    short = Cameras.create(cams.c2w, fx=2.0, fy=2.0, cx=1.0, cy=1.0, width=2, height=2, near=0.0, far=1.0)
    assert np.all(np.isinf(camera_surfaces(fog, GRID_ORIGIN, GRID_VOXEL, short).depth[0]))
    assert camera_surfaces(np.zeros((10, 10, 10)), GRID_ORIGIN, GRID_VOXEL, cams).voxels.shape == (0, 3)
    np.testing.assert_array_equal(surface_mask(foggy, (slice(6, 7), slice(0, 10), slice(0, 10))).any(), True)
    assert not surface_mask(foggy, (slice(0, 6), slice(0, 10), slice(0, 10))).any()


def test_observed_voxels_hand_built_wall():
    """A camera in front of a wall sees the space before it and the wall itself, not behind it."""
    cams = Cameras.create(cv_look_at((-1.0, 0.5, 0.5), (0.0, 0.5, 0.5)), fx=16.0, fy=16.0, cx=16.0, cy=16.0, width=32, height=32)
    observed, occupied = observed_voxels(wall_grid(), GRID_ORIGIN, GRID_VOXEL, cams)
    np.testing.assert_array_equal(occupied, wall_grid())
    assert observed[:4].all()  # free, in front of the wall
    # the layer touching the wall (centres half a voxel before its face): its outer ring is behind
    # the nearest surface of their 3x3 pixels at these oblique angles
    assert observed[4].mean() >= 0.85
    assert observed[4, 2:8, 2:8].all()
    assert observed[5].all()  # the wall: occupied, within the margin of the first surface
    assert not observed[6:].any()  # behind it
    # a surface outside the grid (a depth map of 0.5 everywhere) hides it all but the nearest layers
    near_wall = [np.full((32, 32), 0.5)]
    assert not observed_voxels(wall_grid(), GRID_ORIGIN, GRID_VOXEL, cams, occluder_depth=near_wall)[0][2:].any()


def test_observed_voxels_foggy_wall_is_a_surface():
    """Fog that no voxel of which is opaque enough alone: the voxels where the camera's rays reach
    T = 0.5 are occupied and observed, the fog in front is observed free, the fog behind unknown."""
    cams = Cameras.create(cv_look_at((-1.0, 0.5, 0.5), (0.0, 0.5, 0.5)), fx=16.0, fy=16.0, cx=16.0, cy=16.0, width=32, height=32)
    fog = np.zeros((10, 10, 10))
    fog[5:8] = 0.3
    observed, occupied = observed_voxels(fog, GRID_ORIGIN, GRID_VOXEL, cams)
    assert not occupied[:5].any() and not occupied[7:].any()
    assert occupied[6, 2:8, 2:8].all()  # the rays cross T = 0.5 in the second layer
    assert observed[:4].all() and observed[6][occupied[6]].all()
    assert not observed[8:].any()


def test_observed_voxels_floor_at_a_grazing_angle():
    """A floor two voxels thick seen across 6 m from 1.4 m above it by a camera the size of a
    map's depth maps (80 x 60): far away a pixel's depth grows by tens of centimetres from one row
    to the next. Against each pixel's own depth the floor's top voxels whose centre falls in the
    far half of their pixel were unobserved; against its back depth every one in the camera's
    view is observed, and the layer beneath stays hidden (within 5 m; beyond, the margin reaches
    it where a coarse pixel spans a metre of floor)."""
    voxel = 0.1
    occupied = np.zeros((80, 60, 3), bool)
    occupied[:, :, :2] = True  # its top at z = 0.2
    origin = np.array([0.05, 0.05, 0.05])
    cams = Cameras.create(cv_look_at((-0.5, 3.0, 1.4), (4.0, 3.0, 0.6)), fx=64.0, fy=64.0, cx=40.0, cy=30.0, width=80, height=60)
    observed, occ = observed_voxels(occupied, origin, voxel, cams)
    np.testing.assert_array_equal(occ, occupied)
    top = np.zeros_like(occupied)
    top[:60, 20:40, 1] = True  # the top layer ahead of the camera
    centres = origin + voxel * np.argwhere(top)
    in_view = visible_from_cameras(centres, cams, [np.full((60, 80), np.inf)], 0.0)
    assert in_view.sum() > 500
    np.testing.assert_array_equal(observed[top], in_view)
    surfaces = camera_surfaces(occupied, origin, voxel, cams)
    own = visible_from_cameras(centres, cams, surfaces.depth, SQRT3 * voxel)
    assert own.sum() < in_view.sum() - 50  # the pixel's own depth missed the far floor
    assert not observed[:50, :, 0].any()


def test_input_errors():
    cams = three_cameras()
    maps = [np.zeros((int(h), int(w))) for h, w in zip(cams.height, cams.width)]
    with pytest.raises(InputError, match="points"):
        visible_from_cameras(np.zeros((4, 2)), cams, maps, 0.1)
    with pytest.raises(InputError, match="depth map 1"):
        visible_from_cameras(np.zeros((4, 3)), cams, [maps[0], maps[0], maps[2]], 0.1)
    with pytest.raises(InputError, match="depth maps"):
        visible_from_cameras(np.zeros((4, 3)), cams, maps[:2], 0.1)
    with pytest.raises(InputError, match="margin"):
        visible_from_cameras(np.zeros((4, 3)), cams, maps, -1.0)
    assert visible_from_cameras(np.zeros((0, 3)), cams, maps, 0.1).shape == (0,)


def test_cameras_dict_round_trip():
    cams = three_cameras()
    back = cameras_from_dict(cameras_to_dict(cams))
    for name in cams.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(back, name), getattr(cams, name))
    assert back.width.dtype == np.int64
    with pytest.raises(InputError, match="c2w"):
        cameras_from_dict({k: v for k, v in cameras_to_dict(cams).items() if k != "c2w"})


# ---------------------------------------------------------------------------- on the trained toy scene


@pytest.mark.slow
def test_toy_scene_map_observed_space(toy_build):
    """Box interiors are UNKNOWN (occluded from every camera) or occupied, box tops stay occupied
    with their class, space above the boxes is FREE, space under the floor and outside every
    frustum is UNKNOWN. The trained surfaces are soft (a voxel or two deep), hence the insets."""
    from scenelabel import FREE, UNKNOWN
    from scenelabel.data.synthetic import TOY_BOXES

    field = toy_build.field
    m = field.occupancy_map(voxel_size=0.05)
    assert m.unknown_rule == "visibility"
    vs = m.voxel_size
    centres = m.world_from_index(np.stack(np.meshgrid(*[np.arange(n) for n in m.shape], indexing="ij"), -1).reshape(-1, 3))
    label = m.label.reshape(-1)
    for box in TOY_BOXES[1:]:
        lo, hi = np.array(box.lo), np.array(box.hi)
        inside = np.all((centres > lo + 2 * vs) & (centres < hi - 2 * vs), axis=1)
        assert inside.any() and set(np.unique(label[inside]).tolist()) <= {UNKNOWN, box.class_id}, box.part
        deep = np.all((centres > lo + 3 * vs) & (centres < hi - 3 * vs), axis=1)
        assert deep.any() and np.mean(label[deep] == UNKNOWN) >= 0.9, box.part
        footprint = np.all((centres[:, :2] > lo[:2] + 2 * vs) & (centres[:, :2] < hi[:2] - 2 * vs), axis=1)
        top = footprint & (np.abs(centres[:, 2] - hi[2]) <= vs / 2)
        assert top.any() and np.all(label[top] == box.class_id), box.part
        above = footprint & (centres[:, 2] > hi[2] + 2 * vs) & (centres[:, 2] < hi[2] + 5 * vs)
        assert above.any() and np.all(label[above] == FREE), box.part
    under_floor = (centres[:, 2] < -0.1) & np.all(np.abs(centres[:, :2]) < 1.4, axis=1)  # floor: |x|, |y| < 1.5
    assert under_floor.any() and not np.any(label[under_floor] == FREE)
    assert np.mean(label[under_floor] == UNKNOWN) >= 0.99  # a few soft-surface voxels stay occupied
    cams = field.training_cameras()
    in_any = np.zeros(len(centres), bool)
    for i in range(len(cams)):
        uv, z, _ = project_points(centres, cams.c2w[i], cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i])
        with np.errstate(invalid="ignore"):
            in_any |= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cams.width[i]) & (uv[:, 1] >= 0) & (uv[:, 1] < cams.height[i])
    assert np.all(label[~in_any] == UNKNOWN)
