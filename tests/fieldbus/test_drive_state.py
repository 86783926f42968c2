"""Per-cycle CiA-402 state machine against scripted statuswords (no drive needed)."""

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import STATUSWORD_OF_STATE, State
from nurbsmotion.fieldbus.drive_state import enable_step, is_ready


def _drive(state: State, cw: int) -> State:
    """The drive side of CiA 402 for the commands the master sends (transitions 2, 3, 4, 15, 12)."""
    command = cw & 0x8F
    if state is State.FAULT and cw & 0x80:
        return State.SWITCH_ON_DISABLED
    table = {(State.SWITCH_ON_DISABLED, 0x06): State.READY_TO_SWITCH_ON,
             (State.READY_TO_SWITCH_ON, 0x07): State.SWITCHED_ON,
             (State.SWITCHED_ON, 0x0F): State.OPERATION_ENABLED,
             (State.QUICK_STOP_ACTIVE, 0x00): State.SWITCH_ON_DISABLED}
    return table.get((state, command), state)


def _run(start: State, ip: bool, edge_required: bool = True) -> list[int]:
    state, cw, sent = start, 0x80 if edge_required else 0, []
    for _ in range(10):
        step, new_cw = enable_step(state, cw, ip)
        if state is State.FAULT and not (new_cw & 0x80 and not cw & 0x80):
            state_after = state  # no rising edge: the drive stays in FAULT
        else:
            state_after = _drive(state, new_cw)
        sent.append(new_cw)
        cw, state = new_cw, state_after
        if state is State.OPERATION_ENABLED:
            break
    return sent


def test_from_switch_on_disabled_to_enabled():
    assert _run(State.SWITCH_ON_DISABLED, ip=False, edge_required=False) == [0x06, 0x07, 0x0F]


def test_fault_reset_needs_a_rising_edge_of_bit_7():
    sent = _run(State.FAULT, ip=False)  # bit 7 already high: first send it low
    assert sent[:2] == [0x00, 0x80]
    assert sent[-3:] == [0x06, 0x07, 0x0F]


def test_quick_stop_active_is_left_through_disable_voltage():
    assert _run(State.QUICK_STOP_ACTIVE, ip=True, edge_required=False)[0] == 0x00


def test_ip_mode_sets_bit_4_and_waits_for_ip_active():
    sw = STATUSWORD_OF_STATE[State.OPERATION_ENABLED]
    step, cw = enable_step(State.OPERATION_ENABLED, 0x0F, ip_mode=True)
    assert (step, cw) == ("enable interpolation", 0x1F)
    assert not is_ready(sw, ip_mode=True)
    assert is_ready(sw | c.SW_IP_ACTIVE, ip_mode=True)
    assert is_ready(sw, ip_mode=False)


def test_step_names_for_error_messages():
    assert enable_step(State.SWITCHED_ON, 0, False)[0] == "enable operation"
    assert enable_step(State.READY_TO_SWITCH_ON, 0, False)[0] == "switch on"
    assert enable_step(None, 0, False) == ("shutdown", 0x06)
