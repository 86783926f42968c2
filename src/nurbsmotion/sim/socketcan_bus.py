"""The drives' SocketCAN bus: python-can's, with one system call per frame instead of two.

python-can's ``SocketcanBus`` waits in ``select`` before every ``recvmsg`` and polls the
socket for writability with ``select`` before every ``send``. The simulated drives receive
SYNC and one RPDO per drive every cycle and answer each SYNC with a TPDO per drive, so
their process makes two system calls per frame. On a real kernel that costs microseconds;
inside User-Mode Linux (scripts/with-vcan) every system call of a guest process is trapped
by the host and costs tens of µs, and the drives' process, the master and any listener
share the guest's one CPU: with three drives at T = 4 ms the guest ran at 100 % and the
drives' process fell behind the wire by up to seconds (docs/vcan.md, "The drives' lag").

:class:`BatchedSocketcanBus` keeps python-can's frame parsing (``capture_message``) and its
``select`` when the socket is empty, but on a non-blocking socket: after each wake-up it
reads every frame the socket holds (one ``recvmsg`` each, the last one failing with EAGAIN)
and hands them out one by one, and it sends with one ``send`` (python-can's polling send
only when the kernel refuses, e.g. a full transmit queue). canopen's ``Network`` uses it as
its bus (``network.bus`` set before ``connect``, as canopen allows), so the receive thread,
the Notifier and the dispatch are canopen's and python-can's own.
"""

from __future__ import annotations

import collections
import errno
import time
from typing import Any

import can
from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame, capture_message

EMPTY = (errno.EAGAIN, errno.EWOULDBLOCK)


LAG_SAMPLES = 100_000  # wake-ups whose reception lag is kept (about 7 min at 4 ms)


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


class BatchedSocketcanBus(SocketcanBus):
    """``SocketcanBus`` reading the socket empty per wake-up and sending without the poll.
    ``batch=False`` reads one frame per wake-up, as python-can does (to measure the difference)."""

    def __init__(self, channel: str, batch: bool = True, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        self.socket.setblocking(False)
        self.batch = batch
        self._received: collections.deque[can.Message] = collections.deque()
        self.lag = ReceiveLag()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._received:
            msg, filtered = super()._recv_internal(timeout)  # select, then one recvmsg
            if msg is None:
                return None, filtered
            self._received.append(msg)
            if self.batch:
                self._read_all()
            self.lag.add(time.time() - msg.timestamp, len(self._received))
        return self._received.popleft(), self._is_filtered

    def _read_all(self) -> None:
        """Every frame the socket still holds, without waiting."""
        get_channel = self.channel == ""
        while True:
            try:
                msg = capture_message(self.socket, get_channel)
            except can.CanOperationError as err:
                if err.error_code in EMPTY:
                    return
                raise
            if msg is None:
                return
            if not msg.channel and self.channel:
                msg.channel = self.channel
            self._received.append(msg)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """One ``send``; python-can's polling send when the kernel refuses the frame."""
        data = build_can_frame(msg)
        try:
            sent = self.socket.send(data)
        except (BlockingIOError, OSError):
            sent = 0
        if sent != len(data):
            super().send(msg, timeout)
