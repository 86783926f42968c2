"""The shipped EDS: loadable by canopen, with the CiA-301/402 objects the issue lists."""

from __future__ import annotations

import canopen
import pytest

from nurbsmotion.sim import default_eds_path
from nurbsmotion.sim.eds import check_range, initial_data, limits, supported_modes

REQUIRED = [
    0x1000, 0x1001, 0x1003, 0x1005, 0x1006, 0x1014, 0x1016, 0x1017, 0x1018,
    *range(0x1400, 0x1404), *range(0x1600, 0x1604), *range(0x1800, 0x1804), *range(0x1A00, 0x1A04),
    0x603F, 0x6040, 0x6041, 0x605A, 0x6060, 0x6061, 0x6064, 0x6065, 0x6066, 0x607A, 0x607D,
    0x6085, 0x60C0, 0x60C1, 0x60C2, 0x60C4, 0x60F4, 0x6502,
]


def test_default_eds_is_the_repository_file() -> None:
    path = default_eds_path()
    assert path.name == "nurbsmotion-servo.eds" and path.parent.name == "eds"


@pytest.mark.parametrize("index", REQUIRED, ids=lambda i: f"0x{i:04X}")
def test_eds_has_object(index: int) -> None:
    od = canopen.import_od(str(default_eds_path()), 5)
    assert index in od


@pytest.mark.parametrize("node_id", [1, 42, 127])
def test_default_cob_ids_follow_the_node_id(node_id: int) -> None:
    od = canopen.import_od(str(default_eds_path()), node_id)
    assert od[0x1014].default == 0x80 + node_id
    assert od[0x1400][1].default == 0x200 + node_id
    assert od[0x1800][1].default == 0x180 + node_id
    assert od[0x1402][1].default == 0x8000_0400 + node_id  # RPDO3 disabled by default


def test_supported_modes_advertise_ip_and_csp() -> None:
    od = canopen.import_od(str(default_eds_path()), 1)
    assert od[0x6502].default & (1 << 6) and od[0x6502].default & (1 << 7)
    assert od[0x6040].pdo_mappable and od[0x607A].pdo_mappable and od[0x60C1][1].pdo_mappable


def test_local_and_remote_nodes_load_the_eds() -> None:
    local = canopen.LocalNode(3, str(default_eds_path()))
    remote = canopen.RemoteNode(3, str(default_eds_path()))
    assert local.object_dictionary[0x1018][4].default == 3
    assert remote.tpdo[1].map_array.od.index == 0x1A00


def test_generated_file_is_up_to_date() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("eds_generate", default_eds_path().with_name("generate.py"))
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.eds_text() == default_eds_path().read_text(encoding="ascii")


CORPUS = default_eds_path().parents[1] / "tests" / "data" / "eds"


def entry(file: str, index: int, subindex: int = 0):
    od = canopen.import_od(str(CORPUS / file), 1)
    obj = od[index]
    return obj if subindex == 0 and not hasattr(obj, "subindices") else obj[subindex]


def test_a_signed_default_written_in_hex_is_its_twos_complement() -> None:
    var = entry("maxon_epos2_347717.eds", 0x60C0)  # DefaultValue=0xFFFF on an INTEGER16
    assert var.decode_raw(initial_data(var)) == -1


def test_an_entry_without_default_starts_at_0_or_at_its_nearest_limit() -> None:
    assert entry("zeroerr_eDriver_V1.5.eds", 0x607F).decode_raw(initial_data(entry("zeroerr_eDriver_V1.5.eds", 0x607F))) == 100
    var = entry("elmo_Elmo.eds", 0x6502)
    assert var.default is None and var.decode_raw(initial_data(var)) == 0


def test_an_inverted_range_is_no_range() -> None:
    var = entry("faulhaber_605.3150.73-A-EK-2-60.eds", 0x6061)  # 0..0xFF on INTEGER8 reads 0..-1
    assert limits(var) == (None, None)
    check_range(var, 5)


def test_supported_modes_from_0x6502_or_the_range_of_0x6060() -> None:
    assert supported_modes(0x3A5) == {1, 3, 6, 8, 9, 10}  # EPOS4: CSP, no IP
    assert supported_modes(0, entry("faulhaber_605.3150.73-A-EK-2-60.eds", 0x6060)) == {1, 2, 3, 4, 6}
    assert supported_modes(0) == {1, 2, 3, 4, 6, 7, 8, 9, 10}
