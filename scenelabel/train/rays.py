"""Training rays: every pixel ray of the training views with its targets (:func:`rays_for_views`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from scenelabel.codes import FREE
from scenelabel.data.scene import ClassMap, Scene
from scenelabel.geometry.frame import SceneFrame
from scenelabel.geometry.rays import rays_from_cameras
from scenelabel.render.marcher import ray_intervals

__all__ = ["RayData", "rays_for_views"]


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

    def __len__(self) -> int:
        return self.origins.shape[0]


def rays_for_views(
    scene: Scene, indices: list[int], frame: SceneFrame, class_map: ClassMap, aabb_n: torch.Tensor
) -> RayData:
    """Every pixel ray of views ``indices``, with targets, clipped to the scene box and near/far.

    Pixels a view's mask excludes (``scene.masks``) give no ray; sensor depths
    (``scene.sensor_depths``) become ``depth`` in the normalised frame. A FREE pixel (its ray meets
    nothing) of a view without alpha gets alpha 0: its colour target is the background, so the ray
    learns to stay transparent; a view's own alpha rules where it has one.
    """
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("o", "d", "near", "far", "rgb", "ch", "depth", "alpha")}
    sensor = scene.sensor_depths
    for i in indices:
        origins, directions = rays_from_cameras(scene.cameras, i)
        n = len(origins)
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
    )
