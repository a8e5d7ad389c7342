"""scenelabel.geometry.bin_agreement: Σ count² / n² over bins, against a dictionary count."""

from __future__ import annotations

import numpy as np

from scenelabel.geometry.bin_agreement import bin_spreads, squares_by_counting, squares_by_sorting


def _squares_reference(cells: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """[m] Σ count² over the bins of each row's valid entries: a float64 dictionary count."""
    out = np.zeros(len(valid))
    for row in range(len(valid)):
        counts: dict[tuple, int] = {}
        for c in cells[row][valid[row]]:
            counts[tuple(c)] = counts.get(tuple(c), 0) + 1
        out[row] = float(sum(c * c for c in counts.values()))
    return out


def test_spreads_match_a_naive_count_in_1d_and_2d():
    """Σ count² / v² per row over its valid entries against a dictionary count, for points binned
    in 1D and 2D; a row without valid entries gives 0, one whose entries share a bin 1."""
    rng = np.random.default_rng(1)
    points = rng.normal(0.0, 0.3, (3, 500, 2))
    valid = rng.random((3, 500)) < 0.7
    valid[2] = False
    for k in (1, 2):
        cells = np.floor(points[..., :k] / 0.05).astype(np.int64)
        v = valid.sum(axis=1)
        expected = np.where(v > 0, _squares_reference(cells, valid) / np.maximum(v, 1) ** 2, 0.0)
        np.testing.assert_array_equal(bin_spreads(cells, valid), expected)
    for k in (1, 2):
        assert bin_spreads(np.zeros((1, 7, k), np.int64), np.ones((1, 7), bool))[0] == 1.0


def test_spreads_count_and_sort_alike():
    """1D bins are counted in an array where their span is small and sorted where a few lie far
    away (grazing rays): both give the dictionary's exact Σ count², so the choice changes nothing."""
    rng = np.random.default_rng(2)
    cells = rng.integers(-40, 40, (5, 300, 1))
    valid = rng.random((5, 300)) < 0.8
    valid[4] = False
    counted, sorted_ = squares_by_counting(cells, valid), squares_by_sorting(cells, valid)
    np.testing.assert_array_equal(counted, _squares_reference(cells, valid))
    np.testing.assert_array_equal(sorted_, counted)
    far = cells.copy()
    far[0, 0, 0] = 1 << 30  # one cut a long way off: counting would need an array of 2^30 bins
    assert valid[0, 0] and squares_by_counting(far, valid) is None
    np.testing.assert_array_equal(squares_by_sorting(far, valid), _squares_reference(far, valid))
