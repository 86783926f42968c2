"""The papers' interpolators on Wang's Table 1 experiment, measured by planning.measure."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning import PlanLimits, plan
from nurbsmotion.planning.measure import measure
from nurbsmotion.program import Block, BlockKind, Program, SourceRef
from tests.conftest import WANG_KNOTS, WANG_POINTS, WANG_WEIGHTS

NAMES = ("taylor1", "taylor2", "wang", "zhang")
# Wang's Table 1 experiment: V0 = 12 m/min, t_l = 1.2 s, T = 4 ms, δ = 10 µm, a = 2.5 m/s²
WANG_LIMITS = PlanLimits(period_s=0.004, chord_error_mm=0.010, max_accel_mm_s2=2500.0, acc_time_s=1.2)
WANG_FEED_MM_S = 200.0
ACC_DEC_MM_S2 = WANG_FEED_MM_S / WANG_LIMITS.acc_time_s  # a_l = V0 / t_l


def program_of(*blocks: tuple[NurbsCurve, float | None, BlockKind]) -> Program:
    built = tuple(Block(kind, curve, feed, SourceRef("t", i + 1)) for i, (curve, feed, kind) in enumerate(blocks))
    return Program("t", built, built[0].start)


@pytest.fixture(scope="module")
def wang_program() -> Program:
    curve = NurbsCurve.create(2, WANG_POINTS, WANG_WEIGHTS, WANG_KNOTS)
    return program_of((curve, WANG_FEED_MM_S, BlockKind.NURBS))


@pytest.fixture(scope="module")
def runs(wang_program):
    """name -> (trajectory, measurements) of Wang's experiment."""
    out = {}
    for name in NAMES:
        trajectory = plan(wang_program, WANG_LIMITS, name)
        out[name] = (trajectory, measure(trajectory, wang_program))
    return out


def test_wang_holds_chord_error_and_resultant_acceleration_at_every_cycle(runs):
    trajectory, m = runs["wang"]
    assert trajectory.algorithm == "wang"
    assert m.max_chord_error_mm <= WANG_LIMITS.chord_error_mm
    assert m.max_accel_mm_s2 <= WANG_LIMITS.max_accel_mm_s2 * (1 + 1e-12)


def test_zhang_holds_the_limits_too(runs):
    _, m = runs["zhang"]
    assert m.max_chord_error_mm <= WANG_LIMITS.chord_error_mm
    assert m.max_accel_mm_s2 <= WANG_LIMITS.max_accel_mm_s2 * (1 + 1e-12)
    assert m.max_speed_mm_s <= WANG_FEED_MM_S * (1 + 1e-6)  # the corrected chord is the commanded step


def test_constant_feed_baselines_break_the_limits_the_papers_address(runs):
    # the baselines run at V0 through ρ ≈ 5.9 mm: a_n = V0²/ρ ≈ 6.8 m/s²
    assert runs["taylor2"][1].max_accel_mm_s2 > 2 * WANG_LIMITS.max_accel_mm_s2


def test_feed_fluctuation_ordering(runs):
    fluct = {name: runs[name][1].max_fluctuation for name in NAMES}
    assert fluct["taylor2"] < fluct["taylor1"]
    assert fluct["zhang"] < fluct["taylor2"]
    assert fluct["zhang"] < 1e-4


@pytest.mark.parametrize("name", NAMES)
def test_exact_ends_and_no_tail(runs, wang_program, name):
    trajectory, m = runs[name]
    np.testing.assert_array_equal(trajectory.position_mm[0], wang_program.blocks[0].start)
    assert m.end_error_mm < 1e-9
    assert trajectory.feed_mm_s[0] == 0.0
    # the last K cycles decelerate monotonically at about a_l and the final step is a normal
    # deceleration step (at most a_l T²): the feed reaches zero in the cycle that reaches the end
    k = 40
    speeds = m.speed_mm_s[-k:]
    assert np.all(np.diff(speeds) < 0)
    np.testing.assert_allclose(np.diff(speeds[:-1]), -ACC_DEC_MM_S2 * WANG_LIMITS.period_s, rtol=0.05)
    assert speeds[-1] <= ACC_DEC_MM_S2 * WANG_LIMITS.period_s * (1 + 1e-9)
    # starting: from rest, one a_l T step at a time
    np.testing.assert_allclose(m.speed_mm_s[1:4], ACC_DEC_MM_S2 * WANG_LIMITS.period_s * np.arange(1, 4), rtol=0.05)


def test_planned_and_measured_motion_time_agree_with_the_feed(runs, wang_program):
    # constant feed 200 mm/s over 1028 mm plus the 1.2 s acc/dec ramps: about 6.34 s
    _, m = runs["taylor2"]
    assert m.length_mm == pytest.approx(wang_program.length_mm, rel=1e-4)
    expected = wang_program.length_mm / WANG_FEED_MM_S + WANG_LIMITS.acc_time_s
    assert m.duration_s == pytest.approx(expected, rel=0.01)


def test_sharp_corner_stops_exactly_on_the_junction():
    corner = (10.0, 0.0, 0.0)
    prog = program_of((line_curve((0, 0, 0), corner), 50.0, BlockKind.LINE),
                      (line_curve(corner, (10, 10, 0)), 50.0, BlockKind.LINE))
    limits = PlanLimits(period_s=0.004, acc_time_s=0.2)
    for name in NAMES:
        trajectory = plan(prog, limits, name)
        m = measure(trajectory, prog)
        at_corner = np.flatnonzero(np.all(trajectory.position_mm == corner, axis=1))
        assert len(at_corner) == 1, name
        i = int(at_corner[0])
        a_l_step = 50.0 / 0.2 * 0.004
        assert m.speed_mm_s[i] <= a_l_step * (1 + 1e-9) and m.speed_mm_s[i + 1] <= a_l_step * (1 + 1e-9)
        assert trajectory.notes["stops"] == 1
        assert m.end_error_mm < 1e-9


def test_tangent_blocks_run_through_the_junction_without_stopping():
    radius = 20.0
    first = arc_curve((0, 0, 0), (radius, 0, 0), math.pi / 2)
    second = arc_curve((0, 0, 0), (0, radius, 0), math.pi / 2)
    prog = program_of((first, 100.0, BlockKind.ARC), (second, 100.0, BlockKind.ARC))
    limits = PlanLimits(period_s=0.002, acc_time_s=0.1, max_accel_mm_s2=5000.0)
    trajectory = plan(prog, limits, "zhang")
    m = measure(trajectory, prog)
    crossing = int(np.flatnonzero(trajectory.block == 1)[0])
    assert m.speed_mm_s[crossing] == pytest.approx(100.0, rel=1e-6)
    assert trajectory.notes["stops"] == 0
    assert m.max_fluctuation < 1e-6


def test_rapid_blocks_run_at_the_rapid_feed():
    prog = program_of((line_curve((0, 0, 0), (200, 0, 0)), None, BlockKind.RAPID))
    limits = PlanLimits(period_s=0.004, rapid_feed_mm_s=150.0, feed_mm_s=20.0, acc_time_s=0.2)
    m = measure(plan(prog, limits, "taylor2"), prog)
    assert m.max_speed_mm_s == pytest.approx(150.0, rel=1e-9)


def test_zhang_correction_survives_a_very_sharp_nurbs_corner():
    # a weight-1000 control point makes a near-cusp: a plain Newton step on the chord diverges here
    curve = NurbsCurve.create(2, [(0, 0, 0), (10, 0, 0), (10, 10, 0)], [1, 1000, 1])
    prog = program_of((curve, 200.0, BlockKind.NURBS))
    limits = PlanLimits(period_s=0.004, chord_error_mm=0.01, max_accel_mm_s2=2500.0, acc_time_s=0.5)
    trajectory = plan(prog, limits, "zhang")
    m = measure(trajectory, prog)
    assert np.all(np.isfinite(trajectory.position_mm))
    assert np.all(np.diff(trajectory.u) >= 0)
    assert m.end_error_mm < 1e-9
    assert m.max_chord_error_mm <= limits.chord_error_mm


def test_a_program_with_a_gap_is_refused_naming_the_block():
    prog = program_of((line_curve((0, 0, 0), (1, 0, 0)), 10.0, BlockKind.LINE),
                      (line_curve((1, 1, 0), (2, 1, 0)), 10.0, BlockKind.LINE))
    with pytest.raises(InputError, match="t:2: block starts 1 mm away"):
        plan(prog, WANG_LIMITS, "wang")


def test_a_step_longer_than_the_whole_program_is_one_cycle_to_the_end():
    prog = program_of((line_curve((0, 0, 0), (1e-4, 0, 0)), 10.0, BlockKind.LINE))
    trajectory = plan(prog, WANG_LIMITS, "zhang")
    assert len(trajectory) == 2
    np.testing.assert_array_equal(trajectory.position_mm[-1], (1e-4, 0, 0))


def test_a_kink_inside_a_block_is_a_stop_on_its_vertex():
    # one degree-1 NURBS with a 90-degree vertex: the curve is cut there and the motion stops on it
    polyline = NurbsCurve.create(1, [(0, 0, 0), (10, 0, 0), (10, 10, 0)], [1, 1, 1], [0, 0, 0.5, 1, 1])
    prog = program_of((polyline, 50.0, BlockKind.NURBS))
    trajectory = plan(prog, PlanLimits(period_s=0.004, acc_time_s=0.2), "wang")
    at_vertex = np.flatnonzero(np.all(trajectory.position_mm == (10.0, 0.0, 0.0), axis=1))
    assert len(at_vertex) == 1 and trajectory.notes["stops"] == 1
    assert np.all(trajectory.block == 0)
    m = measure(trajectory, prog)
    assert m.max_chord_error_mm < 1e-12 and m.end_error_mm < 1e-9
