"""How well points agree: Σ count² / n² over the bins they fall in (1 when they share one bin,
1 / n when none does), the score :mod:`scenelabel.geometry.layout` searches planes and directions
by. Many rows at once, each over its own valid entries; the counts are exact integers, however
they are made.
"""

from __future__ import annotations

import numpy as np

__all__ = ["COUNTING_SPAN", "bin_spreads", "squares_by_counting", "squares_by_sorting"]


def bin_spreads(cells: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """[m]: per row of ``cells`` [m, n, k] (integer bin coordinates, k <= 2, each below 2^30 in
    size), Σ count² / v² over the bins of its ``valid`` [m, n] entries (v of them): 1 when they
    all share one bin, 1 / v when none does, 0 when v = 0. The counts are exact integers either
    way they are made (:func:`squares_by_counting`, :func:`squares_by_sorting`), so the result
    does not depend on which."""
    v = valid.sum(axis=1)
    squares = squares_by_counting(cells, valid) if cells.shape[-1] == 1 else None
    if squares is None:
        squares = squares_by_sorting(cells, valid)
    return np.where(v > 0, squares / np.maximum(v, 1) ** 2, 0.0)


def squares_by_sorting(cells: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """[m] Σ count² over the bins of each row's valid entries (float64, exact), from each row's
    keys sorted: a bin's entries make one run."""
    m, n = valid.shape
    key = cells[..., 0] if cells.shape[-1] == 1 else cells[..., 0] * (1 << 32) + cells[..., 1]
    key = np.sort(np.where(valid, key, np.iinfo(np.int64).max - np.arange(n)), axis=1)  # invalid: alone
    starts = np.ones((m, n), bool)
    starts[:, 1:] = key[:, 1:] != key[:, :-1]
    first = np.flatnonzero(starts)  # every row starts a run at its first entry: no run spans two rows
    runs = np.diff(np.append(first, m * n)).astype(np.float64)
    squares = np.bincount(first // n, weights=runs**2, minlength=m)
    return squares - (n - valid.sum(axis=1))  # each invalid entry was a run of one


COUNTING_SPAN = 4
"""1D bins are counted in an array (:func:`squares_by_counting`) where the rows' bins span at most
this many times their entries; sorted otherwise (a few cuts far away on grazing rays)."""


def squares_by_counting(cells: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
    """[m] Σ count² over the 1D bins (``cells`` [m, n, 1]) of each row's valid entries (float64,
    exact), counted in one array over every row's span of bins; None where those spans add up to
    more than :data:`COUNTING_SPAN` times the entries (sorting is then cheaper)."""
    m, n = valid.shape
    key = cells[..., 0]
    some = valid.any(axis=1)  # a row without valid entries gets one empty bin at 0
    lo = np.where(some, np.where(valid, key, np.iinfo(np.int64).max).min(axis=1), 0)
    hi = np.where(some, np.where(valid, key, np.iinfo(np.int64).min).max(axis=1), 0)
    span = hi - lo + 1
    if span.sum() > COUNTING_SPAN * m * n + 1024:
        return None
    offsets = np.concatenate([[0], np.cumsum(span)[:-1]])
    counts = np.bincount((key - lo[:, None] + offsets[:, None])[valid], minlength=int(span.sum()))
    return np.add.reduceat(counts**2, offsets).astype(np.float64)
