"""What a query answers, for the field and the baked field alike: the answer types (PointQuery,
RayQuery, RenderResult), the label rule, and the checks of query inputs (numpy only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenelabel.codes import CODE_NAMES
from scenelabel.errors import InputError
from scenelabel.geometry.rays import normalize_directions
from scenelabel.maps import FREE, OCCUPIED_THRESHOLD, UNKNOWN

__all__ = [
    "PointQuery",
    "RayQuery",
    "RenderResult",
    "OCCUPIED_THRESHOLD",
    "softmax64",
    "inside_bounds",
    "labels_from_answers",
    "ray_contract",
    "ray_query_inputs",
    "checked_array",
]

@dataclass
class PointQuery:
    """Answers for N points. ``label``: class id where occupied, FREE (-1), UNKNOWN (-2) outside the
    bounds where no training camera saw through."""

    density: np.ndarray  # [N] σ per world unit
    occupancy: np.ndarray  # [N] 1 - exp(-σ δ), δ = SemanticField.occupancy_delta
    probs: np.ndarray  # [N, C] class probabilities (rows sum to 1)
    class_ids: np.ndarray  # [C] external class id of each column of probs
    label: np.ndarray  # [N] int

    def __repr__(self) -> str:
        return _summary("PointQuery", self, "points")


@dataclass
class RayQuery:
    """Answers for N rays, under the ray contract (docs/conventions.md, "Rays"; :func:`ray_contract`):
    a ray that hits (opacity ≥ 0.5 within its interval) has a finite ``depth`` and its class id
    as ``label``; one that crosses the modelled bounds without hitting has depth ``inf`` and
    label FREE; one that never enters them (or whose [near, far] is empty) has depth ``inf``
    and label UNKNOWN."""

    rgb: np.ndarray  # [N, 3]
    depth: np.ndarray  # [N] distance along the unit direction, world units; inf: no hit
    opacity: np.ndarray  # [N]
    probs: np.ndarray  # [N, C]
    class_ids: np.ndarray  # [C]
    label: np.ndarray  # [N]

    def __repr__(self) -> str:
        return _summary("RayQuery", self, "rays")


@dataclass
class RenderResult:
    """Images of one camera."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    depth: np.ndarray  # [H, W] composited depth along each pixel's unit ray (also where nothing was hit: an image to draw)
    opacity: np.ndarray  # [H, W]
    probs: np.ndarray  # [H, W, C] (smoothed when smooth_sigma was given)
    label: np.ndarray  # [H, W] class ids; FREE / UNKNOWN where nothing was hit


def _summary(name: str, answers, count_field: str) -> str:
    """A one-line repr of an answer: how many, over which classes, and its labels' counts."""
    label = np.asarray(answers.label)
    codes, counts = np.unique(label, return_counts=True)
    tally = ", ".join(f"{CODE_NAMES.get(int(c), int(c))}: {int(n)}" for c, n in zip(codes[:8], counts[:8]))
    more = ", ..." if len(codes) > 8 else ""
    return f"{name}({count_field}={label.size}, classes={np.asarray(answers.class_ids).tolist()}, labels={{{tally}{more}}})"


def softmax64(logits: np.ndarray) -> np.ndarray:
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


def ray_contract(
    depth: np.ndarray, opacity: np.ndarray, hit_label: np.ndarray, entered: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The ray contract shared by ``SemanticField.query_rays``, ``BakedField.query_rays`` and
    ``OccupancyMap.cast_rays`` (docs/conventions.md, "Rays"): where a ray's ``opacity`` reaches
    OCCUPIED_THRESHOLD it hits, at ``depth`` with ``hit_label``; elsewhere its depth is ``inf``
    and its label FREE (it crossed the bounds) or UNKNOWN (``entered`` False: it never did).

    Args:
        depth: [N] composited depth, world units; opacity: [N] Σ w; hit_label: [N] class id of the
            composited probabilities; entered: [N] bool, the ray's [t_min, t_max] is not empty.
    Returns:
        depth [N] float64 (``inf`` without a hit), label [N] (:func:`labels_from_answers`).
    """
    hit = entered & (opacity >= OCCUPIED_THRESHOLD)
    return np.where(hit, depth, np.inf), labels_from_answers(hit_label, opacity, entered)


def ray_query_inputs(origins, directions, near, far) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A ray query's inputs checked: origins [N, 3], unit directions [N, 3] (see
    :func:`scenelabel.geometry.rays.normalize_directions`), near / far as [N] float64 or None (scalars
    broadcast), all world units."""
    origins = checked_array(origins, "origins", 3)
    directions = checked_array(directions, "directions", 3)
    if len(origins) != len(directions):
        raise InputError(f"{len(origins)} origins but {len(directions)} directions", field="directions")
    directions, _ = normalize_directions(directions)

    def limit(value, name):
        return None if value is None else checked_array(np.broadcast_to(np.asarray(value, np.float64), (len(origins),)), name, None)

    return origins, directions, limit(near, "near"), limit(far, "far")


def checked_array(value, name: str, last_dim: int | None) -> np.ndarray:
    """numpy or torch input -> float64 numpy [N, last_dim] (or [N]); checks shape and finiteness."""
    if hasattr(value, "detach"):  # a torch tensor (torch itself is not imported here)
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
