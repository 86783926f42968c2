"""``spindle:`` as a drive: fields, YAML-line errors, node id clash, the EDS's velocity-mode objects."""

from pathlib import Path

import pytest

from nurbsmotion.config import default_eds_path, load_config
from nurbsmotion.errors import InputError
from nurbsmotion.config.spindle import SpindleConfig, SpindleMode

ROOT = Path(__file__).resolve().parents[1]
GOOD = "spindle:\n  node_id: 5\n  counts_per_rev: 4096\n  max_rpm: 12000\n  accel_rpm_s: 6000\n"


def _config(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "machine.yaml"
    path.write_text((ROOT / "config" / "demo.yaml").read_text() + extra)
    return path


def _line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)




def test_the_fields_and_defaults(tmp_path):
    spindle = load_config(_config(tmp_path, GOOD)).spindle
    assert isinstance(spindle, SpindleConfig)
    assert (spindle.node_id, spindle.mode, spindle.at_speed_timeout_s) == (5, SpindleMode.PROFILE_VELOCITY, 5.0)
    assert spindle.eds == default_eds_path() and spindle.od is not None
    assert spindle.counts_s(600) == 40960 and spindle.rpm(40960) == 600 and spindle.accel_counts_s2 == 409600


def test_csv_mode_and_timeout(tmp_path):
    spindle = load_config(_config(tmp_path, GOOD + "  mode: csv\n  at_speed_timeout_s: 2.5\n")).spindle
    assert spindle.mode is SpindleMode.CSV and spindle.mode.number == 9 and spindle.at_speed_timeout_s == 2.5


@pytest.mark.parametrize("line, message", [
    ("  max_rpm: -5\n", "spindle.max_rpm: must be > 0, got -5"),
    ("  mode: velocity\n", "spindle.mode: must be one of profile_velocity, csv, got 'velocity'"),
    ("  rpm: 3\n", "spindle.rpm: unknown key 'rpm'"),
])
def test_bad_fields_are_named_at_their_line(tmp_path, line, message):
    text = GOOD.replace("  max_rpm: 12000\n", "") + line if "max_rpm" in line else GOOD + line
    path = _config(tmp_path, text)
    with pytest.raises(InputError) as err:
        load_config(path)
    assert f"machine.yaml:{_line_of(path, line.strip())}: {message}" in str(err.value)


def test_the_node_id_of_an_axis_is_refused(tmp_path):
    path = _config(tmp_path, GOOD.replace("node_id: 5", "node_id: 2"))
    with pytest.raises(InputError, match=rf"machine.yaml:{_line_of(path, '  node_id: 2')}: spindle.node_id: node id 2 "
                                         r"is already used by axis Y"):
        load_config(path)


def test_an_eds_without_the_velocity_objects_is_refused_at_the_eds_line(tmp_path):
    text = Path(default_eds_path()).read_text()
    start = text.index("[60FF]")
    end = text.index("\n[", start + 1)
    (tmp_path / "no60ff.eds").write_text(text[:start] + text[end + 1:])
    path = _config(tmp_path, GOOD + "  eds: no60ff.eds\n")
    with pytest.raises(InputError, match=rf"machine.yaml:{_line_of(path, '  eds: no60ff')}: spindle.eds: no60ff.eds "
                                         r"has no 0x60FF"):
        load_config(path)
