"""YAML curve files: defaults, 2-D points, several curves, and Zhang's invalid example."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.errors import InputErrors
from nurbsmotion.geometry import clamped_uniform_knots
from nurbsmotion.program import BlockKind, parse_curve_yaml, read_program

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_defaults_weights_one_knots_clamped_uniform_machine_feed():
    program = parse_curve_yaml("degree: 2\npoints: [[1,2,3],[4,5,6],[7,5,3],[9,9,9]]\n", "c.yaml")
    (block,) = program.blocks
    assert block.kind is BlockKind.NURBS and block.feed_mm_s is None
    np.testing.assert_array_equal(block.curve.weights, np.ones(4))
    np.testing.assert_array_equal(block.curve.knots, clamped_uniform_knots(4, 2))
    np.testing.assert_array_equal(program.start_position, [1, 2, 3])
    assert program.name == "c"


def test_two_dimensional_points_get_z_zero():
    (block,) = parse_curve_yaml("degree: 1\npoints: [[0, 0], [3, 4]]\nfeed_mm_min: 600\n", "c.yaml").blocks
    np.testing.assert_array_equal(block.curve.control_points, [[0, 0, 0], [3, 4, 0]])
    assert block.feed_mm_s == pytest.approx(10.0)


def test_several_curves_with_a_default_feed_and_their_own():
    text = """name: two
feed_mm_min: 1200
curves:
  - degree: 1
    points: [[0,0,0],[1,0,0]]
  - name: second
    degree: 2
    feed_mm_min: 600
    points: [[1,0,0],[2,1,0],[3,0,0]]
"""
    program = parse_curve_yaml(text, "c.yaml")
    assert program.name == "two"
    assert [b.feed_mm_s for b in program.blocks] == [20.0, 10.0]
    assert [b.source.line for b in program.blocks] == [4, 6]
    np.testing.assert_array_equal(program.end_position, [3, 0, 0])


def test_zhang_example_yaml_is_rejected_naming_zero_weights_and_decreasing_knots():
    with pytest.raises(InputErrors) as info:
        read_program(EXAMPLES / "zhang_invalid.yaml")
    lines = str(info.value).splitlines()
    source = str(EXAMPLES / "zhang_invalid.yaml")
    assert all(line.startswith(source + ":") for line in lines)
    wheres = [e.where.split(": ", 1)[1] for e in info.value.errors]
    assert {"weights[0]", "weights[1]", "knots[2]", "knots[4]"} <= set(wheres)
    messages = {e.where.split(": ", 1)[1]: e.message for e in info.value.errors}
    assert "weight 1 is 0" in messages["weights[0]"] and "weight 2 is 0" in messages["weights[1]"]
    assert "must not decrease" in messages["knots[2]"] and "must not decrease" in messages["knots[4]"]
    assert "need 10 knots" in messages["knots"]


def test_zhang_example_gcode_is_rejected_naming_zero_weights_and_decreasing_knots():
    with pytest.raises(InputErrors) as info:
        read_program(EXAMPLES / "zhang_invalid.nc")
    source = str(EXAMPLES / "zhang_invalid.nc")
    words = [e.where.removeprefix(source + ":") for e in info.value.errors]
    assert words == ["7: R0", "8: R0", "9: K0.7", "11: K0.6"]
