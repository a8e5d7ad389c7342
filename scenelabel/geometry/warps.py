"""Where the field spends its resolution: maps from the normalised frame to the encoding's cube.

The field and its density grid see points through a *warp* ``w: R^3 -> [-1, 1]^3`` (points that
map outside the cube have no density). Queries, renders, depths and maps stay in the input's world
frame: a warp only decides which world points share an encoding cell, it never changes the
geometry the user sees, and densities stay per world unit (unlike NDC rendering, which changes
the ray parameter itself).

- :class:`BoxWarp`: the scene box scaled to the cube (uniform resolution): inward-looking
  captures (a room, an object orbit).
- :class:`ForwardWarp`: for forward-facing captures (LLFF-style: every camera looks the same
  way at a scene that extends far in depth). A reference camera's frustum is mapped to the cube
  projectively, ``u = x / (z tan_x)``, ``v = y / (z tan_y)`` and ``s`` linear in ``1 / z`` from
  -1 at ``near`` to +1 at ``far``, the map NeRF's NDC uses for its rays (Mildenhall et al. 2020,
  appendix C), so a cell's world size grows with depth like a pixel's footprint does. Rays
  through such a field are sampled uniformly in disparity (:func:`scenelabel.render.sampling.march_disparity`).

Both are thin modules over pure tensor maps; :func:`forward_facing_reference` decides from the
cameras whether a capture is forward-facing and builds the reference camera.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from scenelabel.errors import InputError
from scenelabel.geometry.boxes import box_corners
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.frame import (
    FORWARD_MAX_ANGLE_DEG,
    SceneFrame,
    frustum_points,
    looking_one_way,
    mean_optical_axis,
    near_far_or_fallback,
)

__all__ = [
    "BoxWarp",
    "ForwardWarp",
    "warp_from_dict",
    "forward_facing_reference",
    "capture_reference",
    "choose_warp",
    "FORWARD_MAX_ANGLE_DEG",
]

BEHIND_EPS = 1e-6
"""Camera-frame depths below this (normalised units) count as behind the reference camera."""

AXIS_EPS = 1e-6
"""Rays whose direction has a smaller component along the reference axis never cross its slab."""

MIN_NEAR_FRACTION = 1e-3
"""A forward warp needs its nearest covered point at least this fraction of its farthest away."""


class BoxWarp(nn.Module):
    """The axis-aligned box ``aabb`` [2, 3] affinely onto [-1, 1]^3."""

    kind = "box"
    spacing = "uniform"  # rays are marched in equal steps

    def __init__(self, aabb: torch.Tensor):
        super().__init__()
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).clone())

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points [..., 3] (normalised frame) -> [..., 3] cube coordinates."""
        return (points - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2.0 - 1.0

    def inverse(self, unit: torch.Tensor) -> torch.Tensor:
        """cube coordinates [..., 3] -> points [..., 3]."""
        return (unit + 1.0) * 0.5 * (self.aabb[1] - self.aabb[0]) + self.aabb[0]

    def cube_extent(self) -> tuple[float, float, float]:
        """How long the cube's x, y, z axes are relative to each other: the box's side lengths."""
        return tuple((self.aabb[1] - self.aabb[0]).tolist())

    def clip(
        self, origins: torch.Tensor, directions: torch.Tensor, t_min: torch.Tensor, t_max: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Ray intervals limited to where the warp is defined: the box (rays are clipped to it already)."""
        return t_min, t_max

    def to_dict(self) -> dict:
        return {"kind": self.kind, "aabb": self.aabb.tolist()}


class ForwardWarp(nn.Module):
    """A reference camera's frustum onto [-1, 1]^3, linear in disparity along its axis.

    With ``p = R^T (x - c)`` the point in the reference camera's frame (OpenCV axes, z forward):
    ``u = p_x / (p_z tan_x)``, ``v = p_y / (p_z tan_y)``,
    ``s = 2 (1/near - 1/p_z) / (1/near - 1/far) - 1``; points with ``p_z <= BEHIND_EPS`` map to
    ``s = -2`` (outside). ``far`` may be ``inf`` (``1/far = 0``: the cube then reaches infinity).

    Args:
        centre: [3] reference camera centre (normalised frame).
        rotation: [3, 3] its camera-to-world rotation (columns: x right, y down, z forward).
        tan_xy: [2] half-extents of the frustum, tan of the half field of view in x and y.
        near, far: depth range along the reference axis (normalised units), 0 < near < far.
    """

    kind = "forward"
    spacing = "disparity"  # rays are marched in equal steps of 1 / t

    def __init__(self, centre, rotation, tan_xy, near: float, far: float):
        super().__init__()
        if not (0 < near < far):
            raise ValueError(f"ForwardWarp needs 0 < near < far, got near={near}, far={far}")
        self.register_buffer("centre", torch.as_tensor(np.asarray(centre), dtype=torch.float32).reshape(3).clone())
        self.register_buffer("rotation", torch.as_tensor(np.asarray(rotation), dtype=torch.float32).reshape(3, 3).clone())
        self.register_buffer("tan_xy", torch.as_tensor(np.asarray(tan_xy), dtype=torch.float32).reshape(2).clone())
        self.register_buffer("inv_range", torch.tensor([1.0 / near, 1.0 / far], dtype=torch.float32))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points [..., 3] (normalised frame) -> [..., 3] cube coordinates (outside for points behind)."""
        p = (points - self.centre) @ self.rotation  # [..., 3] = R^T (x - c), row vectors
        z = p[..., 2]
        front = z > BEHIND_EPS
        inv_z = 1.0 / torch.where(front, z, torch.ones_like(z))  # eps: no division by ~0 behind the camera
        inv_near, inv_far = self.inv_range[0], self.inv_range[1]
        u = p[..., 0] * inv_z / self.tan_xy[0]
        v = p[..., 1] * inv_z / self.tan_xy[1]
        s = 2.0 * (inv_near - inv_z) / (inv_near - inv_far) - 1.0
        s = torch.where(front, s, torch.full_like(s, -2.0))
        return torch.stack([u, v, s], -1)

    def inverse(self, unit: torch.Tensor) -> torch.Tensor:
        """cube coordinates [..., 3] (s in [-1, 1]) -> points [..., 3]."""
        inv_near, inv_far = self.inv_range[0], self.inv_range[1]
        inv_z = inv_near - (unit[..., 2] + 1.0) * 0.5 * (inv_near - inv_far)
        z = 1.0 / inv_z.clamp(min=1e-12)  # eps: s = 1 with far = inf is the point at infinity
        p = torch.stack([unit[..., 0] * self.tan_xy[0] * z, unit[..., 1] * self.tan_xy[1] * z, z], -1)
        return p @ self.rotation.T + self.centre

    def cube_extent(self) -> tuple[float, float, float]:
        """How long the cube's u, v, s axes are relative to each other: u and v as the reference
        view's image sides (tan_x : tan_y), the disparity axis s half the longer of them (views a
        small baseline apart resolve depth more coarsely than the image plane)."""
        tan_x, tan_y = self.tan_xy.tolist()
        return tan_x, tan_y, 0.5 * max(tan_x, tan_y)

    def clip(
        self, origins: torch.Tensor, directions: torch.Tensor, t_min: torch.Tensor, t_max: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Ray intervals [n_rays] limited to the slab near <= p_z <= far of the reference camera.

        Disparity marching needs a start away from the camera: a ray from inside the scene box
        (t_min = 0) would otherwise crowd its samples at the camera. Rays along or against the
        reference axis (d_z <= AXIS_EPS) keep their interval if they start inside the slab, else
        it is emptied (t_max = t_min).
        """
        z_axis = self.rotation[:, 2]
        z0 = (origins - self.centre) @ z_axis  # [n_rays] depth of the origin along the reference axis
        dz = directions @ z_axis
        near, far = 1.0 / self.inv_range[0], 1.0 / self.inv_range[1].clamp(min=1e-30)
        along = dz > AXIS_EPS
        safe_dz = torch.where(along, dz, torch.ones_like(dz))
        t_lo = torch.where(along, torch.maximum(t_min, (near - z0) / safe_dz), t_min)
        t_hi = torch.where(along, torch.minimum(t_max, (far - z0) / safe_dz), t_max)
        inside = (z0 >= near) & (z0 <= far)
        t_hi = torch.where(along | inside, t_hi, t_lo)
        return t_lo, t_hi

    def to_dict(self) -> dict:
        inv_near, inv_far = self.inv_range.tolist()
        return {
            "kind": self.kind,
            "centre": self.centre.tolist(),
            "rotation": self.rotation.tolist(),
            "tan_xy": self.tan_xy.tolist(),
            "near": 1.0 / inv_near,
            "far": math.inf if inv_far == 0 else 1.0 / inv_far,
        }


def warp_from_dict(data: dict) -> BoxWarp | ForwardWarp:
    """Rebuild a warp saved with :meth:`BoxWarp.to_dict` / :meth:`ForwardWarp.to_dict`."""
    if data["kind"] == "box":
        return BoxWarp(torch.tensor(data["aabb"]))
    if data["kind"] == "forward":
        return ForwardWarp(data["centre"], data["rotation"], data["tan_xy"], data["near"], data["far"])
    raise ValueError(f"unknown warp kind {data['kind']!r}")


def forward_facing_reference(
    cameras: Cameras, points: np.ndarray, max_angle_deg: float = FORWARD_MAX_ANGLE_DEG
) -> dict | None:
    """The reference camera of a forward-facing capture, or None when the capture is not one.

    Forward-facing: every optical axis within ``max_angle_deg`` of the mean axis, and every point
    of ``points`` (the cameras' frusta over near/far) in front of the mean camera. The reference
    camera sits at the mean centre looking along the mean axis (right axis orthogonalised from the
    mean right axis, as LLFF's ``poses_avg``); its frustum is widened to hold all ``points``.

    Args:
        cameras: the training cameras (world or normalised frame, the same as ``points``).
        points: [m, 3] points the warp must cover.
    Returns:
        keyword arguments of :class:`ForwardWarp` (numpy / floats), or None.
    """
    if not looking_one_way(cameras, max_angle_deg):
        return None
    z = mean_optical_axis(cameras)
    x = cameras.c2w[:, :3, 0].mean(0)
    x = x - (x @ z) * z
    if np.linalg.norm(x) < 1e-9:
        return None
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z], axis=1)  # columns x right, y down, z forward
    centre = cameras.centres.mean(0)
    p = (np.asarray(points, np.float64) - centre) @ rotation
    depth = p[:, 2]
    if not np.all(depth > 0):
        return None
    near, far = float(depth.min()), float(depth.max())
    if near < MIN_NEAR_FRACTION * far:  # a point almost in the mean camera's plane: no useful frustum
        return None
    tan_xy = np.abs(p[:, :2] / depth[:, None]).max(0) * 1.05  # 5% margin beyond the outermost frustum corner
    return {"centre": centre, "rotation": rotation, "tan_xy": tan_xy, "near": 0.95 * near, "far": 1.05 * far}


def capture_reference(cameras: Cameras, box: np.ndarray | None = None) -> dict | None:
    """:func:`forward_facing_reference` of ``cameras`` over their frusta between their near and far
    (:func:`scenelabel.geometry.frame.near_far_or_fallback` where the input gives none): the reference
    camera of a forward-facing capture, or None when the capture is not one. Given the modelled
    ``box`` ([2, 3], the cameras' frame), its near and far are narrowed to the box's corners' depths
    where the box ends sooner (the box fitted to the observed geometry of an input without near/far):
    the field's resolution is not spent on depths outside the box.
    """
    near, far = near_far_or_fallback(cameras)
    reference = forward_facing_reference(cameras, frustum_points(cameras, near, far))
    if reference is None or box is None:
        return reference
    depth = (box_corners(box) - reference["centre"]) @ reference["rotation"][:, 2]
    reference["near"] = max(reference["near"], float(depth.min()))
    reference["far"] = min(reference["far"], float(depth.max()))
    return reference


def choose_warp(kind: str, cameras: Cameras, frame: SceneFrame, aabb_n: torch.Tensor) -> BoxWarp | ForwardWarp:
    """The field's warp: ``"box"``, ``"forward"`` or ``"auto"`` (forward when the training
    ``cameras`` are forward-facing, :func:`capture_reference`, over the depths of the modelled box).
    ``aabb_n``: [2, 3] the box in ``frame``'s normalised coordinates.

    Raises InputError for ``"forward"`` when the cameras are not forward-facing.
    """
    if kind == "box":
        return BoxWarp(aabb_n)
    reference = capture_reference(cameras, frame.to_world(aabb_n.numpy()))
    if reference is None:
        if kind == "forward":
            raise InputError(
                "sampling.warp is 'forward' but the training cameras are not forward-facing "
                f"(optical axes within {FORWARD_MAX_ANGLE_DEG:g} degrees of their mean, the scene in front)"
            )
        return BoxWarp(aabb_n)
    return ForwardWarp(
        frame.to_normalised(reference["centre"]),
        reference["rotation"],
        reference["tan_xy"],
        reference["near"] * frame.scale,
        reference["far"] * frame.scale,
    )
