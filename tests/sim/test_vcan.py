"""The simulated drives on a real kernel SocketCAN vcan0 (run through scripts/with-vcan):
the same protocol behaviour as on the virtual bus, with the kernel in between."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from nurbsmotion.can.cia402 import State, state_of_statusword
from nurbsmotion.sim import FaultInjection

from conftest import Bench, open_bench, rpdo, wait_for

pytestmark = pytest.mark.vcan
CHANNEL = "vcan0"


@pytest.fixture
def vcan_bench() -> Iterator[Bench]:
    flags = Path("/sys/class/net") / CHANNEL / "flags"
    if not flags.exists() or not int(flags.read_text(), 16) & 0x1:
        pytest.skip(f"{CHANNEL} is not up: run through scripts/with-vcan")
    with open_bench("socketcan", CHANNEL) as bench:
        yield bench


def test_boot_sdo_and_heartbeat_on_vcan(vcan_bench: Bench) -> None:
    drive, node = vcan_bench.add(1, identity=(0x11, 0x22))
    assert (node.sdo[0x1018][1].raw, node.sdo[0x1018][2].raw) == (0x11, 0x22)
    node.sdo[0x1017].raw = 20
    wait_for(lambda: b"\x7f" in vcan_bench.frames.of(0x701), what="heartbeat")


def test_csp_stream_on_vcan_is_applied_one_sync_later_and_recorded(vcan_bench: Bench) -> None:
    drives = [vcan_bench.add(n)[0] for n in (1, 2)]
    for n in (1, 2):
        vcan_bench.operational(n)
        vcan_bench.enable(n, 8)
    vcan_bench.sync()
    sent = [7 * k for k in range(1, 31)]
    for value in sent:
        for n in (1, 2):
            vcan_bench.send(0x200 + n, rpdo(0x0F, value * n))
        vcan_bench.sync()
    for n, drive in zip((1, 2), drives):
        records = drive.recorder.records()
        assert [r.setpoint_counts for r in records] == [v * n for v in sent]
        assert [r.sync_index for r in records] == list(range(2, 2 + len(sent)))
        statusword, actual = struct.unpack("<Hi", vcan_bench.frames.of(0x180 + n)[-1])
        assert state_of_statusword(statusword) is State.OPERATION_ENABLED and actual == records[-1].position_actual_counts


def test_fault_emcy_on_vcan(vcan_bench: Bench) -> None:
    drive, _ = vcan_bench.add(3)
    vcan_bench.operational(3)
    drive.inject(FaultInjection("fault", at_sync=2, code=0x2310))
    vcan_bench.sync()
    vcan_bench.sync()
    assert struct.unpack_from("<H", vcan_bench.frames.of(0x83)[0])[0] == 0x2310
    assert state_of_statusword(struct.unpack_from("<H", vcan_bench.frames.of(0x183)[-1])[0]) is State.FAULT
