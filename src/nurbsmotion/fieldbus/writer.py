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

from nurbsmotion.can import cia402 as c
from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats, wait_until
from nurbsmotion.fieldbus.supervisor import CycleHistory


RpdoSlot = tuple[int, int, int, Callable[[bytearray, int, int], None]]  # COB-ID, DLC, axis, pack(data, cw, sp)
CycleSlot = tuple[int, int, Callable[[bytearray, int], None]]  # COB-ID, DLC, pack(data, cycle)


class Retimed(Protocol):
    """An extra whose newest change can start later (fieldbus.cyclic_velocity.CyclicVelocity)."""

    def postpone(self, first_changed: int, first_free: int) -> bool:
        """A change from ``first_changed`` on, not queued yet, starts at ``first_free``; True when one moved."""

    def queued(self) -> None:
        """The kernel queue holds every change now."""


class CyclicFrames:
    """SYNC (COB-ID 0x80, no data), then the RPDOs of every axis as bring-up mapped them
    (bringup_plan.rpdo_packer: controlword + set-point in one frame, or split in two), then
    the ``extras``: RPDOs of other nodes whose data is a function of the cycle (the csv
    spindle's 0x60FF, fieldbus.cyclic_velocity), and ``retimed``: the owners of those whose
    change the kernel queue may move to a later cycle (when the wire overtook it)."""

    def __init__(self, rpdos: list[RpdoSlot], extras: list[CycleSlot] | None = None,
                 retimed: list[Retimed] | None = None) -> None:
        self.sync_id = c.COB_SYNC
        self.rpdos = rpdos
        self.extras = extras or []
        self.retimed = retimed or []
        self.rpdo_ids = [cob_id for cob_id, _, _, _ in rpdos] + [cob_id for cob_id, _, _ in self.extras]
        self.per_cycle = 1 + len(rpdos) + len(self.extras)

    def heads(self) -> list[tuple[int, int]]:
        """(COB-ID, DLC) of every RPDO of a cycle, in the order they are sent."""
        return [(cob_id, dlc) for cob_id, dlc, _, _ in self.rpdos] + [(cob_id, dlc) for cob_id, dlc, _ in self.extras]

    def postpone_extras(self, first_changed: int, first_free: int) -> bool:
        """Every extra's change from ``first_changed`` on not queued yet starts at
        ``first_free`` instead; True when one moved (its frames before ``first_free`` are the
        ones queued before)."""
        moved = [extra.postpone(first_changed, first_free) for extra in self.retimed]
        return any(moved)

    def extras_queued(self) -> None:
        """After a TX_SETUP: every extra's changes are in the kernel queue."""
        for extra in self.retimed:
            extra.queued()

    def messages(self) -> tuple[can.Message, list[can.Message]]:
        """One reusable SYNC message and one message per RPDO (the axes', then the extras)."""
        sync = can.Message(arbitration_id=self.sync_id, is_extended_id=False, data=b"")
        return sync, [can.Message(arbitration_id=cob_id, is_extended_id=False, data=bytearray(dlc))
                      for cob_id, dlc in self.heads()]


class CycleWriter(Protocol):
    guard: int  # cycles up to c + guard are never rewritten
    change_guard: int  # requests (stop, override, a new 0x60FF target) act from c + change_guard + 1
    stats: LatenessStats
    send_errors: int

    def start(self) -> None: ...

    def next_wake_s(self) -> float: ...  # perf_counter time the cycle thread wakes next (deadline - spin)

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
    change_guard = 0

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
        self.extra_msgs = self.rpdo_msgs[len(frames.rpdos):]
        self.all_msgs = [self.sync_msg, *self.rpdo_msgs]
        self.grid = DeadlineGrid(period_s, time.perf_counter() + period_s)
        self.k = 0
        self.last_missed = (0.0, False)

    def start(self) -> None:
        self.grid = DeadlineGrid(self.period_s, time.perf_counter() + self.period_s)

    def next_wake_s(self) -> float:
        """When the cycle thread wakes for the next cycle: its spin before the deadline."""
        return self.grid.next_s - self.spin_s

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
        send = self.bus.send
        try:
            history.sync_time[row] = time.time()  # frame timestamps are time.time() based
            send(self.sync_msg)
            for msg, (_, _, i, pack) in zip(self.rpdo_msgs, self.frames.rpdos):  # one or two RPDOs per axis
                pack(msg.data, cw[i], sp[i])
                send(msg)
            for msg, (_, _, pack_cycle) in zip(self.extra_msgs, self.frames.extras):
                pack_cycle(msg.data, k)
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
