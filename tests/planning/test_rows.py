"""planning.rows: the column-by-column row figures equal numpy's own reductions, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.planning.rows import column_max, row_norms


@pytest.mark.parametrize("columns", [1, 2, 3, 4])
def test_row_norms_and_column_maxima_are_numpys_to_the_bit(columns):
    rng = np.random.default_rng(columns)
    a = rng.normal(0.0, 1.0, (1000, columns)) * 10.0 ** rng.integers(-15, 15, (1000, columns))
    a[:3] = 0.0
    assert np.array_equal(row_norms(a), np.linalg.norm(a, axis=1))
    assert np.array_equal(column_max(a), a.max(axis=0))
    assert np.array_equal(column_max(np.abs(a)), np.abs(a).max(axis=0))
