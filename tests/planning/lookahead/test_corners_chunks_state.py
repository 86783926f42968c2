"""Corners, chunked planning and re-planning from a moving state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.planning import Trajectory
from nurbsmotion.planning.lookahead import PlanState, plan_from_state, plan_lookahead, plan_lookahead_chunks
from nurbsmotion.planning.measure import measure
from tests.planning.lookahead.conftest import WANG_LIMITS, assert_within_limits, polyline

NO_JERK = replace(WANG_LIMITS, max_jerk_mm_s3=None)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_right_angle_corner_is_an_exact_stop(limits):
    """Two lines at 90 deg: the corner is a set-point, held for one cycle (speed 0 there)."""
    program = polyline([(0, 0, 0), (50, 0, 0), (50, 50, 0)])
    trajectory = plan_lookahead(program, limits)
    at_corner = np.flatnonzero(np.all(trajectory.position_mm == [50.0, 0.0, 0.0], axis=1))
    assert len(at_corner) == 2 and at_corner[1] == at_corner[0] + 1
    assert_within_limits(measure(trajectory, program), limits)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_shallow_corner_is_passed_moving_within_limits(limits):
    """A 3 deg kink is passed without stopping, and every cycle still holds every limit."""
    angle = np.radians(3.0)
    program = polyline([(0, 0, 0), (50, 0, 0), (50 + 50 * np.cos(angle), 50 * np.sin(angle), 0)])
    trajectory = plan_lookahead(program, limits)
    m = measure(trajectory, program)
    near = np.argmin(np.linalg.norm(trajectory.position_mm - [50.0, 0.0, 0.0], axis=1))
    assert m.speed_mm_s[near] > 1.0
    assert_within_limits(m, limits)


def test_chunks_hold_the_limits_across_their_joins(wang_program):
    chunks = list(plan_lookahead_chunks(wang_program, WANG_LIMITS, chunk_cycles=150))
    assert len(chunks) >= 3
    trajectory = Trajectory.concatenate(chunks)
    assert_within_limits(measure(trajectory, wang_program), WANG_LIMITS)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_replanning_from_a_moving_state_with_a_lower_feed(wang_program, limits):
    """Feed override: re-plan at 120 mm/s from the state at set-point 300 of the 200 mm/s plan;
    the old set-points up to the state followed by the new ones hold every limit."""
    curve = wang_program.blocks[0].curve
    first = plan_lookahead(wang_program, limits)
    s = np.asarray(curve.arc_length(first.u))
    i, period = 300, limits.period_s
    state = PlanState(s[i], (s[i + 1] - s[i - 1]) / (2 * period), (s[i + 1] - 2 * s[i] + s[i - 1]) / period**2)
    rest = Trajectory.concatenate(list(plan_from_state(wang_program, replace(limits, feed_mm_s=120.0), state)))
    head = Trajectory(first.algorithm, period, first.block[: i + 1], first.u[: i + 1], first.position_mm[: i + 1],
                      first.feed_mm_s[: i + 1])
    joined = Trajectory.concatenate([head, rest])
    assert_within_limits(measure(joined, wang_program), limits)
    assert np.linalg.norm(rest.position_mm[0] - first.position_mm[i]) <= state.v_mm_s * period * 1.1
    late = rest.feed_mm_s[len(rest) // 2:]
    assert late.max() <= 120.0 * (1 + 1e-9)
