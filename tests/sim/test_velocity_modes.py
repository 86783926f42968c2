"""A simulated spindle: the drive in profile velocity (3) and cyclic synchronous velocity (9)
mode on the virtual bus: ramps by 0x6083/0x6084, 0x606C, bit 10 by the velocity window,
halt, 0x60FF by RPDO each SYNC, and modes refused when the EDS lacks their objects."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

from conftest import Bench, derived_eds

NODE = 6
ACCEL, DECEL = 100_000, 200_000  # counts/s²
TARGET = 20_000  # counts/s


def _pv_drive(bench: Bench):
    drive, node = bench.add(NODE)
    bench.operational(NODE)
    for index, value in ((0x6083, ACCEL), (0x6084, DECEL), (0x606D, 50), (0x606E, 5), (0x60FF, TARGET)):
        node.sdo[index].raw = value
    bench.enable(NODE, 3)
    return drive, node


def _syncs(bench: Bench, n: int) -> None:
    for _ in range(n):
        bench.sync()


def test_profile_velocity_ramps_to_the_target_and_reports_target_reached(bench: Bench) -> None:
    drive, node = _pv_drive(bench)
    _syncs(bench, 100)  # half the ramp (1 ms cycle)
    assert node.sdo[0x606C].raw == ACCEL * 100 // 1000
    assert not node.sdo[0x6041].raw & (1 << 10)
    _syncs(bench, 100)  # at the target: 0.2 s, x = a·t²/2 = 2000 counts
    assert node.sdo[0x606C].raw == TARGET
    assert drive.position_actual == 2000
    assert not node.sdo[0x6041].raw & (1 << 10)  # within the window for 1 ms only, 0x606E is 5 ms
    _syncs(bench, 5)
    assert node.sdo[0x6041].raw & (1 << 10)
    assert drive.position_actual == 2000 + 5 * TARGET // 1000
    node.sdo[0x60FF].raw = TARGET + 1000  # a new target: not reached any more
    bench.sync()
    assert not node.sdo[0x6041].raw & (1 << 10)


def test_halt_decelerates_with_the_profile_deceleration(bench: Bench) -> None:
    drive, node = _pv_drive(bench)
    _syncs(bench, 200)
    node.sdo[0x6040].raw = 0x010F  # halt
    _syncs(bench, 50)
    assert node.sdo[0x606C].raw == TARGET - DECEL * 50 // 1000
    _syncs(bench, 50 + 5)
    assert node.sdo[0x606C].raw == 0
    assert node.sdo[0x6041].raw & (1 << 10)  # halted: velocity 0 reached
    node.sdo[0x6040].raw = 0x000F
    _syncs(bench, 10)
    assert node.sdo[0x606C].raw == ACCEL * 10 // 1000


def test_disabling_stops_the_spindle_and_keeps_the_position(bench: Bench) -> None:
    drive, node = _pv_drive(bench)
    _syncs(bench, 50)
    here = drive.position_actual
    node.sdo[0x6040].raw = 0x07  # disable operation
    _syncs(bench, 5)
    assert node.sdo[0x606C].raw == 0 and drive.position_actual == here


def _map_rpdo4_to_target_velocity(node) -> None:
    """CiA 301 remap: COB-ID invalid (default), mapping count 0, entry, count 1, COB-ID valid."""
    node.sdo[0x1603][0].raw = 0
    node.sdo[0x1603][1].raw = 0x60FF0020
    node.sdo[0x1603][0].raw = 1
    node.sdo[0x1403][2].raw = 1
    node.sdo[0x1403][1].raw = 0x500 + NODE


def test_cyclic_synchronous_velocity_follows_0x60ff_from_the_rpdo_each_sync(bench: Bench) -> None:
    drive, node = bench.add(NODE)
    _map_rpdo4_to_target_velocity(node)
    bench.operational(NODE)
    bench.enable(NODE, 9)
    position = 0.0
    previous = 0
    for velocity in (1000, 3000, 3000, -2000, 0):
        bench.send(0x500 + NODE, struct.pack("<i", velocity))
        bench.sync()
        position += (previous + velocity) * 1e-3 / 2
        previous = velocity
        assert drive.axis.velocity_actual == velocity
        assert drive.position_actual == round(position)
    assert node.sdo[0x6041].raw & (1 << 12)  # target velocity used
    bench.send(0x500 + NODE, struct.pack("<i", 4000))
    bench.sync()
    bench.sync()  # no new set-point: the last one stays
    assert node.sdo[0x606C].raw == 4000


@pytest.mark.parametrize("drop, refused, accepted", [
    (("6083",), 3, 9),  # no profile acceleration: no profile velocity mode
    (("606C",), 3, None),  # no velocity actual: neither
    (("606D", "606E", "6084"), None, 3),  # window 0 for 0 ms, 0x6083 decelerates too
])
def test_velocity_modes_need_their_objects(bench: Bench, tmp_path: Path, drop, refused, accepted) -> None:
    _, node = bench.add(NODE, eds=derived_eds(tmp_path, drop=drop))
    for mode in (refused, 9 if accepted is None and refused is not None else None):
        if mode is None:
            continue
        with pytest.raises(SdoAbortedError):
            node.sdo[0x6060].raw = mode
    if accepted is not None:
        node.sdo[0x6060].raw = accepted
        assert node.sdo[0x6061].raw == accepted


def test_velocity_modes_need_their_0x6502_bits(bench: Bench, tmp_path: Path) -> None:
    _, node = bench.add(NODE, eds=derived_eds(tmp_path, change={"6502": {"DefaultValue": "0x000000E0"}}))
    for mode in (3, 9):
        with pytest.raises(SdoAbortedError):
            node.sdo[0x6060].raw = mode
