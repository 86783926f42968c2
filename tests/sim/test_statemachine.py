"""The CiA-402 state machine, transition by transition (CiA 402-2 figure 'state machine')."""

from __future__ import annotations

import pytest

from nurbsmotion.can.cia402 import State
from nurbsmotion.sim.statemachine import apply_controlword

S = State
# (transition, from state, controlword, to state); quick-stop option 2 unless noted
TRANSITIONS = [
    (2, S.SWITCH_ON_DISABLED, 0x06, S.READY_TO_SWITCH_ON),
    (3, S.READY_TO_SWITCH_ON, 0x07, S.SWITCHED_ON),
    (4, S.SWITCHED_ON, 0x0F, S.OPERATION_ENABLED),
    (5, S.OPERATION_ENABLED, 0x07, S.SWITCHED_ON),
    (6, S.SWITCHED_ON, 0x06, S.READY_TO_SWITCH_ON),
    (7, S.READY_TO_SWITCH_ON, 0x00, S.SWITCH_ON_DISABLED),
    (7, S.READY_TO_SWITCH_ON, 0x02, S.SWITCH_ON_DISABLED),
    (8, S.OPERATION_ENABLED, 0x06, S.READY_TO_SWITCH_ON),
    (9, S.OPERATION_ENABLED, 0x00, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, 0x00, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, 0x02, S.SWITCH_ON_DISABLED),
    (11, S.OPERATION_ENABLED, 0x02, S.QUICK_STOP_ACTIVE),
    (12, S.QUICK_STOP_ACTIVE, 0x00, S.SWITCH_ON_DISABLED),
    (15, S.FAULT, 0x80, S.SWITCH_ON_DISABLED),
]


@pytest.mark.parametrize("number,start,controlword,end", TRANSITIONS, ids=lambda v: str(v))
def test_transition(number: int, start: State, controlword: int, end: State) -> None:
    state, taken = apply_controlword(start, controlword, previous_controlword=0, quick_stop_option=2)
    assert (state, taken) == (end, [number])


def test_transition_16_needs_a_quick_stop_option_that_stays_active() -> None:
    assert apply_controlword(S.QUICK_STOP_ACTIVE, 0x0F, 0x02, quick_stop_option=6) == (S.OPERATION_ENABLED, [16])
    assert apply_controlword(S.QUICK_STOP_ACTIVE, 0x0F, 0x02, quick_stop_option=2) == (S.QUICK_STOP_ACTIVE, [])


def test_switch_on_and_enable_in_one_word_takes_3_then_4() -> None:
    assert apply_controlword(S.READY_TO_SWITCH_ON, 0x0F, 0x06, 2) == (S.OPERATION_ENABLED, [3, 4])


def test_fault_reset_acts_only_on_the_rising_edge_of_bit_7() -> None:
    assert apply_controlword(S.FAULT, 0x80, previous_controlword=0x80, quick_stop_option=2) == (S.FAULT, [])
    assert apply_controlword(S.FAULT, 0x86, previous_controlword=0x06, quick_stop_option=2) == (S.SWITCH_ON_DISABLED, [15])


@pytest.mark.parametrize("controlword", [0x06, 0x07, 0x0F, 0x00])
def test_fault_ignores_every_other_command(controlword: int) -> None:
    assert apply_controlword(S.FAULT, controlword, 0, 2) == (S.FAULT, [])


@pytest.mark.parametrize(
    "start,controlword",
    [(S.SWITCH_ON_DISABLED, 0x07), (S.SWITCH_ON_DISABLED, 0x0F), (S.READY_TO_SWITCH_ON, 0x06), (S.OPERATION_ENABLED, 0x0F)],
)
def test_commands_without_a_transition_keep_the_state(start: State, controlword: int) -> None:
    assert apply_controlword(start, controlword, 0, 2) == (start, [])
