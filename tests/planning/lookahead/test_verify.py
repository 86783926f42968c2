"""verify: the arc fluctuation of a step is measured beyond the arc-length arithmetic's own
resolution, so the last nanometre steps of a long curve coming to rest are not failures."""

from __future__ import annotations

import numpy as np

from nurbsmotion.planning.lookahead.path import BlockPiece, build_grid
from nurbsmotion.planning.lookahead.sampling import Samples, sample_path
from nurbsmotion.planning.lookahead.verify import FLUCTUATION_LIMIT, MachineLimits, check

LIMITS = MachineLimits(0.001, 0.01, 2500.0, 50000.0, None, None)


def end_of_wang(wang_curve, last_step_mm: float, residual_before_end_mm: float):
    """The check of four set-points at the end of Wang's curve (~1028 mm), the last step
    ``last_step_mm`` long, with the given arc-length residual on the set-point before the end."""
    grid = build_grid((BlockPiece(0, wang_curve, wang_curve.u_min, wang_curve.u_max, 200.0),), 0.4)
    length = grid.length_mm
    s = np.array([length - 0.4, length - 0.2, length - last_step_mm, length])
    samples = sample_path(grid, s)
    residual = np.array([0.0, 0.0, residual_before_end_mm, 0.0])
    samples = Samples(samples.piece, samples.u, samples.position_mm, residual)
    planned = np.diff(np.concatenate([[s[0] - 0.2], s]))
    before = np.repeat(samples.position_mm[:1], 3, axis=0)
    after = np.repeat(samples.position_mm[-1:], 3, axis=0)
    return check(grid, samples, s, planned, LIMITS, before, after, None)


def test_a_rounding_level_residual_on_a_nanometre_step_at_the_end_of_a_long_curve_passes(wang_curve):
    # what the planner met at the end of Wang's curve (T = 1 ms, J = 2e4): a 3 nm last step and
    # 4e-12 mm left in the residual before it (17 roundings of s): 1.3e-6 of the step, which no
    # arithmetic on s ~ 1028 mm resolves; it threw the whole curve onto the slower-feed fallback
    result = end_of_wang(wang_curve, 3e-6, 4e-12)
    assert "fluctuation" not in result.violations()
    assert result.arc_fluctuation[-1] == 0.0


def test_a_residual_beyond_the_arithmetic_is_still_a_fluctuation(wang_curve):
    # 1e-10 mm on the same 3 nm step: 30 x the step's 1e-6 and far above the rounding of s
    result = end_of_wang(wang_curve, 3e-6, 1e-10)
    assert list(result.violations()["fluctuation"]) == [3]
    # and on a 0.1 mm step, 2e-6 of it
    result = end_of_wang(wang_curve, 0.1, 2e-7)
    assert list(result.violations()["fluctuation"]) == [2, 3]
    assert result.arc_fluctuation[3] > FLUCTUATION_LIMIT
