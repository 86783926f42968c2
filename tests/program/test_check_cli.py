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


POST_WITH_FIVE_PROBLEMS = """%
O1001 (BRACKET)
(T1 D=6. CR=0. - ZMIN=-3. - FLAT END MILL)
G90 G94 G17 G91.1
G21
G53 G0 Z0.
T1 M6
S8000 M3
G54
G0 X10. Y10.
G43 Z15. H1
G0 Z5.
G1 Z-3. F300.
G1 X40. A5.
G2 X50. Y20. I0. J10.
G41 D1 X60.
G3 X40. Y40. R15.
G81 X20. Y20. Z-5. R2. F100.
G1 X10. Y10. Q2
M5
G28 G91 Z0.
M30
%
"""


def test_check_reports_every_problem_of_a_post_in_one_run(tmp_path, capsys):
    """The issue's user needed five edit-and-check rounds; one run now names all five."""
    path = tmp_path / "post.nc"
    path.write_text(POST_WITH_FIVE_PROBLEMS)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    prefix = f"nurbsmotion check: error: {path}:"
    assert all(line.startswith(prefix) for line in err), err
    where = [line[len(prefix):].split(":")[0] for line in err]
    assert where == ["11", "14", "16", "18", "19"], err  # the bad lines 14 and 16 end where they were meant to
    assert "G43 needs a tool table for tool 1" in err[0] and "unsupported: axis A" in err[1]


def test_check_accepts_the_post_with_a_tool_table_and_json_lists_events(tmp_path, capsys):
    fixed = POST_WITH_FIVE_PROBLEMS.replace(" A5.", "").replace(" Q2", "").replace("G41 D1 ", "G1 ")
    text = "\n".join(line for line in fixed.splitlines() if "G81" not in line) + "\n"
    (tmp_path / "post.nc").write_text(text)
    (tmp_path / "tools.yaml").write_text("tools:\n  - number: 1\n    length_mm: 50\n    diameter_mm: 6\n")
    assert main(["check", "--json", "--tool-table", str(tmp_path / "tools.yaml"), str(tmp_path / "post.nc")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["events_by_kind"] == {"tool_change": 1, "spindle": 2}
    assert data["tools"] == [1] and data["requires_spindle"] is True and data["requires_coolant"] is False
    assert data["bbox_max_mm"][2] == pytest.approx(65)  # G43 H1 Z15 in G54 (zero offsets): machine Z 15 + 50
