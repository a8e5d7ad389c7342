"""A trained field baked onto a vertex lattice: point and ray queries without the network.

:meth:`BakedField.from_field` evaluates a :class:`~scenelabel.semantic_field.SemanticField` once
at the vertices of a lattice over its modelled bounds (density and class logits, the network's
output as the field's own queries see it: zero where its occupancy grid holds space empty).
Queries then interpolate that lattice trilinearly in compiled loops (numba), so they cost a few
memory reads per point and per ray sample instead of a network evaluation:

- :meth:`BakedField.query_points`: density, occupancy, class probabilities and label per point;
- :meth:`BakedField.query_rays`: depth, opacity, class probabilities and label per ray, marched
  and composited as the field marches them (same step, NeRF eq. 3 quadrature, eq. 7 or eq. 3
  class compositing, the same early stop).

The trade: answers follow the field to within what trilinear interpolation at the lattice's
spacing keeps (the default spacing is the field's ``default_voxel_size``, what the images
resolve); tools/bench.py measures the agreement next to the speed. The maths (:func:`trilinear`,
:func:`composite_baked_rays`) is pure and takes numpy arrays; :class:`BakedField` holds the
lattice. Both are safe to call from several threads at once (nothing is modified).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np
from numba import njit

from .errors import InputError
from .maps import FREE, UNKNOWN, ray_box_distances
from .rendering import OPACITY_EPS
from .renderer import EARLY_STOP_TRANS
from .rays import normalize_directions
from .semantic_field import OCCUPIED_THRESHOLD, PointQuery, RayQuery, SemanticField, _as_array, inside_bounds

__all__ = ["BakedField", "trilinear", "composite_baked_rays", "MAX_BAKE_BYTES"]

MAX_BAKE_BYTES = 2 * 1024**3
"""A bake refuses a lattice whose values would take more memory than this (ask for a larger voxel size)."""

MIN_ROWS_PER_THREAD = 4096
"""Queries are split over threads (one per core) in chunks of at least this many points or rays."""

FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Baked densities are clamped to this (the lattice is float32; the kernels blend in float64)."""

BAKE_CHUNK = 1 << 18
"""Vertices evaluated per network call while baking."""


# ---------------------------------------------------------------------------------------------
# compiled kernels (numba): one point or one ray at a time, no allocation inside the loops


@njit(cache=True, nogil=True)
def _lerp_channels(values, x, y, z, c0, c1, out):  # pragma: no cover - compiled
    """Trilinear interpolation of channels [c0, c1) of ``values`` [nx+1, ny+1, nz+1, F] at lattice
    coordinates (x, y, z) (in vertex spacings from vertex 0, each in [0, n]) into out[: c1 - c0]."""
    nx, ny, nz = values.shape[0] - 1, values.shape[1] - 1, values.shape[2] - 1
    i, j, k = min(int(x), nx - 1), min(int(y), ny - 1), min(int(z), nz - 1)
    fx, fy, fz = x - i, y - j, z - k
    gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
    w000, w001, w010, w011 = gx * gy * gz, gx * gy * fz, gx * fy * gz, gx * fy * fz
    w100, w101, w110, w111 = fx * gy * gz, fx * gy * fz, fx * fy * gz, fx * fy * fz
    for c in range(c0, c1):
        out[c - c0] = (
            w000 * values[i, j, k, c]
            + w001 * values[i, j, k + 1, c]
            + w010 * values[i, j + 1, k, c]
            + w011 * values[i, j + 1, k + 1, c]
            + w100 * values[i + 1, j, k, c]
            + w101 * values[i + 1, j, k + 1, c]
            + w110 * values[i + 1, j + 1, k, c]
            + w111 * values[i + 1, j + 1, k + 1, c]
        )


@njit(cache=True, nogil=True)
def _lattice_coords(values, corner, inv_spacing, px, py, pz, coords):  # pragma: no cover - compiled
    """World point -> lattice coordinates of ``values``' vertices in coords[:3]; False when it
    lies outside the lattice (or is NaN)."""
    coords[0] = (px - corner[0]) * inv_spacing
    coords[1] = (py - corner[1]) * inv_spacing
    coords[2] = (pz - corner[2]) * inv_spacing
    for a in range(3):
        if not (0.0 <= coords[a] <= values.shape[a] - 1):
            return False
    return True


@njit(cache=True, nogil=True)
def _trilinear_kernel(values, corner, inv_spacing, points, out):  # pragma: no cover - compiled
    coords = np.empty(3)
    n_channels = values.shape[3]
    for n in range(points.shape[0]):
        if _lattice_coords(values, corner, inv_spacing, points[n, 0], points[n, 1], points[n, 2], coords):
            _lerp_channels(values, coords[0], coords[1], coords[2], 0, n_channels, out[n])
        else:
            out[n, :] = 0.0


@njit(cache=True, nogil=True)
def _softmax_into(logits, probs):  # pragma: no cover - compiled
    """probs = softmax(logits), shifted by the maximum (no overflow), in float64."""
    top = logits[0]
    for c in range(1, logits.shape[0]):
        top = max(top, logits[c])
    total = 0.0
    for c in range(logits.shape[0]):
        probs[c] = math.exp(logits[c] - top)
        total += probs[c]
    for c in range(logits.shape[0]):
        probs[c] /= total


@njit(cache=True, nogil=True)
def _points_kernel(values, corner, inv_spacing, points, density, probs):  # pragma: no cover - compiled
    """density [N] (channel 0, clamped at 0) and probs [N, C] (softmax of channels 1..C; uniform
    outside the lattice) at world points [N, 3]."""
    coords = np.empty(3)
    n_classes = values.shape[3] - 1
    logits = np.empty(n_classes)
    sigma = np.empty(1)
    for n in range(points.shape[0]):
        if _lattice_coords(values, corner, inv_spacing, points[n, 0], points[n, 1], points[n, 2], coords):
            _lerp_channels(values, coords[0], coords[1], coords[2], 0, 1, sigma)
            _lerp_channels(values, coords[0], coords[1], coords[2], 1, n_classes + 1, logits)
            density[n] = max(sigma[0], 0.0)
        else:
            density[n] = 0.0
            logits[:] = 0.0
        _softmax_into(logits, probs[n])


@njit(cache=True, nogil=True)
def _rays_kernel(
    values, corner, inv_spacing, origins, directions, t_min, t_max, step, min_trans, scores, depth, opacity, probs
):  # pragma: no cover - compiled
    """March each ray from t_min to t_max in intervals of ``step`` (the last one cut at t_max),
    density at the interval middles, and composite (see :func:`composite_baked_rays`)."""
    coords = np.empty(3)
    n_classes = values.shape[3] - 1
    sigma = np.empty(1)
    logits = np.empty(n_classes)
    sample = np.empty(n_classes)
    acc = np.empty(n_classes)
    for r in range(origins.shape[0]):
        acc[:] = 0.0
        trans, w_sum, wt_sum = 1.0, 0.0, 0.0
        t_lo, t_hi = t_min[r], t_max[r]
        k = 0
        t_start = t_lo
        while t_start < t_hi and trans >= min_trans:
            k += 1
            t_end = min(t_lo + k * step, t_hi)
            t_mid = 0.5 * (t_start + t_end)
            px = origins[r, 0] + t_mid * directions[r, 0]
            py = origins[r, 1] + t_mid * directions[r, 1]
            pz = origins[r, 2] + t_mid * directions[r, 2]
            if _lattice_coords(values, corner, inv_spacing, px, py, pz, coords):
                _lerp_channels(values, coords[0], coords[1], coords[2], 0, 1, sigma)
                if sigma[0] > 0.0:
                    alpha = -math.expm1(-sigma[0] * (t_end - t_start))
                    weight = trans * alpha
                    trans *= 1.0 - alpha
                    w_sum += weight
                    wt_sum += weight * t_mid
                    _lerp_channels(values, coords[0], coords[1], coords[2], 1, n_classes + 1, logits)
                    if scores:  # eq. 3: composite the scores, softmax after
                        for c in range(n_classes):
                            acc[c] += weight * logits[c]
                    else:  # eq. 7: composite the per-sample probabilities
                        _softmax_into(logits, sample)
                        for c in range(n_classes):
                            acc[c] += weight * sample[c]
            t_start = t_end
        far = max(t_hi, 0.0)
        near = min(t_lo, far)
        opacity[r] = w_sum
        if w_sum > OPACITY_EPS:
            depth[r] = min(max(wt_sum / w_sum, near), far)
            if scores:
                _softmax_into(acc, probs[r])
            else:
                for c in range(n_classes):
                    probs[r, c] = acc[c] / w_sum
        else:  # no weight: the far end and the uniform law, as rendering.depth_from_weights does
            depth[r] = far
            probs[r, :] = 1.0 / n_classes


# ---------------------------------------------------------------------------------------------
# the maths, on numpy arrays


def _check_lattice(values: np.ndarray, corner: Any, spacing: float, min_channels: int) -> tuple[np.ndarray, np.ndarray, float]:
    values = np.asarray(values)
    if values.ndim != 4 or min(values.shape[:3]) < 2 or values.shape[3] < min_channels:
        raise InputError(
            f"values must be [nx+1, ny+1, nz+1, F] with at least 2 vertices per axis and {min_channels}+ channels, "
            f"got {values.shape}",
            field="values",
        )
    corner = np.asarray(corner, np.float64).reshape(3)
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"spacing must be a positive number, got {spacing}", field="spacing")
    return np.ascontiguousarray(values, dtype=np.float32), corner, 1.0 / float(spacing)


def _in_threads(run: Callable[[slice], None], n: int) -> None:
    """run(rows) over [0, n) split into one contiguous slice per core (each at least
    MIN_ROWS_PER_THREAD rows); the kernels release the GIL, so the slices run in parallel."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = max(1, min(cores, n // MIN_ROWS_PER_THREAD))
    if workers == 1:
        run(slice(0, n))
        return
    bounds = np.linspace(0, n, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(run, [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]))


def trilinear(values: np.ndarray, corner: Any, spacing: float, points: Any) -> np.ndarray:
    """Trilinear interpolation of a vertex lattice at world points.

    Vertex ``[i, j, k]`` sits at ``corner + spacing * (i, j, k)``; a point between vertices gets
    the tensor-product linear blend of its cell's 8 corners (exact at the vertices, linear along
    each cell edge). Points outside the lattice (or NaN) get 0.

    Args:
        values: [nx+1, ny+1, nz+1, F] (read as float32).
        corner: [3] world position of vertex [0, 0, 0].
        spacing: vertex spacing, world units.
        points: [N, 3] world points.
    Returns:
        [N, F] float32.
    """
    values, corner, inv = _check_lattice(values, corner, spacing, 1)
    points = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
    out = np.empty((len(points), values.shape[3]), np.float32)
    _in_threads(lambda rows: _trilinear_kernel(values, corner, inv, points[rows], out[rows]), len(points))
    return out


def composite_baked_rays(
    values: np.ndarray,
    corner: Any,
    spacing: float,
    rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    step: float,
    scores: bool = False,
    min_trans: float = EARLY_STOP_TRANS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Volume-render rays through a lattice of density (channel 0) and class logits (channels 1..C).

    Each ray is marched from t_min in intervals of ``step`` (the last one cut at t_max, as
    :func:`scenelabel.sampling.march_uniform` without jitter) with the density σ_i read at the
    interval middle t_i (trilinear; negative values count as 0, points outside the lattice as 0),
    and composited as a renderer does (NeRF eq. 3): α_i = 1 - exp(-σ_i δ_i), T_{i+1} = T_i (1 - α_i),
    w_i = T_i α_i. Depth is Σ w_i t_i / Σ w_i clipped to [t_min, t_max]; class probabilities are
    Σ w_i softmax(l_i) / Σ w_i (eq. 7), or softmax(Σ w_i l_i) with ``scores`` (eq. 3). A ray with
    Σ w_i ≤ OPACITY_EPS (1e-10, "empty") reports depth max(t_max, 0) and the uniform law. A ray
    stops once T < ``min_trans`` (the weight it leaves out is at most that; 0: never stop).

    Args:
        values: [nx+1, ny+1, nz+1, 1 + C] density (per world unit) and logits at the vertices.
        corner: [3] world position of vertex [0, 0, 0]; spacing: vertex spacing (world units).
        rays: (origins [N, 3], directions [N, 3] unit, t_min [N], t_max [N]) world units;
            t_max ≤ t_min for a ray with nothing to march.
        step: marching interval, world units (> 0).
        scores: composite the logits (eq. 3) instead of the probabilities (eq. 7).
        min_trans: early-stop transmittance in [0, 1).
    Returns:
        depth [N] float64, opacity (Σ w_i) [N] float64, probs [N, C] float64 (rows sum to 1).
    """
    values, corner, inv = _check_lattice(values, corner, spacing, 2)
    origins, directions, t_min, t_max = (np.ascontiguousarray(np.asarray(a, np.float64)) for a in rays)
    n = len(origins)
    if origins.shape != (n, 3) or directions.shape != (n, 3) or t_min.shape != (n,) or t_max.shape != (n,):
        raise InputError(
            f"rays must be origins [N, 3], directions [N, 3], t_min [N], t_max [N]; got {origins.shape}, "
            f"{directions.shape}, {t_min.shape}, {t_max.shape}",
            field="rays",
        )
    if not (np.isfinite(step) and step > 0):
        raise InputError(f"step must be a positive number, got {step}", field="step")
    if not 0.0 <= min_trans < 1.0:
        raise InputError(f"min_trans must lie in [0, 1), got {min_trans}", field="min_trans")
    depth, opacity = np.empty(n), np.empty(n)
    probs = np.empty((n, values.shape[3] - 1))

    def run(rows: slice) -> None:
        _rays_kernel(
            values, corner, inv, origins[rows], directions[rows], t_min[rows], t_max[rows], float(step),
            float(min_trans), bool(scores), depth[rows], opacity[rows], probs[rows],
        )

    _in_threads(run, n)
    return depth, opacity, probs


# ---------------------------------------------------------------------------------------------
# the baked field


class BakedField:
    """A :class:`~scenelabel.semantic_field.SemanticField` evaluated once on a vertex lattice,
    answering ``query_points`` and ``query_rays`` (no colour) from it. Build with
    :meth:`from_field`; numpy in, numpy out, world frame, the field's labels and class ids.
    Safe to query from several threads at once.

    Attributes:
        values: [nx+1, ny+1, nz+1, 1 + C] float32: density per world unit, then class logits.
        corner: [3] world position of vertex [0, 0, 0] (the modelled bounds' minimum corner).
        voxel_size: vertex spacing, world units.
        aabb: [2, 3] the modelled bounds (outside them: UNKNOWN, as the field answers).
        class_ids: [C] external class id of each probability column.
        classes: class id -> name.
        occupancy_delta: δ in occupancy = 1 - exp(-density δ) (the field's).
        step: the field's marching step, world units.
        scores: True when the field composites class scores (eq. 3), False for eq. 7.
    """

    def __init__(
        self,
        values: np.ndarray,
        corner: np.ndarray,
        voxel_size: float,
        aabb: np.ndarray,
        classes: dict[int, str],
        rendering: tuple[float, float, bool],
    ):
        """``rendering``: (occupancy_delta, step, scores), as the attributes."""
        self.values, self.corner, _ = _check_lattice(values, corner, voxel_size, 2)
        self.voxel_size = float(voxel_size)
        self.aabb = np.asarray(aabb, np.float64)
        self.classes = dict(classes)
        self.class_ids = np.asarray(list(self.classes), dtype=np.int64)
        if len(self.class_ids) != self.values.shape[3] - 1:
            raise InputError(f"{len(self.class_ids)} classes for {self.values.shape[3] - 1} logit channels", field="classes")
        self.occupancy_delta, self.step, self.scores = float(rendering[0]), float(rendering[1]), bool(rendering[2])
        self.values.setflags(write=False)

    @classmethod
    def from_field(cls, field: SemanticField, voxel_size: float | None = None) -> "BakedField":
        """Evaluate ``field`` at the vertices of a lattice over its modelled bounds.

        The lattice starts at the bounds' minimum corner and has ceil(extent / voxel_size) cells
        per axis (it covers the bounds). Each vertex holds the density and class logits the
        field's own queries see there (0 and uniform where its occupancy grid holds space empty).

        Args:
            field: a box-warped field (room and object captures; a forward-facing capture's
                disparity-marched field is refused: its rays are not marched in equal steps).
            voxel_size: vertex spacing, world units (default: ``field.default_voxel_size()``,
                what the training images resolve).
        Raises:
            InputError: a forward-facing field, a non-positive voxel size, or a lattice larger
                than MAX_BAKE_BYTES.
        """
        if field.model.warp.spacing != "uniform":
            raise InputError(
                "only box-warped fields can be baked (this one marches rays in disparity, a forward-facing capture); "
                "query the SemanticField itself",
                field="field",
            )
        voxel_size = field.default_voxel_size() if voxel_size is None else float(voxel_size)
        if not (np.isfinite(voxel_size) and voxel_size > 0):
            raise InputError(f"voxel_size must be a positive number, got {voxel_size}", field="voxel_size")
        lo, hi = field.aabb
        cells = np.maximum(np.ceil((hi - lo) / voxel_size), 1).astype(int)
        cells += lo + cells * voxel_size < hi  # the division rounded down: one more cell covers the bounds
        n_channels = 1 + field.class_map.num_classes
        n_bytes = int(np.prod(cells + 1)) * n_channels * 4
        if n_bytes > MAX_BAKE_BYTES:
            raise InputError(
                f"a {voxel_size:g} lattice over these bounds needs {n_bytes / 1024**3:.1f} GiB "
                f"(limit {MAX_BAKE_BYTES / 1024**3:.0f} GiB): ask for a larger voxel size",
                field="voxel_size",
            )
        axes = [lo[a] + voxel_size * np.arange(cells[a] + 1) for a in range(3)]
        values = np.empty((*(cells + 1), n_channels), np.float32)
        slab = max(1, BAKE_CHUNK // ((cells[1] + 1) * (cells[2] + 1)))  # x-slabs per network call
        for i in range(0, cells[0] + 1, slab):
            grid = np.stack(np.meshgrid(axes[0][i : i + slab], axes[1], axes[2], indexing="ij"), -1)
            sigma_n, logits = field._sigma_logits_n(field.frame.to_internal(grid.reshape(-1, 3)))
            block = values[i : i + slab]
            # a density past float32's range stays finite (an inf vertex would make a 0-weight corner NaN)
            block[..., 0] = np.minimum(sigma_n * field.frame.scale, FLOAT32_MAX).reshape(block.shape[:3])
            block[..., 1:] = logits.reshape(*block.shape[:3], -1)
        rendering = (field.occupancy_delta, field._step_n / field.frame.scale, field.model.config.semantic_rendering == "scores")
        return cls(values, lo, voxel_size, field.aabb, field.classes, rendering)

    @property
    def nbytes(self) -> int:
        """Memory the lattice takes, bytes."""
        return int(self.values.nbytes)

    def query_points(self, xyz) -> PointQuery:
        """What is at these world points: as :meth:`SemanticField.query_points`, from the lattice.

        Args:
            xyz: (N, 3) world coordinates (numpy or torch).
        Returns:
            PointQuery: density (trilinear, per world unit), occupancy 1 - exp(-density δ), probs
            [N, C] = softmax of the trilinear logits, label = class id where occupancy ≥ 0.5, FREE
            where lower, UNKNOWN outside the modelled bounds (density, occupancy, probs 0 there).
        """
        xyz = np.ascontiguousarray(_as_array(xyz, "xyz", 3))
        n, n_classes = len(xyz), len(self.class_ids)
        density, probs = np.empty(n), np.empty((n, n_classes))

        def run(rows: slice) -> None:
            _points_kernel(self.values, self.corner, 1.0 / self.voxel_size, xyz[rows], density[rows], probs[rows])

        _in_threads(run, n)
        inside = inside_bounds(xyz, self.aabb)
        density[~inside] = 0.0
        probs[~inside] = 0.0
        occupancy = -np.expm1(-density * self.occupancy_delta)
        label = np.where(occupancy >= OCCUPIED_THRESHOLD, self.class_ids[probs.argmax(-1)], FREE)
        label[~inside] = UNKNOWN
        return PointQuery(density, occupancy, probs, self.class_ids.copy(), label)

    def query_rays(self, origins, directions, near=None, far=None) -> RayQuery:
        """What each ray hits, how far, and with which class: as :meth:`SemanticField.query_rays`
        (same step, compositing and early stop; :func:`composite_baked_rays`), from the lattice.

        Args:
            origins: (N, 3) world ray origins.
            directions: (N, 3) world directions; need not be unit length (no zero vector).
            near, far: optional (N,) or scalar limits, distances along the *unit* direction.
        Returns:
            RayQuery (rgb is zeros: the lattice holds no colour); label = class id where the
            opacity is ≥ 0.5, FREE where the ray crosses the bounds without that, UNKNOWN where
            it never enters them.
        """
        origins = _as_array(origins, "origins", 3)
        directions = _as_array(directions, "directions", 3)
        if len(origins) != len(directions):
            raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
        directions, _ = normalize_directions(directions)
        t_enter, t_exit = ray_box_distances(origins, directions, *self.aabb)
        t_min, t_max = np.maximum(t_enter, 0.0), t_exit
        if near is not None:
            t_min = np.maximum(t_min, _as_array(np.broadcast_to(np.asarray(near, np.float64), (len(origins),)), "near", None))
        if far is not None:
            t_max = np.minimum(t_max, _as_array(np.broadcast_to(np.asarray(far, np.float64), (len(origins),)), "far", None))
        depth, opacity, probs = composite_baked_rays(
            self.values, self.corner, self.voxel_size, (origins, directions, t_min, t_max), self.step, self.scores
        )
        hit_label = self.class_ids[probs.argmax(-1)]
        label = np.where(t_max > t_min, np.where(opacity >= OCCUPIED_THRESHOLD, hit_label, FREE), UNKNOWN)
        return RayQuery(np.zeros((len(origins), 3)), depth, opacity, probs, self.class_ids.copy(), label)
