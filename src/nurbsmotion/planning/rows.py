"""Row-wise figures of (N, k) arrays of set-points, column by column: numpy's reductions over
a short last axis (k = 3) call their inner loop once per row, several times slower than a
few whole-column operations; the results are the same to the bit (same operations in the
same order: x^2 + y^2 + z^2, then the square root)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def row_norms(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """|a_i| of every row of an (N, k) array, as np.linalg.norm(a, axis=1) computes it."""
    if a.ndim == 2 and a.shape[1] == 3:
        x, y, z = a[:, 0], a[:, 1], a[:, 2]
        return np.sqrt(x * x + y * y + z * z)
    return np.linalg.norm(a, axis=1)


def column_max(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """The largest entry of every column of an (N, k) array (a.max(axis=0)), each column's
    own reduction; -inf for no rows."""
    return np.array([a[:, j].max(initial=-np.inf) for j in range(a.shape[1])])
