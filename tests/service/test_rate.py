"""Feed override: r scales v by r and a by r², so r_max = min(1.5, sqrt(a_max/a), v_max/v)."""

import numpy as np
import pytest

from nurbsmotion.service.rate import axis_peaks, effective_rate, max_rate


def test_peaks_are_finite_differences_of_the_set_points():
    t = np.arange(0, 1.0001, 0.004)
    pos = np.column_stack([50.0 * t**2, 10.0 * t, np.zeros_like(t)])  # a = 100, v <= 100 / 10
    v, a = axis_peaks(pos, 0.004)
    assert v[0] == pytest.approx(100.0, rel=0.01) and v[1] == pytest.approx(10.0)
    assert a[0] == pytest.approx(100.0, rel=1e-6) and a[2] == 0.0


def test_the_tightest_axis_limit_bounds_the_rate():
    v, a = np.array([100.0, 10.0, 0.0]), np.array([100.0, 1.0, 0.0])
    assert max_rate(v, a, [1000.0, None, 1.0], [144.0, None, None]) == pytest.approx(1.2)  # sqrt(144/100)
    assert max_rate(v, a, [110.0, None, None], [1e6, None, None]) == pytest.approx(1.1)  # 110/100
    assert max_rate(v, a, [None] * 3, [None] * 3) == pytest.approx(1.5)


def test_overrides_up_to_100_percent_are_used_as_asked_and_above_are_clamped():
    assert effective_rate(0.3, 0.8) == pytest.approx(0.3)
    assert effective_rate(1.4, 1.2) == pytest.approx(1.2)
    assert effective_rate(1.4, 0.9) == pytest.approx(1.0)
    assert effective_rate(1.1, 1.5) == pytest.approx(1.1)
