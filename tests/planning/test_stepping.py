"""The per-cycle building blocks: fast scalar evaluation, Zhang's chord correction, the reverse table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning.interpolators.fastcurve import FastCurve, scalar_evaluators
from nurbsmotion.planning.interpolators.feed import FeedLimits
from nurbsmotion.planning.interpolators.reverse import build_reverse_table
from nurbsmotion.planning.interpolators.stepping import CurvePath, Stepper, distance
from tests.conftest import WANG_KNOTS, WANG_POINTS, WANG_WEIGHTS

CURVES = {
    "wang": NurbsCurve.create(2, WANG_POINTS, WANG_WEIGHTS, WANG_KNOTS),
    "arc": arc_curve((1, 2, 3), (6, 2, 3), 4.0, (0, 1, 1)),
    "line": line_curve((0, 0, 0), (1, 2, 3)),
    "polyline": NurbsCurve.create(1, [(0, 0, 0), (1, 2, 3), (2, 2, 2), (5, 0, 1)], [1, 2, 0.5, 1], [0, 0, 0.2, 0.7, 1, 1]),
    "cubic": NurbsCurve.create(3, [(0, 0, 0), (1, 2, 0), (3, 1, 1), (4, 4, 2), (6, 0, 1)], [1, 2, 1, 0.5, 1]),
}


@pytest.mark.parametrize("name", CURVES)
def test_fast_evaluation_matches_the_curve(name):
    curve = CURVES[name]
    fast = FastCurve(curve)
    for u in np.linspace(curve.u_min, curve.u_max, 301):
        expected = curve.point_and_derivatives(float(u))
        got = fast.point_and_derivatives(float(u))
        for k in range(3):
            scale = max(1.0, max(abs(v) for v in expected[k]))
            np.testing.assert_allclose(got[k], expected[k], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(fast.point(float(u)), expected[0], rtol=0, atol=1e-12 * max(1.0, np.abs(expected[0]).max()))


def test_higher_degrees_fall_back_to_the_curve():
    quartic = NurbsCurve.create(4, [(0, 0, 0), (1, 1, 0), (2, 0, 1), (3, 1, 1), (4, 0, 0)])
    evaluate, point = scalar_evaluators(quartic)
    np.testing.assert_allclose(point(0.3), quartic.points(0.3))
    np.testing.assert_allclose(evaluate(0.3)[1], quartic.derivatives(0.3, 1)[1])


def test_zhang_correction_makes_the_chord_exactly_the_step():
    path = CurvePath([CURVES["wang"]])
    stepper = Stepper(order=2, correct=True, chord_error_mm=1.0)
    here = path.start()
    for _ in range(300):
        point, step, at_end = stepper.step(path, here, 0.8, 0.8)
        assert distance(point.x, here.x) == pytest.approx(step, abs=1e-9)
        here = point


def test_zhang_midpoint_rule_shortens_a_step_with_too_much_chord_error():
    radius = 5.0
    path = CurvePath([arc_curve((0, 0, 0), (radius, 0, 0), math.pi)])
    stepper = Stepper(order=2, correct=True, chord_error_mm=0.001)
    point, step, _ = stepper.step(path, path.start(), 1.0, 1.0)  # a 1 mm chord on r = 5 mm bows 25 µm
    sagitta = radius - math.sqrt(radius**2 - step**2 / 4)
    assert step < 1.0 and sagitta <= 0.001 * (1 + 1e-6)


def test_reverse_table_lands_exactly_from_any_phase():
    """S -> S - T V_achieve(S) keeps the fraction of the table step: every start lands on 0
    with the last step at most a_l T², decelerating by a_l T per cycle."""
    period, accel = 0.004, 150.0
    line = line_curve((0, 0, 0), (0, 0, 200))  # longer than the 133 mm ramp
    reversed_path = CurvePath([line.reversed()])
    table = build_reverse_table(reversed_path, [200.0], accel, FeedLimits(period, 0.01, 2500.0, False),
                                Stepper(2, False), period)
    assert table.feed_mm_s[-1] >= 200.0 - accel * period
    for start in np.random.default_rng(3).uniform(1.0, table.remaining_mm[-1] * 0.99, 20):
        s, speeds = float(start), []
        while s > 1e-12 * (1.0 + start):  # the planner's own "landed" test (runner.py)
            v = table.v_achieve(s)
            speeds.append(v)
            s -= v * period
            assert len(speeds) < 10_000
        assert s == pytest.approx(0.0, abs=1e-9)
        assert speeds[-1] * period <= accel * period**2 * (1 + 1e-9)
        np.testing.assert_allclose(np.diff(speeds), -accel * period, rtol=1e-6)
