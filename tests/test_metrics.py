"""Metrics against hand-computed values and naive loops."""

import math

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from scenelabel.errors import InputError
from scenelabel.metrics import confusion_matrix, depth_error, miou, psnr, ssim, boundary_f1, label_boundaries


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
