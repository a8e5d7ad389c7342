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
from scenelabel.geometry.lens import CAMERA_MODELS, FISHEYE, PINHOLE

__all__ = ["Cameras", "OPENGL_TO_OPENCV", "opengl_to_opencv", "opencv_to_opengl", "cameras_to_dict", "cameras_from_dict"]

#: Right-multiplying an OpenGL-axes camera-to-world by this flips camera y and z: OpenCV axes (and
#: back: the matrix is its own inverse).
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

CAMERA_FIELDS = ("c2w", "fx", "fy", "cx", "cy", "width", "height", "distortion", "near", "far")
"""The fields of :class:`Cameras` a camera record (:func:`cameras_to_dict`) carries ..."""

OPTIONAL_CAMERA_FIELDS = {"model": PINHOLE}
"""... and those it may lack (a record written before the field existed), with their default."""

INT_FIELDS = ("width", "height")


@dataclass(frozen=True)
class Cameras:
    """A batch of cameras: pinholes (optionally with OpenCV radial-tangential distortion) or
    equidistant fisheyes (docs/conventions.md, "Camera models"; :mod:`scenelabel.geometry.lens`).

    Attributes:
        c2w: [n, 4, 4] float64 camera-to-world, OpenCV axes (x right, y down, z forward).
        fx, fy, cx, cy: [n] float64 intrinsics in pixels (cx, cy from the top-left image corner).
        width, height: [n] int64 image size in pixels.
        distortion: [n, 4] float64 the model's coefficients: a pinhole's OpenCV (k1, k2, p1, p2),
            zeros for an ideal pinhole; a fisheye's OpenCV (k1, k2, k3, k4).
        near, far: [n] float64 scene depth range seen by each camera (distance along the unit
            ray); NaN where the input does not say.
        model: [n] str, ``"pinhole"`` or ``"fisheye"`` per camera; None (the default) means every
            camera is a pinhole.
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
    model: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = self.c2w.shape[0] if self.c2w.ndim == 3 else -1
        if self.c2w.shape != (n, 4, 4):
            raise InputError(f"c2w must have shape [n, 4, 4], got {self.c2w.shape}", field="c2w")
        for name in ("fx", "fy", "cx", "cy", "width", "height", "near", "far"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"{name} must have shape [{n}], got {getattr(self, name).shape}", field=name)
        if self.distortion.shape != (n, 4):
            raise InputError(f"distortion must have shape [{n}, 4], got {self.distortion.shape}", field="distortion")
        model = np.full(n, PINHOLE) if self.model is None else np.asarray(self.model, dtype=np.str_)
        if model.shape != (n,):
            raise InputError(f"model must have shape [{n}], got {model.shape}", field="model")
        unknown = sorted(set(model.tolist()) - set(CAMERA_MODELS))
        if unknown:
            raise InputError(f"unknown camera model {unknown[0]!r}; known: {', '.join(CAMERA_MODELS)}", field="model")
        object.__setattr__(self, "model", model)

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
        model=None,
    ) -> "Cameras":
        """Build cameras from per-camera arrays or scalars broadcast to all cameras (``model``:
        ``"pinhole"`` when None)."""
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
            model=per_cam(model, np.str_, PINHOLE),
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
        """[n] bool: the camera has non-zero distortion coefficients (a fisheye without is still
        a fisheye: see ``model``)."""
        return np.any(self.distortion != 0, axis=1)

    @property
    def is_fisheye(self) -> np.ndarray:
        """[n] bool: the camera is an equidistant fisheye."""
        return self.model == FISHEYE


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
    return {name: getattr(cameras, name).tolist() for name in (*CAMERA_FIELDS, *OPTIONAL_CAMERA_FIELDS)}


def cameras_from_dict(data: dict[str, Any]) -> Cameras:
    """Inverse of :func:`cameras_to_dict`; a record without ``model`` (written before fisheye
    cameras existed) holds pinholes."""
    try:
        fields = {
            name: np.asarray(data[name], dtype=np.int64 if name in INT_FIELDS else np.float64) for name in CAMERA_FIELDS
        }
        n = fields["c2w"].shape[0] if fields["c2w"].ndim == 3 else 0
        for name, default in OPTIONAL_CAMERA_FIELDS.items():
            fields[name] = np.asarray(data.get(name, [default] * n), dtype=np.str_)
        return Cameras(**fields)
    except KeyError as err:
        raise InputError(f"camera record lacks {err.args[0]!r}", field=str(err.args[0])) from None
