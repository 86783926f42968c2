"""Configuration is validated once, and every error points at the YAML line and field."""

from pathlib import Path

import pytest

from nurbsmotion.config import load_config, parse_config
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
    (tmp_path / "m.yaml").write_text("axes: [{name: X, node_id: 1, eds: drives/a.eds}]\n")
    cfg = load_config(tmp_path / "m.yaml")
    assert cfg.axes[0].eds == str((tmp_path / "drives" / "a.eds").resolve())
