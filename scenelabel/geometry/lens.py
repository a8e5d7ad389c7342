"""Lens models: pixels <-> camera-frame rays for the camera models :class:`scenelabel.Cameras`
carries (docs/conventions.md, "Camera models"). Pure numpy functions, float64.

Both models keep their four coefficients in ``Cameras.distortion`` and act on normalised
coordinates (so they survive a change of image resolution unchanged):

- ``"pinhole"``: OpenCV's radial-tangential model, ``distortion = (k1, k2, p1, p2)``. A camera-frame
  point ``(x, y, z)`` with ``z > 0`` has ``a = x / z``, ``b = y / z``, ``r² = a² + b²`` and::

      a' = a (1 + k1 r² + k2 r⁴) + 2 p1 a b + p2 (r² + 2 a²)
      b' = b (1 + k1 r² + k2 r⁴) + p1 (r² + 2 b²) + 2 p2 a b
      (u, v) = (fx a' + cx, fy b' + cy)

- ``"fisheye"``: OpenCV's equidistant fisheye (``cv2.fisheye``, COLMAP's ``OPENCV_FISHEYE``),
  ``distortion = (k1, k2, k3, k4)``. With ``θ`` the angle between the ray and the optical axis
  (``atan2(√(x² + y²), z)``, anywhere in [0, π]: a fisheye sees past 90°) and ``φ = atan2(y, x)``::

      θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
      (u, v) = (fx θ_d cos φ + cx, fy θ_d sin φ + cy)

  ``k = 0`` is the ideal equidistant lens, image radius ``f θ``. The model is used only up to
  :func:`fisheye_max_angle`, where ``θ_d(θ)`` stops increasing (π at most): beyond it the
  polynomial folds back and a pixel would have two rays. Directions are built from ``θ`` and
  ``φ`` directly, never through ``tan θ``, so they stay finite and unit up to 180°.
"""

from __future__ import annotations

import math

import numpy as np

from scenelabel.errors import InputError

__all__ = [
    "CAMERA_MODELS",
    "PINHOLE",
    "FISHEYE",
    "fisheye_distorted_angle",
    "fisheye_max_angle",
    "fisheye_angle_from_distorted",
    "fisheye_directions_from_pixels",
    "pixels_from_camera_points",
    "project_points",
    "inside_image",
    "is_ideal_pinhole",
    "ideal_pinhole_image",
]

PINHOLE = "pinhole"
"""Pinhole with OpenCV radial-tangential distortion (k1, k2, p1, p2)."""

FISHEYE = "fisheye"
"""OpenCV equidistant fisheye (k1, k2, k3, k4)."""

CAMERA_MODELS = (PINHOLE, FISHEYE)
"""The camera models a :class:`scenelabel.Cameras` can hold, per camera."""

ROOT_IMAG_EPS = 1e-9
"""A root of dθ_d/dθ (as a polynomial in θ²) counts as real when its imaginary part is at most
this times max(1, |root|) (numerical noise of the companion-matrix eigenvalues)."""

NEWTON_TOL = 1e-15
"""The inverse of θ_d(θ) stops once every Newton step is at most this many radians."""

NEWTON_MAX_ITER = 100
"""At most this many safeguarded Newton steps (each falls back to bisection when it would leave
the bracket, so the bracket at least halves: 100 steps reach float64 resolution of any angle)."""


def _fisheye_coefficients(k) -> np.ndarray:
    k = np.asarray(k, dtype=np.float64).reshape(-1)
    if k.shape != (4,):
        raise InputError(f"fisheye distortion needs 4 coefficients (k1, k2, k3, k4), got {k.shape[0]}", field="distortion")
    return k


def fisheye_distorted_angle(theta: np.ndarray, k) -> np.ndarray:
    """``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` (the equidistant fisheye's radius / f).

    Args:
        theta: [n] angles from the optical axis, radians.
        k: [4] (k1, k2, k3, k4).
    Returns:
        [n] float64.
    """
    k1, k2, k3, k4 = _fisheye_coefficients(k)
    theta = np.asarray(theta, dtype=np.float64)
    s = theta * theta
    return theta * (1.0 + s * (k1 + s * (k2 + s * (k3 + s * k4))))


def _fisheye_slope(theta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """dθ_d/dθ = 1 + 3 k1 θ² + 5 k2 θ⁴ + 7 k3 θ⁶ + 9 k4 θ⁸."""
    k1, k2, k3, k4 = k
    s = theta * theta
    return 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * (7.0 * k3 + s * 9.0 * k4)))


def fisheye_max_angle(k) -> float:
    """The widest angle (radians) the fisheye model maps one-to-one: the first ``θ > 0`` where
    ``dθ_d/dθ`` reaches 0, or π when it stays positive up to π (always with ``k = 0``).

    Args:
        k: [4] (k1, k2, k3, k4).
    """
    k1, k2, k3, k4 = _fisheye_coefficients(k)
    roots = np.polynomial.polynomial.polyroots(np.trim_zeros([1.0, 3 * k1, 5 * k2, 7 * k3, 9 * k4], "b"))  # in s = θ²
    real = roots[np.abs(roots.imag) <= ROOT_IMAG_EPS * np.maximum(1.0, np.abs(roots))].real
    real = real[real > 0]
    return float(min(math.pi, math.sqrt(real.min()))) if real.size else math.pi


def fisheye_angle_from_distorted(theta_d: np.ndarray, k, theta_max: float | None = None) -> np.ndarray:
    """Inverse of :func:`fisheye_distorted_angle` on [0, ``theta_max``]: safeguarded Newton
    (bisection whenever a step would leave the bracket), vectorised.

    Args:
        theta_d: [n] distorted angles (image radius / f), >= 0.
        k: [4] (k1, k2, k3, k4).
        theta_max: the model's widest angle (default :func:`fisheye_max_angle`); ``θ_d`` beyond
            ``θ_d(theta_max)`` (outside the lens's model) gives ``theta_max``.
    Returns:
        [n] float64 θ in [0, theta_max].
    """
    k = _fisheye_coefficients(k)
    theta_max = fisheye_max_angle(k) if theta_max is None else float(theta_max)
    target = np.clip(np.asarray(theta_d, dtype=np.float64), 0.0, fisheye_distorted_angle(theta_max, k))
    lo = np.zeros_like(target)
    hi = np.full_like(target, theta_max)
    theta = np.minimum(target, theta_max)  # exact for k = 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(NEWTON_MAX_ITER):
            residual = fisheye_distorted_angle(theta, k) - target
            lo = np.where(residual < 0, theta, lo)
            hi = np.where(residual > 0, theta, hi)
            new = theta - residual / _fisheye_slope(theta, k)
            new = np.where(residual == 0, theta, new)
            stray = ~((new >= lo) & (new <= hi))  # out of the bracket, or not finite (slope 0)
            new = np.where(stray, 0.5 * (lo + hi), new)
            step = np.abs(new - theta)
            theta = new
            if not np.any(step > NEWTON_TOL):
                break
    return theta


def fisheye_directions_from_pixels(pixels: np.ndarray, fx: float, fy: float, cx: float, cy: float, k) -> np.ndarray:
    """Camera-frame (OpenCV axes) unit directions through pixels of an equidistant fisheye.

    ``(θ_d cos φ, θ_d sin φ) = ((u - cx) / fx, (v - cy) / fy)``; θ from
    :func:`fisheye_angle_from_distorted`; direction ``(sin θ cos φ, sin θ sin φ, cos θ)``, so
    pixels at or past 90° from the axis still get finite unit directions (z <= 0). Pixels
    beyond the model's widest angle (:func:`fisheye_max_angle`) get the ray at that angle.

    Args:
        pixels: [n, 2] (u, v); a pixel's centre is (col + 0.5, row + 0.5).
        fx, fy, cx, cy: intrinsics in pixels.
        k: [4] (k1, k2, k3, k4).
    Returns:
        [n, 3] float64 unit directions.
    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    xd = (pixels[:, 0] - cx) / fx  # [n] θ_d cos φ
    yd = (pixels[:, 1] - cy) / fy  # [n] θ_d sin φ
    theta_d = np.hypot(xd, yd)
    theta = fisheye_angle_from_distorted(theta_d, k)
    on_axis = theta_d == 0
    safe = np.where(on_axis, 1.0, theta_d)
    cos_phi = np.where(on_axis, 1.0, xd / safe)
    sin_phi = np.where(on_axis, 0.0, yd / safe)
    sin_theta = np.sin(theta)
    dirs = np.stack([sin_theta * cos_phi, sin_theta * sin_phi, np.cos(theta)], axis=-1)
    return dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)


def pixels_from_camera_points(
    points: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion=None,
    model: str = PINHOLE,
) -> np.ndarray:
    """Project camera-frame points (OpenCV axes) to continuous pixel coordinates (module docstring).

    The inverse of :func:`scenelabel.geometry.rays.camera_directions_from_pixels` (any point on a
    pixel's ray projects back to that pixel). A pinhole projects points with ``z > 0`` (its
    distortion applied as OpenCV's ``projectPoints`` does, which, like OpenCV, may fold points
    far outside the calibrated field back into the image); a fisheye projects every point within
    :func:`fisheye_max_angle` of its axis, behind the image plane included.

    Args:
        points: [n, 3] camera-frame points.
        fx, fy, cx, cy: intrinsics in pixels (pixel centres at +0.5).
        distortion: [4] the model's coefficients, or None for zeros.
        model: ``"pinhole"`` or ``"fisheye"``.
    Returns:
        [n, 2] float64 (u, v); NaN where the model does not project the point (a pinhole: ``z <= 0``;
        a fisheye: beyond its widest angle, or the camera centre itself).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    coeffs = np.zeros(4) if distortion is None else np.asarray(distortion, dtype=np.float64).reshape(4)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if model == PINHOLE:
            valid = z > 0
            a = np.where(valid, x / z, np.nan)
            b = np.where(valid, y / z, np.nan)
            k1, k2, p1, p2 = coeffs
            if np.any(coeffs != 0):
                r2 = a * a + b * b
                radial = 1.0 + r2 * (k1 + r2 * k2)
                a, b = (
                    a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a),
                    b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b,
                )
        elif model == FISHEYE:
            r = np.hypot(x, y)
            theta = np.arctan2(r, z)
            valid = (theta <= fisheye_max_angle(coeffs)) & ((r > 0) | (z > 0))
            scale = np.where(r > 0, fisheye_distorted_angle(theta, coeffs) / np.where(r > 0, r, 1.0), 0.0)
            a = np.where(valid, x * scale, np.nan)
            b = np.where(valid, y * scale, np.nan)
        else:
            raise InputError(f"unknown camera model {model!r}; known: {', '.join(CAMERA_MODELS)}", field="model")
    return np.stack([fx * a + cx, fy * b + cy], axis=-1)


def project_points(
    points: np.ndarray,
    c2w: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion: np.ndarray | None = None,
    model: str = PINHOLE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Projection of world points into one camera (OpenCV axes) through its lens model
    (:func:`pixels_from_camera_points`; an ideal pinhole by default).

    Args:
        points: [N, 3] world points.
        c2w: [4, 4] camera-to-world (OpenCV axes: x right, y down, z forward).
        fx, fy, cx, cy: intrinsics in pixels (pixel centres at +0.5).
        distortion: [4] the model's coefficients, or None (zeros).
        model: ``"pinhole"`` or ``"fisheye"``.
    Returns:
        uv: [N, 2] continuous pixel coordinates (NaN where the model does not project the
            point: for a pinhole ``z <= 0``, not in front).
        z: [N] camera-frame z (forward) of each point.
        dist: [N] distance from the camera centre, i.e. the depth along the point's unit ray.
    """
    rel = np.asarray(points, np.float64) - c2w[:3, 3]  # [N, 3] world offsets from the centre
    cam = rel @ c2w[:3, :3]  # [N, 3] camera frame: R^T (p - t)
    uv = pixels_from_camera_points(cam, fx, fy, cx, cy, distortion, model)  # [N, 2]
    return uv, cam[:, 2], np.linalg.norm(rel, axis=-1)


def inside_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """[n] bool: the continuous pixel coordinates uv [n, 2] lie in a width x height image
    (``0 <= u < width``, ``0 <= v < height``; NaN is outside)."""
    with np.errstate(invalid="ignore"):
        return (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)


def is_ideal_pinhole(distortion=None, model: str = PINHOLE) -> bool:
    """True for a pinhole without distortion (what viewers such as rerun's Pinhole draw)."""
    return model == PINHOLE and (distortion is None or not np.any(np.asarray(distortion) != 0))


def ideal_pinhole_image(
    image: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    distortion=None,
    model: str = PINHOLE,
    *,
    nearest: bool = False,
    fill: float = 0.0,
) -> np.ndarray:
    """An image resampled to the ideal pinhole with the same fx, fy, cx, cy and size: pixel (u, v) of
    the result shows what the camera's own lens (``distortion``, ``model``) saw along the ray
    ``((u - cx) / fx, (v - cy) / fy, 1)`` (pixel centres at +0.5). Values that do not depend on the
    pixel's ray (colour, labels, z-depth) stay valid; a depth along the ray does not.

    Args:
        image: [h, w] or [h, w, k], in the camera's own lens.
        fx, fy, cx, cy, distortion, model: the camera (:func:`pixels_from_camera_points`).
        nearest: take the nearest pixel (labels, depths) instead of a bilinear blend.
        fill: the value of pixels whose ray falls outside the camera's image.
    Returns:
        [h, w] or [h, w, k], the dtype of ``image``.
    """
    from scipy.ndimage import map_coordinates

    image = np.asarray(image)
    if is_ideal_pinhole(distortion, model):
        return image.copy()
    h, w = image.shape[:2]
    v, u = np.mgrid[0:h, 0:w] + 0.5  # [h, w] pixel centres of the ideal pinhole
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1).reshape(-1, 3)
    src = pixels_from_camera_points(rays, fx, fy, cx, cy, distortion, model)  # [h w, 2], NaN: not imaged
    seen = inside_image(src, w, h)
    coords = [np.clip(np.nan_to_num(src[:, 1]) - 0.5, 0, h - 1), np.clip(np.nan_to_num(src[:, 0]) - 0.5, 0, w - 1)]
    channels = image.reshape(h, w, -1).astype(np.float64)
    out = np.stack([
        np.where(seen, map_coordinates(channels[..., c], coords, order=0 if nearest else 1, mode="nearest"), fill)
        for c in range(channels.shape[-1])
    ], -1)
    if np.issubdtype(image.dtype, np.integer):
        out = np.rint(out)
    return out.reshape(image.shape).astype(image.dtype)
