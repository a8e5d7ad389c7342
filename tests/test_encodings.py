"""scenelabel.fields.encodings: the dense grid's trilinear interpolation (compiled loops on the
CPU, grid_sample elsewhere) against a float64 loop, its gradient against grid_sample's; the
tri-plane's features (square and cubic cells) against a float64 bilinear loop."""

import itertools

import numpy as np
import pytest
import torch

from scenelabel.fields.encodings import PLANE_AXES, DenseGrid, TriPlane, cubic_plane_vertices, trilinear_from_grid
from scenelabel.fields.model import dense_grid_shape
from scenelabel.geometry.warps import BoxWarp, ForwardWarp

SHAPES = [(2, 2, 2, 1), (5, 4, 3, 2), (9, 7, 6, 5)]


def naive_trilinear(grid: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """float64 loop: points clamped onto the cube, vertex (i, j, k) at -1 + 2 (i, j, k) / (shape - 1)."""
    grid = grid.astype(np.float64)
    top = np.array(grid.shape[:3]) - 1
    out = np.zeros((len(unit), grid.shape[3]))
    for n, p in enumerate(unit.astype(np.float64)):
        f = (np.clip(p, -1.0, 1.0) + 1.0) * 0.5 * top
        i0 = np.minimum(np.floor(f).astype(int), top - 1)
        t = f - i0
        for corner in itertools.product((0, 1), repeat=3):
            w = np.prod([t[a] if corner[a] else 1.0 - t[a] for a in range(3)])
            out[n] += w * grid[i0[0] + corner[0], i0[1] + corner[1], i0[2] + corner[2]]
    return out


def _points(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    unit = torch.rand(n, 3, generator=g) * 2.4 - 1.2  # some outside the cube: clamped onto its border
    corners = torch.tensor(list(itertools.product((-1.0, 1.0), repeat=3)))  # exactly on vertices
    return torch.cat([unit, corners])


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("needs_grad", [False, True], ids=["compiled", "grid_sample"])
def test_trilinear_matches_a_float64_loop(shape, needs_grad):
    torch.manual_seed(0)
    grid = torch.randn(*shape)
    unit = _points(300, 1).requires_grad_(needs_grad)  # points needing a gradient take grid_sample
    out = trilinear_from_grid(grid, unit)
    assert out.shape == (len(unit), shape[3]) and out.dtype == torch.float32
    np.testing.assert_allclose(out.detach().numpy(), naive_trilinear(grid.numpy(), unit.detach().numpy()), atol=2e-6)


@pytest.mark.parametrize("shape", SHAPES)
def test_trilinear_gradient_matches_grid_sample(shape):
    """The compiled backward (a scatter into the grid's gradient) is grid_sample's."""
    torch.manual_seed(2)
    values = torch.randn(*shape)
    unit = _points(500, 3)
    weights = torch.randn(len(unit), shape[3])
    grads = []
    for needs_grad in (False, True):
        grid = values.clone().requires_grad_(True)
        (trilinear_from_grid(grid, unit.clone().requires_grad_(needs_grad)) * weights).sum().backward()
        grads.append(grid.grad)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-5, atol=1e-5)


def test_trilinear_is_finite_at_extreme_values():
    grid = torch.tensor([-3e38, 3e38, 0.0, 1e-38]).repeat(8).reshape(2, 2, 2, 4)
    unit = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1e30, -1e30, 0.5]])
    out = trilinear_from_grid(grid, unit)
    assert torch.isfinite(out).all()
    torch.testing.assert_close(out, grid[0, 0, 0].expand(4, 4))  # every vertex holds the same channels


def test_dense_grid_module_reads_its_parameter():
    enc = DenseGrid((3, 4, 5), channels=2)
    assert enc.grid.shape == (3, 4, 5, 2) and enc.out_dim == 2
    unit = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    torch.testing.assert_close(enc(unit), torch.stack([enc.grid[0, 0, 0], enc.grid[-1, -1, -1]]).detach())


def test_dense_grid_shape_follows_the_warp():
    box = BoxWarp(torch.tensor([[0.0, 0.0, 0.0], [4.0, 2.0, 1.0]]))
    assert dense_grid_shape(box, 64) == (65, 33, 17)  # cells in proportion to the box's sides
    assert dense_grid_shape(BoxWarp(torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1e-6]])), 8) == (9, 9, 2)
    fwd = ForwardWarp(np.zeros(3), np.eye(3), [0.5, 0.375], 1.0, 10.0)  # a 4:3 reference view
    assert dense_grid_shape(fwd, 256) == (257, 193, 129)  # disparity: half the longer image side


def naive_bilinear(plane: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """float64 loop: plane [C, H, W], points (u along W, v along H) clamped onto [-1, 1]^2, vertex
    (i, j) at -1 + 2 (i, j) / (W - 1, H - 1) -> [n, C]."""
    plane = plane.astype(np.float64)
    top = np.array([plane.shape[2], plane.shape[1]]) - 1
    out = np.zeros((len(uv), plane.shape[0]))
    for n, p in enumerate(uv.astype(np.float64)):
        f = (np.clip(p, -1.0, 1.0) + 1.0) * 0.5 * top
        i0 = np.minimum(np.floor(f).astype(int), np.maximum(top - 1, 0))
        t = f - i0
        for du, dv in itertools.product((0, 1), repeat=2):
            w = (t[0] if du else 1.0 - t[0]) * (t[1] if dv else 1.0 - t[1])
            if w:
                out[n] += w * plane[:, i0[1] + dv, i0[0] + du]
    return out


@pytest.mark.parametrize("extent", [None, (3.0, 1.0, 0.5), (1.0, 1.0, 1.0)], ids=["square", "long-box", "cube"])
def test_triplane_matches_a_float64_loop(extent):
    """Features are the planes' bilinear reads, level by level and plane by plane (xy, xz, yz)."""
    torch.manual_seed(4)
    enc = TriPlane((5, 9), channels=3, extent=extent)
    unit = _points(200, 5)
    out = enc(unit).detach().numpy()
    assert out.shape == (len(unit), enc.out_dim) == (len(unit), 3 * 3 * 2)
    planes = [p.detach().numpy() for p in enc.planes]
    if extent is None:  # one [3, C, r, r] tensor per level
        planes = [level[k] for level in planes for k in range(3)]
    expected = [naive_bilinear(plane, unit.numpy()[:, list(PLANE_AXES[k % 3])]) for k, plane in enumerate(planes)]
    np.testing.assert_allclose(out, np.concatenate(expected, axis=1), atol=2e-6)


def test_cubic_plane_vertices_make_cubic_cells_of_the_square_levels_features():
    assert cubic_plane_vertices(256, (2.0, 2.0, 2.0)) == (256, 256, 256)  # a cube: the square level
    for extent in [(12.0, 8.0, 5.2), (10.0, 1.0, 1.0), (1e-3, 2e-3, 5e-4), (1e4, 3e3, 2e3)]:
        vertices = np.array(cubic_plane_vertices(128, extent))
        cells = np.asarray(extent) / (vertices - 1)
        np.testing.assert_allclose(cells, cells.mean(), rtol=0.02)  # one cell size on every axis
        features = vertices[0] * vertices[1] + vertices[0] * vertices[2] + vertices[1] * vertices[2]
        assert abs(features / (3 * 128**2) - 1) < 0.03  # the square level's number of features
    thin = cubic_plane_vertices(64, (100.0, 100.0, 1e-6))  # a flat box keeps at least one cell
    assert thin[2] == 2 and thin[0] == thin[1] > 64
    for bad in [(1.0, 0.0, 1.0), (1.0, float("nan"), 1.0), (1.0, 1.0)]:
        with pytest.raises(ValueError, match="three positive finite lengths"):
            cubic_plane_vertices(64, bad)
