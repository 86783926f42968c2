"""Every rejected input: one error naming file:line and the offending word, and no Program."""

from __future__ import annotations

import pytest

from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.program import parse_curve_yaml, parse_gcode

GCODE_ERRORS = [
    # (program, where, message fragment)
    ("F100\nG06.2 P2 K0\nK0 X1\nK1 X2\nK0.5\nK1", "t.nc:5: K0.5", "knots must not decrease"),
    ("F100\nG06.2 P2 K0\nK0.2 X1\nK1\nK1", "t.nc:3: K0.2", "start not clamped"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK0.5\nK0.7", "t.nc:4: K0.5", "end not clamped"),
    ("F100\nG06.2 P2 K0\nK0 X1 R-1\nK1\nK1", "t.nc:3: R-1", "weights must be > 0"),
    ("F100\nG06.2 P2 K0 R0\nK0 X1\nK1\nK1", "t.nc:2: R0", "weights must be > 0"),
    ("F100\nG06.2 P2 K0\nK0 X1 R1e999\nK1\nK1", "t.nc:3: R1e999", "not finite"),
    ("F100\nG06.2 P11 K0", "t.nc:2: P11", "order must be an integer from 2 to 10"),
    ("F100\nG06.2 P1 K0", "t.nc:2: P1", "order must be"),
    ("F100\nG06.2 P3.5 K0", "t.nc:2: P3.5", "order must be"),
    ("F100\nG06.2 P3 K0\nK0 X1\nK1\nK1\nK1", "t.nc:2: P3", "needs at least 3 control points"),
    ("F100\nG06.2 P2 K0\nK0 X0\nK1\nK1", "t.nc:3", "zero-length NURBS"),
    ("G1 X5 F100\nG06.2 P2 K0 X0 Y0\nK0 X1\nK1\nK1", "t.nc:2: X0", "must be the current position (5, 0, 0)"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK1\nG01 X0", "t.nc:5: G01", "missing K blocks"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK1", "t.nc:4", "missing K blocks: the program ends"),
    ("F100\nG06.2 P2 K0\nX1 Y1\nK1\nK1", "t.nc:3", "K missing"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK1\nK1 X3", "t.nc:5: X3", "control point after a closing K block"),
    ("F100\nG06.2 P2 K0\nK0 X1 F200", "t.nc:3: F200", "F inside a NURBS definition"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK0 X2\nK1\nK1", "t.nc:4: K0", "start knot 0 repeats more than 2"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK1 X2\nK1\nK1", "t.nc:4: K1", "end knot 1 repeats more than 2"),
    ("F100\nG06.2 P2 K0\nK0 X1 R1e-7\nK1\nK1", "t.nc:3: R1e-7", "weights must be between 1e-06 and 1e+06"),
    ("F100\nG06.2 P2 K0\nK0 X1\nK1e-12 X2\nK1\nK1", "t.nc:4: K1e-12", "too close to knot 2"),
    ("G81 X1 Y1 Z-1 R1 F100", "t.nc:1: G81", "unsupported G code G81 (canned cycle)"),
    ("G41 D1", "t.nc:1: G41", "unsupported G code G41 (cutter radius compensation)"),
    ("G43 H1", "t.nc:1: H1", "G43 needs a tool table for tool 1"),
    ("H1", "t.nc:1: H1", "H without G43"),
    ("G4", "t.nc:1: G4", "G4 needs P"),
    ("G1 X0 F100\nG04 X1.5", "t.nc:2: X1.5", "G4 takes P, the dwell in seconds"),
    ("G4 P-1", "t.nc:1: P-1", "dwell time must be >= 0"),
    ("G10 L1 P1 Z5", "t.nc:1: L1", "unsupported: G10 L1"),
    ("G10 L2 P12 X1", "t.nc:1: P12", "P1..P9"),
    ("G92", "t.nc:1: G92", "G92 needs at least one axis word"),
    ("G1 G92 X1 F100", "t.nc:1: G1", "both use the axis words"),
    ("G91 G53 G0 X1", "t.nc:1: G53", "G53 needs G90"),
    ("G53 G2 X1 I1 F100", "t.nc:1: G53", "G53 needs G0 or G1"),
    ("G1 X1 A5 F100", "t.nc:1: A5", "unsupported: axis A"),
    ("M60", "t.nc:1: M60", "unsupported M code"),
    ("M61", "t.nc:1: M61", "M61 needs Q"),
    ("T1.5", "t.nc:1: T1.5", "a tool number is a whole number"),
    ("M3 S-5", "t.nc:1: S-5", "spindle speed must be >= 0"),
    ("G64 P-1", "t.nc:1: P-1", "G64 P is a tolerance"),
    ("G2 X1 I0.5 P0 F100", "t.nc:1: P0", "P (turns) must be a whole number >= 1"),
    ("G1.5 X1", "t.nc:1: G1.5", "unsupported G code"),
    ("M3 M5", "t.nc:1: M5", "M5 and M3 in one block: both set the spindle"),
    ("E1", "t.nc:1: E1", "unsupported word E"),
    ("#1=5+1", "t.nc:1: #1=5+", "write the expression in brackets"),
    ("G1 X[1+] F100", "t.nc:1: X[1+]", "expected a number, parameter or [expression]"),
    ("G1 X[1/0] F100", "t.nc:1: X[1/0]", "division by zero"),
    ("G1 X[SQRT[-1]] F100", "t.nc:1: X[SQRT[-1]]", "SQRT[-1] is undefined"),
    ("G1 X#<nope> F100", "t.nc:1: X#<nope>", "parameter #<nope> is not defined"),
    ("G1 X[1 F100", "t.nc:1: X[1", "expected ']'"),
    ("o100 if [1]\nG0 X1", "t.nc:1: o100if[1]", "o100 if is never closed with o100 endif"),
    ("o100 endif", "t.nc:1: o100endif", "endif does not close an open o100 if"),
    ("o<missing> call", "t.nc:1: o<missing>call", "unsupported: O-word call of o<missing>: no o<missing> sub in this file"),
    ("o100 loop", "t.nc:1: o100loop", "unsupported: O-word 'loop'"),
    ("o100 break", "t.nc:1: o100break", "break outside an o100 loop"),
    ("G1 X1.2.3 F100", "t.nc:1: X1.2.3", "malformed number"),
    ("G1 Xabc F100", "t.nc:1: X", "X needs a number, got 'abc'"),
    ("G1 X F100", "t.nc:1: X", "X needs a number"),
    ("G1 X1e999 F100", "t.nc:1: X1e999", "not finite"),
    ("G1 X1,5 F100", "t.nc:1: X1,5", "malformed number"),
    ("G1 X1 F0", "t.nc:1: F0", "feed must be > 0"),
    ("G1 X1 F-5", "t.nc:1: F-5", "feed must be > 0"),
    ("G1 X1", "t.nc:1", "no feed rate: F missing"),
    ("G2 X1 I0.5", "t.nc:1", "no feed rate: F missing"),
    ("G17 G2 X10 Y0 I4 J0 F100", "t.nc:1: I4 J0", "inconsistent arc radius: 4 mm at the start, 6 mm at the end"),
    ("G17 G2 X10 Y0 I5.03 J0 F100", "t.nc:1: I5.03 J0", "inconsistent arc radius: 5.03 mm at the start, 4.97 mm"),
    ("G17 G2 X10 Y0 R4 F100", "t.nc:1: R4", "too small for the chord"),
    ("G17 G2 X0 Y0 R4 F100", "t.nc:1: R4", "end point different from the start"),
    ("G17 G2 X10 Y0 I5 R5 F100", "t.nc:1: R5", "either R or I J K"),
    ("G17 G2 X10 Y0 F100", "t.nc:1: G2", "an arc needs centre offsets I J or a radius R"),
    ("G17 G2 X10 Y0 K5 F100", "t.nc:1: K5", "K not allowed in a G17 arc"),
    ("G1 X1 I3 F100", "t.nc:1: I3", "I not allowed in a G01 block"),
    ("G0 X1 R3", "t.nc:1: R3", "R not allowed in a G00 block"),
    ("G1 X1 X2 F100", "t.nc:1: X2", "X appears twice"),
    ("G0 G1 X1 F100", "t.nc:1: G1", "both set the motion"),
    ("X1", "t.nc:1: X1", "no motion mode"),
    ("G1 X1 (comment F100", "t.nc:1", "comment '(' is not closed"),
    ("G1 X1 ) F100", "t.nc:1", "')' without an opening"),
    ("G1 X1 F100 $", "t.nc:1: $", "unexpected character '$'"),
    ("G5.3", "t.nc:1: G5.3", "G5.3 without an open G5.2"),
    ("F100\nG5.2 X1 Y1\nX2 Y0\nX3 Y3", "t.nc:4", "not closed with G5.3"),
    ("F100\nG5.2 X1 Y1\nG1 X0", "t.nc:3: G1", "close the NURBS with G5.3 first"),
    ("F100\nG5.2 X1 Y1 Z1", "t.nc:2: Z1", "Z not allowed in a G5.2 block"),
    ("F100\nG5.2 X1 Y1 L3\nG5.3", "t.nc:3", "needs at least 3 control points"),
    ("F100\nG5.2 X1 Y1\nX2 Y0 P0\nG5.3", "t.nc:3: P0", "weights must be > 0"),
    ("F100\nG18 G5.2 X1 Y1", "t.nc:2: Y1", "Y not allowed in a G5.2 block"),
    ("F100\nG5.2 X1 Y1\nX2 Y0 L4\nG5.3", "t.nc:3: L4", "L only allowed on the G5.2 line"),
    ("F100\nG06.2 P2 K0 Q4", "t.nc:2: Q4", "must be 1, 2 or 3"),
    ("G20 G21 G1 X1 F1", "t.nc:1: G21", "both set the units"),
    ("G1 X2e9 F100", "t.nc:1: X2e9", "out of range"),
]


def line_of(where: str) -> int:
    return int(where.split(":")[1].split()[0])


def assert_rejected(parse, text: str, source: str, where: str, fragment: str) -> None:
    """One error names ``where`` and says ``fragment``; every line names the source; the
    errors come in line order."""
    with pytest.raises(InputError) as info:
        parse(text, source)
    errors = getattr(info.value, "errors", [info.value])
    assert any(e.where == where and fragment in e.message for e in errors), [str(e) for e in errors]
    assert all("\n" not in e.message for e in errors)
    assert all(line.startswith(f"{source}:") for line in str(info.value).splitlines())
    numbered = [line_of(e.where) for e in errors if e.where.count(":")]
    assert numbered == sorted(numbered)


@pytest.mark.parametrize("text,where,fragment", GCODE_ERRORS, ids=[e[1] + " " + e[2] for e in GCODE_ERRORS])
def test_gcode_error_names_line_and_word(text, where, fragment):
    assert_rejected(parse_gcode, text, "t.nc", where, fragment)


def test_every_bad_line_is_reported_in_one_run():
    text = "G1 X1 F100\nG1 Xbad\nG4 P1\nT1 M6 G43 H1\nG1 X2 Q3\nM06 M0\nG81 X1\n"
    with pytest.raises(InputErrors) as info:
        parse_gcode(text, "t.nc")
    assert [e.where for e in info.value.errors] == ["t.nc:2: X", "t.nc:4: H1", "t.nc:5: Q3", "t.nc:7: G81"]


def test_the_error_list_stops_at_the_limit():
    from nurbsmotion.program import ReadOptions
    text = "\n".join(f"G1 X{i} Q1 F100" for i in range(1, 80))
    with pytest.raises(InputErrors) as info:
        parse_gcode(text, "t.nc", options=ReadOptions(max_errors=50))
    lines = str(info.value).splitlines()
    assert len(lines) == 51 and lines[-1] == "t.nc: stopped after 50 problems; fix these and check again"
    assert lines[0].startswith("t.nc:1: Q1:") and lines[49].startswith("t.nc:50: Q1:")


def test_a_nurbs_cut_short_also_reports_its_bad_values():
    """Too few closing K blocks hides nothing: zero weights and decreasing knots are named too."""
    text = "F100\nG06.2 P3 K0 R0\nK0 X1 R0\nK0 X2\nK1 X3\nK0.5 X4\nK2\nG01 X0\n"
    with pytest.raises(InputErrors) as info:
        parse_gcode(text, "t.nc")
    assert [(e.where, e.message.split(";")[0].split(":")[0]) for e in info.value.errors] == [
        ("t.nc:2: R0", "weight 1 is 0"), ("t.nc:3: R0", "weight 2 is 0"),
        ("t.nc:6: K0.5", "knot 5 (0.5) is less than knot 4 (1)"), ("t.nc:8: G01", "missing K blocks")]


def test_all_problems_of_one_nurbs_are_reported_each_on_its_line():
    text = "F100\nG06.2 P2 K0 R0\nK2 X1 R-3\nK1 X2\nK3\nK3"
    with pytest.raises(InputErrors) as info:
        parse_gcode(text, "t.nc")
    assert [e.where for e in info.value.errors] == ["t.nc:2: R0", "t.nc:3: R-3", "t.nc:4: K1"]
    assert len(str(info.value).splitlines()) == 3


YAML_ERRORS = [
    # (yaml text, where, message fragment); line numbers are 1-based
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nknots: [0,0,0,1,0.5,1]\n", "c.yaml:3: knots[4]", "knots must not decrease"),
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nknots: [0,0,0,1,1]\n", "c.yaml:3: knots", "need 6 knots"),
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nknots: [0,0,0.1,1,1,1]\n", "c.yaml:3: knots[2]", "start not clamped"),
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nweights:\n  - 1\n  - 0\n  - 1\n", "c.yaml:5: weights[1]", "weights must be > 0"),
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nweights: [1, .inf, 1]\n", "c.yaml:3: weights[1]", "must be a finite number"),
    ("degree: 2\npoints: [[0,0,0],[1,0,0],[2,1,0]]\nweights: [1, 1]\n", "c.yaml:3: weights", "need one weight per control point"),
    ("degree: 2\npoints: [[0,0],[1,0],[2,1],[3,0]]\nknots: [0,0,0,1,1,1,1]\n", "c.yaml:3: knots[3]",
     "end knot 1 repeats more than 3"),
    ("degree: 0\npoints: [[0,0,0],[1,0,0]]\n", "c.yaml:1: degree", "degree must be between 1 and 9"),
    ("degree: 12\npoints: [[0,0,0],[1,0,0]]\n", "c.yaml:1: degree", "degree must be between 1 and 9"),
    ("degree: 2.5\npoints: [[0,0,0],[1,0,0]]\n", "c.yaml:1: degree", "must be an integer"),
    ("degree: 3\npoints:\n  - [0,0,0]\n  - [1,0,0]\n", "c.yaml:2: points", "needs at least 4 control points"),
    ("degree: 1\npoints:\n  - [0,0,0]\n  - [1,0]\n  - [1,0,0,4]\n", "c.yaml:5: points[2]", "a point is [x, y] or [x, y, z]"),
    ("degree: 1\npoints:\n  - [0,0,0]\n  - [1,x,0]\n", "c.yaml:4: points[1][1]", "must be a number, got 'x'"),
    ("degree: 1\npoints: [[0,0,0],[0,0,0]]\n", "c.yaml:2: points[1]", "zero-length NURBS"),
    ("degree: 1\npoints: [[0,0,0],[1,0,0]]\nfeed_mm_min: 0\n", "c.yaml:3: feed_mm_min", "must be > 0"),
    ("degree: 1\npoints: [[0,0,0],[1,0,0]]\nfeedrate: 5\n", "c.yaml:3: feedrate", "unknown key 'feedrate'"),
    ("points: [[0,0,0],[1,0,0]]\n", "c.yaml:1: degree", "missing (required)"),
    ("degree: 1\npoints: [[0,0,0],[1,0,0]\n", "c.yaml:3", "YAML syntax error"),
    ("", "c.yaml:1", "empty curve file"),
    ("- 1\n- 2\n", "c.yaml:1", "must be a mapping"),
    ("curves:\n  - degree: 1\n    points: [[0,0,0],[1,0,0]]\n  - degree: 1\n    points: [[2,0,0],[3,0,0]]\n",
     "c.yaml:5: curves[1].points[0]", "does not start where curves[0] ends"),
    ("curves:\n  - degree: 1\n    points: [[0,0,0],[1,0,0]]\n    weights: [1, -2]\n",
     "c.yaml:4: curves[0].weights[1]", "weights must be > 0"),
    ("curves: []\n", "c.yaml:1: curves", "must not be empty"),
]


@pytest.mark.parametrize("text,where,fragment", YAML_ERRORS, ids=[e[1] + " " + e[2] for e in YAML_ERRORS])
def test_yaml_error_names_line_and_field(text, where, fragment):
    assert_rejected(parse_curve_yaml, text, "c.yaml", where, fragment)


# A curve that stops dead (zero parametric speed) cannot be interpolated at any feed: the
# planners divide by |x'|. Found by feeding mutated programs to the planners (issue 9).
@pytest.mark.parametrize(
    "text, where, fragment",
    [
        ("G21 G90 G01 X0 Y0 F600\nG06.2 P3 K0 X0 Y0 Z0\nK0 X5 Y5 Z0\nK0 X5 Y5 Z0\nK0.5 X10 Y0 Z0\nK1\nK1\nK1\n",
         "t.nc:4", "control point 3 repeats control point 2"),
        ("G21 G90 G1 X1 Y2 F100\nG5.2 X1 Y1 P2 L3\nX3 Y0\nX4 Y2 P0.5\nX4 Y2 P0.5\nG5.3\n",
         "t.nc:5", "control point 5 repeats control point 4"),
        # folds back on itself: x(t) = 2t(1-t) (10, 0, 0) has x' = 0 at t = 1/2
        ("G21 G90 G01 X0 Y0 F600\nG06.2 P3 K0 X0 Y0 Z0\nK0 X10 Y0 Z0\nK0 X0 Y0 Z0\nK1\nK1\nK1\n",
         "t.nc:3", "zero speed, a cusp"),
    ],
)
def test_curves_that_stop_dead_are_rejected_naming_the_line(text, where, fragment):
    assert_rejected(parse_gcode, text, "t.nc", where, fragment)


@pytest.mark.parametrize("text, message", [
    ("G21\no100 sub\no200 sub\no200 endsub\no100 endsub\n", "p.nc:3: o200sub: a sub cannot be defined inside another sub"),
    ("G21\n#1=6001\n#[#1]=1\n", "p.nc:3: #[#1]=1: parameter number must be a whole number from 1 to 5602, got 6001"),
    ("G21 (a (b) c)\n", "p.nc:1: nested comments are not supported"),
    ("G21 G17 G90 F100\nG2 X0 Y0 R5\n", "p.nc:2: R5: an R arc needs an end point different from the start"),
    ("G21 G17 F100\nG2 X5 Y0 R0\n", "p.nc:2: R0: arc radius must not be zero"),
    ("G21 G17 F100\nG2 X5 Y0 I0 J0\n", "p.nc:2: I0 J0: arc radius is zero (the centre is at the start point)"),
])
def test_error_table_rows_for_subs_parameters_comments_and_zero_radii(text, message):
    """Rows of docs/programs.md's error table, each as the one line a user reads."""
    with pytest.raises((InputError, InputErrors)) as info:
        parse_gcode(text, "p.nc")
    assert str(info.value).splitlines()[0].startswith(message)
