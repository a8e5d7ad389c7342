"""A trained field baked onto a vertex lattice: point and ray queries without the network.

:meth:`BakedField.from_field` evaluates a :class:`~scenelabel.query.field.SemanticField` once
at the vertices of a lattice over its modelled bounds (density and the class values the field
composites, as its own queries see them: zero density where its density grid holds space
empty; class probabilities as uint8 codes for an eq. 7 field, float32 logits for an eq. 3 one).
Queries then interpolate that lattice trilinearly in compiled loops (numba), so they cost a few
memory reads per point and per ray sample instead of a network evaluation:

- :meth:`BakedField.query_points`: density, occupancy, class probabilities and label per point;
- :meth:`BakedField.query_rays`: depth, opacity, class probabilities and label per ray, marched
  and composited as the field marches them (same step, NeRF eq. 3 quadrature, eq. 7 or eq. 3
  class compositing, the same early stop).

The trade: answers follow the field to within what trilinear interpolation at the lattice's
spacing keeps (the default spacing is the field's ``finest_cell``, the finest detail it holds);
tools/bench.py measures the agreement next to the speed. The maths (:func:`trilinear`,
:func:`composite_baked_rays`) is pure and takes numpy arrays; :class:`BakedField` holds the
lattice. Both are safe to call from several threads at once (nothing is modified).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from scenelabel._version import __version__
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras, cameras_from_dict, cameras_to_dict
from scenelabel.maps import FREE, ray_box_distances, uint8_from_unit
from scenelabel.maps.visibility import seen_before_bounds
from scenelabel.maps.zarr_io import check_target, staged_group
from scenelabel.query.answers import (
    PointQuery,
    RayQuery,
    checked_array,
    labels_from_answers,
    ray_contract,
    ray_query_inputs,
    softmax64,
)
from scenelabel.render.constants import EARLY_STOP_TRANS

if TYPE_CHECKING:  # the field (and torch) only for baking; a saved BakedField loads without them
    from scenelabel.query.field import SemanticField

__all__ = ["BakedField", "trilinear", "composite_baked_rays", "MAX_BAKE_BYTES", "BAKED_FORMAT", "BAKED_FORMAT_VERSION"]

BAKED_FORMAT = "scenelabel.baked_field"
"""The ``format`` attribute of a saved BakedField's zarr group (:meth:`BakedField.save`)."""

BAKED_FORMAT_VERSION = 1
"""Its layout version; :meth:`BakedField.load` refuses other versions."""

MAX_BAKE_BYTES = 2 * 1024**3
"""A bake refuses a lattice whose values would take more memory than this (ask for a larger voxel size)."""

FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Baked densities are clamped to this (the lattice is float32; the kernels blend in float64)."""

BAKE_CHUNK = 1 << 18
"""Vertices evaluated per network call while baking."""


# ---------------------------------------------------------------------------------------------
# the maths, on numpy arrays (the loops: scenelabel.render.lattice_kernels, imported on first use)


def _kernels():
    from scenelabel.render import lattice_kernels

    return lattice_kernels


def _lattice_frame(corner: Any, spacing: float) -> np.ndarray:
    """(corner x, y, z, 1 / spacing) as the kernels read a lattice's placement."""
    corner = np.asarray(corner, np.float64).reshape(3)
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"spacing must be a positive number, got {spacing}", field="spacing")
    return np.append(corner, 1.0 / float(spacing))


def _vertex_grid(values: Any, name: str, ndim: int, dtypes: tuple = (np.float32,)) -> np.ndarray:
    """values as a C-contiguous [nx+1, ny+1, nz+1(, F)] array (at least 2 vertices per axis and 1
    channel), kept in its dtype when it is one of ``dtypes``, else converted to the first."""
    values = np.asarray(values)
    if values.ndim != ndim or min(values.shape[:3]) < 2 or values.shape[3:] == (0,):
        want = "[nx+1, ny+1, nz+1" + (", F]" if ndim == 4 else "]")
        raise InputError(f"{name} must be {want} with at least 2 vertices per axis, got {values.shape}", field=name)
    return np.ascontiguousarray(values, dtype=values.dtype if values.dtype in dtypes else dtypes[0])


def _check_lattice(density: Any, class_values: Any) -> tuple[np.ndarray, np.ndarray]:
    """density float32 [nx+1, ny+1, nz+1] and class values [nx+1, ny+1, nz+1, C] (uint8 kept,
    anything else float32) on the same vertices."""
    density = _vertex_grid(density, "density", 3)
    class_values = _vertex_grid(class_values, "class_values", 4, (np.float32, np.uint8))
    if class_values.shape[:3] != density.shape:
        raise InputError(f"class_values {class_values.shape} and density {density.shape} differ in vertices", field="class_values")
    return density, class_values


def trilinear(values: np.ndarray, corner: Any, spacing: float, points: Any) -> np.ndarray:
    """Trilinear interpolation of a vertex lattice at world points.

    Vertex ``[i, j, k]`` sits at ``corner + spacing * (i, j, k)``; a point between vertices gets
    the tensor-product linear blend of its cell's 8 corners (exact at the vertices, linear along
    each cell edge). Points outside the lattice (or NaN) get 0.

    Args:
        values: [nx+1, ny+1, nz+1, F] (read as float32, uint8 as it is).
        corner: [3] world position of vertex [0, 0, 0].
        spacing: vertex spacing, world units.
        points: [N, 3] world points.
    Returns:
        [N, F] float32.
    """
    values = _vertex_grid(values, "values", 4, (np.float32, np.uint8))
    frame = _lattice_frame(corner, spacing)
    points = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
    out = np.empty((len(points), values.shape[3]), np.float32)
    kernel = _kernels().trilinear_kernel
    _kernels().in_threads(lambda rows: kernel(values, frame, points[rows], out[rows]), len(points))
    return out


def composite_baked_rays(
    lattice: tuple[np.ndarray, np.ndarray, Any, float],
    rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    step: float,
    scores: bool = False,
    min_trans: float = EARLY_STOP_TRANS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Volume-render rays through a lattice of density and class values (probabilities, or
    logits with ``scores``).

    Each ray is marched from t_min in intervals of ``step`` (the last one cut at t_max, as
    :func:`scenelabel.render.sampling.march_uniform` without jitter) with the density σ_i read at the
    interval middle t_i (trilinear; negative values count as 0, points outside the lattice as 0),
    and composited as a renderer does (NeRF eq. 3): α_i = 1 - exp(-σ_i δ_i), T_{i+1} = T_i (1 - α_i),
    w_i = T_i α_i. Depth is Σ w_i t_i / Σ w_i clipped to [t_min, t_max]; class probabilities are
    Σ w_i p_i / Σ w_i (eq. 7, p_i the trilinear probabilities), or softmax(Σ w_i l_i) with
    ``scores`` (eq. 3, l_i the trilinear logits). A ray with Σ w_i ≤ OPACITY_EPS (1e-10, "empty")
    reports depth max(t_max, 0) and the uniform law. A ray stops once T < ``min_trans`` (the
    weight it leaves out is at most that; 0: never stop).

    Args:
        lattice: (density [nx+1, ny+1, nz+1] per world unit, class_values [nx+1, ny+1, nz+1, C],
            corner [3] world position of vertex [0, 0, 0], spacing between vertices in world
            units). Probabilities may carry any scale (uint8 codes q = round(255 p) are read as
            they are): each sample's trilinear values are normalised to sum to 1.
        rays: (origins [N, 3], directions [N, 3] unit, t_min [N], t_max [N]) world units;
            t_max ≤ t_min for a ray with nothing to march.
        step: marching interval, world units (> 0).
        scores: the class values are logits, composited before the softmax (eq. 3).
        min_trans: early-stop transmittance in [0, 1).
    Returns:
        depth [N] float64, opacity (Σ w_i) [N] float64, probs [N, C] float64 (rows sum to 1).
    """
    density, class_values = _check_lattice(lattice[0], lattice[1])
    frame = _lattice_frame(lattice[2], lattice[3])
    origins, directions, t_min, t_max = (np.asarray(a, np.float64) for a in rays)
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
    origins, directions = np.ascontiguousarray(origins), np.ascontiguousarray(directions)
    span = np.stack([t_min, t_max], -1)
    out, probs = np.empty((n, 2)), np.empty((n, class_values.shape[3]))
    kernel = _kernels().rays_kernel

    def run(rows: slice) -> None:
        kernel(
            density, class_values, frame, origins[rows], directions[rows], span[rows], (float(step), float(min_trans)),
            bool(scores), out[rows], probs[rows],
        )

    _kernels().in_threads(run, n)
    return out[:, 0], out[:, 1], probs


# ---------------------------------------------------------------------------------------------
# the baked field


class BakedField:
    """A :class:`~scenelabel.query.field.SemanticField` evaluated once on a vertex lattice,
    answering ``query_points`` and ``query_rays`` (no colour) from it. Build with
    :meth:`from_field`; numpy in, numpy out, world frame, the field's labels and class ids.
    Safe to query from several threads at once.

    Attributes:
        density: [nx+1, ny+1, nz+1] float32, per world unit.
        class_values: [nx+1, ny+1, nz+1, C]: uint8 class probabilities ``round(255 p)`` (an eq. 7
            field, which composites probabilities: a code q means q / 255, as in maps), or float32
            logits (``scores``, an eq. 3 field).
        corner: [3] world position of vertex [0, 0, 0] (the modelled bounds' minimum corner).
        voxel_size: vertex spacing, world units.
        aabb: [2, 3] the modelled bounds (outside them: FREE where a training camera saw through,
            else UNKNOWN, as the field answers).
        train_cameras: the field's training cameras (world frame), or None (outside the bounds:
            UNKNOWN).
        class_ids: [C] external class id of each probability column.
        classes: class id -> name.
        occupancy_delta: δ in occupancy = 1 - exp(-density δ) (the field's).
        step: the field's marching step, world units.
        scores: True when the field composites class scores (eq. 3), False for probabilities (eq. 7).
    """

    def __init__(
        self,
        lattice: tuple[np.ndarray, np.ndarray, Any, float],
        aabb: np.ndarray,
        classes: dict[int, str],
        rendering: tuple[float, float, bool],
        train_cameras: Cameras | None = None,
    ):
        """``lattice``: (density, class_values, corner, voxel_size); ``rendering``:
        (occupancy_delta, step, scores); ``train_cameras``: as the attributes."""
        self.density, self.class_values = _check_lattice(lattice[0], lattice[1])
        self.corner = _lattice_frame(lattice[2], lattice[3])[:3]
        self.voxel_size = float(lattice[3])
        self.aabb = np.asarray(aabb, np.float64)
        self.classes = dict(classes)
        self.class_ids = np.asarray(list(self.classes), dtype=np.int64)
        if len(self.class_ids) != self.class_values.shape[3]:
            raise InputError(f"{len(self.class_ids)} classes for {self.class_values.shape[3]} class channels", field="classes")
        self.occupancy_delta, self.step, self.scores = float(rendering[0]), float(rendering[1]), bool(rendering[2])
        self.train_cameras = train_cameras
        self.density.setflags(write=False)
        self.class_values.setflags(write=False)

    def __repr__(self) -> str:
        return (
            f"BakedField(vertices={self.density.shape}, voxel_size={self.voxel_size:.4g}, classes={self.classes}, "
            f"{self.density.nbytes + self.class_values.nbytes:,} bytes)"
        )

    @classmethod
    def from_field(cls, field: "SemanticField", voxel_size: float | None = None) -> "BakedField":
        """Evaluate ``field`` at the vertices of a lattice over its modelled bounds.

        The lattice starts at the bounds' minimum corner and has ceil(extent / voxel_size) cells
        per axis (it covers the bounds). Each vertex holds the density and class values the
        field's own queries see there (0 and uniform where its density grid holds space empty).
        An eq. 7 field's vertices hold class probabilities, the values it composites, as uint8
        codes: a ray sample then reads C bytes and blends them instead of C floats and a softmax.
        An eq. 3 field's vertices hold its float32 logits.

        Args:
            field: a box-warped field (room and object captures; a forward-facing capture's
                disparity-marched field is refused: its rays are not marched in equal steps).
            voxel_size: vertex spacing, world units (default: ``field.finest_cell()``, the
                finest detail the field holds).
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
        voxel_size = field.finest_cell() if voxel_size is None else float(voxel_size)
        if not (np.isfinite(voxel_size) and voxel_size > 0):
            raise InputError(f"voxel_size must be a positive number, got {voxel_size}", field="voxel_size")
        lo, hi = field.aabb
        cells = np.maximum(np.ceil((hi - lo) / voxel_size), 1).astype(int)
        cells += lo + cells * voxel_size < hi  # the division rounded down: one more cell covers the bounds
        scores = field.model.config.semantic_rendering == "scores"
        class_dtype = np.float32 if scores else np.uint8
        n_classes = field.class_map.num_classes
        n_bytes = int(np.prod(cells + 1)) * (4 + n_classes * np.dtype(class_dtype).itemsize)
        if n_bytes > MAX_BAKE_BYTES:
            raise InputError(
                f"a {voxel_size:g} lattice over these bounds needs {n_bytes / 1024**3:.1f} GiB "
                f"(limit {MAX_BAKE_BYTES / 1024**3:.0f} GiB): ask for a larger voxel size",
                field="voxel_size",
            )
        axes = [lo[a] + voxel_size * np.arange(cells[a] + 1) for a in range(3)]
        density = np.empty(tuple(cells + 1), np.float32)
        class_values = np.empty((*(cells + 1), n_classes), class_dtype)
        slab = max(1, BAKE_CHUNK // ((cells[1] + 1) * (cells[2] + 1)))  # x-slabs per network call
        for i in range(0, cells[0] + 1, slab):
            grid = np.stack(np.meshgrid(axes[0][i : i + slab], axes[1], axes[2], indexing="ij"), -1)
            sigma_n, logits = field.sigmas_and_logits_n(field.frame.to_normalised(grid.reshape(-1, 3)))
            block = density[i : i + slab]
            # a density past float32's range stays finite (an inf vertex would make a 0-weight corner NaN)
            block[:] = np.minimum(sigma_n * field.frame.scale, FLOAT32_MAX).reshape(block.shape)
            class_values[i : i + slab] = (logits if scores else uint8_from_unit(softmax64(logits))).reshape(*block.shape, -1)
        rendering = (field.occupancy_delta, field.marching.step / field.frame.scale, scores)
        return cls((density, class_values, lo, voxel_size), field.aabb, field.classes, rendering, field.training_cameras())

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the lattice as a zarr group (format 3), so another process can answer queries
        with :meth:`load` without the field, the network or torch (docs/formats.md, "Baked field").

        Layout: arrays ``density`` [nx+1, ny+1, nz+1] float32 and ``class_values`` [nx+1, ny+1,
        nz+1, C] (uint8 codes, or float32 logits with ``scores``); group attributes ``format``
        (:data:`BAKED_FORMAT`), ``format_version``, ``scenelabel_version``, ``corner``,
        ``voxel_size``, ``aabb``, ``classes`` (``{"id": name}``, the channel order),
        ``occupancy_delta``, ``step``, ``scores``, and ``train_cameras`` where the field stored them
        (:func:`scenelabel.geometry.cameras.cameras_to_dict`). Written atomically (a failed write leaves
        ``path`` as it was).

        Args:
            path: the ``.zarr`` folder to write.
            overwrite: replace an existing zarr group at ``path``.
        Returns:
            The absolute path written.
        """
        import zarr

        _, _, path = check_target(path, 3, (64, 64, 64), overwrite)
        attrs = {
            "format": BAKED_FORMAT,
            "format_version": BAKED_FORMAT_VERSION,
            "scenelabel_version": __version__,
            "corner": self.corner.tolist(),
            "voxel_size": self.voxel_size,
            "aabb": self.aabb.tolist(),
            "classes": {str(cid): name for cid, name in self.classes.items()},
            "occupancy_delta": self.occupancy_delta,
            "step": self.step,
            "scores": self.scores,
        }
        if self.train_cameras is not None:
            attrs["train_cameras"] = cameras_to_dict(self.train_cameras)
        with staged_group(path) as tmp:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            group.attrs.update(attrs)
            for name, values in (("density", self.density), ("class_values", self.class_values)):
                chunks = (64, 64, 64) + values.shape[3:]
                group.create_array(name, shape=values.shape, dtype=values.dtype, chunks=chunks)[...] = values
        return path

    @classmethod
    def load(cls, path: str | Path) -> "BakedField":
        """A BakedField written by :meth:`save`. Imports neither torch nor the field.

        Raises:
            InputError: ``path`` is not a saved BakedField, or one of another format version.
        """
        path = Path(path).expanduser()
        import zarr

        try:
            group = zarr.open_group(str(path), mode="r")
        except (FileNotFoundError, ValueError) as err:  # zarr's GroupNotFoundError is both
            raise InputError(f"not a zarr group ({type(err).__name__})", path=path) from None
        attrs = dict(group.attrs.asdict())
        if attrs.get("format") != BAKED_FORMAT:
            raise InputError(f"format is {attrs.get('format')!r}, expected {BAKED_FORMAT!r}", path=path, field="format")
        if attrs.get("format_version") != BAKED_FORMAT_VERSION:
            raise InputError(
                f"format_version {attrs.get('format_version')!r} is not supported (this scenelabel reads "
                f"{BAKED_FORMAT_VERSION}): bake the field again with this version",
                path=path, field="format_version",
            )
        lattice = (group["density"][...], group["class_values"][...], attrs["corner"], attrs["voxel_size"])
        classes = {int(cid): name for cid, name in attrs["classes"].items()}
        rendering = (attrs["occupancy_delta"], attrs["step"], attrs["scores"])
        cameras = cameras_from_dict(attrs["train_cameras"]) if "train_cameras" in attrs else None
        return cls(lattice, np.asarray(attrs["aabb"]), classes, rendering, cameras)

    @property
    def nbytes(self) -> int:
        """Memory the lattice takes, bytes."""
        return int(self.density.nbytes + self.class_values.nbytes)

    def query_points(self, xyz) -> PointQuery:
        """What is at these world points: as :meth:`SemanticField.query_points`, from the lattice.

        Args:
            xyz: (N, 3) world coordinates (numpy or torch).
        Returns:
            PointQuery: density (trilinear, per world unit), occupancy 1 - exp(-density δ), probs
            [N, C] (the trilinear probabilities, normalised; for an eq. 3 field the softmax of
            the trilinear logits), label = class id where occupancy ≥ 0.5, FREE where lower,
            outside the modelled bounds (density, occupancy, probs 0 there) FREE where a training
            camera saw through the point (:func:`scenelabel.maps.visibility.seen_before_bounds`),
            else UNKNOWN.
        """
        xyz = np.ascontiguousarray(checked_array(xyz, "xyz", 3))
        n, n_classes = len(xyz), len(self.class_ids)
        density, probs = np.empty(n), np.empty((n, n_classes))
        inside, top = np.empty(n, bool), np.empty(n, np.int64)  # in the bounds; argmax of probs
        frame, aabb, kernel = _lattice_frame(self.corner, self.voxel_size), np.ascontiguousarray(self.aabb), _kernels().points_kernel

        def run(rows: slice) -> None:
            kernel(
                self.density, self.class_values, frame, aabb, xyz[rows], self.scores,
                density[rows], probs[rows], inside[rows], top[rows],
            )

        _kernels().in_threads(run, n)
        occupancy = -np.expm1(-density * self.occupancy_delta)
        label = labels_from_answers(self.class_ids[top], occupancy, inside)
        if self.train_cameras is not None:
            label[seen_before_bounds(xyz, self.train_cameras, self.aabb)] = FREE
        return PointQuery(density, occupancy, probs, self.class_ids.copy(), label)

    def query_rays(self, origins, directions, near=None, far=None) -> RayQuery:
        """What each ray hits, how far, and with which class: as :meth:`SemanticField.query_rays`
        (same step, compositing and early stop; :func:`composite_baked_rays`), from the lattice.

        Args:
            origins: (N, 3) world ray origins.
            directions: (N, 3) world directions; need not be unit length (no zero vector).
            near, far: optional (N,) or scalar limits, distances along the *unit* direction.
        Returns:
            RayQuery (rgb is zeros: the lattice holds no colour) under the ray contract
            (:func:`~scenelabel.query.answers.ray_contract`): depth and class id where the opacity
            is ≥ 0.5; depth ``inf`` and FREE where the ray crosses the bounds without that,
            ``inf`` and UNKNOWN where it never enters them.
        """
        origins, directions, near, far = ray_query_inputs(origins, directions, near, far)
        t_enter, t_exit = ray_box_distances(origins, directions, *self.aabb)
        t_min, t_max = np.maximum(t_enter, 0.0), t_exit
        if near is not None:
            t_min = np.maximum(t_min, near)
        if far is not None:
            t_max = np.minimum(t_max, far)
        depth, opacity, probs = composite_baked_rays(
            (self.density, self.class_values, self.corner, self.voxel_size), (origins, directions, t_min, t_max),
            self.step, self.scores,
        )
        depth, label = ray_contract(depth, opacity, self.class_ids[probs.argmax(-1)], t_max > t_min)
        return RayQuery(np.zeros((len(origins), 3)), depth, opacity, probs, self.class_ids.copy(), label)
