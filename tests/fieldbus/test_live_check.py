"""fieldbus.live_check: a configured node against what the bus says (pure), and the PDO
capacity read from a node whose mapping object is too short."""

from __future__ import annotations

import itertools

import canopen
import pytest

from nurbsmotion.fieldbus.live_check import ExpectedNode, PdoNeed, compare, extra_nodes, read_pdo_capacity
from nurbsmotion.fieldbus.scan import DeviceType, Identity, NodeReport, ScanSettings
from tests.fieldbus.fake_nodes import FakeNode

WHERE = "m.yaml:4: axes[0] (X, node 1)"
AXIS = ExpectedNode(1, WHERE, 402, identity=None, eds_identity=(0, 0x4E4D0402), eds_name="servo.eds",
                    mode_bit=(7, "csp"))
GOOD = NodeReport(1, 0x7F, 0.1, DeviceType(0x00020192), Identity(0, 0x4E4D0402, 1), modes=0x1E4, answered_sdo=True)
_channels = itertools.count()


def texts(findings):
    return [(f.error, f.text) for f in findings]


def test_a_matching_node_has_no_findings():
    assert compare(AXIS, GOOD) == []


def test_missing_silent_and_wrong_nodes_are_errors_naming_the_configuration_line():
    assert texts(compare(AXIS, None)) == [(True, f"{WHERE}: not on the bus (no heartbeat, no SDO answer to 0x1000)")]
    heard = NodeReport(1, 0x04)
    assert texts(compare(AXIS, heard)) == [
        (True, f"{WHERE}: heard by its heartbeat only (heartbeat only: NMT STOPPED answers no SDO): cannot be checked")]
    io = NodeReport(1, 0x7F, None, DeviceType(0x00030191), Identity(0, 0x401), answered_sdo=True)
    assert (True, f"{WHERE}: device type 0x00030191 is CiA 401 I/O, digital in + digital out, expected CiA 402 "
                  "drive") in texts(compare(AXIS, io))
    no_csp = NodeReport(1, 0x7F, None, DeviceType(0x00020192), Identity(0, 0x4E4D0402), modes=0x65,
                        answered_sdo=True)
    assert texts(compare(AXIS, no_csp)) == [(True, f"{WHERE}: 0x6502 = 0x00000065 (pp pv hm ip) has no csp (bit 7)")]
    failing = NodeReport(1, 0x7F, None, DeviceType(0x00020192), None, answered_sdo=True,
                         problems=("0x1018:01 (vendor id): SDO abort 0x06060000 (Access failed due to a hardware error)",))
    assert texts(compare(AXIS, failing))[0] == (True, f"{WHERE}: 0x1018:01 (vendor id): SDO abort 0x06060000 (Access "
                                                      "failed due to a hardware error)")


def test_identity_configured_is_an_error_and_the_eds_identity_a_warning():
    maxon = NodeReport(1, 0x7F, None, DeviceType(0x00020192), Identity(0xFB, 0x65520000), modes=0x3A5,
                       answered_sdo=True)
    assert texts(compare(AXIS, maxon)) == [(False, f"{WHERE}: the node reports vendor 0x000000FB (maxon motor ag) "
                                                   "product 0x65520000, servo.eds describes vendor 0x00000000 product "
                                                   "0x4E4D0402")]
    configured = ExpectedNode(1, WHERE, 402, identity=(0xFB, 0x63220000), mode_bit=(7, "csp"))
    assert texts(compare(configured, maxon)) == [(True, f"{WHERE}: the node reports vendor 0x000000FB (maxon motor ag) "
                                                        "product 0x65520000, identity says vendor 0x000000FB product "
                                                        "0x63220000")]


def test_unreadable_0x6502_is_a_warning_and_extra_nodes_are_warnings():
    from dataclasses import replace

    assert texts(compare(AXIS, replace(GOOD, modes=None))) == [
        (False, f"{WHERE}: 0x6502 not readable: the mode is checked at bring-up (0x6061 read back)")]
    assert texts(extra_nodes([AXIS], [GOOD, NodeReport(7, 0x7F), NodeReport(127, 0x05)], master_node_id=127)) == [
        (False, "node 7 (heartbeat only: no SDO answer) is on the bus but not in the configuration")]


@pytest.fixture
def channel():
    return f"live-check-{next(_channels)}"


@pytest.fixture
def network(channel):
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    yield net
    net.disconnect()


def test_pdo_capacity_read_from_the_node(network, channel):
    side = canopen.Network()
    side.connect(interface="virtual", channel=channel)
    node = FakeNode(side, 1, {(0x1400, 1): 0x201, (0x1600, 1): 0, (0x1800, 1): 0x181, (0x1A00, 1): 0, (0x1A00, 2): 0})
    try:
        needs = (PdoNeed("RPDO", 1, 2), PdoNeed("TPDO", 1, 2), PdoNeed("TPDO", 2, 1))
        found = read_pdo_capacity(network, 1, needs, WHERE, ScanSettings(sdo_timeout_s=0.5))
    finally:
        side.disconnect()
    assert [f.text for f in found] == [
        f"{WHERE}: PDO capacity: 0x1600:02 (RPDO1 mapping entry 2): SDO abort 0x06020000 (Object does not exist)",
        f"{WHERE}: PDO capacity: 0x1801:01 (TPDO2 COB-ID): SDO abort 0x06020000 (Object does not exist)",
        f"{WHERE}: PDO capacity: 0x1A01:01 (TPDO2 mapping entry 1): SDO abort 0x06020000 (Object does not exist)"]
    assert node.requests == [(0x1400, 1), (0x1600, 2), (0x1800, 1), (0x1A00, 2), (0x1801, 1), (0x1A01, 1)]
