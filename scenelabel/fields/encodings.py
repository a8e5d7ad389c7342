"""Spatial encodings: points in the unit box [-1, 1]^3 -> feature vectors.

``TriPlane`` (the default; measured ≈ 0.45-0.5M points/s fwd+bwd+Adam on 2 CPU cores in
shared/DESIGN.md) and ``DenseGrid`` (channels-last, read in compiled loops on the CPU; the
``voxels`` preset's whole field) are explicit, fast to fit; ``Positional`` is the original NeRF
frequency encoding, kept for the paper preset.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["TriPlane", "cubic_plane_vertices", "DenseGrid", "trilinear_from_grid", "Positional", "sh_directions"]

PLANE_AXES = ((0, 1), (0, 2), (1, 2))
"""The tri-plane's planes: xy, xz, yz (grid_sample's (x, y) = (first, second) axis)."""


def cubic_plane_vertices(resolution: int, extent: tuple[float, float, float]) -> tuple[int, int, int]:
    """Vertices per axis of a tri-plane level whose cells are cubes: as many features as three
    planes of ``resolution`` x ``resolution`` vertices, laid out over a box of sides ``extent``.

    The cell's side s solves (ab + ac + bc) / s^2 = 3 (resolution - 1)^2 for the box's sides a, b, c
    (a cube's: s = a / (resolution - 1), the square level's cell); each axis gets round(side / s)
    cells, at least one. A box three times longer than wide then has cells of one size along each
    axis, where square planes stretch theirs with the box's sides (coarser along the longest).
    """
    sides = np.asarray(extent, dtype=np.float64)
    if sides.shape != (3,) or not np.all(np.isfinite(sides)) or not np.all(sides > 0):
        raise ValueError(f"extent must be three positive finite lengths, got {extent!r}")
    a, b, c = sides
    cell = np.sqrt((a * b + a * c + b * c) / 3.0) / (resolution - 1)
    return tuple(int(max(np.rint(side / cell), 1)) + 1 for side in sides)


class TriPlane(nn.Module):
    """Multi-resolution tri-plane: bilinear features from three axis-aligned planes per level.

    Features of all planes and levels are concatenated (3 * channels * len(resolutions)). Without
    ``extent`` each level's planes are ``r`` x ``r`` vertices over the unit box (cells stretched
    with the box's sides); with the box's sides as ``extent`` they are shaped by
    :func:`cubic_plane_vertices` (cubic cells, the same number of features), stored as one
    [channels, second axis, first axis] plane each.
    """

    def __init__(
        self,
        resolutions: tuple[int, ...] = (64, 128),
        channels: int = 16,
        init_std: float = 0.1,
        extent: tuple[float, float, float] | None = None,
    ):
        super().__init__()
        self.square = extent is None
        if self.square:
            shapes = [(3, channels, r, r) for r in resolutions]
        else:
            levels = [cubic_plane_vertices(r, extent) for r in resolutions]
            shapes = [(channels, v[j], v[i]) for v in levels for i, j in PLANE_AXES]
        self.planes = nn.ParameterList(nn.Parameter(init_std * torch.randn(shape)) for shape in shapes)
        self.out_dim = 3 * channels * len(resolutions)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [n, 3] in [-1, 1] -> [n, out_dim]."""
        n = x.shape[0]
        coords = torch.stack([x[:, list(axes)] for axes in PLANE_AXES])  # [3, n, 2]
        coords = coords[:, None]  # [3, 1, n, 2]
        if self.square:
            feats = [_bilinear(planes, coords) for planes in self.planes]  # each [3, C, 1, n]
        else:
            feats = [_bilinear(plane[None], coords[k % 3][None]) for k, plane in enumerate(self.planes)]  # [1, C, 1, n]
        # a transposed view, not copied: the linear layers read it as it is
        return torch.cat([f.reshape(f.shape[0] * f.shape[1], n) for f in feats]).T


def _bilinear(planes: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """planes [B, C, H, W] at coords [B, 1, n, 2] in [-1, 1] (x along W) -> [B, C, 1, n]."""
    return F.grid_sample(planes, coords, mode="bilinear", padding_mode="border", align_corners=True)


class _TrilinearCPU(torch.autograd.Function):
    """grid [X, Y, Z, C] trilinear at vertex-index coordinates [n, 3] -> [n, C], in compiled loops
    (scenelabel.render.lattice_kernels); the backward scatters into a dense gradient of the grid (none
    for the coordinates)."""

    @staticmethod
    def forward(ctx, grid: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        from scenelabel.render import lattice_kernels as kernels

        values, points = grid.detach().contiguous().numpy(), index.detach().contiguous().numpy()
        out = np.empty((len(points), values.shape[3]), np.float32)

        def run(rows: slice) -> None:
            kernels.trilinear_kernel(values, _INDEX_FRAME, points[rows], out[rows])

        kernels.in_threads(run, len(points))
        ctx.save_for_backward(index)
        ctx.grid_shape = tuple(grid.shape)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        from scenelabel.render import lattice_kernels as kernels

        (index,) = ctx.saved_tensors
        grad = np.zeros(ctx.grid_shape, np.float32)
        kernels.scatter_kernel(grad_out.contiguous().numpy(), _INDEX_FRAME, index.numpy(), grad)
        return torch.from_numpy(grad), None


_INDEX_FRAME = np.array([0.0, 0.0, 0.0, 1.0])
"""The kernels' lattice placement for coordinates already in vertex units (corner 0, spacing 1)."""


def trilinear_from_grid(grid: torch.Tensor, unit: torch.Tensor) -> torch.Tensor:
    """Trilinear interpolation of a vertex grid over the cube [-1, 1]^3.

    Vertex ``[i, j, k]`` of grid [X, Y, Z, C] sits at ``-1 + 2 (i, j, k) / (X - 1, Y - 1, Z - 1)``;
    points outside the cube read its border (they are clamped onto it, grid_sample's "border").
    On the CPU compiled loops (forward over the cores, backward serial into a dense gradient of
    ``grid``; the points get no gradient); elsewhere, or when ``unit`` needs a gradient,
    :func:`torch.nn.functional.grid_sample`, which gives the same values.

    Args:
        grid: [X, Y, Z, C], X, Y, Z >= 2.
        unit: [n, 3] points.
    Returns:
        [n, C].
    """
    if grid.device.type == "cpu" and grid.dtype == torch.float32 and not unit.requires_grad:
        top = torch.tensor(grid.shape[:3], dtype=unit.dtype) - 1
        index = (unit.detach().clamp(-1.0, 1.0) + 1.0) * 0.5 * top
        return _TrilinearCPU.apply(grid, index)
    # grid_sample reads [N, C, D, H, W] at (x, y, z) = (W, H, D): the grid as [1, C, Z, Y, X]
    volume = grid.permute(3, 2, 1, 0)[None]
    out = F.grid_sample(volume, unit.reshape(1, 1, 1, -1, 3), mode="bilinear", padding_mode="border", align_corners=True)
    return out.reshape(grid.shape[3], -1).T


class DenseGrid(nn.Module):
    """A dense vertex grid [X, Y, Z, C] over [-1, 1]^3 sampled trilinearly (:func:`trilinear_from_grid`)."""

    def __init__(self, shape: tuple[int, int, int], channels: int = 8, init_std: float = 0.1):
        super().__init__()
        self.grid = nn.Parameter(init_std * torch.randn(*shape, channels))
        self.out_dim = channels

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [n, 3] in [-1, 1] -> [n, channels]."""
        return trilinear_from_grid(self.grid, x)


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
