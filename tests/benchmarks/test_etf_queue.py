"""TxtimeSocket against a fake socket: the launch time and TX-stamp request it puts on each
frame, ENOBUFS (frame refused by the qdisc at once), and what it reads from the error queue
(ETF drop reports, transmit stamps) in the kernel's byte layout."""

from __future__ import annotations

import errno
import socket

import pytest

from benchmarks.etf_queue import (
    CAN_FRAME,
    EXTENDED_ERR,
    SCM_TIMESTAMPING,
    SO_EE_ORIGIN_TIMESTAMPING,
    SO_EE_ORIGIN_TXTIME,
    SO_TIMESTAMPING,
    SO_TXTIME,
    SOF_TIMESTAMPING_TX_SOFTWARE,
    TX_STAMP_REQUEST,
    TXTIME,
    DroppedFrame,
    TxtimeError,
    TxtimeSocket,
)

SOL_CAN_RAW = 101  # the level the CAN_RAW error queue reports under (SCM_CAN_RAW_ERRQUEUE = 1)


class FakeSocket:
    def __init__(self) -> None:
        self.sent: list[tuple[list[bytes], list[tuple[int, int, bytes]]]] = []
        self.errqueue: list[tuple[bytes, list[tuple[int, int, bytes]]]] = []
        self.fail_with: int | None = None

    def sendmsg(self, buffers, ancdata):
        if self.fail_with is not None:
            raise OSError(self.fail_with, errno.errorcode[self.fail_with])
        self.sent.append((list(buffers), list(ancdata)))
        return sum(len(b) for b in buffers)

    def recvmsg(self, size, control, flags):
        assert flags & socket.MSG_ERRQUEUE and flags & socket.MSG_DONTWAIT
        if not self.errqueue:
            raise BlockingIOError
        return (*self.errqueue.pop(0), 0, None)

    def close(self) -> None:
        pass


def frame(can_id: int) -> bytes:
    return CAN_FRAME.pack(can_id, 6, b"\x0f\x00\x01\x00\x00\x00")


def etf_report(can_id: int, ee_errno: int, code: int, txtime_ns: int) -> tuple[bytes, list]:
    """What sch_etf's report_sock_error queues: the frame, and sock_extended_err with the
    txtime's low 32 bits in ee_info and the high ones in ee_data."""
    serr = EXTENDED_ERR.pack(ee_errno, SO_EE_ORIGIN_TXTIME, 0, code, 0, txtime_ns & 0xFFFFFFFF, txtime_ns >> 32)
    return frame(can_id), [(SOL_CAN_RAW, 1, serr)]


def tx_stamp_report(stamp_s: float) -> tuple[bytes, list]:
    """A software TX timestamp report (SOF_TIMESTAMPING_OPT_TSONLY: no frame copy)."""
    sec, nsec = int(stamp_s), round((stamp_s - int(stamp_s)) * 1e9)
    stamps = SCM_TIMESTAMPING.pack(sec, nsec, 0, 0, 0, 0)
    serr = EXTENDED_ERR.pack(errno.ENOMSG, SO_EE_ORIGIN_TIMESTAMPING, 0, 0, 0, 0, 0)
    return b"", [(socket.SOL_SOCKET, SO_TIMESTAMPING, stamps), (SOL_CAN_RAW, 1, serr)]


def test_send_at_carries_the_launch_time_in_ns():
    fake = FakeSocket()
    sock = TxtimeSocket("vcan0", sock=fake)  # type: ignore[arg-type]
    assert sock.send_at(frame(0x201), 1_700_000_000_123_456_789)
    buffers, ancdata = fake.sent[0]
    assert buffers == [frame(0x201)]
    assert ancdata == [(socket.SOL_SOCKET, SO_TXTIME, TXTIME.pack(1_700_000_000_123_456_789))]


def test_report_sent_asks_the_driver_for_a_software_transmit_stamp():
    fake = FakeSocket()
    TxtimeSocket("vcan0", sock=fake).send_at(frame(0x80), 5, report_sent=True)  # type: ignore[arg-type]
    _, ancdata = fake.sent[0]
    assert (socket.SOL_SOCKET, SO_TIMESTAMPING, TX_STAMP_REQUEST.pack(SOF_TIMESTAMPING_TX_SOFTWARE)) in ancdata


def test_a_frame_the_qdisc_refuses_at_once_is_counted_not_raised():
    fake = FakeSocket()
    fake.fail_with = errno.ENOBUFS
    sock = TxtimeSocket("vcan0", sock=fake)  # type: ignore[arg-type]
    assert not sock.send_at(frame(0x201), 1)
    assert sock.refused == 1


def test_other_send_errors_propagate():
    fake = FakeSocket()
    fake.fail_with = errno.ENETDOWN
    with pytest.raises(OSError):
        TxtimeSocket("vcan0", sock=fake).send_at(frame(0x201), 1)  # type: ignore[arg-type]


def test_drain_sorts_drop_reports_and_transmit_stamps():
    fake = FakeSocket()
    late_ns = 0x1_2345_6789_ABCD  # needs both halves of the 64-bit txtime
    fake.errqueue = [
        etf_report(0x80, errno.ECANCELED, TxtimeError.MISSED.value, late_ns),
        tx_stamp_report(1700000000.25),
        etf_report(0x203, errno.EINVAL, TxtimeError.INVALID_PARAM.value, 42),
        (b"", [(SOL_CAN_RAW, 1, EXTENDED_ERR.pack(errno.EIO, 2, 0, 0, 0, 0, 0))]),  # another origin: ignored
    ]
    sock = TxtimeSocket("vcan0", sock=fake)  # type: ignore[arg-type]
    assert sock.drain_dropped() == [DroppedFrame(0x80, late_ns, TxtimeError.MISSED),
                                    DroppedFrame(0x203, 42, TxtimeError.INVALID_PARAM)]
    assert sock.sent_stamps == [pytest.approx(1700000000.25, abs=1e-9)]
    assert sock.drain_dropped() == []
