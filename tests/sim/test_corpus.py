"""Every real vendor EDS/DCF of tests/data/eds builds a simulated drive that answers SDO for
every object its EDS describes, refuses the ones it does not, and reports the modes and
cycle its EDS gives (see tests/data/eds/SOURCES.md for where each file comes from)."""

from __future__ import annotations

import struct
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from nurbsmotion.can.cia402 import State
from nurbsmotion.sim.eds import supported_modes
from nurbsmotion.sim.velocity import REQUIRED_OBJECTS

from conftest import Bench

CORPUS = Path(__file__).resolve().parents[1] / "data" / "eds"
FILES = sorted(p for p in CORPUS.glob("*") if p.suffix.lower() in (".eds", ".dcf"))
# Objects whose writes the drive judges by more than access and range (PDO procedure,
# modes, sub-mode, consumer entries, counter), so writing back the value read is not a no-op.
JUDGED = {0x1003, 0x1016, 0x1019, 0x6040, 0x6060, 0x60C0, *range(0x1400, 0x1C00)}


def entries(od: canopen.ObjectDictionary) -> list[ODVariable]:
    return [v for obj in od.values() for v in ([obj] if isinstance(obj, ODVariable) else obj.subindices.values())]


def test_the_corpus_is_there() -> None:
    assert len(FILES) >= 10, f"expected the real EDS corpus in {CORPUS}"


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_a_drive_built_from_a_real_eds_answers_sdo_for_its_objects(bench: Bench, path: Path) -> None:
    drive, node = bench.add(5, eds=path)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    readable = [v for v in entries(drive.od) if v.readable and v.index >= 0x1000]
    for var in readable:
        data = node.sdo.upload(var.index, var.subindex)
        assert data, f"0x{var.index:04X}:{var.subindex:02X} read as no data"
    for var in entries(drive.od):
        if var.writable and var.readable and var.index >= 0x1000 and var.index not in JUDGED and var.fixed_size:
            node.sdo.download(var.index, var.subindex, node.sdo.upload(var.index, var.subindex))  # its own value
    missing = next(i for i in range(0x2FFF, 0x1FFF, -1) if i not in drive.od)
    with pytest.raises(SdoAbortedError) as err:
        node.sdo.upload(missing, 0)
    assert err.value.code == 0x06020000


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_a_drive_takes_only_the_modes_its_eds_declares(bench: Bench, path: Path) -> None:
    drive, node = bench.add(5, eds=path)
    modes = supported_modes(drive.value(0x6502) if 0x6502 in drive.od else 0, drive.od[0x6060])
    # a velocity mode also needs its objects (sim.velocity.REQUIRED_OBJECTS): Schunk's PRL120
    # declares CSV/PV without 0x60FF
    modes -= {mode for mode, objects in REQUIRED_OBJECTS.items() if any(i not in drive.od for i in objects)}
    assert drive.axis.params.modes == modes
    for mode in (1, 7, 8):
        if mode in modes:
            node.sdo[0x6060].raw = mode
            assert node.sdo[0x6061].raw == mode
        else:
            with pytest.raises(SdoAbortedError) as err:
                node.sdo[0x6060].raw = mode
            assert err.value.code in (0x06090030, 0x06090031, 0x06090032)  # not supported / outside 0x6060's range


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_a_drive_enables_in_csp_or_ip_only_with_a_cycle_period(bench: Bench, path: Path) -> None:
    drive, node = bench.add(5, eds=path)
    mode = next((m for m in (8, 7) if m in drive.axis.params.modes), None)
    if mode is None:
        pytest.skip(f"{path.name}: neither CSP nor IP")
    node.sdo[0x6060].raw = mode
    bench.operational(5)
    for word in (0x06, 0x07, 0x1F):
        node.sdo.download(0x6040, 0, word.to_bytes(2, "little"))
    expected = State.OPERATION_ENABLED if drive.period_s > 0 else State.FAULT
    assert drive.state is expected, f"period {drive.period_s} s"


# (file, object, value) -> the CiA 301 abort the simulated drive answers, as its EDS says
HOMING_REFUSALS = [
    ("maxon_epos4_50_15_node1.dcf", 0x607C, 0, 1000, 0x06020000),  # no home offset object
    ("schunk_PRL120.eds", 0x6098, 0, 34, 0x06020000),  # no homing method object
    ("elmo_Elmo.eds", 0x6098, 0, 37, 0x06090031),  # HighLimit 35
    ("zeroerr_eDriver_V1.5.eds", 0x6099, 1, 20001, 0x06090031),  # HighLimit 20000
    ("zeroerr_eDriver_V1.5.eds", 0x6060, 0, 6, 0x06090030),  # 0x6502 = 0x38D: no homing mode
    ("pilz_prbt.eds", 0x6098, 0, 34, 0x06010002),  # const
]


@pytest.mark.parametrize("name, index, subindex, value, code", HOMING_REFUSALS)
def test_a_drive_refuses_the_homing_writes_its_eds_refuses(bench: Bench, name: str, index: int, subindex: int,
                                                           value: int, code: int) -> None:
    """What fieldbus.homing_check refuses at load is what the drive itself would refuse."""
    drive, node = bench.add(5, eds=CORPUS / name)
    fmt = {0x6098: "<b", 0x6060: "<b", 0x607C: "<i"}.get(index, "<I")
    with pytest.raises(SdoAbortedError) as err:
        node.sdo.download(index, subindex, struct.pack(fmt, value))
    assert err.value.code == code


@pytest.mark.parametrize("name", ["elmo_Elmo.eds", "maxon_epos4_50_15_node1.dcf", "technosoft_ISD860.eds"])
def test_a_drive_takes_the_homing_writes_its_eds_allows(bench: Bench, name: str) -> None:
    drive, node = bench.add(5, eds=CORPUS / name)
    for index, subindex, fmt, value in ((0x6098, 0, "<b", 34), (0x6099, 1, "<I", 20000), (0x6099, 2, "<I", 2000),
                                        (0x609A, 0, "<I", 200000), (0x6060, 0, "<b", 6)):
        node.sdo.download(index, subindex, struct.pack(fmt, value))
    assert node.sdo[0x6061].raw == 6
