"""Homing mode (6) of the simulated drive, driven by the master's own procedure
(``fieldbus.homing``: SDO plan, then ``HomingProcedure.step`` per SYNC) on python-can's
virtual bus: final position, statusword bits, the home offset and the drive's refusals."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c
from nurbsmotion.fieldbus.homing import HomingDriveValues, HomingOutcome, HomingProcedure, homing_plan
from nurbsmotion.sim.homing import HomeSensors

from conftest import Bench, derived_eds

NODE = 4
# raw counts at power-on (the drive starts at 0): switches at -2500 / +2500, index every 1000 at ..-1700, -700, 300..
SENSORS = HomeSensors(negative_limit_counts=-2500, positive_limit_counts=2500, index_pitch_counts=1000,
                      index_phase_counts=300)
OFFSET = 500  # 0x607C: the home position reads -500 (CiA 402: zero = home + home offset)
SPEED_SEARCH, SPEED_ZERO, ACCEL = 50_000, 10_000, 1_000_000  # counts/s, counts/s²
MAX_CYCLES = 2000


def _statusword(bench: Bench) -> int | None:
    frames = bench.frames.of(0x180 + NODE)
    return struct.unpack_from("<H", frames[-1])[0] if frames else None


def _tpdo_position(bench: Bench) -> int:
    return struct.unpack_from("<Hi", bench.frames.of(0x180 + NODE)[-1])[1]


def _configure(bench: Bench, method: int, sensors: HomeSensors = SENSORS, eds: Path | None = None) -> None:
    drive, node = bench.add(NODE, home_sensors=sensors, eds=eds)
    values = HomingDriveValues(method, SPEED_SEARCH, SPEED_ZERO, ACCEL, OFFSET)
    for write in homing_plan(values, c.Mode.CYCLIC_SYNC_POSITION).writes:
        node.sdo.download(write.index, write.subindex, write.data())
    assert node.sdo[0x6061].raw == 6
    bench.operational(NODE)


def _home(bench: Bench, method: int, stop_after: int | None = None) -> HomingOutcome:
    """Run the master's procedure one SYNC per step until it ends (RPDO1: controlword, target)."""
    procedure = HomingProcedure(NODE, method, bench.sync_period_s, timeout_s=MAX_CYCLES * bench.sync_period_s)
    for cycle in range(MAX_CYCLES + 1):
        step = procedure.step(_statusword(bench))
        controlword = step.controlword if stop_after is None or cycle < stop_after else 0x06  # shutdown
        bench.send(0x200 + NODE, struct.pack("<Hi", controlword, 0))
        bench.sync()
        if step.outcome is not None:
            return step.outcome
    raise AssertionError("the procedure did not end")


def _finish(bench: Bench) -> None:
    """A few more cycles with bit 4 kept low: the drive decelerates to rest after its home."""
    for _ in range(60):
        bench.send(0x200 + NODE, struct.pack("<Hi", 0x0F, 0))
        bench.sync()


@pytest.mark.parametrize("method, home_raw, tolerance", [
    (1, -1700, 0),  # negative limit at -2500, back off, first index after the switch
    (17, -2500, SPEED_ZERO * 1e-3),  # where the switch is seen released: sampled once per cycle
    (34, 300, 0),  # positive at speed_zero, first index
    (35, 0, 0),  # current position (CiA 402 v3)
    (37, 0, 0),  # current position (CiA 402 v4)
])
def test_the_master_procedure_homes_the_simulated_drive(bench: Bench, method: int, home_raw: int,
                                                        tolerance: float) -> None:
    _configure(bench, method)
    outcome = _home(bench, method)
    assert outcome.homed, outcome.reason
    word = _statusword(bench)
    assert word is not None and word & (1 << 12) and word & (1 << 10) and not word & (1 << 13)
    _finish(bench)
    drive = bench.sim[NODE]
    state = drive.axis.homing_state
    # the home position reads -0x607C: position = raw + shift, shift = -OFFSET - home_raw
    assert abs(drive.axis.home_shift - (-OFFSET - home_raw)) <= tolerance
    assert drive.position_actual == round(state.raw + drive.axis.home_shift) == _tpdo_position(bench)
    assert abs(drive.position_actual - (-OFFSET + state.raw - home_raw)) <= tolerance + 0.5
    if method in (35, 37):
        assert drive.position_actual == -OFFSET


def test_after_homing_csp_continues_from_the_homed_position(bench: Bench) -> None:
    _configure(bench, 1)
    assert _home(bench, 1).homed
    _finish(bench)
    drive, node = bench.sim[NODE], bench.nodes[NODE]
    here = drive.position_actual
    node.sdo[0x6060].raw = 8  # the plan's restore write
    for _ in range(5):
        bench.send(0x200 + NODE, struct.pack("<Hi", 0x0F, here))
        bench.sync()
    assert drive.position_actual == here
    assert drive.following_error == 0
    assert drive.axis.home_shift == -OFFSET + 1700  # the switches stay where they are on the machine


def test_a_method_without_index_pulses_ends_in_a_homing_error(bench: Bench) -> None:
    """Method 34 on an axis without index pulses runs into the positive limit: bit 13."""
    _configure(bench, 34, sensors=HomeSensors(negative_limit_counts=-2500, positive_limit_counts=2500))
    outcome = _home(bench, 34)
    assert not outcome.homed
    assert "homing error" in outcome.reason and f"node {NODE}" in outcome.reason
    assert _statusword(bench) & (1 << 13)


def test_leaving_operation_enabled_interrupts_homing(bench: Bench) -> None:
    _configure(bench, 1)
    outcome = _home(bench, 1, stop_after=150)  # shutdown while still searching the switch
    assert not outcome.homed and "left OPERATION ENABLED" in outcome.reason
    drive = bench.sim[NODE]
    assert drive.axis.homing_state.phase.value == "not started"
    assert drive.axis.home_shift == 0.0


def test_the_drive_refuses_homing_methods_it_does_not_have(bench: Bench) -> None:
    _, node = bench.add(NODE)
    for method in (3, 19, 36, -1):
        with pytest.raises(SdoAbortedError) as err:
            node.sdo[0x6098].raw = method
        assert err.value.code == 0x06090030
    node.sdo[0x6098].raw = 37
    assert node.sdo[0x6098].raw == 37


def test_the_packaged_eds_declares_homing(bench: Bench) -> None:
    drive, node = bench.add(NODE)
    assert drive.value(0x6502) & (1 << 5)
    node.sdo[0x6060].raw = 6
    assert node.sdo[0x6061].raw == 6


def test_without_homing_in_0x6502_mode_6_is_refused(bench: Bench, tmp_path: Path) -> None:
    eds = derived_eds(tmp_path, change={"6502": {"DefaultValue": "0x000000C0"}})
    _, node = bench.add(NODE, eds=eds)
    with pytest.raises(SdoAbortedError):
        node.sdo[0x6060].raw = 6


def test_homing_needs_a_rising_edge_of_bit_4_while_enabled(bench: Bench) -> None:
    """Enabling with bit 4 already set starts nothing (CiA 402-2: the edge starts homing)."""
    _configure(bench, 35)
    for word in (0x06, 0x07, 0x1F, 0x1F, 0x1F):
        bench.send(0x200 + NODE, struct.pack("<Hi", word, 0))
        bench.sync()
    word = _statusword(bench)
    assert c.state_of_statusword(word) is c.State.OPERATION_ENABLED
    assert word & (1 << 10) and not word & (1 << 12)  # not started
    assert bench.sim[NODE].position_actual == 0
