"""SemanticField: a trained field that answers questions in the world frame (numpy in, numpy out).

- ``query_points(xyz)``: density, occupancy, class probabilities and a label per point.
- ``query_rays(origins, directions)``: colour, depth, opacity, class probabilities and label per ray.
- ``render(c2w, width, height, focal)``: images of rgb, depth and labels.
- ``occupancy_map(voxel_size)``: a semantic occupancy grid (:class:`scenelabel.maps.OccupancyMap`),
  UNKNOWN where no training camera observed (the training cameras are kept in the checkpoint).

Every input and output is in the input's world frame and units (docs/conventions.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .checkpoint import load_checkpoint
from .config import config_from_dict
from .errors import InputError
from .fields.model import SemanticField3D
from .io.transforms_json import opengl_to_opencv
from .frame import SceneFrame
from .maps import (
    ray_box_distances,
    FREE,
    UNKNOWN,
    OccupancyMap,
    block_centers,
    confidence_from_probs,
    iter_chunks,
    lattice,
    uint8_from_unit,
)
from .postprocess import smooth_class_probs
from .rays import camera_directions_from_pixels, normalize_directions, pixel_grid, rays_from_cameras
from .renderer import ray_intervals, render_rays_early_stop, render_rays_hierarchical
from .sampling import OccupancyGrid, march
from .scene import Cameras, ClassMap
from .visibility import DEPTH_MAP_WIDTH, cameras_from_dict, observed_voxels, scaled_cameras
from .warps import BoxWarp, warp_from_dict

__all__ = ["SemanticField", "PointQuery", "RayQuery", "RenderResult", "TRAIN_CAMERAS_KEY"]

OCCUPIED_THRESHOLD = 0.5
"""A point (or ray) counts as occupied (hit) when its occupancy (opacity) is at least this."""

MAX_MAP_VOXELS = 256**3 * 4
"""occupancy_map refuses grids larger than this (ask for a larger voxel size)."""

MAX_SUBSAMPLES = 4
"""At most this many sub-samples per voxel axis when evaluating a map."""

TRAIN_CAMERAS_KEY = "train_cameras"
"""Checkpoint key: the training cameras (:func:`scenelabel.visibility.cameras_to_dict`, world frame)."""


@dataclass
class PointQuery:
    """Answers for N points. ``label``: class id where occupied, FREE (-1), UNKNOWN (-2) outside bounds."""

    density: np.ndarray  # [N] σ per world unit
    occupancy: np.ndarray  # [N] 1 - exp(-σ δ), δ = SemanticField.occupancy_delta
    probs: np.ndarray  # [N, C] class probabilities (rows sum to 1)
    class_ids: np.ndarray  # [C] external class id of each column of probs
    label: np.ndarray  # [N] int


@dataclass
class RayQuery:
    """Answers for N rays. ``label``: class id where the ray hits (opacity ≥ 0.5), FREE if it
    crosses the modelled bounds without hitting, UNKNOWN if it never enters them."""

    rgb: np.ndarray  # [N, 3]
    depth: np.ndarray  # [N] distance along the unit direction, world units
    opacity: np.ndarray  # [N]
    probs: np.ndarray  # [N, C]
    class_ids: np.ndarray  # [C]
    label: np.ndarray  # [N]


@dataclass
class RenderResult:
    """Images of one camera."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    depth: np.ndarray  # [H, W] distance along each pixel's unit ray
    opacity: np.ndarray  # [H, W]
    probs: np.ndarray  # [H, W, C] (smoothed when smooth_sigma was given)
    label: np.ndarray  # [H, W] class ids; FREE / UNKNOWN where nothing was hit


def _softmax64(logits: np.ndarray) -> np.ndarray:
    """Softmax over the last axis in float64 ([..., C] -> [..., C], rows sum to 1)."""
    z = logits.astype(np.float64)
    z = np.exp(z - z.max(-1, keepdims=True))  # shifted by the row maximum: no overflow
    return z / z.sum(-1, keepdims=True)


def inside_bounds(xyz: np.ndarray, aabb: np.ndarray) -> np.ndarray:
    """[N] True where world points [N, 3] lie in the box aabb [2, 3] (faces included)."""
    return np.all((xyz >= aabb[0]) & (xyz <= aabb[1]), axis=-1)


def labels_from_answers(hit_label: np.ndarray, opacity: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The label rule of point and ray queries: the hit class id where ``opacity`` (a point's
    occupancy, a ray's Σ w) is ≥ OCCUPIED_THRESHOLD, FREE where lower, UNKNOWN where ``seen`` is
    False (a point outside the bounds, a ray that never enters them). All [N]."""
    return np.where(seen, np.where(opacity >= OCCUPIED_THRESHOLD, hit_label, FREE), UNKNOWN)


def ray_query_inputs(origins, directions, near, far) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A ray query's inputs checked: origins [N, 3], unit directions [N, 3] (see
    :func:`scenelabel.rays.normalize_directions`), near / far as [N] float64 or None (scalars
    broadcast), all world units."""
    origins = _as_array(origins, "origins", 3)
    directions = _as_array(directions, "directions", 3)
    if len(origins) != len(directions):
        raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
    directions, _ = normalize_directions(directions)

    def limit(value, name):
        return None if value is None else _as_array(np.broadcast_to(np.asarray(value, np.float64), (len(origins),)), name, None)

    return origins, directions, limit(near, "near"), limit(far, "far")


def _as_array(value, name: str, last_dim: int | None) -> np.ndarray:
    """numpy or torch input -> float64 numpy [N, last_dim] (or [N]); checks shape and finiteness."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    array = np.asarray(value, dtype=np.float64)
    if last_dim is not None:
        if array.ndim == 1 and array.shape[0] == last_dim:
            array = array[None]
        if array.ndim != 2 or array.shape[1] != last_dim:
            raise InputError(f"expected shape (N, {last_dim}), got {array.shape}", field=name)
    elif array.ndim != 1:
        raise InputError(f"expected shape (N,), got {array.shape}", field=name)
    if not np.all(np.isfinite(array)):
        raise InputError(f"{int((~np.isfinite(array)).sum())} non-finite values (NaN/inf)", field=name)
    return array


class SemanticField:
    """A trained semantic radiance field in the world frame.

    Build one with ``scenelabel build`` (or :func:`scenelabel.build`), then ``SemanticField.load``.
    Safe to query from several threads at once (queries never modify the field).
    """

    def __init__(
        self,
        model: SemanticField3D,
        occupancy: OccupancyGrid,
        frame: SceneFrame,
        class_map: ClassMap,
        meta: dict,
        coarse: SemanticField3D | None = None,
    ):
        """``coarse``: NeRF's coarse network when the field was trained with hierarchical
        sampling (``sampling.strategy``); rays are then rendered as in training."""
        self.model = model.eval()
        self.coarse = None if coarse is None else coarse.eval()
        self.occupancy = occupancy
        self.frame = frame
        self.class_map = class_map
        self.meta = meta
        self.config = meta["config"]
        self.device = next(model.parameters()).device
        self.aabb = np.asarray(meta["aabb_world"], np.float64)  # [2, 3] world bounds
        self._aabb_n = model.aabb  # normalised-frame box
        n_steps = self.config.sampling.n_steps
        diag_n = float(torch.linalg.norm(self._aabb_n[1] - self._aabb_n[0]))
        self._step_n = diag_n / n_steps
        self._n_samples = n_steps + 1

    # ------------------------------------------------------------------ construction
    @staticmethod
    def load(path: str | Path, device: str | torch.device | None = None) -> "SemanticField":
        """Load a build folder (or its checkpoint.pt). ``device``: 'cpu', 'cuda', or None (best)."""
        data = load_checkpoint(path)
        return SemanticField.from_checkpoint(data, device)

    @staticmethod
    def from_checkpoint(data: dict, device: str | torch.device | None = None) -> "SemanticField":
        device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        config = config_from_dict(data["config"])
        class_map = ClassMap.from_dict(data["class_map"])
        aabb_n = torch.as_tensor(np.asarray(data["aabb_internal"]), dtype=torch.float32)
        warp = warp_from_dict(data["warp"]) if "warp" in data else BoxWarp(aabb_n)  # before warps: the box
        model = SemanticField3D(config.field, class_map.num_classes, aabb_n, warp)
        model.load_state_dict(data["model"])
        coarse = None
        if "coarse_model" in data:
            coarse = SemanticField3D(config.field, class_map.num_classes, aabb_n, warp)
            coarse.load_state_dict(data["coarse_model"])
            coarse = coarse.to(device)
        sc = config.sampling
        grid = OccupancyGrid.for_march(warp, aabb_n, sc.grid_resolution, sc.n_steps, sc.alpha_threshold)
        grid.load_state_dict(data["occupancy"])
        meta = {k: v for k, v in data.items() if k not in ("model", "coarse_model", "occupancy", "optimizer")}
        meta["config"] = config
        frame = SceneFrame.from_dict(data["frame"])
        return SemanticField(model.to(device), grid.to(device), frame, class_map, meta, coarse)

    # ------------------------------------------------------------------ properties
    @property
    def class_ids(self) -> np.ndarray:
        """[C] external class ids, one per probability column."""
        return self.class_map.ids.copy()

    @property
    def classes(self) -> dict[int, str]:
        """External class id -> name for the classes the field models."""
        return dict(zip(self.class_map.ids.tolist(), self.class_map.names))

    @property
    def occupancy_delta(self) -> float:
        """δ (world units) in occupancy = 1 - exp(-σ δ): the default voxel size, i.e. the smallest
        length the training images resolve (see :meth:`default_voxel_size`). A point is occupied
        when a slab of that thickness there would be at least half opaque."""
        return self.default_voxel_size()

    # ------------------------------------------------------------------ points
    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(array, dtype=torch.float32, device=self.device)

    def _semantics_n(self, points_n: np.ndarray, chunk: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
        """σ (normalised units) [N] and class probs [N, C] float64 at normalised points.

        The network runs only where the occupancy grid may hold density (the grid is what
        training and rendering use too): elsewhere σ = 0 and the probabilities are uniform
        (no class evidence in space the field holds empty).
        """
        sigmas, logits = self._sigma_logits_n(points_n, chunk)
        return sigmas, _softmax64(logits)

    @torch.no_grad()
    def _sigma_logits_n(self, points_n: np.ndarray, chunk: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
        """σ (normalised units) [N] float64 and class logits [N, C] float32 (:meth:`_semantics_n`
        without the softmax; logits 0, i.e. uniform, where the grid holds space empty)."""
        n, c = len(points_n), self.class_map.num_classes
        sigmas_out = np.zeros(n)
        logits_out = np.zeros((n, c), dtype=np.float32)
        for i in range(0, n, chunk):
            pts = self._tensor(points_n[i : i + chunk])
            keep = self.occupancy(pts)  # [n_chunk] bool
            if not bool(keep.any()):
                continue
            sigmas, logits = self.model.semantics(pts[keep])
            rows = i + keep.nonzero()[:, 0].cpu().numpy()
            sigmas_out[rows] = sigmas.cpu().numpy()
            logits_out[rows] = logits.float().cpu().numpy()
        return sigmas_out, logits_out

    def _inside(self, xyz: np.ndarray) -> np.ndarray:
        return inside_bounds(xyz, self.aabb)

    def query_points(self, xyz) -> PointQuery:
        """What is at these world points.

        Args:
            xyz: (N, 3) world coordinates (numpy or torch).
        Returns:
            PointQuery: density per world unit; occupancy = 1 - exp(-density * occupancy_delta);
            probs [N, C] over ``class_ids``; label = class id where occupancy ≥ 0.5, FREE where
            lower, UNKNOWN outside the modelled bounds (where density, occupancy and probs are 0).
        """
        xyz = _as_array(xyz, "xyz", 3)
        inside = self._inside(xyz)
        sigmas_n, probs = self._semantics_n(self.frame.to_internal(xyz[inside]))
        n, c = len(xyz), self.class_map.num_classes
        density = np.zeros(n)
        density[inside] = sigmas_n * self.frame.scale
        occupancy = -np.expm1(-density * self.occupancy_delta)
        all_probs = np.zeros((n, c))
        all_probs[inside] = probs
        label = labels_from_answers(self.class_map.ids_from_channels(all_probs.argmax(-1)), occupancy, inside)
        return PointQuery(density, occupancy, all_probs, self.class_ids, label)

    # ------------------------------------------------------------------ rays
    @torch.no_grad()
    def _render_n(
        self, origins_n: np.ndarray, directions: np.ndarray, near_n=None, far_n=None, with_rgb: bool = True
    ) -> dict[str, np.ndarray]:
        """Render rays given in the normalised frame, chunk by chunk; a ray stops once it is opaque
        (transmittance below :data:`scenelabel.renderer.EARLY_STOP_TRANS`). A field trained with
        hierarchical sampling renders as in training (coarse, then fine samples; no early stop)."""
        sampling = self.config.sampling
        chunk = sampling.chunk_rays
        background = self.config.train.background
        bg = None if background is None else self._tensor(np.asarray(background))
        outs: dict[str, list] = {"rgb": [], "depth": [], "opacity": [], "probs": [], "entered": []}
        for i in range(0, len(origins_n), chunk):
            o = self._tensor(origins_n[i : i + chunk])
            d = self._tensor(directions[i : i + chunk])
            nr = None if near_n is None else self._tensor(near_n[i : i + chunk])
            fr = None if far_n is None else self._tensor(far_n[i : i + chunk])
            t_min, t_max = ray_intervals(o, d, self._aabb_n, nr, fr)
            if self.coarse is not None:
                hierarchical = (sampling.n_coarse, sampling.n_fine)
                out, _ = render_rays_hierarchical(self.coarse, self.model, o, d, t_min, t_max, hierarchical, None, bg, with_rgb)
            else:
                out = render_rays_early_stop(
                    self.model, self.occupancy, o, d, t_min, t_max, self._step_n, self._n_samples, bg, with_rgb
                )
            if with_rgb:
                outs["rgb"].append(out.rgb.cpu().numpy())
            outs["depth"].append(out.depth.double().cpu().numpy())
            outs["opacity"].append(out.opacity.double().cpu().numpy())
            outs["probs"].append(torch.exp(out.class_log_probs.double()).cpu().numpy())
            outs["entered"].append((t_max > t_min).cpu().numpy())
        return {k: np.concatenate(v) if v else np.zeros(0) for k, v in outs.items()}

    def _labels_from_rays(self, probs: np.ndarray, opacity: np.ndarray, entered: np.ndarray) -> np.ndarray:
        return labels_from_answers(self.class_map.ids_from_channels(probs.argmax(-1)), opacity, entered)

    def query_rays(self, origins, directions, near=None, far=None, with_rgb: bool = True) -> RayQuery:
        """What each ray hits, how far, and with which class.

        Rays are composited as in training (eq. 2 / eq. 7, no jitter), except that a ray stops
        once its transmittance is below :data:`scenelabel.renderer.EARLY_STOP_TRANS` (1e-4): the
        weight it leaves out is at most that. A field trained with hierarchical sampling
        (``sampling.strategy``) renders as in training: coarse, then fine samples, no early stop.

        Args:
            origins: (N, 3) world ray origins.
            directions: (N, 3) world directions; need not be unit length.
            near, far: optional (N,) or scalar limits, as distances along the *unit* direction.
            with_rgb: also composite colour (False is faster; rgb is then zeros).
        Returns:
            RayQuery with depth in world units along the unit direction.
        """
        origins, directions, near, far = ray_query_inputs(origins, directions, near, far)
        scale = self.frame.scale
        near_n, far_n = (None if v is None else v * scale for v in (near, far))
        out = self._render_n(self.frame.to_internal(origins), directions, near_n, far_n, with_rgb)
        rgb = out["rgb"] if with_rgb else np.zeros((len(origins), 3))
        return RayQuery(
            rgb=rgb,
            depth=out["depth"] / scale,
            opacity=out["opacity"],
            probs=out["probs"],
            class_ids=self.class_ids,
            label=self._labels_from_rays(out["probs"], out["opacity"], out["entered"]),
        )

    def render(
        self,
        c2w,
        width: int,
        height: int,
        focal: float | tuple[float, float],
        cx: float | None = None,
        cy: float | None = None,
        smooth_sigma: float | None = None,
        convention: str = "opencv",
        distortion=None,
        near: float | None = None,
        far: float | None = None,
    ) -> RenderResult:
        """Render one pinhole camera.

        Args:
            c2w: (4, 4) or (3, 4) camera-to-world; OpenCV axes (x right, y down, z forward), or
                OpenGL axes (nerfstudio) with ``convention="opengl"``.
            width, height: image size in pixels.
            focal: focal length in pixels (or (fx, fy)).
            cx, cy: principal point (default: the image centre); pixel centres at +0.5.
            smooth_sigma: Gaussian smoothing (pixels) of the class-probability images before the
                argmax (the seed paper's post-processing); None for none.
            distortion: optional OpenCV (k1, k2, p1, p2).
            near, far: optional limits of every ray, distances along its unit direction (world
                units), as a capture's per-view depth range (LLFF's bounds); None: the scene bounds.
        Returns:
            RenderResult.
        """
        c2w = _as_array(np.asarray(c2w, np.float64).reshape(-1, 4), "c2w", 4)
        if c2w.shape[0] == 3:
            c2w = np.vstack([c2w, [0, 0, 0, 1]])
        if c2w.shape != (4, 4):
            raise InputError(f"c2w must be 4x4 or 3x4, got {c2w.shape}", field="c2w")
        if convention == "opengl":
            c2w = opengl_to_opencv(c2w)
        elif convention != "opencv":
            raise InputError(f"convention must be 'opencv' or 'opengl', got {convention!r}", field="convention")
        fx, fy = (focal, focal) if np.isscalar(focal) else focal
        cx = width / 2.0 if cx is None else cx
        cy = height / 2.0 if cy is None else cy
        dirs_cam = camera_directions_from_pixels(pixel_grid(width, height), fx, fy, cx, cy, distortion)
        directions = dirs_cam @ c2w[:3, :3].T
        origins = np.broadcast_to(c2w[:3, 3], directions.shape)
        near_n, far_n = (None if v is None else np.full(len(directions), float(v) * self.frame.scale) for v in (near, far))
        out = self._render_n(self.frame.to_internal(origins), directions, near_n, far_n)
        probs = out["probs"].reshape(height, width, -1)
        if smooth_sigma:
            probs = smooth_class_probs(probs, smooth_sigma)
        label = self._labels_from_rays(probs.reshape(-1, probs.shape[-1]), out["opacity"], out["entered"])
        return RenderResult(
            rgb=out["rgb"].reshape(height, width, 3).astype(np.float32),
            depth=(out["depth"] / self.frame.scale).reshape(height, width),
            opacity=out["opacity"].reshape(height, width),
            probs=probs,
            label=label.reshape(height, width),
        )

    def render_camera(self, cameras: Cameras, index: int, smooth_sigma: float | None = None) -> RenderResult:
        """Render camera ``index`` of a :class:`Cameras` batch (intrinsics, distortion and its depth
        range kept: rays span [near, far] where those are finite, as the training rays did)."""
        cam = cameras[index]
        near, far = float(cam.near[0]), float(cam.far[0])
        return self.render(
            cam.c2w[0],
            int(cam.width[0]),
            int(cam.height[0]),
            (cam.fx[0], cam.fy[0]),
            cam.cx[0],
            cam.cy[0],
            smooth_sigma=smooth_sigma,
            distortion=cam.distortion[0],
            near=near if np.isfinite(near) else None,
            far=far if np.isfinite(far) else None,
        )

    # ------------------------------------------------------------------ maps
    def default_voxel_size(self) -> float:
        """What the images can resolve: twice the median training pixel footprint at the median
        camera-to-scene-centre distance, but no finer than the field's own finest cell."""
        return float(self.meta["default_voxel_size"])

    def training_cameras(self) -> Cameras | None:
        """The training cameras (world frame, OpenCV axes) as the build stored them, or None for a
        checkpoint made before scenelabel stored them."""
        record = self.meta.get(TRAIN_CAMERAS_KEY)
        return None if record is None else cameras_from_dict(record)

    @torch.no_grad()
    def _surface_t_n(
        self, origins_n: np.ndarray, directions: np.ndarray, near_n: np.ndarray, far_n: np.ndarray
    ) -> np.ndarray:
        """Distance (normalised units) along each ray to where its transmittance through the field
        falls to 0.5, ``inf`` if it never does: the surface of :meth:`occupancy_map`'s visibility
        rule, for a ray outside the map.

        Rays march as in rendering (same step, within the box and [near, far]); density is constant
        over each sample's interval (NeRF eq. 3), so the crossing is exact for those samples:
        ``T = exp(-sum σ_i δ_i)``, interpolated linearly in optical depth inside the sample that
        reaches log 2.

        Args:
            origins_n, directions: [R, 3] normalised-frame origins, unit directions.
            near_n, far_n: [R] limits, normalised units (0 / inf for none).
        Returns:
            [R] float64.
        """
        goal = math.log(2.0)
        out = np.full(len(origins_n), np.inf)
        todo = np.flatnonzero(far_n > near_n)  # rays with something to march
        chunk = self.config.sampling.chunk_rays
        for start in range(0, len(todo), chunk):
            rows = todo[start : start + chunk]
            o, d = self._tensor(origins_n[rows]), self._tensor(directions[rows])
            t_min, t_max = ray_intervals(o, d, self._aabb_n, self._tensor(near_n[rows]), self._tensor(far_n[rows]))
            t_min, t_max = self.model.warp.clip(o, d, t_min, t_max)
            longest = float((t_max - t_min).max()) if len(rows) else 0.0
            if not longest > 0:
                continue
            spacing = self.model.warp.spacing
            n_samples = self._n_samples
            if spacing == "uniform":
                n_samples = min(n_samples, math.ceil(longest / self._step_n) + 1)  # no empty tail
            t_starts, t_ends = march(spacing, t_min, t_max, self._step_n, n_samples)  # [r, S]
            t_starts, t_ends = t_starts.double().cpu().numpy(), t_ends.double().cpu().numpy()
            t_mids = 0.5 * (t_starts + t_ends)
            points = origins_n[rows, None, :] + t_mids[..., None] * directions[rows, None, :]  # [r, S, 3]
            sigma_n = self._semantics_n(points.reshape(-1, 3))[0].reshape(t_mids.shape)  # [r, S]
            tau_after = np.cumsum(sigma_n * np.maximum(t_ends - t_starts, 0.0), axis=-1)  # optical depth after each sample
            crossed = tau_after >= goal
            first = crossed.argmax(-1)  # [r]
            ar = np.arange(len(rows))
            tau_before = tau_after[ar, first] - sigma_n[ar, first] * np.maximum(t_ends - t_starts, 0.0)[ar, first]
            with np.errstate(divide="ignore", invalid="ignore"):
                t_cross = t_starts[ar, first] + (goal - tau_before) / sigma_n[ar, first]
            out[rows] = np.where(crossed.any(-1), t_cross, np.inf)
        return out

    def occupancy_map(
        self, voxel_size: float | None = None, bounds=None, chunk: int = 32, visibility: bool = True
    ) -> OccupancyMap:
        """Evaluate the field on a voxel lattice, in chunks (bounded memory).

        A voxel's occupancy is the opacity of crossing it at its largest density,
        1 - exp(-max σ · voxel_size), the maximum taken over a regular n³ pattern of sub-samples
        (n chosen so that samples are no further apart than half the field's finest cell, at most
        MAX_SUBSAMPLES), so a thin surface anywhere in the voxel makes it occupied. A voxel with
        occupancy ≥ 0.5 carries the class of its densest sub-sample, others are FREE; its
        ``probs`` are that sub-sample's class probabilities and ``confidence`` their
        1 - entropy / log C (:meth:`evaluate_map_block`).

        With ``visibility`` (and training cameras in the checkpoint), the training cameras' pixel
        rays are cast through these opacities to where their transmittance falls to 0.5, the
        surface a volume renderer draws (:func:`scenelabel.visibility.camera_surfaces`). A voxel
        such a surface lies in is occupied too, with the class of its most probable ``probs``
        channel and its occupancy raised to the threshold: a field's walls are often fog a few
        voxels deep, no voxel of it opaque enough alone. Then every voxel no training camera observed becomes UNKNOWN
        (:func:`scenelabel.visibility.observed_voxels`; docs/conventions.md, "Observed space"): an
        occupied voxel is observed when its centre lies at most one voxel diagonal
        (√3 · voxel_size) plus one pixel footprint behind a camera's surface, a transparent one
        only when its centre lies in front of it. When ``bounds`` leave out part of the modelled
        bounds, the field's surfaces between a camera and the map occlude too
        (:meth:`map_visibility_inputs`). UNKNOWN voxels (occupancy, probs and confidence 0) are
        also those whose centre lies outside the modelled bounds. The map's ``unknown_rule`` says
        which rule was applied: "visibility", or "bounds" when visibility was off or the
        checkpoint stores no training cameras.

        The whole map is held in memory; :func:`scenelabel.map_export.write_occupancy_map` writes
        the same map chunk by chunk into a zarr store (on a Dask cluster too).

        Args:
            voxel_size: voxel edge in world units (default: :meth:`default_voxel_size`).
            bounds: (2, 3) world box to cover (default: the modelled bounds).
            chunk: voxels per chunk edge.
            visibility: mark voxels no training camera observed as UNKNOWN.
        """
        voxel_size, origin, shape = self.map_lattice(voxel_size, bounds)
        label = np.full(shape, UNKNOWN, dtype=np.int16)
        occupancy = np.zeros(shape, dtype=np.float32)
        probs = np.zeros((*shape, self.class_map.num_classes), dtype=np.uint8)
        confidence = np.zeros(shape, dtype=np.uint8)
        for sl in iter_chunks(shape, chunk):
            label[sl], occupancy[sl], probs[sl], confidence[sl] = self.evaluate_map_block(origin, voxel_size, sl)
        inputs = self.map_visibility_inputs(origin, voxel_size, shape) if visibility else None
        if inputs is not None:
            cameras, occluders = inputs
            observed, occupied = observed_voxels(occupancy, origin, voxel_size, cameras, occluders, chunk)  # [nx, ny, nz]
            surface = occupied & (label == FREE)  # a camera's surface in a voxel below the threshold
            label[surface] = self.class_map.ids_from_channels(probs[surface].argmax(-1))
            occupancy[surface] = OCCUPIED_THRESHOLD  # so that label >= 0 stays occupancy >= threshold
            unseen = ~observed & (label != UNKNOWN)
            label[unseen] = UNKNOWN
            occupancy[unseen] = 0.0
            probs[unseen] = 0
            confidence[unseen] = 0
        return OccupancyMap(
            label=label,
            occupancy=occupancy,
            voxel_size=voxel_size,
            origin=origin,
            probs=probs,
            confidence=confidence,
            **self.map_metadata(voxel_size, "visibility" if inputs is not None else "bounds"),
        )

    # ---- the pieces of a map (shared by occupancy_map and scenelabel.map_export) ----

    def map_lattice(
        self, voxel_size: float | None = None, bounds=None, max_voxels: int = MAX_MAP_VOXELS
    ) -> tuple[float, np.ndarray, tuple[int, int, int]]:
        """The voxel lattice of a map (:func:`scenelabel.maps.lattice` over ``bounds``).

        Args:
            voxel_size: voxel edge in world units (default: :meth:`default_voxel_size`).
            bounds: (2, 3) world box to cover (default: the modelled bounds).
            max_voxels: refuse (InputError) a lattice of more voxels than this.
        Returns:
            voxel_size (float), origin [3] (world centre of voxel [0, 0, 0]), shape (nx, ny, nz).
        """
        voxel_size = self.default_voxel_size() if voxel_size is None else float(voxel_size)
        if not (np.isfinite(voxel_size) and voxel_size > 0):
            raise InputError(f"voxel_size must be a positive number, got {voxel_size}", field="voxel_size")
        box = self.aabb if bounds is None else _as_array(bounds, "bounds", 3)
        origin, shape = lattice(box[0], box[1], voxel_size, max_voxels=max_voxels)
        return voxel_size, origin, shape

    def evaluate_map_block(
        self, origin: np.ndarray, voxel_size: float, block: tuple[slice, slice, slice]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Evaluate one block of a map's lattice (the rule of :meth:`occupancy_map`, before the
        visibility rule): label, occupancy, probs and confidence of its voxels.

        Args:
            origin: [3] world centre of voxel [0, 0, 0] of the lattice.
            voxel_size: voxel edge, world units.
            block: (slice_i, slice_j, slice_k) with explicit start and stop (:func:`iter_chunks`).
        Returns:
            label [bi, bj, bk] int16 (class id, FREE, or UNKNOWN outside the modelled bounds),
            occupancy [bi, bj, bk] float32, probs [bi, bj, bk, C] uint8, confidence [bi, bj, bk]
            uint8 (0 where UNKNOWN).
        """
        n_sub = int(np.clip(np.ceil(voxel_size / (0.5 * self.meta["finest_cell"])), 1, MAX_SUBSAMPLES))
        offsets = (np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n_sub - 0.5
        offsets *= voxel_size  # [S, 3] world offsets from the voxel centre
        n_classes = self.class_map.num_classes
        shape = tuple(s.stop - s.start for s in block)
        centres = block_centers(origin, voxel_size, block)  # [V, 3]
        inside = self._inside(centres)  # [V]
        pts = (centres[inside][:, None, :] + offsets[None]).reshape(-1, 3)
        sig_n, sub_logits = self._sigma_logits_n(self.frame.to_internal(pts))
        sig_n = sig_n.reshape(-1, len(offsets))  # [K, S], K voxels inside the bounds
        densest = sig_n.argmax(-1)  # [K]
        occ = -np.expm1(-sig_n.max(-1) * self.frame.scale * voxel_size)  # [K]
        # only the densest sub-sample's distribution is kept: softmax just those
        p = _softmax64(sub_logits.reshape(len(sig_n), len(offsets), n_classes)[np.arange(len(sig_n)), densest])
        label = np.full(len(centres), UNKNOWN, dtype=np.int16)
        occupancy = np.zeros(len(centres), dtype=np.float32)
        probs = np.zeros((len(centres), n_classes), dtype=np.uint8)
        confidence = np.zeros(len(centres), dtype=np.uint8)
        label[inside] = np.where(occ >= OCCUPIED_THRESHOLD, self.class_map.ids_from_channels(p.argmax(-1)), FREE)
        occupancy[inside] = occ
        probs[inside] = uint8_from_unit(p)
        confidence[inside] = uint8_from_unit(confidence_from_probs(p))
        return label.reshape(shape), occupancy.reshape(shape), probs.reshape(*shape, n_classes), confidence.reshape(shape)

    def map_visibility_inputs(
        self, origin: np.ndarray, voxel_size: float, shape: tuple[int, int, int]
    ) -> tuple[Cameras, list[np.ndarray] | None] | None:
        """What the visibility rule of a map needs from the field, besides the map itself.

        Args:
            origin: [3] world centre of voxel [0, 0, 0] of the map's lattice.
            voxel_size: voxel edge, world units.
            shape: (nx, ny, nz).
        Returns:
            None when the checkpoint stores no training cameras (the map falls back to the
            "bounds" rule); else the training cameras shrunk to depth-map size
            (:func:`scenelabel.visibility.scaled_cameras`) and, when the lattice does not cover
            the modelled bounds, their depth maps of the field's surfaces outside it
            (:meth:`_occluders_outside`, n arrays [h_i, w_i]; None when it covers them).
        """
        cameras = self.training_cameras()
        if cameras is None:
            return None
        small = scaled_cameras(cameras, DEPTH_MAP_WIDTH)
        lo = origin - voxel_size / 2.0
        hi = lo + voxel_size * np.asarray(shape)
        covers_bounds = bool(np.all(lo <= self.aabb[0]) and np.all(hi >= self.aabb[1]))
        return small, None if covers_bounds else self._occluders_outside(small, lo, hi)

    def map_metadata(self, voxel_size: float, unknown_rule: str) -> dict:
        """The :class:`OccupancyMap` fields of this field's maps other than the arrays, ``origin``
        and ``voxel_size``: classes, colours, frame, threshold, δ, units, ``unknown_rule``."""
        colors = self.meta.get("class_colors") or {}
        return {
            "classes": self.classes,
            "occupancy_delta": voxel_size,
            "class_colors": {i: tuple(colors[i]) for i in self.class_map.ids.tolist() if i in colors} or None,
            "frame_id": self.meta.get("frame_id", "world"),
            "occupancy_threshold": OCCUPIED_THRESHOLD,
            "unknown_rule": unknown_rule,
            **self._scale_record(),
        }

    def _scale_record(self) -> dict:
        """The map's ``scale_source`` / ``units``: the input's own, or the input's times ``data.scale``."""
        world_scale = float(self.meta.get("world_scale", 1.0))
        if world_scale == 1.0:
            return {}
        return {"scale_source": f"input poses x {world_scale:g} (data.scale)", "units": "metre"}

    def _occluders_outside(self, cameras: Cameras, lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
        """The field's surfaces that a map covering only the box [lo, hi] does not hold.

        Per camera, the distance along each pixel ray to where its transmittance through the field
        falls to 0.5 (:meth:`_surface_t_n`) *before the ray enters the box* (surfaces past the box hide
        nothing in it), within the camera's near / far; ``inf`` where there is none.

        Args:
            cameras: n cameras (pinholes, world frame).
            lo, hi: [3] the map's box.
        Returns:
            n arrays [h_i, w_i] float64, world units.
        """
        rays = [rays_from_cameras(cameras, i) for i in range(len(cameras))]  # n x ([h w, 3], [h w, 3])
        counts = [len(o) for o, _ in rays]
        origins = np.concatenate([o for o, _ in rays])  # [R, 3]
        directions = np.concatenate([d for _, d in rays])
        near = np.repeat(np.where(np.isfinite(cameras.near), cameras.near, 0.0), counts)  # [R]
        far = np.repeat(np.where(np.isfinite(cameras.far), cameras.far, np.inf), counts)
        t_enter, t_exit = ray_box_distances(origins, directions, lo, hi)
        far = np.where(t_exit >= np.maximum(t_enter, 0.0), np.minimum(far, t_enter), near)  # a miss: nothing to march
        scale = self.frame.scale
        depth = self._surface_t_n(self.frame.to_internal(origins), directions, near * scale, far * scale) / scale
        parts = np.split(depth, np.cumsum(counts)[:-1])
        return [d.reshape(int(h), int(w)) for d, h, w in zip(parts, cameras.height, cameras.width)]
