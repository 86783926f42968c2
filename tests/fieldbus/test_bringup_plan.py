"""The bring-up plan derived from each drive's EDS, checked before the bus is touched (pure)."""

from __future__ import annotations

import pytest

from nurbsmotion.can import cia402 as c
from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.bringup_plan import (Field, PdoSetup, ReadBack, Write, cyclic_load, describe_value,
                                               plan_drive, plan_within_load, rpdo_packer)
from tests.fieldbus.eds_variants import eds_variant, one_entry_pdos


def config(mode: str = "csp", eds: str | None = None, axis_extra: str = "", top: str = "", period_ms: float = 4):
    eds_line = f"\n    eds: {eds}" if eds else ""
    text = (f"cycle_period_ms: {period_ms}\n{top}axes:\n  - name: X\n    node_id: 1\n    mode: {mode}{eds_line}\n"
            f"{axis_extra}")
    return parse_config(text, "machine.yaml")


def plan(cfg, fe_tpdo: bool = True):
    return plan_drive(cfg, 0, 1000, fe_tpdo)


def writes(p) -> dict[tuple[int, int], int]:
    return {(s.index, s.subindex): s.value for s in p.steps if isinstance(s, Write)}


def skipped(p) -> set[str]:
    return {s.what for s in p.skipped}


def test_packaged_drive_in_csp_gets_every_standard_object():
    p = plan(config("csp"))
    w = writes(p)
    assert w[(c.MODES_OF_OPERATION, 0)] == 8
    assert ReadBack("read mode back", c.MODES_OF_OPERATION_DISPLAY, 0, 8) in p.steps
    assert (w[(c.IP_TIME_PERIOD, 1)], w[(c.IP_TIME_PERIOD, 2)]) == (4, -3)  # 0x60C2 in CSP too
    assert w[(c.COMM_CYCLE_PERIOD, 0)] == 4000
    assert w[(0x1007, 0)] == 0  # SYNC window set explicitly: none unless bus.sync_window_us
    assert 1 <= w[(c.QUICK_STOP_OPTION, 0)] <= 4
    assert w[(c.CONSUMER_HEARTBEAT_TIME, 1)] == 127 << 16 | 500  # master node 127, 100 ms x 5
    assert (c.QUICK_STOP_DECELERATION, 0) not in w and "0x6085:00" in skipped(p)
    assert (c.IP_SUB_MODE, 0) not in w
    order = [(s.index, s.subindex) for s in p.steps if isinstance(s, Write)]
    assert order.index((c.MODES_OF_OPERATION, 0)) == 0


def test_sync_window_as_configured():
    assert writes(plan(config("csp", top="bus: {sync_window_us: 3000}\n")))[(0x1007, 0)] == 3000


def test_ip_writes_linear_sub_mode_and_period():
    p = plan(config("ip"))
    w = writes(p)
    assert w[(c.MODES_OF_OPERATION, 0)] == 7 and w[(c.IP_SUB_MODE, 0)] == 0
    assert p.layout.rpdos[0].fields == (Field.CONTROLWORD, Field.SETPOINT_IP)


def test_standard_layout_is_one_rpdo_and_tpdo1_plus_following_error():
    layout = plan(config("csp")).layout
    assert [(f.cob_id, f.fields) for f in layout.rpdos] == [(0x201, (Field.CONTROLWORD, Field.SETPOINT_CSP))]
    assert [f.cob_id for f in layout.tpdos] == [0x181, 0x281]
    assert layout.has_following_error
    assert not plan(config("csp"), fe_tpdo=False).layout.has_following_error


def test_optional_objects_the_drive_lacks_are_skipped(tmp_path):
    eds = eds_variant(tmp_path, "lean.eds", drop=(0x6066, 0x60C0, 0x60F4, 0x1006, 0x1007, 0x1016, 0x6085, 0x605A))
    p = plan(config("ip", str(eds)))
    w = writes(p)
    for index in (0x6066, 0x60C0, 0x1006, 0x1007, 0x1016, 0x605A):
        assert not any(i == index for i, _ in w), hex(index)
    assert {"0x6066:00", "0x60C0:00", "0x1006:00", "0x1007:00", "0x1016:01", "0x605A:00", "0x60F4:00"} <= skipped(p)
    assert not p.layout.has_following_error
    assert not any(isinstance(s, PdoSetup) and s.kind == "TPDO" and s.number == 2 for s in p.steps)


def test_missing_ip_set_point_refuses_ip_and_names_what_the_drive_offers(tmp_path):
    eds = eds_variant(tmp_path, "no_ip.eds", drop=(0x60C1,))
    with pytest.raises(InputError) as info:
        plan(config("ip", str(eds)))
    assert str(info.value) == ("machine.yaml:5: axes[0].mode (X, node 1): no_ip.eds has no 0x60C1:01, so "
                               "interpolated position (mode 7) is not possible; it offers cyclic synchronous "
                               "position (mode 8)")


def test_supported_modes_default_without_the_bit_refuses(tmp_path):
    eds = eds_variant(tmp_path, "ip_only.eds", set_keys={"6502": {"DefaultValue": "0x00000040"}})
    with pytest.raises(InputError, match=r"ip_only.eds's 0x6502 .* lacks bit 7, so cyclic synchronous position "
                                         r"\(mode 8\) is not possible; it offers interpolated position"):
        plan(config("csp", str(eds)))


def test_unmappable_set_point_refuses(tmp_path):
    eds = eds_variant(tmp_path, "schunk_like.eds", set_keys={"607A": {"PDOMapping": "0"}})
    with pytest.raises(InputError, match=r"does not allow 0x607A:00 \(Target position\) in a PDO"):
        plan(config("csp", str(eds)))


def test_sixteen_bit_set_point_refuses(tmp_path):
    eds = eds_variant(tmp_path, "erob_like.eds", set_keys={"60C1sub1": {"DataType": "0x0003"}})
    with pytest.raises(InputError, match=r"has 0x60C1:01 \(.*\) as int16; the master needs 32-bit signed"):
        plan(config("ip", str(eds)))


def test_one_entry_pdos_split_controlword_and_set_point(tmp_path):
    eds = eds_variant(tmp_path, "idm_like.eds", **one_entry_pdos())
    layout = plan(config("csp", str(eds))).layout
    assert [(f.number, f.fields) for f in layout.rpdos] == [(1, (Field.CONTROLWORD,)), (2, (Field.SETPOINT_CSP,))]
    assert [(f.number, f.fields) for f in layout.tpdos] == [(1, (Field.STATUSWORD,)), (2, (Field.POSITION,)),
                                                            (3, (Field.FOLLOWING_ERROR,))]
    cw_frame, sp_frame = layout.rpdos
    cw_data, sp_data = bytearray(cw_frame.dlc), bytearray(sp_frame.dlc)
    rpdo_packer(cw_frame)(cw_data, 0x0F, -5)
    rpdo_packer(sp_frame)(sp_data, 0x0F, -5)
    assert bytes(cw_data) == b"\x0f\x00" and bytes(sp_data) == (-5).to_bytes(4, "little", signed=True)


def test_following_error_time_out_out_of_the_drive_range_is_left_to_the_drive(tmp_path):
    eds = eds_variant(tmp_path, "epos4_like.eds", set_keys={"6066": {"LowLimit": "0", "HighLimit": "0"}})
    p = plan(config("csp", str(eds)))
    assert (c.FOLLOWING_ERROR_TIMEOUT, 0) not in writes(p)
    assert any(s.what == "0x6066:00" and "allows 0..0" in s.reason for s in p.skipped)


def test_quick_stop_deceleration_only_as_configured_in_drive_units(tmp_path):
    p = plan(config("csp", axis_extra="    quick_stop_decel: 50000\n"))
    assert writes(p)[(c.QUICK_STOP_DECELERATION, 0)] == 50000
    eds = eds_variant(tmp_path, "erob_6085.eds", set_keys={"6085": {"HighLimit": "65500"}})
    with pytest.raises(InputError, match=r"^machine.yaml:7: axes\[0\].quick_stop_decel \(X, node 1\): "
                                         r"erob_6085.eds's 0x6085:00 \(Quick stop deceleration\) allows 0..65500"):
        plan(config("csp", str(eds), axis_extra="    quick_stop_decel: 70000\n"))


def test_quick_stop_option_fixed_outside_1_to_4_refuses(tmp_path):
    eds = eds_variant(tmp_path, "qs6.eds", set_keys={"605A": {"AccessType": "ro", "DefaultValue": "6"}})
    with pytest.raises(InputError, match=r"0x605A:00 \(quick stop option\) is read-only at 6"):
        plan(config("csp", str(eds)))


def test_fixed_interpolation_exponent_scales_the_value(tmp_path):
    eds = eds_variant(tmp_path, "elmo_like.eds", set_keys={"60C2sub2": {"AccessType": "ro", "DefaultValue": "-4"}})
    w = writes(plan(config("csp", str(eds))))
    assert w[(c.IP_TIME_PERIOD, 1)] == 40 and (c.IP_TIME_PERIOD, 2) not in w


def test_master_heartbeat_off_writes_no_consumer():
    p = plan(config("csp", top="monitoring: {master_heartbeat_ms: 0}\n"))
    assert (c.CONSUMER_HEARTBEAT_TIME, 1) not in writes(p)


def test_sdo_list_is_written_last_in_order():
    p = plan(config("csp", axis_extra="    sdo:\n      - {index: 0x60C4, subindex: 2, value: 1}\n"
                                      "      - {index: 0x605A, value: 1}\n      - {index: 0x1007, value: 1000}\n"))
    last = [(s.index, s.subindex, s.value) for s in p.steps[-3:]]
    # another quick-stop option within 1-4, and this drive's own SYNC window, are the user's choice
    assert last == [(0x60C4, 2, 1), (0x605A, 0, 1), (0x1007, 0, 1000)]


@pytest.mark.parametrize("entry, message", [
    ("{index: 0x605A, value: 6}", "0x605A (quick stop option) = 6 is refused: the master needs 1-4"),
    ("{index: 0x6060, value: 1}", "0x6060 is written by the bring-up from axes[].mode; set it there"),
    ("{index: 0x6066, value: 100}", "0x6066 is written by the bring-up from axes[].following_error_timeout_ms"),
    ("{index: 0x1016, subindex: 1, value: 0}", "from monitoring.master_heartbeat_ms"),
    ("{index: 0x1A00, subindex: 1, value: 0x60410010}", "0x1A00 is a PDO object the bring-up maps itself"),
])
def test_sdo_list_may_not_undo_what_the_bring_up_writes(entry, message):
    """The list is written last: an entry for an object the plan writes would silently undo it
    (a 0x605A of 5-8 would let a quick-stopped drive resume motion)."""
    cfg = config("csp", axis_extra=f"    sdo:\n      - {{index: 0x60C4, subindex: 2, value: 1}}\n      - {entry}\n")
    with pytest.raises(InputError) as info:
        plan(cfg)
    text = str(info.value)
    assert text.startswith("machine.yaml:8: axes[0].sdo[1] (X, node 1): nurbsmotion-servo.eds: ") and "\n" not in text
    assert message in text


def test_abort_descriptions_name_the_object_in_hex_and_words():
    od = config("ip").axes[0].od
    assert describe_value(od, 0x1600, 2, 0x60C10120) == "0x1600:02 = 0x60C10120 (0x60C1:01, 32 bit)"
    assert describe_value(od, 0x6060, 0, 7) == "0x6060:00 = 7 (Modes of operation)"


def test_split_pdos_count_in_the_bus_load(tmp_path):
    eds = eds_variant(tmp_path, "one_entry.eds", **one_entry_pdos())
    axes = "".join(f"  - {{name: {n}, node_id: {i + 1}, eds: {eds}}}\n" for i, n in enumerate("XYZ"))
    standard = parse_config(f"cycle_period_ms: 1\naxes:\n" + "".join(
        f"  - {{name: {n}, node_id: {i + 1}}}\n" for i, n in enumerate("XYZ")), "m.yaml")
    assert cyclic_load(standard, plan_within_load(standard, [1000] * 3)) < 0.8  # one PDO each way: fits
    split = parse_config(f"cycle_period_ms: 1\naxes:\n{axes}", "m.yaml")
    with pytest.raises(InputError, match=r"^m.yaml:1: cycle_period_ms: bus load 1\d\d% of the planned PDOs"):
        plan_within_load(split, [1000] * 3)
    relaxed = parse_config(f"cycle_period_ms: 4\naxes:\n{axes}", "m.yaml")
    plans = plan_within_load(relaxed, [1000] * 3)
    assert all(p.layout.has_following_error for p in plans) and cyclic_load(relaxed, plans) < 0.8
