"""Feed override: r scales v by r and a by r² (plus interpolation and ramp room), clamped."""

import math

import numpy as np
import pytest

from nurbsmotion.service.rate import effective_rate, max_rate


def test_the_tightest_axis_limit_bounds_the_rate():
    v, a = np.array([100.0, 10.0, 0.0]), np.array([100.0, 1.0, 0.0])
    # X: sqrt((0.75 * 225 - 100 / 4) / 100) = 1.19...; Y has no limits; Z does not move
    assert max_rate(v, a, [1000.0, None, 1.0], [225.0, None, None]) == pytest.approx(math.sqrt(1.4375))
    assert max_rate(v, a, [110.0, None, None], [1e6, None, None]) == pytest.approx(1.1)  # 110/100
    assert max_rate(v, a, [None] * 3, [30.0, None, None]) == 0.0  # no room: above 100 % is refused
    assert max_rate(v, a, [None] * 3, [None] * 3) == pytest.approx(1.5)


def test_overrides_up_to_100_percent_are_used_as_asked_and_above_are_clamped():
    assert effective_rate(0.3, 0.8) == pytest.approx(0.3)
    assert effective_rate(1.4, 1.2) == pytest.approx(1.2)
    assert effective_rate(1.4, 0.9) == pytest.approx(1.0)
    assert effective_rate(1.1, 1.5) == pytest.approx(1.1)


def _replay_peak_accel(x: np.ndarray, rate: float, period: float) -> float:
    """Largest |acceleration| of the rows x played at a constant rate (linear interpolation)."""
    s = np.arange(0.0, len(x) - 1, rate)
    replay = np.interp(s, np.arange(len(x)), x)
    return float((np.abs(np.diff(replay, n=2)) / period**2).max())


@pytest.mark.parametrize("a_plan", [300.0, 600.0, 1000.0])
def test_the_clamped_rate_keeps_a_replayed_plan_within_the_axis_limit(a_plan):
    """A constant-acceleration plan replayed at r_max stays within a_max with room for the
    rate ramp; at the issue's plain sqrt(a_max / a_planned) the interpolation overshoots."""
    from nurbsmotion.service.rate import RAMP_SHARE

    period, a_max = 0.004, 2000.0
    t = np.arange(0, 1.0, period)
    x = 0.5 * a_plan * t**2
    r_max = max_rate(np.array([a_plan * t[-1]]), np.array([a_plan]), [None], [a_max])
    assert r_max > 1.0
    assert _replay_peak_accel(x, r_max, period) <= (1.0 - RAMP_SHARE) * a_max + 1e-6
    assert _replay_peak_accel(x, math.sqrt(a_max / a_plan), period) > a_max
