"""Training rays: every pixel ray of the training views with its targets (:func:`rays_for_views`),
and rays moved within their pixels (:func:`jittered_rays`, ``train.pixel_jitter``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from scenelabel.codes import FREE
from scenelabel.data.scene import ClassMap, Scene
from scenelabel.geometry.frame import SceneFrame
from scenelabel.geometry.rays import pixel_grid, rays_from_cameras
from scenelabel.render.marcher import ray_intervals

__all__ = ["RayData", "rays_for_views", "jittered_rays"]


@dataclass
class RayData:
    """All rays of some views, in the normalised frame (float32 tensors)."""

    origins: torch.Tensor  # [N, 3]
    directions: torch.Tensor  # [N, 3] unit
    t_min: torch.Tensor  # [N]
    t_max: torch.Tensor  # [N]
    rgb: torch.Tensor  # [N, 3]
    channels: torch.Tensor  # [N] int64 class channel, -1 = no label
    depth: torch.Tensor | None = None  # [N] measured distance along the ray (sensor depth), NaN = none; None: no view has one
    alpha: torch.Tensor | None = None  # [N] pixel alpha in [0, 1] (Scene.image_alphas; rgb is composited on the background); None: opaque
    # [N] where training stops marching, at most t_max (sampling.depth_ray_end: a little past the measured
    # surface); None: t_max. The depth loss still places a ray's transparent rest at t_max
    t_stop: torch.Tensor | None = None
    # [N, 3] each: how the ray's direction changes across its pixel, one pixel step along the image's x and y
    # (rays_for_views with footprint=True; train.pixel_jitter); None: rays through pixel centres only
    pixel_dx: torch.Tensor | None = None
    pixel_dy: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.origins.shape[0]


def rays_for_views(
    scene: Scene,
    indices: list[int],
    frame: SceneFrame,
    class_map: ClassMap,
    aabb_n: torch.Tensor,
    footprint: bool = False,
) -> RayData:
    """Every pixel ray of views ``indices``, with targets, clipped to the scene box and near/far.

    Pixels a view's mask excludes (``scene.masks``) give no ray; sensor depths
    (``scene.sensor_depths``) become ``depth`` in the normalised frame. A FREE pixel (its ray meets
    nothing) of a view without alpha gets alpha 0: its colour target is the background, so the ray
    learns to stay transparent; a view's own alpha rules where it has one. With ``footprint``, also
    each ray's ``pixel_dx`` / ``pixel_dy``: the direction through the pixel centre one step along x /
    y, less its own (through the camera's lens model), for :func:`jittered_rays`.
    """
    keys = ("o", "d", "near", "far", "rgb", "ch", "depth", "alpha") + (("dx", "dy") if footprint else ())
    parts: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    sensor = scene.sensor_depths
    for i in indices:
        origins, directions = rays_from_cameras(scene.cameras, i)
        n = len(origins)
        if footprint:
            centres = pixel_grid(int(scene.cameras.width[i]), int(scene.cameras.height[i]))
            for key, step in (("dx", (1.0, 0.0)), ("dy", (0.0, 1.0))):
                parts[key].append(rays_from_cameras(scene.cameras, i, centres + np.array(step))[1] - directions)
        depth = None if sensor is None else sensor[i]
        parts["depth"].append(np.full(n, np.nan) if depth is None else depth.reshape(-1) * frame.scale)
        parts["o"].append(frame.to_normalised(origins))
        parts["d"].append(directions)
        near, far = scene.cameras.near[i], scene.cameras.far[i]
        parts["near"].append(np.full(n, near * frame.scale if np.isfinite(near) else 0.0))
        parts["far"].append(np.full(n, far * frame.scale if np.isfinite(far) else np.inf))
        parts["rgb"].append(scene.images[i].reshape(-1, 3))
        label = scene.labels[i]
        parts["ch"].append(np.full(n, -1) if label is None else class_map.channels_from_ids(label.reshape(-1)))
        alpha = None if scene.image_alphas is None else scene.image_alphas[i]
        if alpha is None and label is not None:
            alpha = (label != FREE).astype(np.float32)
        parts["alpha"].append(np.ones(n, np.float32) if alpha is None else alpha.reshape(-1))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    if scene.masks is not None:  # a masked-out pixel gives no training ray
        keep = np.concatenate([
            np.ones(len(o), bool) if scene.masks[i] is None else scene.masks[i].reshape(-1)
            for i, o in zip(indices, parts["o"])
        ])
        cat = {k: v[keep] for k, v in cat.items()}
    o = torch.as_tensor(cat["o"], dtype=torch.float32)
    d = torch.as_tensor(cat["d"], dtype=torch.float32)
    t_min, t_max = ray_intervals(
        o, d, aabb_n, torch.as_tensor(cat["near"], dtype=torch.float32), torch.as_tensor(cat["far"], dtype=torch.float32)
    )
    return RayData(
        origins=o,
        directions=d,
        t_min=t_min,
        t_max=t_max,
        rgb=torch.as_tensor(cat["rgb"], dtype=torch.float32),
        channels=torch.as_tensor(cat["ch"], dtype=torch.int64),
        depth=None if sensor is None else torch.as_tensor(cat["depth"], dtype=torch.float32),
        alpha=None if np.all(cat["alpha"] == 1) else torch.as_tensor(cat["alpha"], dtype=torch.float32),
        pixel_dx=torch.as_tensor(cat["dx"], dtype=torch.float32) if footprint else None,
        pixel_dy=torch.as_tensor(cat["dy"], dtype=torch.float32) if footprint else None,
    )


def jittered_rays(
    origins: torch.Tensor,
    directions: torch.Tensor,
    pixel_dx: torch.Tensor,
    pixel_dy: torch.Tensor,
    offsets: torch.Tensor,
    aabb: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays through a point of their pixels instead of its centre: the camera's pixel integrates the
    light over its area (a real sensor's, a supersampled render's), so a pixel on an edge holds a
    blend of both sides, which one ray through its centre can only match with a half-transparent
    fringe past the edge. Drawn anywhere in the pixel, the rays that land on each side see that
    side, and the colour loss averages them as the pixel did.

    The direction moves linearly across the pixel, d + u pixel_dx + v pixel_dy (exact for a pinhole up
    to the normalisation, to first order through a lens model), then is normalised.

    Args:
        origins, directions: [n_rays, 3] (unit directions through the pixel centres).
        pixel_dx, pixel_dy: [n_rays, 3] (:class:`RayData`).
        offsets: [n_rays, 2] (u, v) in [-0.5, 0.5], pixels from the centre.
        aabb: [2, 3] the scene box (normalised frame).
    Returns:
        directions [n_rays, 3] (unit), and the box's entry and exit along them, t_enter, t_exit [n_rays]
        (t_exit <= t_enter where a ray now misses the box).
    """
    moved = directions + offsets[:, :1] * pixel_dx + offsets[:, 1:] * pixel_dy
    moved = moved / moved.norm(dim=-1, keepdim=True)
    t_enter, t_exit = ray_intervals(origins, moved, aabb)
    return moved, t_enter, t_exit
