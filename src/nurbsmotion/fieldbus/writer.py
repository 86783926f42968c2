"""Cycle writers: the only code that puts the cyclic frames (SYNC, RPDOs) on the bus.

Both writers serve the master's cycle thread the same way: :meth:`next_cycle` returns the
wire cycle c (the last SYNC on the wire), the master makes sure the commands of every cycle
up to :meth:`horizon` are in the :class:`~nurbsmotion.fieldbus.supervisor.CycleHistory`, then
calls :meth:`commit`. Commands of cycles up to c + guard are never changed again.

- :class:`LoopWriter` (python-can virtual bus and any interface without a kernel queue):
  sleeps to the deadline of cycle c and sends SYNC c and its RPDOs at once; guard 0, the
  commands of cycle c + 1 are computed after the sends. A late thread delays the cycle.
- :class:`~nurbsmotion.fieldbus.bcm_queue.BcmQueueWriter` (SocketCAN): the frames of the
  coming cycles queued in the kernel's broadcast manager.

The per-cycle frame layout (COB ids, packing) is :class:`CyclicFrames`, the one place to
change when the PDO mapping changes.
"""

from __future__ import annotations

import time
from typing import Callable, Protocol

import can

from nurbsmotion import cia402 as c
from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats, wait_until
from nurbsmotion.fieldbus.pdo import RPDO_FORMAT
from nurbsmotion.fieldbus.supervisor import CycleHistory


class CyclicFrames:
    """SYNC (COB-ID 0x80, no data) then RPDO1 of each axis: controlword u16 + set-point i32."""

    def __init__(self, node_ids: list[int]) -> None:
        self.sync_id = c.COB_SYNC
        self.rpdo_ids = [c.COB_RPDO[0] + node for node in node_ids]
        self.rpdo_size = RPDO_FORMAT.size
        self.pack_rpdo = RPDO_FORMAT.pack_into  # (buffer, offset, controlword, set-point)
        self.per_cycle = 1 + len(node_ids)

    def messages(self) -> tuple[can.Message, list[can.Message]]:
        """One reusable SYNC message and one RPDO message per axis."""
        sync = can.Message(arbitration_id=self.sync_id, is_extended_id=False, data=b"")
        return sync, [can.Message(arbitration_id=i, is_extended_id=False, data=bytearray(self.rpdo_size))
                      for i in self.rpdo_ids]


class CycleWriter(Protocol):
    guard: int
    stats: LatenessStats
    send_errors: int

    def start(self) -> None: ...

    def next_cycle(self) -> int: ...

    def horizon(self, c: int, stop_cycles: int, moving: bool) -> int: ...

    def commit(self, c: int, horizon: int, first_new: int,
               tail: Callable[[list[list[int]], list[list[int]]], int]) -> None: ...

    def quick_stop_now(self, c: int, controlwords: list[int], setpoints: list[int]) -> None: ...

    def stalled(self) -> bool: ...

    def restart(self, c: int) -> None: ...

    def close(self) -> None: ...


class LoopWriter:
    """SYNC and RPDOs sent by the cycle thread at absolute deadlines (fieldbus.cycle)."""

    guard = 0

    def __init__(self, bus: can.BusABC, frames: CyclicFrames, history: CycleHistory, period_s: float,
                 spin_s: float, late_threshold_s: float, on_sent: Callable[[list[can.Message]], None] | None,
                 on_error: Callable[[int, Exception], None]) -> None:
        self.bus = bus
        self.frames = frames
        self.history = history
        self.period_s = period_s
        self.spin_s = spin_s
        self.stats = LatenessStats(late_threshold_s)
        self.send_errors = 0
        self.on_sent = on_sent  # traffic log while it records
        self.on_error = on_error
        self.sync_msg, self.rpdo_msgs = frames.messages()
        self.all_msgs = [self.sync_msg, *self.rpdo_msgs]
        self.grid = DeadlineGrid(period_s, time.perf_counter() + period_s)
        self.k = 0
        self.last_missed = (0.0, False)

    def start(self) -> None:
        self.grid = DeadlineGrid(self.period_s, time.perf_counter() + self.period_s)

    def next_cycle(self) -> int:
        """Wait for the deadline of the next cycle, send its SYNC and RPDOs; return it."""
        woke = wait_until(self.grid.next_s, self.spin_s)
        lateness, missed = self.grid.advance(woke)
        self.stats.add(lateness, missed)
        self.last_missed = (lateness, missed)
        self.k = k = self.k + 1
        history = self.history
        row = k % history.size
        cw, sp = history.cw[row], history.sp[row]
        send, pack = self.bus.send, self.frames.pack_rpdo
        try:
            history.sync_time[row] = time.time()  # frame timestamps are time.time() based
            send(self.sync_msg)
            for i, msg in enumerate(self.rpdo_msgs):
                pack(msg.data, 0, cw[i], sp[i])
                send(msg)
        except (can.CanError, OSError) as err:
            self.send_errors += 1
            self.on_error(k, err)
        if self.on_sent is not None:
            self.on_sent(self.all_msgs)
        return k

    def horizon(self, c: int, stop_cycles: int, moving: bool) -> int:
        return c + 1

    def commit(self, c: int, horizon: int, first_new: int,
               tail: Callable[[list[list[int]], list[list[int]]], int]) -> None:
        """Nothing to do: cycle c + 1 is sent at its deadline from the history."""

    def quick_stop_now(self, c: int, controlwords: list[int], setpoints: list[int]) -> None:
        """The next cycle carries the quick stop already (guard 0)."""

    def stalled(self) -> bool:
        return False

    def restart(self, c: int) -> None:
        """Never stalls."""

    def close(self) -> None:
        """The bus belongs to the master."""
