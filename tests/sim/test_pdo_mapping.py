"""PDO (re)mapping by a master (CiA 301 procedure) and transmission types."""

from __future__ import annotations

import struct

import pytest
from canopen.sdo import SdoAbortedError

from conftest import Bench, wait_for


def test_master_remaps_rpdo_and_tpdo_with_canopen(bench: Bench) -> None:
    drive, node = bench.add(2)
    node.rpdo.read(from_od=False)
    node.tpdo.read(from_od=False)
    rpdo = node.rpdo[1]
    rpdo.clear()
    rpdo.add_variable(0x60C1, 1)  # IP set-point first, then the controlword
    rpdo.add_variable(0x6040)
    rpdo.trans_type = 1
    rpdo.enabled = True
    tpdo = node.tpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x60F4)
    tpdo.add_variable(0x6041)
    tpdo.trans_type = 2  # every 2nd SYNC
    tpdo.enabled = True
    node.rpdo.save()
    node.tpdo.save()
    assert node.sdo[0x1600][0].raw == 2 and node.sdo[0x1600][1].raw == 0x60C10120
    bench.operational(2)
    bench.enable(2, mode=7)
    bench.sync()
    bench.send(0x202, struct.pack("<iH", 4321, 0x1F))
    for _ in range(4):
        bench.sync()
    assert [r.setpoint_counts for r in drive.recorder.records()] == [4321]
    frames = bench.frames.of(0x182)
    assert len(frames) == 2  # SYNCs 2 and 4 of 5
    following_error, statusword = struct.unpack("<iH", frames[-1])
    assert statusword & 0x6F == 0x27 and following_error == 0


def test_mapping_cannot_change_while_pdo_is_valid(bench: Bench) -> None:
    _, node = bench.add(3)
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1600][0].raw = 0
    assert err.value.code == 0x08000022
    node.sdo[0x1400][1].raw = 0x8000_0203
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1600][1].raw = 0x60400010  # count is still 2
    assert err.value.code == 0x08000022


def test_cob_id_of_a_valid_pdo_cannot_change(bench: Bench) -> None:
    _, node = bench.add(3)
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1400][1].raw = 0x250
    assert err.value.code == 0x06090030
    node.sdo[0x1400][1].raw = 0x8000_0203
    node.sdo[0x1400][1].raw = 0x250  # disabled first: allowed, and valid again


@pytest.mark.parametrize(
    "entries,code",
    [
        ([0x60410010], 0x06040041),  # statusword is not receivable
        ([0x60650020], 0x06040041),  # following-error window is not mappable
        ([0x60400020], 0x06040041),  # wrong length
        ([0x607A0020, 0x60C10120, 0x60400010], 0x06040042),  # 80 bits
    ],
)
def test_bad_rpdo_mapping_is_refused(bench: Bench, entries: list[int], code: int) -> None:
    _, node = bench.add(4)
    node.sdo[0x1400][1].raw = 0x8000_0204
    node.sdo[0x1600][0].raw = 0
    with pytest.raises(SdoAbortedError) as err:
        for n, entry in enumerate(entries, 1):
            node.sdo[0x1600][n].raw = entry
        node.sdo[0x1600][0].raw = len(entries)
    assert err.value.code == code


def test_disabled_rpdo_is_ignored(bench: Bench) -> None:
    drive, node = bench.add(5)
    node.sdo[0x1400][1].raw = 0x8000_0205
    bench.operational(5)
    bench.send(0x205, struct.pack("<Hi", 0x06, 0))
    bench.sync()
    assert drive.stats.rpdos_received == 0


def test_short_rpdo_gives_emcy_8210(bench: Bench) -> None:
    drive, _ = bench.add(6)
    bench.operational(6)
    bench.send(0x206, b"\x06\x00")
    wait_for(lambda: bench.frames.of(0x86), what="EMCY")
    code, register = struct.unpack_from("<HB", bench.frames.of(0x86)[-1])
    assert code == 0x8210 and drive.stats.rpdo_length_errors == 1


def test_asynchronous_rpdo_takes_effect_at_once(bench: Bench) -> None:
    drive, node = bench.add(7)
    node.sdo[0x1400][2].raw = 255
    bench.operational(7)
    bench.send(0x207, struct.pack("<Hi", 0x06, 0))
    wait_for(lambda: drive.controlword == 0x06, what="controlword without SYNC")


@pytest.mark.parametrize("trans_type", [0, 254, 255])
def test_event_tpdo_is_sent_when_its_data_changes(bench: Bench, trans_type: int) -> None:
    drive, node = bench.add(8)
    node.sdo[0x1800][2].raw = trans_type
    bench.operational(8)
    for _ in range(3):  # the statusword changes once: bit 8 when the drive has locked onto SYNC
        bench.sync()
    sent = len(bench.frames.of(0x188))
    assert sent == 2 and drive.sync_locked
    bench.sync()
    assert len(bench.frames.of(0x188)) == sent
    node.sdo[0x6040].raw = 0x06
    bench.sync()
    assert len(bench.frames.of(0x188)) == sent + 1


def test_tpdo_mapping_may_hold_any_readable_mappable_object(bench: Bench) -> None:
    drive, node = bench.add(9)
    node.sdo[0x1801][1].raw = 0x8000_0289
    node.sdo[0x1A01][0].raw = 0
    node.sdo[0x1A01][1].raw = 0x60610008
    node.sdo[0x1A01][2].raw = 0x603F0010
    node.sdo[0x1A01][0].raw = 2
    node.sdo[0x1801][1].raw = 0x289
    node.sdo[0x6060].raw = 7
    bench.operational(9)
    bench.sync()
    assert bench.frames.of(0x289) == [struct.pack("<bH", 7, 0)]


@pytest.mark.parametrize("can_id", [0x000, 0x07F, 0x581, 0x605, 0x704, 0x7E5])
def test_a_restricted_can_id_cannot_be_a_pdo(bench: Bench, can_id: int) -> None:
    _, node = bench.add(3)
    node.sdo[0x1400][1].raw = 0x8000_0203
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1400][1].raw = can_id  # CiA 301 7.3.5: NMT, SDO, heartbeat, LSS ... ids
    assert err.value.code == 0x06090030
    node.sdo[0x1400][1].raw = 0x8000_0000 | can_id  # stored while disabled: harmless


def test_a_count_over_entries_never_written_is_refused(bench: Bench) -> None:
    # e.g. canopen's PdoMap.save on an ARRAY mapping object: sub 0 set to 0 makes it write no entry
    _, node = bench.add(3)
    node.sdo[0x1400][1].raw = 0x8000_0203
    node.sdo[0x1600][0].raw = 0
    node.sdo[0x1600][1].raw = 0x60400010
    node.sdo[0x1600][2].raw = 0
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1600][0].raw = 2
    assert err.value.code == 0x06040041
    node.sdo[0x1600][0].raw = 1
