"""CiA-301 / CiA-402 numbers shared by the master (fieldbus) and the simulated drives (sim).

Only constants and pure decoding live here, so that the two sides stay independent
implementations of the standard (architecture rule: sim never imports fieldbus).
"""

from __future__ import annotations

import enum

# --- CiA 301 communication objects -------------------------------------------------
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
PREDEFINED_ERROR_FIELD = 0x1003
SYNC_COB_ID = 0x1005
COMM_CYCLE_PERIOD = 0x1006
EMCY_COB_ID = 0x1014
CONSUMER_HEARTBEAT_TIME = 0x1016
PRODUCER_HEARTBEAT_TIME = 0x1017
IDENTITY = 0x1018
RPDO_COMM = 0x1400  # + n-1, n = 1..4
RPDO_MAPPING = 0x1600
TPDO_COMM = 0x1800
TPDO_MAPPING = 0x1A00

# COB-ID bases (pre-defined connection set); add the node id.
COB_SYNC = 0x080
COB_EMCY = 0x080
COB_TPDO = (0x180, 0x280, 0x380, 0x480)
COB_RPDO = (0x200, 0x300, 0x400, 0x500)
COB_SDO_TX = 0x580  # server -> client
COB_SDO_RX = 0x600  # client -> server
COB_HEARTBEAT = 0x700
COB_NMT = 0x000

PDO_COB_ID_INVALID = 0x8000_0000  # bit 31 of sub 1: PDO does not exist / disabled
TRANSMISSION_SYNC_EVERY = 1  # transmission type 1: synchronous, every SYNC


class NmtCommand(enum.IntEnum):
    START = 0x01
    STOP = 0x02
    PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class NmtState(enum.IntEnum):
    """Heartbeat state byte (CiA 301 7.2.8.3.2.1)."""

    BOOTUP = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


# --- CiA 402 objects -------------------------------------------------------------------
ERROR_CODE = 0x603F
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064
FOLLOWING_ERROR_WINDOW = 0x6065
FOLLOWING_ERROR_TIMEOUT = 0x6066
TARGET_POSITION = 0x607A
SOFTWARE_POSITION_LIMIT = 0x607D  # sub 1 min, sub 2 max
QUICK_STOP_DECELERATION = 0x6085
IP_SUB_MODE = 0x60C0
IP_DATA_RECORD = 0x60C1  # sub 1 = position set-point
IP_TIME_PERIOD = 0x60C2  # sub 1 value, sub 2 exponent (period = value * 10**exponent s)
IP_DATA_CONFIGURATION = 0x60C4
FOLLOWING_ERROR_ACTUAL = 0x60F4
SUPPORTED_DRIVE_MODES = 0x6502


class Mode(enum.IntEnum):
    """0x6060 modes of operation used here."""

    PROFILE_POSITION = 1
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8


SUPPORTED_MODE_BIT = {Mode.PROFILE_POSITION: 0, Mode.INTERPOLATED_POSITION: 6, Mode.CYCLIC_SYNC_POSITION: 7}


class Controlword(enum.IntEnum):
    """Commands (CiA 402 table 'device control commands'); bits 0-3 and 7."""

    DISABLE_VOLTAGE = 0x00
    QUICK_STOP = 0x02
    SHUTDOWN = 0x06
    SWITCH_ON = 0x07
    DISABLE_OPERATION = 0x07
    ENABLE_OPERATION = 0x0F
    FAULT_RESET = 0x80


CW_ENABLE_IP = 1 << 4  # IP mode: enable interpolation
CW_HALT = 1 << 8
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # 0 = quick stop active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_IP_ACTIVE = 1 << 12  # IP: interpolation active; CSP: target position ignored=0/used=1
SW_FOLLOWING_ERROR = 1 << 13


class State(enum.Enum):
    """CiA 402 power drive system states."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"


# (mask, value) pairs of the statusword, CiA 402 table 'state coding'.
_STATE_CODING: tuple[tuple[int, int, State], ...] = (
    (0x4F, 0x00, State.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)

# The value bits 0-3, 5, 6 take in each state (what a drive reports).
STATUSWORD_OF_STATE: dict[State, int] = {
    State.NOT_READY_TO_SWITCH_ON: 0x00,
    State.SWITCH_ON_DISABLED: 0x40,
    State.READY_TO_SWITCH_ON: 0x21,
    State.SWITCHED_ON: 0x23,
    State.OPERATION_ENABLED: 0x27,
    State.QUICK_STOP_ACTIVE: 0x07,
    State.FAULT_REACTION_ACTIVE: 0x0F,
    State.FAULT: 0x08,
}


def state_of_statusword(statusword: int) -> State | None:
    """Decode the drive state from a statusword; None if the bits match no state."""
    for mask, value, state in _STATE_CODING:
        if statusword & mask == value:
            return state
    return None


# --- EMCY error codes used (CiA 301 table 'emergency error codes', CiA 402 additions) ----
class EmcyCode(enum.IntEnum):
    NO_ERROR = 0x0000
    GENERIC = 0x1000
    OVERCURRENT = 0x2310
    OVERVOLTAGE = 0x3210
    TEMPERATURE = 0x4210
    COMMUNICATION = 0x8100
    HEARTBEAT = 0x8130  # life guard / heartbeat error
    PDO_LENGTH = 0x8210  # PDO not processed due to length error
    FOLLOWING_ERROR = 0x8611
    SOFTWARE_LIMIT = 0xFF01  # manufacturer specific: software position limit reached
