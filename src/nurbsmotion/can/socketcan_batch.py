"""A SocketCAN bus for the per-cycle traffic: python-can's, with a few system calls per
cycle instead of two per frame. Used by the master (fieldbus.connection) and the simulated
drives (sim.network) on ``interface: socketcan``; transport only, no CANopen in it.

python-can's ``SocketcanBus`` waits in ``select`` before every ``recvmsg`` and polls the
socket for writability with ``select`` before every ``send``. Every cycle the simulated
drives receive SYNC and one RPDO per drive and answer with TPDO1 and TPDO2 per drive, and
the master receives those TPDOs: with three drives 20 system calls in the drives' process
and 12 in the master's per cycle. On a real kernel that costs microseconds; inside
User-Mode Linux (scripts/with-vcan) every system call of a guest process is trapped by the
host and costs ~100-150 µs of the guest's one CPU (measured, docs/vcan.md "The drives'
lag"), which both processes and any listener share: at T = 4 ms the guest ran at 100 %
and the drives' process fell behind the wire by seconds.

:class:`BatchedSocketcanBus` keeps python-can's ``select`` when the socket is empty, and:

- **receives in batches**: after each wake-up one ``recvmmsg`` (Linux, via ctypes) takes
  every frame the socket holds with its kernel timestamp; they are handed out one by one
  (``recv``, canopen's Notifier), parsed as python-can parses them;
- **sends the receive thread's frames in one go**: frames sent from the thread that reads
  the bus (the drives answer SYNC with TPDOs and SDO requests with responses from
  canopen's callbacks) wait until the frames of the batch have been handled, then leave
  with one ``sendmmsg`` before the thread waits again (a simulated drive answers after the
  whole burst it received, within the cycle); frames from other threads (the master's
  cycle thread, heartbeats and EMCY from the drives' ticker) leave at once with one
  ``send``, after the receive thread's waiting frames (the order of sends across threads
  is kept), python-can's polling send only when the kernel refuses the frame.

canopen's ``Network`` takes it as its bus (``canopen.Network(bus)``, or ``network.bus``
set before ``connect``), so the dispatch stays canopen's.

:class:`BatchNotifier` is python-can's ``Notifier`` with one change in its receive thread:
it waits for a batch with one blocking ``recvmmsg`` (``MSG_WAITFORONE``, the wait bounded by
``SO_RCVTIMEO``) and hands the whole batch to the listeners under one acquisition of the
notifier's lock. python-can's thread takes per frame ``bus.recv(timeout)`` (a clock read) and
the notifier's lock (CPython 3.11 reads the monotonic clock on every lock acquisition), and
per wake-up ``select`` + ``recvmsg`` + ``recvmmsg``: inside User-Mode Linux each of those is
a trapped system call of ~100-150 µs, and the master's receive thread took 69 % of the
guest's CPU for 1,500 TPDOs/s (3 axes, T = 4 ms; docs/vcan.md). With this thread a wake-up
costs one ``recvmmsg`` and one clock read (``read_perf_s``, which the master's arrival
clock uses instead of a clock read per frame), whatever the number of frames.
"""

from __future__ import annotations

import collections
import ctypes
import errno
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import can
from can.interfaces.socketcan import constants
from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame, dissect_can_frame

from nurbsmotion.can.arrival_clock import WallClockOffset

MSG_WAITFORONE = 0x10000  # linux/socket.h: block for the first message only
TIMEVAL = struct.Struct("@ll")  # struct timeval for SO_RCVTIMEO
# Frames per recvmmsg: a cycle's burst is 1 + n frames; a reader that lags takes its backlog
# in calls of this many. A call is one stretch of kernel work that cannot be preempted inside
# User-Mode Linux (0.6-1.4 ms for 64 frames there, 0.1-0.6 ms for 16): 16 keeps the kernel
# queue's soft timers from waiting behind a master catching up after a stall (five 60 ms
# stalls at T = 4 ms: 15 of 16 jobs within 2 T against 12 of 16 with 64; docs/benchmarks.md).
BATCH_FRAMES = 16
FRAME_BYTES = 16  # struct can_frame (the bus is opened without CAN FD)
TIMESPEC = struct.Struct("@qq")
CMSG_HEAD = struct.Struct("@Qii")  # cmsg_len, cmsg_level, cmsg_type (x86_64 / aarch64 layout)
CONTROL_BYTES = CMSG_HEAD.size + TIMESPEC.size  # CMSG_SPACE(sizeof(struct timespec))
LAG_SAMPLES = 100_000  # wake-ups whose reception lag is kept (about 7 min at 4 ms)
SEND_WAIT_S = 0.1  # a frame the kernel refuses at once: python-can's polling send for this long


class IoVec(ctypes.Structure):
    _fields_ = [("base", ctypes.c_void_p), ("len", ctypes.c_size_t)]


class MsgHdr(ctypes.Structure):
    _fields_ = [("name", ctypes.c_void_p), ("namelen", ctypes.c_uint32), ("iov", ctypes.POINTER(IoVec)),
                ("iovlen", ctypes.c_size_t), ("control", ctypes.c_void_p), ("controllen", ctypes.c_size_t),
                ("flags", ctypes.c_int)]


class MMsgHdr(ctypes.Structure):
    _fields_ = [("hdr", MsgHdr), ("len", ctypes.c_uint)]


_libc = ctypes.CDLL(None, use_errno=True)
_recvmmsg = _libc.recvmmsg
_recvmmsg.argtypes = [ctypes.c_int, ctypes.POINTER(MMsgHdr), ctypes.c_uint, ctypes.c_int, ctypes.c_void_p]
_sendmmsg = _libc.sendmmsg
_sendmmsg.argtypes = [ctypes.c_int, ctypes.POINTER(MMsgHdr), ctypes.c_uint, ctypes.c_int]


class FrameVector:
    """``count`` frame buffers (and timestamp buffers) with their mmsghdr array, reused."""

    def __init__(self, count: int, control: bool) -> None:
        self.count = count
        self.frames = ctypes.create_string_buffer(count * FRAME_BYTES)
        self.control = ctypes.create_string_buffer(count * CONTROL_BYTES) if control else None
        self.iovs = (IoVec * count)()
        self.headers = (MMsgHdr * count)()
        base = ctypes.addressof(self.frames)
        for i in range(count):
            self.iovs[i].base = base + i * FRAME_BYTES
            self.iovs[i].len = FRAME_BYTES
            hdr = self.headers[i].hdr
            hdr.iov = ctypes.pointer(self.iovs[i])
            hdr.iovlen = 1
            if self.control is not None:
                hdr.control = ctypes.addressof(self.control) + i * CONTROL_BYTES

    def reset_control(self) -> None:
        """The kernel shortens controllen and sets flags per message: restore before a receive."""
        for i in range(self.count):
            hdr = self.headers[i].hdr
            hdr.controllen = CONTROL_BYTES
            hdr.flags = 0

    def timestamp(self, i: int) -> float:
        """SO_TIMESTAMPNS of message i (0.0 if the kernel gave none)."""
        assert self.control is not None
        offset = i * CONTROL_BYTES
        if self.headers[i].hdr.controllen < CONTROL_BYTES:
            return 0.0
        _, level, kind = CMSG_HEAD.unpack_from(self.control, offset)
        if level != socket.SOL_SOCKET or kind != constants.SO_TIMESTAMPNS:
            return 0.0
        sec, nsec = TIMESPEC.unpack_from(self.control, offset + CMSG_HEAD.size)
        return sec + nsec * 1e-9


class ReceiveLag:
    """How far behind the wire the process reads: at each wake-up, the wall clock minus the
    kernel's reception stamp of the oldest frame read (SocketCAN stamps with the wall clock)."""

    def __init__(self) -> None:
        self.samples_s: collections.deque[float] = collections.deque(maxlen=LAG_SAMPLES)
        self.wakeups = 0
        self.frames = 0

    def add(self, lag_s: float, frames: int) -> None:
        self.samples_s.append(lag_s)
        self.wakeups += 1
        self.frames += frames

    def percentile_s(self, share: float) -> float:
        ordered = sorted(self.samples_s)
        return ordered[min(len(ordered) - 1, int(share * len(ordered)))] if ordered else 0.0

    def figures(self) -> dict[str, float]:
        """Frames, wake-ups and the lag's p50 / p99 / max in ms, for a log line."""
        return {"frames": self.frames, "wakeups": self.wakeups,
                "frames_per_wakeup": round(self.frames / max(self.wakeups, 1), 2),
                "lag_p50_ms": round(self.percentile_s(0.5) * 1000, 2),
                "lag_p99_ms": round(self.percentile_s(0.99) * 1000, 2),
                "lag_max_ms": round(max(self.samples_s, default=0.0) * 1000, 2)}


def frame_message(frame: bytes, timestamp: float, msg_flags: int, channel: str) -> can.Message:
    """A received classical CAN frame as python-can's ``capture_message`` builds it."""
    can_id, dlc, _, data = dissect_can_frame(frame)
    extended = bool(can_id & constants.CAN_EFF_FLAG)
    return can.Message(timestamp=timestamp, channel=channel or None,
                       arbitration_id=can_id & (0x1FFFFFFF if extended else 0x7FF), is_extended_id=extended,
                       is_remote_frame=bool(can_id & constants.CAN_RTR_FLAG),
                       is_error_frame=bool(can_id & constants.CAN_ERR_FLAG),
                       is_rx=not msg_flags & socket.MSG_DONTROUTE, dlc=dlc, data=data)


class BatchedSocketcanBus(SocketcanBus):
    """``SocketcanBus`` receiving and sending in batches (module docstring). ``batch=False``
    behaves as python-can's bus (one frame per wake-up, every send at once), to compare."""

    def __init__(self, channel: str, batch: bool = True, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        # Blocking, so one recvmmsg both waits and reads (wait_batch, bounded by SO_RCVTIMEO);
        # every other call passes MSG_DONTWAIT, and python-can's recv waits in select first.
        self.socket.setblocking(True)
        self._receive_timeout_s: float | None = None
        self.batch = batch
        self._fd = self.socket.fileno()
        self._rx = FrameVector(BATCH_FRAMES, control=True)
        self._tx = FrameVector(BATCH_FRAMES, control=False)
        self._received: collections.deque[can.Message] = collections.deque()
        self._pending: list[bytes] = []  # frames the receive thread sent during the batch
        self._send_lock = threading.Lock()  # pending frames leave before any later send
        self._rx_thread = 0
        self.lag = ReceiveLag()
        self.read_perf_s = 0.0  # perf_counter when the last batch was read (one read per batch)
        self._wall_offset = WallClockOffset()

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """A frame already read in a batch is handed out at once; python-can's ``recv`` (a clock
        read per call, a trapped system call inside User-Mode Linux) only to wait for more."""
        received = self._received
        while received:
            msg = received.popleft()
            if self._is_filtered or self._matches_filters(msg):
                return msg
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._received:
            self._rx_thread = threading.get_ident()
            self._flush()
            msg, filtered = super()._recv_internal(timeout)  # select, then one recvmsg
            if msg is None:
                return None, filtered
            self._received.append(msg)
            if self.batch:
                self._receive_all()
            self._note_read(msg.timestamp)
        return self._received.popleft(), self._is_filtered

    def wait_batch(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for frames and read every frame waiting, with one blocking
        ``recvmmsg`` per BATCH_FRAMES (BatchNotifier's thread); they are handed out by
        ``take``. The receive thread's pending answers leave first. True when frames wait."""
        if self._received:
            return True
        self._rx_thread = threading.get_ident()
        if self._pending:
            self._flush()
        self._set_receive_timeout(timeout_s)
        first = len(self._received)
        if self._read_vector(MSG_WAITFORONE) == self._rx.count:
            self._receive_all()
        if len(self._received) == first:
            return False
        self._note_read(self._received[first].timestamp)
        return True

    def take(self) -> can.Message | None:
        """The next frame read by ``wait_batch`` that passes the filters (None when none)."""
        received = self._received
        while received:
            msg = received.popleft()
            if self._is_filtered or self._matches_filters(msg):
                return msg
        return None

    def _note_read(self, oldest_stamp_s: float) -> None:
        """One clock read per batch: ``read_perf_s`` and the reception lag of its oldest frame."""
        now = time.perf_counter()
        self.read_perf_s = now
        self.lag.add(now + self._wall_offset.at(now) - oldest_stamp_s, len(self._received))

    def _set_receive_timeout(self, timeout_s: float) -> None:
        """SO_RCVTIMEO bounds wait_batch's blocking recvmmsg (0 would mean for ever: >= 1 µs)."""
        if timeout_s == self._receive_timeout_s:
            return
        whole = int(timeout_s)
        micro = max(round((timeout_s - whole) * 1e6), 0 if whole else 1)
        self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, TIMEVAL.pack(whole, micro))
        self._receive_timeout_s = timeout_s

    def frames_waiting(self) -> bool:
        """Frames received but not yet handed out, or waiting in the socket (any thread)."""
        if self._received:
            return True
        try:
            return bool(select.select([self._fd], [], [], 0)[0])
        except (OSError, ValueError):  # closed while stopping
            return False

    def _receive_all(self) -> None:
        """Every frame the socket still holds, BATCH_FRAMES per recvmmsg, without waiting."""
        while self._read_vector(socket.MSG_DONTWAIT) == self._rx.count:
            pass

    def _read_vector(self, flags: int) -> int:
        """One recvmmsg of up to BATCH_FRAMES frames into the queue; how many (0: none)."""
        rx, channel = self._rx, self.channel
        rx.reset_control()
        n = _recvmmsg(self._fd, rx.headers, rx.count, flags, None)
        if n < 0:
            code = ctypes.get_errno()
            if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                return 0
            raise can.CanOperationError(f"Error receiving: {errno.errorcode.get(code, code)}", code)
        raw = rx.frames.raw
        for i in range(n):
            frame = raw[i * FRAME_BYTES:(i + 1) * FRAME_BYTES]
            self._received.append(frame_message(frame, rx.timestamp(i), rx.headers[i].hdr.flags, channel))
        return n

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """From the receive thread: kept for the batch's sendmmsg; else one ``send``, after
        the frames the receive thread keeps (a frame never overtakes one sent before it)."""
        data = build_can_frame(msg)
        with self._send_lock:
            if self.batch and threading.get_ident() == self._rx_thread:
                if len(self._pending) == BATCH_FRAMES:
                    self._flush_locked()
                self._pending.append(data)
                return
            self._flush_locked()
            self._send_now(data, msg, timeout)

    def _send_now(self, data: bytes, msg: can.Message | None, timeout: float | None) -> None:
        try:
            sent = self.socket.send(data, socket.MSG_DONTWAIT)
        except OSError:
            sent = 0
        if sent != len(data):  # refused at once (buffer full): python-can's polling send
            if msg is None:
                msg = frame_message(data, 0.0, 0, self.channel)
                msg.is_rx = False
            super().send(msg, SEND_WAIT_S if timeout is None else timeout)

    def _flush(self) -> None:
        with self._send_lock:
            self._flush_locked()

    def _flush_locked(self) -> None:
        """The receive thread's frames of the last batch, in order, with one sendmmsg."""
        pending = self._pending
        if not pending:
            return
        self._pending = []
        if len(pending) == 1:
            self._send_now(pending[0], None, None)
            return
        tx = self._tx
        ctypes.memmove(tx.frames, b"".join(pending), len(pending) * FRAME_BYTES)
        sent = _sendmmsg(self._fd, tx.headers, len(pending), socket.MSG_DONTWAIT)
        for data in pending[max(sent, 0):]:  # not taken at once (or an error): one by one
            self._send_now(data, None, None)

    def shutdown(self) -> None:
        self._flush()
        super().shutdown()


class BatchNotifier(can.Notifier):
    """python-can's Notifier whose receive thread takes a batch per wake-up from a
    :class:`BatchedSocketcanBus` (module docstring); other buses as python-can's. Listeners
    see every frame in order, as with python-can's thread. ``on_thread_start()`` runs first
    in each receive thread (the master and the daemon's simulated drives make it SCHED_FIFO).

    ``holdoff_s``: after handling a batch the thread sleeps this long before it waits again,
    so the frames that arrive meanwhile are read as one batch. A SCHED_FIFO receive thread
    otherwise preempts the sender at every frame: the master's woke once per TPDO (1,300
    wake-ups for 1,360 frames a second, 3 axes at T = 4 ms inside User-Mode Linux, where a
    wake-up costs a trapped ``recvmmsg``, a clock read and two context switches; docs/vcan.md,
    "The master's receive thread"). With half a cycle the drives' answers to one SYNC come in
    one wake-up; a frame waits at most ``holdoff_s`` longer (its kernel timestamp, which the
    arrival clock judges on, is unchanged). ``thread_cpu_s``: the thread's CPU time when it
    ended (batched reads only)."""

    def __init__(self, bus: can.BusABC, listeners: Any, timeout: float = 1.0,
                 on_thread_start: Callable[[], None] | None = None, holdoff_s: float = 0.0) -> None:
        self.on_thread_start = on_thread_start  # before super() starts the threads
        self.holdoff_s = holdoff_s
        self.thread_cpu_s = 0.0
        super().__init__(bus, listeners, timeout)

    def _rx_thread(self, bus: can.BusABC) -> None:
        if self.on_thread_start is not None:
            self.on_thread_start()
        if not isinstance(bus, BatchedSocketcanBus) or not bus.batch or self._loop is not None:
            super()._rx_thread(bus)
            return
        holdoff_s = self.holdoff_s
        try:
            while not self._stopped:
                try:
                    if bus.wait_batch(self.timeout):
                        with self._lock:
                            while (msg := bus.take()) is not None:
                                self._on_message_received(msg)
                        if holdoff_s > 0.0:
                            time.sleep(holdoff_s)
                except Exception as exc:  # noqa: BLE001 - as python-can's thread: on_error or raise
                    self.exception = exc
                    if not self._on_error(exc):
                        raise
        finally:
            self.thread_cpu_s = time.thread_time()
