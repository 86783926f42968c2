"""CiA-402 homing mode (6) as a pure, non-blocking per-cycle procedure; ``method: here``.

The master runs a drive homing in three parts:

1. :func:`homing_plan`: the SDO writes to do first (0x6098 method, 0x6099:01/02 speeds,
   0x609A acceleration, 0x607C home offset unless 0, then 0x6060 = 6), the mode to read back from
   0x6061, and the writes that restore the streaming mode afterwards. Values come from
   :func:`homing_drive_values`, the one place where mm become drive units.
2. :class:`HomingProcedure`: each cycle, given the drive's statusword (TPDO1), the
   controlword to send (RPDO1) and, once finished, the outcome. CiA 402-2 homing mode:
   controlword bit 4 rising edge in OPERATION ENABLED starts homing; statusword bit 12
   (homing attained), bit 13 (homing error) and bit 10 (target reached) report it:

   ====== ====== ====== =======================================================
   bit 13 bit 12 bit 10 meaning
   ====== ====== ====== =======================================================
   0      0      0      homing in progress
   0      0      1      homing interrupted or not started
   0      1      0      homing attained, target not reached (still moving)
   0      1      1      homing completed
   1      x      x      homing error
   ====== ====== ====== =======================================================

3. After the outcome: the restore writes (0x6060 back to IP/CSP), then the master reads the
   position actual and holds there.

``method: here`` needs no drive: :func:`here_offset_counts` gives the axis map offset that
makes the current position read ``offset_mm``.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import State
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.drive_state import enable_step
from nurbsmotion.config.homing import HomingConfig

HOMING_METHOD = 0x6098
HOMING_SPEEDS = 0x6099  # sub 1: search for switch, sub 2: search for zero
HOMING_ACCELERATION = 0x609A
HOME_OFFSET = 0x607C
MODE_HOMING = 6
CW_START_HOMING = 1 << 4  # operation mode specific bit 4: homing operation start
SW_HOMING_ATTAINED = 1 << 12
SW_HOMING_ERROR = 1 << 13
UINT32_MAX = 2**32 - 1
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
# Statuswords right after the rising edge may predate it: an RPDO sent after SYNC n takes
# effect at SYNC n+1 (CiA 301), whose TPDO the master reads in cycle n+2; one more cycle of
# margin for a TPDO that arrives after the master looked. A drive may also need some time to
# start its homing and clear bit 10 ("not started"): an assumed 100 ms. Waiting only delays
# the verdict on a fast homing (35/37) by that much.
ACK_CYCLES = 3
ACK_S = 0.1
# After the acknowledge, "bit 10 without bit 12" may still be the statusword from before the
# start when the drive's answers lag the wire (a drive process inside User-Mode Linux lagged
# 0.7-1.8 s; the vcan homing test failed on it): before the drive has shown the homing under
# way (bit 10 low, or bit 12 / 13), that word counts as "not started yet" for START_S. A drive
# that really does not start is reported that much later; nothing moves meanwhile.
START_S = 3.0


# --------------------------------------------------------------------------- drive values
@dataclass(frozen=True)
class HomingDriveValues:
    """What the drive is given, in its own units."""

    method: int
    speed_search: int  # 0x6099:01, drive velocity units
    speed_zero: int  # 0x6099:02
    acceleration: int  # 0x609A, drive acceleration units
    home_offset: int  # 0x607C, counts


def home_counts(offset_mm: float, counts_per_mm: float, invert: bool, offset_counts: int) -> int:
    """Counts at which the axis map reads ``offset_mm``: round(±offset_mm·counts_per_mm) + offset_counts."""
    sign = -1.0 if invert else 1.0
    return round(sign * offset_mm * counts_per_mm) + offset_counts


def _drive_unit(where: str, value_mm: float, counts_per_mm: float, counts_per_unit: float, low: int = 1) -> int:
    value = round(value_mm * counts_per_mm / counts_per_unit)
    if not low <= value <= UINT32_MAX:
        raise InputError(where, f"{value_mm:g} mm is {value} drive units ({counts_per_mm:g} counts/mm, "
                         f"{counts_per_unit:g} counts per unit): outside {low}..{UINT32_MAX}")
    return value


def homing_drive_values(homing: HomingConfig, counts_per_mm: float, invert: bool, offset_counts: int,
                        axis_name: str) -> HomingDriveValues:
    """The drive units of a homing configuration (the only mm -> drive unit conversion here):

    - 0x6099:0n = round(speed_mm_s · counts_per_mm / speed_unit_counts_s)
      (speed_unit_counts_s = counts/s one drive velocity unit stands for: 1 for counts/s,
      counts_per_rev/60 for a drive in rpm);
    - 0x609A = round(accel_mm_s2 · counts_per_mm / accel_unit_counts_s2);
    - 0x607C = home_offset_sign · home_counts(offset_mm): the drive reports
      home_offset_sign · 0x607C at the home position (CiA 402: zero = home + 0x607C, so -1),
      and the axis map must read offset_mm there.

    A value that rounds to 0 or leaves UNSIGNED32 / INTEGER32 is an InputError naming the field.
    """
    if not homing.on_drive:
        raise ValueError("method 'here' has no drive values")
    where = f"axis {axis_name}: homing"
    speeds = [0, 0, 0]
    if homing.moves:
        assert homing.speed_search_mm_s and homing.speed_zero_mm_s and homing.accel_mm_s2
        speeds = [_drive_unit(f"{where}.speed_search_mm_s", homing.speed_search_mm_s, counts_per_mm,
                              homing.speed_unit_counts_s),
                  _drive_unit(f"{where}.speed_zero_mm_s", homing.speed_zero_mm_s, counts_per_mm,
                              homing.speed_unit_counts_s),
                  _drive_unit(f"{where}.accel_mm_s2", homing.accel_mm_s2, counts_per_mm,
                              homing.accel_unit_counts_s2)]
    offset = homing.home_offset_sign * home_counts(homing.offset_mm, counts_per_mm, invert, offset_counts)
    if not INT32_MIN <= offset <= INT32_MAX:
        raise InputError(f"{where}.offset_mm", f"{homing.offset_mm:g} mm is {offset} counts: outside INTEGER32")
    assert isinstance(homing.method, int)
    return HomingDriveValues(homing.method, speeds[0], speeds[1], speeds[2], offset)


@dataclass(frozen=True)
class ObjectWrite:
    """One SDO download of the plan. ``fmt`` is the object's CiA-402 data type as a struct
    code, for a master that writes without the drive's EDS (with it, the EDS types the value)."""

    step: str
    index: int
    subindex: int
    fmt: str
    value: int

    def data(self) -> bytes:
        return struct.pack(self.fmt, self.value)


@dataclass(frozen=True)
class HomingPlan:
    """SDO work around one drive homing: ``writes`` before, read 0x6061 == ``mode_check``,
    then the per-cycle procedure, then ``restore``."""

    writes: tuple[ObjectWrite, ...]
    mode_check: int
    restore: tuple[ObjectWrite, ...]


@dataclass(frozen=True)
class OffsetObject:
    """Where the home offset goes: 0x607C (CiA 402) or a vendor object (``fmt``: its type)."""

    index: int = HOME_OFFSET
    subindex: int = 0
    fmt: str = "<i"


def homing_plan(values: HomingDriveValues, streaming_mode: c.Mode,
                offset_object: OffsetObject | None = OffsetObject()) -> HomingPlan:
    """The SDO writes of a homing, in order (objects of CiA 402-2 homing mode). The home
    offset goes to ``offset_object`` unless it is 0 (nothing to write) or ``offset_object``
    is None (the master applies it: fieldbus.homing_check)."""
    step = "homing configuration"
    writes = [ObjectWrite(step, HOMING_METHOD, 0, "<b", values.method)]
    if values.speed_search:  # methods 35/37 do not move: speeds and acceleration are not written
        writes += [ObjectWrite(step, HOMING_SPEEDS, 1, "<I", values.speed_search),
                   ObjectWrite(step, HOMING_SPEEDS, 2, "<I", values.speed_zero),
                   ObjectWrite(step, HOMING_ACCELERATION, 0, "<I", values.acceleration)]
    if offset_object is not None and values.home_offset != 0:
        writes.append(ObjectWrite(step, offset_object.index, offset_object.subindex, offset_object.fmt,
                                  values.home_offset))
    writes.append(ObjectWrite("set homing mode", c.MODES_OF_OPERATION, 0, "<b", MODE_HOMING))
    restore = (ObjectWrite("restore streaming mode", c.MODES_OF_OPERATION, 0, "<b", int(streaming_mode)),)
    return HomingPlan(tuple(writes), MODE_HOMING, restore)


def here_offset_counts(position_counts: int, offset_mm: float, counts_per_mm: float, invert: bool) -> int:
    """``method: here``: the axis map offset_counts with which ``position_counts`` reads
    ``offset_mm`` (mm = sign·(counts - offset_counts)/counts_per_mm solved for offset_counts)."""
    return position_counts - home_counts(offset_mm, counts_per_mm, invert, 0)


# --------------------------------------------------------------------------- procedure
class Phase(enum.Enum):
    ENABLING = "enabling"  # towards OPERATION ENABLED, bit 4 low
    ARMED = "armed"  # OPERATION ENABLED with bit 4 low: the rising edge comes next cycle
    STARTED = "started"  # bit 4 high; statuswords may still predate the edge
    RUNNING = "running"  # bit 4 high; bits 10/12/13 are this homing's
    HOMED = "homed"
    FAILED = "failed"


class Event(enum.Enum):
    """What one statusword says, for the transition table."""

    NO_STATUS = "no statusword yet"
    FAULT = "fault"
    NOT_ENABLED = "not enabled"
    ACK_PENDING = "acknowledge pending"  # enabled, but the statusword may predate the edge
    IN_PROGRESS = "in progress"
    ATTAINED = "attained"  # bit 12 without bit 10: still moving to the home position
    COMPLETED = "completed"
    INTERRUPTED = "interrupted"
    HOMING_ERROR = "homing error"
    TIMEOUT = "timeout"
    CANCELLED = "cancelled"  # the operator stopped the homing (cancel())


P, E = Phase, Event
_ENABLED_EVENTS = (E.ACK_PENDING, E.IN_PROGRESS, E.ATTAINED, E.COMPLETED, E.INTERRUPTED, E.HOMING_ERROR)
_TABLE: dict[tuple[Phase, Event], Phase] = {
    (P.ENABLING, E.NO_STATUS): P.ENABLING,
    (P.ENABLING, E.NOT_ENABLED): P.ENABLING,
    **{(P.ENABLING, e): P.ARMED for e in _ENABLED_EVENTS},
    **{(P.ARMED, e): P.STARTED for e in _ENABLED_EVENTS},
    (P.STARTED, E.ACK_PENDING): P.STARTED,
    (P.STARTED, E.IN_PROGRESS): P.RUNNING,
    (P.STARTED, E.ATTAINED): P.RUNNING,
    (P.STARTED, E.COMPLETED): P.HOMED,
    (P.RUNNING, E.IN_PROGRESS): P.RUNNING,
    (P.RUNNING, E.ATTAINED): P.RUNNING,
    (P.RUNNING, E.COMPLETED): P.HOMED,
}  # every pair not listed (fault, disabled, error, interrupted, time-out) -> FAILED


def classify(statusword: int | None, acknowledged: bool) -> Event:
    """The event of one statusword (``acknowledged``: it postdates the rising edge)."""
    if statusword is None:
        return E.NO_STATUS
    state = c.state_of_statusword(statusword)
    if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
        return E.FAULT
    if state is not State.OPERATION_ENABLED:
        return E.NOT_ENABLED
    if not acknowledged:
        return E.ACK_PENDING
    if statusword & SW_HOMING_ERROR:
        return E.HOMING_ERROR
    if statusword & SW_HOMING_ATTAINED:
        return E.COMPLETED if statusword & c.SW_TARGET_REACHED else E.ATTAINED
    return E.INTERRUPTED if statusword & c.SW_TARGET_REACHED else E.IN_PROGRESS


@dataclass(frozen=True)
class HomingOutcome:
    homed: bool
    reason: str  # one line naming the node; "" when homed


@dataclass(frozen=True)
class HomingStep:
    controlword: int
    phase: Phase
    outcome: HomingOutcome | None  # set once, in the cycle the procedure ends


class HomingProcedure:
    """One drive's homing, one :meth:`step` per cycle (the 0x6060 = 6 write is done and
    read back before the first step). No I/O, no clock: time is counted in cycles."""

    def __init__(self, node_id: int, method: int, cycle_period_s: float, timeout_s: float,
                 ack_s: float = ACK_S, start_s: float = START_S) -> None:
        self.node_id = node_id
        self.method = method
        self.timeout_s = timeout_s
        self.timeout_cycles = max(1, math.ceil(timeout_s / cycle_period_s - 1e-9))
        self.ack_cycles = max(ACK_CYCLES, math.ceil(ack_s / cycle_period_s - 1e-9))
        self.start_cycles = max(self.ack_cycles, math.ceil(start_s / cycle_period_s - 1e-9))
        self.phase = Phase.ENABLING
        self.cycles = 0
        self._started_at = -1
        self._controlword = 0
        self.cancelled = False
        self.outcome: HomingOutcome | None = None

    @property
    def done(self) -> bool:
        return self.phase in (Phase.HOMED, Phase.FAILED)

    def snapshot(self) -> tuple[Phase, int, int, int, bool, HomingOutcome | None]:
        """The state after a step, for a master that computes cycles ahead and may redo them."""
        return (self.phase, self.cycles, self._started_at, self._controlword, self.cancelled, self.outcome)

    def restore(self, state: tuple[Phase, int, int, int, bool, HomingOutcome | None]) -> None:
        self.phase, self.cycles, self._started_at, self._controlword, self.cancelled, self.outcome = state

    def cancel(self) -> None:
        """Stop the homing at the next step (bit 4 low: the drive stops its search)."""
        self.cancelled = True

    def step(self, statusword: int | None) -> HomingStep:
        """The controlword for this cycle given the latest statusword; ends with an outcome."""
        if self.done:
            return HomingStep(self._controlword, self.phase, None)
        self.cycles += 1
        acknowledged = self._started_at >= 0 and self.cycles - self._started_at > self.ack_cycles
        event = E.TIMEOUT if self.cycles > self.timeout_cycles else classify(statusword, acknowledged)
        if self.cancelled:
            event = E.CANCELLED
        if event is E.INTERRUPTED and self.phase is Phase.STARTED and self.cycles - self._started_at <= self.start_cycles:
            event = E.ACK_PENDING  # not started yet, or a statusword older than the start (START_S)
        previous = self.phase
        self.phase = _TABLE.get((previous, event), Phase.FAILED)
        if self.phase is Phase.STARTED and previous is not Phase.STARTED:
            self._started_at = self.cycles
        self._controlword = self._controlword_for(statusword)
        outcome = None
        if self.done:
            outcome = self.outcome = HomingOutcome(self.phase is Phase.HOMED, self._reason(event, statusword))
        return HomingStep(self._controlword, self.phase, outcome)

    def _controlword_for(self, statusword: int | None) -> int:
        if self.phase is Phase.ENABLING:
            state = c.state_of_statusword(statusword) if statusword is not None else None
            return enable_step(state, self._controlword, ip_mode=False)[1]
        enabled = int(c.Controlword.ENABLE_OPERATION)
        if self.phase in (Phase.STARTED, Phase.RUNNING):
            return enabled | CW_START_HOMING
        if self.phase is Phase.FAILED and statusword is not None \
                and c.state_of_statusword(statusword) is not State.OPERATION_ENABLED:
            return self._controlword & ~CW_START_HOMING  # not enabled: no new command
        return enabled  # ARMED, HOMED, FAILED while enabled: bit 4 low ends/interrupts homing

    def _reason(self, event: Event, statusword: int | None) -> str:
        if self.phase is Phase.HOMED:
            return ""
        word = "no statusword" if statusword is None else f"statusword 0x{statusword:04X}"
        where = f"node {self.node_id}: homing method {self.method}"
        if event is E.TIMEOUT:
            return f"{where}: not completed within {self.timeout_s:g} s ({word})"
        if event is E.CANCELLED:
            return f"{where}: stopped on request ({word})"
        if event is E.HOMING_ERROR:
            return f"{where}: the drive reports a homing error ({word}, bit 13)"
        if event is E.INTERRUPTED:
            return f"{where}: the drive interrupted or did not start homing ({word}, bit 10 without bit 12)"
        if event is E.FAULT:
            return f"{where}: the drive went to FAULT ({word})"
        state = c.state_of_statusword(statusword) if statusword is not None else None
        return f"{where}: the drive left OPERATION ENABLED (now {state.value if state else word})"
