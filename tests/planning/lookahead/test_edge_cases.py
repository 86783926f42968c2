"""Programs at the edges: a 0.1 um move, a reversal, a full circle, many short zigzags."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import arc_curve
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.planning.measure import measure
from tests.planning.lookahead.conftest import WANG_LIMITS, assert_within_limits, polyline, single_block

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
    assert_within_limits(measure(trajectory, program), limits)
    assert trajectory.duration_s < 5.0  # a short program is not planned as a crawl
