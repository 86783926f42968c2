"""Helical arcs in every plane, G5.2 in G18/G19 and its first-line form, NURBS orders up to 10,
LinuxCNC's G6.2 dialect and LinuxCNC's arc radius tolerances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve, clamped_uniform_knots
from nurbsmotion.geometry.primitives import HELIX_TOLERANCE_MM, arc_curve
from nurbsmotion.program import BlockKind, parse_gcode
from nurbsmotion.program.summary import curve_samples


def helix_error_mm(curve: NurbsCurve, centre, radius, plane_axes, normal_axis, z0, rise, sweep) -> tuple[float, float]:
    """Largest distance from the cylinder and largest height error against the true helix."""
    pts = curve.points(np.linspace(curve.u_min, curve.u_max, 4001))
    a, b = plane_axes
    r = np.hypot(pts[:, a] - centre[a], pts[:, b] - centre[b])
    angle = np.unwrap(np.arctan2(pts[:, b] - centre[b], pts[:, a] - centre[a]))
    z_true = z0 + rise * np.abs(angle - angle[0]) / abs(sweep)
    return float(np.max(np.abs(r - radius))), float(np.max(np.abs(pts[:, normal_axis] - z_true)))


@pytest.mark.parametrize("plane,text,axes,normal,rise", [
    (17, "G17 G2 X10 Y0 I5 J0 Z-2 F100", (0, 1), 2, -2.0),
    (18, "G18 G3 X10 Z0 I5 K0 Y1.5 F100", (2, 0), 1, 1.5),
    (19, "G19 G2 Y10 Z0 J5 K0 X-3 F100", (1, 2), 0, -3.0),
])
def test_helical_arcs_in_every_plane_stay_on_the_cylinder_and_the_helix(plane, text, axes, normal, rise):
    block = parse_gcode(text, "t.nc").blocks[0]
    assert block.kind is BlockKind.ARC
    centre = np.zeros(3)
    centre[axes[0] if plane != 18 else 0] = 5.0
    radial, height = helix_error_mm(block.curve, centre, 5.0, axes, normal, 0.0, rise, math.pi)
    assert radial < 1e-9 and height <= HELIX_TOLERANCE_MM
    assert block.end[normal] == pytest.approx(rise)


def test_full_turn_helix_with_p_turns_and_a_fusion_style_ramp():
    block = parse_gcode("G17 G3 X5 Y0 I-5 J0 Z-3 P3 F600", "t.nc", (5, 0, 0)).blocks[0]
    expected = 3 * math.hypot(2 * math.pi * 5, 1.0)  # three turns of a helix of pitch 1 mm
    assert block.length_mm == pytest.approx(expected, rel=1e-6)
    radial, height = helix_error_mm(block.curve, np.zeros(3), 5.0, (0, 1), 2, 0.0, -3.0, 6 * math.pi)
    assert radial < 1e-9 and height <= HELIX_TOLERANCE_MM


def test_helix_segments_shrink_with_the_rise():
    flat = arc_curve((0, 0, 0), (5, 0, 0), math.pi, rise_mm=0.0)
    steep = arc_curve((0, 0, 0), (5, 0, 0), math.pi, rise_mm=20.0)
    assert len(flat.control_points) == 5 and len(steep.control_points) > len(flat.control_points)


def test_linuxcnc_arc_tolerance_accepts_rounded_inch_arcs_and_refuses_real_mismatches():
    # the inch arc: radii differ by less than the file's last digit (0.0001 in = 0.00254 mm)
    inch = parse_gcode("G20 G17 G0 X0 Y0\nG2 X1.0001 Y0 I0.5 J0 F10", "t.nc")
    assert inch.blocks[-1].kind is BlockKind.ARC
    # LinuxCNC: 2 sqrt(2) 0.001 in = 0.0718 mm absolute in G20 ...
    parse_gcode("G20 G2 X1.0025 Y0 I0.5 J0 F10", "t.nc")
    with pytest.raises(InputError, match="inconsistent arc radius"):
        parse_gcode("G20 G2 X1.003 Y0 I0.5 J0 F10", "t.nc")
    # ... and 0.0283 mm in G21; beyond that 0.1 % of the radius up to 100 times the absolute
    parse_gcode("G21 G2 X10.028 Y0 I5 J0 F10", "t.nc")
    with pytest.raises(InputError, match="inconsistent arc radius"):
        parse_gcode("G21 G2 X10.03 Y0 I5 J0 F10", "t.nc")
    parse_gcode("G21 G2 X2001 Y0 I1000 J0 F10", "t.nc")  # 1 mm on r = 1000 mm: 0.1 %


def test_accepted_mismatched_arcs_still_end_exactly_at_the_programmed_point():
    block = parse_gcode("G20 G2 X1.0025 Y0 I0.5 J0 F10", "t.nc").blocks[0]
    np.testing.assert_allclose(block.end, [1.0025 * 25.4, 0, 0], atol=1e-12)


@pytest.mark.parametrize("plane,words,point", [
    ("G18", "X1 Z2", (1, 0, 2)), ("G19", "Y1 Z2", (0, 1, 2)), ("G17", "X1 Y2", (1, 2, 0)),
])
def test_g5_2_works_in_every_plane(plane, words, point):
    text = f"{plane} G1 X0 Y0 Z0 F100\nG5.2 {words.replace('1', '3').replace('2', '0')} L3\n{words}\nG5.3\n"
    block = parse_gcode(text, "t.nc").blocks[-1]
    np.testing.assert_allclose(block.end, point, atol=1e-12)


def test_g5_2_first_line_form_gives_the_weight_of_the_current_position():
    """LinuxCNC's documented example: 'G5.2 P1 L3' then X Y P lines."""
    text = "G0 X0 Y0\nF10\nG5.2 P2 L3\nX0 Y1 P1\nX2 Y2 P1\nX2 Y0 P1\nX0 Y0 P2\nG5.3\n"
    block = parse_gcode(text, "t.nc").blocks[-1]
    np.testing.assert_allclose(block.curve.weights, [2, 1, 1, 1, 2])
    np.testing.assert_allclose(block.curve.control_points[0], [0, 0, 0])


def test_nurbs_orders_up_to_ten():
    points = [(i, (-1) ** i, 0) for i in range(1, 12)]
    body = "\n".join(f"X{x} Y{y}" for x, y, _ in points)
    block = parse_gcode(f"F100\nG5.2 L10\n{body}\nG5.3\n", "t.nc").blocks[0]
    assert block.curve.degree == 9
    knots = "\n".join(f"K{k:g} X{x} Y{y}" for k, (x, y, _) in zip(clamped_uniform_knots(12, 9)[1:], points))
    fanuc = parse_gcode(f"F100\nG6.2 P10 K0\n{knots}\n" + "K1\n" * 10, "t.nc").blocks[0]
    assert fanuc.curve.degree == 9


def test_linuxcnc_g6_2_dialect_with_q_and_repeated_g6_2_on_the_closing_blocks():
    """As in LinuxCNC's nc_files/nurbs/G6: Q on the first block, G6.2 repeated on the K blocks."""
    text = ("G21 G90 G0 X10 Y0\nF290\nG6.2 X10 Y0 R1 K0 P3 Q1\n X12 Y4 R1 K0\n X16 Y4 R1 K0\n X18 Y0 R1 K1\n"
            "G6.2 K2\nG6.2 K2\nG6.2 K2\nG1 X0\n")
    program = parse_gcode(text, "t.nc")
    assert [b.kind for b in program.blocks] == [BlockKind.RAPID, BlockKind.NURBS, BlockKind.LINE]
    np.testing.assert_allclose(program.blocks[1].end, [18, 0, 0])


def test_linuxcnc_g6_2_in_g18_reads_z_x_control_points():
    text = "G18 G0 Z1 X2\nF100\nG6.2 Z1 X2 R1 K0 P2 Q2\nZ5 X2 R1 K0\nZ5 X6 R1 K1\nG6.2 K2\nG6.2 K2\n"
    np.testing.assert_allclose(parse_gcode(text, "t.nc").blocks[-1].end, [6, 0, 5])


def test_helix_bounding_box_in_summary():
    from nurbsmotion.program.summary import summarize
    s = summarize(parse_gcode("G17 G2 X10 Y0 I5 J0 Z-2 F100", "t.nc"))
    assert s.bbox_min_mm[2] == pytest.approx(-2) and s.bbox_max_mm[1] == pytest.approx(5, abs=1e-6)
    assert len(curve_samples(parse_gcode("G17 G2 X10 Y0 I5 J0 Z-2 F100", "t.nc").blocks[0].curve)) > 64
