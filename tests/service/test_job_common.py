"""job_common.block_lines: the program line of each block from the block columns is its Block's."""

from __future__ import annotations

from pathlib import Path

import pytest

from nurbsmotion.program import Program, ReadOptions, read_program
from nurbsmotion.program.records import BlockRecords
from nurbsmotion.service.job_common import block_lines

GCODE = Path(__file__).resolve().parents[1] / "data" / "gcode"


@pytest.mark.parametrize("name, start_line", [("fusion360_led_floor_1121_btn8copies_20bit.nc", None),
                                              ("fusion360_led_floor_1121_btn8copies_20bit.nc", 400),
                                              ("linuxcnc_nurbs_G5_butterfly-xy.ngc", None)])
def test_the_block_lines_from_the_columns_are_the_blocks(name, start_line):
    options = ReadOptions(start_line=start_line, safe_z_mm=10.0) if start_line else None
    program = read_program(GCODE / name, options=options)
    assert isinstance(program.blocks, BlockRecords)
    if start_line:
        assert program.blocks.source_overrides  # the approach's blocks name another text
    want = [b.source.line for b in tuple(program.blocks)]
    assert block_lines(program) == want
    assert block_lines(Program(program.name, tuple(program.blocks), program.start_position)) == want
