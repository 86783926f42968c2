"""Time on the frames' arrival timeline, for whoever judges a CANopen timeout in Python.

A drive firmware stamps each frame as it arrives (an interrupt) and judges its timeouts
(CiA 301 heartbeat consumer 0x1016, SYNC loss, RPDO event timers 0x14xx:05) against those
stamps, in real time; a master's heartbeat consumer (CiA 301 §7.2.8.3.2.2) judges the same way.
A Python process handles frames after they arrive: inside a starved guest (User-Mode Linux on a
busy host) by up to seconds, and on a loaded machine whenever its receive thread waits for the
CPU or the GIL. Judged against the process's own clock, a backlog of frames that all arrived in
time reads as a loss.

So the simulated drives (sim/drive.py) and the master's supervisor (fieldbus/supervisor.py)
judge on the arrival timeline, never more leniently than the frames show:

- each frame's arrival time is its receive timestamp (kernel time on SocketCAN, the sender's
  time on python-can's in-process virtual bus);
- while frames wait in the socket, the judging time is the arrival of the last frame handled:
  the bus is known up to there, and a heartbeat missing between stamped frames is found just
  as a firmware finds it;
- once nothing waits, the judging time runs on from there in real time (``last arrival +
  (now - last handled)``): a bus gone silent is found the timeout after the last arrival,
  seen through the process's lag.

A neutral module (like socketcan_batch): it knows no CANopen object, so the simulator and the
master share a clock, not a protocol implementation.
"""

from __future__ import annotations

import time
from collections.abc import Callable

OFFSET_REFRESH_S = 1.0  # WallClockOffset reads the wall clock again after this long


class ArrivalClock:
    """Arrival time of the last handled frame and the judging time derived from it.

    The pair (arrival, handled) is one attribute, replaced in one store: a reader in another
    thread (the master's cycle loop reading what the notifier thread wrote) never pairs a new
    arrival with an old handling time, which would run the judging time ahead of the wire."""

    __slots__ = ("_last", "_pending")

    def __init__(self, pending: Callable[[], bool]) -> None:
        """``pending()``: frames are waiting in the receive socket or queue (False when
        unknowable)."""
        self._last: tuple[float, float] | None = None
        self._pending = pending

    @property
    def arrival_s(self) -> float | None:
        """Arrival time of the last handled frame (None before any)."""
        return None if self._last is None else self._last[0]

    @property
    def lag_s(self) -> float:
        """How late the last frame was handled after it arrived."""
        last = self._last
        return 0.0 if last is None else max(0.0, last[1] - last[0])

    def arrived(self, arrival_s: float, handled_s: float) -> float:
        """A frame that arrived at ``arrival_s`` is handled at ``handled_s`` (the judge's clock)."""
        self._last = (arrival_s, handled_s)
        return arrival_s

    def caught_up(self) -> bool:
        """Nothing waits in the socket."""
        return not self._pending()

    def judging_time(self, now_s: float) -> float:
        """``now_s`` on the arrival timeline (module docstring)."""
        last = self._last
        if last is None:
            return now_s
        if not self.caught_up():
            return last[0]
        return last[0] + max(0.0, now_s - last[1])


def socket_pending(bus: object) -> Callable[[], bool]:
    """``pending()`` for a python-can bus: the bus's own ``frames_waiting()`` (the batched
    SocketCAN bus, nurbsmotion.can.socketcan_batch: frames it has read but not yet handed out are
    invisible to select()), the receive queue of python-can's in-process virtual bus,
    select() on its file descriptor (SocketCAN), else always False."""
    import select

    frames_waiting = getattr(bus, "frames_waiting", None)
    if callable(frames_waiting):
        return frames_waiting
    queue = getattr(bus, "queue", None)
    if queue is not None and hasattr(queue, "qsize"):
        return lambda: queue.qsize() > 0
    try:
        fileno = bus.fileno()  # type: ignore[attr-defined]
    except (AttributeError, NotImplementedError, OSError):
        return lambda: False
    if not isinstance(fileno, int) or fileno < 0:
        return lambda: False

    def pending() -> bool:
        try:
            return bool(select.select([fileno], [], [], 0)[0])
        except (OSError, ValueError):  # closed while stopping
            return False
    return pending


class WallClockOffset:
    """time.time() - time.perf_counter(), read again at most every OFFSET_REFRESH_S of
    perf_counter time: a frame's receive timestamp (wall clock) minus it is on the process's
    clock. Refreshed, not read per frame: inside User-Mode Linux each clock read is a trapped
    system call, and the offset moves only with NTP slewing (ppm)."""

    __slots__ = ("_offset_s", "_read_s", "_wall_time")

    def __init__(self, wall_time: Callable[[], float] | None = None) -> None:
        """``wall_time``: the wall clock (None: time.time; a test injects its own)."""
        self._offset_s = 0.0
        self._read_s = -1e18
        self._wall_time = wall_time

    def at(self, now_s: float) -> float:
        """The offset, read again when ``now_s`` (perf_counter) is OFFSET_REFRESH_S past the last read."""
        if now_s - self._read_s > OFFSET_REFRESH_S:
            self._offset_s, self._read_s = (self._wall_time or time.time)() - now_s, now_s
        return self._offset_s
