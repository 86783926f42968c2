"""sampling: the quintic Hermite first guess of u(s) from the grid's per-interval coefficients."""

from __future__ import annotations

import numpy as np

from nurbsmotion.planning.lookahead.path import BlockPiece, build_grid
from nurbsmotion.planning.lookahead.sampling import hermite_u


def hermite_by_basis(grid, k, s):
    """The quintic Hermite of u(s) from its six basis functions (the textbook form)."""
    h = grid.s[k + 1] - grid.s[k]
    r = np.clip((s - grid.s[k]) / h, 0.0, 1.0)
    h00 = 1 - 10 * r**3 + 15 * r**4 - 6 * r**5
    h10 = r - 6 * r**3 + 8 * r**4 - 3 * r**5
    h20 = 0.5 * (r**2 - 3 * r**3 + 3 * r**4 - r**5)
    h01 = 10 * r**3 - 15 * r**4 + 6 * r**5
    h11 = -4 * r**3 + 7 * r**4 - 3 * r**5
    h21 = 0.5 * (r**3 - 2 * r**4 + r**5)
    return (h00 * grid.u[k] + h10 * h * grid.u_s[k] + h20 * h**2 * grid.u_ss[k]
            + h01 * grid.u[k + 1] + h11 * h * grid.u_s[k + 1] + h21 * h**2 * grid.u_ss_left[k + 1])


def test_hermite_u_is_the_quintic_and_exact_at_the_grid_points(wang_curve):
    grid = build_grid((BlockPiece(0, wang_curve, wang_curve.u_min, wang_curve.u_max, 200.0),), 0.4)
    rng = np.random.default_rng(7)
    k = rng.integers(0, len(grid) - 1, 5000)
    s = grid.s[k] + rng.uniform(0.0, 1.0, len(k)) * (grid.s[k + 1] - grid.s[k])
    np.testing.assert_allclose(hermite_u(grid, k, s), hermite_by_basis(grid, k, s), rtol=0.0, atol=1e-13)
    every = np.arange(len(grid) - 1)
    assert np.array_equal(hermite_u(grid, every, grid.s[:-1]), grid.u[:-1])
    assert np.array_equal(hermite_u(grid, every, grid.s[1:]), grid.u[1:])  # the end, exactly (the exact end)
