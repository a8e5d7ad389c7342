"""Spatial encodings: points in the unit box [-1, 1]^3 -> feature vectors.

``TriPlane`` (the default; measured ≈ 0.45-0.5M points/s fwd+bwd+Adam on 2 CPU cores in
shared/DESIGN.md) and ``DenseGrid`` are explicit, fast to fit; ``Positional`` is the original NeRF
frequency encoding, kept for the paper preset.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["TriPlane", "DenseGrid", "Positional", "sh_directions"]

PLANE_AXES = ((0, 1), (0, 2), (1, 2))
"""The tri-plane's planes: xy, xz, yz (grid_sample's (x, y) = (first, second) axis)."""


class TriPlane(nn.Module):
    """Multi-resolution tri-plane: bilinear features from three axis-aligned planes per level.

    Features of all planes and levels are concatenated (3 * channels * len(resolutions)).
    """

    def __init__(self, resolutions: tuple[int, ...] = (64, 128), channels: int = 16, init_std: float = 0.1):
        super().__init__()
        self.planes = nn.ParameterList(
            nn.Parameter(init_std * torch.randn(3, channels, r, r)) for r in resolutions
        )
        self.out_dim = 3 * channels * len(resolutions)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [n, 3] in [-1, 1] -> [n, out_dim]."""
        n = x.shape[0]
        coords = torch.stack([x[:, list(axes)] for axes in PLANE_AXES])  # [3, n, 2]
        coords = coords[:, None]  # [3, 1, n, 2]
        feats = [
            F.grid_sample(planes, coords, mode="bilinear", padding_mode="border", align_corners=True)
            for planes in self.planes
        ]  # each [3, C, 1, n]
        return torch.cat([f.reshape(f.shape[0] * f.shape[1], n) for f in feats]).T.contiguous()


class DenseGrid(nn.Module):
    """A dense [C, R, R, R] voxel grid sampled trilinearly."""

    def __init__(self, resolution: int = 96, channels: int = 8, init_std: float = 0.1):
        super().__init__()
        self.grid = nn.Parameter(init_std * torch.randn(1, channels, resolution, resolution, resolution))
        self.out_dim = channels

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [n, 3] in [-1, 1] -> [n, channels]."""
        # The grid is stored [C, X, Y, Z], i.e. grid_sample's (D, H, W) = (x, y, z); grid_sample's
        # coordinate triple is (W, H, D), so pass (z, y, x).
        coords = x[:, [2, 1, 0]].reshape(1, 1, 1, -1, 3)
        out = F.grid_sample(self.grid, coords, mode="bilinear", padding_mode="border", align_corners=True)
        return out.reshape(self.grid.shape[1], x.shape[0]).T.contiguous()


class Positional(nn.Module):
    """NeRF frequency encoding γ(p) = (p, sin(2^k π p), cos(2^k π p)), k < n_freqs (Mildenhall eq. 4)."""

    def __init__(self, n_freqs: int = 10, in_dim: int = 3, include_input: bool = True):
        super().__init__()
        self.register_buffer("freqs", (2.0 ** torch.arange(n_freqs)) * torch.pi)
        self.include_input = include_input
        self.out_dim = in_dim * (2 * n_freqs + int(include_input))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        xf = (x[..., None] * self.freqs).flatten(-2)  # [n, in_dim * n_freqs]
        parts = [x] if self.include_input else []
        return torch.cat(parts + [torch.sin(xf), torch.cos(xf)], dim=-1)


def sh_directions(d: torch.Tensor) -> torch.Tensor:
    """Real spherical harmonics up to degree 2 of unit directions: [n, 3] -> [n, 9]."""
    x, y, z = d.unbind(-1)
    return torch.stack(
        [
            torch.full_like(x, 0.28209479177387814),
            0.4886025119029199 * y,
            0.4886025119029199 * z,
            0.4886025119029199 * x,
            1.0925484305920792 * x * y,
            1.0925484305920792 * y * z,
            0.31539156525252005 * (3 * z * z - 1),
            1.0925484305920792 * x * z,
            0.5462742152960396 * (x * x - y * y),
        ],
        dim=-1,
    )
