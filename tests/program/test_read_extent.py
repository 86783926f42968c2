"""No program is shortened silently (issue 26.5): a '%' line with text is refused at its line
(LinuxCNC: "Bad character '%' used"), a bare '%' is the tape mark, and the reader says how
many of the file's lines it read and why it stopped (M2/M30, the closing %: LinuxCNC ignores
what follows, so it is said, not silent)."""

from __future__ import annotations

import pytest

from nurbsmotion.cli._format import reading_text
from nurbsmotion.errors import InputError
from nurbsmotion.program import parse_gcode
from nurbsmotion.program.model import ReadExtent
from nurbsmotion.program.summary import reading_dict

# line 33 of a public drilling program for a grbl router: "% vfd enable", 101 moves after it
DRILLING = "%\nG21 G90\nG00 Z5\n% vfd enable\nG01 X10 F600\nG01 X20\nM30\n%\n"


def read(text: str) -> ReadExtent:
    program = parse_gcode(text, "p.nc")
    assert program.reading is not None
    return program.reading


def test_a_percent_line_with_text_is_refused_at_its_line():
    with pytest.raises(InputError) as refused:
        parse_gcode(DRILLING, "drill.nc")
    assert str(refused.value) == ("drill.nc:4: % vfd enable: a '%' line is the tape mark and holds nothing else "
                                  "(as a comment: (vfd enable))")


def test_it_is_refused_in_a_file_that_does_not_open_with_a_percent_too():
    with pytest.raises(InputError, match=r"^p\.nc:2: %vfd: a '%' line is the tape mark"):
        parse_gcode("G21\n%vfd\nG01 X1 F600\n", "p.nc")


def test_a_bare_percent_is_the_tape_mark_and_says_where_reading_ended():
    program = parse_gcode("%\nG21 G90\nG01 X1 F600\n  %  \nG01 X9\n\n", "p.nc")
    assert len(program.blocks) == 1
    assert program.reading == ReadExtent(lines_total=6, last_line=4, ended_by="%", lines_not_read=1)
    assert reading_text(reading_dict(program)) == "4 of 6 read, to % at line 4; lines after % not read: 1"


def test_lines_after_m30_are_counted_and_said():
    extent = read("G21 G90\nG01 X1 F600\nM30\nG01 X5\n(comment)\n\nG01 X6\n%\n")
    assert extent == ReadExtent(lines_total=8, last_line=3, ended_by="M30", lines_not_read=2)  # comments, blanks, % not
    assert reading_text({"lines_total": 8, "last_line": 3, "ended_by": "M30", "lines_not_read": 2}) == \
        "3 of 8 read, to M30 at line 3; lines after M30 not read: 2"


def test_a_program_read_to_its_end_says_so():
    assert read("G21 G90\nG01 X1 F600") == ReadExtent(lines_total=2, last_line=2, ended_by="end of file",
                                                      lines_not_read=0)
    assert read("G21 G90\nG01 X1 F600\nm2\n") == ReadExtent(3, 3, "M2", 0)
    assert reading_text({"lines_total": 2, "last_line": 2, "ended_by": "end of file", "lines_not_read": 0}) == \
        "2 of 2 read"
