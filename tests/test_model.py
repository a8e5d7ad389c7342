"""The field's semantic variants (eq. 5 per-class densities vs eq. 6 class head, sum vs max)."""

import numpy as np
import pytest
import torch

from scenelabel import SemanticField, build, preset, write_toy_scene
from scenelabel.config import FieldConfig
from scenelabel.errors import ConfigError
from scenelabel.fields.encodings import trilinear_from_grid
from scenelabel.fields.model import FieldNetwork, SkipMLP, combine_class_densities, live_sigmoid

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
VARIANTS = [
    {},  # eq. 6, eq. 7 rendering, cross-entropy (the default)
    {"field": {"class_head": "density", "density_combine": "sum"}},
    {"field": {"class_head": "density", "density_combine": "max"}},
    {"field": {"semantic_rendering": "scores"}},
    {"field": {"class_head": "density", "semantic_rendering": "scores"}},
    {"train": {"semantic_loss": "focal", "focal_gamma": 2.0}},
    {"train": {"detach_semantic_weights": True}},
    {"field": {"encoding": "positional", "view_encoding": "positional", "hidden": 32, "layers": 4, "skip_layer": 2}},
    {"sampling": {"strategy": "hierarchical", "n_coarse": 24, "n_fine": 48}},  # NeRF's coarse + fine networks
    # no network: the dense grid's channels are σ, colour and logits (the voxels preset, smaller)
    {"field": {"encoding": "dense", "head": "direct", "view_dependent": False, "grid_resolution": 24}, "train": {"lr_encoding": 0.1}},
    {"field": {"encoding": "dense", "head": "direct", "view_dependent": False, "grid_resolution": 24, "class_head": "density"}, "train": {"lr_encoding": 0.1}},
]


def _ids(v):
    return "-".join(f"{k}={val}" for stage in v.values() for k, val in stage.items()) or "default"


NETWORKS = {"mlp": {"resolutions": (8,), "hidden": 16}, "direct": {"encoding": "dense", "head": "direct", "view_dependent": False, "grid_resolution": 8}}


@pytest.mark.parametrize("network", sorted(NETWORKS))
@pytest.mark.parametrize("head", ["linear", "density"])
@pytest.mark.parametrize("n_classes", [1, 2, 255])
def test_heads_give_probabilities_that_sum_to_one(head, n_classes, network):
    torch.manual_seed(0)
    model = FieldNetwork(FieldConfig(**NETWORKS[network], class_head=head), n_classes, AABB)
    if network == "direct":  # a trained grid is not all zeros
        with torch.no_grad():
            model.encoding.grid.normal_(0.0, 3.0)
    pts = torch.rand(100, 3) * 2 - 1
    sigmas, rgbs, logits = model(pts, torch.nn.functional.normalize(torch.randn(100, 3), dim=-1))
    assert sigmas.shape == (100,) and rgbs.shape == (100, 3) and logits.shape == (100, n_classes)
    probs = torch.softmax(logits.double(), -1)
    torch.testing.assert_close(probs.sum(-1), torch.ones(100, dtype=torch.float64))
    assert torch.all(sigmas >= 0) and torch.all(torch.isfinite(sigmas))


def test_density_head_probabilities_are_density_shares():
    """eq. 5 with f = sum: softmax(s)_j = σ_j / Σ σ_k and σ = Σ σ_j."""
    torch.manual_seed(1)
    config = FieldConfig(resolutions=(8,), hidden=16, class_head="density", density_combine="sum")
    model = FieldNetwork(config, 4, AABB)
    pts = torch.rand(50, 3) * 2 - 1
    out = model.trunk(model.encoding(model.warp(pts)))
    class_sigmas = torch.exp(out[:, :4] + config.density_bias).double()
    sigmas, logits = model.semantics(pts)
    torch.testing.assert_close(sigmas.double(), class_sigmas.sum(-1), rtol=1e-5, atol=0)
    torch.testing.assert_close(torch.softmax(logits.double(), -1), class_sigmas / class_sigmas.sum(-1, keepdim=True))


def test_combine_class_densities_sum_and_max():
    s = torch.tensor([[0.0, 1.0, 3.0], [2.0, 2.0, 0.0], [0.0, 0.0, 0.0], [1e30, 1e30, 0.0]])
    torch.testing.assert_close(combine_class_densities(s, "sum"), torch.tensor([4.0, 4.0, 0.0, 2e30]))
    torch.testing.assert_close(combine_class_densities(s, "max"), torch.tensor([3.0, 2.0, 0.0, 1e30]))


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("variants") / "scene", n_train=14, n_test=2, width=32, height=24)


@pytest.mark.parametrize("overrides", VARIANTS, ids=_ids)
def test_each_variant_trains_builds_and_answers_queries(tiny_scene, tmp_path, overrides):
    """A few steps of each variant: finite, decreasing loss; the build loads and answers queries."""
    config = preset("quick", overrides)
    config.train.steps = 100
    config.train.batch_rays = 256
    config.train.log_every = 10
    config.output.write_map = False
    config.output.write_renders = False
    result = build(tiny_scene, tmp_path / "out", config, progress=False)
    losses = [h["loss"] for h in result.metrics["history"]]
    assert all(np.isfinite(losses))
    assert np.mean(losses[-3:]) < 0.8 * np.mean(losses[:3]), losses
    field = SemanticField.load(tmp_path / "out")
    assert field.config.field == config.field and field.config.train.semantic_loss == config.train.semantic_loss
    assert (field.coarse is not None) == (config.sampling.strategy == "hierarchical")
    q = field.query_points(np.array([[0.0, 0.0, 0.1], [-0.45, -0.25, 0.3]]))
    np.testing.assert_allclose(q.probs.sum(-1), 1.0, atol=1e-9)
    r = field.query_rays(np.array([[0.0, 0.0, 3.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert np.isfinite(r.depth[0]) == (r.label[0] >= 0) and np.allclose(r.probs.sum(-1), 1.0)  # the ray contract


def test_skip_mlp_matches_a_hand_written_forward():
    torch.manual_seed(2)
    mlp = SkipMLP(5, 8, 3, layers=4, skip=2)
    x = torch.randn(6, 5)
    lin = [m for m in mlp if isinstance(m, torch.nn.Linear)]
    h = torch.relu(lin[0](x))
    h = torch.relu(lin[1](h))
    h = torch.relu(lin[2](torch.cat([h, x], -1)))  # the input again before layer 2
    torch.testing.assert_close(mlp(x), lin[3](h))
    assert [m.in_features for m in lin] == [5, 8, 13, 8]
    torch.testing.assert_close(mlp(x, n_out=2), lin[3](h)[:, :2])  # only the first outputs
    x_before = x.clone()
    with torch.no_grad():  # in-place ReLUs without autograd: the same outputs, the input untouched
        torch.testing.assert_close(mlp(x), lin[3](h), rtol=0, atol=0)
    torch.testing.assert_close(x, x_before, rtol=0, atol=0)


@pytest.mark.parametrize("network", sorted(NETWORKS))
def test_features_without_autograd_are_the_features_with_it(network):
    torch.manual_seed(4)
    model = FieldNetwork(FieldConfig(**NETWORKS[network]), 5, AABB)
    pts = torch.rand(64, 3) * 2 - 1
    with_grad = model.features(pts)
    with torch.no_grad():
        without = model.features(pts)
    for a, b in zip(with_grad, without):
        torch.testing.assert_close(a.detach(), b, rtol=0, atol=0)


@pytest.mark.parametrize("network", sorted(NETWORKS))
@pytest.mark.parametrize("head", ["linear", "density"])
def test_density_alone_is_the_full_forwards_density(head, network):
    """``density`` computes only the trunk's density rows; σ is the full forward's."""
    torch.manual_seed(3)
    model = FieldNetwork(FieldConfig(**NETWORKS[network], class_head=head), 5, AABB)
    pts = torch.rand(64, 3) * 2 - 1
    sigmas, _, _ = model(pts, torch.nn.functional.normalize(torch.randn(64, 3), dim=-1))
    torch.testing.assert_close(model.density(pts), sigmas)


def test_one_output_row_does_not_depend_on_the_batch():
    """SkipMLP's single-row output (the density of ``density``) is the same bits for a point
    whatever else shares its batch, as the full forward's rows are, so that a map's blocks agree
    exactly however the lattice is split (batches of a few rows, under a dozen, take other BLAS
    paths in the hidden layers, full forward included)."""
    torch.manual_seed(4)
    mlp = SkipMLP(12, 64, 65, 3, skip=1)
    x = torch.rand(4099, 12)
    with torch.no_grad():
        whole = mlp(x, n_out=1)
        for start, stop in [(5, 21), (17, 50), (100, 1100), (3, 4099)]:
            torch.testing.assert_close(mlp(x[start:stop], n_out=1), whole[start:stop], rtol=0, atol=0)
        torch.testing.assert_close(whole, mlp(x)[:, :1])  # the full forward's first row, to rounding


@pytest.mark.parametrize("network", sorted(NETWORKS))
@pytest.mark.parametrize("head", ["linear", "density"])
def test_heads_on_a_subset_of_the_features_are_the_full_forwards(head, network):
    """``features`` then ``heads`` on some of the points (as the early-stopping renderer runs them)
    give the full forward's σ, colour and class scores of those points; no directions: no colour."""
    torch.manual_seed(3)
    model = FieldNetwork(FieldConfig(**NETWORKS[network], class_head=head), 5, AABB)
    pts = torch.rand(64, 3) * 2 - 1
    dirs = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    sigmas, rgbs, logits = model(pts, dirs)
    f_sigmas, h, raw = model.features(pts)
    some = torch.arange(0, 64, 3)
    h_rgbs, h_logits = model.heads(h[some], raw[some], dirs[some])
    torch.testing.assert_close(f_sigmas, sigmas)
    torch.testing.assert_close(h_rgbs, rgbs[some])
    torch.testing.assert_close(h_logits, logits[some])
    no_rgb, s_logits = model.heads(h, raw, None)
    assert no_rgb is None
    torch.testing.assert_close(s_logits, model.semantics(pts)[1])


@pytest.mark.parametrize("name", ["paper", "multihead", "tiny", "dense"])
def test_model_family_presets_build_a_field(name):
    config = preset(name).field
    model = FieldNetwork(config, 3, AABB)
    pts = torch.rand(10, 3) * 2 - 1
    sigmas, rgbs, logits = model(pts, torch.nn.functional.normalize(torch.randn(10, 3), dim=-1))
    assert sigmas.shape == (10,) and rgbs.shape == (10, 3) and logits.shape == (10, 3)
    n_linear = sum(isinstance(m, torch.nn.Linear) for m in model.trunk)
    assert n_linear == config.layers
    if name == "paper":  # NeRF: 8 x 256, γ(x) with 10 frequencies (63 dims) again before layer 5
        assert (config.hidden, config.layers, config.skip_layer) == (256, 8, 5)
        assert model.trunk[0].in_features == 63 and model.trunk[10].in_features == 256 + 63
        assert model.view_encoding.out_dim == 27


@pytest.mark.parametrize("class_head", ["linear", "density"])
def test_direct_head_activates_the_grid_channels(class_head):
    """head="direct": σ = exp(raw σ + bias) (summed over σ_j for eq. 5), rgb = sigmoid, logits as
    stored (eq. 6) or the raw σ_j (eq. 5), each from the trilinear channels; no network."""
    torch.manual_seed(3)
    config = FieldConfig(encoding="dense", head="direct", view_dependent=False, grid_resolution=6, class_head=class_head)
    n_classes = 4
    model = FieldNetwork(config, n_classes, AABB)
    n_density = n_classes if class_head == "density" else 1
    n_logits = n_classes if class_head == "linear" else 0
    assert model.encoding.grid.shape == (7, 7, 7, n_density + 3 + n_logits)
    assert model.mlp_parameters() == [] and list(model.parameters()) == [model.encoding.grid]
    with torch.no_grad():
        model.encoding.grid.normal_(0.0, 2.0)
    pts = torch.rand(64, 3) * 2 - 1
    sigmas, rgbs, logits = model(pts, torch.nn.functional.normalize(torch.randn(64, 3), dim=-1))
    raw = trilinear_from_grid(model.encoding.grid.detach(), model.warp(pts)).double()
    class_sigmas = torch.exp(raw[:, :n_density] + config.density_bias)
    torch.testing.assert_close(sigmas.double(), class_sigmas.sum(-1), rtol=1e-5, atol=0)
    torch.testing.assert_close(rgbs.double(), torch.sigmoid(raw[:, n_density : n_density + 3]), rtol=1e-5, atol=1e-6)
    expected = raw[:, :n_density] if class_head == "density" else raw[:, n_density + 3 :]
    torch.testing.assert_close(logits.double(), expected, rtol=1e-5, atol=1e-6)


def test_voxels_preset_is_a_direct_dense_grid():
    config = preset("voxels").field
    assert (config.encoding, config.head) == ("dense", "direct")
    with pytest.raises(ConfigError, match="dense"):
        FieldConfig(encoding="triplane", head="direct")
    with pytest.raises(ConfigError, match="view_dependent"):
        FieldConfig(encoding="dense", head="direct")
    with pytest.raises(ConfigError, match="head"):
        FieldConfig(head="kan")


def reference_live_sigmoid_grad(x: float, live: float) -> float:
    """d sigmoid / dx at x clamped to [-live, live] (live 0: unclamped), in float64."""
    z = x if live <= 0 else min(max(x, -live), live)
    e = np.exp(-abs(np.float64(z)))  # the logistic function in the form that cannot overflow (z = -1e4)
    s = 1.0 / (1.0 + e) if z >= 0 else e / (1.0 + e)
    return float(s * (1.0 - s))


@pytest.mark.parametrize("live", [0.0, 4.0, 10.0])
def test_live_sigmoid_is_the_sigmoid_forward_and_keeps_its_slope_beyond_live(live):
    xs = [-1e4, -60.0, -20.0, -4.5, -1.0, 0.0, 0.3, 3.9, 20.0, 1e4]
    x = torch.tensor(xs, dtype=torch.float64, requires_grad=True)
    y = live_sigmoid(x, live)
    assert torch.equal(y, torch.sigmoid(x))
    y.sum().backward()
    assert torch.isfinite(x.grad).all()
    for xi, gi in zip(xs, x.grad.tolist()):
        assert gi == pytest.approx(reference_live_sigmoid_grad(xi, live), rel=1e-12, abs=1e-300)
    if live > 0:  # deep logits still learn: the slope at ±live, not 0
        assert float(x.grad[0]) == pytest.approx(float(x.grad[-1])) and float(x.grad[0]) > 0


def test_colour_live_logit_reaches_the_colour_and_is_checked():
    net = FieldNetwork(FieldConfig(colour_live_logit=4.0), 3, AABB)
    with torch.no_grad():  # a colour layer driven deep: every logit about -25
        net.rgb_head[2].weight.zero_()
        net.rgb_head[2].bias.fill_(-25.0)
    points, dirs = torch.rand(64, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    rgb = net(points, dirs)[1]
    rgb.sum().backward()
    plain = torch.sigmoid(torch.tensor(-25.0))
    assert torch.allclose(rgb, plain.expand_as(rgb))  # the forward is the sigmoid's
    assert float(net.rgb_head[2].bias.grad.min()) > 64 * 0.9 * float(torch.sigmoid(torch.tensor(4.0)) * torch.sigmoid(torch.tensor(-4.0)))
    for bad in (-1.0, float("nan"), float("inf"), True):
        with pytest.raises(ConfigError, match="colour_live_logit"):
            FieldConfig(colour_live_logit=bad)
