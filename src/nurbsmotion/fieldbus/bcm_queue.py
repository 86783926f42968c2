"""Kernel-timed stream on SocketCAN: the frames of the coming cycles queued in the kernel.

One broadcast-manager (BCM) TX operation holds a ring of whole cycles (SYNC, then the RPDO
of each axis; at most 256 frames, e.g. 64 cycles for 3 axes) and sends one frame every
T/(1 + n_axes): SYNC at the start of each cycle, the RPDOs spread over it, all before the
next SYNC. (Several ops, one per frame of the cycle, all at T, would send each cycle as one
burst from one timer interrupt; measured, that halves the SYNC jitter inside User-Mode Linux
and wakes every reader once per cycle instead of 1 + n times, but the kernel orders frames
of different ops only by their timers: a delay of about T between two ops' handlers (a
starved guest) can put an RPDO behind the next SYNC for good, and the drive then applies
every set-point one cycle late: seen once in about 15 runs inside User-Mode Linux (node 3,
the last 318 cycles of a job). One ring keeps the order by construction; docs/benchmarks.md,
"Kernel-timed stream".) Python only keeps the ring ahead of the kernel:

- **Where the wire is.** A raw socket that receives only SYNC counts the SYNCs the kernel
  sent (with their kernel timestamps): cycle c. The cycle thread drains it without blocking.
- **What it may change.** Slots of cycles up to c + guard are never rewritten (the kernel
  may be copying them: before Linux 6.15's "extend bcm_tx_lock usage" the copy takes no
  lock). Each TX_SETUP carries the whole ring, so those slots are rewritten with identical
  bytes. Stop, feed override and abort act from c + guard + 1 on: latency (guard + 1)·T.
  After a TX_SETUP that changed queued cycles the echo is read again: if the wire has
  passed c + guard meanwhile (the cycle thread was held up between its count and its write
  longer than the guard: seen inside a starved User-Mode Linux guest), those cycles went out
  with their old frames (a stop or a velocity ramp starting late, a step in the set-points).
  They are counted and logged (``kernel_queue_overtaken``), and the change guard (where
  requests act from: c + change_guard + 1) grows by what was measured, up to
  MAX_GUARD_CYCLES, so the next change lands beyond the wire; the planning horizon keeps the
  guard of 3 (the stop tail beyond it is never adopted as sent before the wire reaches it).
  The echo is also read right before that TX_SETUP: a change of the extras (the csv
  spindle's 0x60FF ramp) the wire has reached by then starts after wire + guard instead, and
  the cycles before keep the frames the queue held: a ramp never starts in the past.
- **The lease.** Each renewal sets the op's ``count`` to (L - c)·(1 + n) frames, with
  L = c + cycles - 1 - pad (SETTIMER without STARTTIMER keeps the phase). If Python stops
  renewing, the kernel sends into cycle L and stops by itself: SYNC
  stops, drives notice. The planner keeps the cycles after its horizon a controlled stop
  along the path that reaches rest before L, so a stall longer than the queue ends with
  the axes at rest; the master then reports a ``stall`` fault.
- **At rest, a longer lease.** While every queued cycle carries the same frames (holding:
  the same set-points and controlwords in every slot), sending the ring round more than once
  sends exactly what Python would have written, so the lease covers REST_LEASE_S (1 s;
  the ring alone is 64 ms at T = 1 ms) instead of one lap: a daemon held up while the axes
  stand still does not fault the machine; a hung one still stops SYNC within REST_LEASE_S.
  The first renewal that writes anything else (a job, a controlword) cuts the lease back to
  the ring in the same TX_SETUP.
- **The period.** The BCM re-arms each frame at now + ival, so the wire runs slow by the
  timer latency of every frame (about 6 % inside User-Mode Linux), and a held-up timer
  shifts it for good. The median of the last 64 echoed SYNC intervals trims the frequency;
  the phase against t0 + k·T is caught up at most 4 % of T per cycle (a frozen guest's
  lag of more than 4 T is accepted, not caught up).

Why the BCM and not ETF + SO_TXTIME: queued SO_TXTIME frames cannot be revised (a stop or
an override would wait for the whole queue, or the queue must be short), and an ETF root
qdisc makes frames without a launch time fail (SDO, NMT) unless it sits under a prio
qdisc, which needs root and tc at every start. The BCM needs neither and its frames can be
rewritten until shortly before they are sent.
"""

from __future__ import annotations

import collections
import logging
import socket
import struct
import time
from typing import Callable

import can
from can.interfaces.socketcan import constants as bcm
from can.interfaces.socketcan.socketcan import build_bcm_header, create_bcm_socket, send_bcm

from nurbsmotion.cycle_watch import CycleWatch
from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats, wait_until
from nurbsmotion.fieldbus.supervisor import CycleHistory
from nurbsmotion.fieldbus.writer import CyclicFrames
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

MAX_NFRAMES = 256  # linux/net/can/bcm.c
FRAME_BYTES = 16  # struct can_frame
CAN_FRAME_HEAD = struct.Struct("=IB3x")  # can_id, len, pad, res, len8_dlc
SYNC_FILTER = struct.Struct("=II")
SFF_EXACT_MASK = 0xC00007FF  # CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_SFF_MASK
TIMESPEC = struct.Struct("@ll")
GUARD_CYCLES = 3
WRITE_MARGIN_CYCLES = 1  # a change the wire is this close to when the TX_SETUP goes is moved (extras)
MAX_GUARD_CYCLES = 16  # the change guard grows after an overtaken change (module docstring) up to this
BATCH_CYCLES = 8  # the planning horizon moves in steps of this many cycles (fewer tail rewrites)
WAKE_PERIOD_S = 0.008  # the cycle thread wakes about this often (whole cycles): the queue, not it, keeps time
TRIM_WINDOW = 64  # echoed SYNC intervals the period trim looks at
TRIM_GAIN = 0.01  # share of the median's error corrected per renewal (x ~32 renewals per window: stable)
TRIM_LIMIT = 0.3  # share of T the frequency correction may reach (a starved guest: 4 late timers a cycle)
PHASE_GAIN = 0.1  # share of the SYNC phase error caught up per renewal
PHASE_LIMIT = 0.04  # at most this share of T faster or slower per cycle to catch up the phase
RE_ANCHOR_CYCLES = 4  # a phase error beyond this many periods moves the reference
REST_LEASE_S = 1.0  # lease while every queued cycle is the same (axes at rest; module docstring)


class QueueHeadroom:
    """Cycles still queued beyond the wire when the cycle thread wakes while moving (h - c
    before it commits): how close a stall came to the queue's planned end. A histogram over
    0..cycles (negative: the kernel went past the horizon into the tail, counted as 0)."""

    def __init__(self, cycles: int) -> None:
        self.counts = [0] * (cycles + 1)
        self.samples = 0
        self.min = cycles
        self.into_tail = 0  # wake-ups that found the wire past the horizon (the tail was sent)

    def add(self, headroom_cycles: int) -> None:
        if headroom_cycles < 0:
            self.into_tail += 1
        h = max(0, min(headroom_cycles, len(self.counts) - 1))
        self.counts[h] += 1
        self.samples += 1
        self.min = min(self.min, h)

    def percentile(self, share: float) -> int:
        """Smallest headroom h with at least ``share`` of the samples at or below it."""
        need, seen = share * self.samples, 0
        for h, n in enumerate(self.counts):
            seen += n
            if seen >= need and seen:
                return h
        return 0


def ring_cycles(frames_per_cycle: int) -> int:
    """Whole cycles that fit the BCM's 256 frames."""
    return MAX_NFRAMES // frames_per_cycle


class SyncEcho:
    """Raw CAN socket receiving only SYNC (COB-ID 0x80), non-blocking, kernel timestamps (ns)."""

    def __init__(self, channel: str, sync_id: int) -> None:
        sock = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, SYNC_FILTER.pack(sync_id, SFF_EXACT_MASK))
        sock.setsockopt(socket.SOL_SOCKET, bcm.SO_TIMESTAMPNS, 1)
        sock.bind((channel,))
        sock.setblocking(False)
        self.sock = sock
        self.anc_size = socket.CMSG_SPACE(TIMESPEC.size)

    def drain(self, on_sync: Callable[[float], None]) -> None:
        """Call ``on_sync(timestamp)`` for every SYNC received since the last drain."""
        recvmsg, anc_size = self.sock.recvmsg, self.anc_size
        while True:
            try:
                _, ancdata, _, _ = recvmsg(FRAME_BYTES, anc_size)
            except BlockingIOError:
                return
            stamp = 0.0
            for level, kind, data in ancdata:
                if level == socket.SOL_SOCKET and kind == bcm.SO_TIMESTAMPNS:
                    sec, nsec = TIMESPEC.unpack_from(data)
                    stamp = sec + nsec * 1e-9
            on_sync(stamp or time.time())

    def close(self) -> None:
        self.sock.close()


class BcmQueueWriter:
    """The cycle writer for SocketCAN (see the module docstring)."""

    def __init__(self, channel: str, frames: CyclicFrames, history: CycleHistory, period_s: float,
                 late_threshold_s: float, bus: can.BusABC) -> None:
        self.channel = channel
        self.frames = frames
        self.history = history
        self.period_s = period_s
        self.bus = bus  # for the immediate quick stop (raw socket of the master)
        self.fpc = frames.per_cycle
        self.cycles = ring_cycles(self.fpc)
        if self.cycles < 2 * GUARD_CYCLES + BATCH_CYCLES + 4:
            raise ValueError(f"kernel queue: {self.fpc} frames per cycle leave only {self.cycles} cycles of 256 frames")
        self.pad = GUARD_CYCLES
        self.rest_cycles = max(self.cycles, round(REST_LEASE_S / period_s))
        self.stats = LatenessStats(late_threshold_s)
        self.send_errors = 0
        self.buf = bytearray(self.cycles * self.fpc * FRAME_BYTES)
        self._ring_view = memoryview(self.buf)  # for ring_uniform (the buffer is never resized)
        self.scratch = [bytearray(dlc) for _, dlc in frames.heads()]
        self._init_frames()
        self.bcm_sock: socket.socket | None = None
        self.echo: SyncEcho | None = None
        self.running = False
        self.op_base = 1  # cycle of ring slot 0
        self.synced = 0  # SYNCs echoed since the op started
        self.c = 0
        self.h = 0  # horizon committed last
        self.c_committed = 0  # wire cycle at the last commit
        self.lease_end = 0
        n_axes = len(history.sp[0])
        self.tail_sp = [[0] * n_axes for _ in range(self.cycles)]
        self.tail_cw = [[0] * n_axes for _ in range(self.cycles)]
        self.correction_s = self.frequency_s = 0.0
        self.t_ref, self.k_ref = 0.0, -1
        self.intervals: collections.deque[float] = collections.deque(maxlen=TRIM_WINDOW)
        self.last_stamp = 0.0
        self.wake_s = max(1, round(WAKE_PERIOD_S / period_s)) * period_s
        self.grid = DeadlineGrid(self.wake_s, time.perf_counter() + self.wake_s)
        self.expired = 0  # lease expiries seen
        self.guard = GUARD_CYCLES  # slots up to c + guard are never rewritten
        self.change_guard = GUARD_CYCLES  # requests act beyond it; grows when the wire overtakes one
        self.overtaken = 0  # changed cycles the wire sent with their old frames
        self.headroom = QueueHeadroom(self.cycles)  # while moving (at rest the horizon is a few cycles)
        self.moving = False
        self.watch = CycleWatch(period_s, self.cycles * period_s / 2)  # cycle_thread_late: back after half the queue

    def _init_frames(self) -> None:
        """SYNC frames and the RPDO frame heads of every slot (their data is packed per cycle)."""
        for slot in range(self.cycles):
            base = slot * self.fpc * FRAME_BYTES
            CAN_FRAME_HEAD.pack_into(self.buf, base, self.frames.sync_id, 0)
            for j, (can_id, dlc) in enumerate(self.frames.heads()):
                CAN_FRAME_HEAD.pack_into(self.buf, base + (1 + j) * FRAME_BYTES, can_id, dlc)

    # ------------------------------------------------------------------ CycleWriter
    def start(self) -> None:
        self.bcm_sock = create_bcm_socket(self.channel)
        self.echo = SyncEcho(self.channel, self.frames.sync_id)
        self.grid = DeadlineGrid(self.wake_s, time.perf_counter() + self.wake_s)

    def next_wake_s(self) -> float:
        """When the cycle thread wakes next (no spin)."""
        return self.grid.next_s

    def next_cycle(self) -> int:
        """Sleep until the next wake-up (every WAKE_PERIOD_S, whole cycles), then count the
        SYNCs the kernel sent meanwhile: the wire cycle."""
        woke = wait_until(self.grid.next_s, 0.0)  # no spin: the kernel keeps the time, not this wake-up
        lateness, missed = self.grid.advance(woke)
        self.stats.add(lateness, missed)
        assert self.echo is not None
        c_before = self.c
        self.echo.drain(self._on_sync)
        self.watch.woke(lateness, self.c - c_before, self.stalled())
        if self.running and self.moving:
            self.headroom.add(self.h - self.c)
        return self.c

    def _on_sync(self, stamp: float) -> None:
        self.synced += 1
        self.c = k = self.op_base + self.synced - 1
        self.history.sync_time[k % self.history.size] = stamp
        if self.last_stamp:
            self.intervals.append(stamp - self.last_stamp)
        self.last_stamp = stamp

    def horizon(self, c: int, stop_cycles: int, moving: bool) -> int:
        """Deepest cycle to plan: moving, as deep as the stop after it still ends before the
        lease; else a few cycles (the drives' state machine answers the feedback)."""
        least = c + self.guard + 1
        self.moving = moving
        if moving:
            deepest = c + self.cycles - 1 - self.pad - stop_cycles
            target = (deepest // BATCH_CYCLES) * BATCH_CYCLES
        else:
            target = -(-(least + 1) // BATCH_CYCLES) * BATCH_CYCLES
        return max(least, target)

    def commit(self, c: int, horizon: int, first_new: int,
               tail: Callable[[list[list[int]], list[list[int]]], int]) -> None:
        """Write the new and recomputed cycles and the tail into the ring; renew the lease."""
        history = self.history
        end = c + self.cycles - 1  # last cycle the ring can hold ahead of c
        changed_queued = self.running and first_new <= self.h
        if not self.running:
            first_new = self.op_base
        for x in range(max(first_new, c + 1), horizon + 1):
            self._pack(x, history.cw[x % history.size], history.sp[x % history.size])
        if first_new <= horizon or horizon != self.h or not self.running:
            tail(self.tail_sp, self.tail_cw)
            tail_from = horizon + 1
        else:
            tail_from = max(horizon + 1, self.c_committed + self.cycles)
        for x in range(tail_from, end + 1):
            row = x - horizon - 1
            self._pack(x, self.tail_cw[row], self.tail_sp[row])
        self.h = horizon
        self.c_committed = c
        if changed_queued:
            self._keep_cycle_changes_ahead_of_wire(c, first_new, end)
        self._renew(c)
        self.frames.extras_queued()
        if changed_queued:
            self._check_overtaken(c, first_new)

    def _keep_cycle_changes_ahead_of_wire(self, c: int, first_changed: int, end: int) -> None:
        """Right before the TX_SETUP: the SYNCs sent since the count. When the wire is within
        WRITE_MARGIN_CYCLES of the first changed cycle (or past it), the extras' change (a new
        0x60FF ramp, fieldbus.cyclic_velocity) starts after wire + guard instead and the cycles
        before are packed again as the queue held them: no frame of the new ramp goes out
        before one of the old (else a step in 0x60FF of as many ramp steps as cycles
        overtaken). The axes' commands cannot move: the check after the write counts them."""
        assert self.echo is not None
        self.echo.drain(self._on_sync)
        if self.c + WRITE_MARGIN_CYCLES < first_changed:
            return
        first_free = self.c + self.guard + 1
        if not self.frames.postpone_extras(first_changed, first_free):
            return
        for x in range(max(first_changed, c + 1), end + 1):
            self._pack_extras(x)
        log.warning(kv("kernel_queue_change_postponed", cycle=c, wire=self.c, first_changed=first_changed,
                       postponed_to=first_free))

    def _check_overtaken(self, c: int, first_changed: int) -> None:
        """After changing queued cycles from ``first_changed`` on (>= c + change_guard + 1): the
        SYNCs sent since the count. Changed cycles up to the wire may have gone out with their
        old frames (at most that many: a SYNC echoed before this read may have left after the
        write): count them and widen the change guard by as many (module docstring)."""
        assert self.echo is not None
        self.echo.drain(self._on_sync)
        late = self.c - max(first_changed, c + self.guard + 1) + 1
        if late <= 0:
            return
        self.overtaken += late
        self.change_guard = min(self.change_guard + late, MAX_GUARD_CYCLES)
        log.warning(kv("kernel_queue_overtaken", cycle=c, wire=self.c, first_changed=first_changed,
                       cycles=late, change_guard=self.change_guard))

    def _pack(self, x: int, cw: list[int], sp: list[int]) -> None:
        """The RPDO data of cycle x into its ring slot (each frame packed into its scratch buffer)."""
        base = ((x - self.op_base) % self.cycles) * self.fpc * FRAME_BYTES + FRAME_BYTES + 8
        buf = self.buf
        for j, (_, dlc, i, pack) in enumerate(self.frames.rpdos):
            data = self.scratch[j]
            pack(data, cw[i], sp[i])
            offset = base + j * FRAME_BYTES
            buf[offset:offset + dlc] = data
        if self.frames.extras:
            self._pack_extras(x)

    def _pack_extras(self, x: int) -> None:
        """The frames of cycle x that are a function of x alone (CyclicFrames.extras) into its slot."""
        base = ((x - self.op_base) % self.cycles) * self.fpc * FRAME_BYTES + FRAME_BYTES + 8
        buf = self.buf
        for j, (_, dlc, pack_cycle) in enumerate(self.frames.extras, len(self.frames.rpdos)):
            data = self.scratch[j]
            pack_cycle(data, x)
            offset = base + j * FRAME_BYTES
            buf[offset:offset + dlc] = data

    def _renew(self, c: int) -> None:
        """TX_SETUP with the whole ring, count = frames up to the lease end, trimmed ival."""
        span = self.rest_cycles if self.ring_uniform() else self.cycles
        self.lease_end = lease_end = c + span - 1 - self.pad
        count = (lease_end - c) * self.fpc
        flags = bcm.SETTIMER
        if not self.running:
            flags |= bcm.STARTTIMER
            count = (lease_end - self.op_base + 1) * self.fpc
        ival_us = round((self.period_s - self._trim()) / self.fpc * 1e6)
        head = build_bcm_header(bcm.CAN_BCM_TX_SETUP, flags, count, 0, ival_us, 0, 0, self.frames.sync_id,
                                self.cycles * self.fpc)
        assert self.bcm_sock is not None
        try:
            self.bcm_sock.sendmsg([head, self.buf])
        except OSError as err:
            self.send_errors += 1
            raise can.CanOperationError(f"kernel queue: TX_SETUP failed: {err}") from err
        self.running = True

    def ring_uniform(self) -> bool:
        """Every slot of the ring holds the same frames (the kernel may send it round again):
        the ring equals itself shifted by one slot (memoryview comparison, no copy)."""
        ring = self._ring_view
        slot = self.fpc * FRAME_BYTES
        return ring[slot:] == ring[:-slot]

    def _trim(self) -> float:
        """Period correction (s per cycle), two terms. Frequency: the median of the last
        TRIM_WINDOW echoed SYNC intervals against T, integrated with gain TRIM_GAIN (the
        median ignores intervals a held-up timer stretched), within ±TRIM_LIMIT·T. Phase: the
        last SYNC against t0 + k·T, caught up at most PHASE_LIMIT·T per cycle, so a late
        timer does not shift the wire for good; a lag beyond RE_ANCHOR_CYCLES·T (the guest
        was frozen) moves the reference instead of running fast for long."""
        intervals, period = self.intervals, self.period_s
        if len(intervals) >= TRIM_WINDOW // 2:
            median = sorted(intervals)[len(intervals) // 2]
            limit = TRIM_LIMIT * period
            self.frequency_s = max(-limit, min(limit, self.frequency_s + TRIM_GAIN * (median - period)))
        phase = 0.0
        if self.k_ref >= 0:
            error = self.last_stamp - (self.t_ref + (self.c - self.k_ref) * period)  # > 0: the wire is late
            if abs(error) > RE_ANCHOR_CYCLES * period:
                self.t_ref, self.k_ref = self.last_stamp, self.c
            else:
                phase = max(-PHASE_LIMIT * period, min(PHASE_LIMIT * period, PHASE_GAIN * error))
        elif self.last_stamp:
            self.t_ref, self.k_ref = self.last_stamp, self.c
        self.correction_s = self.frequency_s + phase
        return self.correction_s

    def quick_stop_now(self, c: int, controlwords: list[int], setpoints: list[int]) -> None:
        """Quick-stop RPDOs on the bus at once, and the same controlword in the queued cycles
        up to c + guard (the master rewrites the later ones): a queued 'enable operation'
        could otherwise re-enable a drive in QUICK STOP ACTIVE (0x605A 5-8, transition 16)."""
        for can_id, dlc, i, pack in self.frames.rpdos:
            data = bytearray(dlc)
            pack(data, controlwords[i], setpoints[i])
            try:
                self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
            except (can.CanError, OSError):
                self.send_errors += 1
        for x in range(c + 1, c + self.guard + 1):
            self._pack(x, controlwords, setpoints)

    def stalled(self) -> bool:
        """The lease ran out: the kernel sent the SYNC of its last cycle (L) and stops within
        it (count = (L - c)·(1 + n) frames from a renewal inside cycle c ends inside cycle L),
        and a count that reached 0 cannot be renewed (the op's timer is not re-armed)."""
        return self.running and self.c >= self.lease_end

    def restart(self, c: int) -> None:
        """A fresh op (the expired one cannot be renewed): ring slot 0 is cycle c + 1."""
        self.expired += 1
        log.warning(kv("kernel_queue_expired", cycle=c, lease_end=self.lease_end))
        self._delete()
        self.running = False
        self.op_base = c + 1
        self.synced = 0
        self.c = c
        self.last_stamp = 0.0
        self.k_ref = -1
        self.intervals.clear()

    def _delete(self) -> None:
        if self.bcm_sock is not None and self.running:
            try:
                send_bcm(self.bcm_sock, build_bcm_header(bcm.CAN_BCM_TX_DELETE, 0, 0, 0, 0, 0, 0,
                                                         self.frames.sync_id, 1))
            except can.CanError:
                pass

    def close(self) -> None:
        if self.headroom.samples:
            log.info(kv("kernel_queue_summary", wakes=self.headroom.samples, headroom_min=self.headroom.min,
                        headroom_p1=self.headroom.percentile(0.01), headroom_p50=self.headroom.percentile(0.5),
                        into_tail=self.headroom.into_tail, lease_expiries=self.expired, ring_cycles=self.cycles,
                        overtaken=self.overtaken, change_guard=self.change_guard))
        self._delete()
        self.running = False
        if self.bcm_sock is not None:
            self.bcm_sock.close()
            self.bcm_sock = None
        if self.echo is not None:
            self.echo.close()
            self.echo = None

    def queue_cycles(self) -> int:
        """Cycles queued ahead of the wire at the last commit (stall tolerance while moving)."""
        return self.h - self.c

