"""The master's receive filter on the kernel queue (fieldbus.connection.filter_received): the
raw socket takes only what the master consumes. The kernel's CAN loopback hands a raw socket
every frame other sockets of the host send, so without it the daemon's receive thread would
also read its own SYNC and RPDOs (the kernel queue's BCM socket) and its own heartbeat."""

from __future__ import annotations

import uuid
from pathlib import Path

import can
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.fieldbus import Master

REPOSITORY = Path(__file__).resolve().parents[2]
DRIVES = (1, 2, 3)  # config/vcan.yaml's axes


def accepts(bus: can.BusABC, can_id: int) -> bool:
    return bus._matches_filters(can.Message(arbitration_id=can_id, data=bytes(8), is_extended_id=False))


@pytest.fixture
def master_on_kernel_queue():
    """A master of config/vcan.yaml on a virtual bus, with the kernel queue's filter (no bring-up)."""
    bus = can.Bus(interface="virtual", channel=f"filter-{uuid.uuid4().hex}")
    master = Master(load_config(REPOSITORY / "config" / "vcan.yaml"), bus, sync_source="kernel")
    try:
        yield master, bus
    finally:
        bus.shutdown()


def test_the_master_receives_what_the_drives_send_and_not_its_own_cyclic_frames(master_on_kernel_queue):
    master, bus = master_on_kernel_queue
    master._conn.filter_received()
    wanted = [base + node for node in DRIVES for base in (0x80, 0x180, 0x280, 0x580, 0x700)]  # EMCY TPDO1/2 SDO hb
    own = [0x80, 0x000, 0x700 + master.config.master.node_id] + [0x200 + n for n in DRIVES] + \
          [0x600 + n for n in DRIVES]  # SYNC, NMT, its heartbeat, RPDO1s, SDO requests
    assert [hex(i) for i in wanted if not accepts(bus, i)] == []
    assert [hex(i) for i in own if accepts(bus, i)] == []


def test_another_node_joins_the_filter_with_its_answers_and_tpdos(master_on_kernel_queue):
    master, bus = master_on_kernel_queue
    master._conn.filter_received()
    assert not accepts(bus, 0x585) and not accepts(bus, 0x18A)
    master.receive_from(5)  # the spindle (fieldbus.spindle): SDO answers, EMCY, heartbeat
    master.receive_from(10, (0x18A,))  # the I/O node and its TPDO1 (fieldbus.io)
    assert all(accepts(bus, i) for i in (0x85, 0x585, 0x705, 0x8A, 0x58A, 0x70A, 0x18A))
    assert not accepts(bus, 0x605) and not accepts(bus, 0x185)


def test_a_recorded_bus_takes_every_frame(master_on_kernel_queue, tmp_path):
    """The traffic record (monitoring.traffic_log) shows the whole bus: no filter while it records."""
    master, bus = master_on_kernel_queue
    master.connect()
    try:
        master._conn.record_traffic(tmp_path / "traffic.log")
        assert accepts(bus, 0x80) and accepts(bus, 0x201)
        master._conn.record_traffic(None)
        assert not accepts(bus, 0x80) and accepts(bus, 0x181)
    finally:
        master._conn.close()
