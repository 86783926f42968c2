"""axes[i].homing: drive methods need speeds and acceleration; every error names its line."""

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.config.homing import HERE, HomingConfig


def _axis(homing: str) -> str:
    return f"axes:\n  - name: X\n    node_id: 1\n    homing: {homing}\n"


def _errors(text: str) -> list[str]:
    with pytest.raises(InputError) as info:
        parse_config(text, "m.yaml")
    return str(info.value).splitlines()


def test_drive_method_is_read_with_defaults():
    cfg = parse_config(_axis("{method: 17, speed_search_mm_s: 20, speed_zero_mm_s: 2, accel_mm_s2: 200, offset_mm: -5}"))
    assert cfg.axes[0].homing == HomingConfig(method=17, offset_mm=-5, speed_search_mm_s=20, speed_zero_mm_s=2,
                                              accel_mm_s2=200, timeout_s=60.0, speed_unit_counts_s=1.0,
                                              accel_unit_counts_s2=1.0, home_offset_sign=-1)
    assert cfg.axes[0].homing.on_drive


def test_method_here_needs_no_speeds():
    homing = parse_config(_axis("{method: here, offset_mm: 12.5}")).axes[0].homing
    assert homing.method == HERE and homing.offset_mm == 12.5 and not homing.on_drive


def test_no_homing_section_means_none():
    assert parse_config("axes: [{name: X, node_id: 1}]\n").axes[0].homing is None


def test_drive_method_without_speeds_names_the_missing_keys():
    assert _errors(_axis("{method: 1, speed_search_mm_s: 20}")) == [
        "m.yaml:4: axes[0].homing: homing method 1 runs on the drive and needs speed_zero_mm_s, accel_mm_s2"]


@pytest.mark.parametrize("value, message", [
    ("36", "homing method 36 is not defined by CiA 402 (1..35, 37; -128..-1 manufacturer specific)"),
    ("0", "homing method 0 is not defined by CiA 402 (1..35, 37; -128..-1 manufacturer specific)"),
    ("-129", "homing method -129 is not defined by CiA 402 (1..35, 37; -128..-1 manufacturer specific)"),
    ("home", "must be a CiA-402 homing method number or 'here', got 'home'"),
    ("true", "must be a CiA-402 homing method number or 'here', got True"),
])
def test_bad_method(value, message):
    text = f"axes:\n  - name: X\n    node_id: 1\n    homing:\n      method: {value}\n"
    assert _errors(text) == [f"m.yaml:5: axes[0].homing.method: {message}"]


def test_bad_values_and_unknown_keys_are_located():
    text = ("axes:\n  - name: X\n    node_id: 1\n    homing:\n      method: here\n"
            "      speed_zero_mm_s: -1\n      home_offset_sign: 2\n      ofset_mm: 3\n")
    lines = _errors(text)
    assert lines[0].startswith("m.yaml:8: axes[0].homing.ofset_mm: unknown key 'ofset_mm'; expected one of: method,")
    assert lines[1] == "m.yaml:6: axes[0].homing.speed_zero_mm_s: must be > 0, got -1"
    assert lines[2] == "m.yaml:7: axes[0].homing.home_offset_sign: must be -1 or 1, got 2"
    assert len(lines) == 3


def test_manufacturer_specific_method_is_accepted():
    cfg = parse_config(_axis("{method: -3, speed_search_mm_s: 1, speed_zero_mm_s: 1, accel_mm_s2: 1}"))
    assert cfg.axes[0].homing.method == -3


def test_drive_methods_35_and_37_need_no_speeds():
    homing = parse_config(_axis("{method: 37, offset_mm: 1}")).axes[0].homing
    assert homing.on_drive and not homing.moves


def test_an_axis_sim_section_places_the_simulated_switches_and_index_pulses():
    from nurbsmotion.config.homing import AxisSimSensors

    cfg = parse_config("axes:\n  - name: X\n    node_id: 1\n    sim: {negative_limit_mm: -3, index_pitch_mm: 2, "
                       "index_phase_mm: 0.7}\n  - {name: Y, node_id: 2}\n")
    assert cfg.axes[0].sim == AxisSimSensors(negative_limit_mm=-3, index_pitch_mm=2, index_phase_mm=0.7)
    assert cfg.axes[1].sim is None


def test_axis_sim_errors_name_their_yaml_line():
    assert _errors("axes:\n  - name: X\n    node_id: 1\n    sim:\n      negative_limit_mm: 5\n"
                   "      positive_limit_mm: 5\n      index_pitch_mm: 0\n      home_switch_mm: 1\n") == [
        "m.yaml:8: axes[0].sim.home_switch_mm: unknown key 'home_switch_mm'; expected one of: negative_limit_mm, "
        "positive_limit_mm, index_pitch_mm, index_phase_mm",
        "m.yaml:7: axes[0].sim.index_pitch_mm: must be > 0, got 0",
        "m.yaml:5: axes[0].sim: negative_limit_mm 5 must be below positive_limit_mm 5"]


def test_a_vendor_offset_object_needs_its_sign():
    assert _errors(_axis("{method: 35, offset_mm: 1, home_offset_object: 0x30B0}")) == [
        "m.yaml:4: axes[0].homing: home_offset_object 0x30B0 needs home_offset_sign (1: the home reads the value "
        "written, -1: it reads minus it; see the drive's manual)"]
    homing = parse_config(_axis("{method: 35, home_offset_object: 0x30B0, home_offset_sign: 1}")).axes[0].homing
    assert homing.home_offset_object == 0x30B0 and homing.home_offset_sign == 1


def test_a_vendor_offset_object_is_in_the_manufacturer_area():
    assert _errors(_axis("{method: 35, home_offset_object: 0x607C, home_offset_sign: 1}")) == [
        "m.yaml:4: axes[0].homing.home_offset_object: must be a manufacturer-specific object 0x2000..0x5FFF, got "
        "0x607C (0x607C is used by itself where the drive's EDS lists it)"]
