"""Corners, chunked planning and re-planning from a moving state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.planning import Trajectory
from nurbsmotion.errors import InputError
from nurbsmotion.planning.lookahead import (PlanningError, PlanState, plan_from_state, plan_lookahead,
                                            plan_lookahead_chunks, plan_lookahead_resumable)
from nurbsmotion.program import read_program
from tests.planning.lookahead.conftest import measure_planned, planned_arc_lengths, EXAMPLES, WANG_LIMITS, assert_within_limits, polyline

NO_JERK = replace(WANG_LIMITS, max_jerk_mm_s3=None)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_right_angle_corner_is_an_exact_stop(limits):
    """Two lines at 90 deg without corner blending (path tolerance 0): the corner is a
    set-point, held for one cycle (speed 0 there)."""
    limits = replace(limits, path_tolerance_mm=0.0)
    program = polyline([(0, 0, 0), (50, 0, 0), (50, 50, 0)])
    trajectory = plan_lookahead(program, limits)
    at_corner = np.flatnonzero(np.all(trajectory.position_mm == [50.0, 0.0, 0.0], axis=1))
    assert len(at_corner) == 2 and at_corner[1] == at_corner[0] + 1
    assert_within_limits(measure_planned(trajectory, program, limits), limits)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_shallow_corner_is_passed_moving_within_limits(limits):
    """A 3 deg kink is passed without stopping, and every cycle still holds every limit."""
    angle = np.radians(3.0)
    program = polyline([(0, 0, 0), (50, 0, 0), (50 + 50 * np.cos(angle), 50 * np.sin(angle), 0)])
    trajectory = plan_lookahead(program, limits)
    m = measure_planned(trajectory, program, limits)
    near = np.argmin(np.linalg.norm(trajectory.position_mm - [50.0, 0.0, 0.0], axis=1))
    assert m.speed_mm_s[near] > 1.0
    assert_within_limits(m, limits)


def test_chunks_hold_the_limits_across_their_joins(wang_program):
    chunks = list(plan_lookahead_chunks(wang_program, WANG_LIMITS, chunk_cycles=150))
    assert len(chunks) >= 3
    trajectory = Trajectory.concatenate(chunks)
    assert_within_limits(measure_planned(trajectory, wang_program, WANG_LIMITS), WANG_LIMITS)


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
    assert_within_limits(measure_planned(joined, wang_program, limits), limits)
    assert np.linalg.norm(rest.position_mm[0] - first.position_mm[i]) <= state.v_mm_s * period * 1.1
    late = rest.feed_mm_s[len(rest) // 2:]
    assert late.max() <= 120.0 * (1 + 1e-9)


@pytest.fixture(scope="module")
def mixed_plans():
    program = read_program(EXAMPLES / "mixed.nc")
    plans = {}
    for name, limits in (("jerk", WANG_LIMITS), ("no-jerk", NO_JERK)):
        trajectory = plan_lookahead(program, limits)
        plans[name] = (limits, trajectory, planned_arc_lengths(trajectory, program, limits))
    return program, plans


@pytest.mark.parametrize("name", ["jerk", "no-jerk"])
@pytest.mark.parametrize("where", [0.0, 0.4])
def test_replanning_mixed_program_from_states_along_it(mixed_plans, name, where):
    """mixed.nc (lines, arcs, NURBS, stops): re-plan at 150 mm/s from the state of a set-point
    a fraction ``where`` into the plan; old set-points + new ones hold every limit."""
    program, plans = mixed_plans
    limits, first, s = plans[name]
    i, period = max(int(where * len(first)), 1), limits.period_s
    state = PlanState(float(s[i]), (s[i + 1] - s[i - 1]) / (2 * period), (s[i + 1] - 2 * s[i] + s[i - 1]) / period**2)
    rest = Trajectory.concatenate(list(plan_from_state(program, replace(limits, feed_mm_s=150.0), state)))
    head = Trajectory(first.algorithm, period, first.block[: i + 1], first.u[: i + 1], first.position_mm[: i + 1],
                      first.feed_mm_s[: i + 1])
    assert_within_limits(measure_planned(Trajectory.concatenate([head, rest]), program, limits), limits)


def test_replanning_too_close_to_the_end_is_a_clear_error(wang_program):
    first = plan_lookahead(wang_program, WANG_LIMITS)
    s = np.asarray(wang_program.blocks[0].curve.arc_length(first.u))
    i, period = len(first) - 3, WANG_LIMITS.period_s
    state = PlanState(float(s[i]), (s[i + 1] - s[i - 1]) / (2 * period), (s[i + 1] - 2 * s[i] + s[i - 1]) / period**2)
    try:
        rest = Trajectory.concatenate(list(plan_from_state(wang_program, WANG_LIMITS, state)))
    except PlanningError as err:
        assert "re-plan" in str(err) or "cannot hold" in str(err)
    else:
        np.testing.assert_array_equal(rest.position_mm[-1], wang_program.end_position)


@pytest.mark.parametrize("limits", [WANG_LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
@pytest.mark.parametrize("feed_mm_s", [80.0, 250.0])
def test_feed_override_resumes_exactly_at_a_chunk_boundary(mixed_plans, limits, feed_mm_s):
    """Stop consuming a chunked plan after 3 chunks, resume from its Resume with a new feed:
    old chunks + resumed ones hold every limit and end exactly."""
    program = mixed_plans[0]
    chunks = plan_lookahead_resumable(program, limits, chunk_cycles=150)
    head = [next(chunks) for _ in range(3)]
    tail = [chunk for chunk, _ in plan_lookahead_resumable(program, replace(limits, feed_mm_s=feed_mm_s), 150,
                                                           head[-1][1])]
    assert tail
    joined = Trajectory.concatenate([chunk for chunk, _ in head] + tail)
    assert_within_limits(measure_planned(joined, program, limits), limits)


def test_resuming_with_other_acceleration_limits_is_refused(mixed_plans):
    program = mixed_plans[0]
    _, resume = next(plan_lookahead_resumable(program, WANG_LIMITS, chunk_cycles=150))
    with pytest.raises(InputError, match="acceleration and jerk"):
        list(plan_lookahead_resumable(program, replace(WANG_LIMITS, max_jerk_mm_s3=20000.0), 150, resume))
