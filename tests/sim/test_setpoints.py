"""IP and CSP set-points: RPDO data received after SYNC n takes effect at SYNC n+1 (CiA 301),
the TPDO of a SYNC carries the state after it, and every applied set-point is recorded."""

from __future__ import annotations

import struct

import pytest

from nurbsmotion.can.cia402 import State, state_of_statusword
from nurbsmotion.sim import SetpointRecord, read_csv

from conftest import Bench, rpdo, wait_for

CSP, IP = 8, 7


def time_ns(drive, bench: Bench) -> int:
    """The last SYNC's time as the drive recorded it (the bench's stamp on the drive's clock)."""
    return drive.timeline.records()[-1].sync_time_ns


def tpdo1(data: bytes) -> tuple[int, int]:
    return struct.unpack("<Hi", data)


@pytest.mark.parametrize("mode,cob,controlword", [(CSP, 0x200, 0x0F), (IP, 0x300, 0x1F)])
def test_setpoint_received_after_sync_n_is_applied_at_sync_n_plus_1(bench: Bench, mode: int, cob: int, controlword: int) -> None:
    drive, _ = bench.add_enabled(2, mode, lag_cycles=0)
    bench.sync()  # SYNC 1
    bench.send(cob + 2, rpdo(controlword, 1000))
    wait_for(lambda: drive.stats.rpdos_received == 1, what="RPDO received")
    assert len(drive.recorder) == 0 and drive.position_actual == 0  # not before the next SYNC
    bench.sync()  # SYNC 2
    assert drive.recorder.records() == [SetpointRecord(2, mode, 1000, 1000, -1, time_ns(drive, bench))]
    statusword, actual = tpdo1(bench.frames.of(0x182)[-1])
    assert actual == 1000
    assert state_of_statusword(statusword) is State.OPERATION_ENABLED
    assert statusword & (1 << 12)  # CSP target used / IP active


def test_ip_active_bit_needs_controlword_bit_4(bench: Bench) -> None:
    drive, node = bench.add_enabled(3, IP)
    node.sdo[0x6040].raw = 0x0F
    assert not node.sdo[0x6041].raw & (1 << 12)
    bench.send(0x303, rpdo(0x0F, 500))
    bench.sync()
    assert len(drive.recorder) == 0 and drive.stats.setpoints_ignored == 1
    node.sdo[0x6040].raw = 0x1F
    assert node.sdo[0x6041].raw & (1 << 12)


def test_stream_of_setpoints_is_recorded_once_each_in_order(bench: Bench) -> None:
    drive, _ = bench.add_enabled(4, CSP)
    bench.sync()
    sent = [10 * k * k for k in range(1, 41)]
    for k, value in enumerate(sent):
        bench.send(0x204, rpdo(0x0F, value))
        bench.sync(counter=(k + 2) % 256)
    records = drive.recorder.records()
    assert [r.setpoint_counts for r in records] == sent
    assert [r.sync_index for r in records] == list(range(2, 2 + len(sent)))
    assert [r.sync_counter for r in records] == [(k + 2) % 256 for k in range(len(sent))]
    assert {r.mode for r in records} == {CSP}


def test_two_rpdos_before_one_sync_the_last_wins_and_is_counted(bench: Bench) -> None:
    drive, _ = bench.add_enabled(4, CSP)
    bench.sync()
    bench.send(0x204, rpdo(0x0F, 100))
    bench.send(0x204, rpdo(0x0F, 200))
    wait_for(lambda: drive.stats.rpdos_received == 2, what="both RPDOs")
    bench.sync()
    assert [r.setpoint_counts for r in drive.recorder.records()] == [200]
    assert drive.stats.rpdos_overwritten == 1


def test_setpoints_while_disabled_are_not_applied(bench: Bench) -> None:
    drive, node = bench.add(5)
    bench.operational(5)
    bench.send(0x205, rpdo(0x06, 1000))  # shutdown + a target: READY TO SWITCH ON only
    bench.sync()
    assert drive.state is State.READY_TO_SWITCH_ON
    assert len(drive.recorder) == 0 and drive.position_actual == 0


def test_controlword_by_rpdo_drives_the_state_machine_at_sync(bench: Bench) -> None:
    drive, _ = bench.add(5)
    bench.operational(5)
    bench.sync()
    for word, state in ((0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON), (0x0F, State.OPERATION_ENABLED)):
        bench.send(0x205, rpdo(word, 0))
        wait_for(lambda: drive.stats.rpdos_received > 0, what="RPDO")
        bench.sync()
        assert drive.state is state
        assert state_of_statusword(tpdo1(bench.frames.of(0x185)[-1])[0]) is state


def test_enable_holds_position_until_the_first_setpoint(bench: Bench) -> None:
    drive, _ = bench.add_enabled(6, CSP)
    for _ in range(3):
        bench.sync()
    assert drive.position_actual == 0 and len(drive.recorder) == 0
    assert drive.following_error == 0


def test_recording_csv_round_trip(bench: Bench, tmp_path) -> None:
    drive, _ = bench.add_enabled(7, CSP)
    bench.sync()
    for value in (5, 6, 7):
        bench.send(0x207, rpdo(0x0F, value))
        bench.sync()
    path = drive.write_recording(tmp_path / "node7.csv")
    assert read_csv(path) == drive.recorder.records()
    assert path.read_text().splitlines()[0] == \
        "sync_index,mode,setpoint_counts,position_actual_counts,sync_counter,sync_time_ns"


def test_sync_index_restarts_when_entering_operational(bench: Bench) -> None:
    drive, _ = bench.add_enabled(8, CSP)
    bench.sync()
    bench.sync()
    assert drive.sync_index == 2
    bench.nmt(0x80, 8)
    wait_for(lambda: drive.nmt_state == 0x7F, what="pre-operational")
    bench.operational(8)
    bench.sync()
    assert drive.sync_index == 1


def test_velocity_limit_and_lag_shape_the_actual_position(bench: Bench) -> None:
    # 1 ms period, 100000 counts/s: at most 100 counts per SYNC; lag 2 SYNCs
    drive, _ = bench.add_enabled(9, CSP, lag_cycles=2, max_velocity_counts_s=100_000)
    bench.sync()
    bench.send(0x209, rpdo(0x0F, 1000))
    actual = []
    for _ in range(5):
        bench.sync()
        actual.append(tpdo1(bench.frames.of(0x189)[-1])[1])
    assert actual == [0, 0, 100, 200, 300]


@pytest.mark.parametrize("mode", [CSP, IP])
def test_cycle_period_is_0x60c2_in_csp_and_ip_when_the_eds_has_it(bench: Bench, mode: int) -> None:
    # EPOS4, AKD, Elmo, Nanotec interpolate over 0x60C2 in CSP too; 0x1006 is the SYNC cycle
    drive, node = bench.add(10)
    node.sdo[0x1006].raw = 4000
    node.sdo[0x60C2][1].raw = 2
    node.sdo[0x6060].raw = mode
    assert drive.period_s == pytest.approx(0.002)
