"""Non-blocking CiA-402 state machine of the master: one controlword per drive per cycle.

Each cycle the master looks at the latest statusword (from TPDO1) and answers with the
controlword that moves the drive one transition closer to OPERATION ENABLED (CiA 402
'device control'): FAULT -> fault reset (rising edge of bit 7), SWITCH ON DISABLED ->
shutdown, READY TO SWITCH ON -> switch on, SWITCHED ON -> enable operation. In IP mode
bit 4 (enable interpolation) is set once the drive is enabled, and the drive counts as
ready only when statusword bit 12 (IP active) answers it.
"""

from __future__ import annotations

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import State
from nurbsmotion.config import AxisConfig

CW_ENABLED = int(c.Controlword.ENABLE_OPERATION)
CW_ENABLED_IP = CW_ENABLED | c.CW_ENABLE_IP
CW_QUICK_STOP = int(c.Controlword.QUICK_STOP)
CW_DISABLE_VOLTAGE = int(c.Controlword.DISABLE_VOLTAGE)
CW_SHUTDOWN = int(c.Controlword.SHUTDOWN)


def enable_step(state: State | None, previous_controlword: int, ip_mode: bool) -> tuple[str, int]:
    """(name of the step under way, controlword to send) towards OPERATION ENABLED."""
    if state is State.FAULT:
        # fault reset acts on the rising edge of bit 7: send 0 first if bit 7 is already high
        return "fault reset", 0 if previous_controlword & c.Controlword.FAULT_RESET else int(c.Controlword.FAULT_RESET)
    if state is State.FAULT_REACTION_ACTIVE:
        return "fault reset", 0
    if state is State.QUICK_STOP_ACTIVE:
        return "leave quick stop", CW_DISABLE_VOLTAGE
    if state in (State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON, None):
        return "shutdown", CW_SHUTDOWN
    if state is State.READY_TO_SWITCH_ON:
        return "switch on", int(c.Controlword.SWITCH_ON)
    if state is State.SWITCHED_ON:
        return "enable operation", CW_ENABLED
    # OPERATION ENABLED
    return ("enable interpolation", CW_ENABLED_IP) if ip_mode else ("enabled", CW_ENABLED)


def is_ready(statusword: int, ip_mode: bool) -> bool:
    """Enabled and (IP mode) interpolation active: the drive follows set-points."""
    if c.state_of_statusword(statusword) is not State.OPERATION_ENABLED:
        return False
    return bool(statusword & c.SW_IP_ACTIVE) if ip_mode else True


def running_controlword(ip_mode: bool) -> int:
    """Controlword while streaming set-points to an enabled drive."""
    return CW_ENABLED_IP if ip_mode else CW_ENABLED


def state_name(statusword: int | None) -> str:
    if statusword is None:
        return "NO STATUSWORD YET"
    state = c.state_of_statusword(statusword)
    return state.value if state is not None else f"UNKNOWN STATUSWORD 0x{statusword:04X}"


def mode_of(axis: AxisConfig) -> c.Mode:
    """The CiA-402 mode (0x6060) of an axis' ``mode``: ip or csp."""
    return c.Mode.INTERPOLATED_POSITION if axis.mode == "ip" else c.Mode.CYCLIC_SYNC_POSITION
