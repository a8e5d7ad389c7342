"""The semantic radiance field: encoding + heads -> σ, rgb, class logits (a thin nn.Module).

Inputs are points in the *normalised* frame (docs/conventions.md); ``aabb`` is the scene box in
that frame, mapped onto the encoding's unit box. σ is per normalised unit of length.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from scenelabel.config import FieldConfig
from scenelabel.errors import ConfigError
from scenelabel.fields.encodings import DenseGrid, Positional, TriPlane, sh_directions
from scenelabel.geometry.warps import BoxWarp

__all__ = ["FieldNetwork", "build_encoding", "dense_grid_shape", "trunc_exp", "live_sigmoid", "combine_class_densities"]

SH_DIM = 9
TRUNC_EXP_MAX = 15.0
"""trunc_exp's backward clamps its input at this value so that gradients stay finite (exp(15) ≈ 3e6)."""


class _TruncExp(torch.autograd.Function):
    """exp(x) with the gradient of exp(min(x, TRUNC_EXP_MAX)) (instant-ngp's density activation)."""

    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=TRUNC_EXP_MAX))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """exp(x), its gradient computed with x clamped at TRUNC_EXP_MAX."""
    return _TruncExp.apply(x)


class _LiveSigmoid(torch.autograd.Function):
    """sigmoid(x) with the gradient of sigmoid(clamp(x, -live, live))."""

    @staticmethod
    def forward(ctx, x, live):
        ctx.save_for_backward(x)
        ctx.live = live
        return torch.sigmoid(x)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        s = torch.sigmoid(x.clamp(-ctx.live, ctx.live))
        return grad * s * (1.0 - s), None


def live_sigmoid(x: torch.Tensor, live: float) -> torch.Tensor:
    """sigmoid(x), its gradient that of x clamped to [-live, live] (``field.colour_live_logit``;
    ``live`` 0: the plain sigmoid, same gradient), as trunc_exp bounds the density's.

    Why: while the field is still transparent, a rendered pixel is mostly background and every
    sample's colour gradient points the same way; Adam moves each weight by about its learning
    rate whatever the gradient's size, and a channel's logits can dive to -20 in the first
    hundred steps, where the sigmoid's slope (2e-9) no longer lets the channel learn. The field
    then matches the missing channel with the background seen through half-transparent walls.
    Beyond ±``live`` the slope stays that at ``live`` (0.018 at 4), so the photometric loss pulls
    the channel back once surfaces form; the forward value, and the gradient inside [-live, live],
    are the sigmoid's (docs/models.md, docs/suite_colour_live.md).
    """
    if live <= 0:
        return torch.sigmoid(x)
    return _LiveSigmoid.apply(x, float(live))


def dense_grid_shape(warp: nn.Module, resolution: int) -> tuple[int, int, int]:
    """Vertices of a dense grid per cube axis: ``resolution`` cells along the cube's longest axis
    and the others in proportion to the warp's :meth:`cube_extent` (at least 1 cell each)."""
    extent = np.asarray(warp.cube_extent(), dtype=np.float64)
    cells = np.maximum(np.rint(resolution * extent / extent.max()), 1).astype(int)
    return tuple(int(c) + 1 for c in cells)


def build_encoding(config: FieldConfig, warp: nn.Module) -> nn.Module:
    """The encoding ``config`` names; a dense grid, and tri-planes of cubic cells, are shaped by the warp
    (:func:`dense_grid_shape`, :func:`~scenelabel.fields.encodings.cubic_plane_vertices`)."""
    if config.encoding == "triplane":
        extent = warp.cube_extent() if config.plane_cells == "cubic" else None
        return TriPlane(config.resolutions, config.channels, extent=extent)
    if config.encoding == "dense":
        return DenseGrid(dense_grid_shape(warp, config.grid_resolution), config.channels)
    if config.encoding == "positional":
        return Positional(config.pe_frequencies)
    raise ConfigError(f"unknown encoding {config.encoding!r}; choose 'triplane', 'dense' or 'positional'")


class SkipMLP(nn.Sequential):
    """Linear layers with ReLU between them; the input is concatenated again before layer
    ``skip`` (NeRF's skip connection). Layout (state-dict keys) is that of nn.Sequential."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, layers: int, skip: int | None = None):
        mods: list[nn.Module] = []
        for i in range(layers):
            d_in = in_dim if i == 0 else hidden + (in_dim if i == skip else 0)
            mods.append(nn.Linear(d_in, out_dim if i == layers - 1 else hidden))
            if i < layers - 1:
                mods.append(nn.ReLU())
        super().__init__(*mods)
        self.skip = skip

    def forward(self, x: torch.Tensor, n_out: int | None = None) -> torch.Tensor:
        """x [n, in_dim] -> [n, out_dim], or with ``n_out`` only the first n_out outputs [n, n_out]
        (the last layer's other rows are not computed; one row as a per-point dot product: a
        matrix-vector product's last bits change with the batch size, which a map's blocks would
        see). Without autograd (queries, renders, maps)
        the ReLUs work in place: no second [n, hidden] tensor per layer."""
        h, layer, last = x, 0, len(self) - 1
        in_place = not torch.is_grad_enabled()
        for i, mod in enumerate(self):
            if isinstance(mod, nn.Linear):
                if layer == self.skip:
                    h = torch.cat([h, x], -1)
                layer += 1
            if i == last and n_out == 1:  # a dot product per point, the same bits in any batch
                return (h * mod.weight[0]).sum(-1, keepdim=True) + mod.bias[:1]
            if i == last and n_out is not None:
                return F.linear(h, mod.weight[:n_out], mod.bias[:n_out])
            h = torch.relu_(h) if in_place and isinstance(mod, nn.ReLU) else mod(h)
        return h


def combine_class_densities(class_sigmas: torch.Tensor, how: str) -> torch.Tensor:
    """The colour/geometry density σ from per-class densities σ_j (seed paper eq. 4: σ = f(σ_j)).

    Args:
        class_sigmas: [n, C] non-negative.
        how: "sum" (σ = Σ_j σ_j) or "max" (σ = max_j σ_j).
    Returns:
        [n].
    """
    return class_sigmas.sum(-1) if how == "sum" else class_sigmas.amax(-1)


class FieldNetwork(nn.Module):
    """σ, colour and class scores at points (the seed paper's eq. 5 and eq. 6 variants).

    - ``class_head="linear"`` (eq. 6): trunk: features -> hidden -> (σ_raw, h); class: h -> logits.
    - ``class_head="density"`` (eq. 5): the trunk predicts one density per class,
      σ_j = trunc_exp(s_j + density_bias); σ = Σ_j σ_j or max_j σ_j (eq. 4), and the class
      scores are s_j, so softmax(s)_j = σ_j / Σ_k σ_k: each class's share of the density.

    Colour: (h, SH(d) or γ(d)) -> hidden -> rgb in both. The trunk is ``layers`` deep, with
    NeRF's skip connection when ``skip_layer`` is set (:class:`SkipMLP`).

    ``head="direct"`` has no network: a dense grid's channels are the raw densities (1, or C with
    ``class_head="density"``), the colour before its sigmoid (3, view-independent) and, with
    ``class_head="linear"``, the class logits (C), each interpolated trilinearly and activated
    after (Plenoxels, Fridovich-Keil et al. 2022; DVGO's post-activation, Sun et al. 2022).
    """

    def __init__(self, config: FieldConfig, num_classes: int, aabb: torch.Tensor, warp: nn.Module | None = None):
        super().__init__()
        self.config = config
        self.num_classes = num_classes
        self.register_buffer("aabb", aabb.clone().float())
        self.warp = BoxWarp(aabb) if warp is None else warp  # normalised frame -> the encoding's [-1, 1]^3
        self._n_density = num_classes if config.class_head == "density" else 1
        self.direct = config.head == "direct"
        if self.direct:
            n_logits = num_classes if config.class_head == "linear" else 0
            shape = dense_grid_shape(self.warp, config.grid_resolution)
            self.encoding = DenseGrid(shape, self._n_density + 3 + n_logits, init_std=0.0)  # σ = exp(bias), grey
            return
        self.encoding = build_encoding(config, self.warp)
        h = config.hidden
        self.trunk = SkipMLP(self.encoding.out_dim, h, h + self._n_density, config.layers, config.skip_layer)
        self.view_encoding = Positional(config.pe_view_frequencies) if config.view_encoding == "positional" else None
        view_dim = SH_DIM if self.view_encoding is None else self.view_encoding.out_dim
        rgb_in = h + (view_dim if config.view_dependent else 0)
        # the ReLU overwrites the first layer's output (its backward needs only its own output): no second tensor
        self.rgb_head = nn.Sequential(nn.Linear(rgb_in, h), nn.ReLU(inplace=True), nn.Linear(h, 3))
        self.class_head = nn.Linear(h, num_classes) if config.class_head == "linear" else None

    def encoding_parameters(self) -> list[nn.Parameter]:
        return list(self.encoding.parameters())

    def mlp_parameters(self) -> list[nn.Parameter]:
        ids = {id(p) for p in self.encoding.parameters()}
        return [p for p in self.parameters() if id(p) not in ids]

    def features(
        self, points: torch.Tensor, heads_input: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """points [n, 3] -> σ [n], features h [n, F], raw densities [n, 1] (σ's) or [n, C] (σ_j's):
        the trunk, whose h and raw :meth:`heads` turns into colour and class scores (so that a
        renderer can run the heads on only the points whose weight turns out to matter).

        h is the trunk's hidden layer, or with ``head="direct"`` the grid's colour and logit
        channels. With ``heads_input=False`` a network's last layer computes only the density rows and
        h is [n, 0] (a grid reads all its channels either way). Points the warp maps
        outside [-1, 1]^3 (only a forward warp has such points inside the scene box: behind or
        beside its reference frustum) have σ = 0.
        """
        unit = self.warp(points)
        if self.direct:
            out = self.encoding(unit)
        else:
            out = self.trunk(self.encoding(unit), None if heads_input else self._n_density)
        raw, h = out[:, : self._n_density], out[:, self._n_density :]
        if not self.direct:
            h = F.relu(h, inplace=not torch.is_grad_enabled())  # in place: h is out's own columns
        if self.config.class_head == "linear":
            sigmas = trunc_exp(raw[:, 0] + self.config.density_bias)
        else:
            class_sigmas = trunc_exp(raw + self.config.density_bias)  # [n, C]
            sigmas = combine_class_densities(class_sigmas, self.config.density_combine)
        if self.warp.kind != "box":
            sigmas = torch.where((unit.abs() <= 1.0).all(-1), sigmas, torch.zeros_like(sigmas))
        return sigmas, h, raw

    def _class_logits(self, h: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
        if self.config.class_head == "density":
            return raw
        return h[:, 3:] if self.direct else self.class_head(h)

    def density(self, points: torch.Tensor) -> torch.Tensor:
        """points [n, 3] -> σ [n] (no colour or class work)."""
        return self.features(points, heads_input=False)[0]

    def semantics(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points [n, 3] -> σ [n], class_logits [n, C] (no colour work)."""
        sigmas, h, raw = self.features(points)
        return sigmas, self._class_logits(h, raw)

    def heads(
        self, h: torch.Tensor, raw: torch.Tensor, directions: torch.Tensor | None
    ) -> tuple[torch.Tensor | None, torch.Tensor]:
        """:meth:`features`' h [n, F] and raw [n, D] with unit directions [n, 3] -> rgb [n, 3]
        (None when ``directions`` is None: no colour work) and class_logits [n, C]."""
        logits = self._class_logits(h, raw)
        if directions is None:
            return None, logits
        if self.direct:
            return live_sigmoid(h[:, :3], self.config.colour_live_logit), logits
        rgb_in = h
        if self.config.view_dependent:
            views = sh_directions(directions) if self.view_encoding is None else self.view_encoding(directions)
            rgb_in = torch.cat([h, views], -1)
        return live_sigmoid(self.rgb_head(rgb_in), self.config.colour_live_logit), logits

    def forward(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """points [n, 3], unit directions [n, 3] -> σ [n], rgb [n, 3], class_logits [n, C]."""
        sigmas, h, raw = self.features(points)
        rgbs, logits = self.heads(h, raw, directions)
        return sigmas, rgbs, logits
