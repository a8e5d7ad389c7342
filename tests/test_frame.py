"""Scene bounds from cameras and the world <-> normalised transform."""

import numpy as np
import pytest

from scenelabel.errors import InputError
from scenelabel.frame import SceneFrame, aabb_from_cameras
from scenelabel.scene import Cameras


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
    np.testing.assert_allclose(frame.to_world(frame.to_internal(pts)), pts)
    np.testing.assert_allclose(frame.to_internal(np.array([[2.0, 1, 1]])), [[1.0, 0.25, 0.25]])
    again = SceneFrame.from_dict(frame.to_dict())
    np.testing.assert_array_equal(again.centre, frame.centre)
    assert again.scale == frame.scale
