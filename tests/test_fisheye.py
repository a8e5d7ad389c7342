"""Fisheye cameras (OpenCV's equidistant model): rays and projection against a naive float64
reference, past 90° from the axis, round trips, Cameras.model and its records, visibility."""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np
import pytest

from scenelabel.data.io.depth import MIN_DIRECTION_Z, z_depth_from_ray_depth
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, cameras_from_dict, cameras_to_dict
from scenelabel.geometry.lens import (
    FISHEYE,
    PINHOLE,
    fisheye_angle_from_distorted,
    fisheye_distorted_angle,
    fisheye_max_angle,
    ideal_pinhole_image,
    pixels_from_camera_points,
)
from scenelabel.geometry.rays import camera_directions_from_pixels, pixel_grid, rays_from_cameras
from scenelabel.maps.visibility import project_points, scaled_cameras, visible_from_cameras

# a 64 x 48 fisheye whose image corners lie ~150° from the axis (f = 12 px: radius 40 px = 3.3 rad)
W, H = 64, 48
FX, FY, CX, CY = 12.0, 12.5, 31.5, 24.25
K = np.array([0.02, -0.003, 0.0004, -0.00002])  # monotone well past the corners
FOLDING = np.array([-0.1, 0.0, 0.0, 0.0])  # dθ_d/dθ = 1 - 0.3 θ² reaches 0 at θ = 1/√0.3


# ---------------------------------------------------------------------------------------------
# naive reference: one point at a time, plain float64 maths


def ref_distorted(theta: float, k) -> float:
    return theta * (1 + k[0] * theta**2 + k[1] * theta**4 + k[2] * theta**6 + k[3] * theta**8)


def ref_max_angle(k, step: float = 1e-5) -> float:
    """First θ where θ_d stops increasing, scanning [0, π] (π if it never does)."""
    return _ref_max_angle(tuple(float(c) for c in k), step)


@lru_cache(maxsize=None)
def _ref_max_angle(k: tuple, step: float) -> float:
    theta, previous = step, ref_distorted(0.0, k)
    while theta <= math.pi:
        value = ref_distorted(theta, k)
        if value <= previous:
            return theta - step
        previous, theta = value, theta + step
    return math.pi


def ref_project(point, fx, fy, cx, cy, k) -> tuple[float, float]:
    x, y, z = (float(c) for c in point)
    r = math.hypot(x, y)
    theta = math.atan2(r, z)
    if r == 0.0:
        return cx, cy
    theta_d = ref_distorted(theta, k)
    return fx * theta_d * x / r + cx, fy * theta_d * y / r + cy


def ref_ray(u, v, fx, fy, cx, cy, k) -> tuple[float, float, float]:
    """Unit direction through (u, v): θ by bisection of θ_d(θ) on [0, θ_max]."""
    xd, yd = (u - cx) / fx, (v - cy) / fy
    theta_d = math.hypot(xd, yd)
    if theta_d == 0.0:
        return 0.0, 0.0, 1.0
    lo, hi = 0.0, ref_max_angle(k)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if ref_distorted(mid, k) < theta_d:
            lo = mid
        else:
            hi = mid
    theta = 0.5 * (lo + hi)
    return math.sin(theta) * xd / theta_d, math.sin(theta) * yd / theta_d, math.cos(theta)


def random_pixels(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform([0, 0], [W, H], (n, 2))


# ---------------------------------------------------------------------------------------------
# rays and projection


def test_rays_match_naive_reference_past_90_degrees():
    pixels = np.concatenate([random_pixels(300), pixel_grid(W, H)[:: 37]])
    dirs = camera_directions_from_pixels(pixels, FX, FY, CX, CY, K, "fisheye")
    want = np.array([ref_ray(u, v, FX, FY, CX, CY, K) for u, v in pixels])
    np.testing.assert_allclose(dirs, want, atol=1e-9)
    assert np.all(np.isfinite(dirs))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    assert np.sum(dirs[:, 2] < 0) > 50  # many pixels look more than 90° off the axis


def test_projection_matches_naive_reference_and_opencv():
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.0, 2.6, 400)  # up to 149°, behind the image plane too
    phi = rng.uniform(-math.pi, math.pi, 400)
    dist = rng.uniform(0.5, 4.0, 400)
    points = dist[:, None] * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    uv = pixels_from_camera_points(points, FX, FY, CX, CY, K, "fisheye")
    want = np.array([ref_project(p, FX, FY, CX, CY, K) for p in points])
    np.testing.assert_allclose(uv, want, atol=1e-9)
    front = points[:, 2] > 1e-3  # OpenCV's fisheye projects points in front (it takes atan(r / z))
    k_matrix = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    projected, _ = cv2.fisheye.projectPoints(points[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k_matrix, K)
    np.testing.assert_allclose(uv[front], projected.reshape(-1, 2), atol=1e-9)


def test_zero_coefficients_are_the_ideal_equidistant_lens():
    theta = np.linspace(0.0, 3.1, 32)
    points = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)  # along +x
    uv = pixels_from_camera_points(points, FX, FY, CX, CY, np.zeros(4), "fisheye")
    np.testing.assert_allclose(uv[:, 0] - CX, FX * theta, atol=1e-12)  # r = f θ
    np.testing.assert_allclose(uv[:, 1], CY, atol=1e-12)
    dirs = camera_directions_from_pixels(np.stack([CX + FX * theta, np.full_like(theta, CY)], -1), FX, FY, CX, CY,
                                         None, "fisheye")
    np.testing.assert_allclose(dirs, points, atol=1e-12)


def test_180_degree_fisheye_gives_finite_unit_directions():
    radius = FX * np.array([0.5 * math.pi, 0.99 * math.pi, math.pi, 1.2 * math.pi])  # 90°, 178°, 180°, beyond
    dirs = camera_directions_from_pixels(np.stack([CX + radius, np.full(4, CY)], -1), FX, FX, CX, CY, np.zeros(4), "fisheye")
    assert np.all(np.isfinite(dirs))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(dirs[0], [1.0, 0.0, 0.0], atol=1e-12)  # exactly sideways
    np.testing.assert_allclose(dirs[1], [math.sin(0.99 * math.pi), 0.0, math.cos(0.99 * math.pi)], atol=1e-12)
    np.testing.assert_allclose(dirs[2:], [[0.0, 0.0, -1.0]] * 2, atol=1e-12)  # π: the model's widest angle


@pytest.mark.parametrize("k", [K, np.zeros(4), FOLDING])
def test_round_trip_pixels_to_rays_to_pixels(k):
    """project(rays(pixels)) == pixels for every pixel the model maps one-to-one."""
    pixels = np.concatenate([random_pixels(500, 2), pixel_grid(W, H)])
    dirs = camera_directions_from_pixels(pixels, FX, FY, CX, CY, k, "fisheye")
    inside = np.hypot((pixels[:, 0] - CX) / FX, (pixels[:, 1] - CY) / FY) < fisheye_distorted_angle(fisheye_max_angle(k), k)
    assert inside.sum() > 100
    uv = pixels_from_camera_points(2.5 * dirs[inside], FX, FY, CX, CY, k, "fisheye")
    np.testing.assert_allclose(uv, pixels[inside], atol=1e-6)


def test_round_trip_pinhole_with_distortion():
    dist = np.array([0.0578421, -0.0805099, -0.000980296, 0.00015575])
    pixels = np.random.default_rng(3).uniform([0, 0], [320, 240], (200, 2))
    dirs = camera_directions_from_pixels(pixels, 300.0, 310.0, 160.0, 120.0, dist)
    np.testing.assert_allclose(pixels_from_camera_points(3.0 * dirs, 300.0, 310.0, 160.0, 120.0, dist), pixels, atol=1e-6)
    k_matrix = np.array([[300.0, 0, 160], [0, 310.0, 120], [0, 0, 1]])
    projected, _ = cv2.projectPoints(dirs, np.zeros(3), np.zeros(3), k_matrix, dist)
    np.testing.assert_allclose(pixels_from_camera_points(dirs, 300.0, 310.0, 160.0, 120.0, dist), projected.reshape(-1, 2),
                               atol=1e-9)
    behind = pixels_from_camera_points(np.array([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0]]), 300.0, 310.0, 160.0, 120.0, dist)
    assert np.all(np.isnan(behind))


def test_folding_coefficients_stop_at_the_widest_angle():
    widest = fisheye_max_angle(FOLDING)
    assert widest == pytest.approx(1.0 / math.sqrt(0.3), abs=1e-12)
    assert widest == pytest.approx(ref_max_angle(FOLDING), abs=1e-4)
    assert fisheye_max_angle(np.zeros(4)) == math.pi
    assert fisheye_max_angle(K) == math.pi  # monotone up to 180°
    # beyond it: no projection, and pixels past its image radius get its ray
    beyond = np.array([[math.sin(widest + 0.05), 0.0, math.cos(widest + 0.05)]])
    assert np.all(np.isnan(pixels_from_camera_points(beyond, FX, FY, CX, CY, FOLDING, "fisheye")))
    edge = fisheye_distorted_angle(widest, FOLDING)
    dirs = camera_directions_from_pixels(np.array([[CX + FX * edge * 1.5, CY]]), FX, FY, CX, CY, FOLDING, "fisheye")
    np.testing.assert_allclose(dirs[0], [math.sin(widest), 0.0, math.cos(widest)], atol=1e-12)
    theta = np.linspace(0.0, widest, 50)
    np.testing.assert_allclose(fisheye_angle_from_distorted(fisheye_distorted_angle(theta, FOLDING), FOLDING), theta,
                               atol=1e-9)


def test_unknown_model_is_an_input_error():
    with pytest.raises(InputError, match="unknown camera model 'fov'"):
        camera_directions_from_pixels(np.zeros((1, 2)), 1.0, 1.0, 0.0, 0.0, None, "fov")
    with pytest.raises(InputError, match="unknown camera model"):
        pixels_from_camera_points(np.ones((1, 3)), 1.0, 1.0, 0.0, 0.0, None, "fov")


# ---------------------------------------------------------------------------------------------
# Cameras.model


def fisheye_camera(c2w=None) -> Cameras:
    return Cameras.create(np.eye(4) if c2w is None else c2w, FX, FY, CX, CY, W, H, distortion=K, model="fisheye",
                          near=0.1, far=10.0)


def test_cameras_model_defaults_to_pinhole_and_is_kept():
    plain = Cameras.create(np.stack([np.eye(4)] * 2), 10.0, 10.0, 5.0, 5.0, 10, 10)
    np.testing.assert_array_equal(plain.model, ["pinhole", "pinhole"])
    legacy = Cameras(**{name: getattr(plain, name) for name in plain.__dataclass_fields__ if name != "model"})
    np.testing.assert_array_equal(legacy.model, "pinhole")
    mixed = Cameras.create(np.stack([np.eye(4)] * 3), 10.0, 10.0, 5.0, 5.0, 10, 10, model=["pinhole", "fisheye", "pinhole"])
    np.testing.assert_array_equal(mixed[1].model, ["fisheye"])
    np.testing.assert_array_equal(mixed[[2, 1]].is_fisheye, [False, True])
    with pytest.raises(InputError, match="unknown camera model 'fov'"):
        Cameras.create(np.eye(4), 10.0, 10.0, 5.0, 5.0, 10, 10, model="fov")


def test_camera_records_round_trip_and_old_records_load_as_pinholes():
    cams = Cameras.create(np.stack([np.eye(4)] * 2), FX, FY, CX, CY, W, H, distortion=K, model=["fisheye", "pinhole"])
    record = cameras_to_dict(cams)
    assert record["model"] == ["fisheye", "pinhole"]
    back = cameras_from_dict(record)
    for name in cams.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(back, name), getattr(cams, name))
    old = {key: value for key, value in record.items() if key != "model"}  # a checkpoint from before fisheyes
    np.testing.assert_array_equal(cameras_from_dict(old).model, ["pinhole", "pinhole"])


def test_world_rays_of_a_fisheye_camera_follow_its_model():
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float)  # looking along world +x
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    origins, directions = rays_from_cameras(fisheye_camera(c2w), 0)
    assert origins.shape == directions.shape == (W * H, 3)
    want = camera_directions_from_pixels(pixel_grid(W, H), FX, FY, CX, CY, K, "fisheye") @ c2w[:3, :3].T
    np.testing.assert_allclose(directions, want, atol=1e-12)
    assert np.sum(directions[:, 0] < 0) > 0  # some rays look backwards (world -x)


def test_fisheye_and_pinhole_rays_meet_the_same_world_points():
    """A world point a pinhole pixel sees is seen by the fisheye (rotated, same centre) at the pixel
    its projection gives, and that fisheye pixel's ray meets the point."""
    centre = np.array([0.2, -0.1, 0.0])
    angle = 0.5
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])
    c2w[:3, 3] = centre
    fisheye = fisheye_camera(c2w)
    pin = np.eye(4)
    pin[:3, 3] = centre
    pinhole = Cameras.create(pin, 40.0, 40.0, 16.0, 12.0, 32, 24)
    origins, directions = rays_from_cameras(pinhole, 0)
    t = (2.0 - origins[:, 2]) / directions[:, 2]  # the plane z = 2 in front of the pinhole
    points = origins + t[:, None] * directions
    uv, _, dist = project_points(points, fisheye.c2w[0], FX, FY, CX, CY, K, "fisheye")
    assert np.all((uv >= 0) & (uv < [W, H]))  # the whole pinhole view lies inside the fisheye image
    f_origins, f_directions = rays_from_cameras(fisheye, 0, uv)
    np.testing.assert_allclose(f_origins + dist[:, None] * f_directions, points, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# users of the model: visibility, rerun depth


def test_scaled_fisheye_keeps_its_model_and_rays():
    cams = Cameras.create(np.stack([np.eye(4)] * 2), 2 * FX, 2 * FY, 2 * CX, 2 * CY, 2 * W, 2 * H,
                          distortion=[K, [0.1, 0, 0, 0]], model=["fisheye", "pinhole"])
    small = scaled_cameras(cams, W)
    np.testing.assert_array_equal(small.model, ["fisheye", "pinhole"])
    np.testing.assert_array_equal(small.distortion, [K, np.zeros(4)])  # a pinhole's distortion dropped
    a = camera_directions_from_pixels(np.array([[0.5, 0.5]]), small.fx[0], small.fy[0], small.cx[0], small.cy[0],
                                      small.distortion[0], "fisheye")
    b = camera_directions_from_pixels(np.array([[1.0, 1.0]]), 2 * FX, 2 * FY, 2 * CX, 2 * CY, K, "fisheye")
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_visibility_sees_through_the_fisheye_model():
    """A point 120° off the axis is seen by the fisheye (its pixel's depth is beyond it), not by a
    pinhole with the same intrinsics; a point behind that pixel's surface is not seen."""
    cams = fisheye_camera()
    theta = math.radians(120.0)
    ray = np.array([math.sin(theta), 0.0, math.cos(theta)])
    uv = pixels_from_camera_points(ray[None], FX, FY, CX, CY, K, "fisheye")[0]
    col, row = int(uv[0]), int(uv[1])
    depth = np.full((H, W), np.inf)
    depth[row, col] = 2.0
    points = np.stack([1.5 * ray, 3.0 * ray])  # in front of, behind the surface at 2
    np.testing.assert_array_equal(visible_from_cameras(points, cams, [depth], margin=0.1, pixel_margin=0.0), [True, False])
    pinhole = Cameras(**{**vars(cams), "model": np.array(["pinhole"]), "distortion": np.zeros((1, 4))})
    assert not visible_from_cameras(points[:1], pinhole, [depth], margin=0.1).any()


def test_z_depth_of_a_fisheye():
    depth = np.full((H, W), 2.0)
    z = z_depth_from_ray_depth(depth, FX, FY, CX, CY, K, "fisheye").reshape(-1)
    dirs = camera_directions_from_pixels(pixel_grid(W, H), FX, FY, CX, CY, K, "fisheye")
    ahead = dirs[:, 2] > MIN_DIRECTION_Z
    np.testing.assert_allclose(z[ahead], 2.0 * dirs[ahead, 2], atol=1e-6)
    assert (~ahead).any() and np.isnan(z[~ahead]).all()  # 90° or more off the axis: no z-depth


# resampling to the ideal pinhole (what rerun's Pinhole draws)
def _image_of_a_function(fn, w, h, fx, fy, cx, cy, distortion, model):
    """[h, w] image whose pixel shows fn(a, b) of the point (a, b, 1) its ray meets (a pinhole's
    normalised coordinates)."""
    rays = camera_directions_from_pixels(pixel_grid(w, h), fx, fy, cx, cy, distortion, model)  # [h w, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return fn(rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]).reshape(h, w)


@pytest.mark.parametrize("distortion, model", [((0.12, -0.04, 0.004, -0.003), PINHOLE), ((0.05, -0.01, 0.0, 0.0), FISHEYE)])
def test_ideal_pinhole_image_undoes_the_lens(distortion, model):
    w, h, fx, fy, cx, cy = 64, 48, 40.0, 42.0, 31.0, 25.0
    plane = lambda a, b: 3.0 + 2.0 * a - 1.5 * b  # noqa: E731 - linear in the ideal pinhole's coordinates
    seen = _image_of_a_function(plane, w, h, fx, fy, cx, cy, distortion, model)
    ideal = ideal_pinhole_image(seen, fx, fy, cx, cy, distortion, model, fill=np.nan)
    want = _image_of_a_function(plane, w, h, fx, fy, cx, cy, None, PINHOLE)
    inside = np.isfinite(ideal)
    assert inside.mean() > 0.8
    np.testing.assert_allclose(ideal[inside], want[inside], atol=0.02)  # bilinear blend of a curved map of a plane
    # labels: nearest, no blend, and the lens's own ideal pinhole is left as it is
    labels = (seen > 3.0).astype(np.int16)
    ideal_labels = ideal_pinhole_image(labels, fx, fy, cx, cy, distortion, model, nearest=True, fill=-1)
    assert ideal_labels.dtype == np.int16 and set(np.unique(ideal_labels)) <= {-1, 0, 1}
    agree = (ideal_labels >= 0) & (np.abs(want - 3.0) > 0.1)
    np.testing.assert_array_equal(ideal_labels[agree], (want[agree] > 3.0).astype(np.int16))
    np.testing.assert_array_equal(ideal_pinhole_image(labels, fx, fy, cx, cy), labels)


def test_ideal_pinhole_image_fills_rays_the_lens_did_not_image():
    """Pincushion distortion (k1 > 0) pushes the ideal pinhole's corner rays out of the image."""
    image = np.full((40, 40, 3), 200, np.uint8)
    out = ideal_pinhole_image(image, 10.0, 10.0, 20.0, 20.0, (0.3, 0.0, 0.0, 0.0), PINHOLE, fill=7)
    assert out.dtype == np.uint8 and out.shape == image.shape
    assert (out[20, 20] == 200).all() and (out[0, 0] == 7).all()
