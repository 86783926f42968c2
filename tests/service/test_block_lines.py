"""blocks.csv of a streamed job, appended by the planner worker as blocks are planned."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.service.block_lines import BlockLinesFile
from nurbsmotion.service.job_common import block_lines
from nurbsmotion.service.records import BLOCK_LINES_FILE

TEXT = "G21 G90 F3000\n\nG01 X1\nG01 X2\n(note)\nG02 X4 R1\nG01 X5\nG01 X6\nM30\n"


def rows(folder: Path) -> list[str]:
    return (folder / BLOCK_LINES_FILE).read_text().splitlines()


def test_the_lines_of_the_blocks_planned_are_there_after_each_write(tmp_path: Path):
    program = parse_gcode(TEXT, "p.nc", np.zeros(3))
    assert block_lines(program) == [3, 4, 6, 7, 8]
    assert block_lines(program, 1, 3) == [4, 6] and block_lines(program, 4, 99) == [8]
    out = BlockLinesFile(program)
    out.write(tmp_path)
    assert rows(tmp_path) == ["line"]  # nothing planned yet
    out.reach(2)
    out.write(tmp_path)
    assert rows(tmp_path) == ["line", "3", "4"]
    out.reach(1)  # an earlier block again (a chunk within the same block): nothing new
    out.reach(99)  # the program's end: every block
    out.write(tmp_path)
    out.close()
    assert rows(tmp_path) == ["line", "3", "4", "6", "7", "8"]


def test_a_record_that_cannot_be_written_is_one_log_line_not_a_stopped_job(tmp_path: Path, caplog):
    out = BlockLinesFile(parse_gcode(TEXT, "p.nc", np.zeros(3)))
    out.reach(3)
    caplog.set_level(logging.WARNING)
    out.write(tmp_path / "gone")
    out.write(tmp_path / "gone")
    out.close()
    assert [r.getMessage().split()[0] for r in caplog.records] == ["block_lines_not_written"]
