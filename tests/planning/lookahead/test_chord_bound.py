"""The chord-error bound is tight where chord error limits the speed (issue 17, deliverable 4).

A step of length v T on curvature kappa deviates kappa (v T)^2 / 8 from its chord and
kappa v^2 <= A, so within the acceleration limit no plan exceeds A T^2 / 8 (0.31 um at
A = 2500 mm/s^2, T = 1 ms) whatever the allowed chord error: chord error can only limit the
speed where delta < A T^2 / 8. There the plan must use most of delta (target >= 0.8), as
measured on the true curve by planning.measure (the independent ruler), and never exceed it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.program import parse_gcode, read_program

from .conftest import EXAMPLES, TOLERANCE, measure_planned

BUTTERFLY = Path(__file__).resolve().parents[2] / "data" / "gcode" / "linuxcnc_nurbs_G5_butterfly-xy.ngc"
USED_AT_LEAST = 0.8


def program(name: str):
    if name == "butterfly":
        return parse_gcode(BUTTERFLY.read_text(), BUTTERFLY.name)
    return read_program(EXAMPLES / "wang_table1.nc")


@pytest.mark.parametrize("jerk", [None, 50000.0])
@pytest.mark.parametrize("period_s, chord_mm", [(0.004, 0.001), (0.001, 0.0001)])
@pytest.mark.parametrize("name", ["wang", "butterfly"])
def test_the_plan_uses_most_of_the_chord_error_where_it_limits_the_speed(name, period_s, chord_mm, jerk):
    accel = 2500.0
    assert chord_mm < accel * period_s**2 / 8.0  # chord error, not acceleration, can limit here
    limits = PlanLimits(period_s=period_s, chord_error_mm=chord_mm, max_accel_mm_s2=accel, feed_mm_s=200.0,
                        max_jerk_mm_s3=jerk)
    trajectory = plan_lookahead(program(name), limits)
    measured = measure_planned(trajectory, program(name), limits).max_chord_error_mm
    verified = trajectory.notes["verified_max_chord_error_mm"]
    assert USED_AT_LEAST * chord_mm <= measured <= verified * (1 + 1e-6)
    assert verified <= chord_mm * (1 + TOLERANCE)
