"""starting_config: the YAML `drives scan --write-config` writes refuses to load until its
FILL_IN values are replaced, and then loads with the scan's node ids, identities and EDS files."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputErrors
from nurbsmotion.fieldbus.eds_catalog import EdsMatch, read_entry
from nurbsmotion.fieldbus.scan import DeviceType, Identity, NodeReport
from nurbsmotion.cli._starting_config import FILL_IN, BusSettings, axis_mode, spindle_mode, starting_config

ROOT = Path(__file__).resolve().parents[1]
SERVO = read_entry(ROOT / "eds" / "nurbsmotion-servo.eds")
FILLED = {"counts_per_mm": "1000", "soft_limits_mm": "[-100, 100]", "counts_per_rev": "4096", "max_rpm": "12000",
          "accel_rpm_s": "8000"}


def drive(node_id: int, modes: int | None, product: int = 0x4E4D0402) -> NodeReport:
    return NodeReport(node_id, 0x7F, 0.1, DeviceType(0x00020192), Identity(0, product, 0x00010000), modes=modes,
                      answered_sdo=True)


REPORTS = [drive(1, 0x1E4), drive(2, 0x1E4), drive(3, 0x65),  # csp+ip, csp+ip, ip only (Technosoft-like)
           drive(5, 0x104),  # pv + csv only: the spindle
           NodeReport(10, 0x7F, None, DeviceType(0x00030191), Identity(0, 0x401), answered_sdo=True),
           NodeReport(20, 0x7F)]  # heartbeat only


def test_modes_chosen_from_0x6502():
    assert [axis_mode(m) for m in (0x1E4, 0x65, 0x104, None)] == ["csp", "ip", None, "csp"]
    assert [spindle_mode(m) for m in (0x104, 0x04, 0x1E4 & ~0x104, None)] == ["csv", "profile_velocity", None, None]


def write(tmp_path: Path, matched: bool = True) -> Path:
    out = tmp_path / "machine.yaml"
    matches = {r.node_id: EdsMatch(SERVO) for r in REPORTS} if matched else {}
    out.write_text(starting_config(REPORTS, matches, BusSettings("socketcan", "can0", 500_000), out, "on test day"))
    return out


def test_it_does_not_load_before_the_fill_ins_are_replaced(tmp_path):
    out = write(tmp_path)
    with pytest.raises(InputErrors) as caught:
        load_config(out)
    lines = str(caught.value).splitlines()
    text = out.read_text().splitlines()
    assert len(lines) == sum(1 for line in text if f": {FILL_IN}" in line)  # one error per FILL_IN
    for line in lines:
        number = int(line.split(":")[1])
        assert FILL_IN in text[number - 1], line  # each error names the line that holds a FILL_IN


def test_filled_in_it_loads_with_the_scanned_nodes(tmp_path):
    out = write(tmp_path)
    out.write_text(re.sub(r"(\w+): FILL_IN", lambda m: f"{m[1]}: {FILLED[m[1]]}", out.read_text()))
    config = load_config(out)
    assert [(a.name, a.node_id, a.mode) for a in config.axes] == [("X", 1, "csp"), ("Y", 2, "csp"), ("Z", 3, "ip")]
    assert all(a.identity is not None and (a.identity.vendor_id, a.identity.product_code) == (0, 0x4E4D0402)
               for a in config.axes)
    assert {Path(a.eds).resolve() for a in config.axes} == {SERVO.path.resolve()}  # type: ignore[arg-type]
    assert (config.spindle.node_id, config.spindle.mode.value) == (5, "csv")
    assert config.io is not None and config.io.node_id == 10
    assert (config.bus.interface, config.bus.channel, config.bus.bitrate) == ("socketcan", "can0", 500_000)
    assert "# node 20 (no device type read; heartbeat only: no SDO answer) is not in this file" in out.read_text()


def test_without_a_matching_eds_the_eds_must_be_filled_in_too(tmp_path):
    out = write(tmp_path, matched=False)
    with pytest.raises(InputErrors) as caught:
        load_config(out)
    assert "axes[0].eds" in str(caught.value) or "eds" in str(caught.value)
    assert "eds: FILL_IN   # the drive's EDS/DCF file (no --eds-dir given)" in out.read_text()
