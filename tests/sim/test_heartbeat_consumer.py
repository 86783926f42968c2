"""Heartbeat consumer (0x1016): a drive faults when the master's heartbeat stops."""

from __future__ import annotations

import struct

from nurbsmotion.can.cia402 import State
from nurbsmotion.sim.heartbeat import HeartbeatConsumer, decode_consumer_entry

from conftest import Bench, wait_for

MASTER_ID = 0x7F


def test_decode_entry() -> None:
    assert decode_consumer_entry(0x007F_0064) == (0x7F, 0.1)
    assert decode_consumer_entry(0x007F_0000) is None and decode_consumer_entry(0x0000_0064) is None


def test_monitoring_starts_with_the_first_heartbeat_and_reports_a_loss_once() -> None:
    consumer = HeartbeatConsumer()
    consumer.configure([0x0005_000A, 0])  # node 5, 10 ms
    assert consumer.newly_failed(1.0) == []  # never seen: not monitored yet
    consumer.seen(5, 0.5)
    assert consumer.newly_failed(0.5 + 0.0078125) == []
    assert consumer.newly_failed(0.5 + 0.0117188) == [5]
    assert consumer.newly_failed(0.75) == []
    consumer.seen(5, 1.0)  # back: re-armed
    assert consumer.newly_failed(1.25) == [5]


def test_drive_faults_with_emcy_8130_when_the_master_heartbeat_stops(bench: Bench) -> None:
    drive, node = bench.add(2)
    node.sdo[0x1016][1].raw = MASTER_ID << 16 | 30
    bench.operational(2)
    bench.enable(2)
    for _ in range(3):
        bench.send(0x700 + MASTER_ID, b"\x05")
    wait_for(lambda: bench.frames.of(0x82), what="EMCY after the master went silent")
    assert struct.unpack_from("<H", bench.frames.of(0x82)[0])[0] == 0x8130
    assert drive.state is State.FAULT


def test_a_sync_arriving_after_the_deadline_finds_the_loss_before_it_counts(bench: Bench) -> None:
    """A drive working through a backlog judges at each SYNC's arrival (its ticker does not
    poll while frames wait): the TPDO answering the first SYNC that arrived more than the
    consumer time after the last heartbeat already reports FAULT."""
    drive, node = bench.add(2)
    node.sdo[0x1016][1].raw = MASTER_ID << 16 | 300
    bench.operational(2)
    bench.enable(2)
    for k in range(3):  # heartbeats that arrived at 0.0, 0.1, 0.2 s
        bench.send(0x700 + MASTER_ID, b"\x05", at_s=0.1 * k)
    bench.sync(at_s=0.45)  # within 300 ms of the last heartbeat
    assert drive.state is State.OPERATION_ENABLED
    bench.frames.clear()
    bench.sync(at_s=0.55)  # 350 ms after it: the master fell silent
    statusword = struct.unpack_from("<H", bench.frames.of(0x182)[0])[0]
    assert statusword & 0x08, f"statusword 0x{statusword:04X} answers the late SYNC without the fault"
    assert struct.unpack_from("<H", bench.frames.of(0x82)[0])[0] == 0x8130
