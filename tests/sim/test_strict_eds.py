"""A simulated drive is exactly as capable as its EDS says, and as strict as a real drive:
one test per rule, each on a drive derived from the packaged EDS with just that property."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

from nurbsmotion.can.cia402 import State

from conftest import Bench, derived_eds, rpdo, variable_section, wait_for

UINT8, UINT16, UINT32 = 0x5, 0x6, 0x7


def abort_of(call) -> int:
    with pytest.raises(SdoAbortedError) as err:
        call()
    return err.value.code


def emcy_codes(bench: Bench, node_id: int) -> list[int]:
    return [struct.unpack_from("<H", data)[0] for data in bench.frames.of(0x80 + node_id)]


# ------------------------------------------------------------------ objects and values
def test_an_object_the_eds_lacks_does_not_exist(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add(2, eds=derived_eds(tmp_path, drop=("6066",)))
    assert abort_of(lambda: node.sdo.download(0x6066, 0, b"\x14\x00")) == 0x06020000
    assert abort_of(lambda: node.sdo.upload(0x6066, 0)) == 0x06020000
    assert abort_of(lambda: node.sdo.upload(0x1016, 5)) == 0x06090011  # 4 entries declared
    assert abort_of(lambda: node.sdo.upload(0x60C1, 2)) == 0x06090011  # ARRAY with one entry


def test_an_entry_without_default_value_starts_at_0(bench: Bench, tmp_path: Path) -> None:
    eds = derived_eds(tmp_path, change={"6065": {"DefaultValue": None}, "1017": {"DefaultValue": None},
                                        "6060": {"DefaultValue": None}})
    drive, node = bench.add(2, eds=eds)
    assert node.sdo[0x6065].raw == 0 and node.sdo[0x1017].raw == 0 and node.sdo[0x6061].raw == 0
    assert drive.axis.mode_display == 0


def test_read_only_refuses_writes_and_write_only_refuses_reads(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add(2, eds=derived_eds(tmp_path, change={"6040": {"AccessType": "wo"}}))
    assert abort_of(lambda: node.sdo.download(0x6041, 0, b"\x00\x00")) == 0x06010002
    assert abort_of(lambda: node.sdo.download(0x1008, 0, b"x")) == 0x06010002  # const
    assert abort_of(lambda: node.sdo.upload(0x6040, 0)) == 0x06010001
    node.sdo.download(0x6040, 0, b"\x06\x00")
    assert drive.state is State.READY_TO_SWITCH_ON


def test_low_and_high_limits_of_the_eds_are_enforced(bench: Bench, tmp_path: Path) -> None:
    eds = derived_eds(tmp_path, change={"6085": {"HighLimit": "65500"}, "6065": {"LowLimit": "10"}})
    drive, node = bench.add(2, eds=eds)
    assert abort_of(lambda: setattr(node.sdo[0x6085], "raw", 65501)) == 0x06090031
    assert abort_of(lambda: setattr(node.sdo[0x6065], "raw", 9)) == 0x06090032
    node.sdo[0x6085].raw = 65500
    node.sdo[0x6065].raw = 10
    assert drive.value(0x6085) == 65500 and drive.value(0x6065) == 10


# ------------------------------------------------------------------ PDO mapping
def remap_rpdo1(node, entries: list[int]) -> None:
    node.sdo[0x1400][1].raw = 0x8000_0202
    node.sdo[0x1600][0].raw = 0
    for n, entry in enumerate(entries, 1):
        node.sdo[0x1600][n].raw = entry
    node.sdo[0x1600][0].raw = len(entries)


def test_an_object_the_eds_marks_not_mappable_cannot_be_mapped(bench: Bench, tmp_path: Path) -> None:
    # Schunk's 0x607A is not PDO-mappable
    _, node = bench.add(2, eds=derived_eds(tmp_path, change={"607A": {"PDOMapping": "0"}}))
    assert abort_of(lambda: remap_rpdo1(node, [0x60400010, 0x607A0020])) == 0x06040041


def test_a_pdo_takes_no_more_entries_than_its_eds_declares(bench: Bench, tmp_path: Path) -> None:
    # IDM's 0x1600 has one entry: controlword and set-point need two PDOs there
    eds = derived_eds(tmp_path, drop=tuple(f"1600sub{n}" for n in range(2, 9)),
                      change={"1600": {"SubNumber": "2"}, "1600sub0": {"DefaultValue": "1"}})
    drive, node = bench.add(2, eds=eds)
    node.sdo[0x1400][1].raw = 0x8000_0202
    node.sdo[0x1600][0].raw = 0
    assert abort_of(lambda: node.sdo.download(0x1600, 2, struct.pack("<I", 0x607A0020))) == 0x06090011
    node.sdo[0x1600][1].raw = 0x60400010
    assert abort_of(lambda: node.sdo.download(0x1600, 0, b"\x02")) == 0x06040042
    node.sdo[0x1600][0].raw = 1
    node.sdo[0x1400][1].raw = 0x202
    assert drive.value(0x1600, 0) == 1


def test_a_mapping_longer_than_a_can_frame_is_refused(bench: Bench) -> None:
    _, node = bench.add(2)
    assert abort_of(lambda: remap_rpdo1(node, [0x607A0020, 0x60C10120, 0x60400010])) == 0x06040042


# ------------------------------------------------------------------ modes (0x6502)
def test_a_mode_not_in_0x6502_is_refused_and_0x6061_keeps_the_accepted_one(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add(2, eds=derived_eds(tmp_path, change={"6502": {"DefaultValue": "0x80"}}))  # CSP only
    node.sdo[0x6060].raw = 8
    assert abort_of(lambda: setattr(node.sdo[0x6060], "raw", 7)) == 0x06090030
    assert node.sdo[0x6061].raw == 8


def test_a_drive_without_0x6502_value_takes_any_standard_mode_and_reports_it(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add(2, eds=derived_eds(tmp_path, change={"6502": {"DefaultValue": None}}))
    for mode in (1, 7, 8):
        node.sdo[0x6060].raw = mode
        assert node.sdo[0x6061].raw == mode  # the master reads back what was accepted
    assert abort_of(lambda: setattr(node.sdo[0x6060], "raw", -3)) == 0x06090030


def test_a_drive_with_neither_ip_nor_csp_is_still_simulated(bench: Bench, tmp_path: Path) -> None:
    # profile position only: the master must refuse it, the simulator must not fail
    drive, node = bench.add(2, eds=derived_eds(tmp_path, change={"6502": {"DefaultValue": "0x01"},
                                                                 "6060": {"DefaultValue": "1"}}))
    assert node.sdo[0x6502].raw == 0x01 and node.sdo[0x6061].raw == 1
    assert abort_of(lambda: setattr(node.sdo[0x6060], "raw", 8)) == 0x06090030
    bench.operational(2)
    for word in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = word
    bench.sync()
    assert drive.state is State.OPERATION_ENABLED and len(drive.recorder) == 0


# ------------------------------------------------------------------ cycle period
@pytest.mark.parametrize("mode,controlword", [(8, 0x0F), (7, 0x1F)])
def test_ip_and_csp_cannot_run_without_a_cycle_period(bench: Bench, tmp_path: Path, mode: int, controlword: int) -> None:
    eds = derived_eds(tmp_path, change={"60C2sub1": {"DefaultValue": None}, "1006": {"DefaultValue": "0"}})
    drive, node = bench.add(2, eds=eds)
    assert drive.period_s == 0
    bench.operational(2)
    node.sdo[0x6060].raw = mode
    for word in (0x06, 0x07, controlword):
        node.sdo[0x6040].raw = word
    assert drive.state is State.FAULT and drive.axis.error_code == 0x6320
    wait_for(lambda: 0x6320 in emcy_codes(bench, 2), what="EMCY 0x6320")
    node.sdo[0x60C2][1].raw = 4  # the write the master forgot: now it runs
    for word in (0x80, 0x06, 0x07, controlword):
        node.sdo[0x6040].raw = word
    assert drive.state is State.OPERATION_ENABLED and drive.period_s == pytest.approx(0.004)


def test_0x1006_is_not_the_csp_cycle_when_the_eds_has_0x60c2(bench: Bench, tmp_path: Path) -> None:
    eds = derived_eds(tmp_path, change={"60C2sub1": {"DefaultValue": "0"}})
    drive, node = bench.add(2, eds=eds)
    node.sdo[0x1006].raw = 4000  # what the master writes today in CSP: not enough for this drive
    bench.operational(2)
    for word in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = word
    assert drive.state is State.FAULT and drive.axis.error_code == 0x6320


def test_a_drive_without_0x60c2_takes_its_cycle_from_0x1006(bench: Bench, tmp_path: Path) -> None:
    sections = ("60C2", "60C2sub0", "60C2sub1", "60C2sub2")
    drive, node = bench.add(2, eds=derived_eds(tmp_path, drop=sections))
    node.sdo[0x1006].raw = 2000
    assert drive.period_s == pytest.approx(0.002)


def test_a_drive_with_neither_takes_the_measured_sync_interval(bench: Bench, tmp_path: Path) -> None:
    sections = ("60C2", "60C2sub0", "60C2sub1", "60C2sub2", "1006")
    drive, _ = bench.add(2, eds=derived_eds(tmp_path, drop=sections))
    bench.operational(2)
    bench.sync_period_s = 0.004
    bench.sync()
    bench.sync()
    assert drive.period_s == pytest.approx(0.004, abs=1e-6)


# ------------------------------------------------------------------ CiA 301 objects
def test_two_consumer_entries_for_one_producer_are_refused(bench: Bench) -> None:
    _, node = bench.add(2)
    node.sdo[0x1016][1].raw = 0x7F << 16 | 300
    assert abort_of(lambda: setattr(node.sdo[0x1016][2], "raw", 0x7F << 16 | 100)) == 0x06040043
    node.sdo[0x1016][1].raw = 0x7F << 16 | 100  # the same entry may change


def test_a_drive_without_0x1016_runs(bench: Bench, tmp_path: Path) -> None:
    sections = ("1016", *(f"1016sub{n}" for n in range(5)))
    drive, node = bench.add(2, eds=derived_eds(tmp_path, drop=sections))
    assert abort_of(lambda: node.sdo.upload(0x1016, 1)) == 0x06020000
    bench.send(0x77F, b"\x05")
    assert drive.state is State.SWITCH_ON_DISABLED


def sync_window_eds(tmp_path: Path) -> Path:
    return derived_eds(tmp_path, change={"1007": variable_section("Synchronous window length", UINT32, "rw")})


def test_rpdos_after_the_synchronous_window_are_discarded(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add_enabled(2, eds=sync_window_eds(tmp_path))
    node.sdo[0x1007].raw = 500  # µs
    bench.sync()
    t = bench.sync_time_s
    bench.send(0x202, rpdo(0x0F, 100), at_s=t + 0.0004)  # inside the window
    bench.sync()
    bench.send(0x202, rpdo(0x0F, 200), at_s=bench.sync_time_s + 0.0006)  # too late: discarded
    bench.sync()
    assert [r.setpoint_counts for r in drive.recorder.records()] == [100]
    assert drive.stats.rpdos_outside_window == 1
    assert drive.timeline.records()[-1].source == 2  # the drive held its set-point


def counter_eds(tmp_path: Path) -> Path:
    return derived_eds(tmp_path, change={"1019": variable_section("Synchronous counter overflow value", UINT8, "rw")})


def test_0x1019_changes_only_while_0x1006_is_0(bench: Bench, tmp_path: Path) -> None:
    _, node = bench.add(2, eds=counter_eds(tmp_path))
    assert abort_of(lambda: setattr(node.sdo[0x1019], "raw", 4)) == 0x08000022  # 0x1006 = 1000 by default
    node.sdo[0x1006].raw = 0
    assert abort_of(lambda: setattr(node.sdo[0x1019], "raw", 1)) == 0x06090030
    node.sdo[0x1019].raw = 4
    assert node.sdo[0x1019].raw == 4


def test_the_sync_counter_is_checked_against_0x1019(bench: Bench, tmp_path: Path) -> None:
    drive, node = bench.add(2, eds=counter_eds(tmp_path))
    node.sdo[0x1006].raw = 0
    node.sdo[0x1019].raw = 4
    bench.operational(2)
    for counter in (1, 2, 3, 4, 1):
        bench.sync(counter=counter)
    assert drive.stats.sync_counter_jumps == 0 and drive.stats.sync_length_errors == 0
    bench.sync(counter=3)  # counter 2 lost on the way
    assert drive.stats.sync_counter_jumps == 1
    bench.sync()  # no counter byte although 0x1019 > 0
    wait_for(lambda: 0x8240 in emcy_codes(bench, 2), what="EMCY 0x8240")
    assert drive.stats.sync_length_errors == 1
