"""Fault injection, each observed from the master side as a real drive would show it."""

from __future__ import annotations

import struct

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from nurbsmotion.can.cia402 import State, state_of_statusword
from nurbsmotion.errors import InputError
from nurbsmotion.sim import FaultInjection, parse_fault_spec

from conftest import Bench, rpdo, wait_for


def emcys(bench: Bench, node_id: int) -> list[tuple[int, int]]:
    return [struct.unpack_from("<HB", data) for data in bench.frames.of(0x80 + node_id)]


def statuswords(bench: Bench, node_id: int) -> list[int]:
    return [struct.unpack_from("<H", data)[0] for data in bench.frames.of(0x180 + node_id)]


def test_fault_at_sync_sends_emcy_and_sets_the_fault_bit_in_that_syncs_tpdo(bench: Bench) -> None:
    drive, node = bench.add_enabled(2)
    drive.inject(FaultInjection("fault", at_sync=3, code=0x2310))
    bench.sync()
    bench.sync()
    assert emcys(bench, 2) == []
    bench.sync()
    assert emcys(bench, 2) == [(0x2310, 0x03)]  # generic + current bit in 0x1001
    assert state_of_statusword(statuswords(bench, 2)[-1]) is State.FAULT
    assert statuswords(bench, 2)[-2] & 0x6F == 0x27
    assert node.sdo[0x603F].raw == 0x2310 and node.sdo[0x1001].raw == 0x03
    assert node.sdo[0x1003][0].raw == 1 and node.sdo[0x1003][1].raw == 0x2310


def test_fault_reset_on_rising_edge_clears_and_sends_emcy_reset(bench: Bench) -> None:
    drive, node = bench.add_enabled(2)
    drive.inject(FaultInjection("fault", code=0x4210))
    assert state_of_statusword(node.sdo[0x6041].raw) is State.FAULT
    node.sdo[0x6040].raw = 0x80
    assert state_of_statusword(node.sdo[0x6041].raw) is State.SWITCH_ON_DISABLED
    assert node.sdo[0x603F].raw == 0
    wait_for(lambda: (0, 0) in emcys(bench, 2), what="EMCY error reset")
    assert drive.transitions[-3:] == [13, 14, 15]


def test_fault_at_time(bench: Bench) -> None:
    drive, node = bench.add_enabled(3)
    bench.sim.inject(FaultInjection("fault", node_id=3, at_s=0.0, code=0x3210))
    wait_for(lambda: emcys(bench, 3), what="timed fault EMCY")
    assert emcys(bench, 3) == [(0x3210, 0x05)]


def test_heartbeat_stop_makes_the_node_silent(bench: Bench) -> None:
    drive, node = bench.add_enabled(4)
    node.sdo[0x1017].raw = 10
    wait_for(lambda: len(bench.frames.of(0x704)) >= 3, what="heartbeats")
    drive.inject(FaultInjection("heartbeat_stop"))
    bench.flush()
    silent_from = len(bench.frames.frames)
    bench.send(0x80, b"")  # SYNC: no TPDO
    node.sdo.RESPONSE_TIMEOUT = 0.1
    node.sdo.MAX_RETRIES = 1
    with pytest.raises(canopen.SdoCommunicationError):
        node.sdo[0x6041].raw
    bench.nmt(0x81, 4)  # reset node: no boot-up either
    bench.flush()
    node_frames = [cid for cid, _, _ in bench.frames.frames[silent_from:] if cid & 0x7F == 4]
    assert node_frames == []
    drive.power_on()
    wait_for(lambda: bench.frames.of(0x704)[-1:] == [b"\x00"] or b"\x7f" in bench.frames.of(0x704)[-1:], what="boot after power on")
    assert drive.state is State.SWITCH_ON_DISABLED and drive.nmt_state == 0x7F


def test_ignore_sync_sends_no_tpdo_and_applies_nothing(bench: Bench) -> None:
    drive, _ = bench.add_enabled(5)
    bench.sync()
    drive.inject(FaultInjection("ignore_sync", count=2))
    bench.send(0x205, rpdo(0x0F, 50))
    bench.sync()
    bench.sync()
    assert len(statuswords(bench, 5)) == 1 and len(drive.recorder) == 0
    bench.sync()  # SYNC 4: processed again; the RPDO is taken now
    assert len(statuswords(bench, 5)) == 2
    assert [(r.sync_index, r.setpoint_counts) for r in drive.recorder.records()] == [(4, 50)]
    assert drive.stats.syncs_ignored == 2


def test_forced_following_error(bench: Bench) -> None:
    drive, _ = bench.add_enabled(6)
    drive.inject(FaultInjection("following_error", at_sync=2))
    bench.sync()
    bench.sync()
    assert emcys(bench, 6) == [(0x8611, 0x21)]
    statusword = statuswords(bench, 6)[-1]
    assert state_of_statusword(statusword) is State.FAULT and statusword & (1 << 13)


def test_stall_trips_the_following_error_window_after_the_timeout(bench: Bench) -> None:
    drive, node = bench.add_enabled(7)
    node.sdo[0x6065].raw = 100  # window, counts
    node.sdo[0x6066].raw = 3  # time-out, ms (3 SYNCs of 1 ms)
    drive.inject(FaultInjection("stall"))
    bench.sync()
    bench.send(0x207, rpdo(0x0F, 1000))
    for _ in range(3):  # SYNCs 2-4: 1, 2, 3 ms outside the window
        bench.sync()
    assert emcys(bench, 7) == []
    bench.sync()  # SYNC 5: 4 ms outside the window, longer than the 3 ms time-out
    assert emcys(bench, 7) == [(0x8611, 0x21)]
    assert node.sdo[0x60F4].raw == 1000


def test_following_error_window_disabled_by_all_ones(bench: Bench) -> None:
    drive, node = bench.add_enabled(7)
    node.sdo[0x6065].raw = 0xFFFFFFFF
    drive.inject(FaultInjection("stall"))
    bench.send(0x207, rpdo(0x0F, 10**6))
    for _ in range(30):
        bench.sync()
    assert emcys(bench, 7) == [] and drive.following_error == 10**6


def test_drop_rpdo(bench: Bench) -> None:
    drive, _ = bench.add_enabled(8)
    bench.sync()
    drive.inject(FaultInjection("drop_rpdo", count=2))
    for value in (1, 2, 3, 4):
        bench.send(0x208, rpdo(0x0F, value))
        bench.sync()
    assert [r.setpoint_counts for r in drive.recorder.records()] == [3, 4]
    assert drive.stats.rpdos_dropped == 2


@pytest.mark.parametrize("index,subindex", [(0x6065, 0), (None, None)])
def test_sdo_abort_refuses_writes(bench: Bench, index: int | None, subindex: int | None) -> None:
    drive, node = bench.add(9)
    drive.inject(FaultInjection("sdo_abort", index=index, subindex=subindex, code=0x08000021, count=1))
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x6065].raw = 5
    assert err.value.code == 0x08000021
    assert node.sdo[0x6065].raw == 10000  # refused write changed nothing
    node.sdo[0x6065].raw = 5  # count=1: the next write goes through
    assert node.sdo[0x6065].raw == 5


def test_sdo_abort_for_one_object_leaves_others_alone(bench: Bench) -> None:
    drive, node = bench.add(9)
    drive.inject(FaultInjection("sdo_abort", index=0x6060))
    node.sdo[0x6065].raw = 5
    for _ in range(2):
        with pytest.raises(SdoAbortedError):
            node.sdo[0x6060].raw = 7


def test_software_limit_refuses_the_setpoint_with_a_fault(bench: Bench) -> None:
    drive, node = bench.add_enabled(10)
    node.sdo[0x607D][1].raw = -100
    node.sdo[0x607D][2].raw = 100
    bench.sync()
    bench.send(0x20A, rpdo(0x0F, 50))
    bench.sync()
    bench.send(0x20A, rpdo(0x0F, 150))
    bench.sync()
    assert [r.setpoint_counts for r in drive.recorder.records()] == [50]
    assert emcys(bench, 10) == [(0xFF01, 0x81)]
    assert state_of_statusword(statuswords(bench, 10)[-1]) is State.FAULT


@pytest.mark.parametrize("option,end,transitions", [(2, State.SWITCH_ON_DISABLED, [11, 12]), (6, State.QUICK_STOP_ACTIVE, [11]), (0, State.SWITCH_ON_DISABLED, [11, 12])])
def test_quick_stop_ramps_down_then_follows_the_option(bench: Bench, option: int, end: State, transitions: list[int]) -> None:
    drive, node = bench.add_enabled(11, lag_cycles=0)
    node.sdo[0x605A].raw = option
    node.sdo[0x6085].raw = 1_000_000  # counts/s^2: 1000 counts/s less per 1 ms SYNC
    bench.sync()
    for k in range(1, 6):  # moving at 10 counts/SYNC = 10000 counts/s
        bench.send(0x20B, rpdo(0x0F, 10 * k))
        bench.sync()
    bench.send(0x20B, rpdo(0x02, 60))
    for _ in range(12):
        bench.sync()
    assert drive.state is end
    assert drive.transitions[-len(transitions):] == transitions
    if option:  # ramp: 9+8+...+1 counts after the stop command
        assert drive.position_actual == 50 + sum(range(1, 10))
    if option == 6:
        node.sdo[0x6040].raw = 0x0F
        assert drive.state is State.OPERATION_ENABLED and drive.transitions[-1] == 16


@pytest.mark.parametrize(
    "text,expected",
    [
        ("node=2,kind=fault,at_sync=500,code=0x2310", FaultInjection("fault", node_id=2, at_sync=500, code=0x2310)),
        ("node=1,kind=heartbeat_stop,at_s=3", FaultInjection("heartbeat_stop", node_id=1, at_s=3.0)),
        ("node=3, kind=sdo_abort, index=0x6060, subindex=0, code=0x06010002", FaultInjection("sdo_abort", node_id=3, index=0x6060, subindex=0, code=0x06010002)),
        ("kind=drop_rpdo,count=5", FaultInjection("drop_rpdo", count=5)),
    ],
)
def test_parse_fault_spec(text: str, expected: FaultInjection) -> None:
    assert parse_fault_spec(text) == expected


@pytest.mark.parametrize(
    "text,message",
    [
        ("node=2,kind=explode", "unknown fault kind"),
        ("node=2,at_sync=5", "kind is required"),
        ("node=x,kind=fault", "not a number"),
        ("node=2,kind=fault,at_sync=1,at_s=2", "not both"),
        ("node=2,kind=fault,colour=red", "unknown key"),
        ("node=2,kind=fault,node=3", "given twice"),
        ("node=2,kind", "key=value"),
        ("node=2;kind=fault", "not a number"),
    ],
)
def test_bad_fault_spec_is_one_line_naming_the_spec(text: str, message: str) -> None:
    with pytest.raises(InputError) as err:
        parse_fault_spec(text)
    assert message in str(err.value) and text in str(err.value) and "\n" not in str(err.value)


def test_fault_injected_before_start_fires_right_after_boot(channel: str) -> None:
    import can

    from nurbsmotion.sim import SimNetwork

    listener = can.Bus(interface="virtual", channel=channel)
    sim = SimNetwork(channel=channel)
    drive = sim.add_drive(12)
    drive.inject(FaultInjection("fault", code=0x4210))
    drive.inject(FaultInjection("fault", at_s=0.0, code=0x3210))
    try:
        sim.start()
        frames: list[can.Message] = []

        def emcy_codes() -> list[bytes]:
            while (msg := listener.recv(0)) is not None:
                frames.append(msg)
            return [bytes(m.data[:2]) for m in frames if m.arbitration_id == 0x8C]

        wait_for(lambda: emcy_codes() == [b"\x10\x42", b"\x10\x32"], what="both EMCYs after the boot-up")
        assert frames[0].arbitration_id == 0x70C and bytes(frames[0].data) == b"\x00"
        assert drive.state is State.FAULT
    finally:
        sim.stop()
        listener.shutdown()


def test_the_setpoint_of_the_sync_whose_following_error_faults_is_recorded_as_sent(bench: Bench) -> None:
    drive, node = bench.add_enabled(7)
    node.sdo[0x6065].raw = 100
    node.sdo[0x6066].raw = 0  # fault at the first SYNC outside the window
    drive.inject(FaultInjection("stall"))
    bench.sync()
    bench.send(0x207, rpdo(0x0F, 1000))
    bench.sync()
    assert drive.state is State.FAULT
    assert [r.setpoint_counts for r in drive.recorder.records()] == [1000]
    assert drive.timeline.records()[-1].demand_counts == 1000
