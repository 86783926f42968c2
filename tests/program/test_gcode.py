"""G-code features: modal words, distance and unit modes, comments, arcs in three planes, NURBS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.geometry import NurbsCurve, clamped_uniform_knots
from nurbsmotion.program import BlockKind, parse_gcode
from nurbsmotion.program.summary import curve_samples


def blocks(text: str, start=(0.0, 0.0, 0.0)):
    return parse_gcode(text, "t.nc", start).blocks


def ends(text: str, start=(0.0, 0.0, 0.0)):
    return [tuple(np.round(b.end, 9)) for b in blocks(text, start)]


def test_modal_motion_and_feed_carry_over_lines():
    bs = blocks("G01 X10 F600\nY10\nG00 X0\nZ5\nG01 Z0\n")
    assert [b.kind for b in bs] == [BlockKind.LINE, BlockKind.LINE, BlockKind.RAPID, BlockKind.RAPID, BlockKind.LINE]
    assert [b.feed_mm_s for b in bs] == [10.0, 10.0, None, None, 10.0]
    assert ends("G01 X10 F600\nY10\nG00 X0\nZ5\nG01 Z0\n")[-1] == (0, 10, 0)


def test_feed_is_mm_per_min_converted_to_mm_per_s_and_modal_until_changed():
    bs = blocks("G1 X1 F120\nX2\nX3 F6000\nX4")
    assert [b.feed_mm_s for b in bs] == [2.0, 2.0, 100.0, 100.0]


def test_incremental_g91_and_back_to_absolute_g90():
    assert ends("G91 G1 X10 Y5 F100\nX10\nG90 X0 Y0") == [(10, 5, 0), (20, 5, 0), (0, 0, 0)]


def test_program_starts_at_the_given_position():
    program = parse_gcode("G91 G1 X1 F100", "t.nc", (5, 6, 7))
    np.testing.assert_array_equal(program.start_position, [5, 6, 7])
    np.testing.assert_allclose(program.blocks[0].start, [5, 6, 7])
    np.testing.assert_allclose(program.end_position, [6, 6, 7])


def test_inch_units_convert_coordinates_offsets_and_feed():
    bs = blocks("G20 G1 X1 F10\nG2 X3 Y0 I1 J0\nG21 G1 X10")
    np.testing.assert_allclose(bs[0].end, [25.4, 0, 0])
    assert bs[0].feed_mm_s == pytest.approx(25.4 * 10 / 60)
    np.testing.assert_allclose(bs[1].end, [76.2, 0, 0], atol=1e-12)
    assert bs[1].length_mm == pytest.approx(math.pi * 25.4, rel=1e-9)  # half circle of radius 1 inch
    np.testing.assert_allclose(bs[2].end, [10, 0, 0])


def test_comments_line_numbers_percent_lines_and_case():
    text = "%\nN10 (setup) G21 G90 ; trailing\n( whole line )\n; whole line\nn20 g1 x5 (mid) y2 f100\n\n%\n"
    assert ends(text) == [(5, 2, 0)]


def test_words_may_be_written_without_spaces():
    assert ends("G1X5Y-2.5F100") == [(5, -2.5, 0)]


def test_m30_stops_reading_and_nothing_after_it_is_checked():
    assert ends("G1 X1 F100\nM30\nG1 X2\nthis is not G-code ###\n") == [(1, 0, 0)]
    assert ends("G1 X1 F100\nX2 M02\nX3") == [(1, 0, 0), (2, 0, 0)]


def test_spindle_and_coolant_codes_are_accepted_and_ignored():
    assert ends("M03 S1200\nG1 X1 F100 M08\nM09 M05") == [(1, 0, 0)]


def test_zero_length_moves_make_no_block():
    assert blocks("G0 X0 Y0 Z0\nG1 X0 F100\nG1 X1\nX1") and len(blocks("G0 X0 Y0 Z0\nG1 X0 F100\nG1 X1\nX1")) == 1


def test_modal_words_without_motion_make_no_block():
    assert blocks("G17 G21 G90 G94 G40 G49 G80 G54 F100") == ()


# ---- arcs ------------------------------------------------------------------------------

PLANE_CASES = {  # plane, the two plane axes, normal axis, offset letters
    "G17": ((0, 1), 2, "IJ"),
    "G18": ((2, 0), 1, "KI"),
    "G19": ((1, 2), 0, "JK"),
}


def arc_program(plane: str, g: str, a_end: float, b_end: float, centre_words: str) -> str:
    (a, b), _, _ = PLANE_CASES[plane]
    letters = "XYZ"
    return f"{plane} G1 F100\n{g} {letters[a]}{a_end:g} {letters[b]}{b_end:g} {centre_words}"


def assert_on_circle(curve: NurbsCurve, centre, radius: float) -> None:
    pts = curve_samples(curve)
    np.testing.assert_allclose(np.linalg.norm(pts - np.asarray(centre, float), axis=1), radius, atol=1e-9)


@pytest.mark.parametrize("plane", ["G17", "G18", "G19"])
@pytest.mark.parametrize("g", ["G02", "G03"])
def test_ijk_arcs_in_every_plane_end_exactly_and_turn_the_right_way(plane, g):
    (a, b), normal_axis, (oa, ob) = PLANE_CASES[plane]
    # from the origin around a centre 10 mm along the first plane axis, to (a, b) = (10, 10):
    # seen from the normal that is a quarter turn clockwise or three quarters counter-clockwise
    (block,) = blocks(arc_program(plane, g, 10.0, 10.0, f"{oa}10 {ob}0"))
    centre, end = np.zeros(3), np.zeros(3)
    centre[a] = 10
    end[a], end[b] = 10, 10
    np.testing.assert_array_equal(block.start, [0, 0, 0])
    np.testing.assert_array_equal(block.end, end)
    assert_on_circle(block.curve, centre, 10.0)
    _, d1 = block.curve.derivatives(block.curve.u_min, 1)
    turn = np.cross(block.start - centre, d1)[normal_axis]  # > 0: counter-clockwise about the normal
    assert (turn > 0) == (g == "G03")
    assert block.length_mm == pytest.approx(10 * (math.pi / 2 if g == "G02" else 3 * math.pi / 2), rel=1e-9)


@pytest.mark.parametrize("plane", ["G17", "G18", "G19"])
@pytest.mark.parametrize("g,r,expected_sweep", [("G02", 10, math.pi / 2), ("G02", -10, 3 * math.pi / 2),
                                                 ("G03", 10, math.pi / 2), ("G03", -10, 3 * math.pi / 2)])
def test_r_format_arcs_pick_the_short_or_long_arc_by_sign(plane, g, r, expected_sweep):
    (a, b), _, _ = PLANE_CASES[plane]
    (block,) = blocks(arc_program(plane, g, 10.0, 10.0, f"R{r}"))
    end = np.zeros(3)
    end[a], end[b] = 10, 10
    np.testing.assert_array_equal(block.end, end)
    assert block.length_mm == pytest.approx(10 * expected_sweep, rel=1e-9)
    # centre is one of the two points at distance 10 from start and end
    candidates = [np.where(np.arange(3) == a, 10.0, 0.0), np.where(np.arange(3) == b, 10.0, 0.0)]
    pts = curve_samples(block.curve)
    assert any(np.allclose(np.linalg.norm(pts - c, axis=1), 10.0, atol=1e-9) for c in candidates)


def test_g02_in_g17_goes_clockwise_seen_from_plus_z():
    (block,) = blocks("G17 G2 X10 Y0 I5 J0 F100")  # half circle from (0,0) to (10,0) around (5,0)
    mid = block.curve.points(0.5 * (block.curve.u_min + block.curve.u_max))
    assert mid[1] > 4.99  # clockwise from the left end passes over the top (+Y)


def test_full_circle_when_ijk_arc_ends_where_it_starts():
    for g, sign in (("G02", -1), ("G03", 1)):
        (block,) = blocks(f"G1 X5 F100\nG17 {g} X5 Y0 I-5 J0")[1:]
        np.testing.assert_array_equal(block.start, [5, 0, 0])
        np.testing.assert_array_equal(block.end, [5, 0, 0])
        assert block.length_mm == pytest.approx(2 * math.pi * 5, rel=1e-9)
        assert_on_circle(block.curve, (0, 0, 0), 5.0)
        _, d1 = block.curve.derivatives(block.curve.u_min, 1)
        assert np.sign(d1[1]) == sign


def test_arc_with_radii_differing_within_tolerance_still_ends_exactly_at_the_programmed_point():
    (block,) = blocks("G17 G3 X10.001 Y0 I5 J0 F100")  # radii 5 and 5.001 (within 0.002 mm)
    np.testing.assert_array_equal(block.start, [0, 0, 0])
    np.testing.assert_array_equal(block.end, [10.001, 0, 0])
    # the centre moves onto the chord's bisector: the arc is a half circle of radius 5.0005
    assert_on_circle(block.curve, (5.0005, 0, 0), 5.0005)


def test_incremental_arc_end_and_always_incremental_centre():
    bs = blocks("G1 X10 Y10 F100\nG91 G3 X-10 Y10 I-10 J0")
    np.testing.assert_array_equal(bs[-1].end, [0, 20, 0])
    assert_on_circle(bs[-1].curve, (0, 10, 0), 10.0)


# ---- NURBS ------------------------------------------------------------------------------

def test_g06_2_reference_example_and_omitted_first_point():
    full = blocks("G06.2 P3 K0 X0 Y0 Z0 R1 F5000\nK0 X0 Y5 Z0 R1\nK0 X5 Y5 Z0 R1\nK1\nK1\nK1")
    short = blocks("F5000\nG06.2 P3 K0\nK0 X0 Y5 Z0\nK0 X5 Y5 Z0\nK1\nK1\nK1")
    for bs in (full, short):
        (block,) = bs
        assert block.kind is BlockKind.NURBS and block.curve.degree == 2
        np.testing.assert_array_equal(block.curve.knots, [0, 0, 0, 1, 1, 1])
        np.testing.assert_array_equal(block.curve.control_points, [[0, 0, 0], [0, 5, 0], [5, 5, 0]])
        np.testing.assert_array_equal(block.curve.weights, [1, 1, 1])
        assert block.feed_mm_s == pytest.approx(5000 / 60)


def test_g06_2_default_order_is_cubic_and_missing_coordinates_keep_the_previous_point():
    text = "G1 X1 F100\nG06.2 K0\nK0 Y2\nK0 X3\nK0 Z4 R2\nK1\nK1\nK1\nK1"
    (_, block) = blocks(text)
    assert block.curve.degree == 3
    np.testing.assert_array_equal(block.curve.control_points, [[1, 0, 0], [1, 2, 0], [3, 2, 0], [3, 2, 4]])
    np.testing.assert_array_equal(block.curve.weights, [1, 1, 1, 2])


def test_g06_2_incremental_control_points_are_relative_to_the_previous_point():
    (block,) = blocks("G91 F100\nG06.2 P2 K0 X0\nK0 X1 Y1\nK1 X1\nK2\nK2")
    np.testing.assert_array_equal(block.curve.control_points, [[0, 0, 0], [1, 1, 0], [2, 1, 0]])


def test_g06_2_is_modal_consecutive_curves_and_ends_at_g01():
    text = "F100\nG06.2 P2 K0\nK0 X1\nK1\nK1\nP2 K0\nK0 Y1\nK1\nK1\nG01 X0 Y0"
    bs = blocks(text)
    assert [b.kind for b in bs] == [BlockKind.NURBS, BlockKind.NURBS, BlockKind.LINE]
    np.testing.assert_array_equal(bs[1].end, [1, 1, 0])


def test_g5_2_linuxcnc_nurbs_starts_at_the_current_position_with_clamped_uniform_knots():
    text = "G1 X1 Y1 Z3 F100\nG5.2 X2 Y3 P2 L3\nX4 Y3\nX5 Y1 P0.5\nG5.3\nG1 X0"
    bs = blocks(text)
    nurbs = bs[1]
    assert nurbs.kind is BlockKind.NURBS and nurbs.curve.degree == 2
    np.testing.assert_array_equal(nurbs.curve.control_points, [[1, 1, 3], [2, 3, 3], [4, 3, 3], [5, 1, 3]])
    np.testing.assert_array_equal(nurbs.curve.weights, [1, 2, 1, 0.5])
    np.testing.assert_allclose(nurbs.curve.knots, clamped_uniform_knots(4, 2))
    assert bs[2].kind is BlockKind.LINE


def test_blocks_without_a_programmed_feed_take_the_machines_rapid_or_default_feed():
    from nurbsmotion.program import parse_curve_yaml

    rapid, line = blocks("G0 X1\nG1 X2 F600")
    (curve,) = parse_curve_yaml("degree: 1\npoints: [[0,0],[1,0]]\n", "c.yaml").blocks
    assert rapid.feed_or_default_mm_s(100.0, 300.0) == 300.0
    assert line.feed_or_default_mm_s(100.0, 300.0) == 10.0
    assert curve.feed_or_default_mm_s(100.0, 300.0) == 100.0


def test_a_byte_order_mark_is_not_part_of_line_1():
    from nurbsmotion.program.gcode import parse_gcode

    program = parse_gcode("\ufeffG21 G90\nG01 X10 F3000\n", "bom.nc")
    assert len(program.blocks) == 1
