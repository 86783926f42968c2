"""What the drives last reported, written by canopen's notifier thread.

Plain lists whose items the callbacks store (an item store is atomic under the GIL), and a
deque of events (EMCY, NMT state change, TPDO of the wrong length) the supervisor drains
each cycle. ``wire_cycle`` is the master's count of SYNCs on the wire, set by the cycle
loop; a TPDO1 is stamped with it.
"""

from __future__ import annotations

import collections
import time
from typing import Any, Callable

import can

from nurbsmotion.can.arrival_clock import ArrivalClock, WallClockOffset
from nurbsmotion.fieldbus.pdo import TPDO1_FORMAT, TPDO2_FORMAT

EVENT_EMCY, EVENT_NMT, EVENT_BAD_TPDO = 1, 2, 3

Callback = Callable[[int, bytearray, float], None]


def arrival_perf_s(timestamp: float) -> float:
    """A frame's receive timestamp (``time.time()`` based: kernel time on SocketCAN, the
    sender's time on the virtual bus) on the ``perf_counter`` timeline the supervisor judges
    on; a frame without one (0) arrived now, and none arrived later than now."""
    now = time.perf_counter()
    if timestamp <= 0.0:
        return now
    return min(now, timestamp - time.time() + now)


class Feedback:
    """Per-axis answers of the drives (TPDO1/2, EMCY, heartbeat)."""

    def __init__(self, n_axes: int) -> None:
        self.status: list[int | None] = [None] * n_axes
        self.pos: list[int] = [0] * n_axes
        self.fe: list[int | None] = [None] * n_axes
        self.cycle = [-1] * n_axes  # wire cycle when the last TPDO1 arrived
        self.tpdo_count = [0] * n_axes  # TPDO1s received (one answers each SYNC)
        self.time = [0.0] * n_axes  # its receive timestamp (time.time() based)
        self.bad_tpdo = [0] * n_axes
        self.emcy_count = [0] * n_axes
        self.last_emcy: list[int | None] = [None] * n_axes
        self.hb_time = [0.0] * n_axes  # arrival of the last heartbeat (perf_counter timeline)
        self.hb_state: list[int | None] = [None] * n_axes
        self.events: collections.deque[tuple[int, int, int]] = collections.deque()
        self.wire_cycle = 0
        self.sink: Callable[[int, int, int, int, float], None] | None = None  # Master.record_feedback
        # the master's own reception lag, so heartbeats are judged as they arrived (arrival_clock)
        self.arrival = ArrivalClock(lambda: False)

    def watch_reception(self, pending: Callable[[], bool], read_time: Callable[[], float] | None = None,
                        wall_time: Callable[[], float] | None = None) -> "ArrivalListener":
        """Judge on the arrival timeline of the bus whose waiting frames ``pending()`` reports;
        returns the listener to add to the bus's notifier (it stamps every frame handled).
        ``read_time()``: perf_counter when the bus read the frame's batch (the batched
        SocketCAN bus reads the clock once per batch), else the clock is read per frame;
        ``wall_time``: the clock of the frames' timestamps (both injected by tests)."""
        self.arrival = ArrivalClock(pending)
        return ArrivalListener(self.arrival, read_time or time.perf_counter, wall_time)

    def judging_time_s(self) -> float:
        """Now on the frames' arrival timeline (perf_counter based, arrival_clock)."""
        return self.arrival.judging_time(time.perf_counter())

    def tpdo1_callback(self, i: int) -> Callback:
        size = TPDO1_FORMAT.size
        unpack = TPDO1_FORMAT.unpack_from

        def on_tpdo1(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != size:
                self.bad_tpdo[i] += 1
                self.events.append((EVENT_BAD_TPDO, i, len(data)))
                return
            status, position = unpack(data)
            self.status[i], self.pos[i] = status, position
            self.cycle[i] = self.wire_cycle
            self.tpdo_count[i] += 1
            sink = self.sink
            if sink is not None:
                sink(self.wire_cycle, i, status, position, timestamp)
            self.time[i] = timestamp
        return on_tpdo1

    def tpdo2_callback(self, i: int) -> Callback:
        size = TPDO2_FORMAT.size
        unpack = TPDO2_FORMAT.unpack_from

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != size:
                self.bad_tpdo[i] += 1
                self.events.append((EVENT_BAD_TPDO, i, len(data)))
                return
            self.fe[i] = unpack(data)[0]
        return on_tpdo2

    def split_tpdo_callback(self, i: int, size: int, unpack: Callable[[bytearray], tuple[int, ...]],
                            status: bool) -> Callback:
        """A TPDO carrying the statusword alone (``status``) or the position alone."""
        def on_split_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != size:
                self.bad_tpdo[i] += 1
                self.events.append((EVENT_BAD_TPDO, i, len(data)))
                return
            if status:
                self.status[i] = unpack(data)[0]
                return
            self.pos[i] = unpack(data)[0]
            self.cycle[i] = self.wire_cycle
            self.tpdo_count[i] += 1
            self.time[i] = timestamp
            sink = self.sink
            if sink is not None:
                sink(self.wire_cycle, i, self.status[i] or 0, self.pos[i], timestamp)
        return on_split_tpdo

    def emcy_callback(self, i: int) -> Callable[[Any], None]:
        """canopen's EMCY consumer callback: ``entry.code`` (canopen.emcy.EmcyError)."""
        def on_emcy(entry: Any) -> None:
            code = entry.code
            self.emcy_count[i] += 1
            self.last_emcy[i] = code
            self.events.append((EVENT_EMCY, i, code))
        return on_emcy

    def heartbeat_callback(self, i: int, on_state: Callable[[int], None]) -> Callback:
        def on_heartbeat(can_id: int, data: bytearray, timestamp: float) -> None:
            if not data:
                return
            state = data[0] & 0x7F
            self.hb_time[i] = arrival_perf_s(timestamp)
            if state != self.hb_state[i]:
                self.hb_state[i] = state
                self.events.append((EVENT_NMT, i, state))
            on_state(state)
        return on_heartbeat


class ArrivalListener(can.Listener):
    """python-can listener on the master's notifier: every handled frame moves the arrival
    clock (after canopen's own listener has dispatched it to the callbacks).

    Handled at ``read_time()``: on the batched SocketCAN bus the time its batch was read (one
    clock read per batch, not per frame; a frame counts as handled a little before it is,
    which runs the judging time ahead, never behind), else a clock read per frame. The
    wall-clock to perf_counter offset: arrival_clock.WallClockOffset. Every frame
    passes here, and inside User-Mode Linux each clock read is a trapped system call
    (docs/vcan.md, "The drives' lag")."""

    def __init__(self, clock: ArrivalClock, read_time: Callable[[], float] = time.perf_counter,
                 wall_time: Callable[[], float] | None = None) -> None:
        self.clock = clock
        self._read_time = read_time
        self._wall_offset = WallClockOffset(wall_time)

    def on_message_received(self, msg: can.Message) -> None:
        now = self._read_time()
        stamp = msg.timestamp
        self.clock.arrived(now if stamp <= 0.0 else min(now, stamp - self._wall_offset.at(now)), now)
