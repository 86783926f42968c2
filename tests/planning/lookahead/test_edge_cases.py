"""Programs at the edges: a 0.1 um move, a reversal, a full circle, many short zigzags."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import arc_curve
from nurbsmotion.planning.lookahead import plan_lookahead
from tests.planning.lookahead.conftest import measure_planned, WANG_LIMITS, assert_within_limits, polyline, single_block

PROGRAMS = {
    "0.1 um line": lambda: polyline([(0, 0, 0), (1e-4, 0, 0)]),
    "reversal": lambda: polyline([(0, 0, 0), (10, 0, 0), (0, 0, 0)]),
    "full circle": lambda: single_block(arc_curve((10, 0, 0), (0, 0, 0), 2 * np.pi)),
    "zigzag": lambda: polyline([(i, (i % 2) * 0.5, 0) for i in range(12)]),
}


@pytest.mark.parametrize("name", PROGRAMS)
@pytest.mark.parametrize("limits", [WANG_LIMITS, replace(WANG_LIMITS, max_jerk_mm_s3=None),
                                    replace(WANG_LIMITS, period_s=0.001)], ids=["jerk", "no-jerk", "1ms"])
def test_edge_program_holds_every_limit(name, limits):
    program = PROGRAMS[name]()
    trajectory = plan_lookahead(program, limits)
    assert_within_limits(measure_planned(trajectory, program, limits), limits)
    assert trajectory.duration_s < 5.0  # a short program is not planned as a crawl


@pytest.mark.parametrize("axis_v, axis_a", [((150.0, None, None), None), (None, (1500.0, None, 800.0))],
                         ids=["velocity on X only", "acceleration on X and Z"])
def test_limits_on_some_axes_hold_on_those_axes(axis_v, axis_a):
    """A configuration may give max_velocity_mm_s / max_accel_mm_s2 for some axes only
    (limits.axis_limits: None for the others): the given ones hold, the others are free."""
    program = polyline([(0, 0, 0), (50, 0, 0), (50, 50, 0), (0, 50, 10)])
    limits = replace(WANG_LIMITS, axis_max_velocity_mm_s=axis_v, axis_max_accel_mm_s2=axis_a)
    m = measure_planned(plan_lookahead(program, limits), program, limits)
    assert_within_limits(m, limits)
    if axis_v is not None:
        assert m.axis_max_velocity_mm_s[1] > axis_v[0]  # Y is free: it runs faster than X may
