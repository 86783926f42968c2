"""Timeouts judged on the frames' arrival timeline (nurbsmotion.can.arrival_clock), as the simulated
drives and the master's heartbeat consumer judge them:
a backlog of frames that arrived in time is not a loss; a silent bus is."""

from __future__ import annotations

import can
import pytest

from nurbsmotion.can.arrival_clock import ArrivalClock, socket_pending
from nurbsmotion.sim.heartbeat import HeartbeatConsumer

MASTER = 0x7F


def test_before_any_frame_the_judging_time_is_now() -> None:
    assert ArrivalClock(lambda: False).judging_time(5.0) == 5.0


def test_while_frames_wait_the_judging_time_is_the_last_arrival_handled() -> None:
    waiting = [True]
    clock = ArrivalClock(lambda: waiting[0])
    clock.arrived(arrival_s=10.0, handled_s=10.8)  # handled 0.8 s late, more behind it
    assert clock.lag_s == pytest.approx(0.8)
    assert clock.judging_time(11.5) == 10.0  # the bus is known up to 10.0, no further
    waiting[0] = False
    assert clock.judging_time(11.5) == pytest.approx(10.7)  # caught up: runs on from there, through the lag


def test_a_backlog_of_heartbeats_that_arrived_in_time_is_not_a_loss() -> None:
    """Heartbeats every 100 ms, consumer 300 ms; the process stops handling for 1 s (frames
    pile up in the socket) and then handles the backlog: judged on processing time this was
    a loss, judged on arrival times it is not; after the last one the loss is found."""
    consumer = HeartbeatConsumer()
    consumer.configure([MASTER << 16 | 300])
    waiting = [False]
    clock = ArrivalClock(lambda: waiting[0])
    for k in range(5):  # handled in time
        consumer.seen(MASTER, clock.arrived(0.1 * k, 0.1 * k + 0.001))
        assert consumer.newly_failed(clock.judging_time(0.1 * k + 0.002)) == []
    waiting[0] = True  # 0.5 .. 1.4 arrive while the process is away
    assert consumer.newly_failed(clock.judging_time(1.45)) == []  # the ticker runs before the backlog
    for k in range(5, 15):
        consumer.seen(MASTER, clock.arrived(0.1 * k, 1.45 + 0.01 * (k - 5)))
        assert consumer.newly_failed(clock.judging_time(1.46 + 0.01 * (k - 5))) == []
    waiting[0] = False  # caught up; the master then falls silent after its heartbeat at 1.4
    last_handled = 1.45 + 0.01 * 9
    lag = last_handled - 1.4
    assert consumer.newly_failed(clock.judging_time(1.4 + 0.29 + lag)) == []
    assert consumer.newly_failed(clock.judging_time(1.4 + 0.31 + lag)) == [MASTER]


def test_pending_on_the_virtual_bus_is_its_receive_queue() -> None:
    with can.Bus(interface="virtual", channel="arrival-clock-test") as reader, \
            can.Bus(interface="virtual", channel="arrival-clock-test") as sender:
        pending = socket_pending(reader)
        assert pending() is False
        sender.send(can.Message(arbitration_id=0x77F, data=b"\x05", is_extended_id=False))
        assert pending() is True
        assert reader.recv(1.0) is not None
        assert pending() is False


def test_the_wall_clock_offset_is_read_again_only_after_its_refresh_time(monkeypatch) -> None:
    from nurbsmotion.can import arrival_clock

    wall = [1000.0]
    monkeypatch.setattr(arrival_clock.time, "time", lambda: wall[0])
    offset = arrival_clock.WallClockOffset()
    assert offset.at(10.0) == 990.0
    wall[0] = 1000.5  # the wall clock stepped: not seen until the refresh time has passed
    assert offset.at(10.0 + arrival_clock.OFFSET_REFRESH_S) == 990.0
    assert offset.at(10.001 + arrival_clock.OFFSET_REFRESH_S) == 1000.5 - 11.001
