"""Losses: cross-entropy on composited probabilities, ignore handling, gradients."""

import math

import numpy as np
import pytest
import torch

from scenelabel.train.losses import (
    DEPTH_HUBER,
    class_balance_weights,
    depth_loss,
    free_space_loss,
    mean_colour_mse,
    photometric_mse,
    semantic_cross_entropy,
    semantic_focal_loss,
    solid_interior_loss,
    total_variation,
    total_variation_grad,
)


def test_cross_entropy_matches_hand_value_and_skips_ignored():
    log_probs = torch.log(torch.tensor([[0.7, 0.2, 0.1], [0.1, 0.1, 0.8], [0.3, 0.3, 0.4]]))
    target = torch.tensor([0, 2, -1])
    loss = semantic_cross_entropy(log_probs, target)
    assert math.isclose(float(loss), -(math.log(0.7) + math.log(0.8)) / 2, rel_tol=1e-6)


def test_no_labelled_pixel_gives_zero_with_gradient():
    log_probs = torch.log_softmax(torch.randn(4, 3, requires_grad=True), -1)
    loss = semantic_cross_entropy(log_probs, torch.full((4,), -1))
    loss.backward()
    assert float(loss.detach()) == 0.0


def test_mse():
    assert float(photometric_mse(torch.zeros(2, 3), torch.ones(2, 3))) == 1.0


def test_weighted_mse_matches_a_float64_loop_and_unit_weights_the_plain_mean():
    g = torch.Generator().manual_seed(0)
    rgb, target, weights = torch.rand(6, 3, generator=g), torch.rand(6, 3, generator=g), 3 * torch.rand(6, generator=g)
    ref = 0.0
    for i in range(6):
        for c in range(3):
            ref += float(weights[i]) * (float(rgb[i, c]) - float(target[i, c])) ** 2
    assert float(photometric_mse(rgb, target, weights)) == pytest.approx(ref / 18, rel=1e-6)
    assert float(photometric_mse(rgb, target, torch.ones(6))) == pytest.approx(float(photometric_mse(rgb, target)), rel=1e-6)


def test_class_balance_weights_median_frequency():
    channels = torch.tensor([0] * 6 + [1] * 3 + [2] * 1 + [-1] * 5)
    w = class_balance_weights(channels, 4)
    # frequencies 0.6, 0.3, 0.1, 0 -> median of present 0.3 -> weights 0.5, 1, 3, 0
    torch.testing.assert_close(w, torch.tensor([0.5, 1.0, 3.0, 0.0]))


def test_weighted_cross_entropy_equals_plain_with_unit_weights():
    log_probs = torch.log_softmax(torch.randn(10, 3), -1)
    target = torch.tensor([0, 1, 2, -1, 0, 1, 2, 2, -1, 0])
    torch.testing.assert_close(
        semantic_cross_entropy(log_probs, target, torch.ones(3)), semantic_cross_entropy(log_probs, target)
    )


def test_focal_with_gamma_zero_equals_cross_entropy():
    torch.manual_seed(0)
    log_p = torch.log_softmax(torch.randn(50, 6, dtype=torch.float64), -1)
    targets = torch.randint(-1, 6, (50,))
    weights = torch.rand(6, dtype=torch.float64)
    for w in (None, weights):
        torch.testing.assert_close(semantic_focal_loss(log_p, targets, 0.0, w), semantic_cross_entropy(log_p, targets, w))


def test_ray_weighted_losses_match_a_float64_loop():
    """``ray_weights`` (and ``class_weights`` with them): Σ w loss / Σ w over the labelled rays,
    w = w_class x w_ray, against a naive loop; weights 1 give the plain mean."""
    torch.manual_seed(1)
    log_p = torch.log_softmax(torch.randn(40, 5, dtype=torch.float64), -1)
    targets = torch.randint(-1, 5, (40,))
    ray_w, class_w = torch.rand(40, dtype=torch.float64) * 3, torch.rand(5, dtype=torch.float64)
    for gamma in (0.0, 2.0):
        for cw in (None, class_w):
            num = den = 0.0
            for i in range(40):
                t = int(targets[i])
                if t < 0:
                    continue
                p = math.exp(float(log_p[i, t]))
                w = float(ray_w[i]) * (1.0 if cw is None else float(cw[t]))
                num += w * -((1.0 - p) ** gamma) * math.log(p)
                den += w
            got = semantic_focal_loss(log_p, targets, gamma, cw, ray_w)
            assert float(got) == pytest.approx(num / den, rel=1e-12)
            if gamma == 0.0:
                assert float(semantic_cross_entropy(log_p, targets, cw, ray_w)) == pytest.approx(num / den, rel=1e-12)
    ones = torch.ones(40, dtype=torch.float64)
    torch.testing.assert_close(semantic_cross_entropy(log_p, targets, None, ones), semantic_cross_entropy(log_p, targets))
    # all weight on unlabelled rays: finite, 0
    unlabelled_only = (targets < 0).double()
    assert float(semantic_cross_entropy(log_p, targets, None, unlabelled_only)) == 0.0


def test_focal_hand_value_and_down_weighting():
    # P_t = 0.9 and 0.2, γ = 2: mean of -(0.1)^2 log 0.9 and -(0.8)^2 log 0.2
    log_p = torch.log(torch.tensor([[0.9, 0.1], [0.8, 0.2]], dtype=torch.float64))
    targets = torch.tensor([0, 1])
    expected = (-(0.1**2) * math.log(0.9) - (0.8**2) * math.log(0.2)) / 2
    assert float(semantic_focal_loss(log_p, targets, 2.0)) == pytest.approx(expected, rel=1e-12)
    # confident pixels count less under focal than under CE
    confident = torch.log(torch.tensor([[0.99, 0.01]], dtype=torch.float64))
    assert float(semantic_focal_loss(confident, torch.tensor([0]), 2.0)) < 1e-3 * float(
        semantic_cross_entropy(confident, torch.tensor([0]))
    )


def test_focal_finite_at_extremes():
    log_p = torch.tensor([[0.0, -1e30], [-1e30, 0.0], [-800.0, -1e-300]], dtype=torch.float64, requires_grad=True)
    loss = semantic_focal_loss(log_p, torch.tensor([0, 0, 1]), 2.0)
    loss.backward()
    assert torch.isfinite(loss) and torch.all(torch.isfinite(log_p.grad))
    assert float(semantic_focal_loss(log_p.detach()[:1], torch.tensor([0]), 2.0)) == 0.0  # P_t = 1: no loss
    with pytest.raises(ValueError):
        semantic_focal_loss(log_p, torch.tensor([0, 0, 1]), -1.0)


def naive_total_variation(grid: np.ndarray) -> float:
    """float64 loop: mean over vertices with three forward neighbours of Σ_axes Σ_c (next - v)^2."""
    X, Y, Z, C = grid.shape
    total, count = 0.0, 0
    for i in range(X - 1):
        for j in range(Y - 1):
            for k in range(Z - 1):
                v = grid[i, j, k].astype(np.float64)
                total += sum(float(((grid[n].astype(np.float64) - v) ** 2).sum()) for n in ((i + 1, j, k), (i, j + 1, k), (i, j, k + 1)))
                count += 1
    return total / count


@pytest.mark.parametrize("shape", [(2, 2, 2, 1), (4, 3, 5, 2)])
def test_total_variation_matches_a_float64_loop(shape):
    grid = torch.randn(*shape, generator=torch.Generator().manual_seed(0))
    assert math.isclose(float(total_variation(grid)), naive_total_variation(grid.numpy()), rel_tol=1e-5)


def test_total_variation_is_zero_on_a_constant_grid_and_finite_at_extremes():
    assert float(total_variation(torch.full((3, 3, 3, 2), 7.0))) == 0.0
    big = torch.zeros(2, 2, 2, 1)
    big[1] = 1e18  # (1e18)^2 = 1e36: within float32
    assert math.isfinite(float(total_variation(big)))
    with pytest.raises(ValueError, match="X, Y, Z, C"):
        total_variation(torch.zeros(1, 3, 3, 1))


@pytest.mark.parametrize("shape", [(2, 2, 2, 1), (5, 4, 3, 2)])
def test_total_variation_grad_is_autograds(shape):
    grid = torch.randn(*shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64, requires_grad=True)
    total_variation(grid).backward()
    value, grad = total_variation_grad(grid.detach())
    torch.testing.assert_close(value, total_variation(grid.detach()))
    torch.testing.assert_close(grad, grid.grad)


def test_solid_interior_loss_matches_a_float64_loop_and_stops_at_its_target():
    from scenelabel.train.losses import SOLID_SIGMA_EPS, SOLID_TAU

    step = 0.02
    sigmas = torch.tensor([0.0, 1e-3, 1.0, SOLID_TAU / step, 1e4], dtype=torch.float64, requires_grad=True)
    loss = solid_interior_loss(sigmas, step)
    want = sum(max(0.0, math.log(SOLID_TAU / step) - math.log(s + SOLID_SIGMA_EPS)) for s in sigmas.tolist()) / 5
    assert abs(loss.detach().item() - want) < 1e-12
    loss.backward()
    # below the target the gradient on log σ is -1 / n; at and above it nothing moves
    grad_log = (sigmas.grad * (sigmas.detach() + SOLID_SIGMA_EPS)).tolist()
    np.testing.assert_allclose(grad_log[:3], [-0.2] * 3, rtol=1e-9)
    assert grad_log[3] == 0.0 or abs(grad_log[3]) < 1e-9
    assert grad_log[4] == 0.0
    empty = solid_interior_loss(torch.zeros(0), step)
    assert float(empty) == 0.0


def test_solid_interior_loss_finite_at_extremes():
    for dtype in (torch.float32, torch.float64):
        sigmas = torch.tensor([0.0, 1e-38, 3e38], dtype=dtype, requires_grad=True)
        loss = solid_interior_loss(sigmas, 1e-6)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(sigmas.grad).all()


def _depth_loss_loop(termination, target):
    """Huber on the relative error, the rays with a measurement only (float64 loop)."""
    terms = []
    for t, z in zip(termination, target):
        if not (math.isfinite(z) and z > 0):
            continue
        e = abs((t - z) / z)
        terms.append(0.5 * e * e / DEPTH_HUBER if e < DEPTH_HUBER else e - 0.5 * DEPTH_HUBER)
    return sum(terms) / len(terms) if terms else 0.0


def test_depth_loss_matches_a_float64_loop_and_skips_holes():
    rng = np.random.default_rng(0)
    target = rng.uniform(0.1, 10.0, 64)
    target[::7] = np.nan  # holes
    target[3] = 0.0  # a sensor's "no return"
    termination = target * rng.uniform(0.9, 1.1, 64)
    termination = np.where(np.isfinite(termination), termination, 1.0)
    got = depth_loss(torch.tensor(termination), torch.tensor(target))
    assert math.isclose(float(got), _depth_loss_loop(termination, target), rel_tol=1e-9)


def test_depth_loss_is_robust_to_an_outlier_and_zero_without_measurements():
    target = torch.ones(10)
    near = torch.full((10,), 1.01)
    wild = near.clone()
    wild[0] = 100.0  # a flying pixel: pulls linearly, not quadratically
    outlier = (99.0 - 0.5 * DEPTH_HUBER) / 10  # linear in the error, not quadratic
    near_one = 0.5 * 0.01**2 / DEPTH_HUBER / 10
    assert math.isclose(float(depth_loss(wild, target)) - float(depth_loss(near, target)), outlier - near_one, rel_tol=1e-5)
    pred = torch.ones(4, requires_grad=True)
    loss = depth_loss(pred, torch.full((4,), float("nan")))
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.all(pred.grad == 0)


def test_depth_loss_finite_at_extreme_distances():
    for scale in (1e-6, 1.0, 1e6):
        target = torch.full((8,), scale, dtype=torch.float32)
        pred = (target * 1.5).requires_grad_()
        loss = depth_loss(pred, target)
        loss.backward()
        assert math.isfinite(float(loss.detach())) and torch.all(torch.isfinite(pred.grad))
        assert math.isclose(float(loss.detach()), 0.5 - 0.5 * DEPTH_HUBER, rel_tol=1e-5)  # scale-free: a relative error


def test_free_space_loss_means_front_weight_over_measured_rays():
    front = torch.tensor([0.5, 0.2, 0.9, 0.0])
    target = torch.tensor([1.0, float("nan"), 2.0, 3.0])
    assert math.isclose(float(free_space_loss(front, target)), (0.5 + 0.9 + 0.0) / 3, rel_tol=1e-6)
    assert float(free_space_loss(front, torch.full((4,), float("nan")))) == 0.0


def test_mean_colour_mse_is_the_variance_of_the_composited_targets():
    """Against a float64 loop: the MSE of the mean colour over the targets composited on the background;
    with a random background, on its mean (grey 0.5) plus 1/12 (1 - alpha)^2 for the uniform colour's variance."""
    gen = torch.Generator().manual_seed(0)
    rgb = torch.rand(50, 3, generator=gen, dtype=torch.float64)
    alpha = torch.rand(50, generator=gen, dtype=torch.float64)
    white = torch.ones(3, dtype=torch.float64)

    def loop(alpha_, background, random_bg):
        rows = []
        for i in range(50):
            a = 1.0 if alpha_ is None else float(alpha_[i])
            back = [0.5] * 3 if random_bg else [float(b) for b in background]
            rows.append([float(rgb[i, c]) * a + back[c] * (1 - a) for c in range(3)])
        means = [sum(r[c] for r in rows) / 50 for c in range(3)]
        mse = sum((r[c] - means[c]) ** 2 for r in rows for c in range(3)) / 150
        if random_bg and alpha_ is not None:
            mse += sum((1 - float(a)) ** 2 for a in alpha_) / 50 / 12
        return mse

    for alpha_, background, random_bg in [(None, white, False), (alpha, white, False), (alpha, None, True), (None, None, True)]:
        got = mean_colour_mse(rgb, alpha_, background, random_bg)
        assert got == pytest.approx(loop(alpha_, background, random_bg), rel=1e-12)
