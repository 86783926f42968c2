"""The CiA-402 power drive system state machine as a pure function (CiA 402-2, 'state machine').

``apply_controlword(state, controlword, previous_controlword, quick_stop_option)`` returns the
new state and the numbers of the transitions taken. Transitions 0/1 (power-on), 12 after a
completed quick-stop ramp, 13/14 (fault) are triggered by the drive, not the controlword.
"""

from __future__ import annotations

from nurbsmotion.can.cia402 import State

S = State
CW_FAULT_RESET_BIT = 0x80

# Device control commands, decoded with the masks of the CiA 402 command table (bits 7, 3-0).
SHUTDOWN = "shutdown"  # 0xxx x110
SWITCH_ON = "switch on"  # 0xxx 0111 (also 'disable operation')
ENABLE_OPERATION = "enable operation"  # 0xxx 1111 ('switch on + enable operation' from RTSO)
DISABLE_VOLTAGE = "disable voltage"  # 0xxx xx0x
QUICK_STOP = "quick stop"  # 0xxx x01x
FAULT_RESET = "fault reset"  # bit 7 (acts on its rising edge)


def decode_command(controlword: int) -> str | None:
    """The device control command of a controlword (None for a bit pattern with no command)."""
    if controlword & CW_FAULT_RESET_BIT:
        return FAULT_RESET
    if controlword & 0x02 == 0x00:
        return DISABLE_VOLTAGE
    if controlword & 0x06 == 0x02:
        return QUICK_STOP
    if controlword & 0x07 == 0x06:
        return SHUTDOWN
    if controlword & 0x0F == 0x07:
        return SWITCH_ON
    if controlword & 0x0F == 0x0F:
        return ENABLE_OPERATION
    return None


def quick_stop_stays_active(option: int) -> bool:
    """0x605A 5..8: stay in QUICK STOP ACTIVE after the stop (transition 16 allowed)."""
    return 5 <= option <= 8


# (state, command) -> list of (transition number, next state)
_TABLE: dict[tuple[State, str], list[tuple[int, State]]] = {
    (S.SWITCH_ON_DISABLED, SHUTDOWN): [(2, S.READY_TO_SWITCH_ON)],
    (S.READY_TO_SWITCH_ON, SWITCH_ON): [(3, S.SWITCHED_ON)],
    (S.READY_TO_SWITCH_ON, ENABLE_OPERATION): [(3, S.SWITCHED_ON), (4, S.OPERATION_ENABLED)],
    (S.READY_TO_SWITCH_ON, DISABLE_VOLTAGE): [(7, S.SWITCH_ON_DISABLED)],
    (S.READY_TO_SWITCH_ON, QUICK_STOP): [(7, S.SWITCH_ON_DISABLED)],
    (S.SWITCHED_ON, ENABLE_OPERATION): [(4, S.OPERATION_ENABLED)],
    (S.SWITCHED_ON, SHUTDOWN): [(6, S.READY_TO_SWITCH_ON)],
    (S.SWITCHED_ON, DISABLE_VOLTAGE): [(10, S.SWITCH_ON_DISABLED)],
    (S.SWITCHED_ON, QUICK_STOP): [(10, S.SWITCH_ON_DISABLED)],
    (S.OPERATION_ENABLED, SWITCH_ON): [(5, S.SWITCHED_ON)],
    (S.OPERATION_ENABLED, SHUTDOWN): [(8, S.READY_TO_SWITCH_ON)],
    (S.OPERATION_ENABLED, DISABLE_VOLTAGE): [(9, S.SWITCH_ON_DISABLED)],
    (S.OPERATION_ENABLED, QUICK_STOP): [(11, S.QUICK_STOP_ACTIVE)],
    (S.QUICK_STOP_ACTIVE, DISABLE_VOLTAGE): [(12, S.SWITCH_ON_DISABLED)],
}


def apply_controlword(
    state: State, controlword: int, previous_controlword: int, quick_stop_option: int
) -> tuple[State, list[int]]:
    """New state and transitions taken when ``controlword`` is written in ``state``."""
    command = decode_command(controlword)
    if command == FAULT_RESET:
        rising = not previous_controlword & CW_FAULT_RESET_BIT
        if state is S.FAULT and rising:
            return S.SWITCH_ON_DISABLED, [15]
        return state, []
    if command is None:
        return state, []
    if state is S.QUICK_STOP_ACTIVE and command == ENABLE_OPERATION and quick_stop_stays_active(quick_stop_option):
        return S.OPERATION_ENABLED, [16]
    steps = _TABLE.get((state, command))
    if not steps:
        return state, []
    return steps[-1][1], [number for number, _ in steps]
