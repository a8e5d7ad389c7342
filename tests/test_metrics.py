"""Metrics against hand-computed values and naive loops."""

import math

import numpy as np

from scenelabel.metrics import confusion_matrix, depth_error, miou, psnr, ssim


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
