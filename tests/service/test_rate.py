"""Feed override: r scales v by r and a by r², so r_max = min(1.5, sqrt(a_max/a), v_max/v)."""

import numpy as np
import pytest

from nurbsmotion.service.rate import effective_rate, max_rate


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
