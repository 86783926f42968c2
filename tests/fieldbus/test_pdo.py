"""SDO configuration plan of a drive: mode, IP period, PDO mapping in CiA 301 order."""

import pytest

from nurbsmotion import cia402 as c
from nurbsmotion.fieldbus.pdo import drive_configuration, interpolation_period, mapping_entry


def _plan(mode, fe_tpdo=False):
    return drive_configuration(3, mode, 0.004, 100, 1000, 20, fe_tpdo)


def _value(plan, index, sub):
    return [w.value for w in plan if (w.index, w.subindex) == (index, sub)]


@pytest.mark.parametrize("period_s, expected", [(0.004, (4, -3)), (0.0025, (25, -4)), (0.001, (1, -3))])
def test_interpolation_period_value_and_exponent(period_s, expected):
    assert interpolation_period(period_s) == expected


def test_ip_plan_sets_mode_submode_period_and_maps_60c1():
    plan = _plan(c.Mode.INTERPOLATED_POSITION)
    assert _value(plan, c.MODES_OF_OPERATION, 0) == [7]
    assert _value(plan, c.IP_SUB_MODE, 0) == [0]
    assert _value(plan, c.IP_TIME_PERIOD, 1) == [4] and _value(plan, c.IP_TIME_PERIOD, 2) == [-3]
    assert mapping_entry(c.IP_DATA_RECORD, 1, 32) in _value(plan, c.RPDO_MAPPING, 2)


def test_csp_plan_maps_607a_and_no_ip_objects():
    plan = _plan(c.Mode.CYCLIC_SYNC_POSITION)
    assert _value(plan, c.MODES_OF_OPERATION, 0) == [8]
    assert not _value(plan, c.IP_TIME_PERIOD, 1)
    assert _value(plan, c.RPDO_MAPPING, 2) == [0x607A0020]


def test_pdo_is_disabled_before_remapping_and_enabled_last():
    plan = _plan(c.Mode.CYCLIC_SYNC_POSITION)
    tpdo1 = [(w.index, w.subindex, w.value) for w in plan if w.index in (c.TPDO_COMM, c.TPDO_MAPPING)]
    assert tpdo1[0] == (c.TPDO_COMM, 1, 0x8000_0183)
    assert tpdo1[-1] == (c.TPDO_COMM, 1, 0x183)
    assert (c.TPDO_COMM, 2, 1) in tpdo1  # synchronous, every SYNC
    counts = [v for i, s, v in tpdo1 if (i, s) == (c.TPDO_MAPPING, 0)]
    assert counts == [0, 2]


def test_following_error_tpdo_only_when_asked():
    without = _value(_plan(c.Mode.CYCLIC_SYNC_POSITION), c.TPDO_COMM + 1, 1)
    with_fe = _value(_plan(c.Mode.CYCLIC_SYNC_POSITION, True), c.TPDO_COMM + 1, 1)
    assert without == [0x8000_0283]
    assert with_fe[-1] == 0x283


def test_monitoring_objects_written():
    plan = _plan(c.Mode.CYCLIC_SYNC_POSITION)
    assert _value(plan, c.FOLLOWING_ERROR_WINDOW, 0) == [1000]
    assert _value(plan, c.FOLLOWING_ERROR_TIMEOUT, 0) == [20]
    assert _value(plan, c.PRODUCER_HEARTBEAT_TIME, 0) == [100]
    assert all(len(w.data()) in (1, 2, 4) for w in plan)
