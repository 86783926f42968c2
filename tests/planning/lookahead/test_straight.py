"""One straight block between stops: the time-optimal S-curve, to the machine's limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.planning.lookahead.straight import ROUNDING_MARGIN, phase_times, positions, scurve
from nurbsmotion.planning.measure import measure
from tests.planning.lookahead.conftest import measure_planned, assert_within_limits, polyline

V, A, J = 200.0, 2500.0, 50_000.0


def optimal_duration(distance: float, v: float = V, a: float = A, j: float = J) -> float:
    """Closed forms of the three cases of a rest-to-rest S-curve."""
    if distance >= v * (v / a + a / j):  # cruise at V: D/V + V/A + A/J
        return distance / v + v / a + a / j
    pure_jerk = 4.0 * (distance / (2.0 * j)) ** (1.0 / 3.0)
    if (distance / (2.0 * j)) ** (1.0 / 3.0) * j <= a:  # peak acceleration below A
        return pure_jerk
    t_j = a / j
    t_a = (math.sqrt(t_j * t_j + 4.0 * distance / a) - 3.0 * t_j) / 2.0
    return 4.0 * t_j + 2.0 * t_a


@pytest.mark.parametrize("distance", [0.5, 2.0, 5.0, 12.0, 20.0, 100.0, 500.0])
def test_phase_times_give_the_optimal_duration(distance):
    t_j, t_a, t_v = phase_times(distance, V, A, J)
    assert 4 * t_j + 2 * t_a + t_v == pytest.approx(optimal_duration(distance), rel=1e-12)


@pytest.mark.parametrize("distance", [2.0, 12.0, 100.0])
def test_profile_reaches_the_end_at_rest_within_every_limit(distance):
    """Sampled every 0.1 ms: differences of 1 to 3 steps are averages of v, a and j."""
    profile = scurve(distance, V, A, J)
    dt = 1e-4
    t = np.arange(-3, int(profile.duration_s / dt) + 5) * dt
    s = positions(profile, t)
    assert s[-1] == pytest.approx(distance, abs=1e-9)
    assert np.all(np.diff(s) >= -1e-12)
    assert np.diff(s).max() / dt <= V * (1 + 1e-9)
    assert np.abs(np.diff(s, 2)).max() / dt**2 <= A * (1 + 1e-6)
    assert np.abs(np.diff(s, 3)).max() / dt**3 <= J * (1 + 1e-3)  # rounding: 8 ulp(s) / dt^3


def test_trapezoid_without_a_jerk_limit():
    profile = scurve(100.0, V, A, None)
    assert profile.duration_s == pytest.approx(100.0 / V + V / A, rel=1e-12)
    assert positions(profile, np.array([profile.duration_s]))[0] == pytest.approx(100.0, abs=1e-12)


@pytest.mark.parametrize("distance", [2.0, 5.0, 20.0, 100.0])
def test_a_line_between_stops_takes_the_optimal_number_of_cycles(distance):
    limits = PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=A, max_jerk_mm_s3=J, feed_mm_s=V)
    program = polyline([(0.0, 0.0, 0.0), (distance, 0.0, 0.0)])
    trajectory = plan_lookahead(program, limits)
    m = measure(trajectory, program)
    assert_within_limits(m, limits)
    best_cycles = math.ceil(optimal_duration(distance) / limits.period_s / ROUNDING_MARGIN ** (1 / 3) - 1e-9)
    assert len(trajectory) - 1 <= best_cycles
    assert m.duration_s >= optimal_duration(distance) - 1e-12  # nothing beats the optimum


def test_axis_limits_scale_with_the_direction():
    """A diagonal line in XY: each axis carries 1/sqrt(2) of the path's velocity and
    acceleration, so the path may go sqrt(2) x the axis limit."""
    limits = PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=10_000.0, max_jerk_mm_s3=J, feed_mm_s=1000.0,
                        axis_max_velocity_mm_s=(100.0, 100.0, 100.0), axis_max_accel_mm_s2=(1000.0, 1000.0, 1000.0))
    program = polyline([(0.0, 0.0, 0.0), (60.0, 60.0, 0.0)])
    m = measure(plan_lookahead(program, limits), program)
    assert_within_limits(m, limits)
    assert max(m.axis_max_velocity_mm_s) >= 100.0 * 0.999  # the cruise reaches the axis limit
    assert max(m.axis_max_accel_mm_s2) >= 1000.0 * 0.99


def test_polyline_corners_are_stops_and_every_segment_is_optimal():
    """Without corner blending (path tolerance 0) a 90 deg corner is a stop."""
    limits = PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=A, max_jerk_mm_s3=J, feed_mm_s=V,
                        path_tolerance_mm=0.0)
    program = polyline([(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0)])
    trajectory = plan_lookahead(program, limits)
    assert_within_limits(measure_planned(trajectory, program, limits), limits)
    assert trajectory.notes["stops"] == 1
    one = math.ceil(optimal_duration(10.0) / limits.period_s / ROUNDING_MARGIN ** (1 / 3) - 1e-9)
    assert len(trajectory) - 1 <= 2 * one + 1  # the corner is held for one cycle
