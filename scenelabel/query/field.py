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
from pathlib import Path

import numpy as np
import torch

from scenelabel.config import config_from_dict, render_background
from scenelabel.data.scene import ClassMap
from scenelabel.errors import InputError
from scenelabel.fields.checkpoint import Checkpoint, load_checkpoint
from scenelabel.fields.model import FieldNetwork
from scenelabel.geometry.cameras import Cameras, cameras_from_dict, opengl_to_opencv
from scenelabel.geometry.frame import SceneFrame
from scenelabel.geometry.rays import camera_directions_from_pixels, pixel_grid
from scenelabel.geometry.warps import BoxWarp, warp_from_dict
from scenelabel.maps import FREE, OccupancyMap
from scenelabel.maps.visibility import seen_before_bounds
from scenelabel.query.answers import (
    PointQuery,
    RayQuery,
    RenderResult,
    checked_array,
    inside_bounds,
    labels_from_answers,
    ray_contract,
    ray_query_inputs,
    softmax64,
)
from scenelabel.query.mapping import occupancy_map
from scenelabel.query.postprocess import smooth_class_probs
from scenelabel.render.marcher import (
    CompositeOptions,
    Marching,
    ray_intervals,
    render_rays_early_stop,
    render_rays_hierarchical,
)
from scenelabel.render.sampling import DensityGrid, march

__all__ = ["SemanticField", "PointQuery", "RayQuery", "RenderResult", "TRAIN_CAMERAS_KEY"]

TRAIN_CAMERAS_KEY = "train_cameras"
"""Checkpoint key: the training cameras (:func:`scenelabel.geometry.cameras.cameras_to_dict`, world frame)."""


class SemanticField:
    """A trained semantic radiance field in the world frame.

    Build one with ``scenelabel build`` (or :func:`scenelabel.build`), then ``SemanticField.load``.
    Safe to query from several threads at once (queries never modify the field).
    """

    def __init__(
        self,
        model: FieldNetwork,
        occupancy: DensityGrid,
        frame: SceneFrame,
        class_map: ClassMap,
        meta: dict,
        coarse: FieldNetwork | None = None,
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
        observed = meta.get("observed_bounds")  # [2, 3] the observed geometry's extent, or None
        self.observed_bounds = None if observed is None else np.asarray(observed, np.float64)
        self._aabb_n = model.aabb  # normalised-frame box
        self.marching = Marching.across_box(self._aabb_n, self.config.sampling.n_steps)  # as in training
        self._train_cameras = self.training_cameras()  # outside the bounds, what they saw through is FREE

    def __repr__(self) -> str:
        lo, hi = self.aabb
        return (
            f"SemanticField(classes={self.classes}, bounds={np.round(lo, 3).tolist()} to {np.round(hi, 3).tolist()}, "
            f"default_voxel_size={self.default_voxel_size():.4g}, preset={self.config.preset!r}, device={self.device})"
        )

    # ------------------------------------------------------------------ construction
    @staticmethod
    def load(path: str | Path, device: str | torch.device | None = None) -> "SemanticField":
        """Load a build folder (or its checkpoint.pt). ``device``: 'cpu', 'cuda', or None (best)."""
        return SemanticField.from_checkpoint(load_checkpoint(path), device)

    @staticmethod
    def from_checkpoint(ckpt: Checkpoint, device: str | torch.device | None = None) -> "SemanticField":
        """The field of a loaded :class:`~scenelabel.fields.checkpoint.Checkpoint`; ``meta`` is its
        record, with ``config`` as a BuildConfig and ``class_colors`` keyed by int class id."""
        device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        data = ckpt.meta
        config = config_from_dict(data["config"])
        class_map = ClassMap.from_dict(data["class_map"])
        aabb_n = torch.as_tensor(np.asarray(data["aabb_internal"]), dtype=torch.float32)
        warp = warp_from_dict(data["warp"]) if "warp" in data else BoxWarp(aabb_n)  # before warps: the box
        model = FieldNetwork(config.field, class_map.num_classes, aabb_n, warp)
        model.load_state_dict(ckpt.model)
        coarse = None
        if ckpt.coarse_model is not None:
            coarse = FieldNetwork(config.field, class_map.num_classes, aabb_n, warp)
            coarse.load_state_dict(ckpt.coarse_model)
            coarse = coarse.to(device)
        sc = config.sampling
        grid = DensityGrid.for_march(warp, aabb_n, sc.grid_resolution, sc.n_steps, sc.alpha_threshold)
        grid.load_state_dict(ckpt.occupancy)
        meta = dict(data)
        meta["config"] = config
        if data.get("class_colors"):  # JSON keys are strings
            meta["class_colors"] = {int(k): v for k, v in data["class_colors"].items()}
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

        The network runs only where the density grid may hold density (the grid is what
        training and rendering use too): elsewhere σ = 0 and the probabilities are uniform
        (no class evidence in space the field holds empty).
        """
        sigmas, logits = self.sigmas_and_logits_n(points_n, chunk)
        return sigmas, softmax64(logits)

    def _kept_chunks(self, points_n: np.ndarray, chunk: int):
        """(rows [k] int64, points [k, 3] tensor) of each ``chunk`` of normalised points [N, 3],
        only the points where the density grid may hold density (chunks with none are skipped)."""
        for i in range(0, len(points_n), chunk):
            pts = self._tensor(points_n[i : i + chunk])
            keep = self.occupancy(pts)  # [n_chunk] bool
            if bool(keep.any()):
                yield i + keep.nonzero()[:, 0].cpu().numpy(), pts[keep]

    @torch.no_grad()
    def sigmas_n(self, points_n: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
        """σ (normalised units) [N] float64 at normalised points [N, 3], without the class head and
        the last layer's feature rows (:meth:`FieldNetwork.density`); 0 where the grid holds space empty."""
        sigmas_out = np.zeros(len(points_n))
        for rows, pts in self._kept_chunks(points_n, chunk):
            sigmas_out[rows] = self.model.density(pts).cpu().numpy()
        return sigmas_out

    @torch.no_grad()
    def sigmas_and_logits_n(self, points_n: np.ndarray, chunk: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
        """σ (normalised units) [N] float64 and class logits [N, C] float32 (:meth:`_semantics_n`
        without the softmax; normalised-frame points [N, 3]; logits 0, i.e. uniform, where the grid holds space empty)."""
        sigmas_out = np.zeros(len(points_n))
        logits_out = np.zeros((len(points_n), self.class_map.num_classes), dtype=np.float32)
        for rows, pts in self._kept_chunks(points_n, chunk):
            sigmas, logits = self.model.semantics(pts)
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
            lower; outside the modelled bounds (where density, occupancy and probs are 0) FREE
            where a training camera saw through the point on its way into the bounds
            (:func:`scenelabel.maps.visibility.seen_before_bounds`), else UNKNOWN.
        """
        xyz = checked_array(xyz, "xyz", 3)
        inside = self._inside(xyz)
        sigmas_n, probs = self._semantics_n(self.frame.to_normalised(xyz[inside]))
        n, c = len(xyz), self.class_map.num_classes
        density = np.zeros(n)
        density[inside] = sigmas_n * self.frame.scale
        occupancy = -np.expm1(-density * self.occupancy_delta)
        all_probs = np.zeros((n, c))
        all_probs[inside] = probs
        label = labels_from_answers(self.class_map.ids_from_channels(all_probs.argmax(-1)), occupancy, inside)
        if self._train_cameras is not None:
            label[seen_before_bounds(xyz, self._train_cameras, self.aabb)] = FREE
        return PointQuery(density, occupancy, all_probs, self.class_ids, label)

    # ------------------------------------------------------------------ rays
    @torch.no_grad()
    def _render_n(
        self, origins_n: np.ndarray, directions: np.ndarray, near_n=None, far_n=None, with_rgb: bool = True
    ) -> dict[str, np.ndarray]:
        """Render rays given in the normalised frame, chunk by chunk; a ray stops once it is opaque
        (transmittance below :data:`scenelabel.render.constants.EARLY_STOP_TRANS`). A field trained with
        hierarchical sampling renders as in training (coarse, then fine samples; no early stop)."""
        sampling = self.config.sampling
        chunk = sampling.chunk_rays
        background = render_background(self.config.train.background)  # "random" training: white
        bg = None if background is None else self._tensor(np.asarray(background))
        options = CompositeOptions(bg, with_rgb)
        outs: dict[str, list] = {"rgb": [], "depth": [], "opacity": [], "probs": [], "entered": []}
        for i in range(0, len(origins_n), chunk):
            o = self._tensor(origins_n[i : i + chunk])
            d = self._tensor(directions[i : i + chunk])
            nr = None if near_n is None else self._tensor(near_n[i : i + chunk])
            fr = None if far_n is None else self._tensor(far_n[i : i + chunk])
            t_min, t_max = ray_intervals(o, d, self._aabb_n, nr, fr)
            if self.coarse is not None:
                hierarchical = (sampling.n_coarse, sampling.n_fine)
                out, _ = render_rays_hierarchical(self.coarse, self.model, o, d, t_min, t_max, hierarchical, None, options)
            else:
                out = render_rays_early_stop(self.model, self.occupancy, o, d, t_min, t_max, self.marching, options)
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
        once its transmittance is below :data:`scenelabel.render.constants.EARLY_STOP_TRANS` (1e-4), and
        samples too faint to matter count as empty: the weight left out is at most twice that
        (:func:`~scenelabel.render.marcher.render_rays_early_stop`). A field trained with hierarchical sampling
        (``sampling.strategy``) renders as in training: coarse, then fine samples, no early stop.

        Args:
            origins: (N, 3) world ray origins.
            directions: (N, 3) world directions; need not be unit length.
            near, far: optional (N,) or scalar limits, as distances along the *unit* direction.
            with_rgb: also composite colour (False is faster; rgb is then zeros).
        Returns:
            RayQuery under the ray contract (:func:`~scenelabel.query.answers.ray_contract`): a hit
            (opacity ≥ 0.5) has depth Σ w_i t_i / Σ w_i in world units along the unit direction
            and its class; no hit has depth ``inf`` and label FREE (UNKNOWN if the ray never
            enters the bounds).
        """
        origins, directions, near, far = ray_query_inputs(origins, directions, near, far)
        scale = self.frame.scale
        near_n, far_n = (None if v is None else v * scale for v in (near, far))
        out = self._render_n(self.frame.to_normalised(origins), directions, near_n, far_n, with_rgb)
        rgb = out["rgb"] if with_rgb else np.zeros((len(origins), 3))
        hit_label = self.class_map.ids_from_channels(out["probs"].argmax(-1))
        depth, label = ray_contract(out["depth"] / scale, out["opacity"], hit_label, out["entered"])
        return RayQuery(rgb, depth, out["opacity"], out["probs"], self.class_ids, label)

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
        camera_model: str = "pinhole",
    ) -> RenderResult:
        """Render one camera (a pinhole unless ``camera_model`` says otherwise).

        Args:
            c2w: (4, 4) or (3, 4) camera-to-world; OpenCV axes (x right, y down, z forward), or
                OpenGL axes (nerfstudio) with ``convention="opengl"``.
            width, height: image size in pixels.
            focal: focal length in pixels (or (fx, fy)).
            cx, cy: principal point (default: the image centre); pixel centres at +0.5.
            smooth_sigma: Gaussian smoothing (pixels) of the class-probability images before the
                argmax (the seed paper's post-processing); None for none.
            distortion: optional lens coefficients: a pinhole's OpenCV (k1, k2, p1, p2), a
                fisheye's (k1, k2, k3, k4) (docs/conventions.md, "Camera models").
            near, far: optional limits of every ray, distances along its unit direction (world
                units), as a capture's per-view depth range (LLFF's bounds); None: the scene bounds.
            camera_model: ``"pinhole"`` or ``"fisheye"`` (OpenCV's equidistant model).
        Returns:
            RenderResult.
        """
        c2w = checked_array(np.asarray(c2w, np.float64).reshape(-1, 4), "c2w", 4)
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
        dirs_cam = camera_directions_from_pixels(pixel_grid(width, height), fx, fy, cx, cy, distortion, camera_model)
        directions = dirs_cam @ c2w[:3, :3].T
        origins = np.broadcast_to(c2w[:3, 3], directions.shape)
        near_n, far_n = (None if v is None else np.full(len(directions), float(v) * self.frame.scale) for v in (near, far))
        out = self._render_n(self.frame.to_normalised(origins), directions, near_n, far_n)
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
            camera_model=str(cam.model[0]),
            near=near if np.isfinite(near) else None,
            far=far if np.isfinite(far) else None,
        )

    # ------------------------------------------------------------------ maps
    def default_voxel_size(self) -> float:
        """What the images can resolve: twice the median training pixel footprint at the median
        camera-to-scene-centre distance, but no finer than two of the field's finest cells
        (:meth:`finest_cell`; older builds floored it at one)."""
        return float(self.meta["default_voxel_size"])

    def finest_cell(self) -> float:
        """World length of the encoding's finest cell along the modelled box's longest side: the
        finest detail the field holds (a baked lattice's default spacing; a map reads a voxel
        once per finest cell along each axis)."""
        return float(self.meta["finest_cell"])

    def training_cameras(self) -> Cameras | None:
        """The training cameras (world frame, OpenCV axes) as the build stored them, or None for a
        checkpoint made before scenelabel stored them."""
        record = self.meta.get(TRAIN_CAMERAS_KEY)
        return None if record is None else cameras_from_dict(record)

    @torch.no_grad()
    def surface_distances_n(
        self, origins_n: np.ndarray, directions: np.ndarray, near_n: np.ndarray, far_n: np.ndarray
    ) -> np.ndarray:
        """Distance (normalised units) along each ray to where its transmittance through the field
        falls to 0.5, ``inf`` if it never does: the surface of a map's visibility
        rule, for a ray outside the map (:func:`scenelabel.query.mapping.occluders_outside`).

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
            n_samples = self.marching.n_samples
            if spacing == "uniform":
                n_samples = min(n_samples, math.ceil(longest / self.marching.step) + 1)  # no empty tail
            t_starts, t_ends = march(spacing, t_min, t_max, self.marching.step, n_samples)  # [r, S]
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
        """Evaluate the field on a voxel lattice, in chunks (bounded memory): a semantic occupancy map.

        A voxel is occupied when crossing it at its largest density (over a regular pattern of
        sub-samples, read where density is near: :func:`scenelabel.query.mapping.evaluate_map_block`)
        is at least half opaque, with the class of its densest sub-sample; with
        ``visibility`` (and training cameras in the checkpoint) the voxels a camera's surface lies
        in are occupied too and those no training camera observed are UNKNOWN. The rule, once:
        docs/conventions.md, "Density and occupancy" and "Observed space". The map's
        ``unknown_rule`` says which rule applied: "visibility", or "bounds" (UNKNOWN only outside
        the modelled bounds) when visibility was off or the checkpoint stores no training cameras.

        The whole map is held in memory; :func:`scenelabel.query.map_writer.write_occupancy_map`
        writes the same map chunk by chunk into a zarr store (on a Dask cluster too).

        Args:
            voxel_size: voxel edge in world units (default: :meth:`default_voxel_size`).
            bounds: (2, 3) world box to cover (default: the modelled bounds, cut to the observed
                geometry: :func:`scenelabel.query.mapping.map_lattice`).
            chunk: voxels per chunk edge.
            visibility: mark voxels no training camera observed as UNKNOWN.
        """
        return occupancy_map(self, voxel_size, bounds, chunk, visibility)

    def scale_record(self) -> dict:
        """A map's ``scale_source`` / ``units``: the input's own, or the input's times ``data.scale``."""
        world_scale = float(self.meta.get("world_scale", 1.0))
        if world_scale == 1.0:
            return {}
        return {"scale_source": f"input poses x {world_scale:g} (data.scale)", "units": "metre"}
