"""``tools:`` (the tool table file, read with the program package's reader) and ``spindle:``."""

from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
TABLE = "tools:\n  - {number: 1, length_mm: 52.3, diameter_mm: 6}\n  - {number: 2, length_mm: 47.15, diameter_mm: 3.175}\n"


def _config(tmp_path: Path, extra: str, table: str | None = TABLE) -> Path:
    if table is not None:
        (tmp_path / "tools").mkdir(exist_ok=True)
        (tmp_path / "tools" / "table.yaml").write_text(table)
    path = tmp_path / "machine.yaml"
    path.write_text((ROOT / "config" / "demo.yaml").read_text() + extra)
    return path


def test_the_tool_table_is_read_relative_to_the_config_file(tmp_path):
    config = load_config(_config(tmp_path, "tools: tools/table.yaml\n"))
    assert config.tools == str((tmp_path / "tools" / "table.yaml").resolve())
    assert config.tool_table.length_mm(2) == 47.15 and config.tool_table.get(1).diameter_mm == 6.0


def test_a_missing_tool_table_is_an_error_at_the_tools_line(tmp_path):
    path = _config(tmp_path, "tools: tools/none.yaml\n")
    line = len(path.read_text().splitlines())
    with pytest.raises(InputError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}:{line}: tools: tool table ") and "does not exist" in str(err.value)


def test_a_bad_tool_table_reports_each_problem_at_the_tables_own_line(tmp_path):
    path = _config(tmp_path, "tools: tools/table.yaml\n", table=TABLE + "  - {number: 2, length_mm: x, diameter_mm: -1}\n")
    with pytest.raises(InputError) as err:
        load_config(path)
    lines = str(err.value).splitlines()
    assert lines == [f"{(tmp_path / 'tools' / 'table.yaml').resolve()}:4: tools[2].length_mm: must be a finite "
                     f"number, got 'x'"]


@pytest.mark.parametrize("value, expected", [("none", "none"), ("null", None)])
def test_spindle_none_or_absent_means_no_spindle(tmp_path, value, expected):
    assert load_config(_config(tmp_path, f"spindle: {value}\n", table=None)).spindle == expected
    assert load_config(ROOT / "config" / "demo.yaml").spindle is None


def test_a_spindle_mapping_is_read_as_a_drive(tmp_path):
    path = _config(tmp_path, "spindle: {node_id: 5}\n", table=None)
    line = len(path.read_text().splitlines())
    with pytest.raises(InputError, match=rf"machine.yaml:{line}: spindle: missing required key 'counts_per_rev'"):
        load_config(path)
