"""The CiA-402 axis without a bus: every transition as the statusword reports it."""

from __future__ import annotations

import pytest

from nurbsmotion.can.cia402 import State, state_of_statusword
from nurbsmotion.sim import Cia402Axis, DriveStats, ServoModel, SetpointRecorder

S = State
# (transition, controlword sequence from SWITCH ON DISABLED, quick-stop option, end state)
PATHS = [
    (2, [0x06], 2, S.READY_TO_SWITCH_ON),
    (3, [0x06, 0x07], 2, S.SWITCHED_ON),
    (4, [0x06, 0x07, 0x0F], 2, S.OPERATION_ENABLED),
    (5, [0x06, 0x07, 0x0F, 0x07], 2, S.SWITCHED_ON),
    (6, [0x06, 0x07, 0x06], 2, S.READY_TO_SWITCH_ON),
    (7, [0x06, 0x00], 2, S.SWITCH_ON_DISABLED),
    (8, [0x06, 0x07, 0x0F, 0x06], 2, S.READY_TO_SWITCH_ON),
    (9, [0x06, 0x07, 0x0F, 0x00], 2, S.SWITCH_ON_DISABLED),
    (10, [0x06, 0x07, 0x00], 2, S.SWITCH_ON_DISABLED),
    (11, [0x06, 0x07, 0x0F, 0x02], 6, S.QUICK_STOP_ACTIVE),
    (12, [0x06, 0x07, 0x0F, 0x02, 0x00], 6, S.SWITCH_ON_DISABLED),
    (16, [0x06, 0x07, 0x0F, 0x02, 0x0F], 6, S.OPERATION_ENABLED),
]


def make_axis() -> tuple[Cia402Axis, list[tuple[int, int]]]:
    emcys: list[tuple[int, int]] = []
    axis = Cia402Axis(ServoModel(lag_cycles=0), SetpointRecorder(), DriveStats(), lambda code, reg: emcys.append((code, reg)), "x", 8)
    return axis, emcys


@pytest.mark.parametrize("number,words,option,end", PATHS, ids=[f"t{p[0]}" for p in PATHS])
def test_transition_is_reported_by_the_statusword(number: int, words: list[int], option: int, end: State) -> None:
    axis, _ = make_axis()
    axis.params.quick_stop_option = option
    for word in words:
        axis.set_controlword(word)
    assert axis.transitions[-1] == number
    assert state_of_statusword(axis.statusword) is end


def test_transitions_0_1_at_power_on_and_13_14_15_through_a_fault() -> None:
    axis, emcys = make_axis()
    assert axis.transitions == [0, 1] and state_of_statusword(axis.statusword) is S.SWITCH_ON_DISABLED
    axis.set_controlword(0x06)
    axis.raise_fault(0x2310)
    assert axis.transitions[-2:] == [13, 14] and state_of_statusword(axis.statusword) is S.FAULT
    axis.set_controlword(0x86)
    assert axis.transitions[-1] == 15 and emcys == [(0x2310, 0x03), (0, 0)]


def test_statusword_bit_12_and_setpoint_recording_in_ip() -> None:
    axis, _ = make_axis()
    axis.set_mode(7)
    for word in (0x06, 0x07, 0x0F):
        axis.set_controlword(word)
    assert not axis.statusword & 0x1000
    axis.set_controlword(0x1F)
    assert axis.statusword & 0x1000
    axis.set_ip_setpoint(42)
    axis.step(sync_index=9, sync_counter=-1)
    assert [(r.sync_index, r.mode, r.setpoint_counts) for r in axis.recorder.records()] == [(9, 7, 42)]
    assert axis.position_actual == 42


@pytest.mark.parametrize("setpoint_first", [True, False])
def test_setpoint_with_the_enabling_controlword_counts_in_either_order(setpoint_first: bool) -> None:
    axis, _ = make_axis()
    axis.set_controlword(0x06)
    axis.set_controlword(0x07)
    writes = [lambda: axis.set_target_position(300), lambda: axis.set_controlword(0x0F)]
    for write in writes if setpoint_first else writes[::-1]:
        write()
    axis.step(sync_index=1, sync_counter=-1)
    assert [r.setpoint_counts for r in axis.recorder.records()] == [300]
