"""Evaluation metrics: PSNR, SSIM, confusion matrix / mIoU, depth error (numpy in, numbers out).

Pixels labelled ``ignore_index`` never count; neither do pixels whose true class is not in the
evaluated ``class_ids``. Predictions outside ``class_ids`` (FREE, UNKNOWN, other ids) are always
wrong: they count as misses of the true class (a last "other" column of the confusion matrix).
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

from scenelabel.codes import FREE
from scenelabel.errors import InputError

__all__ = [
    "BOX_DISTANCE_CHUNK_PAIRS",
    "COMMON_CLASS_SHARE",
    "FREE_PROBE_MARGIN",
    "FSCORE_THRESHOLD",
    "SURFACE_PROBE_BEHIND",
    "boundary_f1",
    "box_surface_distance",
    "boxes_lo_hi",
    "confusion_matrix",
    "depth_error",
    "label_accuracy",
    "label_boundaries",
    "miou",
    "no_hit_as_free",
    "spurious_classes",
    "pose_centre_errors",
    "pose_rotation_errors_deg",
    "probe_points",
    "psnr",
    "relative_depth_error",
    "ssim",
    "surface_fscore",
    "surface_points_from_depth",
]

SSIM_WINDOW = 7
"""skimage's default SSIM window; smaller images use the largest odd window that fits."""
SSIM_MIN_WINDOW = 3
"""skimage cannot compute SSIM with a window below 3 px: smaller images are an error."""
SURFACE_PROBE_BEHIND = 0.02
"""Metres past the true surface, along the viewing ray, of a surface (occupied) probe point."""
FREE_PROBE_MARGIN = 0.1
"""Metres before the true surface that free-space probe points keep clear of."""
FSCORE_THRESHOLD = 0.05
"""Metres: distance within which a point counts as on the other surface (surface F-score)."""
BOX_DISTANCE_CHUNK_PAIRS = 1 << 20
"""Point-box pairs per chunk in :func:`box_surface_distance`: each [chunk, m, 3] float64
temporary is 24 MiB, and the peak extra memory stays below ~80 MiB whatever n."""


def _same_shape(pred: np.ndarray, target: np.ndarray, what: str) -> None:
    if pred.shape != target.shape:
        raise InputError(f"{what}: prediction {pred.shape} and target {target.shape} differ", field="pred")


def psnr(pred: np.ndarray, target: np.ndarray, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio 10 log10(max² / MSE) in dB; inf for identical images.

    Args:
        pred, target: [H, W, 3] (any matching shape) in [0, max_value].
    Returns:
        PSNR in dB; ``inf`` when the images are identical (MSE 0).
    """
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    _same_shape(pred, target, "psnr")
    mse = float(np.mean((pred - target) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(max_value**2 / mse))


def ssim(pred: np.ndarray, target: np.ndarray, data_range: float = 1.0) -> float:
    """Structural similarity (skimage, uniform 7x7 window) of images in [0, data_range].

    Args:
        pred, target: [H, W, 3] colour (channel axis last) or [H, W] grey images.
    Images smaller than 7 px use the largest odd window that fits (at least 3 px; smaller
    images raise InputError).
    """
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    _same_shape(pred, target, "ssim")
    if pred.ndim not in (2, 3):
        raise InputError(f"ssim needs [H, W] or [H, W, C] images, got {pred.shape}", field="pred")
    win = min(SSIM_WINDOW, *pred.shape[:2])
    win = win if win % 2 == 1 else win - 1
    if win < SSIM_MIN_WINDOW:
        raise InputError(f"ssim needs images of at least {SSIM_MIN_WINDOW}x{SSIM_MIN_WINDOW} px, got {pred.shape[:2]}", field="pred")
    channel_axis = -1 if pred.ndim == 3 else None
    return float(
        structural_similarity(pred, target, channel_axis=channel_axis, data_range=data_range, win_size=win)
    )


def no_hit_as_free(pred_ids: np.ndarray) -> np.ndarray:
    """Predicted labels [...] with every code of a ray that hit nothing (FREE, and UNKNOWN: it never
    entered the modelled bounds) read as FREE: the prediction a true FREE pixel (its ray meets
    nothing, classes.json's ``free_index``) is scored against. Against a class, both are wrong."""
    pred_ids = np.asarray(pred_ids)
    return np.where(pred_ids < 0, FREE, pred_ids)


def confusion_matrix(
    pred_ids: np.ndarray, target_ids: np.ndarray, class_ids: np.ndarray, ignore_index: int | None = None
) -> np.ndarray:
    """Counts [C, C + 1]: rows = true class, columns = predicted class over ``class_ids``, and a
    last column for predictions outside class_ids (FREE, UNKNOWN, other ids: always wrong).

    Pixels whose target is ignore_index or not in class_ids are skipped.

    Args:
        pred_ids, target_ids: int arrays of external ids, same shape.
        class_ids: [C] ascending external ids.
    """
    class_ids = np.asarray(class_ids, np.int64)
    pred = np.asarray(pred_ids, np.int64).ravel()
    target = np.asarray(target_ids, np.int64).ravel()
    if np.shape(pred_ids) != np.shape(target_ids):
        raise InputError(f"prediction {np.shape(pred_ids)} and target {np.shape(target_ids)} differ", field="pred_ids")
    if class_ids.ndim != 1 or len(class_ids) == 0 or np.any(np.diff(class_ids) <= 0):
        raise InputError(f"class_ids must be non-empty, unique and ascending, got {class_ids.tolist()}", field="class_ids")
    C = len(class_ids)
    t_pos = np.searchsorted(class_ids, target).clip(0, C - 1)
    valid = class_ids[t_pos] == target
    if ignore_index is not None:
        valid &= target != ignore_index
    p_pos = np.searchsorted(class_ids, pred).clip(0, C - 1)
    cols = np.where(class_ids[p_pos] == pred, p_pos, C)
    flat = t_pos[valid] * (C + 1) + cols[valid]
    return np.bincount(flat, minlength=C * (C + 1)).astype(np.int64).reshape(C, C + 1)


COMMON_CLASS_SHARE = 0.001
"""The share of the labelled held-out pixels a class needs to enter ``miou_common`` (``metrics.json``):
the classes that cover at least 0.1 % of them. A class below it rests its IoU on a few dozen pixels
at 160x120 (a lamp's pole in a large room: whether single pixel centres hit a pole narrower than
their footprint), so its IoU swings from run to run. The measure of the office scan in issue 20."""


def miou(confusion: np.ndarray, min_share: float = 0.0) -> tuple[float, np.ndarray]:
    """Mean intersection over union from a [C, C + 1] confusion matrix (or a plain [C, C] one).

    IoU_c = TP / (TP + FP + FN) for every class; NaN for a class absent from both target and
    prediction. The mean is over the classes the **target** holds (Semantic-NeRF's
    ``miou_valid_class``; ScanNet's and Cityscapes' benchmarks also leave classes without ground
    truth out): a class that is only predicted keeps its IoU of 0 in the per-class array, and its
    pixels count against the classes they truly belong to (as their false negatives), but it does
    not enter the mean with the weight of a whole class. On the few held-out views of a room, that
    weight made the mean hinge on a handful of stray pixels of a class no held-out view shows.
    :func:`spurious_classes` names such classes. With ``min_share``, the mean is over the classes
    that hold at least that share of the target's pixels (:data:`COMMON_CLASS_SHARE`).

    Returns:
        (mean IoU, NaN when the target holds no class; [C] per-class IoU).
    """
    confusion = np.asarray(confusion, np.float64)
    C = confusion.shape[0]
    tp = np.diag(confusion[:, :C])
    in_target = confusion.sum(1)
    fn = in_target - tp
    fp = confusion[:, :C].sum(0) - tp
    denom = tp + fp + fn
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(denom > 0, tp / denom, np.nan)
    counted = (in_target > 0) & (in_target >= min_share * in_target.sum())
    return (float(np.mean(iou[counted])) if np.any(counted) else float("nan")), iou


def spurious_classes(confusion: np.ndarray) -> np.ndarray:
    """[C] predicted pixels of each class the target does not hold (0 for the classes it holds):
    what :func:`miou` leaves out of its mean, from a [C, C + 1] (or [C, C]) confusion matrix."""
    confusion = np.asarray(confusion)
    C = confusion.shape[0]
    predicted = confusion[:, :C].sum(0)
    return np.where(confusion.sum(1) > 0, 0, predicted)


def depth_error(
    pred_depth: np.ndarray, target_depth: np.ndarray, valid_mask: np.ndarray | None = None
) -> dict[str, float]:
    """Depth errors over valid pixels: abs_rel = mean |p - t| / t, rmse, mae (world units).

    Args:
        pred_depth, target_depth: [H, W] depth along the unit ray (any matching shape).
        valid_mask: [H, W] bool, or None for all pixels. Pixels whose target is not finite and
            positive (0 = no surface in the synthetic scenes) never count. A non-finite
            prediction at a valid pixel is not skipped: it makes the errors non-finite.
    Returns:
        {"abs_rel", "rmse", "mae"}: NaN each when no pixel is valid.
    """
    pred = np.asarray(pred_depth, np.float64)
    target = np.asarray(target_depth, np.float64)
    _same_shape(pred, target, "depth_error")
    valid = np.isfinite(target) & (target > 0)
    if valid_mask is not None:
        valid &= np.asarray(valid_mask, bool)
    if not valid.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "mae": float("nan")}
    diff = pred[valid] - target[valid]
    return {
        "abs_rel": float(np.mean(np.abs(diff) / target[valid])),
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "mae": float(np.mean(np.abs(diff))),
    }


def label_boundaries(labels: np.ndarray, ignore_index: int | None = None) -> np.ndarray:
    """[H, W] bool: pixels whose right or lower 4-neighbour has another label.

    A pair where either pixel is ``ignore_index`` is not a boundary.
    """
    labels = np.asarray(labels)
    edge = np.zeros(labels.shape, dtype=bool)
    for axis in (0, 1):
        a = labels.take(np.arange(labels.shape[axis] - 1), axis=axis)
        b = labels.take(np.arange(1, labels.shape[axis]), axis=axis)
        diff = a != b
        if ignore_index is not None:
            diff &= (a != ignore_index) & (b != ignore_index)
        pad = [(0, 1) if ax == axis else (0, 0) for ax in range(2)]
        edge |= np.pad(diff, pad)
    return edge


def boundary_f1(pred: np.ndarray, target: np.ndarray, tolerance: float = 2.0, ignore_index: int | None = None) -> float:
    """Boundary F-score (Csurka et al. 2013): how well predicted label boundaries match true ones.

    Precision: fraction of predicted boundary pixels within ``tolerance`` pixels (Euclidean) of a
    true boundary; recall: the converse; F1 their harmonic mean. 1.0 when neither has a boundary,
    0.0 when only one has.

    Args:
        pred, target: [H, W] integer label images.
        tolerance: pixels.
        ignore_index: target pixels with this value are never boundaries (pred boundaries there
            are dropped too).
    """
    from scipy.ndimage import distance_transform_edt

    _same_shape(pred, target, "boundary_f1")
    bt = label_boundaries(target, ignore_index)
    bp = label_boundaries(pred)
    if ignore_index is not None:
        bp &= np.asarray(target) != ignore_index
    if not bt.any() and not bp.any():
        return 1.0
    if not bt.any() or not bp.any():
        return 0.0
    near_true = distance_transform_edt(~bt) <= tolerance
    near_pred = distance_transform_edt(~bp) <= tolerance
    precision = float(near_true[bp].mean())
    recall = float(near_pred[bt].mean())
    return 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)


# ------------------------------------------------------------------ camera poses


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix to ``m`` [3, 3] (SVD, det +1)."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def pose_rotation_errors_deg(c2w_true: np.ndarray, c2w_est: np.ndarray) -> np.ndarray:
    """Per-camera rotation error in degrees, after fitting the unknown world rotation G.

    For poses recovered in another world frame (structure from motion): G is the rotation
    nearest to Σ_i R_true_i R_est_iᵀ (the least-squares fit of R_true ≈ G R_est), and the error of
    camera i is the angle of R_true_iᵀ G R_est_i.

    Args:
        c2w_true, c2w_est: [n, 4, 4] camera-to-world, the same camera axes, matched by index.
    Returns:
        [n] float64 degrees.
    """
    r_true, r_est = np.asarray(c2w_true)[:, :3, :3], np.asarray(c2w_est)[:, :3, :3]
    g = _nearest_rotation(np.sum(r_true @ np.transpose(r_est, (0, 2, 1)), axis=0))
    cos = (np.trace(np.transpose(r_true, (0, 2, 1)) @ g @ r_est, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_centre_errors(c2w_true: np.ndarray, c2w_est: np.ndarray) -> np.ndarray:
    """Per-camera centre error after a similarity fit (Umeyama 1991), relative to the true spread.

    Args:
        c2w_true, c2w_est: [n, 4, 4] matched by index (n >= 3, centres not all collinear).
    Returns:
        [n] float64: |s R x_est + t - x_true| / RMS distance of the true centres from their mean.
    """
    x, y = np.asarray(c2w_est)[:, :3, 3], np.asarray(c2w_true)[:, :3, 3]
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    u, s, vt = np.linalg.svd(yc.T @ xc / len(x))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ d @ vt
    scale = np.trace(np.diag(s) @ d) / xc.var(0).sum()
    aligned = scale * xc @ rotation.T + my
    spread = np.sqrt((yc**2).sum(1).mean())
    return np.linalg.norm(aligned - y, axis=1) / spread


# ------------------------------------------------------------------ 3D metrics against exact geometry
# The synthetic scenes are labelled axis-aligned boxes with exact depth (scenelabel.data.synthetic);
# these metrics compare predicted depth, occupancy and surfaces with that exact geometry.


def relative_depth_error(pred_depth: np.ndarray, true_depth: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Median over valid pixels (rays) of the relative depth error |pred - true| / true.

    Args:
        pred_depth, true_depth: depth along the unit ray, any matching shape.
        valid: bool, the same shape, or None for all. Pixels whose true depth is not finite and
            positive (0 = no surface) never count, whatever ``valid`` says.
    A non-finite prediction (inf, NaN) at a valid pixel counts as an infinite error: it moves the
    median but does not poison it.
    Returns:
        The median relative error; NaN when no pixel is valid.
    """
    pred = np.asarray(pred_depth, np.float64)
    true = np.asarray(true_depth, np.float64)
    _same_shape(pred, true, "relative_depth_error")
    mask = np.isfinite(true) & (true > 0)
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != true.shape:
            raise InputError(f"relative_depth_error: valid {valid.shape} and depth {true.shape} differ", field="valid")
        mask &= valid
    if not mask.any():
        return float("nan")
    p, t = pred[mask], true[mask]
    err = np.where(np.isfinite(p), np.abs(p - t) / t, np.inf)
    return float(np.median(err))


def label_accuracy(pred: np.ndarray, true: np.ndarray) -> float:
    """Fraction of entries where ``pred`` equals ``true`` (any matching shape); NaN when empty."""
    pred, true = np.asarray(pred), np.asarray(true)
    _same_shape(pred, true, "label_accuracy")
    return float("nan") if pred.size == 0 else float(np.mean(pred == true))


def _points3(x: np.ndarray, field: str) -> np.ndarray:
    """``x`` as float64 [n, 3]; InputError otherwise."""
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise InputError(f"expected [n, 3] points, got {x.shape}", field=field)
    return x


def boxes_lo_hi(boxes) -> tuple[np.ndarray, np.ndarray]:
    """(lo [m, 3], hi [m, 3]) float64 corners of a sequence of objects with ``.lo`` / ``.hi``
    (e.g. scenelabel.data.synthetic.Box)."""
    boxes = list(boxes)
    lo = np.array([b.lo for b in boxes], np.float64).reshape(-1, 3)
    hi = np.array([b.hi for b in boxes], np.float64).reshape(-1, 3)
    return lo, hi


def box_surface_distance(
    points: np.ndarray, lo: np.ndarray, hi: np.ndarray, chunk_pairs: int = BOX_DISTANCE_CHUNK_PAIRS
) -> np.ndarray:
    """Exact unsigned Euclidean distance from each point to the nearest box surface (float64).

    For one box: outside, the distance to the box; inside (or on it), the distance to its
    nearest face. The result is the minimum over all boxes, so a face buried inside another box
    (e.g. a table leg's bottom on the floor) still counts as surface.

    Args:
        points: [n, 3].
        lo, hi: [m, 3] box corners, lo <= hi (flat boxes allowed).
        chunk_pairs: point-box pairs processed at once (memory bound; the result does not
            depend on it).
    Returns:
        [n] float64; inf for every point when m = 0.
    """
    points = _points3(points, "points")
    lo, hi = _points3(lo, "lo"), _points3(hi, "hi")
    if lo.shape != hi.shape:
        raise InputError(f"lo {lo.shape} and hi {hi.shape} differ", field="hi")
    if not np.all(lo <= hi):
        raise InputError("every box needs lo <= hi", field="hi")
    if chunk_pairs < 1:
        raise InputError(f"chunk_pairs must be >= 1, got {chunk_pairs}", field="chunk_pairs")
    n, m = len(points), len(lo)
    out = np.full(n, np.inf)
    if m == 0:
        return out
    chunk = max(1, int(chunk_pairs) // m)
    for start in range(0, n, chunk):
        p = points[start : start + chunk, None, :]  # [c, 1, 3]
        # q > 0: how far outside the slab on that axis; q <= 0: -(distance to the nearer face)
        q = np.subtract(lo[None], p)  # [c, m, 3]
        np.maximum(q, p - hi[None], out=q)
        inside = q.max(axis=2)  # [c, m]: <= 0 iff the point is in (or on) the box
        np.maximum(q, 0.0, out=q)
        np.square(q, out=q)
        d = np.sqrt(q.sum(axis=2))  # distance to the box from outside; 0 inside
        d = np.where(inside <= 0, -inside, d)
        out[start : start + chunk] = d.min(axis=1)
    return out


def _unit_rays(origins: np.ndarray, directions: np.ndarray, depth: np.ndarray):
    """Flattened float64 origins [n, 3], unit directions [n, 3], depth [n] and hit mask [n].

    ``directions`` [..., 3]; ``origins`` [3] or the same shape; ``depth`` [...]. A ray hits when
    its depth is finite and positive.
    """
    d = np.asarray(directions, np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise InputError(f"directions must be [..., 3], got {d.shape}", field="directions")
    o = np.asarray(origins, np.float64)
    if o.shape != d.shape and o.shape != (3,):
        raise InputError(f"origins {o.shape} must be [3] or match directions {d.shape}", field="origins")
    depth = np.asarray(depth, np.float64)
    if depth.shape != d.shape[:-1]:
        raise InputError(f"depth {depth.shape} must be directions' shape without the last axis {d.shape[:-1]}", field="depth")
    d = d.reshape(-1, 3)
    o = np.broadcast_to(o, d.shape if o.shape == (3,) else o.shape).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise InputError("ray directions must be finite and non-zero", field="directions")
    depth = depth.ravel()
    with np.errstate(invalid="ignore"):
        hit = np.isfinite(depth) & (depth > 0)
    return o, d / norm, depth, hit


def surface_points_from_depth(origins: np.ndarray, directions: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Surface points o + depth * d (unit d) of the rays that hit (depth finite and > 0).

    E.g. the exact depth maps of all views back-projected: the observed true surface, the
    recall set of :func:`surface_fscore` (surfaces no camera sees do not count).

    Args:
        origins: [n, 3] (or [3], one camera centre for all rays).
        directions: [n, 3] any length (normalised here); any [..., 3] works, rays flattened.
        depth: [n] distance along the unit direction; 0 or non-finite = no hit (skipped).
    Returns:
        [k, 3] float64, k = number of hits, in ray order.
    """
    o, d, depth, hit = _unit_rays(origins, directions, depth)
    return o[hit] + depth[hit, None] * d[hit]


def probe_points(
    origins: np.ndarray,
    directions: np.ndarray,
    true_depth: np.ndarray,
    behind: float = SURFACE_PROBE_BEHIND,
    free_margin: float = FREE_PROBE_MARGIN,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Occupied and free probe points along rays with exact depth, to score occupancy.

    Everything between a camera and its first hit is free space by construction (the ray
    crosses no surface before it), so free points are exact, with no tolerance; this assumes the
    ray origins (camera centres) lie in free space, as in the synthetic scenes. Surface points lie
    ``behind`` past the first hit along the ray: inside the hit box when the box is thicker than
    that along the ray (near an edge, or for thin boxes at grazing angles, one may exit it).

    Args:
        origins: [n, 3] (or [3], one camera centre for all rays).
        directions: [n, 3] any length (normalised here); any [..., 3] works, rays flattened.
        true_depth: [n] distance along the unit direction; 0 or non-finite = no hit (skipped).
        behind: metres past the surface of the surface points (>= 0).
        free_margin: free points keep this many metres before the surface (>= 0); rays with
            depth <= free_margin give no free point.
        rng: numpy Generator for the free points' positions (default: seeded 0).
    Returns:
        (surface_points [k, 3] = o + (depth + behind) d, one per hit ray;
         free_points [k', 3] = o + s d with s uniform in [0, depth - free_margin], one per ray
         with depth > free_margin;
         ray_index [k] int64: the (flattened) ray of each surface point).
    """
    if not (np.isfinite(behind) and behind >= 0):
        raise InputError(f"behind must be finite and >= 0, got {behind}", field="behind")
    if not (np.isfinite(free_margin) and free_margin >= 0):
        raise InputError(f"free_margin must be finite and >= 0, got {free_margin}", field="free_margin")
    rng = np.random.default_rng(0) if rng is None else rng
    o, d, depth, hit = _unit_rays(origins, directions, true_depth)
    ray_index = np.flatnonzero(hit)
    surface = o[ray_index] + (depth[ray_index] + behind)[:, None] * d[ray_index]
    free_rays = np.flatnonzero(hit & (depth > free_margin))
    s = rng.uniform(0.0, 1.0, len(free_rays)) * (depth[free_rays] - free_margin)
    free = o[free_rays] + s[:, None] * d[free_rays]
    return surface, free, ray_index.astype(np.int64)


def surface_fscore(
    pred_points: np.ndarray,
    true_points: np.ndarray,
    threshold: float = FSCORE_THRESHOLD,
    lo: np.ndarray | None = None,
    hi: np.ndarray | None = None,
) -> dict[str, float]:
    """Surface precision, recall and F-score at a distance threshold (Tanks and Temples,
    Knapitsch et al. 2017).

    recall: fraction of true points within ``threshold`` of the nearest predicted point.
    precision: fraction of predicted points within ``threshold`` of the true surface: the exact
    distance to the boxes' surfaces (:func:`box_surface_distance`) when ``lo``/``hi`` are given,
    else the distance to the nearest true point. fscore = 2PR / (P + R), 0 when both are 0.
    No predicted point at all scores precision = recall = fscore = 0.

    Args:
        pred_points: [p, 3] predicted surface points (p may be 0).
        true_points: [t, 3] true surface points, t >= 1 (e.g. :func:`surface_points_from_depth`).
        threshold: metres (inclusive).
        lo, hi: [m, 3] box corners of the exact scene, both or neither.
    Returns:
        {"precision", "recall", "fscore"}.
    """
    from scipy.spatial import cKDTree

    pred = _points3(pred_points, "pred_points")
    true = _points3(true_points, "true_points")
    if len(true) == 0:
        raise InputError("surface_fscore needs at least one true point", field="true_points")
    if (lo is None) != (hi is None):
        raise InputError("give both lo and hi, or neither", field="lo" if lo is None else "hi")
    if len(pred) == 0:
        return {"precision": 0.0, "recall": 0.0, "fscore": 0.0}
    recall = float(np.mean(cKDTree(pred).query(true)[0] <= threshold))
    if lo is not None:
        dist = box_surface_distance(pred, lo, hi)
    else:
        dist = cKDTree(true).query(pred)[0]
    precision = float(np.mean(dist <= threshold))
    total = precision + recall
    fscore = 0.0 if total == 0 else 2 * precision * recall / total
    return {"precision": precision, "recall": recall, "fscore": fscore}
