"""SemanticField: a trained field that answers questions in the world frame (numpy in, numpy out).

- ``query_points(xyz)``: density, occupancy, class probabilities and a label per point.
- ``query_rays(origins, directions)``: colour, depth, opacity, class probabilities and label per ray.
- ``render(c2w, width, height, focal)``: images of rgb, depth and labels.
- ``occupancy_map(voxel_size)``: a semantic occupancy grid (:class:`scenelabel.maps.OccupancyMap`).

Every input and output is in the input's world frame and units (docs/conventions.md).
"""

from __future__ import annotations

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
from .maps import FREE, UNKNOWN, OccupancyMap, iter_chunks, lattice
from .postprocess import smooth_class_probs
from .rays import camera_directions_from_pixels, normalize_directions, pixel_grid
from .renderer import ray_intervals, render_rays
from .sampling import OccupancyGrid
from .scene import Cameras, ClassMap

__all__ = ["SemanticField", "PointQuery", "RayQuery", "RenderResult"]

OCCUPIED_THRESHOLD = 0.5
"""A point (or ray) counts as occupied (hit) when its occupancy (opacity) is at least this."""

MAX_MAP_VOXELS = 256**3 * 4
"""occupancy_map refuses grids larger than this (ask for a larger voxel size)."""

MAX_SUBSAMPLES = 4
"""At most this many sub-samples per voxel axis when evaluating a map."""


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
    ):
        self.model = model.eval()
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
        model = SemanticField3D(config.field, class_map.num_classes, aabb_n)
        model.load_state_dict(data["model"])
        grid = OccupancyGrid(aabb_n, config.sampling.grid_resolution)
        grid.load_state_dict(data["occupancy"])
        meta = {k: v for k, v in data.items() if k not in ("model", "occupancy", "optimizer")}
        meta["config"] = config
        return SemanticField(model.to(device), grid.to(device), SceneFrame.from_dict(data["frame"]), class_map, meta)

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

    @torch.no_grad()
    def _semantics_n(self, points_n: np.ndarray, chunk: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
        """σ (normalised units) [N] and class probs [N, C] at normalised points; 0 outside the grid."""
        sig_out, prob_out = [], []
        for i in range(0, len(points_n), chunk):
            pts = self._tensor(points_n[i : i + chunk])
            sigmas, logits = self.model.semantics(pts)
            sigmas = torch.where(self.occupancy(pts), sigmas, torch.zeros_like(sigmas))
            sig_out.append(sigmas.double().cpu().numpy())
            prob_out.append(torch.softmax(logits.double(), -1).cpu().numpy())
        if not sig_out:
            return np.zeros(0), np.zeros((0, self.class_map.num_classes))
        return np.concatenate(sig_out), np.concatenate(prob_out)

    def _inside(self, xyz: np.ndarray) -> np.ndarray:
        return np.all((xyz >= self.aabb[0]) & (xyz <= self.aabb[1]), axis=-1)

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
        label = np.full(n, UNKNOWN, dtype=np.int64)
        label[inside] = np.where(
            occupancy[inside] >= OCCUPIED_THRESHOLD, self.class_map.ids_from_channels(probs.argmax(-1)), FREE
        )
        return PointQuery(density, occupancy, all_probs, self.class_ids, label)

    # ------------------------------------------------------------------ rays
    @torch.no_grad()
    def _render_n(
        self, origins_n: np.ndarray, directions: np.ndarray, near_n=None, far_n=None, with_rgb: bool = True
    ) -> dict[str, np.ndarray]:
        """Render rays given in the normalised frame, chunk by chunk."""
        chunk = self.config.sampling.chunk_rays
        background = self.config.train.background
        bg = None if background is None else self._tensor(np.asarray(background))
        outs: dict[str, list] = {"rgb": [], "depth": [], "opacity": [], "probs": [], "entered": []}
        for i in range(0, len(origins_n), chunk):
            o = self._tensor(origins_n[i : i + chunk])
            d = self._tensor(directions[i : i + chunk])
            nr = None if near_n is None else self._tensor(near_n[i : i + chunk])
            fr = None if far_n is None else self._tensor(far_n[i : i + chunk])
            t_min, t_max = ray_intervals(o, d, self._aabb_n, nr, fr)
            out = render_rays(
                self.model, self.occupancy, o, d, t_min, t_max, self._step_n, self._n_samples, None, bg, with_rgb
            )
            if with_rgb:
                outs["rgb"].append(out.rgb.cpu().numpy())
            outs["depth"].append(out.depth.double().cpu().numpy())
            outs["opacity"].append(out.opacity.double().cpu().numpy())
            outs["probs"].append(torch.exp(out.class_log_probs.double()).cpu().numpy())
            outs["entered"].append((t_max > t_min).cpu().numpy())
        return {k: np.concatenate(v) if v else np.zeros(0) for k, v in outs.items()}

    def _labels_from_rays(self, probs: np.ndarray, opacity: np.ndarray, entered: np.ndarray) -> np.ndarray:
        hit_label = self.class_map.ids_from_channels(probs.argmax(-1))
        return np.where(entered, np.where(opacity >= OCCUPIED_THRESHOLD, hit_label, FREE), UNKNOWN)

    def query_rays(self, origins, directions, near=None, far=None, with_rgb: bool = True) -> RayQuery:
        """What each ray hits, how far, and with which class.

        Args:
            origins: (N, 3) world ray origins.
            directions: (N, 3) world directions; need not be unit length.
            near, far: optional (N,) or scalar limits, as distances along the *unit* direction.
            with_rgb: also composite colour (False is faster; rgb is then zeros).
        Returns:
            RayQuery with depth in world units along the unit direction.
        """
        origins = _as_array(origins, "origins", 3)
        directions = _as_array(directions, "directions", 3)
        if len(origins) != len(directions):
            raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
        directions, _ = normalize_directions(directions)
        scale = self.frame.scale

        def limit(value, name):
            if value is None:
                return None
            return _as_array(np.broadcast_to(np.asarray(value, np.float64), (len(origins),)), name, None) * scale

        out = self._render_n(self.frame.to_internal(origins), directions, limit(near, "near"), limit(far, "far"), with_rgb)
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
        out = self._render_n(self.frame.to_internal(origins), directions)
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
        """Render camera ``index`` of a :class:`Cameras` batch (intrinsics and distortion kept)."""
        cam = cameras[index]
        return self.render(
            cam.c2w[0],
            int(cam.width[0]),
            int(cam.height[0]),
            (cam.fx[0], cam.fy[0]),
            cam.cx[0],
            cam.cy[0],
            smooth_sigma=smooth_sigma,
            distortion=cam.distortion[0],
        )

    # ------------------------------------------------------------------ maps
    def default_voxel_size(self) -> float:
        """What the images can resolve: twice the median training pixel footprint at the median
        camera-to-scene-centre distance, but no finer than the field's own finest cell."""
        return float(self.meta["default_voxel_size"])

    def occupancy_map(self, voxel_size: float | None = None, bounds=None, chunk: int = 32) -> OccupancyMap:
        """Evaluate the field on a voxel lattice, in chunks (bounded memory).

        A voxel's occupancy is the opacity of crossing it at its largest density,
        1 - exp(-max σ · voxel_size), the maximum taken over a regular n³ pattern of sub-samples
        (n chosen so that samples are no further apart than half the field's finest cell, at most
        MAX_SUBSAMPLES), so a thin surface anywhere in the voxel makes it occupied. A voxel with
        occupancy ≥ 0.5 carries the class of its densest sub-sample, others are FREE; voxels whose
        centre lies outside the modelled bounds are UNKNOWN (occupancy 0).

        Args:
            voxel_size: voxel edge in world units (default: :meth:`default_voxel_size`).
            bounds: (2, 3) world box to cover (default: the modelled bounds).
            chunk: voxels per chunk edge.
        """
        voxel_size = self.default_voxel_size() if voxel_size is None else float(voxel_size)
        if not (np.isfinite(voxel_size) and voxel_size > 0):
            raise InputError(f"voxel_size must be a positive number, got {voxel_size}", field="voxel_size")
        box = self.aabb if bounds is None else _as_array(bounds, "bounds", 3)
        origin, shape = lattice(box[0], box[1], voxel_size, max_voxels=MAX_MAP_VOXELS)
        n_sub = int(np.clip(np.ceil(voxel_size / (0.5 * self.meta["finest_cell"])), 1, MAX_SUBSAMPLES))
        offsets = (np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n_sub - 0.5
        offsets *= voxel_size  # [S, 3] world offsets from the voxel centre
        label = np.full(shape, UNKNOWN, dtype=np.int16)
        occupancy = np.zeros(shape, dtype=np.float32)
        for sl in iter_chunks(shape, chunk):
            idx = np.stack(np.meshgrid(*[np.arange(s.start, s.stop) for s in sl], indexing="ij"), -1)
            centres = origin + voxel_size * idx.reshape(-1, 3)  # [V, 3]
            inside = self._inside(centres)
            pts = (centres[inside][:, None, :] + offsets[None]).reshape(-1, 3)
            sig_n, probs = self._semantics_n(self.frame.to_internal(pts))
            sig_n = sig_n.reshape(-1, len(offsets))
            densest = sig_n.argmax(-1)
            occ = -np.expm1(-sig_n.max(-1) * self.frame.scale * voxel_size)
            cls = probs.reshape(len(sig_n), len(offsets), -1)[np.arange(len(sig_n)), densest].argmax(-1)
            block_label = np.full(len(centres), UNKNOWN, dtype=np.int16)
            block_occ = np.zeros(len(centres), dtype=np.float32)
            block_label[inside] = np.where(occ >= OCCUPIED_THRESHOLD, self.class_map.ids_from_channels(cls), FREE)
            block_occ[inside] = occ
            label[sl] = block_label.reshape(idx.shape[:3])
            occupancy[sl] = block_occ.reshape(idx.shape[:3])
        colors = self.meta.get("class_colors") or {}
        return OccupancyMap(
            label=label,
            occupancy=occupancy,
            voxel_size=voxel_size,
            origin=origin,
            classes=self.classes,
            occupancy_delta=voxel_size,
            class_colors={i: tuple(colors[i]) for i in self.class_map.ids.tolist() if i in colors} or None,
            frame_id=self.meta.get("frame_id", "world"),
            occupancy_threshold=OCCUPIED_THRESHOLD,
        )
