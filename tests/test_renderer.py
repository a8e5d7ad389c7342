"""renderer.py: sampling + field evaluation + compositing, against a naive float64 loop; early
stopping (queries, and training's min_trans); NeRF's hierarchical (coarse + fine) sampling."""

from types import SimpleNamespace

import numpy as np
import torch

from scenelabel.geometry.warps import BoxWarp
from scenelabel.render.marcher import (
    CompositeOptions,
    Marching,
    Skipping,
    ray_intervals,
    render_rays,
    render_rays_early_stop,
    render_rays_hierarchical,
)
from scenelabel.render.sampling import DensityGrid

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
N_CLASSES = 3


class SlabField:
    """σ = sigma inside the slab x > 0.2 (a thin haze, σ = ``haze``, elsewhere), colour and classes varying with x."""

    def __init__(self, sigma: float, semantic_rendering: str = "probs", haze: float = 0.05):
        self.sigma, self.haze = sigma, haze
        self.warp = BoxWarp(AABB)
        self.num_classes = N_CLASSES
        self.config = SimpleNamespace(semantic_rendering=semantic_rendering)
        self.calls = 0  # points the trunk (features) evaluated
        self.head_calls = 0  # points the heads evaluated

    def density(self, points):
        return self.features(points)[0]

    def semantics(self, points):
        sigmas, h, raw = self.features(points)
        return sigmas, self.heads(h, raw, None)[1]

    def __call__(self, points, directions):
        sigmas, h, raw = self.features(points)
        return (sigmas, *self.heads(h, raw, directions))

    def features(self, points):  # the trunk's part: σ, and the points as the heads' input
        self.calls += len(points)
        x = points[:, 0]
        sigmas = torch.where(x > 0.2, torch.full_like(x, self.sigma), torch.full_like(x, self.haze))
        return sigmas, points, points[:, :0]

    def heads(self, h, raw, directions):
        self.head_calls += len(h)
        x = h[:, 0]
        logits = torch.stack([x * 3.0, -x, torch.sin(5 * x)], -1)
        rgbs = None if directions is None else torch.sigmoid(torch.stack([h[:, 0], h[:, 1] * 2, h[:, 2] - 1], -1))
        return rgbs, logits


def every_cell(points):
    return torch.ones(points.shape[:-1], dtype=torch.bool)


def not_left_half(points):
    return points[..., 0] > -0.5  # skips part of each ray: packing must keep the order


def rays(n=40, seed=0):
    g = torch.Generator().manual_seed(seed)
    origins = torch.rand(n, 3, generator=g) * 0.6 - 0.3
    origins[:, 0] = -0.9
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) * 0.3 + torch.tensor([1.0, 0, 0]), dim=-1)
    directions[-1] = torch.tensor([-1.0, 0.0, 0.0])  # leaves the box at once: hardly any sample
    t_min, t_max = ray_intervals(origins, directions, AABB)
    return origins, directions, t_min, t_max


def interval_middles(t_min: float, t_max: float, step: float, n_samples: int) -> torch.Tensor:
    """The middles of a ray's marched intervals of positive length: steps of ``step`` from t_min, the
    last cut at t_max, at most n_samples."""
    starts = torch.arange(n_samples) * step + t_min
    return (0.5 * (starts + torch.minimum(starts + step, torch.tensor(t_max))))[starts < t_max]


def naive_render(field, occupancy, origins, directions, t_min, t_max, step):
    """Float64 loop over rays and samples: uniform steps of ``step`` from t_min, eq. 2 and eq. 7."""
    out_rgb, out_depth, out_probs = [], [], []
    for o, d, a, b in zip(origins.double(), directions.double(), t_min.double(), t_max.double()):
        t, trans = float(a), 1.0
        rgb, depth, opacity, probs = np.zeros(3), 0.0, 0.0, np.zeros(N_CLASSES)
        while t < float(b) - 1e-12:
            end = min(t + step, float(b))
            p = (o + 0.5 * (t + end) * d).float()[None]
            if bool(occupancy(p)[0]):
                s, c, logits = field(p, d.float()[None])
                alpha = 1.0 - np.exp(-float(s[0]) * (end - t))
                w = trans * alpha
                rgb += w * c[0].double().numpy()
                depth += w * 0.5 * (t + end)
                opacity += w
                probs += w * torch.softmax(logits[0].double(), -1).numpy()
                trans *= 1.0 - alpha
            t = end
        out_rgb.append(rgb)
        out_depth.append(depth / opacity if opacity > 1e-10 else float(b))
        out_probs.append(probs / opacity if opacity > 1e-10 else np.full(N_CLASSES, 1.0 / N_CLASSES))
    return np.array(out_rgb), np.array(out_depth), np.array(out_probs)


def test_render_rays_matches_a_naive_float64_loop():
    field = SlabField(sigma=4.0)
    o, d, t_min, t_max = rays()
    step, n_samples = 0.05, 64
    out = render_rays(field, not_left_half, o, d, t_min, t_max, Marching(step, n_samples))
    rgb, depth, probs = naive_render(field, not_left_half, o, d, t_min, t_max, step)
    np.testing.assert_allclose(out.rgb.double().numpy(), rgb, atol=2e-5)
    np.testing.assert_allclose(out.depth.double().numpy(), np.clip(depth, 0, None), atol=2e-5)
    np.testing.assert_allclose(out.class_log_probs.exp().double().numpy(), probs, atol=2e-5)


def test_render_rays_evaluates_only_intervals_of_length_in_occupied_space():
    """The field sees each ray's intervals of positive length whose middle the grid holds
    occupied, nothing else (the samples it reports are those, with their σ); rays with no such
    interval composite to nothing."""
    field = SlabField(sigma=4.0)
    o, d, t_min, t_max = rays()
    t_max = torch.where(torch.arange(len(t_max)) % 3 == 0, t_min, t_max)  # every third ray: an empty interval
    step = 0.05
    out = render_rays(field, not_left_half, o, d, t_min, t_max, Marching(step, 64))
    expected = 0
    for a, b, origin, direction in zip(t_min.tolist(), t_max.tolist(), o, d):
        middles = interval_middles(a, b, step, 64)
        expected += int(not_left_half(origin + middles[:, None] * direction).sum())
    assert out.n_evaluated == field.calls == expected == len(out.sample_points) == len(out.sample_sigmas)
    assert not_left_half(out.sample_points).all()
    torch.testing.assert_close(out.sample_sigmas, SlabField(sigma=4.0).features(out.sample_points)[0])
    empty = torch.arange(len(t_max)) % 3 == 0
    torch.testing.assert_close(out.opacity[empty], torch.zeros(int(empty.sum())))
    none = render_rays(field, not_left_half, o, d, t_max + 1, t_max, Marching(step, 64))  # no interval at all
    assert none.n_evaluated == 0 and torch.isfinite(none.rgb).all() and torch.isfinite(none.depth).all()


def test_open_rays_sample_every_step_and_the_others_only_occupied_ones():
    """``open_rays``: those rays render as if every cell were occupied, the others as the grid says,
    in one call (training's class-balanced rays through cells the grid emptied)."""
    o, d, t_min, t_max = rays()
    opened = torch.arange(len(o)) % 4 == 1
    marching = Marching(0.05, 64)
    mixed = render_rays(SlabField(sigma=4.0), not_left_half, o, d, t_min, t_max, marching, skipping=Skipping(open_rays=opened))
    every = render_rays(SlabField(sigma=4.0), every_cell, o, d, t_min, t_max, marching)
    grid = render_rays(SlabField(sigma=4.0), not_left_half, o, d, t_min, t_max, marching)
    assert (mixed.rgb[opened] - grid.rgb[opened]).abs().max() > 1e-3  # the haze in the left half shows
    for name in ("rgb", "depth", "opacity", "class_log_probs"):
        torch.testing.assert_close(getattr(mixed, name)[opened], getattr(every, name)[opened])
        torch.testing.assert_close(getattr(mixed, name)[~opened], getattr(grid, name)[~opened])
    assert mixed.n_evaluated == every.n_evaluated - _skipped(o, d, t_min, t_max, ~opened) > grid.n_evaluated


class ScaledSlabField(SlabField):
    """SlabField with σ and the class logits each scaled by a parameter (for gradients)."""

    def __init__(self):
        super().__init__(sigma=4.0)
        self.sigma_scale = torch.tensor(1.0, requires_grad=True)
        self.logit_scale = torch.tensor(1.0, requires_grad=True)

    def features(self, points):
        sigmas, h, raw = super().features(points)
        return sigmas * self.sigma_scale, h, raw

    def heads(self, h, raw, directions):
        rgbs, logits = super().heads(h, raw, directions)
        return rgbs, logits * self.logit_scale


def test_geometry_only_labels_move_density_and_not_the_classes():
    """``CompositeOptions.geometry_only_labels``: the flagged rays' class composite is unchanged, and a
    loss on it reaches σ but not the class logits; the other rays' reaches both."""
    o, d, t_min, t_max = rays()
    marching, target = Marching(0.05, 64), torch.zeros(len(o), dtype=torch.long)
    for flagged in (torch.ones(len(o), dtype=torch.bool), torch.zeros(len(o), dtype=torch.bool)):
        field = ScaledSlabField()
        out = render_rays(field, every_cell, o, d, t_min, t_max, marching, options=CompositeOptions(geometry_only_labels=flagged))
        plain = render_rays(SlabField(sigma=4.0), every_cell, o, d, t_min, t_max, marching)
        torch.testing.assert_close(out.class_log_probs, plain.class_log_probs)
        torch.nn.functional.nll_loss(out.class_log_probs, target).backward()
        assert field.sigma_scale.grad is not None and float(field.sigma_scale.grad.abs()) > 0
        moved = field.logit_scale.grad is not None and float(field.logit_scale.grad.abs()) > 0
        assert moved == (not bool(flagged.all()))


def _skipped(o, d, t_min, t_max, which):
    """Samples of the rays ``which`` whose middle lies in not_left_half's empty half."""
    n = 0
    for a, b, origin, direction in zip(t_min[which].tolist(), t_max[which].tolist(), o[which], d[which]):
        middles = interval_middles(a, b, 0.05, 64)
        n += int((~not_left_half(origin + middles[:, None] * direction)).sum())
    return n


def test_early_stop_with_zero_threshold_is_the_full_composite():
    for rendering in ("probs", "scores"):
        field = SlabField(sigma=30.0, semantic_rendering=rendering)
        o, d, t_min, t_max = rays()
        full = render_rays(field, not_left_half, o, d, t_min, t_max, Marching(0.03, 80))
        stopped = render_rays_early_stop(field, not_left_half, o, d, t_min, t_max, Marching(0.03, 80), min_trans=0.0, segment=7)
        assert stopped.n_evaluated == full.n_evaluated
        for name in ("rgb", "depth", "opacity", "class_log_probs"):
            torch.testing.assert_close(getattr(stopped, name), getattr(full, name), rtol=0, atol=1e-6)


def test_early_stop_reads_a_box_grid_along_the_rays_as_render_rays_reads_its_points():
    """With a DensityGrid over a box the marcher reads cells without forming every point
    (DensityGrid.cells_along): the same samples and composite as render_rays, which asks the grid
    at the points."""
    grid = DensityGrid(BoxWarp(AABB), resolution=9, step=0.03)
    grid.bits = torch.rand(9, 9, 9, generator=torch.Generator().manual_seed(3)) < 0.6
    field = SlabField(sigma=30.0)
    o, d, t_min, t_max = rays()
    full = render_rays(field, grid, o, d, t_min, t_max, Marching(0.03, 80))
    stopped = render_rays_early_stop(field, grid, o, d, t_min, t_max, Marching(0.03, 80), min_trans=0.0)
    assert stopped.n_evaluated == full.n_evaluated < len(o) * 80
    for name in ("rgb", "depth", "opacity", "class_log_probs"):
        torch.testing.assert_close(getattr(stopped, name), getattr(full, name), rtol=0, atol=1e-6)


def test_early_stop_through_a_box_grid_with_rays_that_miss_the_box():
    """Rays along an axis that miss the box march empty intervals at t = inf (inf x a direction's 0:
    NaN cell coordinates): no sample, nothing composited, no index error."""
    grid = DensityGrid(BoxWarp(AABB), resolution=8, step=0.03)
    grid.bits = torch.ones(8, 8, 8, dtype=torch.bool)
    o, d = torch.full((3, 3), 10.0), torch.eye(3)
    t_min, t_max = ray_intervals(o, d, AABB)
    out = render_rays_early_stop(SlabField(sigma=30.0), grid, o, d, t_min, t_max, Marching(0.03, 80))
    assert out.n_evaluated == 0
    torch.testing.assert_close(out.opacity, torch.zeros(3))


def test_early_stop_evaluates_less_and_changes_the_answer_by_at_most_the_threshold():
    field = SlabField(sigma=200.0)  # opaque within a few samples of x = 0.2
    o, d, t_min, t_max = rays()
    full = render_rays(field, every_cell, o, d, t_min, t_max, Marching(0.02, 120))
    min_trans = 1e-4
    field.calls = field.head_calls = 0
    stopped = render_rays_early_stop(field, every_cell, o, d, t_min, t_max, Marching(0.02, 120), min_trans=min_trans, segment=8)
    assert stopped.n_evaluated == field.calls < 0.75 * full.n_evaluated
    # the heads run only where the transmittance in front is still at least min_trans: on fewer points
    # than the trunk (not those past the stop within a segment, which the composite drops)
    assert field.head_calls < field.calls
    torch.testing.assert_close(stopped.opacity, full.opacity, rtol=0, atol=min_trans)
    torch.testing.assert_close(stopped.rgb, full.rgb, rtol=0, atol=2 * min_trans)
    torch.testing.assert_close(stopped.class_log_probs.exp(), full.class_log_probs.exp(), rtol=0, atol=2 * min_trans)
    span = float((t_max - t_min).max())
    torch.testing.assert_close(stopped.depth, full.depth, rtol=0, atol=2 * min_trans * span)


def test_early_stop_drops_faint_samples_within_the_bound():
    """Samples whose σ δ is below min_trans / S (S marched samples) get no head work and count as
    σ = 0: a haze just below that drops its whole weight, which stays below min_trans per ray."""
    o, d, t_min, t_max = rays()
    marching, min_trans = Marching(0.02, 120), 1e-4
    haze = 0.9 * min_trans / marching.n_samples / marching.step  # σ δ at 0.9 of the faint limit
    field = SlabField(sigma=200.0, haze=haze)
    full = render_rays(field, every_cell, o, d, t_min, t_max, marching)
    field.calls = field.head_calls = 0
    stopped = render_rays_early_stop(field, every_cell, o, d, t_min, t_max, marching, min_trans=min_trans)
    in_slab = 0
    for a, b, origin, direction in zip(t_min.tolist(), t_max.tolist(), o, d):  # slab samples in front of the stop
        middles = interval_middles(a, b, marching.step, marching.n_samples)
        in_slab += int(((origin[0] + middles * direction[0]) > 0.2).sum())
    assert field.head_calls <= in_slab < field.calls  # no haze sample reached the heads
    assert (full.opacity - stopped.opacity).abs().max() <= 2 * min_trans
    torch.testing.assert_close(stopped.rgb, full.rgb, rtol=0, atol=2 * min_trans)
    hit = full.opacity >= 0.5  # averages over the weights move by the dropped weight over the opacity
    assert 0 < int(hit.sum()) < len(hit)
    probs, full_probs = stopped.class_log_probs.exp()[hit], full.class_log_probs.exp()[hit]
    torch.testing.assert_close(probs, full_probs, rtol=0, atol=4 * min_trans)
    span = float((t_max - t_min).max())
    torch.testing.assert_close(stopped.depth[hit], full.depth[hit], rtol=0, atol=4 * min_trans * span)
    haze_only = SlabField(sigma=0.0, haze=haze)  # nothing but faint samples: nothing composited
    empty = render_rays_early_stop(haze_only, every_cell, o, d, t_min, t_max, marching, min_trans=min_trans)
    assert haze_only.head_calls == 0 and float(empty.opacity.max()) == 0.0
    assert float(render_rays(haze_only, every_cell, o, d, t_min, t_max, marching).opacity.max()) < min_trans


def test_early_stop_finite_at_extreme_densities():
    """From no slab (σ = 0) to one opaque within a millionth of a step (σ = 1e8): finite answers,
    opacity in [0, 1], probabilities summing to one, and within the threshold of the full composite."""
    o, d, t_min, t_max = rays()
    for sigma in (0.0, 1e-8, 1e3, 1e8):
        field = SlabField(sigma=sigma)
        full = render_rays(field, every_cell, o, d, t_min, t_max, Marching(0.02, 120))
        for min_trans in (0.0, 1e-4):
            out = render_rays_early_stop(field, every_cell, o, d, t_min, t_max, Marching(0.02, 120), min_trans=min_trans, segment=8)
            for name in ("rgb", "depth", "opacity", "class_log_probs"):
                assert torch.isfinite(getattr(out, name)).all(), (sigma, min_trans, name)
            assert ((out.opacity >= 0) & (out.opacity <= 1 + 1e-6)).all()
            torch.testing.assert_close(out.class_log_probs.exp().sum(-1), torch.ones(len(o)), rtol=0, atol=1e-5)
            torch.testing.assert_close(out.opacity, full.opacity, rtol=0, atol=max(min_trans, 1e-6))
            torch.testing.assert_close(out.rgb, full.rgb, rtol=0, atol=max(2 * min_trans, 1e-5))


def test_early_stop_without_colour_and_with_no_samples():
    field = SlabField(sigma=50.0)
    o, d, t_min, t_max = rays(5)
    out = render_rays_early_stop(field, every_cell, o, d, t_min, t_max, Marching(0.05, 40), CompositeOptions(with_rgb=False))
    assert out.rgb is None and torch.isfinite(out.depth).all()
    empty = render_rays_early_stop(field, every_cell, o, d, t_max + 1, t_max, Marching(0.05, 40))  # every interval empty
    assert empty.n_evaluated == 0
    torch.testing.assert_close(empty.opacity, torch.zeros(5))
    torch.testing.assert_close(empty.class_log_probs.exp(), torch.full((5, N_CLASSES), 1 / N_CLASSES))


class LearntSlab(SlabField):
    """SlabField whose σ and head input are scaled by a parameter: a gradient to compare."""

    def __init__(self, sigma: float):
        super().__init__(sigma)
        self.scale = torch.tensor(1.0, dtype=torch.float32, requires_grad=True)

    def features(self, points):
        sigmas, h, raw = super().features(points)
        return sigmas * self.scale, h * self.scale, raw


def test_training_stop_skips_samples_behind_opaque_and_keeps_answer_and_gradient():
    """render_rays(min_trans > 0), as training marches: samples behind the point where a ray's
    transmittance falls below min_trans are not evaluated; their weights sum to less than min_trans,
    so the composite and the gradient move by less than that."""
    o, d, t_min, t_max = rays()
    marching, min_trans = Marching(0.02, 120), 1e-4
    jitter = torch.rand(len(o), generator=torch.Generator().manual_seed(1))
    outs, grads, calls = [], [], []
    for stop in (0.0, min_trans):
        field = LearntSlab(sigma=200.0)  # opaque within a few samples of x = 0.2
        out = render_rays(field, every_cell, o, d, t_min, t_max, marching, jitter, skipping=Skipping(min_trans=stop))
        (out.rgb.sum() + out.depth.sum() + out.class_log_probs.exp()[:, 0].sum()).backward()
        outs.append(out), grads.append(float(field.scale.grad)), calls.append(field.calls)
    full, stopped = outs
    # the density pass evaluates up to its segment's end; the field then runs again on those kept
    n_kept = len(stopped.sample_points)
    assert n_kept < stopped.n_evaluated < 0.85 * full.n_evaluated and calls[1] == n_kept + stopped.n_evaluated
    torch.testing.assert_close(stopped.opacity, full.opacity, rtol=0, atol=min_trans)
    torch.testing.assert_close(stopped.rgb, full.rgb, rtol=0, atol=min_trans)
    hit = full.opacity >= 0.5  # averages over the weights move by the dropped weight over the opacity
    assert 0 < int(hit.sum()) < len(hit)
    torch.testing.assert_close(stopped.class_log_probs.exp()[hit], full.class_log_probs.exp()[hit], rtol=0, atol=2 * min_trans)
    span = float((t_max - t_min).max())
    torch.testing.assert_close(stopped.depth[hit], full.depth[hit], rtol=0, atol=2 * min_trans * span)
    # per ray, the dropped weights (< min_trans in all) move d(output)/d(scale) by at most about
    # min_trans x (the optical depth at the stop, -ln min_trans ≈ 9, + 1) x the outputs' range (≤ 2)
    assert 0 < abs(grads[1] - grads[0]) <= len(o) * 20 * min_trans


def test_training_stop_evaluates_every_sample_of_a_ray_that_stays_clear():
    """A haze never opaque: min_trans > 0 evaluates every occupied sample, in growing segments, and
    composites exactly what render_rays without it does (also without colour, and with no sample)."""
    o, d, t_min, t_max = rays()
    marching = Marching(0.01, 240)  # long rays: several segments
    for with_rgb in (True, False):
        options = CompositeOptions(with_rgb=with_rgb)
        full = render_rays(SlabField(sigma=0.0, haze=0.5), every_cell, o, d, t_min, t_max, marching, None, options)
        clear = render_rays(SlabField(sigma=0.0, haze=0.5), every_cell, o, d, t_min, t_max, marching, None, options,
                            Skipping(1e-4))
        assert clear.n_evaluated == full.n_evaluated > 100 * len(o)
        for name in ("rgb", "depth", "opacity", "class_log_probs"):
            torch.testing.assert_close(getattr(clear, name), getattr(full, name), rtol=0, atol=1e-6)
    empty = render_rays(SlabField(sigma=1.0), every_cell, o, d, t_max + 1, t_max, marching, skipping=Skipping(1e-4))
    assert empty.n_evaluated == 0 and float(empty.opacity.max()) == 0.0


def test_training_stop_finite_at_extreme_densities():
    """From no slab (σ = 0) to one opaque within a millionth of a step (σ = 1e8), and thresholds from
    1e-12 to 0.5: finite answers, within the threshold of the full composite's opacity."""
    o, d, t_min, t_max = rays()
    marching = Marching(0.02, 120)
    for sigma in (0.0, 1e-8, 1e3, 1e8):
        full = render_rays(SlabField(sigma=sigma), every_cell, o, d, t_min, t_max, marching)
        for min_trans in (1e-12, 1e-4, 0.5):
            out = render_rays(SlabField(sigma=sigma), every_cell, o, d, t_min, t_max, marching, skipping=Skipping(min_trans))
            for name in ("rgb", "depth", "opacity", "class_log_probs"):
                assert torch.isfinite(getattr(out, name)).all(), (sigma, min_trans, name)
            torch.testing.assert_close(out.class_log_probs.exp().sum(-1), torch.ones(len(o)), rtol=0, atol=1e-5)
            torch.testing.assert_close(out.opacity, full.opacity, rtol=0, atol=max(min_trans, 1e-6))


def test_hierarchical_fine_samples_approach_the_dense_composite_the_coarse_ones_miss():
    """A sharp slab: 16 coarse samples place it coarsely; 32 more drawn from their weights put the
    fine composite close to a naive loop with 0.001 steps."""
    field = SlabField(sigma=30.0)
    o, d, t_min, t_max = rays(12)
    rgb, depth, probs = naive_render(field, every_cell, o, d, t_min, t_max, 0.001)
    fine, coarse = render_rays_hierarchical(field, field, o, d, t_min, t_max, (16, 32))

    def errors(out):
        return [
            np.abs(out.rgb.double().numpy() - rgb).max(),
            np.abs(out.depth.double().numpy() - depth).max(),
            np.abs(out.class_log_probs.exp().double().numpy() - probs).max(),
        ]

    fine_err, coarse_err = errors(fine), errors(coarse)
    assert fine_err[0] < 0.1 and fine_err[1] < 0.05 and fine_err[2] < 0.02, fine_err
    assert all(f < c / 4 for f, c in zip(fine_err, coarse_err)), (fine_err, coarse_err)
    n_entered = int((t_max > t_min).sum())
    assert coarse.n_evaluated == 16 * n_entered and fine.n_evaluated == 48 * n_entered


def test_hierarchical_with_jitter_without_colour_and_with_empty_rays():
    field = SlabField(sigma=200.0)
    o, d, t_min, t_max = rays(6)
    g = torch.Generator().manual_seed(3)
    jitter = (torch.rand(6, generator=g), torch.rand(6, 24, generator=g))
    fine, coarse = render_rays_hierarchical(field, field, o, d, t_min, t_max, (12, 24), jitter, CompositeOptions(with_rgb=False))
    assert fine.rgb is None and coarse.rgb is None
    for out in (fine, coarse):
        assert torch.isfinite(out.depth).all() and torch.all(out.opacity <= 1.0 + 1e-6)
    fine, coarse = render_rays_hierarchical(field, field, o, d, t_max + 1, t_max, (12, 24))  # every interval empty
    assert fine.n_evaluated == coarse.n_evaluated == 0
    torch.testing.assert_close(fine.opacity, torch.zeros(6))
    torch.testing.assert_close(fine.class_log_probs.exp(), torch.full((6, N_CLASSES), 1 / N_CLASSES))
