"""Losses: cross-entropy on composited probabilities, ignore handling, gradients."""

import math

import torch

from scenelabel.losses import class_balance_weights, photometric_mse, semantic_cross_entropy


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
