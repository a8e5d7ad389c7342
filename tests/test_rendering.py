"""Rendering maths against a naive float64 loop, and finite at the extremes."""

import itertools
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from scenelabel.render.volume import (
    class_log_probs_from_sample_weights,
    class_log_probs_from_scores,
    class_log_probs_from_weights,
    class_probs_from_sample_weights,
    class_probs_from_weights,
    composite_rgb,
    depth_at_transmittance,
    depth_from_weights,
    depth_of_max_weight,
    distortion_from_weights,
    weight_before,
    weights_from_density,
)


def naive_render(sigmas, deltas, rgbs, logits, t_mids, near, far):
    """One ray at a time, one sample at a time, float64 Python floats (the reference)."""
    n_rays, n_samples = sigmas.shape
    out_w = np.zeros((n_rays, n_samples))
    out_rgb = np.zeros((n_rays, 3))
    out_depth = np.zeros(n_rays)
    out_probs = np.zeros((n_rays, logits.shape[-1]))
    for r in range(n_rays):
        trans = 1.0
        for s in range(n_samples):
            tau = min(float(sigmas[r, s]), 1e30) * float(deltas[r, s])
            alpha = 1.0 - math.exp(-tau) if tau < 1e4 else 1.0
            out_w[r, s] = trans * alpha
            trans *= math.exp(-tau) if tau < 1e4 else 0.0
        opacity = out_w[r].sum()
        out_rgb[r] = (out_w[r][:, None] * rgbs[r]).sum(0)
        if opacity > 1e-10:
            out_depth[r] = min(max((out_w[r] * t_mids[r]).sum() / opacity, near[r]), far[r])
            soft = np.exp(logits[r] - logits[r].max(-1, keepdims=True))
            soft /= soft.sum(-1, keepdims=True)
            out_probs[r] = (out_w[r][:, None] * soft).sum(0) / opacity
        else:
            out_depth[r] = far[r]
            out_probs[r] = 1.0 / logits.shape[-1]
    return out_w, out_rgb, out_depth, out_probs


def random_rays(rng, n_rays=7, n_samples=13, n_classes=5):
    t = np.sort(rng.uniform(0.5, 4.0, (n_rays, n_samples + 1)), axis=-1)
    sigmas = rng.exponential(2.0, (n_rays, n_samples)) * (rng.uniform(size=(n_rays, n_samples)) > 0.3)
    return dict(
        sigmas=sigmas,
        deltas=np.diff(t, axis=-1),
        rgbs=rng.uniform(size=(n_rays, n_samples, 3)),
        logits=rng.normal(0, 3, (n_rays, n_samples, n_classes)),
        t_mids=0.5 * (t[:, 1:] + t[:, :-1]),
        near=t[:, 0],
        far=t[:, -1],
    )


def torch_render(d, dtype):
    T = {k: torch.tensor(v, dtype=dtype) for k, v in d.items()}
    w, _, _ = weights_from_density(T["sigmas"], T["deltas"])
    rgb = composite_rgb(w, T["rgbs"])
    depth = depth_from_weights(w, T["t_mids"], T["near"], T["far"])
    probs = class_probs_from_weights(w, T["logits"])
    return w, rgb, depth, probs


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_matches_naive_float64_loop(dtype, tol):
    rng = np.random.default_rng(0)
    d = random_rays(rng)
    ref = naive_render(**d)
    got = torch_render(d, dtype)
    for r, g in zip(ref, got):
        np.testing.assert_allclose(g.double().numpy(), r, atol=tol, rtol=tol)


def test_weights_sum_at_most_one_and_probs_sum_to_one():
    rng = np.random.default_rng(1)
    d = random_rays(rng, n_rays=50)
    w, _, depth, probs = torch_render(d, torch.float32)
    assert torch.all(w.sum(-1) <= 1 + 1e-6)
    np.testing.assert_allclose(probs.sum(-1).numpy(), 1.0, atol=1e-5)
    assert torch.all(depth >= torch.tensor(d["near"], dtype=torch.float32) - 1e-5)
    assert torch.all(depth <= torch.tensor(d["far"], dtype=torch.float32) + 1e-5)


def test_first_sample_opaque_takes_all_weight():
    sigmas = torch.tensor([[1e30, 1.0, 5.0]])
    deltas = torch.tensor([[0.1, 0.1, 0.1]])
    w, trans, alphas = weights_from_density(sigmas, deltas)
    np.testing.assert_allclose(w.numpy(), [[1.0, 0.0, 0.0]])
    assert trans[0, 0] == 1.0


def test_empty_ray_gives_uniform_probs_and_far_depth():
    sigmas = torch.zeros(1, 4)
    deltas = torch.full((1, 4), 0.5)
    logits = torch.randn(1, 4, 3)
    w, _, _ = weights_from_density(sigmas, deltas)
    probs = class_probs_from_weights(w, logits)
    np.testing.assert_allclose(probs.numpy(), 1 / 3, atol=1e-7)
    depth = depth_from_weights(w, torch.tensor([[1.0, 2.0, 3.0, 4.0]]), torch.tensor([0.5]), torch.tensor([4.5]))
    assert depth.item() == 4.5


SIGMAS = [0.0, 1e-30, 1e-6, 1.0, 1e6, 1e30, float("inf")]
DELTAS = [0.0, 1e-12, 1.0, 1e10]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.bfloat16, torch.float16])
def test_finite_values_and_gradients_at_the_extremes(dtype):
    """Every (σ, δ) pair of the sweep, as the only sample and first of three.

    16-bit types cannot hold δ = 1e10 (fp16 max is 65504): there the sweep keeps the δ the
    type can represent; the maths itself runs in fp32 for 16-bit inputs.
    """
    deltas = [d for d in DELTAS if d <= torch.finfo(dtype).max]
    pairs = list(itertools.product(SIGMAS, deltas))
    n = len(pairs)
    base_sig = torch.tensor([[s, 1.0, 0.0] for s, _ in pairs], dtype=torch.float64)
    base_del = torch.tensor([[d, 0.5, 0.5] for _, d in pairs], dtype=torch.float64)
    for n_samples in (1, 3):
        sig = base_sig[:, :n_samples].to(dtype).requires_grad_(True)
        dl = base_del[:, :n_samples].to(dtype)
        logits = torch.randn(n, n_samples, 4, dtype=torch.float64).to(dtype).requires_grad_(True)
        rgbs = torch.rand(n, n_samples, 3, dtype=torch.float64).to(dtype).requires_grad_(True)
        t_mids = torch.cumsum(dl.float().clamp(max=1e10), -1).to(dtype)
        w, trans, alphas = weights_from_density(sig, dl)
        rgb = composite_rgb(w, rgbs, torch.ones(3, dtype=dtype))
        probs = class_probs_from_weights(w, logits)
        near = torch.zeros(n, dtype=dtype)
        far = torch.full((n,), min(2e10, torch.finfo(dtype).max), dtype=dtype)
        depth = depth_from_weights(w, t_mids, near, far)
        for t in (w, trans, alphas, rgb, probs, depth):
            assert torch.all(torch.isfinite(t)), t
        assert torch.all(w.float().sum(-1) <= 1 + 1e-2)
        hit = w.float().sum(-1) > 1e-3
        np.testing.assert_allclose(probs.detach().float().sum(-1)[hit].numpy(), 1.0, atol=2e-2)
        (rgb.float().sum() + probs.float().log().sum() + depth.float().sum() * 1e-10).backward()
        for g in (sig.grad, logits.grad, rgbs.grad):
            assert torch.all(torch.isfinite(g))


def test_extremes_match_float64_reference():
    """σ/δ sweep with fp32 against the naive float64 loop: |error| ≤ 1e-5."""
    pairs = list(itertools.product(SIGMAS, DELTAS))
    sigmas = np.array([[s, 2.0] for s, _ in pairs])
    deltas = np.array([[d, 0.25] for _, d in pairs])
    rng = np.random.default_rng(3)
    d = dict(
        sigmas=sigmas,
        deltas=deltas,
        rgbs=rng.uniform(size=(len(pairs), 2, 3)),
        logits=rng.normal(size=(len(pairs), 2, 3)),
        t_mids=np.array([[1.0, 2.0]] * len(pairs)),
        near=np.full(len(pairs), 0.5),
        far=np.full(len(pairs), 3.0),
    )
    ref = naive_render(**d)
    got = torch_render(d, torch.float32)
    for r, g in zip(ref, got):
        np.testing.assert_allclose(g.double().numpy(), r, atol=1e-5)


# ---------------------------------------------------------------- property-based

finite_sigma = st.one_of(st.just(0.0), st.floats(1e-30, 1e30), st.just(float("inf")))
finite_delta = st.one_of(st.just(0.0), st.floats(1e-12, 1e10))


@settings(max_examples=200, deadline=None)
@given(
    sigmas=arrays(np.float64, st.tuples(st.integers(1, 4), st.integers(1, 6)), elements=finite_sigma),
    data=st.data(),
)
def test_property_weights_are_a_sub_probability(sigmas, data):
    deltas = data.draw(arrays(np.float64, sigmas.shape, elements=finite_delta))
    logits = data.draw(arrays(np.float64, sigmas.shape + (3,), elements=st.floats(-50, 50)))
    s = torch.tensor(sigmas, dtype=torch.float32, requires_grad=True)
    w, trans, alphas = weights_from_density(s, torch.tensor(deltas, dtype=torch.float32))
    probs = class_probs_from_weights(w, torch.tensor(logits, dtype=torch.float32))
    assert torch.all(torch.isfinite(w)) and torch.all(w >= 0)
    assert torch.all(w.sum(-1) <= 1 + 1e-5)
    assert torch.all(trans[..., 1:] <= trans[..., :-1] + 1e-7)  # transmittance never grows
    np.testing.assert_allclose(probs.detach().sum(-1).numpy(), 1.0, atol=1e-5)
    (w.sum() + probs.sum()).backward()
    assert torch.all(torch.isfinite(s.grad))
    ref_w = naive_render(sigmas, deltas, np.zeros(sigmas.shape + (3,)), logits, np.ones_like(sigmas), np.zeros(len(sigmas)), np.full(len(sigmas), 2.0))[0]
    np.testing.assert_allclose(w.detach().numpy(), ref_w, atol=1e-5)


def test_scores_variant_matches_naive_loop():
    """softmax(Σ w_i l_i) (eq. 3 variant) against a float64 loop; rows sum to 1; no weight: uniform."""
    rng = np.random.default_rng(3)
    d = random_rays(rng)
    w_ref = naive_render(**d)[0]
    for r in range(len(w_ref)):
        scores = [sum(w_ref[r, s] * d["logits"][r, s, c] for s in range(w_ref.shape[1])) for c in range(d["logits"].shape[-1])]
        top = max(scores)
        ref = [math.exp(x - top) for x in scores]
        ref = [x / sum(ref) for x in ref]
        got = class_log_probs_from_scores(torch.tensor(w_ref[r : r + 1]), torch.tensor(d["logits"][r : r + 1])).exp()
        np.testing.assert_allclose(got[0].numpy(), ref, rtol=1e-12, atol=1e-12)
    empty = class_log_probs_from_scores(torch.zeros(2, 4), torch.randn(2, 4, 3)).exp()
    np.testing.assert_allclose(empty.numpy(), 1.0 / 3)
    # extremes: huge logits and weights stay finite with finite gradients
    w = torch.tensor([[1.0, 0.0], [0.5, 0.5]], requires_grad=True)
    logits = torch.tensor([[[1e30, -1e30], [0.0, 0.0]], [[3e38, 0.0], [-3e38, 0.0]]], requires_grad=True)
    out = class_log_probs_from_scores(w, logits)
    out.exp().sum().backward()
    assert torch.all(torch.isfinite(out.exp())) and torch.all(torch.isfinite(w.grad))


def naive_distortion(w, s_starts, s_ends):
    """mip-NeRF 360 eq. 15 as written: a double loop over sample pairs, float64 Python floats."""
    out = []
    for r in range(len(w)):
        n = len(w[r])
        mids = [0.5 * (float(s_starts[r][i]) + float(s_ends[r][i])) for i in range(n)]
        total = sum(float(w[r][i]) * float(w[r][j]) * abs(mids[i] - mids[j]) for i in range(n) for j in range(n))
        total += sum(float(w[r][i]) ** 2 * (float(s_ends[r][i]) - float(s_starts[r][i])) for i in range(n)) / 3.0
        out.append(total)
    return np.array(out)


def random_sorted_intervals(rng, n_rays=12, n_samples=9):
    edges = np.sort(rng.uniform(0.0, 1.0, (n_rays, n_samples + 1)), axis=-1)
    w = rng.dirichlet(np.ones(n_samples + 1), n_rays)[:, :n_samples]  # a sub-probability per ray
    return w, edges[:, :-1], edges[:, 1:]


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-6)])
def test_distortion_matches_naive_double_loop(dtype, tol):
    w, s0, s1 = random_sorted_intervals(np.random.default_rng(4))
    got = distortion_from_weights(*(torch.tensor(x, dtype=dtype) for x in (w, s0, s1)))
    np.testing.assert_allclose(got.double().numpy(), naive_distortion(w, s0, s1), rtol=tol, atol=tol)


def test_distortion_is_lower_for_a_surface_than_for_fog_and_ignores_zero_weight_padding():
    edges = np.linspace(0.0, 1.0, 21)
    s0, s1 = torch.tensor(edges[None, :-1]), torch.tensor(edges[None, 1:])
    surface = torch.zeros(1, 20, dtype=torch.float64)
    surface[0, 10] = 1.0
    fog = torch.full((1, 20), 1.0 / 20, dtype=torch.float64)
    assert float(distortion_from_weights(surface, s0, s1)) == pytest.approx(0.05 / 3)  # only the 1/3 w² δ term
    assert float(distortion_from_weights(fog, s0, s1)) > 10 * float(distortion_from_weights(surface, s0, s1))
    # the renderer pads rays with zero-weight, zero-length intervals at s = 0 after the real ones
    pad = torch.zeros(1, 5, dtype=torch.float64)
    padded = distortion_from_weights(torch.cat([fog, pad], -1), torch.cat([s0, pad], -1), torch.cat([s1, pad], -1))
    np.testing.assert_allclose(padded.numpy(), distortion_from_weights(fog, s0, s1).numpy(), rtol=1e-12)
    assert float(distortion_from_weights(torch.zeros(1, 20, dtype=torch.float64), s0, s1)) == 0.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_distortion_finite_with_finite_gradients_at_the_extremes(dtype):
    """Weights from 0 to 1 with tiny (1e-38) and full-length intervals: finite values and gradients."""
    w = torch.tensor([[1.0, 0.0, 0.0], [1e-38, 1e-38, 1.0 - 2e-38], [0.0, 0.0, 0.0], [0.3, 0.3, 0.4]], dtype=dtype)
    s0 = torch.tensor([[0.0, 0.5, 0.5], [0.0, 1e-38, 2e-38], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    s1 = torch.tensor([[1.0, 0.5, 1.0], [1e-38, 2e-38, 1.0], [0.0, 0.0, 0.0], [0.0, 1.0, 1.0]], dtype=dtype)
    w.requires_grad_(True)
    out = distortion_from_weights(w, s0, s1)
    out.sum().backward()
    assert torch.all(torch.isfinite(out)) and torch.all(out >= 0) and torch.all(torch.isfinite(w.grad))
    np.testing.assert_allclose(out.detach().double().numpy(), naive_distortion(w.detach(), s0, s1), rtol=1e-5, atol=1e-7)


def _naive_depth_at_transmittance(sigmas, t_starts, t_ends, level):
    """Float64 loop: walk each ray's intervals, integrating exp(-σ t) exactly."""
    out = []
    target = -math.log(level)
    for s_row, a_row, b_row in zip(sigmas.tolist(), t_starts.tolist(), t_ends.tolist()):
        tau, depth = 0.0, math.inf
        for s, a, b in zip(s_row, a_row, b_row):
            step = max(s, 0.0) * (b - a)
            if tau + step >= target:
                depth = min(a + (target - tau) / s, b)
                break
            tau += step
        out.append(depth)
    return np.array(out)


@pytest.mark.parametrize("level", [0.5, 0.1, 0.9])
def test_depth_at_transmittance_matches_naive_float64_loop(level):
    gen = torch.Generator().manual_seed(3)
    sigmas = torch.rand(200, 40, generator=gen, dtype=torch.float64) * 3.0
    sigmas[sigmas < 1.5] = 0.0  # gaps of empty space
    sigmas[::2] *= 0.01  # faint rays that keep more than the level
    edges = torch.cumsum(torch.rand(200, 41, generator=gen, dtype=torch.float64) * 0.1, -1)
    t_starts, t_ends = edges[:, :-1], edges[:, 1:]
    got = depth_at_transmittance(sigmas, t_starts, t_ends, level)
    want = _naive_depth_at_transmittance(sigmas.numpy(), t_starts.numpy(), t_ends.numpy(), level)
    assert np.isinf(want).any() and np.isfinite(want).any()  # both kinds of ray are tested
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-12)


def test_depth_at_transmittance_of_a_constant_density_and_at_the_extremes():
    # σ = 2 from t = 1 on: T(t) = exp(-2 (t - 1)) = 0.5 at t = 1 + ln 2 / 2
    t = torch.linspace(0.0, 5.0, 51, dtype=torch.float64)
    sigmas = torch.where(t[:-1] >= 1.0, 2.0, 0.0)[None]
    got = depth_at_transmittance(sigmas, t[None, :-1], t[None, 1:])
    assert abs(float(got) - (1.0 + math.log(2.0) / 2.0)) < 1e-12
    # an opaque sample is crossed where it starts; an empty ray never; huge and tiny densities stay finite
    for dtype in (torch.float32, torch.float64):
        starts = torch.tensor([[0.0, 1.0, 2.0]] * 4, dtype=dtype)
        ends = starts + 1.0
        sigmas = torch.tensor([[0.0, 3e38, 0.0], [0.0, 0.0, 0.0], [1e-30, 1e-30, 1e-30], [0.0, 1e10, 1e10]], dtype=dtype)
        depth = depth_at_transmittance(sigmas, starts, ends)
        assert float(depth[0]) == pytest.approx(1.0, abs=1e-6) and math.isinf(float(depth[1])) and math.isinf(float(depth[2]))
        assert float(depth[3]) == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match="level"):
        depth_at_transmittance(sigmas, starts, ends, 1.0)


def test_depth_of_max_weight_is_the_middle_of_the_heaviest_interval():
    t_starts = torch.tensor([[0.0, 1.0, 2.0, 3.0]] * 3, dtype=torch.float64)
    t_ends = t_starts + 1.0
    weights = torch.tensor([[0.2, 0.1, 0.6, 0.05], [0.0, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.3]], dtype=torch.float64)
    depth = depth_of_max_weight(weights, t_starts, t_ends)
    assert float(depth[0]) == 2.5  # the spike, not the mean (1.9) nor the median
    assert math.isinf(float(depth[1]))  # no weight: no surface
    assert float(depth[2]) == 0.5  # ties: the nearer interval


def test_weight_before_matches_a_float64_loop_and_ignores_nan_limits():
    rng = np.random.default_rng(3)
    weights = rng.uniform(0, 0.2, (6, 9))
    t_ends = np.cumsum(rng.uniform(0.05, 0.3, (6, 9)), axis=1)
    t_free = rng.uniform(0.0, 2.0, 6)
    t_free[2] = np.nan
    expected = [sum(w for w, e in zip(weights[r], t_ends[r]) if e <= t_free[r]) for r in range(6)]
    got = weight_before(torch.tensor(weights), torch.tensor(t_ends), torch.tensor(t_free)).numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert got[2] == 0.0


# ---------------------------------------------------------------- class probabilities over listed samples


def _listed(weights: torch.Tensor, logits: torch.Tensor, order: np.ndarray):
    """[n_rays, S] weights and [n_rays, S, C] logits as a flat list of samples in ``order``, each with its ray."""
    n_rays, n_samples = weights.shape
    rays = torch.arange(n_rays).repeat_interleave(n_samples)[order]
    return weights.reshape(-1)[order], logits.reshape(n_rays * n_samples, -1)[order], rays


def test_class_log_probs_over_listed_samples_match_the_padded_form_and_the_float64_loop():
    """The same eq. 7 as class_log_probs_from_weights, values and gradients, with the samples in any
    order; a ray without weight is uniform; the naive float64 loop agrees, and so does the renders'
    direct sum (class_probs_from_sample_weights, no gradient)."""
    rng = np.random.default_rng(5)
    d = random_rays(rng)
    d["sigmas"][2] = 0.0  # an empty ray
    w, _, _ = weights_from_density(torch.tensor(d["sigmas"]), torch.tensor(d["deltas"]))
    ref_probs = naive_render(**d)[3]
    for order in (np.arange(w.numel()), rng.permutation(w.numel())):
        w1 = w.clone().requires_grad_()
        l1 = torch.tensor(d["logits"], requires_grad=True)
        padded = class_log_probs_from_weights(w1, l1)
        w2 = w.clone().requires_grad_()
        l2 = torch.tensor(d["logits"], requires_grad=True)
        flat_w, flat_l, rays = _listed(w2, l2, order)
        listed = class_log_probs_from_sample_weights(flat_w, flat_l, rays, w.shape[0])
        torch.testing.assert_close(listed, padded, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(listed.exp().detach().numpy(), ref_probs, atol=1e-12)
        direct = class_probs_from_sample_weights(flat_w.detach(), flat_l.detach(), rays, w.shape[0])
        np.testing.assert_allclose(direct.numpy(), ref_probs, atol=1e-12)
        pick = torch.tensor(rng.normal(size=padded.shape))
        (padded * pick).sum().backward()
        (listed * pick).sum().backward()
        torch.testing.assert_close(w2.grad, w1.grad, rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(l2.grad, l1.grad, rtol=1e-10, atol=1e-12)
    no_samples = (torch.zeros(0), torch.zeros(0, 4), torch.zeros(0, dtype=torch.int64), 3)
    torch.testing.assert_close(class_log_probs_from_sample_weights(*no_samples), torch.full((3, 4), -math.log(4)))
    torch.testing.assert_close(class_probs_from_sample_weights(*no_samples), torch.full((3, 4), 0.25))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_class_log_probs_over_listed_samples_finite_at_the_extremes(dtype):
    """σ/δ sweep (weights from 0 to 1) and logits up to ±1e4 (a softmax that underflows in float32):
    finite log-probabilities and gradients, rows that sum to 1 where the ray has weight."""
    pairs = list(itertools.product(SIGMAS, DELTAS))
    sig = torch.tensor([[s, 1.0, 0.0] for s, _ in pairs], dtype=torch.float64)
    dl = torch.tensor([[d, 0.5, 0.5] for _, d in pairs], dtype=torch.float64)
    w, _, _ = weights_from_density(sig, dl)
    w = w.to(dtype).requires_grad_()
    logits = (torch.randn(len(pairs), 3, 4, dtype=torch.float64) * 1e4).to(dtype).requires_grad_()
    flat_w, flat_l, rays = _listed(w, logits, np.arange(w.numel()))
    out = class_log_probs_from_sample_weights(flat_w, flat_l, rays, len(pairs))
    assert torch.all(torch.isfinite(out))
    hit = w.detach().sum(-1) > 1e-10
    np.testing.assert_allclose(out.detach().exp().sum(-1)[hit].double().numpy(), 1.0, atol=1e-5)
    out.sum().backward()
    assert torch.all(torch.isfinite(w.grad)) and torch.all(torch.isfinite(logits.grad))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("n_classes", [1, 2, 200])
def test_class_probs_over_listed_samples_finite_at_the_extremes(dtype, n_classes):
    """σ/δ sweep (weights from 0 to 1), logits up to ±1e4 and one to 200 classes: finite
    probabilities in [0, 1] whose rows sum to 1, uniform where the ray has no weight."""
    pairs = list(itertools.product(SIGMAS, DELTAS))
    sig = torch.tensor([[s, 1.0, 0.0] for s, _ in pairs] + [[0.0, 0.0, 0.0]], dtype=torch.float64)  # + an empty ray
    dl = torch.tensor([[d, 0.5, 0.5] for _, d in pairs] + [[0.5, 0.5, 0.5]], dtype=torch.float64)
    w, _, _ = weights_from_density(sig, dl)
    logits = torch.randn(len(sig), 3, n_classes, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 1e4
    flat_w, flat_l, rays = _listed(w.to(dtype), logits.to(dtype), np.arange(w.numel()))
    probs = class_probs_from_sample_weights(flat_w, flat_l, rays, len(sig))
    assert torch.all(torch.isfinite(probs)) and bool(((probs >= 0) & (probs <= 1)).all())
    np.testing.assert_allclose(probs.sum(-1).double().numpy(), 1.0, atol=1e-5)
    empty = w.sum(-1) <= 1e-10
    assert bool(empty[-1])
    torch.testing.assert_close(probs[empty], torch.full_like(probs[empty], 1.0 / n_classes))
