"""Metrics against hand-computed values and naive loops."""

import math

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from scenelabel.errors import InputError
from scenelabel.metrics import (
    COMMON_CLASS_SHARE,
    boundary_f1,
    confusion_matrix,
    depth_error,
    label_boundaries,
    miou,
    no_hit_as_free,
    psnr,
    ssim,
)


def naive_confusion(pred, target, class_ids, ignore):
    C = len(class_ids)
    conf = np.zeros((C, C + 1), np.int64)
    for p, t in zip(pred.ravel().tolist(), target.ravel().tolist()):
        if t == ignore or t not in class_ids:
            continue
        col = class_ids.index(p) if p in class_ids else C
        conf[class_ids.index(t), col] += 1
    return conf


def test_confusion_matches_naive_loop():
    rng = np.random.default_rng(0)
    ids = [1, 3, 7]
    target = rng.choice([1, 3, 7, 255, 5], size=(20, 30))
    pred = rng.choice([1, 3, 7, -1, -2, 9], size=(20, 30))
    np.testing.assert_array_equal(confusion_matrix(pred, target, np.array(ids), 255), naive_confusion(pred, target, ids, 255))


def test_miou_hand_values():
    target = np.array([1, 1, 3, 3, 255])
    pred = np.array([1, 3, 3, -1, 1])
    conf = confusion_matrix(pred, target, np.array([1, 3, 7]), 255)
    mean, per = miou(conf)
    # class 1: tp 1, fn 1, fp 0 -> 1/2; class 3: tp 1, fn 1 (one FREE), fp 1 -> 1/3; class 7 absent -> NaN
    np.testing.assert_allclose(per[:2], [0.5, 1 / 3])
    assert math.isnan(per[2])
    assert math.isclose(mean, (0.5 + 1 / 3) / 2)


def test_psnr_and_ssim():
    a = np.zeros((8, 8, 3))
    b = np.full((8, 8, 3), 0.1)
    assert math.isclose(psnr(a, b), 20.0, rel_tol=1e-9)  # mse 0.01
    assert psnr(a, a) == float("inf")
    img = np.random.default_rng(1).uniform(size=(16, 16, 3))
    assert math.isclose(ssim(img, img), 1.0, rel_tol=1e-9)
    assert ssim(img, 1 - img) < 0.5
    assert np.isfinite(ssim(img[:5, :5], img[:5, :5]))  # smaller than the default 7x7 window


def test_depth_error():
    err = depth_error(np.array([1.1, 2.0, 5.0]), np.array([1.0, 2.0, 0.0]))
    assert math.isclose(err["abs_rel"], 0.05)
    assert math.isclose(err["mae"], 0.05)
    assert math.isclose(err["rmse"], math.sqrt(0.01 / 2))


def test_psnr_known_mse_other_range():
    a = np.zeros((4, 5, 3))
    b = a.copy()
    b[0, 0, 0] = 60.0  # mse = 3600 / 60
    assert math.isclose(psnr(b, a, max_value=255.0), 10 * math.log10(255.0**2 / 60.0), rel_tol=1e-12)
    with pytest.raises(InputError):
        psnr(a, a[:3])


def test_ssim_matches_skimage_grey_and_tiny_images():
    rng = np.random.default_rng(2)
    a, b = rng.uniform(size=(2, 12, 10, 3))
    ref = structural_similarity(a, b, channel_axis=-1, data_range=1.0)
    assert math.isclose(ssim(a, b), ref, rel_tol=1e-12)
    grey = ssim(a[..., 0], b[..., 0])
    assert math.isclose(grey, structural_similarity(a[..., 0], b[..., 0], data_range=1.0), rel_tol=1e-12)
    assert np.isfinite(ssim(a[:4, :6], b[:4, :6]))  # window 3
    with pytest.raises(InputError):
        ssim(a[:2, :2], b[:2, :2])


def test_confusion_hand_values_and_ignore():
    target = np.array([[1, 1, 7], [7, 255, 255]])
    pred = np.array([[1, 7, 7], [-1, 1, 255]])  # predictions at ignored pixels never count
    conf = confusion_matrix(pred, target, np.array([1, 7]), ignore_index=255)
    np.testing.assert_array_equal(conf, [[1, 1, 0], [0, 1, 1]])
    assert conf.sum() == 4
    with pytest.raises(InputError):
        confusion_matrix(pred, target[:1], np.array([1, 7]), 255)
    with pytest.raises(InputError):
        confusion_matrix(pred, target, np.array([7, 1]), 255)


def test_miou_matches_naive_loop():
    rng = np.random.default_rng(3)
    ids = [2, 4, 9, 11]
    target = rng.choice(ids + [255], size=(30, 40))
    pred = rng.choice(ids + [-1], size=(30, 40))
    mean, per = miou(confusion_matrix(pred, target, np.array(ids), 255))
    expected = []
    for c in ids:
        valid = target != 255
        inter = np.sum((pred == c) & (target == c) & valid)
        union = np.sum(((pred == c) | (target == c)) & valid)
        expected.append(inter / union)
    np.testing.assert_allclose(per, expected, rtol=1e-12)
    assert math.isclose(mean, float(np.mean(expected)), rel_tol=1e-12)


def test_miou_over_the_common_classes_leaves_out_those_below_the_share():
    """min_share: a class holding fewer of the target's pixels (a lamp's 2 of 1000) keeps its IoU in
    the per-class array but not in the mean; the share's edge is inclusive."""
    target = np.repeat([1, 3, 5], [898, 100, 2])
    pred = np.where(target == 5, 1, target)  # the lamp missed: IoU 0
    conf = confusion_matrix(pred, target, np.array([1, 3, 5]))
    everything, per = miou(conf)
    common, per_common = miou(conf, min_share=0.01)
    np.testing.assert_array_equal(per, per_common)
    assert per[2] == 0.0 and math.isclose(everything, (898 / 900 + 1.0 + 0.0) / 3)
    assert math.isclose(common, (898 / 900 + 1.0) / 2)
    assert miou(conf, min_share=0.1)[0] == common  # class 3 holds exactly 10 %: in
    assert miou(conf, min_share=COMMON_CLASS_SHARE)[0] == everything  # 0.2 % >= 0.1 %
    assert math.isnan(miou(conf, min_share=1.0)[0])


def test_a_ray_without_a_hit_predicts_free():
    """FREE and UNKNOWN (outside the bounds) both read as FREE; class ids stay: a true FREE pixel is
    right where nothing was hit, a true class pixel wrong either way."""
    pred = np.array([[3, -1], [-2, 0]])
    np.testing.assert_array_equal(no_hit_as_free(pred), [[3, -1], [-1, 0]])
    conf = confusion_matrix(no_hit_as_free(pred), np.array([[3, -1], [-1, 3]]), np.array([-1, 3]))
    np.testing.assert_array_equal(conf, [[2, 0, 0], [0, 1, 1]])  # row 3: one right, one predicted 0 (outside)


def test_miou_nothing_present_is_nan():
    mean, per = miou(np.zeros((3, 4), np.int64))
    assert math.isnan(mean) and np.all(np.isnan(per))


def test_depth_error_mask_and_naive_loop():
    rng = np.random.default_rng(4)
    target = rng.uniform(0.5, 4.0, (6, 7))
    target[0, :3] = 0.0  # no surface
    target[1, 0] = np.inf
    pred = target + rng.normal(0, 0.1, target.shape)
    mask = rng.uniform(size=target.shape) > 0.3
    err = depth_error(pred, target, mask)
    diffs, rels = [], []
    for i in range(6):
        for j in range(7):
            if mask[i, j] and np.isfinite(target[i, j]) and target[i, j] > 0:
                diffs.append(pred[i, j] - target[i, j])
                rels.append(abs(diffs[-1]) / target[i, j])
    assert math.isclose(err["mae"], float(np.mean(np.abs(diffs))), rel_tol=1e-12)
    assert math.isclose(err["rmse"], float(np.sqrt(np.mean(np.square(diffs)))), rel_tol=1e-12)
    assert math.isclose(err["abs_rel"], float(np.mean(rels)), rel_tol=1e-12)
    none = depth_error(pred, target, np.zeros_like(mask))
    assert all(math.isnan(v) for v in none.values())


def _naive_boundaries(lab):
    h, w = lab.shape
    out = np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            if (i + 1 < h and lab[i + 1, j] != lab[i, j]) or (j + 1 < w and lab[i, j + 1] != lab[i, j]):
                out[i, j] = True
    return out


def test_label_boundaries_match_a_loop():
    rng = np.random.default_rng(0)
    lab = rng.integers(0, 3, (9, 11))
    np.testing.assert_array_equal(label_boundaries(lab), _naive_boundaries(lab))


def test_boundary_f1_values():
    gt = np.zeros((20, 20), int)
    gt[:, 10:] = 1
    assert boundary_f1(gt, gt) == 1.0
    shifted = np.zeros_like(gt)
    shifted[:, 12:] = 1  # boundary 2 px off: within a tolerance of 2, beyond a tolerance of 1
    assert boundary_f1(shifted, gt, tolerance=2) == 1.0
    assert boundary_f1(shifted, gt, tolerance=1) == 0.0
    assert boundary_f1(np.zeros_like(gt), gt) == 0.0
    assert boundary_f1(np.zeros_like(gt), np.zeros_like(gt)) == 1.0
    noisy = gt.copy()
    noisy[5, 3] = 1  # a speck: extra predicted boundary far from the true one lowers precision only
    f = boundary_f1(noisy, gt, tolerance=1)
    assert 0.8 < f < 1.0


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def test_pose_errors_are_zero_up_to_a_similarity_and_see_a_known_perturbation():
    from scenelabel.metrics import pose_centre_errors, pose_rotation_errors_deg

    rng = np.random.default_rng(0)
    n = 6
    truth = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        truth[i, :3, :3] = _rot(0, rng.uniform(-1, 1)) @ _rot(1, rng.uniform(-1, 1)) @ _rot(2, rng.uniform(-1, 1))
        truth[i, :3, 3] = rng.normal(size=3)
    # the same rig in another world frame: rotated, scaled by 0.3 and shifted
    g, scale, shift = _rot(2, 0.7) @ _rot(0, -0.4), 0.3, np.array([5.0, -2.0, 1.0])
    est = truth.copy()
    est[:, :3, :3] = g.T @ truth[:, :3, :3]
    est[:, :3, 3] = scale * (truth[:, :3, 3] @ g) + shift
    np.testing.assert_allclose(pose_rotation_errors_deg(truth, est), 0.0, atol=1e-5)
    np.testing.assert_allclose(pose_centre_errors(truth, est), 0.0, atol=1e-9)
    # camera 2 turned by 0.5 degrees about its own optical axis: the fit spreads a little, camera 2 dominates
    est[2, :3, :3] = est[2, :3, :3] @ _rot(2, np.radians(0.5))
    errors = pose_rotation_errors_deg(truth, est)
    assert errors.argmax() == 2 and 0.3 < errors[2] <= 0.5 + 1e-9


# ------------------------------------------------------------------ 3D metrics against exact geometry

from fractions import Fraction  # noqa: E402

from scenelabel.metrics import (
    box_surface_distance,
    boxes_lo_hi,
    label_accuracy,
    probe_points,
    relative_depth_error,
    surface_fscore,
    surface_points_from_depth,
)


def _naive_box_surface_distance(points, lo, hi):
    """Per point, per box: outside -> distance to the clamped point; inside -> nearest face."""
    out = []
    for p in np.asarray(points, np.float64).tolist():
        best = math.inf
        for l, h in zip(np.asarray(lo).tolist(), np.asarray(hi).tolist()):
            if all(l[a] <= p[a] <= h[a] for a in range(3)):
                d = min(min(p[a] - l[a], h[a] - p[a]) for a in range(3))
            else:
                clamped = [min(max(p[a], l[a]), h[a]) for a in range(3)]
                d = math.sqrt(sum((p[a] - clamped[a]) ** 2 for a in range(3)))
            best = min(best, d)
        out.append(best)
    return np.array(out)


def _random_boxes_and_points(rng, m=5, n=400):
    lo = rng.uniform(-2, 1, (m, 3))
    hi = lo + rng.uniform(0.1, 1.5, (m, 3))
    hi[0, 2] = lo[0, 2]  # one flat box
    pts = [rng.uniform(-3, 3, (n // 4, 3))]  # mostly outside
    b = rng.integers(0, m, n // 4)
    pts.append(rng.uniform(lo[b], hi[b]))  # inside
    b = rng.integers(0, m, n // 4)
    on_face = rng.uniform(lo[b], hi[b])
    axis = rng.integers(0, 3, n // 4)
    on_face[np.arange(n // 4), axis] = np.where(rng.uniform(size=n // 4) < 0.5, lo[b, axis], hi[b, axis])
    pts.append(on_face)  # on faces
    b = rng.integers(0, m, n // 4)
    corner = np.where(rng.uniform(size=(n // 4, 3)) < 0.5, lo[b], hi[b])
    edge = corner.copy()
    free_axis = rng.integers(0, 3, n // 4)
    edge[np.arange(n // 4), free_axis] = rng.uniform(lo[b, free_axis], hi[b, free_axis])
    pts.append(np.concatenate([corner[: n // 8], edge[n // 8 :]]))  # corners and edges
    return np.concatenate(pts), lo, hi


def test_box_surface_distance_matches_naive_loop():
    rng = np.random.default_rng(10)
    for _ in range(3):
        points, lo, hi = _random_boxes_and_points(rng)
        expected = _naive_box_surface_distance(points, lo, hi)
        got = box_surface_distance(points, lo, hi)
        assert got.dtype == np.float64 and got.shape == (len(points),)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        assert np.all(got[len(points) // 2 :] < 1e-12)  # the face / edge / corner points are on a surface
        # chunking never changes the answer
        for chunk_pairs in (1, 7, len(lo) * 13):
            np.testing.assert_array_equal(box_surface_distance(points, lo, hi, chunk_pairs=chunk_pairs), got)


def test_box_surface_distance_hand_values():
    lo, hi = np.zeros((1, 3)), np.ones((1, 3))
    pts = np.array([[0.5, 0.5, 0.5], [2.0, 0.5, 0.5], [2.0, 2.0, 2.0], [0.1, 0.5, 0.5], [1.0, 1.0, 1.0], [-1, -1, 0.5]])
    np.testing.assert_allclose(
        box_surface_distance(pts, lo, hi), [0.5, 1.0, math.sqrt(3), 0.1, 0.0, math.sqrt(2)], rtol=1e-15, atol=1e-15
    )
    # two boxes: the nearer surface wins, including a face buried in another box
    lo2, hi2 = np.array([[0, 0, 0], [0.8, 0, 0]]), np.array([[1, 1, 1], [3, 1, 1]])
    np.testing.assert_allclose(box_surface_distance([[0.9, 0.5, 0.5], [2.0, 0.5, 0.5]], lo2, hi2), [0.1, 0.5])
    assert box_surface_distance(np.zeros((0, 3)), lo, hi).shape == (0,)
    assert np.all(np.isinf(box_surface_distance(pts, np.zeros((0, 3)), np.zeros((0, 3)))))
    with pytest.raises(InputError):
        box_surface_distance(pts, hi, lo)  # lo > hi
    with pytest.raises(InputError):
        box_surface_distance(pts[:, :2], lo, hi)
    with pytest.raises(InputError):
        box_surface_distance(pts, lo, np.ones((2, 3)))


def test_boxes_lo_hi_reads_box_objects():
    from scenelabel.data.synthetic import TOY_BOXES

    lo, hi = boxes_lo_hi(TOY_BOXES)
    assert lo.shape == hi.shape == (len(TOY_BOXES), 3)
    np.testing.assert_array_equal(lo[0], TOY_BOXES[0].lo)
    np.testing.assert_array_equal(hi[-1], TOY_BOXES[-1].hi)


def _exact_distance(p, lo, hi):
    """Exact (Fraction) distance of one float point to one box's surface, rounded once at the end."""
    p, lo, hi = [Fraction(x) for x in p], [Fraction(x) for x in lo], [Fraction(x) for x in hi]
    if all(lo[a] <= p[a] <= hi[a] for a in range(3)):
        return float(min(min(p[a] - lo[a], hi[a] - p[a]) for a in range(3)))
    sq = sum(max(lo[a] - p[a], p[a] - hi[a], Fraction(0)) ** 2 for a in range(3))
    return math.sqrt(sq)  # Fraction -> float is correctly rounded, then one sqrt rounding


def test_box_surface_distance_extremes_are_finite_and_accurate():
    rng = np.random.default_rng(11)
    for offset, size in ((1e6, 1.0), (1e6, 1e-6), (0.0, 1e-6), (-1e6, 1e-6)):
        lo = np.full((1, 3), offset) + rng.uniform(-1, 1, 3) * size
        hi = lo + size * rng.uniform(0.5, 1.0, 3)
        centre = (lo + hi) / 2
        pts = np.concatenate(
            [centre + rng.uniform(-0.4, 0.4, (20, 3)) * size, centre + rng.uniform(-5, 5, (20, 3)) * size]
        )  # inside and outside, at the box's scale
        got = box_surface_distance(pts, lo, hi)
        assert np.all(np.isfinite(got))
        expected = np.array([_exact_distance(p, lo[0], hi[0]) for p in pts])
        assert np.all(expected > 0)
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=0)


def test_box_surface_distance_memory_is_bounded():
    import tracemalloc

    rng = np.random.default_rng(12)
    points = rng.uniform(-1, 1, (100_000, 3))
    lo = rng.uniform(-1, 0, (60, 3))
    hi = lo + 0.5
    tracemalloc.start()
    try:
        box_surface_distance(points, lo, hi)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 100e6, peak


def test_relative_depth_error_known_answers():
    true = np.linspace(0.5, 5.0, 24).reshape(4, 6)
    assert math.isclose(relative_depth_error(1.1 * true, true), 0.1, rel_tol=1e-12)
    assert relative_depth_error(true, true) == 0.0
    # median, not mean: one huge error does not move it
    pred = 1.2 * true
    pred[0, 0] = 1e9
    assert math.isclose(relative_depth_error(pred, true), 0.2, rel_tol=1e-12)
    # non-finite predictions are infinitely wrong: with 3 of 5 infinite, the median is inf
    t = np.array([1.0, 2.0, 4.0, 1.0, 1.0])
    p = np.array([1.5, 2.0, np.inf, np.nan, -np.inf])
    assert relative_depth_error(p, t) == math.inf
    assert math.isclose(relative_depth_error(p[:3], t[:3]), 0.5)  # errors 0.5, 0, inf -> 0.5
    # invalid pixels (no surface, non-finite truth, masked out) are ignored
    t = np.array([1.0, 2.0, 0.0, np.inf, 3.0, 4.0])
    p = np.array([1.1, 2.2, 7.0, 1.0, 3.3, 100.0])
    mask = np.array([True, True, True, True, True, False])
    assert math.isclose(relative_depth_error(p, t, mask), 0.1, rel_tol=1e-12)
    assert math.isnan(relative_depth_error(p, t, np.zeros(6, bool)))
    assert math.isnan(relative_depth_error(p, np.zeros(6)))
    with pytest.raises(InputError):
        relative_depth_error(p, t[:5])
    with pytest.raises(InputError):
        relative_depth_error(p, t, mask[:5])


def test_label_accuracy():
    assert label_accuracy(np.array([[1, 2], [3, 4]]), np.array([[1, 2], [0, 4]])) == 0.75
    assert math.isnan(label_accuracy(np.zeros(0), np.zeros(0)))
    with pytest.raises(InputError):
        label_accuracy(np.zeros(3), np.zeros(4))


def test_probe_points_surface_free_and_skipped_rays():
    rng = np.random.default_rng(13)
    n = 50
    origins = rng.uniform(-1, 1, (n, 3))
    directions = rng.normal(size=(n, 3)) * rng.uniform(0.1, 10, (n, 1))  # not unit length
    depth = rng.uniform(0.05, 3.0, n)
    depth[:4] = [0.0, np.nan, np.inf, -1.0]  # no hit
    depth[4] = 0.1  # a hit, but no room for a free point (depth <= margin)
    surface, free, ray_index = probe_points(origins, directions, depth, behind=0.02, free_margin=0.1)
    hits = np.arange(4, n)
    np.testing.assert_array_equal(ray_index, hits)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    # surface points: exactly `behind` past the true hit, along the unit ray
    along = np.einsum("ij,ij->i", surface - origins[hits], unit[hits])
    np.testing.assert_allclose(along, depth[hits] + 0.02, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(surface - origins[hits], axis=1), depth[hits] + 0.02, rtol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(surface - (origins[hits] + depth[hits, None] * unit[hits]), axis=1), 0.02, rtol=1e-9
    )
    # free points: on the ray, between the origin and depth - margin
    free_rays = hits[depth[hits] > 0.1]
    assert free.shape == (len(free_rays), 3)
    s = np.einsum("ij,ij->i", free - origins[free_rays], unit[free_rays])
    np.testing.assert_allclose(free, origins[free_rays] + s[:, None] * unit[free_rays], atol=1e-12)
    assert np.all(s >= 0) and np.all(s <= depth[free_rays] - 0.1 + 1e-12)
    # default rng is seeded: reproducible; another generator moves only the free points
    again = probe_points(origins, directions, depth, behind=0.02, free_margin=0.1)
    np.testing.assert_array_equal(again[1], free)
    other = probe_points(origins, directions, depth, behind=0.02, free_margin=0.1, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(other[0], surface)
    assert not np.array_equal(other[1], free)
    # one camera centre for all rays, and bad inputs
    one = probe_points(origins[0], directions, depth)
    np.testing.assert_allclose(one[0], origins[0] + (depth[hits] + 0.02)[:, None] * unit[hits], rtol=1e-12)
    with pytest.raises(InputError):
        probe_points(origins, np.zeros((n, 3)), depth)
    with pytest.raises(InputError):
        probe_points(origins, directions, depth[:-1])


def test_probe_points_are_free_and_occupied_in_an_exact_scene():
    from scenelabel.data.synthetic import Box, cast_rays

    boxes = [Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1), Box((2.0, -1.0, -1.0), (2.5, 2.0, 2.0), 2)]
    rng = np.random.default_rng(14)
    directions = np.column_stack([np.ones(200), rng.uniform(-0.3, 0.3, 200), rng.uniform(-0.3, 0.3, 200)])
    origins = np.tile([-2.0, 0.5, 0.5], (200, 1))
    hits = cast_rays(origins, directions, boxes)
    assert hits.hit.all()
    surface, free, _ = probe_points(origins, directions, hits.depth)
    lo, hi = boxes_lo_hi(boxes)
    inside = np.any(np.all((surface[:, None] >= lo) & (surface[:, None] <= hi), axis=2), axis=1)
    assert inside.mean() > 0.9  # all but grazing hits near edges land inside a box
    free_inside = np.any(np.all((free[:, None] >= lo) & (free[:, None] <= hi), axis=2), axis=1)
    assert not free_inside.any()  # not even on a surface
    assert np.all(box_surface_distance(free, lo, hi) > 0)


def test_surface_points_from_depth():
    origins = np.array([[0.0, 0, 0], [1, 1, 1], [0, 0, 0]])
    directions = np.array([[0.0, 0, 2], [3, 0, 0], [0, 1, 0]])
    pts = surface_points_from_depth(origins, directions, np.array([1.5, 0.0, 2.0]))
    np.testing.assert_allclose(pts, [[0, 0, 1.5], [0, 2.0, 0]])
    # image-shaped input flattens in ray order
    grid = surface_points_from_depth(np.zeros(3), np.ones((2, 2, 3)), np.array([[np.sqrt(3), 0], [0, 2 * np.sqrt(3)]]))
    np.testing.assert_allclose(grid, [[1, 1, 1], [2, 2, 2]])


def _plane(spacing=0.01, size=1.0):
    g = np.arange(0.0, size + spacing / 2, spacing)
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def test_surface_fscore_plane_shifts_and_outliers():
    true = _plane()
    near = surface_fscore(true + [0, 0, 0.03], true)
    assert near == {"precision": 1.0, "recall": 1.0, "fscore": 1.0}
    far = surface_fscore(true + [0, 0, 0.08], true)
    assert far == {"precision": 0.0, "recall": 0.0, "fscore": 0.0}
    # as many far-away predictions as good ones: precision halves, recall stays
    half = surface_fscore(np.concatenate([true, true + [0, 0, 1.0]]), true)
    assert half["precision"] == 0.5 and half["recall"] == 1.0
    assert math.isclose(half["fscore"], 2 * 0.5 * 1.0 / 1.5)
    # predictions covering only the half x < 0.5: precision 1, recall ~ one half
    part = true[true[:, 0] < 0.5 - 1e-9]
    score = surface_fscore(part, true, threshold=0.005)
    p, r = score["precision"], score["recall"]
    assert p == 1.0 and math.isclose(r, len(part) / len(true))
    assert math.isclose(score["fscore"], 2 * p * r / (p + r))
    # the threshold is inclusive and configurable
    assert surface_fscore(true + [0, 0, 0.08], true, threshold=0.1)["fscore"] == 1.0


def test_surface_fscore_empty_and_bad_inputs():
    true = _plane(0.1)
    assert surface_fscore(np.zeros((0, 3)), true) == {"precision": 0.0, "recall": 0.0, "fscore": 0.0}
    with pytest.raises(InputError):
        surface_fscore(true, np.zeros((0, 3)))
    with pytest.raises(InputError):
        surface_fscore(true, true, lo=np.zeros((1, 3)))
    with pytest.raises(InputError):
        surface_fscore(true[:, :2], true)


def _unit_cube_surface(spacing=0.01):
    g = np.arange(0.0, 1.0 + spacing / 2, spacing)
    a, b = [x.ravel() for x in np.meshgrid(g, g, indexing="ij")]
    faces = []
    for axis in range(3):
        for value in (0.0, 1.0):
            f = np.empty((a.size, 3))
            others = [k for k in range(3) if k != axis]
            f[:, axis], f[:, others[0]], f[:, others[1]] = value, a, b
            faces.append(f)
    return np.unique(np.concatenate(faces), axis=0)


def test_surface_fscore_exact_boxes_agree_with_dense_point_set():
    true = _unit_cube_surface(0.01)
    lo, hi = np.zeros((1, 3)), np.ones((1, 3))
    rng = np.random.default_rng(15)
    # predictions off face interiors along the normal, at 0.02 (in) or 0.09 (out), in and outside the cube
    k = 600
    axis = rng.integers(0, 3, k)
    side = rng.integers(0, 2, k).astype(float)
    pred = rng.uniform(0.15, 0.85, (k, 3))
    offset = np.where(rng.uniform(size=k) < 0.6, 0.02, 0.09) * np.where(rng.uniform(size=k) < 0.5, 1, -1)
    pred[np.arange(k), axis] = side + np.where(side == 1, 1, -1) * offset  # + outside, - inside
    exact = surface_fscore(pred, true, lo=lo, hi=hi)
    points = surface_fscore(pred, true)
    assert exact == points
    assert math.isclose(exact["precision"], np.mean(np.abs(offset) == 0.02))
    # the exact distance is a lower bound of the point-set distance, within the sampling spacing
    from scipy.spatial import cKDTree

    d_exact = box_surface_distance(pred, lo, hi)
    d_points = cKDTree(true).query(pred)[0]
    np.testing.assert_allclose(d_exact, np.abs(offset), atol=1e-12)
    assert np.all(d_points >= d_exact - 1e-12) and np.all(d_points <= d_exact + 0.01)


def test_miou_leaves_out_classes_only_predicted():
    """A class no target pixel holds: IoU 0 in the per-class array, pixels counted against the
    class they belong to, out of the mean (Semantic-NeRF's miou_valid_class); spurious_classes names it."""
    from scenelabel.metrics import spurious_classes

    target = np.array([1, 1, 1, 1, 3, 3])
    pred = np.array([1, 1, 1, 7, 3, 3])  # one floor pixel called 7, which the target never shows
    conf = confusion_matrix(pred, target, np.array([1, 3, 7]))
    mean, per = miou(conf)
    np.testing.assert_allclose(per, [3 / 4, 1.0, 0.0])
    assert math.isclose(mean, (3 / 4 + 1.0) / 2)  # not (3/4 + 1 + 0) / 3
    np.testing.assert_array_equal(spurious_classes(conf), [0, 0, 1])
    assert np.all(spurious_classes(confusion_matrix(target, target, np.array([1, 3, 7]))) == 0)
