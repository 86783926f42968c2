"""Configuration is validated once, and every error points at the YAML line and field."""

import shutil
from pathlib import Path

import pytest

from nurbsmotion.config import default_eds_path, load_config, parse_config
from nurbsmotion.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", ["demo.yaml"])
def test_example_configs_load(name):
    cfg = load_config(ROOT / "config" / name)
    assert cfg.axis_names() == ("X", "Y", "Z")
    assert cfg.cycle_period_s == pytest.approx(0.004)
    assert cfg.interpolation.feed_mm_s == pytest.approx(200.0)  # 12000 mm/min


def _errors(text: str) -> list[str]:
    with pytest.raises(InputError) as info:
        parse_config(text, "m.yaml")
    return str(info.value).splitlines()


def test_every_bad_field_is_reported_with_its_line():
    text = (
        "axes:\n"
        "  - {name: X, node_id: 1}\n"
        "  - name: Y\n"
        "    node_id: 200\n"
        "    counts_per_mm: -5\n"
        "cycle_period_ms: fast\n"
    )
    assert _errors(text) == [
        "m.yaml:4: axes[1].node_id: must be <= 127, got 200",
        "m.yaml:5: axes[1].counts_per_mm: must be > 0, got -5",
        "m.yaml:6: cycle_period_ms: must be a number, got 'fast'",
    ]


def test_unknown_key_is_an_error_not_ignored():
    lines = _errors("axes: [{name: X, node_id: 1, count_per_mm: 10}]\n")
    assert lines == ["m.yaml:1: axes[0].count_per_mm: unknown key 'count_per_mm'; expected one of: "
                     + ", ".join(__import__("nurbsmotion.config", fromlist=["x"])._AXIS_READERS)]


def test_duplicate_node_ids_and_names():
    lines = _errors("axes:\n  - {name: X, node_id: 1}\n  - {name: X, node_id: 1}\n")
    assert lines == ["m.yaml:3: axes[1].name: axis name 'X' is used twice",
                     "m.yaml:3: axes[1].node_id: node id 1 is used twice"]


def test_heartbeat_consumer_must_outlast_producer():
    lines = _errors("axes: [{name: X, node_id: 1}]\nmonitoring: {heartbeat_producer_ms: 100, heartbeat_consumer_ms: 50}\n")
    assert len(lines) == 1 and lines[0].startswith("m.yaml:2: monitoring.heartbeat_consumer_ms:")


def test_udp_multicast_is_refused():
    lines = _errors("axes: [{name: X, node_id: 1}]\nbus: {interface: udp_multicast}\n")
    assert "leaves the machine" in lines[0]


@pytest.mark.parametrize("text", ["", "axes: [", "- 1\n- 2\n", "axes: [{name: X, node_id: 1, soft_limits_mm: [5, 1]}]"])
def test_malformed_documents_give_one_located_error(text):
    for line in _errors(text):
        assert line.startswith("m.yaml")


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="cannot read configuration"):
        load_config(tmp_path / "nope.yaml")


def test_relative_eds_path_resolves_against_config_folder(tmp_path):
    (tmp_path / "drives").mkdir()
    shutil.copy(default_eds_path(), tmp_path / "drives" / "a.eds")
    (tmp_path / "m.yaml").write_text("axes: [{name: X, node_id: 1, eds: drives/a.eds}]\n")
    cfg = load_config(tmp_path / "m.yaml")
    assert cfg.axes[0].eds == str((tmp_path / "drives" / "a.eds").resolve())
    assert cfg.axes[0].od is not None and 0x6040 in cfg.axes[0].od  # read with canopen's import_od


def test_axis_without_eds_gets_the_packaged_description():
    cfg = parse_config("axes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert Path(cfg.axes[0].eds).name == "nurbsmotion-servo.eds" and cfg.axes[0].od is not None


def test_missing_or_unreadable_eds_is_one_error_at_its_line(tmp_path):
    (tmp_path / "bad.eds").write_text("[1000]\nParameterName=x\nDataType=zz\n")
    text = "axes:\n  - {name: X, node_id: 1, eds: nope.eds}\n  - {name: Y, node_id: 2, eds: bad.eds}\n"
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(InputError) as info:
        load_config(tmp_path / "m.yaml")
    lines = str(info.value).splitlines()
    assert lines[0].endswith("m.yaml:2: axes[0].eds (X, node 1): cannot read nope.eds: No such file or directory")
    assert "m.yaml:3: axes[1].eds (Y, node 2): bad.eds is not a readable EDS/DCF: " in lines[1] and len(lines) == 2


def test_sdo_list_is_checked_against_the_eds_at_its_lines():
    errors = _errors("axes:\n  - name: X\n    node_id: 1\n    sdo:\n"
                     "      - {index: 0x208E, value: 256}\n"
                     "      - {index: 0x6041, value: 1}\n"
                     "      - {index: 0x60C2, subindex: 1, value: 300}\n"
                     "      - {index: 0x6065, value: 5, type: int16}\n"
                     "      - {index: 0x60C4, subindex: 9, value: 1}\n"
                     "      - {index: 0x1007, value: 1000, type: uint32}\n")
    assert errors == [
        "m.yaml:5: axes[0].sdo[0] (X, node 1): nurbsmotion-servo.eds has no 0x208E:00",
        "m.yaml:6: axes[0].sdo[1] (X, node 1): nurbsmotion-servo.eds: 0x6041:00 (Statusword) is read-only "
        "(AccessType=ro)",
        "m.yaml:7: axes[0].sdo[2] (X, node 1): nurbsmotion-servo.eds: 0x60C2:01 (Interpolation time period value) "
        "allows 0..255 (uint8), not 300",
        "m.yaml:8: axes[0].sdo[3] (X, node 1): nurbsmotion-servo.eds: 0x6065:00 (Following error window) is uint32, "
        "not int16",
        "m.yaml:9: axes[0].sdo[4] (X, node 1): nurbsmotion-servo.eds: 0x60C4:09: 0x60C4 has no sub-index 9",
    ]


def test_sdo_entry_fields_are_validated():
    errors = _errors("axes:\n  - name: X\n    node_id: 1\n    sdo:\n      - {index: 0x20, value: 1}\n"
                     "      - {subindex: 1, value: 1}\n      - {index: 0x2000, value: 1, type: float}\n")
    assert errors[0].startswith("m.yaml:5: axes[0].sdo[0].index: must be >= 4096")
    assert errors[1].startswith("m.yaml:6: axes[0].sdo[1]: missing required key 'index'")
    assert errors[2].startswith("m.yaml:7: axes[0].sdo[2].type: must be one of bool, int8")


def test_master_node_and_heartbeat_keys():
    cfg = parse_config("master: {node_id: 100}\nmonitoring: {master_heartbeat_ms: 50, "
                       "master_heartbeat_consumer_multiple: 4}\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert cfg.master.node_id == 100 and cfg.monitoring.master_heartbeat_ms == 50
    assert parse_config("axes: [{name: X, node_id: 1}]\n").master.node_id == 127
    assert _errors("master: {node_id: 1}\naxes: [{name: X, node_id: 1}]\n") == [
        "m.yaml:2: axes[0].node_id: node id 1 is the master's (master.node_id)"]
    assert _errors("monitoring: {master_heartbeat_ms: 20000}\naxes: [{name: X, node_id: 1}]\n")[0].startswith(
        "m.yaml:1: monitoring.master_heartbeat_ms: the drives' consumer time 100000 ms")


def test_drive_step_timeout_is_read_and_checked():
    cfg = parse_config("bus: {drive_step_timeout_ms: 3000}\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert cfg.bus.drive_step_timeout_ms == 3000 and cfg.bus.sdo_timeout_ms == 500
    assert parse_config("axes: [{name: X, node_id: 1}]\n").bus.drive_step_timeout_ms == 500
    assert _errors("bus: {drive_step_timeout_ms: 0}\naxes: [{name: X, node_id: 1}]\n") == [
        "m.yaml:1: bus.drive_step_timeout_ms: must be >= 10, got 0"]


SAFE_Z_AXES = "axes:\n  - {name: X, node_id: 1}\n  - {name: Z, node_id: 3, soft_limits_mm: [-80, 5]}\n"


def test_machine_safe_z_is_read_and_checked_against_z_soft_limits():
    assert parse_config(SAFE_Z_AXES + "machine:\n  safe_z_mm: 2.5\n", "m.yaml").safe_z_mm() == 2.5
    assert _errors(SAFE_Z_AXES + "machine:\n  safe_z_mm: 10\n") == [
        "m.yaml:5: machine.safe_z_mm: 10 mm is outside axis Z's soft limits [-80, 5] mm"]
    assert _errors(SAFE_Z_AXES + "machine:\n  safe_z_mm: high\n") == [
        "m.yaml:5: machine.safe_z_mm: must be a number, got 'high'"]
    assert _errors(SAFE_Z_AXES + "machine:\n  safe_z: 1\n")[0].startswith("m.yaml:5: machine.safe_z")


def test_machine_safe_z_defaults_below_z_upper_soft_limit_or_must_be_given():
    assert parse_config(SAFE_Z_AXES, "m.yaml").safe_z_mm() == 4.0  # 5 mm - SAFE_Z_MARGIN_MM
    assert parse_config("axes:\n  - {name: X, node_id: 1}\n", "m.yaml").safe_z_mm() is None  # no Z: no rise
    with pytest.raises(InputError, match=r"^m.yaml: machine.safe_z_mm: not set, and axis Z has no soft_limits_mm"):
        parse_config("axes:\n  - {name: Z, node_id: 1}\n", "m.yaml").safe_z_mm()


def test_path_tolerance_is_read_checked_and_reaches_the_plan_limits():
    from nurbsmotion.planning.limits import limits_from_config
    cfg = parse_config("interpolation: {path_tolerance_mm: 0.02}\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert cfg.interpolation.path_tolerance_mm == 0.02 and limits_from_config(cfg).path_tolerance_mm == 0.02
    assert parse_config("axes: [{name: X, node_id: 1}]\n", "m.yaml").interpolation.path_tolerance_mm == 0.01
    assert parse_config("interpolation: {path_tolerance_mm: 0}\naxes: [{name: X, node_id: 1}]\n",
                        "m.yaml").interpolation.path_tolerance_mm == 0.0  # 0: no corner blends
    with pytest.raises(InputError) as info:
        parse_config("interpolation:\n  path_tolerance_mm: -1\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert str(info.value).startswith("m.yaml:2: interpolation.path_tolerance_mm")


def test_smoothing_is_read_checked_and_reaches_the_plan_limits():
    from nurbsmotion.planning.limits import limits_from_config
    cfg = parse_config("interpolation: {smoothing: false}\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert cfg.interpolation.smoothing is False and limits_from_config(cfg).smoothing is False
    assert limits_from_config(parse_config("axes: [{name: X, node_id: 1}]\n", "m.yaml")).smoothing is True
    with pytest.raises(InputError) as info:
        parse_config("interpolation:\n  smoothing: 1\naxes: [{name: X, node_id: 1}]\n", "m.yaml")
    assert str(info.value).startswith("m.yaml:2: interpolation.smoothing") and "true or false" in str(info.value)
