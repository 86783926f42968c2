"""fieldbus.scan: decoding 0x1000 / 0x1018 / 0x6502 and SDO answers, and scans on python-can's
virtual bus of simulated drives (nurbsmotion.sim) and of nodes that answer partly or not at all."""

from __future__ import annotations

import itertools
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from nurbsmotion.can import cia402 as c
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus import eds_catalog
from nurbsmotion.fieldbus.scan import VENDOR_NAMES, DeviceType, Identity, NodeReport, ScanSettings, SdoAnswer, \
    nmt_state_name, open_network, parse_upload_answer, read_node, scan_network, supported_modes, upload_request
from nurbsmotion.sim import SimNetwork
from tests.fieldbus.fake_nodes import ABORT_HARDWARE, FakeNode, drive_objects

ROOT = Path(__file__).resolve().parents[2]
EPOS4 = ROOT / "tests" / "data" / "eds" / "maxon_epos4_50_15_node1.dcf"
# In-process answers come within milliseconds; the time-out only bounds the absent ids' probe.
FAST = ScanSettings(listen_s=0.3, sdo_timeout_s=0.3)
_channels = itertools.count()


# ------------------------------------------------------------------ pure decoding


def test_device_type_splits_profile_and_additional_information():
    drive = DeviceType(0x00020192)
    assert (drive.profile, drive.additional) == (402, 2)
    assert drive.describe() == "CiA 402 drive, servo drive"
    assert DeviceType(0x00030191).describe() == "CiA 401 I/O, digital in + digital out"
    assert DeviceType(0x00010192).describe() == "CiA 402 drive, frequency converter"
    assert DeviceType(0x00000194).describe() == "CiA 404 measuring device"
    assert DeviceType(0x00000000).describe() == "no profile"
    assert DeviceType(0x00000123).describe() == "profile 291"


def test_supported_modes_names_the_0x6502_bits():
    assert supported_modes(0x1E4) == ("pv", "hm", "ip", "csp", "csv")  # the packaged servo
    assert supported_modes(0x3A5) == ("pp", "pv", "hm", "csp", "csv", "cst")  # maxon EPOS4 (SOURCES.md)
    assert supported_modes(0x1F0065)[-5:] == tuple(f"vendor bit {b}" for b in range(16, 21))  # Technosoft iPOS
    assert supported_modes(0) == ()


def test_expedited_answers_aborts_and_foreign_frames():
    assert upload_request(0x1018, 2) == bytes([0x40, 0x18, 0x10, 0x02, 0, 0, 0, 0])
    four = bytes([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00])
    assert parse_upload_answer(four, 0x1000, 0) == SdoAnswer(data=bytes([0x92, 0x01, 0x02, 0x00]))
    one = bytes([0x4F, 0x02, 0x65, 0x00, 0x7F, 0xAA, 0xAA, 0xAA])
    assert parse_upload_answer(one, 0x6502, 0) == SdoAnswer(data=b"\x7f")
    unsized = bytes([0x42, 0x00, 0x10, 0x00, 1, 2, 3, 4])
    assert parse_upload_answer(unsized, 0x1000, 0) == SdoAnswer(data=bytes([1, 2, 3, 4]))
    abort = struct.pack("<BHBI", 0x80, 0x1000, 0, 0x06020000)
    assert parse_upload_answer(abort, 0x1000, 0) == SdoAnswer(abort_code=0x06020000)
    assert parse_upload_answer(bytes([0x41, 0x08, 0x10, 0, 20, 0, 0, 0]), 0x1008, 0) == SdoAnswer(segmented=True)
    assert parse_upload_answer(four, 0x1018, 1) is None  # an answer about another object
    assert parse_upload_answer(four[:7], 0x1000, 0) is None
    assert parse_upload_answer(bytes([0x60, 0x00, 0x10, 0, 0, 0, 0, 0]), 0x1000, 0) is None  # a download answer


def test_nmt_state_names():
    assert [nmt_state_name(s) for s in (0x00, 0x04, 0x05, 0x7F, None, 0x33)] == [
        "BOOTUP", "STOPPED", "OPERATIONAL", "PRE-OPERATIONAL", "-", "state 0x33"]


def test_vendor_names_are_the_ones_the_eds_files_give():
    files = sorted((ROOT / "tests" / "data" / "eds").glob("*.[ed][dc][sf]")) + [ROOT / "eds" / "nurbsmotion-servo.eds"]
    named = {}
    for path in files:
        entry = eds_catalog.read_entry(path)
        if entry.vendor_id:
            named[entry.vendor_id] = entry.vendor_name
    assert named == VENDOR_NAMES
    assert Identity(0xFB, 1).vendor() == "0x000000FB (maxon motor ag)"
    assert Identity(0x1234).vendor() == "0x00001234"


# ------------------------------------------------------------------ scans on the virtual bus


@pytest.fixture
def channel() -> str:
    return f"scan-test-{next(_channels)}"


@pytest.fixture
def bus_side(channel: str) -> Iterator[canopen.Network]:
    """A network on the channel for the fake nodes (the scan opens its own)."""
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    yield network
    network.disconnect()


class FrameLog(can.Listener):
    """Every frame on the channel, from a third bus."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[can.Message] = []
        self.lock = threading.Lock()
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            self.frames.append(msg)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def scan(channel: str, settings: ScanSettings = FAST) -> list[NodeReport]:
    network = open_network("virtual", channel, 1_000_000)
    try:
        return scan_network(network, settings).reports
    finally:
        network.disconnect()


def test_scan_reads_what_the_simulated_drives_are_and_changes_nothing(channel):
    frames = FrameLog(channel)
    with SimNetwork(interface="virtual", channel=channel) as sim:
        servo, epos4 = sim.add_drive(1), sim.add_drive(2, EPOS4)
        io = sim.add_io_node(10)
        before = {n: (d.nmt_state, d.state) for n, d in sim.drives.items()}
        reports = scan(channel)
        after = {n: (d.nmt_state, d.state) for n, d in sim.drives.items()}
    frames.close()
    assert [r.node_id for r in reports] == [1, 2, 10]
    for report, drive in zip(reports, (servo, epos4)):
        assert report.answered_sdo and report.problems == ()
        assert report.device_type == DeviceType(drive.value(0x1000))
        assert report.identity == Identity(drive.value(0x1018, 1), drive.value(0x1018, 2), drive.value(0x1018, 3),
                                           drive.value(0x1018, 4))
        assert report.modes == drive.value(0x6502)
    assert reports[0].device_name == servo.value(0x1008) and reports[0].software_version == servo.value(0x100A)
    assert reports[0].nmt_state == c.NmtState.PRE_OPERATIONAL  # the packaged EDS beats every 100 ms
    assert reports[2].device_type == DeviceType(io.od[0x1000].default) and reports[2].modes is None
    assert after == before
    sent = [m for m in frames.frames if not (0x580 < m.arbitration_id < 0x600 or m.arbitration_id > 0x700)]
    assert sent, "the scan's requests were not seen"
    # ccs 2 initiate upload, ccs 3 upload segment (the strings): reads only (CiA 301 7.2.4.3)
    others = [m for m in sent if not (0x600 < m.arbitration_id < 0x680 and m.data[0] >> 5 in (2, 3))]
    assert others == [], "the scan sent something other than SDO upload requests"
    assert {m.arbitration_id - 0x600 for m in sent if m.data[1:4] == b"\x00\x10\x00"} == set(range(1, 128))


def test_nodes_that_answer_partly_or_not_at_all(channel, bus_side):
    nodes = [
        FakeNode(bus_side, 5, sdo=False, heartbeat_state=0x7F),  # heartbeat, no SDO server
        FakeNode(bus_side, 6, sdo=False, heartbeat_state=0x04),  # STOPPED: CiA 301 has SDO off
        FakeNode(bus_side, 7, {(0x1000, 0): 0x00020192, (0x1018, 1): ("abort", ABORT_HARDWARE)}),
        FakeNode(bus_side, 8, {(0x1000, 0): ("abort", ABORT_HARDWARE), (0x1018, 1): 0xFB, (0x1018, 2): 0x65520000}),
        FakeNode(bus_side, 9, drive_objects(0x9A, 0x00030923, modes=None)),  # no 0x6502, 0x1008, 0x1018:03/04
    ]
    try:
        reports = {r.node_id: r for r in scan(channel)}
    finally:
        for node in nodes:
            node.close()
    assert sorted(reports) == [5, 6, 7, 8, 9]
    assert not reports[5].answered_sdo and reports[5].nmt_state == 0x7F
    assert reports[5].status() == "heartbeat only: no SDO answer"
    assert reports[6].status() == "heartbeat only: NMT STOPPED answers no SDO"
    assert reports[7].device_type == DeviceType(0x00020192) and reports[7].identity is None
    assert reports[7].problems[0] == "0x1018:01 (vendor id): SDO abort 0x06060000 (Access failed due to a hardware error)"
    assert reports[7].problems[1].startswith("0x1018:02 (product code): SDO abort 0x06020000")
    assert reports[8].device_type is None and reports[8].identity == Identity(0xFB, 0x65520000)
    assert reports[8].problems == ("0x1000:00 (device type): SDO abort 0x06060000 (Access failed due to a hardware "
                                   "error)",)
    assert reports[9].problems == () and reports[9].modes is None and reports[9].identity == Identity(0x9A, 0x30923)
    assert nodes[4].requests.count((0x1000, 0)) == 1  # the probe's answer is used, not read twice


def test_an_empty_bus_finds_nothing(channel):
    assert scan(channel, ScanSettings(listen_s=0.05, sdo_timeout_s=0.05)) == []


def test_a_request_that_cannot_be_sent_ends_the_nodes_reads_with_one_line(channel, monkeypatch):
    network = open_network("virtual", channel, 1_000_000)

    def bus_off(can_id, data, remote=False):
        raise can.CanOperationError("Transmit buffer full")

    monkeypatch.setattr(network, "send_message", bus_off)
    try:
        report = read_node(network, 5, FAST, SdoAnswer(data=(0x00020192).to_bytes(4, "little")))
    finally:
        network.disconnect()
    assert report.device_type == DeviceType(0x00020192) and report.identity is None
    assert report.problems == ("0x1018:01 (vendor id): cannot send the request (Transmit buffer full); later "
                               "objects not read",)


def test_a_transmit_queue_that_stays_full_is_one_line(channel, monkeypatch):
    network = open_network("virtual", channel, 1_000_000)
    monkeypatch.setattr(network, "send_message", lambda *a, **k: (_ for _ in ()).throw(can.CanOperationError("full")))
    try:
        with pytest.raises(FieldbusError) as caught:
            scan_network(network, ScanSettings(listen_s=0.01, sdo_timeout_s=0.01, send_retry_s=0.0, send_attempts=3))
    finally:
        network.disconnect()
    assert str(caught.value) == ("cannot send the SDO request 0x601 after 3 attempts (full): is the interface up, "
                                 "the bitrate right and a node acknowledging frames?")
