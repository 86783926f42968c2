"""``nurbsmotion check``: summary and exit 0 for good programs, one line per error and exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nurbsmotion.cli import main
from nurbsmotion.program import read_program

from ..conftest import WANG_LENGTH_MM

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize("name", ["wang_table1.nc", "wang_table1.yaml", "mixed.nc"])
def test_good_programs_exit_0_with_a_summary(name, capsys):
    assert main(["check", str(EXAMPLES / name)]) == 0
    out = capsys.readouterr()
    assert out.err == ""
    assert "OK" in out.out and "bbox" in out.out and "mm/min" in out.out


def test_json_summary_has_length_bbox_and_feed(capsys):
    assert main(["check", "--json", str(EXAMPLES / "wang_table1.nc")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] is True
    assert data["length_mm"] == pytest.approx(WANG_LENGTH_MM, abs=0.05)
    assert data["feed_min_mm_min"] == data["feed_max_mm_min"] == pytest.approx(12000)
    assert data["blocks_by_kind"] == {"nurbs": 1}


def test_bounding_box_is_of_the_path_not_the_control_points(capsys):
    # Wang's control points reach +/-100 mm; the curve itself stays inside them
    assert main(["check", "--json", str(EXAMPLES / "wang_table1.yaml")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert 90 < data["bbox_max_mm"][1] < 100 and -100 < data["bbox_min_mm"][1] < -90


def test_mixed_program_bbox_includes_arcs_leaving_the_xy_plane(capsys):
    assert main(["check", "--json", str(EXAMPLES / "mixed.nc")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["bbox_min_mm"][2] == pytest.approx(-10, abs=1e-3)  # the G18 half circle dips to Z-10
    program = read_program(EXAMPLES / "mixed.nc")
    assert data["length_mm"] == pytest.approx(program.length_mm)
    assert max(abs(v) for v in data["bbox_min_mm"] + data["bbox_max_mm"]) <= 150


@pytest.mark.parametrize("name,count", [("zhang_invalid.yaml", 6), ("zhang_invalid.nc", 4)])
def test_bad_programs_exit_2_one_line_per_error_no_traceback(name, count, capsys):
    assert main(["check", str(EXAMPLES / name)]) == 2
    out = capsys.readouterr()
    lines = out.err.splitlines()
    assert len(lines) == count
    assert all(line.startswith(f"nurbsmotion check: error: {EXAMPLES / name}:") for line in lines)
    assert "Traceback" not in out.err and out.out == ""


def test_bad_program_json_lists_every_error(capsys):
    assert main(["check", "--json", str(EXAMPLES / "zhang_invalid.nc")]) == 2
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] is False and len(data["errors"]) == 4
    assert data["errors"][0]["message"].startswith("weight 1 is 0")


def test_missing_file_and_unknown_extension_are_input_errors(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nope.nc")]) == 2
    assert "cannot read" in capsys.readouterr().err
    other = tmp_path / "prog.txt"
    other.write_text("G1 X1 F100")
    assert main(["check", str(other)]) == 2
    assert "unknown program type '.txt'" in capsys.readouterr().err


def test_start_option_moves_the_gcode_start(tmp_path, capsys):
    prog = tmp_path / "p.nc"
    prog.write_text("G91 G1 X1 F100\n")
    assert main(["check", "--json", "--start", "5", "0", "0", str(prog)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["start_mm"] == [5, 0, 0] and data["end_mm"] == [6, 0, 0]


def test_windows_line_ends_and_a_byte_order_mark_are_accepted(tmp_path):
    prog = tmp_path / "w.nc"
    prog.write_bytes("\ufeff%\r\nG1 X1 F100\r\nY2\r\n%\r\n".encode("utf-8"))
    program = read_program(prog)
    assert [b.source.line for b in program.blocks] == [2, 3]
    assert program.blocks[1].source.text == "Y2"


def test_a_non_finite_start_position_is_an_input_error(capsys):
    assert main(["check", "--start", "nan", "0", "0", str(EXAMPLES / "mixed.nc")]) == 2
    assert "start position: must be 3 finite numbers" in capsys.readouterr().err
