"""Scene bounds from cameras and the world <-> normalised transform."""

import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.frame import (
    FALLBACK_FAR_FACTOR,
    FALLBACK_NEAR_FRACTION,
    FORWARD_FALLBACK_FAR_FACTOR,
    MIN_BOUNDING_POINTS,
    POINTS_PAD,
    SceneFrame,
    aabb_from_cameras,
    aabb_from_points,
    forward_rig,
    looking_one_way,
    near_far_or_fallback,
    observed_extent,
)


def looking_down(height):
    c2w = np.eye(4)
    c2w[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV z forward -> world -z
    c2w[:3, 3] = [0, 0, height]
    return c2w


def test_frustum_bounds_from_near_far():
    cams = Cameras.create(looking_down(10.0), 50.0, 50.0, 50.0, 50.0, 100, 100, near=1.0, far=9.0)
    aabb, source = aabb_from_cameras(cams)
    assert "near/far" in source
    # the far plane at z = 1 spans +-9 * (50 / 50) / sqrt(1 + 1 + 1)-ish; check z and symmetry
    assert aabb[0, 2] < 1.0 < 9.0 < aabb[1, 2]
    np.testing.assert_allclose(aabb[0, :2], -aabb[1, :2])


def _yawed(yaw_deg, x):
    """An OpenCV camera at (x, 0, 0) looking along +z turned by ``yaw_deg`` about y."""
    a = np.radians(yaw_deg)
    c2w = np.eye(4)
    c2w[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    c2w[0, 3] = x
    return c2w


def test_cameras_looking_one_way_get_a_far_fallback_for_a_scene_far_away():
    """A forward-facing rig 0.4 m wide without near/far: far 30x its spread, where the 1.5x of an
    inward-looking capture would end every ray 0.6 m from the rig."""
    rig = Cameras.create(np.stack([_yawed(y, x) for y, x in ((-10, -0.2), (0, 0.0), (10, 0.2))]), 30.0, 30.0, 20, 15, 40, 30)
    assert looking_one_way(rig) and not looking_one_way(rig, max_angle_deg=5.0)
    assert forward_rig(rig) and not forward_rig(rig, max_angle_deg=5.0)
    near, far = near_far_or_fallback(rig)
    np.testing.assert_allclose(far, FORWARD_FALLBACK_FAR_FACTOR * 0.4)
    np.testing.assert_allclose(near, FALLBACK_NEAR_FRACTION * far)
    ring = Cameras.create(np.stack([_yawed(y, 0.1 * k) for k, y in enumerate((0, 90, 180, 270))]), 30.0, 30.0, 20, 15, 40, 30)
    assert not looking_one_way(ring)
    np.testing.assert_allclose(near_far_or_fallback(ring)[1], FALLBACK_FAR_FACTOR * 0.3)
    # a camera carried forward (down a corridor) looks one way but is no rig: the inward fallback
    drive = [_yawed(y, x) for y, x in ((-5, 0.0), (0, 0.1), (5, 0.0))]
    for c2w, z in zip(drive, (0.0, 2.0, 4.0)):
        c2w[2, 3] = z
    drive = Cameras.create(np.stack(drive), 30.0, 30.0, 20, 15, 40, 30)
    assert looking_one_way(drive) and not forward_rig(drive)
    np.testing.assert_allclose(near_far_or_fallback(drive)[1], FALLBACK_FAR_FACTOR * np.sqrt(0.1**2 + 4.0**2))
    opposite = Cameras.create(np.stack([_yawed(0, 0.0), _yawed(180, 1.0)]), 30.0, 30.0, 20, 15, 40, 30)
    assert not looking_one_way(opposite)  # axes that cancel have no mean direction
    given = Cameras.create(np.stack([_yawed(0, 0.0), _yawed(5, 0.4)]), 30.0, 30.0, 20, 15, 40, 30, near=1.0, far=7.0)
    np.testing.assert_allclose(near_far_or_fallback(given), [[1.0, 1.0], [7.0, 7.0]])  # given near/far stay


def test_explicit_aabb_wins_and_is_checked():
    cams = Cameras.create(looking_down(10.0), 50.0, 50.0, 50.0, 50.0, 100, 100)
    aabb, source = aabb_from_cameras(cams, np.array([[0, 0, 0], [1, 2, 3.0]]))
    np.testing.assert_array_equal(aabb, [[0, 0, 0], [1, 2, 3]])
    with pytest.raises(InputError, match="max > min"):
        aabb_from_cameras(cams, np.array([[0, 0, 0], [1, -2, 3.0]]))


def test_scene_frame_is_an_isotropic_similarity():
    frame = SceneFrame.from_aabb(np.array([[-2.0, 0, 0], [2.0, 1, 1]]))
    assert frame.scale == 0.5
    pts = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose(frame.to_world(frame.to_normalised(pts)), pts)
    np.testing.assert_allclose(frame.to_normalised(np.array([[2.0, 1, 1]])), [[1.0, 0.25, 0.25]])
    again = SceneFrame.from_dict(frame.to_dict())
    np.testing.assert_array_equal(again.centre, frame.centre)
    assert again.scale == frame.scale


def test_bounds_from_points_are_robust_and_padded():
    rng = np.random.default_rng(0)
    points = rng.uniform([-3.0, -2.0, 0.0], [3.0, 2.0, 2.5], (20000, 3))
    strays = rng.uniform(-50.0, 50.0, (50, 3))  # 0.25 %: beyond the percentiles
    aabb = aabb_from_points(np.concatenate([points, strays]))
    pad = POINTS_PAD * 6.0
    np.testing.assert_allclose(aabb, [[-3.0 - pad, -2.0 - pad, -pad], [3.0 + pad, 2.0 + pad, 2.5 + pad]], atol=0.1)
    tight = aabb_from_points(points, pad=0.03)
    np.testing.assert_allclose(tight, [[-3.18, -2.18, -0.18], [3.18, 2.18, 2.68]], atol=0.1)
    assert aabb_from_points(points[: MIN_BOUNDING_POINTS - 1]) is None
    assert aabb_from_points(np.zeros((500, 3))) is None  # one point repeated bounds nothing
    assert aabb_from_points(np.full((500, 3), np.nan)) is None


def test_observed_extent_is_the_points_full_extent_inside_the_box():
    rng = np.random.default_rng(1)
    points = rng.uniform([-3.0, -2.0, 0.0], [3.0, 2.0, 2.5], (5000, 3))
    points[0] = [-3.5, 0.0, 1.0]  # beyond the percentiles, inside the box: still observed
    points[1] = [0.0, 0.0, 40.0]  # outside the box: left out
    points[2] = [np.nan, 0.0, 0.0]
    aabb = np.array([[-4.0, -3.0, -1.0], [4.0, 3.0, 3.0]])
    extent = observed_extent(points, aabb)
    inside = points[3:]
    np.testing.assert_array_equal(extent, [[-3.5, *inside.min(0)[1:]], inside.max(0)])
    assert observed_extent(points[: MIN_BOUNDING_POINTS - 1], aabb) is None
    assert observed_extent(np.zeros((500, 3)), aabb) is None  # one point repeated bounds nothing
    assert observed_extent(points + 100.0, aabb) is None  # none inside the box


def test_observed_points_bound_a_scene_without_near_far_within_its_frusta():
    c2ws = np.stack([looking_down(3.0), looking_down(3.0)])
    c2ws[:, 0, 3] = [-2.0, 2.0]  # far = FALLBACK_FAR_FACTOR x 4 m reaches below the points
    cams = Cameras.create(c2ws, 50.0, 50.0, 50.0, 50.0, 100, 100)  # two cameras, no near/far
    frusta, frusta_source = aabb_from_cameras(cams)
    points = np.random.default_rng(1).uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 0.5], (1000, 3))
    aabb, source = aabb_from_cameras(cams, None, points)
    assert source.startswith("observed geometry") and "no near/far" in frusta_source
    np.testing.assert_allclose(aabb, aabb_from_points(points))  # inside the frusta already
    assert f"padded {POINTS_PAD:.0%} of the longest side" in source
    tight, tight_source = aabb_from_cameras(cams, None, points, "sensor depth", points_pad=0.03)
    np.testing.assert_allclose(tight, aabb_from_points(points, pad=0.03))
    assert tight_source.startswith("sensor depth") and "padded 3% of the longest side" in tight_source
    assert np.prod(aabb[1] - aabb[0]) < 0.01 * np.prod(frusta[1] - frusta[0])
    # points reaching outside the frusta are cut to them
    far_points = np.concatenate([points, points + [0.0, 0.0, 100.0]])
    cut, _ = aabb_from_cameras(cams, None, far_points)
    assert cut[1, 2] == frusta[1, 2]
    # given near/far, an explicit box, or too few points: the points are not used
    with_far = Cameras.create(c2ws, 50.0, 50.0, 50.0, 50.0, 100, 100, near=1.0, far=9.0)
    assert "near/far" in aabb_from_cameras(with_far, None, points)[1]
    assert aabb_from_cameras(cams, np.array([[0, 0, 0], [1, 1, 1.0]]), points)[1] == "explicit aabb"
    np.testing.assert_array_equal(aabb_from_cameras(cams, None, points[:10])[0], frusta)
