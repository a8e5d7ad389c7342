"""Build orchestration helpers: view split, default voxel size."""

import pytest

from scenelabel.errors import InputError
from scenelabel.pipeline import split_views


def test_every_eighth_view_held_out():
    train, test = split_views(20, 8)
    assert test == [0, 8, 16]
    assert sorted(train + test) == list(range(20))


def test_holdout_zero_trains_on_all():
    train, test = split_views(5, 0)
    assert train == list(range(5)) and test == []


def test_too_few_views():
    with pytest.raises(InputError, match="at least 2 views"):
        split_views(1, 8)
    with pytest.raises(InputError, match="no training view"):
        split_views(2, 1)
