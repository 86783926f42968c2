"""python-can on a real kernel SocketCAN vcan0: frames round-trip, and the kernel's broadcast
manager (BCM) sends SYNC at the cycle period (what the master's `network.sync.start` uses)."""

from __future__ import annotations

import time

import can
import numpy as np
import pytest
from can.interfaces.socketcan.socketcan import CyclicSendTask

from tests.vcan.conftest import CYCLE_PERIOD_S

pytestmark = pytest.mark.vcan

SYNC_COB_ID = 0x80
RPDO1_NODE1 = 0x201
TPDO1_NODE1 = 0x181
RECV_TIMEOUT_S = 2.0
SYNC_MEASURE_S = 1.0


def frames_with_every_length(can_id: int) -> list[can.Message]:
    """One standard frame per DLC 0..8, with distinct payloads."""
    return [can.Message(arbitration_id=can_id, data=bytes((dlc * 16 + i) & 0xFF for i in range(dlc)),
                        is_extended_id=False) for dlc in range(9)]


def receive(bus: can.BusABC, count: int) -> list[can.Message]:
    """Up to `count` frames, each within RECV_TIMEOUT_S."""
    frames = []
    while len(frames) < count and (frame := bus.recv(RECV_TIMEOUT_S)) is not None:
        frames.append(frame)
    return frames


def assert_same_frames(received: list[can.Message], sent: list[can.Message]) -> None:
    assert [(m.arbitration_id, m.dlc, bytes(m.data)) for m in received] == \
           [(m.arbitration_id, m.dlc, bytes(m.data)) for m in sent]


def test_frames_cross_vcan0_between_two_sockets_in_both_directions(open_bus):
    master = open_bus(TPDO1_NODE1)
    drive = open_bus(RPDO1_NODE1)
    set_points = frames_with_every_length(RPDO1_NODE1)
    replies = frames_with_every_length(TPDO1_NODE1)

    for frame in set_points:
        master.send(frame)
    assert_same_frames(receive(drive, len(set_points)), set_points)

    for frame in replies:
        drive.send(frame)
    assert_same_frames(receive(master, len(replies)), replies)


def test_every_listener_on_vcan0_hears_a_frame_but_not_its_sender(open_bus):
    sender = open_bus(RPDO1_NODE1)
    listeners = [open_bus(RPDO1_NODE1), open_bus(RPDO1_NODE1)]
    frame = can.Message(arbitration_id=RPDO1_NODE1, data=b"\x01\x02\x03\x04", is_extended_id=False)

    sender.send(frame)

    for listener in listeners:
        assert_same_frames(receive(listener, 1), [frame])
    assert sender.recv(0.1) is None


def sync_intervals_s(bus: can.BusABC, duration_s: float) -> np.ndarray:
    """Intervals between the kernel receive timestamps of SYNC frames heard for duration_s."""
    stamps = []
    deadline = time.monotonic() + duration_s
    while (left := deadline - time.monotonic()) > 0:
        frame = bus.recv(left)
        if frame is not None:
            stamps.append(frame.timestamp)
    return np.diff(np.array(stamps))


def test_kernel_bcm_sends_sync_every_cycle_with_small_jitter(open_bus):
    master = open_bus(SYNC_COB_ID)
    drive = open_bus(SYNC_COB_ID)
    sync = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)

    task = master.send_periodic(sync, CYCLE_PERIOD_S)
    try:
        assert isinstance(task, CyclicSendTask), "SYNC must come from the kernel BCM, not a Python thread"
        drive.recv(RECV_TIMEOUT_S)  # first SYNC: measure from here
        intervals_s = sync_intervals_s(drive, SYNC_MEASURE_S)
    finally:
        task.stop()

    # The BCM re-arms its timer from the time it fired, so timer latency adds to every period:
    # a few us on a real kernel, ~50-150 us inside User-Mode Linux, and the tail grows to
    # milliseconds when the host is busy (docs/vcan.md). So: the typical interval is the
    # period within 5 %, the count is only roughly the expected one, the tail is printed.
    expected_count = SYNC_MEASURE_S / CYCLE_PERIOD_S
    deviation_s = np.abs(intervals_s - CYCLE_PERIOD_S)
    print(f"SYNC at {CYCLE_PERIOD_S * 1e3:g} ms over {SYNC_MEASURE_S:g} s: {len(intervals_s)} intervals, "
          f"mean {intervals_s.mean() * 1e3:.3f} ms, median {np.median(intervals_s) * 1e3:.3f} ms, "
          f"|interval - period| p50 {np.percentile(deviation_s, 50) * 1e6:.0f} us, "
          f"p90 {np.percentile(deviation_s, 90) * 1e6:.0f} us, max {deviation_s.max() * 1e6:.0f} us")
    assert len(intervals_s) >= 0.75 * expected_count
    assert np.median(deviation_s) < 0.05 * CYCLE_PERIOD_S

def test_stopping_the_bcm_task_stops_sync(open_bus):
    master = open_bus(SYNC_COB_ID)
    drive = open_bus(SYNC_COB_ID)
    task = master.send_periodic(can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False),
                                CYCLE_PERIOD_S)
    assert drive.recv(RECV_TIMEOUT_S) is not None

    task.stop()
    time.sleep(2 * CYCLE_PERIOD_S)
    while drive.recv(0) is not None:  # SYNCs queued before the stop
        pass

    assert drive.recv(10 * CYCLE_PERIOD_S) is None
