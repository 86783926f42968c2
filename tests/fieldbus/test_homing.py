"""CiA-402 homing mode 6 on the master's side: drive values, SDO plan, per-cycle procedure."""

import pytest

from nurbsmotion.can import cia402 as c
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.homing import (
    Event,
    HomingDriveValues,
    HomingProcedure,
    OffsetObject,
    Phase,
    classify,
    here_offset_counts,
    homing_drive_values,
    homing_plan,
)
from nurbsmotion.config.homing import HERE, HomingConfig

OE = 0x0237  # OPERATION ENABLED + voltage + remote
IN_PROGRESS = OE
COMPLETED = OE | c.SW_TARGET_REACHED | 1 << 12
ATTAINED = OE | 1 << 12
ERROR = OE | 1 << 13
INTERRUPTED = OE | c.SW_TARGET_REACHED
FAULT = 0x0208


def _homing(**kw):
    base = {"method": 17, "speed_search_mm_s": 20.0, "speed_zero_mm_s": 2.0, "accel_mm_s2": 200.0, "offset_mm": -5.0}
    return HomingConfig(**{**base, **kw})


def test_drive_values_in_counts_by_default():
    values = homing_drive_values(_homing(), counts_per_mm=1000, invert=False, offset_counts=0, axis_name="X")
    # speeds 20 mm/s and 2 mm/s at 1000 counts/mm; CiA 402: the home reads -0x607C
    assert values == HomingDriveValues(17, 20000, 2000, 200000, 5000)


def test_drive_units_are_explicit_rpm_drive_and_plus_sign_convention():
    # a drive in rpm with 4096 counts/rev: one unit = 4096/60 counts/s; accel in rpm/s
    homing = _homing(speed_unit_counts_s=4096 / 60, accel_unit_counts_s2=4096 / 60, home_offset_sign=1)
    values = homing_drive_values(homing, counts_per_mm=4096 / 5, invert=True, offset_counts=100, axis_name="Z")
    assert (values.speed_search, values.speed_zero, values.acceleration) == (240, 24, 2400)
    assert values.home_offset == round(5 * 4096 / 5) + 100  # inverted axis: -(-5 mm) -> +4096, plus offset


@pytest.mark.parametrize("kw, field", [
    ({"speed_zero_mm_s": 0.0001}, "speed_zero_mm_s"),  # rounds to 0 counts/s
    ({"accel_mm_s2": 1e9}, "accel_mm_s2"),  # beyond UNSIGNED32
    ({"offset_mm": 3e6}, "offset_mm"),  # beyond INTEGER32
])
def test_values_that_do_not_fit_the_drive_are_input_errors(kw, field):
    with pytest.raises(InputError) as info:
        homing_drive_values(_homing(**kw), counts_per_mm=1000, invert=False, offset_counts=0, axis_name="Y")
    assert str(info.value).startswith(f"axis Y: homing.{field}: ")
    assert "\n" not in str(info.value)


def test_method_37_writes_no_speeds_and_a_zero_offset_writes_nothing():
    values = homing_drive_values(HomingConfig(method=37, offset_mm=0), 1000, False, 0, "X")
    plan = homing_plan(values, c.Mode.CYCLIC_SYNC_POSITION)
    assert [(w.index, w.subindex, w.value) for w in plan.writes] == [(0x6098, 0, 37), (0x6060, 0, 6)]
    assert plan.mode_check == 6
    assert [(w.index, w.value) for w in plan.restore] == [(0x6060, 8)]


def test_the_offset_goes_to_the_object_given_or_nowhere():
    values = homing_drive_values(HomingConfig(method=37, offset_mm=2, home_offset_sign=1), 1000, False, 0, "X")
    vendor = homing_plan(values, c.Mode.CYCLIC_SYNC_POSITION, OffsetObject(0x30B0, 0, "<i"))
    assert [(w.index, w.value, w.fmt) for w in vendor.writes] == [(0x6098, 37, "<b"), (0x30B0, 2000, "<i"),
                                                                  (0x6060, 6, "<b")]
    master = homing_plan(values, c.Mode.CYCLIC_SYNC_POSITION, None)
    assert [w.index for w in master.writes] == [0x6098, 0x6060]


def test_plan_writes_every_homing_object_before_the_mode():
    plan = homing_plan(homing_drive_values(_homing(), 1000, False, 0, "X"), c.Mode.INTERPOLATED_POSITION)
    assert [(w.index, w.subindex, w.fmt, w.value) for w in plan.writes] == [
        (0x6098, 0, "<b", 17), (0x6099, 1, "<I", 20000), (0x6099, 2, "<I", 2000), (0x609A, 0, "<I", 200000),
        (0x607C, 0, "<i", 5000), (0x6060, 0, "<b", 6)]
    assert plan.restore[0].value == 7
    assert [w.data() for w in plan.writes[:2]] == [b"\x11", (20000).to_bytes(4, "little")]
    assert plan.writes[4].data() == (5000).to_bytes(4, "little", signed=True)
    with pytest.raises(ValueError):
        homing_drive_values(HomingConfig(method=HERE), 1000, False, 0, "X")


@pytest.mark.parametrize("invert", [False, True])
def test_here_makes_the_current_position_read_offset_mm(invert):
    offset_counts = here_offset_counts(123456, offset_mm=10.0, counts_per_mm=800, invert=invert)
    sign = -1 if invert else 1
    assert sign * (123456 - offset_counts) / 800 == pytest.approx(10.0)


def _run(procedure, statuswords):
    return [procedure.step(sw) for sw in statuswords]


def test_successful_homing_from_switched_on():
    proc = HomingProcedure(3, 17, cycle_period_s=0.004, timeout_s=1.0)
    assert proc.ack_cycles == 25  # 100 ms at 4 ms
    steps = _run(proc, [0x0233, OE, OE] + [COMPLETED] * proc.ack_cycles + [IN_PROGRESS, ATTAINED, COMPLETED])
    words = [s.controlword for s in steps]
    assert words[0] == 0x0F  # SWITCHED ON -> enable operation, bit 4 low
    assert words[1] == 0x0F  # ARMED: bit 4 low one more cycle in OPERATION ENABLED
    assert words[2:-1] == [0x1F] * (len(words) - 3)  # bit 4 high from the rising edge on
    # a stale 'completed' from an earlier homing right after the edge is ignored
    assert [s.phase for s in steps[2:2 + proc.ack_cycles + 1]] == [Phase.STARTED] * (proc.ack_cycles + 1)
    assert steps[-2].phase is Phase.RUNNING and steps[-2].outcome is None
    assert steps[-1].phase is Phase.HOMED and steps[-1].outcome.homed and steps[-1].controlword == 0x0F
    assert proc.step(COMPLETED).outcome is None  # the outcome is reported once


@pytest.mark.parametrize("last, text", [
    (ERROR, "node 3: homing method 1: the drive reports a homing error (statusword 0x2237, bit 13)"),
    (INTERRUPTED, ("node 3: homing method 1: the drive interrupted or did not start homing "
                  "(statusword 0x0637, bit 10 without bit 12)")),
    (FAULT, "node 3: homing method 1: the drive went to FAULT (statusword 0x0208)"),
    (0x0233, "node 3: homing method 1: the drive left OPERATION ENABLED (now SWITCHED ON)"),
])
def test_failures_name_the_node_and_stop_homing(last, text):
    proc = HomingProcedure(3, 1, cycle_period_s=0.004, timeout_s=1.0)
    steps = _run(proc, [OE, OE] + [IN_PROGRESS] * (proc.ack_cycles + 2) + [last])
    assert steps[-1].phase is Phase.FAILED
    assert steps[-1].outcome.reason == text and not steps[-1].outcome.homed
    assert not steps[-1].controlword & 0x10  # bit 4 low interrupts the drive's homing


def test_timeout_counts_cycles():
    proc = HomingProcedure(5, 33, cycle_period_s=0.01, timeout_s=0.1)
    steps = _run(proc, [OE] * 11)
    assert [s.outcome for s in steps[:10]] == [None] * 10
    assert steps[10].outcome.reason == "node 5: homing method 33: not completed within 0.1 s (statusword 0x0237)"


def test_acknowledge_window_is_at_least_three_cycles():
    assert HomingProcedure(1, 1, cycle_period_s=0.1, timeout_s=10).ack_cycles == 3
    assert HomingProcedure(1, 1, cycle_period_s=0.001, timeout_s=10).ack_cycles == 100


def test_fault_before_start_is_not_reset_silently():
    proc = HomingProcedure(2, 18, cycle_period_s=0.004, timeout_s=1.0)
    step = proc.step(FAULT)
    assert step.phase is Phase.FAILED and "went to FAULT" in step.outcome.reason


def test_classify_table():
    assert classify(None, True) is Event.NO_STATUS
    assert classify(OE, False) is Event.ACK_PENDING
    assert classify(ATTAINED, True) is Event.ATTAINED
    assert classify(ERROR | 1 << 12, True) is Event.HOMING_ERROR


def test_a_not_started_word_waits_for_the_start_allowance_before_failing():
    """'bit 10 without bit 12' right after the acknowledge may predate the start (a lagging
    drive): it fails only after start_s; once the drive showed the homing under way it fails at once."""
    proc = HomingProcedure(3, 1, cycle_period_s=0.004, timeout_s=10.0, start_s=0.2)
    assert proc.start_cycles == 50
    steps = _run(proc, [OE, OE] + [INTERRUPTED] * 50 + [IN_PROGRESS, ATTAINED, COMPLETED])
    assert steps[-1].phase is Phase.HOMED  # the drive started late: homed, not a failure
    proc = HomingProcedure(3, 1, cycle_period_s=0.004, timeout_s=10.0, start_s=0.2)
    steps = _run(proc, [OE, OE] + [INTERRUPTED] * 51)  # the edge is sent in the 2nd step
    assert [s.outcome for s in steps[:-1]] == [None] * 52  # 50 cycles after the edge: still waiting
    assert steps[-1].outcome.reason.startswith("node 3: homing method 1: the drive interrupted or did not start")


def test_cancel_ends_the_homing_with_bit_4_low():
    proc = HomingProcedure(3, 17, cycle_period_s=0.004, timeout_s=10.0)
    _run(proc, [OE, OE] + [IN_PROGRESS] * 5)
    proc.cancel()
    step = proc.step(IN_PROGRESS)
    assert step.phase is Phase.FAILED and not step.controlword & 0x10
    assert step.outcome.reason == "node 3: homing method 17: stopped on request (statusword 0x0237)"
