"""Wang's Table 1 curve shipped as G-code (G06.2) and as YAML: both give the paper's curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.program import BlockKind, read_program

from ..conftest import WANG_LENGTH_MM

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize("name", ["wang_table1.nc", "wang_table1.yaml"])
def test_wang_example_is_the_papers_curve(name, wang_curve):
    program = read_program(EXAMPLES / name)
    assert len(program.blocks) == 1
    block = program.blocks[0]
    assert block.kind is BlockKind.NURBS
    assert block.curve.degree == wang_curve.degree
    np.testing.assert_array_equal(block.curve.knots, wang_curve.knots)
    np.testing.assert_array_equal(block.curve.control_points, wang_curve.control_points)
    np.testing.assert_array_equal(block.curve.weights, wang_curve.weights)
    assert program.length_mm == pytest.approx(WANG_LENGTH_MM, abs=0.05)
    assert block.feed_mm_s == pytest.approx(12000 / 60)
    np.testing.assert_array_equal(program.start_position, [0, 0, 0])


def test_wang_gcode_block_names_its_g06_2_line():
    program = read_program(EXAMPLES / "wang_table1.nc")
    source = program.blocks[0].source
    assert source.text.startswith("N30 G06.2 P3")
    lines = (EXAMPLES / "wang_table1.nc").read_text().splitlines()
    assert "G06.2" in lines[source.line - 1]
