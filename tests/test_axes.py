"""mm <-> counts conversion, int32 range and soft limits: checked on the whole job before motion."""

import numpy as np
import pytest

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import AxisConfig
from nurbsmotion.errors import InputError


def _map(**y):
    return AxisMap([AxisConfig("X", 1, counts_per_mm=1000.0, soft_limits_mm=(-10.0, 100.0)),
                    AxisConfig("Y", 2, **({"counts_per_mm": 500.0, "invert": True, "offset_counts": 7} | y))])


def test_counts_follow_sign_scale_and_offset():
    counts = _map().to_counts(np.array([[1.0, 2.0], [-0.0014, 0.0]]))
    assert counts.dtype == np.int32
    assert counts.tolist() == [[1000, -1000 + 7], [-1, 7]]


def test_round_trip_is_exact_to_one_count():
    amap = _map()
    mm = np.column_stack([np.linspace(-5, 50, 101), np.linspace(3, -20, 101)])
    back = amap.to_mm(amap.to_counts(mm))
    assert np.all(np.abs(back - mm) <= 0.5 / amap.counts_per_mm)


def test_soft_limit_names_axis_limit_position_and_cycle():
    mm = np.zeros((5, 2))
    mm[3, 0] = 100.5
    with pytest.raises(InputError) as info:
        _map().to_counts(mm)
    assert info.value.where == "axis X"
    assert "100.5 mm at cycle 3" in info.value.message and "soft limit 100 mm" in info.value.message


def test_int32_overflow_names_axis_and_first_cycle():
    mm = np.zeros((4, 2))
    mm[2:, 1] = 5e6  # 5e6 mm * 500 counts/mm = 2.5e9 counts > int32
    with pytest.raises(InputError) as info:
        _map().to_counts(mm)
    assert info.value.where == "axis Y" and "cycle 2" in str(info.value) and "int32" in str(info.value)


def test_wrong_shape_is_refused():
    with pytest.raises(InputError, match=r"shape \(N, 2\)"):
        _map().to_counts(np.zeros((3, 3)))


def test_limits_exposed_for_planners_and_in_counts():
    amap = AxisMap([AxisConfig("X", 1, counts_per_mm=100.0, max_velocity_mm_s=50.0, max_accel_mm_s2=1000.0),
                    AxisConfig("Y", 2, counts_per_mm=10.0)])
    assert [(lim.name, lim.max_velocity_mm_s, lim.max_accel_mm_s2) for lim in amap.limits()] == \
        [("X", 50.0, 1000.0), ("Y", None, None)]
    assert amap.max_accel_counts_s2(default_mm_s2=200.0).tolist() == [100_000.0, 2000.0]
