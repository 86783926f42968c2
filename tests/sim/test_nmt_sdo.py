"""NMT slave and SDO server of a simulated drive, seen from a canopen master."""

from __future__ import annotations

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from conftest import Bench, wait_for

START, STOP, PRE_OP, RESET_NODE, RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82


def test_boot_up_then_heartbeat_in_pre_operational(bench: Bench) -> None:
    drive, _ = bench.add(3)
    assert bench.frames.of(0x703)[0] == b"\x00"
    wait_for(lambda: b"\x7f" in bench.frames.of(0x703), what="heartbeat")
    assert drive.nmt_state == 0x7F


def test_heartbeat_period_follows_0x1017(bench: Bench) -> None:
    _, node = bench.add(3)
    node.sdo[0x1017].raw = 10
    bench.frames.clear()
    wait_for(lambda: len(bench.frames.of(0x703)) >= 5, timeout_s=1.0, what="5 heartbeats at 10 ms")
    node.sdo[0x1017].raw = 0
    count = len(bench.frames.of(0x703))
    node.sdo[0x1017].raw = 0  # an SDO round trip later no heartbeat is pending any more
    assert node.sdo[0x1017].raw == 0
    assert len(bench.frames.of(0x703)) <= count + 1


@pytest.mark.parametrize("command,state", [(START, 0x05), (STOP, 0x04), (PRE_OP, 0x7F)])
def test_nmt_commands_change_the_heartbeat_state(bench: Bench, command: int, state: int) -> None:
    drive, node = bench.add(4)
    node.sdo[0x1017].raw = 10
    bench.nmt(command, 4)
    wait_for(lambda: bench.frames.of(0x704)[-1:] == [bytes([state])], what=f"heartbeat state {state:#x}")
    assert drive.nmt_state == state


def test_broadcast_nmt_reaches_every_drive(bench: Bench) -> None:
    a, _ = bench.add(1)
    b, _ = bench.add(2)
    bench.nmt(START, 0)
    wait_for(lambda: a.nmt_state == b.nmt_state == 0x05, what="both operational")


@pytest.mark.parametrize("command", [RESET_NODE, RESET_COMM])
def test_reset_resends_boot_up_and_restores_communication_defaults(bench: Bench, command: int) -> None:
    drive, node = bench.add(5)
    node.sdo[0x1017].raw = 250
    node.sdo[0x6065].raw = 1234
    bench.nmt(START, 5)
    bench.frames.clear()
    bench.nmt(command, 5)
    wait_for(lambda: b"\x00" in bench.frames.of(0x705), what="boot-up after reset")
    assert drive.nmt_state == 0x7F
    assert node.sdo[0x1017].raw == 100
    # reset communication keeps the application parameters, reset node restores them too
    assert node.sdo[0x6065].raw == (10000 if command == RESET_NODE else 1234)


def test_sdo_read_of_identity_and_live_objects(bench: Bench) -> None:
    _, node = bench.add(6, identity=(0x1234, 0x5678))
    assert node.sdo[0x1018][1].raw == 0x1234
    assert node.sdo[0x1018][2].raw == 0x5678
    assert node.sdo[0x1018][4].raw == 6
    assert node.sdo[0x6041].raw & 0x4F == 0x40  # switch on disabled
    assert node.sdo[0x6502].raw & 0xC0 == 0xC0
    assert node.sdo[0x6061].raw == 8


def test_sdo_write_then_read_back(bench: Bench) -> None:
    _, node = bench.add(6)
    node.sdo[0x6065].raw = 777
    node.sdo[0x607D][1].raw = -5000
    assert node.sdo[0x6065].raw == 777
    assert node.sdo[0x607D][1].raw == -5000


def test_segmented_upload_of_a_long_object_is_served(bench: Bench) -> None:
    _, node = bench.add(6)
    assert node.sdo[0x1008].raw == "nurbsmotion simulated servo"  # 27 bytes: segmented


@pytest.mark.parametrize(
    "index,subindex,data,code",
    [
        (0x6041, 0, b"\x01\x00", 0x06010002),  # read-only
        (0x2000, 0, b"\x01\x00\x00\x00", 0x06020000),  # no such object
        (0x607D, 9, b"\x01\x00\x00\x00", 0x06090011),  # no such sub-index
        (0x6065, 0, b"\x01\x00", 0x06070010),  # wrong length
        (0x6060, 0, b"\x04", 0x06090030),  # unsupported mode (profile torque)
        (0x60C0, 0, b"\x01\x00", 0x06090030),  # only linear interpolation
        (0x1400, 2, b"\xF5", 0x06090030),  # reserved transmission type 245
    ],
)
def test_sdo_write_aborts(bench: Bench, index: int, subindex: int, data: bytes, code: int) -> None:
    _, node = bench.add(7)
    with pytest.raises(SdoAbortedError) as err:
        node.sdo.download(index, subindex, data)
    assert err.value.code == code


def test_mode_display_follows_mode(bench: Bench) -> None:
    _, node = bench.add(7)
    node.sdo[0x6060].raw = 7
    assert node.sdo[0x6061].raw == 7
    with pytest.raises(SdoAbortedError):
        node.sdo[0x6060].raw = 1
    assert node.sdo[0x6061].raw == 7


def test_sdo_is_silent_in_stopped(bench: Bench) -> None:
    _, node = bench.add(8)
    node.sdo.RESPONSE_TIMEOUT = 0.2
    node.sdo.MAX_RETRIES = 1
    bench.nmt(STOP, 8)
    wait_for(lambda: bench.sim[8].nmt_state == 0x04, what="stopped")
    with pytest.raises(canopen.SdoCommunicationError):
        node.sdo[0x6041].raw
    bench.nmt(PRE_OP, 8)
    wait_for(lambda: bench.sim[8].nmt_state == 0x7F, what="pre-operational")
    assert node.sdo[0x6041].raw & 0x4F == 0x40


@pytest.mark.parametrize("state_command", [PRE_OP, STOP])
def test_no_pdos_outside_operational(bench: Bench, state_command: int) -> None:
    drive, node = bench.add(9)
    bench.enable(9)
    bench.nmt(state_command, 9)
    wait_for(lambda: drive.nmt_state in (0x7F, 0x04) and drive.nmt_state != 0x05, what="not operational")
    bench.send(0x209, bytes([0x0F, 0, 0x10, 0x27, 0, 0]))  # RPDO1: enable, target 10000
    bench.send(0x80, b"")
    bench.flush()
    bench.operational(9)
    bench.sync()
    assert drive.stats.rpdos_received == 0
    assert bench.frames.of(0x189) and len(bench.frames.of(0x189)) == 1  # only the SYNC in OPERATIONAL
    assert drive.sync_index == 1
    assert len(drive.recorder) == 0
