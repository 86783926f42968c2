"""lookahead holds every limit on every cycle, measured by the shared ruler (planning.measure)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.planning import plan
from nurbsmotion.planning.measure import measure
from nurbsmotion.program import read_program
from tests.planning.lookahead.conftest import measure_planned, EXAMPLES, WANG_LIMITS, assert_within_limits


@pytest.fixture(scope="module")
def wang_plan(wang_program):
    return plan(wang_program, WANG_LIMITS, "lookahead")


@pytest.fixture(scope="module")
def sharp_plan(sharp_program):
    return plan(sharp_program, WANG_LIMITS, "lookahead")


def test_lookahead_is_the_default_algorithm(wang_program, wang_plan):
    assert plan(wang_program, WANG_LIMITS).algorithm == "lookahead"


@pytest.mark.parametrize("name", ["wang_plan", "sharp_plan"])
def test_every_cycle_holds_every_limit(name, request, wang_program, sharp_program):
    trajectory = request.getfixturevalue(name)
    program = wang_program if name == "wang_plan" else sharp_program
    assert_within_limits(measure_planned(trajectory, program, WANG_LIMITS), WANG_LIMITS)


@pytest.mark.parametrize("name", ["wang_plan", "sharp_plan"])
def test_end_is_exact_and_at_rest_on_a_cycle_boundary(name, request, wang_program, sharp_program):
    trajectory = request.getfixturevalue(name)
    program = wang_program if name == "wang_plan" else sharp_program
    np.testing.assert_array_equal(trajectory.position_mm[-1], program.end_position)
    np.testing.assert_array_equal(trajectory.position_mm[0], program.blocks[0].start)
    # zero speed at the end instant: the last step is what a jerk-limited stop from rest
    # covers in one cycle backwards, J T^3 / 6
    last_step = np.linalg.norm(trajectory.position_mm[-1] - trajectory.position_mm[-2])
    assert last_step <= WANG_LIMITS.max_jerk_mm_s3 * WANG_LIMITS.period_s**3 / 6.0 * (1 + 1e-9)


@pytest.mark.parametrize("name", ["wang_plan", "sharp_plan"])
def test_step_arc_length_matches_planned_feed(name, request, wang_program, sharp_program):
    """Arc length between consecutive set-points (from the curve's own arc_length) equals the
    planned step feed_mm_s * T within 1e-6 relative."""
    trajectory = request.getfixturevalue(name)
    program = wang_program if name == "wang_plan" else sharp_program
    curve = program.blocks[0].curve
    s = np.asarray(curve.arc_length(trajectory.u))
    step = np.diff(s)
    planned = trajectory.feed_mm_s[1:] * trajectory.period_s
    moving = planned > 1e-6
    assert np.max(np.abs(step[moving] - planned[moving]) / planned[moving]) <= 1e-6


def test_chord_fluctuation_is_the_arc_chord_difference(wang_plan, wang_program):
    """The chord is shorter than the arc by about dL^3 kappa^2 / 24, so the measured (chord)
    fluctuation is not 1e-6 but stays below that bound."""
    m = measure(wang_plan, wang_program)
    assert m.max_fluctuation <= 1e-3


def test_notes_report_the_guarantees_and_tolerance(wang_plan):
    notes = wang_plan.notes
    assert notes["tolerance"] == 1e-9
    for key in ("verified_max_chord_error_mm", "verified_max_accel_mm_s2", "verified_max_jerk_mm_s3",
                "verified_max_arc_fluctuation"):
        assert key in notes
    assert notes["verified_max_arc_fluctuation"] <= notes["fluctuation_limit"]


def test_lookahead_finishes_wangs_experiment_sooner_than_wang(wang_program):
    """Wang's experiment (no jerk limit, like the paper): same limits, shorter motion time,
    and lookahead's limits still hold."""
    limits = replace(WANG_LIMITS, max_jerk_mm_s3=None, axis_max_velocity_mm_s=None, axis_max_accel_mm_s2=None)
    ours = plan(wang_program, limits, "lookahead")
    theirs = plan(wang_program, limits, "wang")
    assert ours.duration_s < theirs.duration_s
    assert_within_limits(measure_planned(ours, wang_program, limits), limits)


def test_a_mixed_program_of_lines_arcs_and_nurbs_holds_every_limit():
    program = read_program(EXAMPLES / "mixed.nc")
    trajectory = plan(program, WANG_LIMITS, "lookahead")
    m = measure_planned(trajectory, program, WANG_LIMITS)
    assert_within_limits(m, WANG_LIMITS)
    assert trajectory.notes["verified_max_arc_fluctuation"] <= 1e-6
