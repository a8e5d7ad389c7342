"""Cameras in scenelabel's conventions (docs/conventions.md): OpenCV camera axes (x right, y down,
z forward), ``c2w`` camera-to-world in the input's world frame and units, intrinsics in pixels with
the centre of pixel (col, row) at (col + 0.5, row + 0.5); their (de)serialisation for checkpoints
and the OpenGL <-> OpenCV axis conversion every loader and writer uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from scenelabel.errors import InputError

__all__ = ["Cameras", "OPENGL_TO_OPENCV", "opengl_to_opencv", "opencv_to_opengl", "cameras_to_dict", "cameras_from_dict"]

#: Right-multiplying an OpenGL-axes camera-to-world by this flips camera y and z: OpenCV axes (and
#: back: the matrix is its own inverse).
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

CAMERA_FIELDS = ("c2w", "fx", "fy", "cx", "cy", "width", "height", "distortion", "near", "far")
"""The fields of :class:`Cameras` a camera record (:func:`cameras_to_dict`) carries."""

INT_FIELDS = ("width", "height")


@dataclass(frozen=True)
class Cameras:
    """A batch of pinhole cameras (optionally with OpenCV radial-tangential distortion).

    Attributes:
        c2w: [n, 4, 4] float64 camera-to-world, OpenCV axes (x right, y down, z forward).
        fx, fy, cx, cy: [n] float64 intrinsics in pixels (cx, cy from the top-left image corner).
        width, height: [n] int64 image size in pixels.
        distortion: [n, 4] float64 OpenCV (k1, k2, p1, p2); zeros for an ideal pinhole.
        near, far: [n] float64 scene depth range seen by each camera (distance along the unit
            ray); NaN where the input does not say.
    """

    c2w: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    width: np.ndarray
    height: np.ndarray
    distortion: np.ndarray
    near: np.ndarray
    far: np.ndarray

    def __post_init__(self) -> None:
        n = self.c2w.shape[0] if self.c2w.ndim == 3 else -1
        if self.c2w.shape != (n, 4, 4):
            raise InputError(f"c2w must have shape [n, 4, 4], got {self.c2w.shape}", field="c2w")
        for name in ("fx", "fy", "cx", "cy", "width", "height", "near", "far"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"{name} must have shape [{n}], got {getattr(self, name).shape}", field=name)
        if self.distortion.shape != (n, 4):
            raise InputError(f"distortion must have shape [{n}, 4], got {self.distortion.shape}", field="distortion")

    @staticmethod
    def create(
        c2w: np.ndarray,
        fx,
        fy,
        cx,
        cy,
        width,
        height,
        distortion=None,
        near=None,
        far=None,
    ) -> "Cameras":
        """Build cameras from per-camera arrays or scalars broadcast to all cameras."""
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.ndim == 2:
            c2w = c2w[None]
        n = c2w.shape[0]

        def per_cam(value, dtype, default=np.nan):
            value = default if value is None else value
            return np.broadcast_to(np.asarray(value, dtype=dtype), (n,)).copy()

        dist = np.zeros((n, 4)) if distortion is None else np.broadcast_to(np.asarray(distortion, np.float64), (n, 4)).copy()
        return Cameras(
            c2w=c2w,
            fx=per_cam(fx, np.float64),
            fy=per_cam(fy, np.float64),
            cx=per_cam(cx, np.float64),
            cy=per_cam(cy, np.float64),
            width=per_cam(width, np.int64),
            height=per_cam(height, np.int64),
            distortion=dist,
            near=per_cam(near, np.float64),
            far=per_cam(far, np.float64),
        )

    def __len__(self) -> int:
        return self.c2w.shape[0]

    def __getitem__(self, index) -> "Cameras":
        """Cameras at ``index`` (an int, slice, or index array); always a batch."""
        index = np.atleast_1d(np.arange(len(self))[index])
        return Cameras(**{name: getattr(self, name)[index] for name in self.__dataclass_fields__})

    @property
    def centres(self) -> np.ndarray:
        """[n, 3] camera centres in world coordinates."""
        return self.c2w[:, :3, 3]

    @property
    def has_distortion(self) -> np.ndarray:
        """[n] bool: the camera has non-zero distortion coefficients."""
        return np.any(self.distortion != 0, axis=1)


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:
    """Camera-to-world with OpenGL camera axes -> OpenCV camera axes: ``c2w @ diag(1, -1, -1, 1)``.

    Works on [4, 4] or [..., 4, 4]; camera centres are unchanged, camera y and z flip.
    """
    return np.asarray(c2w, dtype=np.float64) @ OPENGL_TO_OPENCV


def opencv_to_opengl(c2w: np.ndarray) -> np.ndarray:
    """Camera-to-world with OpenCV camera axes -> OpenGL camera axes (the inverse of
    :func:`opengl_to_opencv`, the same flip)."""
    return np.asarray(c2w, dtype=np.float64) @ OPENGL_TO_OPENCV


def cameras_to_dict(cameras: Cameras) -> dict[str, list]:
    """Cameras as plain lists (for checkpoints): the fields of :class:`Cameras`."""
    return {name: getattr(cameras, name).tolist() for name in CAMERA_FIELDS}


def cameras_from_dict(data: dict[str, Any]) -> Cameras:
    """Inverse of :func:`cameras_to_dict`."""
    try:
        return Cameras(
            **{
                name: np.asarray(data[name], dtype=np.int64 if name in INT_FIELDS else np.float64)
                for name in CAMERA_FIELDS
            }
        )
    except KeyError as err:
        raise InputError(f"camera record lacks {err.args[0]!r}", field=str(err.args[0])) from None
