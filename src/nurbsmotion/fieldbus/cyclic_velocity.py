"""A velocity set-point sent with every SYNC in its own RPDO: the csv spindle's 0x60FF.

In cyclic synchronous velocity mode (9) a drive expects 0x60FF with each SYNC (CiA 402-2
csv); the master sends it in the per-cycle path, right after the axes' RPDOs, as a frame
packed by hand like theirs (the cycle writers own the cyclic frames: fieldbus.writer,
fieldbus.bcm_queue), because canopen's PdoMap.transmit per cycle would allocate and go
through the network lock on the cycle thread.

The value of cycle x is a pure function of x: a list of ramp segments, each starting at a
cycle from the value the previous one had there and moving towards its target by at most
``step`` counts/s per cycle (``accel_rpm_s`` in counts/s² times the period). So a writer that
packs a cycle again (the kernel queue repacks the cycles it recomputes and its tail) gets the
same frame, and a new target never jumps: the master applies it (:meth:`apply`) in the cycle
thread at the first cycle it (re)computes from then on, and recomputes every queued cycle
from there (fieldbus.cycle_loop: a request rewinds). When the wire has reached that cycle by the
time the kernel queue writes it (the cycle thread held up), the queue moves the segment's start
beyond the wire (:meth:`postpone`): the ramp starts late, never with a step. A quick stop is a segment with an unlimited
step (the drive's own quick-stop ramp 0x6085 decelerates).
"""

from __future__ import annotations

import math
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass

from nurbsmotion.can import cia402 as c
from nurbsmotion.config import MachineConfig
from nurbsmotion.config.spindle import SpindleConfig, SpindleMode

TARGET_VELOCITY_FORMAT = struct.Struct("<i")  # 0x60FF INTEGER32, counts/s
KEEP_SEGMENTS = 16  # older segments are gone from every ring and history by then


@dataclass(frozen=True)
class RampSegment:
    """From ``start_cycle`` on: ``start_counts_s`` moved towards ``target_counts_s`` by
    ``step_counts_s`` per cycle (inf: at once)."""

    start_cycle: int
    start_counts_s: float
    target_counts_s: float
    step_counts_s: float

    def value_at(self, cycle: int) -> float:
        """v(x) = start + clamp(target - start, ±step·(x - start_cycle)) for x >= start_cycle."""
        change = self.target_counts_s - self.start_counts_s
        reach = self.step_counts_s * max(cycle - self.start_cycle, 0) if math.isfinite(self.step_counts_s) \
            else math.inf
        return self.target_counts_s if abs(change) <= reach else self.start_counts_s + math.copysign(reach, change)

    def end_cycle(self) -> int:
        """The first cycle at the target."""
        if not math.isfinite(self.step_counts_s):
            return self.start_cycle
        return self.start_cycle + math.ceil(abs(self.target_counts_s - self.start_counts_s) / self.step_counts_s)


class CyclicVelocity:
    """0x60FF of node ``node_id`` in RPDO ``cob_id``, one frame per SYNC; ``notify()`` asks
    the master's cycle thread to :meth:`apply` a new target (Master.cyclic_velocity)."""

    def __init__(self, node_id: int, cob_id: int, step_counts_s: float) -> None:
        self.node_id = node_id
        self.cob_id = cob_id
        self.dlc = TARGET_VELOCITY_FORMAT.size
        self.step_counts_s = step_counts_s
        self.notify: Callable[[], None] = lambda: None  # set by the master
        self.wire_cycle: Callable[[], int] = lambda: 0  # set by the master: the last SYNC on the wire
        self._lock = threading.Lock()
        self._segments = [RampSegment(0, 0.0, 0.0, math.inf)]
        self._pending: tuple[float, bool] | None = None
        self._unqueued = False  # the newest segment is not in a kernel queue yet (postpone may move it)

    def request(self, target_counts_s: float, at_once: bool = False) -> None:
        """A new target (any thread); ``at_once``: no ramp (quick stop, disable)."""
        with self._lock:
            self._pending = (float(target_counts_s), at_once)
        self.notify()

    def apply(self, first_cycle: int) -> bool:
        """Cycle thread: the pending target becomes a segment from ``first_cycle`` (the first
        cycle the writer packs again); True when there was one."""
        with self._lock:
            if self._pending is None:
                return False
            target, at_once = self._pending
            self._pending = None
            start = self._value(first_cycle)
            segments = [s for s in self._segments if s.start_cycle < first_cycle]
            segments.append(RampSegment(first_cycle, start, target, math.inf if at_once else self.step_counts_s))
            self._segments = segments[-KEEP_SEGMENTS:]
            self._unqueued = True
            return True

    def postpone(self, first_cycle: int, first_free: int) -> bool:
        """Cycle thread: the kernel queue found the wire (plus its guard) at or past the
        newest segment's start (it starts in [``first_cycle``, ``first_free``)) before that
        segment was ever queued: it starts at ``first_free`` instead, from the value the older
        ones give there, so the cycles before keep the frames already queued (or sent). A
        segment already queued is never moved: the wire may have sent its first frames. True
        when it moved."""
        with self._lock:
            newest = self._segments[-1]
            older = [s for s in self._segments if s.start_cycle < first_cycle]
            if not self._unqueued or not first_cycle <= newest.start_cycle < first_free or not older:
                return False
            self._segments = older
            start = self._value(first_free)
            self._segments = [*older, RampSegment(first_free, start, newest.target_counts_s, newest.step_counts_s)]
            return True

    def queued(self) -> None:
        """Cycle thread: the kernel queue holds every segment now (its TX_SETUP went out)."""
        with self._lock:
            self._unqueued = False

    def _value(self, cycle: int) -> float:
        segment = self._segments[0]
        for s in self._segments:
            if s.start_cycle <= cycle:
                segment = s
        return segment.value_at(cycle)

    def value_at(self, cycle: int) -> int:
        """0x60FF of cycle ``cycle`` (counts/s)."""
        with self._lock:
            return int(round(self._value(cycle)))

    def pack(self, data: bytearray, cycle: int) -> None:
        """The RPDO data of ``cycle`` (what the writers call per cycle)."""
        TARGET_VELOCITY_FORMAT.pack_into(data, 0, self.value_at(cycle))

    def ramp_done(self) -> bool:
        """The last target is on the wire: applied, and its ramp ended by the current SYNC."""
        with self._lock:
            return self._pending is None and self._segments[-1].end_cycle() <= self.wire_cycle()

    @property
    def target_counts_s(self) -> float:
        with self._lock:
            return self._pending[0] if self._pending is not None else self._segments[-1].target_counts_s


def spindle_cyclic_velocity(config: MachineConfig) -> CyclicVelocity | None:
    """The csv spindle's 0x60FF slot (RPDO1, COB-ID 0x200 + node id; ramp step accel_counts_s2
    x cycle period), or None without a csv spindle."""
    spindle = config.spindle
    if not isinstance(spindle, SpindleConfig) or spindle.mode is not SpindleMode.CSV:
        return None
    return CyclicVelocity(spindle.node_id, c.COB_RPDO[0] + spindle.node_id, spindle.accel_counts_s2 * config.cycle_period_s)
