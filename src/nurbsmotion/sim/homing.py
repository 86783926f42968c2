"""Homing mode (6) of the simulated drive as a pure per-tick function (CiA 402-2 homing).

The machine has limit switches and encoder index pulses at fixed *raw* positions (counts
at power-on, before any homing). The drive reports ``position = raw + shift``; homing sets
``shift`` so that the home position reads ``-0x607C`` (CiA 402: zero position = home
position + home offset).

Methods (CiA 402-2 figures; d = search direction):

====== ================================================================================
1 / 2  move d = -/+ at 0x6099:01 to the negative/positive limit switch, reverse at
       0x6099:02, home = first index pulse after the switch is left
17/18  as 1/2 without index: home = where the switch is seen released
33/34  move d = -/+ at 0x6099:02, home = first index pulse
35/37  home = current position, no motion
====== ================================================================================

Speed changes are limited by 0x609A (v += clamp(v_target - v, ±a·T); x += (v_old + v)·T/2).
Switches are sampled once per tick (at the new position, like a drive polling its inputs);
index pulses are latched exactly (encoder hardware capture). A limit switch that is not the
one searched ends homing with an error; clearing controlword bit 4 interrupts it. Both
stop with 0x609A. Statusword bits 10 / 12 / 13 follow the CiA 402-2 homing table.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

SW_TARGET_REACHED = 1 << 10
SW_HOMING_ATTAINED = 1 << 12
SW_HOMING_ERROR = 1 << 13
SUPPORTED_METHODS = (1, 2, 17, 18, 33, 34, 35, 37)
MODE_HOMING = 6  # 0x6060 value
CW_START_HOMING = 1 << 4  # controlword bit 4 in homing mode: homing operation start
SUPPORTED_MODE_BIT = 5  # 0x6502 bit for homing mode
# The homing objects a drive's EDS must list (index, subindex, CiA 301 data type).
HOMING_OBJECTS = ((0x6098, 0, "INTEGER8"), (0x6099, 1, "UNSIGNED32"), (0x6099, 2, "UNSIGNED32"),
                  (0x609A, 0, "UNSIGNED32"), (0x607C, 0, "INTEGER32"))


class Limit(enum.Enum):
    NEGATIVE = -1
    POSITIVE = 1


@dataclass(frozen=True)
class MethodSpec:
    """``direction`` of the first search; ``switch`` searched first (None: index only)."""

    direction: int
    switch: Limit | None
    index: bool


METHODS: dict[int, MethodSpec | None] = {
    1: MethodSpec(-1, Limit.NEGATIVE, True),
    2: MethodSpec(1, Limit.POSITIVE, True),
    17: MethodSpec(-1, Limit.NEGATIVE, False),
    18: MethodSpec(1, Limit.POSITIVE, False),
    33: MethodSpec(-1, None, True),
    34: MethodSpec(1, None, True),
    35: None,  # current position (CiA 402 v3; 37 in v4)
    37: None,
}


@dataclass(frozen=True)
class HomeSensors:
    """The machine around the motor, in raw counts. A limit switch is active at raw <= the
    negative / >= the positive limit; index pulses at index_phase + k·index_pitch."""

    negative_limit_counts: float | None = None
    positive_limit_counts: float | None = None
    index_pitch_counts: float | None = None
    index_phase_counts: float = 0.0

    def active_limit(self, raw: float) -> Limit | None:
        if self.negative_limit_counts is not None and raw <= self.negative_limit_counts:
            return Limit.NEGATIVE
        if self.positive_limit_counts is not None and raw >= self.positive_limit_counts:
            return Limit.POSITIVE
        return None

    def index_between(self, start: float, end: float) -> float | None:
        """The first index pulse passed moving from ``start`` (excluded) to ``end`` (included)."""
        pitch = self.index_pitch_counts
        if pitch is None or start == end:
            return None
        if end > start:
            k = math.floor((start - self.index_phase_counts) / pitch) + 1
            pulse = self.index_phase_counts + k * pitch
            return pulse if pulse <= end else None
        k = math.ceil((start - self.index_phase_counts) / pitch) - 1
        pulse = self.index_phase_counts + k * pitch
        return pulse if pulse >= end else None


@dataclass(frozen=True)
class HomingSetup:
    """The drive's homing objects (its units: counts, counts/s, counts/s²)."""

    method: int  # 0x6098
    speed_search_counts_s: float  # 0x6099:01
    speed_zero_counts_s: float  # 0x6099:02
    accel_counts_s2: float  # 0x609A
    home_offset_counts: int  # 0x607C: the home reads minus it


def setup_from_objects(read: Callable[[int, int], int], home_object: tuple[int, int] | None = None) -> HomingSetup:
    """The drive's homing objects as a HomingSetup; ``read(index, subindex)`` is the drive's
    object value (what an SDO upload would return). ``home_object`` (index, sign): a vendor
    object whose value the home reads times sign (maxon EPOS4 0x30B0 "home position": +1),
    in place of 0x607C (the home reads -0x607C)."""
    home_offset = read(0x607C, 0) if home_object is None else -home_object[1] * read(home_object[0], 0)
    return HomingSetup(method=read(0x6098, 0), speed_search_counts_s=float(read(0x6099, 1)),
                       speed_zero_counts_s=float(read(0x6099, 2)), accel_counts_s2=float(read(0x609A, 0)),
                       home_offset_counts=home_offset)


class Phase(enum.Enum):
    NOT_STARTED = "not started"
    SEARCH_SWITCH = "search switch"
    LEAVE_SWITCH = "leave switch"
    SEARCH_INDEX = "search index"
    STOPPING_HOMED = "stopping, homed"
    HOMED = "homed"
    STOPPING_ERROR = "stopping, error"
    ERROR = "error"
    STOPPING_INTERRUPTED = "stopping, interrupted"
    INTERRUPTED = "interrupted"


SEARCHING = (Phase.SEARCH_SWITCH, Phase.LEAVE_SWITCH, Phase.SEARCH_INDEX)
AT_REST = (Phase.NOT_STARTED, Phase.HOMED, Phase.ERROR, Phase.INTERRUPTED)
_STOPPED_PHASE = {Phase.STOPPING_HOMED: Phase.HOMED, Phase.STOPPING_ERROR: Phase.ERROR,
                  Phase.STOPPING_INTERRUPTED: Phase.INTERRUPTED}

# (statusword bit 13, bit 12, bit 10) per phase: CiA 402-2 homing mode statusword table
_STATUS_BITS: dict[Phase, int] = {
    Phase.NOT_STARTED: SW_TARGET_REACHED,
    Phase.INTERRUPTED: SW_TARGET_REACHED,
    Phase.STOPPING_INTERRUPTED: 0,
    Phase.SEARCH_SWITCH: 0,
    Phase.LEAVE_SWITCH: 0,
    Phase.SEARCH_INDEX: 0,
    Phase.STOPPING_HOMED: SW_HOMING_ATTAINED,
    Phase.HOMED: SW_HOMING_ATTAINED | SW_TARGET_REACHED,
    Phase.STOPPING_ERROR: SW_HOMING_ERROR,
    Phase.ERROR: SW_HOMING_ERROR | SW_TARGET_REACHED,
}


@dataclass(frozen=True)
class HomingState:
    """position = raw + shift (what 0x6064 reports), speed in counts/s."""

    phase: Phase
    raw: float
    shift: float
    speed_counts_s: float = 0.0
    start_bit: bool = False  # controlword bit 4 at the last tick (rising edge starts homing)

    @property
    def position(self) -> float:
        return self.raw + self.shift

    @property
    def statusword_bits(self) -> int:
        """Bits 10, 12, 13 of the statusword in homing mode."""
        return _STATUS_BITS[self.phase]


def idle(position_counts: float, shift: float = 0.0) -> HomingState:
    """The state on entering homing mode at ``position_counts`` (0x6064)."""
    return HomingState(Phase.NOT_STARTED, position_counts - shift, shift)


def supported(method: int) -> bool:
    """Whether this drive accepts ``method`` in 0x6098 (others: SDO abort 'value range')."""
    return method in METHODS


def homing_tick(state: HomingState, setup: HomingSetup, sensors: HomeSensors, start_bit: bool,
                period_s: float) -> HomingState:
    """One drive cycle of homing mode: start on bit 4's rising edge, move, detect, stop."""
    rising = start_bit and not state.start_bit
    state = replace(state, start_bit=start_bit)
    if state.phase in AT_REST:
        return _start(state, setup, sensors) if rising else state
    if not start_bit and state.phase in SEARCHING:
        state = replace(state, phase=Phase.STOPPING_INTERRUPTED)
    elif setup.method not in METHODS and state.phase in SEARCHING:  # 0x6098 rewritten while homing
        state = replace(state, phase=Phase.STOPPING_ERROR)
    target = _target_speed(state, setup)
    speed = _approach(state.speed_counts_s, target, setup.accel_counts_s2 * period_s)
    raw = state.raw + (state.speed_counts_s + speed) * period_s / 2.0
    moved = replace(state, raw=raw, speed_counts_s=speed)
    if state.phase in _STOPPED_PHASE:
        return replace(moved, phase=_STOPPED_PHASE[state.phase]) if speed == 0.0 and target == 0.0 else moved
    return _detect(state.raw, moved, setup, sensors)


def _start(state: HomingState, setup: HomingSetup, sensors: HomeSensors) -> HomingState:
    spec = METHODS.get(setup.method)
    if setup.method not in METHODS:
        return replace(state, phase=Phase.ERROR)
    if spec is None:  # 35 / 37: the current position is home
        return _homed_at(replace(state, phase=Phase.HOMED), state.raw, setup)
    if spec.switch is None:
        return replace(state, phase=Phase.SEARCH_INDEX)
    on_switch = sensors.active_limit(state.raw) is spec.switch
    return replace(state, phase=Phase.LEAVE_SWITCH if on_switch else Phase.SEARCH_SWITCH)


def _target_speed(state: HomingState, setup: HomingSetup) -> float:
    spec = METHODS.get(setup.method)
    if state.phase not in SEARCHING or spec is None:
        return 0.0
    if state.phase is Phase.SEARCH_SWITCH:
        return spec.direction * setup.speed_search_counts_s
    if state.phase is Phase.SEARCH_INDEX and spec.switch is None:
        return spec.direction * setup.speed_zero_counts_s
    return -spec.direction * setup.speed_zero_counts_s  # back off the switch, then on to the index


def _approach(speed: float, target: float, max_change: float) -> float:
    if abs(target - speed) <= max_change:
        return target
    return speed + math.copysign(max_change, target - speed)


def _detect(start_raw: float, state: HomingState, setup: HomingSetup, sensors: HomeSensors) -> HomingState:
    """Switch and index events of the tick that moved from ``start_raw`` to ``state.raw``."""
    spec = METHODS[setup.method]
    assert spec is not None
    limit = sensors.active_limit(state.raw)
    if state.phase is Phase.SEARCH_SWITCH:
        if limit is spec.switch:
            return replace(state, phase=Phase.LEAVE_SWITCH)
        return replace(state, phase=Phase.STOPPING_ERROR) if limit is not None else state
    if state.phase is Phase.LEAVE_SWITCH:
        moving_off = state.speed_counts_s * spec.direction < 0
        if limit is None and moving_off:
            if not spec.index:
                return _homed_at(replace(state, phase=Phase.STOPPING_HOMED), state.raw, setup)
            return replace(state, phase=Phase.SEARCH_INDEX)  # index capture armed from here on
        if limit is not None and limit is not spec.switch:
            return replace(state, phase=Phase.STOPPING_ERROR)
        return state
    return _search_index(start_raw, state, setup, sensors)


def _search_index(start_raw: float, state: HomingState, setup: HomingSetup, sensors: HomeSensors) -> HomingState:
    pulse = sensors.index_between(start_raw, state.raw)
    if pulse is not None:
        return _homed_at(replace(state, phase=Phase.STOPPING_HOMED), pulse, setup)
    if sensors.active_limit(state.raw) is not None:
        return replace(state, phase=Phase.STOPPING_ERROR)
    return state


def _homed_at(state: HomingState, home_raw: float, setup: HomingSetup) -> HomingState:
    """The home position reads -0x607C from now on (CiA 402: zero = home + home offset)."""
    return replace(state, shift=-setup.home_offset_counts - home_raw)
