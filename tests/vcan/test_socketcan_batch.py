"""The batched SocketCAN bus (nurbsmotion/can/socketcan_batch.py) on a real vcan0: every frame
received once, in order, with its kernel timestamp, however many wait in the socket; frames
the receive thread sends leave after its batch, in order; another thread's frame leaves at
once, but never before a frame the receive thread sent earlier."""

from __future__ import annotations

import threading
import time

import can
import pytest

from nurbsmotion.can.socketcan_batch import BATCH_FRAMES, BatchedSocketcanBus
from tests.helpers import wait_for

pytestmark = pytest.mark.vcan

CYCLES = 1000
IDS = (0x80, 0x201, 0x202, 0x203)


def cycle_frames(k: int) -> list[tuple[int, bytes]]:
    return [(i, b"" if i == 0x80 else k.to_bytes(4, "little") + bytes(4)) for i in IDS]


def test_batches_keep_every_frame_in_order_and_answers_follow(vcan0, open_bus):
    peer = open_bus(0x181)  # hears the answers only
    bus = BatchedSocketcanBus(channel=vcan0)
    got: list[can.Message] = []

    def read() -> None:  # as canopen's Notifier: recv, handle, answer every RPDO of node 1
        while (msg := bus.recv(0.5)) is not None:
            got.append(msg)
            if msg.arbitration_id == 0x201:
                bus.send(can.Message(arbitration_id=0x181, data=msg.data, is_extended_id=False))

    reader = threading.Thread(target=read)
    reader.start()
    sender = can.Bus(interface="socketcan", channel=vcan0)
    t0 = time.time()
    sent = []
    try:
        for k in range(CYCLES):
            for can_id, data in cycle_frames(k):
                sender.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
                sent.append((can_id, data))
            if k % 250 == 0:  # let a backlog of more than one batch build up now and then
                time.sleep(0.05)
        reader.join(30)
        answers = []
        while (msg := peer.recv(0.5)) is not None:
            answers.append(int.from_bytes(msg.data[:4], "little"))
    finally:
        sender.shutdown()
        bus.shutdown()
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == sent
    assert all(t0 - 1.0 < m.timestamp < time.time() for m in got), "kernel receive stamps (wall clock)"
    assert answers == list(range(CYCLES)), "answers lost, repeated or out of order"
    assert bus.lag.wakeups < len(sent), "every frame needed a wake-up of its own: no batch was read"
    assert bus.lag.frames == len(sent)


def test_a_backlog_larger_than_one_recvmmsg_is_read_whole(vcan0):
    bus = BatchedSocketcanBus(channel=vcan0)
    sender = can.Bus(interface="socketcan", channel=vcan0)
    try:
        frames = 3 * BATCH_FRAMES + 5
        for k in range(frames):
            sender.send(can.Message(arbitration_id=0x300, data=k.to_bytes(2, "little"), is_extended_id=False))
        values = []
        while (msg := bus.recv(0.2)) is not None:
            values.append(int.from_bytes(msg.data, "little"))
    finally:
        sender.shutdown()
        bus.shutdown()
    assert values == list(range(frames))
    assert bus.lag.wakeups == 1, "one wake-up reads the whole backlog"


def test_another_threads_frame_leaves_at_once_after_the_receive_threads_earlier_ones(vcan0, open_bus):
    peer = open_bus(0x181, 0x77F)
    bus = BatchedSocketcanBus(channel=vcan0)
    sender = can.Bus(interface="socketcan", channel=vcan0)
    answered, release = threading.Event(), threading.Event()

    def read() -> None:  # answers the one frame, then stays in its callback
        msg = bus.recv(2.0)
        assert msg is not None
        bus.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        answered.set()
        release.wait(5.0)

    reader = threading.Thread(target=read)
    reader.start()
    try:
        time.sleep(0.2)  # the reader waits in recv
        sender.send(can.Message(arbitration_id=0x201, data=b"\x00", is_extended_id=False))
        assert answered.wait(5.0)
        assert peer.recv(0.3) is None, "the receive thread's answer left before its batch was handled"
        bus.send(can.Message(arbitration_id=0x77F, data=b"\x05", is_extended_id=False))  # as a heartbeat
        got = [peer.recv(1.0), peer.recv(1.0)]
    finally:
        release.set()
        reader.join(5.0)
        sender.shutdown()
        bus.shutdown()
    assert [(m.arbitration_id, bytes(m.data)) for m in got if m is not None] == [(0x181, b"\x01"), (0x77F, b"\x05")]


def test_frames_read_but_not_handed_out_count_as_waiting(vcan0):
    """The drives' arrival clock (arrival_clock.py) asks the bus whether frames wait: the
    frames of a batch already read into the bus are invisible to select() but still wait."""
    from nurbsmotion.can.arrival_clock import socket_pending

    bus = BatchedSocketcanBus(channel=vcan0)
    sender = can.Bus(interface="socketcan", channel=vcan0)
    try:
        pending = socket_pending(bus)
        assert pending() is False
        for k in range(3):
            sender.send(can.Message(arbitration_id=0x300, data=bytes([k]), is_extended_id=False))
        time.sleep(0.1)
        assert pending() is True  # in the socket
        assert bus.recv(1.0) is not None  # one wake-up reads all three, hands out one
        assert pending() is True  # two read, not handed out
        assert bus.recv(1.0) is not None and bus.recv(1.0) is not None
        assert pending() is False
    finally:
        sender.shutdown()
        bus.shutdown()


def test_the_batch_notifier_hands_out_every_frame_in_order_with_one_wake_up_per_batch(vcan0):
    """socketcan_batch.BatchNotifier (what the master and `nurbsmotion sim` run): every frame to
    every listener once, in order; a burst waiting in the socket is one wake-up; the read time
    of each batch is kept (the master's arrival clock uses it instead of a clock read per frame)."""
    from nurbsmotion.can.socketcan_batch import BatchNotifier

    bus = BatchedSocketcanBus(channel=vcan0)
    got: list[tuple[int, bytes, float]] = []
    notifier = BatchNotifier(bus, [lambda m: got.append((m.arbitration_id, bytes(m.data), bus.read_perf_s))], 0.2)
    sender = can.Bus(interface="socketcan", channel=vcan0)
    sent = []
    try:
        time.sleep(0.3)  # the thread waits (at most 0.2 s per recvmmsg) and comes back empty
        for k in range(CYCLES):
            for can_id, data in cycle_frames(k):
                sender.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
                sent.append((can_id, data))
            if k % 250 == 0:
                time.sleep(0.05)
        wait_for(lambda: len(got) >= len(sent), 30.0, "every sent frame received", 0.05)
    finally:
        notifier.stop()
        sender.shutdown()
        bus.shutdown()
    assert [(i, d) for i, d, _ in got] == sent
    assert notifier.exception is None
    assert bus.lag.frames == len(sent) and bus.lag.wakeups < len(sent)
    read_times = [t for _, _, t in got]
    assert read_times == sorted(read_times) and len(set(read_times)) == bus.lag.wakeups



def test_with_a_holdoff_the_frames_sent_while_the_thread_sleeps_come_in_one_batch(vcan0):
    """BatchNotifier's ``holdoff_s`` (the master's receive thread: half a cycle): the first
    frame of a burst wakes the thread; the others, sent while it sleeps after that batch, are
    read in one more wake-up, not one each (the master used to wake once per TPDO)."""
    from nurbsmotion.can.socketcan_batch import BatchNotifier

    holdoff_s = 0.5  # much longer than sending the rest of the burst, even inside User-Mode Linux
    bus = BatchedSocketcanBus(channel=vcan0)
    first = threading.Event()
    batches: list[float] = []  # the read time of the batch of each frame received

    def on_frame(msg: can.Message) -> None:
        batches.append(bus.read_perf_s)
        first.set()

    notifier = BatchNotifier(bus, [on_frame], 0.2, holdoff_s=holdoff_s)
    sender = can.Bus(interface="socketcan", channel=vcan0)
    burst = [can.Message(arbitration_id=0x181 + i, data=bytes(8), is_extended_id=False) for i in range(6)]
    try:
        sender.send(burst[0])
        assert first.wait(5.0), "the first frame was not received"
        for msg in burst[1:]:  # while the thread sleeps after its first batch
            sender.send(msg)
        wait_for(lambda: len(batches) == len(burst), 5.0, "the whole burst received", 0.05)
    finally:
        notifier.stop()
        sender.shutdown()
        bus.shutdown()
    assert notifier.exception is None
    assert len(set(batches)) == 2, f"{len(set(batches))} wake-ups for a burst of {len(burst)} frames"
