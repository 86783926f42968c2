"""search_sorted: np.searchsorted's results, by a merge when the keys are sorted."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.planning.lookahead.search import MERGE_MIN_KEYS, search_sorted
from nurbsmotion.planning.lookahead.speed_limits import floor_log2


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("seed", range(20))
def test_search_sorted_is_searchsorted(side, seed):
    """Sorted and unsorted keys, with ties against the array and among themselves, keys
    outside its range, duplicates in the array (junctions repeat s), inf and NaN."""
    rng = np.random.default_rng(seed)
    a = np.sort(np.round(rng.uniform(0.0, 100.0, rng.integers(1, 4000)), 1))  # rounding makes ties
    if seed % 3 == 0:
        a = np.concatenate([a, [np.inf, np.inf]])
    keys = np.round(rng.uniform(-10.0, 110.0, rng.integers(0, 3 * MERGE_MIN_KEYS + 8000)), 1)
    keys = np.concatenate([keys, rng.choice(a, 50)])
    if seed % 4 == 1:
        keys = np.concatenate([keys, [np.inf, -np.inf, np.nan]])
    for v in (np.sort(keys), keys):
        assert np.array_equal(search_sorted(a, v, side), np.searchsorted(a, v, side=side))


def test_search_sorted_merges_long_sorted_keys(monkeypatch):
    """The merge path is taken (not only the fallback) for long sorted keys."""
    a = np.linspace(0.0, 1.0, 1000)
    v = np.linspace(-0.5, 1.5, 4 * MERGE_MIN_KEYS)
    monkeypatch.setattr(np, "searchsorted", lambda *args, **kwargs: pytest.fail("fell back to np.searchsorted"))
    left, right = search_sorted(a, v, "left"), search_sorted(a, v, "right")
    monkeypatch.undo()
    assert np.array_equal(left, np.searchsorted(a, v, side="left"))
    assert np.array_equal(right, np.searchsorted(a, v, side="right"))


def test_floor_log2_is_floor_of_log2():
    widths = np.concatenate([np.arange(-3, 5000), [2**20 - 1, 2**20, 2**20 + 1]])
    expected = np.floor(np.log2(np.maximum(widths, 1))).astype(np.intp)
    assert np.array_equal(floor_log2(widths), expected)
