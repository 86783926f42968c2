"""Controlled stop: stays on the planned polyline and decelerates within every axis' a_max."""

import numpy as np
import pytest

from nurbsmotion.fieldbus.stop_ramp import StopRamp, ramp_slope, stop_slope


def _path(n=2000):
    t = np.arange(n)
    return np.column_stack([200 * t, 50000 * np.sin(t / 300.0), np.full(n, 7)]).astype(np.int32)


def _stop(counts, accel, period_s, start):
    ramp = StopRamp(memoryview(counts.astype(np.int64)), ramp_slope(counts, accel, period_s))
    ramp.start(start)
    out, points = [0, 0, 0], [counts[start].tolist()]
    while ramp.step(out):
        points.append(list(out))
    points.append(list(out))
    return np.array(points, dtype=float)


def test_stop_decelerates_within_each_axis_acceleration():
    counts, period_s = _path(), 0.004
    accel = np.array([2e5, 3e5, 1e5])
    points = _stop(counts, accel, period_s, start=100)
    velocity = np.diff(points, axis=0) / period_s
    planned_accel = np.abs(np.diff(counts.astype(float), 2, axis=0)).max(axis=0) / period_s**2
    achieved = np.abs(np.diff(velocity, axis=0)).max(axis=0) / period_s
    assert np.all(achieved <= accel + planned_accel + 2 / period_s**2)  # +2 counts rounding
    assert np.allclose(points[-1], points[-2])  # ends at rest
    assert len(points) > 5


def test_stop_stays_on_the_planned_polyline():
    counts = _path()
    points = _stop(counts, np.array([1e5, 1e5, 1e5]), 0.004, start=50)
    x = counts[:, 0].astype(float)  # x is monotonic: the path position is x / 200
    for p in points:
        s = p[0] / 200.0
        i = int(s)
        expected_y = counts[i, 1] + (s - i) * (counts[min(i + 1, len(counts) - 1), 1] - counts[i, 1])
        assert abs(p[1] - expected_y) <= 1.5
        assert p[0] <= x[-1]


def test_stop_near_the_end_ends_at_the_last_row():
    counts = _path(60)
    points = _stop(counts, np.array([1.0, 1.0, 1.0]), 0.004, start=55)
    assert points[-1].tolist() == counts[-1].tolist()


def test_standstill_stops_at_once():
    counts = np.zeros((10, 3), dtype=np.int32)
    assert ramp_slope(counts, np.ones(3), 0.004) == 1.0


def test_the_stop_slope_leaves_room_for_the_plans_own_acceleration():
    period, fallback = 0.004, 0.1
    # axis 0: 400 counts per cycle at most, plan accelerates 1e6 counts/s², limit 2e6 counts/s²
    dr = stop_slope([400.0, 0.0], [1e6, 0.0], [2e6, 1e6], period, rate=1.0, fallback=fallback)
    assert dr == pytest.approx((2e6 - 1e6) * period**2 / 400.0)
    assert 400.0 * dr / period**2 + 1e6 <= 2e6 + 1e-6  # ramp + plan within the limit
    assert stop_slope([400.0], [1e6], [2e6], period, rate=0.5, fallback=fallback) > dr  # r² a_planned is less
    assert stop_slope([400.0], [3e6], [2e6], period, rate=1.0, fallback=fallback) == pytest.approx(0.1 * fallback)
    assert stop_slope([1.0], [0.0], [2e6], period, rate=1.0, fallback=fallback) == fallback
