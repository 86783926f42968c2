"""Launch-time CAN frames: a raw socket with SO_TXTIME for the kernel's ETF qdisc.

The ETF ("earliest txtime first", sch_etf) qdisc holds every frame until its absolute launch
time (CLOCK_TAI) and hands it to the driver within [txtime - delta, txtime]; a frame it cannot
send by its txtime (a late qdisc watchdog) is dropped, never sent late, and reported on the
sending socket's error queue (SOF_TXTIME_REPORT_ERRORS: ``sock_extended_err`` with origin
SO_EE_ORIGIN_TXTIME, code MISSED; a txtime already past when queued: INVALID_PARAM, and
sendmsg fails with ENOBUFS). CAN_RAW passes SCM_TXTIME to the skb since kernel commit
51a0d5e51178 (present in the 6.1 guest of scripts/with-vcan).

Not the product's stream: measured against the BCM ring (benchmarks/bench_etf.py), it loses
set-points where the ring only delays them, and a stop would wait for the whole queue;
docs/fieldbus.md, "ETF or BCM". Kept for that benchmark and for whoever measures again.

What it needs (measured inside User-Mode Linux 6.1, docs/fieldbus.md "ETF or BCM"):
- CAP_NET_ADMIN for a CLOCK_TAI SO_TXTIME socket, and root for ``tc``;
- ETF under a ``prio`` qdisc, the TXTIME socket's SO_PRIORITY mapped to the ETF band
  (``tc qdisc add dev vcan0 root handle 1: prio bands 2 priomap 1 1 1 1 1 1 0 1 ...`` and
  ``tc qdisc add dev vcan0 parent 1:1 etf clockid CLOCK_TAI delta D``): as the root qdisc ETF
  drops every frame without a launch time (SDO, NMT: sendmsg fails with ENOBUFS);
- on vcan, the driver's own echo (``modprobe vcan echo=1``): without it the CAN core loops
  a frame back to local readers when it is *queued*, so readers (and ``nurbsmotion sim``)
  would see the frames before their launch time. Real CAN drivers echo on transmission;
- a reader on the same host cannot time these frames: the echoed skb keeps the txtime in
  ``skb->tstamp``, so its SO_TIMESTAMPNS *is* the txtime (every interval exactly T). The driver's
  software TX stamp (``send_at(..., report_sent=True)``, ``sent_stamps``) is the transmit time.

Queued frames cannot be revised or withdrawn (only deleting the qdisc flushes them): a stop
reaches the wire after the queued horizon, (H + 1)·T, and H is also the longest stall survived.
"""

from __future__ import annotations

import errno
import socket
import struct
import time
from dataclasses import dataclass
from enum import Enum

CLOCK_TAI = 11  # linux/time.h
SO_TXTIME = 61  # asm-generic/socket.h (SCM_TXTIME is the same number)
SOF_TXTIME_REPORT_ERRORS = 1 << 1  # linux/net_tstamp.h
SO_EE_ORIGIN_TXTIME = 6  # linux/errqueue.h
SO_EE_ORIGIN_TIMESTAMPING = 4
SO_TIMESTAMPING = 37  # SO_TIMESTAMPING_OLD; SCM_TIMESTAMPING likewise
SOF_TIMESTAMPING_TX_SOFTWARE = 1 << 1  # stamp in the driver's transmit (skb_tx_timestamp)
SOF_TIMESTAMPING_SOFTWARE = 1 << 4  # report software stamps
SOF_TIMESTAMPING_OPT_TSONLY = 1 << 11  # the report carries no copy of the frame
SCM_TIMESTAMPING = struct.Struct("@llllll")  # struct scm_timestamping: ts[0] software, [1] legacy, [2] hardware
TX_STAMP_REQUEST = struct.Struct("=I")
ETF_SOCKET_PRIORITY = 6  # highest SO_PRIORITY without CAP_NET_ADMIN; the priomap sends it to the ETF band
SOCK_TXTIME = struct.Struct("=iI")  # struct sock_txtime: clockid, flags
TXTIME = struct.Struct("=Q")  # SCM_TXTIME payload: u64 ns
EXTENDED_ERR = struct.Struct("=IBBBBII")  # struct sock_extended_err
CAN_FRAME = struct.Struct("=IB3x8s")  # struct can_frame
ERRQUEUE_CONTROL_BYTES = 256


class TxtimeError(Enum):
    """Why the ETF qdisc dropped a frame (linux/errqueue.h SO_EE_CODE_TXTIME_*)."""

    INVALID_PARAM = 1  # txtime already past (or before the last sent) when queued
    MISSED = 2  # the qdisc did not get to it by its txtime (late watchdog): dropped, not sent


@dataclass(frozen=True)
class DroppedFrame:
    can_id: int
    txtime_ns: int
    reason: TxtimeError


def tai_now_ns() -> int:
    """CLOCK_TAI now in ns (the clock ETF and SO_TXTIME use)."""
    return time.clock_gettime_ns(CLOCK_TAI)


def parse_dropped(frame: bytes, ancdata: list[tuple[int, int, bytes]]) -> DroppedFrame | None:
    """One error-queue message of a TXTIME socket as a DroppedFrame (None: not a txtime error).
    ``sock_extended_err.ee_data:ee_info`` carry the frame's txtime (high, low 32 bits)."""
    can_id = CAN_FRAME.unpack_from(frame)[0] if len(frame) >= CAN_FRAME.size else -1
    for level, kind, data in ancdata:
        if level == socket.SOL_SOCKET or len(data) < EXTENDED_ERR.size:
            continue
        _, origin, _, code, _, info, high = EXTENDED_ERR.unpack_from(data)
        if origin != SO_EE_ORIGIN_TXTIME:
            continue
        try:
            reason = TxtimeError(code)
        except ValueError:
            return None
        return DroppedFrame(can_id, (high << 32) | info, reason)
    return None


def parse_sent_stamp(ancdata: list[tuple[int, int, bytes]]) -> float | None:
    """The driver's transmit time (s, CLOCK_REALTIME) of an error-queue message reporting a
    software TX timestamp (SO_EE_ORIGIN_TIMESTAMPING), else None."""
    stamp, origin = None, None
    for level, kind, data in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPING and len(data) >= SCM_TIMESTAMPING.size:
            sec, nsec = SCM_TIMESTAMPING.unpack_from(data)[:2]
            stamp = sec + nsec * 1e-9
        elif level != socket.SOL_SOCKET and len(data) >= EXTENDED_ERR.size:
            origin = EXTENDED_ERR.unpack_from(data)[1]
    return stamp if origin == SO_EE_ORIGIN_TIMESTAMPING else None


class TxtimeSocket:
    """Raw CAN socket whose frames carry a CLOCK_TAI launch time (SO_TXTIME), at the priority
    the prio qdisc maps to its ETF band; receives nothing (empty filter)."""

    def __init__(self, channel: str, sock: socket.socket | None = None) -> None:
        if sock is None:
            sock = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
            sock.setsockopt(socket.SOL_SOCKET, SO_TXTIME, SOCK_TXTIME.pack(CLOCK_TAI, SOF_TXTIME_REPORT_ERRORS))
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPING, SOF_TIMESTAMPING_SOFTWARE | SOF_TIMESTAMPING_OPT_TSONLY)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_PRIORITY, ETF_SOCKET_PRIORITY)
            sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, b"")
            sock.bind((channel,))
        self.sock = sock
        self.refused = 0  # sendmsg refused (the qdisc dropped the frame at once: txtime past)
        self.sent_stamps: list[float] = []  # driver transmit times of the frames sent with report_sent

    def send_at(self, frame: bytes, txtime_ns: int, report_sent: bool = False) -> bool:
        """Queue one can_frame for ``txtime_ns`` (CLOCK_TAI); False if refused at once. With
        ``report_sent`` the driver's transmit time comes back on the error queue (sent_stamps)."""
        control = [(socket.SOL_SOCKET, SO_TXTIME, TXTIME.pack(txtime_ns))]
        if report_sent:
            control.append((socket.SOL_SOCKET, SO_TIMESTAMPING, TX_STAMP_REQUEST.pack(SOF_TIMESTAMPING_TX_SOFTWARE)))
        try:
            self.sock.sendmsg([frame], control)
        except OSError as err:
            if err.errno != errno.ENOBUFS:
                raise
            self.refused += 1
            return False
        return True

    def drain_dropped(self) -> list[DroppedFrame]:
        """Every frame the qdisc dropped since the last call (the socket's error queue); the
        transmit stamps found there go to ``sent_stamps``."""
        dropped: list[DroppedFrame] = []
        while True:
            try:
                frame, ancdata, _, _ = self.sock.recvmsg(CAN_FRAME.size, ERRQUEUE_CONTROL_BYTES,
                                                         socket.MSG_ERRQUEUE | socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                return dropped
            report = parse_dropped(frame, ancdata)
            if report is not None:
                dropped.append(report)
                continue
            stamp = parse_sent_stamp(ancdata)
            if stamp is not None:
                self.sent_stamps.append(stamp)

    def close(self) -> None:
        self.sock.close()
