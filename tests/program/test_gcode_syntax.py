"""RS274NGC syntax as LinuxCNC reads it: spaces, O program numbers, block delete, # parameters,
[expressions] with every operator and function, assignments after the line, O-word flow."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import ReadOptions, parse_gcode
from nurbsmotion.program.expressions import ExpressionError, read_value


def ends(text: str, **options):
    program = parse_gcode(text, "t.nc", options=ReadOptions(**options) if options else None)
    return [tuple(float(round(v, 9)) for v in b.end) for b in program.blocks]


def value(expr: str, params=None) -> float:
    class P:
        def get(self, key):
            return (params or {})[key]

        def exists(self, key):
            return key in (params or {})

    text = "".join(expr.split()).lower()
    e, end = read_value(text, 0)
    assert end == len(text)
    return e.evaluate(P())


def test_spaces_inside_words_and_numbers_count_nowhere():
    assert ends("G 0 1 X 1 0 Y - 2 . 5 F 1 0 0") == [(10, -2.5, 0)]
    assert ends("g1x7f100\nX 7 Y 1") == [(7, 0, 0), (7, 1, 0)]


def test_program_number_percent_and_block_delete():
    text = "%\nO1001 (PART-12)\nG1 X1 F100\n/G1 X5\nG1 X2\n%\nG1 X9\n"
    assert ends(text) == [(1, 0, 0), (2, 0, 0)]  # '/' skipped, the second % ends the program
    assert ends(text, block_delete=False) == [(1, 0, 0), (5, 0, 0), (2, 0, 0)]


@pytest.mark.parametrize("expr,expected", [
    ("[1 + 2 * 3]", 7), ("[[1 + 2] * 3]", 9), ("[2 ** 3 ** 2]", 64), ("[-2 ** 2]", 4), ("[7 MOD 3]", 1),
    ("[-7 MOD 3]", 2), ("[10 / 4]", 2.5), ("[1 - 2 - 3]", -4), ("[8 / 2 / 2]", 2),
    ("[1 EQ 1]", 1), ("[1 NE 1]", 0), ("[2 GT 1]", 1), ("[1 GE 2]", 0), ("[1 LT 2]", 1), ("[2 LE 2]", 1),
    ("[1 AND 0]", 0), ("[1 OR 0]", 1), ("[1 XOR 1]", 0), ("[1 + 1 EQ 2 AND 3 GT 2]", 1),
    ("ABS[-3]", 3), ("ACOS[0]", 90), ("ASIN[1]", 90), ("ATAN[1]/[1]", 45), ("ATAN[1]/[-1]", 135),
    ("COS[60]", 0.5), ("SIN[30]", 0.5), ("TAN[45]", 1), ("EXP[1]", math.e), ("LN[1]", 0), ("SQRT[16]", 4),
    ("FIX[-2.5]", -3), ("FUP[2.1]", 3), ("ROUND[2.5]", 3), ("ROUND[2.4]", 2), ("-[2 + 1]", -3),
    ("#1", 4), ("##2", 4), ("#<x>", 1.5), ("#[1 + 1]", 1), ("[#1 * #<x>]", 6), ("EXISTS[#<x>]", 1), ("EXISTS[#<y>]", 0),
])
def test_expressions_follow_rs274ngc(expr, expected):
    assert value(expr, {1: 4.0, 2: 1.0, "x": 1.5}) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("expr,message", [
    ("[1 / 0]", "division by zero"), ("SQRT[-1]", "SQRT[-1] is undefined"), ("LN[0]", "LN[0] is undefined"),
    ("ACOS[2]", "ACOS[2] is undefined"), ("[1 +]", "expected a number"), ("[1", "expected ']'"),
    ("ATAN[1]", "expected '/' in ATAN[y]/[x]"), ("[-8 ** 0.5]", "negative base"),
])
def test_expression_errors_say_what_is_wrong(expr, message):
    with pytest.raises(ExpressionError, match=message.replace("[", r"\[").replace("]", r"\]")):
        value(expr)


def test_parameters_set_on_a_line_take_effect_after_the_line():
    # RS274NGC 3.3.1: '#1=2 G1 X#1' moves to the old #1; the next line sees the new one
    assert ends("#1 = 1\n#1 = 2 G1 X#1 F100\nG1 X#1") == [(1, 0, 0), (2, 0, 0)]
    assert ends("#1=1\n#2=[#1+1] #1=5\nG1 X#2 Y#1 F100") == [(2, 5, 0)]


def test_named_and_numbered_parameters_with_expressions_in_words():
    text = "#<size> = 10\n#<_depth> = -1.5\n#3 = [#<size> / 2]\nG1 X[#<size> + #3] Y-#3 Z#<_depth> F[60 * 10]\n"
    program = parse_gcode(text, "t.nc")
    np.testing.assert_allclose(program.blocks[0].end, [15, -5, -1.5])
    assert program.blocks[0].feed_mm_s == pytest.approx(10)


def test_unset_numbered_parameters_read_zero_and_unset_names_are_errors():
    assert ends("G1 X[#7 + 1] F100") == [(1, 0, 0)]
    with pytest.raises(InputError, match=r"t.nc:1: X#<nope>: parameter #<nope> is not defined"):
        parse_gcode("G1 X#<nope> F100", "t.nc")


def test_system_parameters_read_offsets_and_position_and_refuse_writes():
    text = "G10 L2 P2 X5\nG55\nG1 X1 F100\n#1 = #5241\n#2 = #5420\n#3 = #5220\nG1 X[#1 + #2 + #3]\n"
    assert ends(text) == [(6, 0, 0), (13, 0, 0)]  # G55 X offset 5; X1 in G55 = #5420; #5220 = 2: X8 in G55
    with pytest.raises(InputError, match="#5221 is a system parameter"):
        parse_gcode("#5221 = 3", "t.nc")


def test_if_elseif_else():
    body = "o1 if [#1 GT 5]\nG1 X1 F100\no1 elseif [#1 GT 2]\nG1 X2 F100\no1 else\nG1 X3 F100\no1 endif\n"
    assert ends("#1=9\n" + body) == [(1, 0, 0)]
    assert ends("#1=3\n" + body) == [(2, 0, 0)]
    assert ends("#1=0\n" + body) == [(3, 0, 0)]


def test_while_do_repeat_break_continue():
    assert ends("#1=0\no2 while [#1 LT 3]\n#1=[#1+1]\nG1 X#1 F100\no2 endwhile") == [(1, 0, 0), (2, 0, 0), (3, 0, 0)]
    assert ends("#1=0\no3 do\n#1=[#1+1]\nG1 X#1 F100\no3 while [#1 LT 2]") == [(1, 0, 0), (2, 0, 0)]
    assert ends("G91 F100\no4 repeat [3]\nG1 X1\no4 endrepeat") == [(1, 0, 0), (2, 0, 0), (3, 0, 0)]
    loop = "#1=0\no5 while [1]\n#1=[#1+1]\no6 if [#1 EQ 2]\no5 continue\no6 endif\no7 if [#1 GT 3]\no5 break\no7 endif\nG1 X#1 F100\no5 endwhile\nG1 Y1"
    assert ends(loop) == [(1, 0, 0), (3, 0, 0), (3, 1, 0)]


def test_subroutines_with_arguments_locals_and_return_value():
    text = """#1 = 99
o<square> sub
  #<half> = [#1 / 2]
  G1 X#<half> Y-#<half> F100
  G1 Y#<half>
  o<square> return [#1 * 2]
  G1 X1000 (never reached)
o<square> endsub
o<square> call [4]
G1 X[#<_value>] Y#1
o100 sub
o100 endsub
o100 call
"""
    assert ends(text) == [(2, -2, 0), (2, 2, 0), (8, 99, 0)]  # #1 is the caller's again after the call


def test_recursion_and_repeat_inside_a_sub():
    text = "o10 sub\no11 if [#1 GT 0]\nG91 G1 X1 F100\no10 call [#1 - 1]\no11 endif\no10 endsub\no10 call [3]\n"
    assert ends(text) == [(1, 0, 0), (2, 0, 0), (3, 0, 0)]


def test_o_words_never_say_malformed_number():
    """Each unsupported or broken O-word gets one precise line naming the construct."""
    cases = {
        "o100 loop [1]": "unsupported: O-word 'loop'",
        "o<other> call [1]": "unsupported: O-word call of o<other>: no o<other> sub in this file",
        "o100 while [1]\no100 endrepeat": "endrepeat does not close an open o100 repeat",
        "o100 else": "else without an open o100 if",
        "G1 X1 F100\nM98 P100": "unsupported M code M98",
    }
    for text, message in cases.items():
        with pytest.raises(InputError) as info:
            parse_gcode(text, "t.nc")
        lines = str(info.value).splitlines()
        assert any(message in line for line in lines), lines
        assert not any("malformed number" in line for line in lines)


def test_an_expression_is_not_a_malformed_number():
    """The issue's example: I[25.00 ...] was 'malformed number'; now it is a value."""
    program = parse_gcode("G17 G2 X50 Y0 I[25.00] J[0] F100", "t.nc")
    np.testing.assert_allclose(program.blocks[0].end, [50, 0, 0], atol=1e-9)


def test_an_endless_loop_is_one_error_on_its_line():
    with pytest.raises(InputError, match=r"^t.nc:2: more than 10,000 lines run in loops and calls"):
        parse_gcode("#1=0\no1 while [#1 GE 0]\n#1=[#1+1]\no1 endwhile\n", "t.nc", options=ReadOptions(max_loop_lines=10_000))
    with pytest.raises(InputError, match=r"^t.nc:2: more than 10,000 lines"):
        parse_gcode("G1 F100\no1 repeat [100000]\nG91 X1\no1 endrepeat\n", "t.nc", options=ReadOptions(max_loop_lines=10_000))


def test_a_broken_o_word_line_is_named_with_the_structure_it_breaks():
    with pytest.raises(InputError) as info:
        parse_gcode("#1=1\no100 if [#1 GT\nG1 X1 F100\no100 endif\n", "t.nc")
    lines = str(info.value).splitlines()
    assert lines[0] == "t.nc:2: o100if[#1GT: a number is missing"
    assert lines[1] == "t.nc:4: o100endif: endif does not close an open o100 if"
