"""Textures of the synthetic scenes: smooth, low-frequency, learnable by a small NeRF.

Each builder returns a :data:`~scenelabel.data.synthetic.geometry.Texture`, a function
(points [n, 3], normals [n, 3]) -> albedo [n, 3] on axis-aligned faces.
"""

from __future__ import annotations

import numpy as np

from scenelabel.data.synthetic.geometry import Texture

__all__ = [
    "plain_with_stripes", "checker_texture", "wood_texture", "wall_texture", "pattern_value", "patterned_texture",
]


def _soft_checker(a: np.ndarray, b: np.ndarray, period: float, sharpness: float = 2.5) -> np.ndarray:
    """Soft-edged checker in [0, 1] over coordinates a, b with the given period (world units)."""
    s = np.sin(2 * np.pi * a / period) * np.sin(2 * np.pi * b / period)
    return 0.5 + 0.5 * np.tanh(sharpness * s) / np.tanh(sharpness)


def _blend(t: np.ndarray, c0, c1) -> np.ndarray:
    """[n, 3] linear blend of two colours by t [n] in [0, 1]."""
    return (1.0 - t)[:, None] * np.asarray(c0, np.float64) + t[:, None] * np.asarray(c1, np.float64)


def _face_coords(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two in-face coordinates of points on axis-aligned faces (drop the normal's axis)."""
    axis = np.abs(normals).argmax(axis=1)
    a = np.where(axis == 0, points[:, 1], points[:, 0])
    b = np.where(axis == 2, points[:, 1], points[:, 2])
    return a, b


def plain_with_stripes(color, amplitude: float = 0.08, period: float = 0.25) -> Texture:
    """Plain colour modulated by a subtle diagonal sinusoid on each face."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, b = _face_coords(points, normals)
        mod = 1.0 + amplitude * np.sin(2 * np.pi * (a + b) / period)
        return np.asarray(color, np.float64)[None] * mod[:, None]

    return texture


def checker_texture(c0, c1, period: float) -> Texture:
    """Soft checker between two colours on each face."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, b = _face_coords(points, normals)
        return _blend(_soft_checker(a, b, period), c0, c1)

    return texture


def wood_texture(c0, c1, period: float, along_axis: int = 0) -> Texture:
    """Smooth plank-like bands across ``along_axis`` with a slow wobble."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        other = 1 - along_axis if along_axis < 2 else 0
        x = points[:, along_axis] + 0.04 * np.sin(2 * np.pi * points[:, other] / 1.3)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * x / period)
        return _blend(t, c0, c1)

    return texture


def wall_texture(c0, c1, period: float) -> Texture:
    """Soft vertical stripes along the wall plus a gentle vertical gradient."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        a, _ = _face_coords(points, normals)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * a / period)
        base = _blend(t, c0, c1)
        return base * (0.92 + 0.08 * np.clip(points[:, 2] / 2.6, 0, 1))[:, None]

    return texture


def pattern_value(name: str, points: np.ndarray, normals: np.ndarray, period: float) -> np.ndarray:
    """[n] the scene suite's pattern ``name`` in [0, 1] at ``points`` [n, 3] on faces with ``normals``
    [n, 3]: "checker" (soft edges), "stripes", "diagonal", "wood" (bands across x + y with a slow
    wobble), "tiles" (1 on soft grout lines) or "painting" (incommensurate sinusoids, blotchy)."""
    a, b = _face_coords(points, normals)
    w = 2 * np.pi / period
    if name == "checker":  # soft edges: antialiased by the 2x2 supersampling
        return _soft_checker(a, b, period, sharpness=1.5)
    if name == "stripes":
        return 0.5 + 0.5 * np.sin(w * a)
    if name == "diagonal":
        return 0.5 + 0.5 * np.sin(w * (a + b))
    if name == "wood":
        return 0.5 + 0.5 * np.sin(w * (points[:, 0] + points[:, 1] + 0.04 * np.sin(2 * np.pi * points[:, 2] / 1.3)))
    if name == "tiles":
        return np.maximum(np.cos(w * a / 2) ** 4, np.cos(w * b / 2) ** 4)
    return 0.5 + (np.sin(w * a) + np.sin(w * (0.6 * a + b) / 1.7) + np.sin(w * b / 0.7)) / 6.0


def patterned_texture(
    pattern: str, c0, c1, period: float, contrast: float = 1.0, gradient_height: float | None = None
) -> Texture:
    """Two colours blended by :func:`pattern_value` around its middle with ``contrast`` (0: the mean
    colour, 1: the full pattern); with ``gradient_height``, 7 % darker at the floor than at that height
    (walls)."""

    def texture(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        t = 0.5 + contrast * (pattern_value(pattern, points, normals, period) - 0.5)
        rgb = _blend(t, c0, c1)
        if gradient_height is not None:
            rgb = rgb * (0.93 + 0.07 * np.clip(points[:, 2] / gradient_height, 0, 1))[:, None]
        return rgb

    return texture
