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


def junction_angles_deg(program) -> list[float]:
    """Angle between the end tangent of each block and the start tangent of the next."""
    angles = []
    for a, b in zip(program.blocks, program.blocks[1:]):
        ta = a.curve.derivatives(a.curve.u_max, 1)[1]
        tb = b.curve.derivatives(b.curve.u_min, 1)[1]
        cos = ta @ tb / (np.linalg.norm(ta) * np.linalg.norm(tb))
        angles.append(float(np.degrees(np.arccos(np.clip(cos, -1, 1)))))
    return angles


def test_mixed_example_has_every_block_kind_arcs_in_three_planes_and_both_junction_kinds():
    program = read_program(EXAMPLES / "mixed.nc")
    kinds = {b.kind for b in program.blocks}
    assert kinds == {BlockKind.RAPID, BlockKind.LINE, BlockKind.ARC, BlockKind.NURBS}
    arcs = [b for b in program.blocks if b.kind is BlockKind.ARC]
    normals = set()
    for arc in arcs:  # the plane normal is the axis along which the arc does not move
        pts = arc.curve.points(np.linspace(arc.curve.u_min, arc.curve.u_max, 50))
        normals.add(int(np.argmin(np.ptp(pts, axis=0))))
    assert normals == {0, 1, 2}
    angles = junction_angles_deg(program)
    assert sum(a < 1e-6 for a in angles) >= 3  # tangent junctions
    assert sum(a > 10 for a in angles) >= 3  # corners
    for a, b in zip(program.blocks, program.blocks[1:]):
        np.testing.assert_allclose(a.end, b.start, atol=1e-12)
