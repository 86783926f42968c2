"""Randomly mutated programs: each is either read into a Program or rejected with InputError.

Never any other exception, and every error line starts with the source name (file:line).
A seeded mutator keeps the run reproducible and short (a few seconds for 3000 cases).
"""

from __future__ import annotations

import random
import re
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import Program, ReadOptions, parse_curve_yaml, parse_gcode

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CASES_PER_KIND = 1500
GARBAGE = ["", "1.2.3", "abc", "1e999", "-0", "9e9", "0", "-1", "1e-300", ".", "+", "-", "1e3", "0.0000001",
           "inf", "nan", "[1, 2]", "{}", "x", "1,5", "  ", "(", ")", ";", "#", "%", "null", "true", "-25", "360"]
EXTRA_GCODE = """G17 G91 G1 X1 Y2 F100
G02 X5 Y5 R5
G03 X-5 Y0 I-2.5 J0
G18 G2 X2 Z0 I1 K0
G19 G3 Y2 Z0 J1 K0
G90 G17 G5.2 X1 Y1 P2 L3
X3 Y0
X4 Y2 P0.5
G5.3
G20 G1 X0.1 F10
G21 G0 Z1
M30
"""
EXTRA_RS274NGC = """%
O1001 (syntax of issue 16)
#<_r> = 5
#1 = [2 * #<_r>] F600
G10 L2 P2 X10 Y-5
G55 G90.1
T1 M6 G43 H0 S1000 M3 M8
o100 sub
  G1 X[#1 + ATAN[1]/[2]] Y-#<_r> F[60 * 10]
  o100 return [#1 MOD 3]
o100 endsub
o101 repeat [2]
  o100 call [#1]
  G91 G91.1 G2 X [#<_value> * 0 + 2] Y0 I1 J0 Z-1 P2
  G90
o101 endrepeat
o102 while [#1 GT 8]
  #1 = [#1 - 1]
  o103 if [#1 EQ 9]
    G4 P0.1
  o103 elseif [#1 LT 0]
    o102 break
  o103 else
    M0
  o103 endif
o102 endwhile
G64 P0.01
G61.1
/ G92 X0
G28 G91 Z0
G53 G90 G0 Z0
G18 G1 X0 Y0 Z0
G5.2 P1 L3
X3 Z1
X4 Z2 P2
G5.3
G17 G6.2 P3 K0 Q1
G6.2 X1 Y1 K0 R1
X2 Y3 K0
G6.2 K1
G6.2 K1
G6.2 K1
M30
%
"""
EXTRA_YAML = """name: two
feed_mm_min: 1200
curves:
  - degree: 1
    points: [[0,0],[1,0]]
  - degree: 2
    weights: [1, 2, 1]
    knots: [0, 0, 0, 1, 1, 1]
    points: [[1,0,0],[2,1,0],[3,0,0]]
"""
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


def mutate(text: str, rng: random.Random) -> str:
    for _ in range(rng.randint(1, 4)):
        lines = text.split("\n")
        op = rng.randrange(9)
        i = rng.randrange(len(text)) if text else 0
        if op == 0 and text:  # delete a character
            text = text[:i] + text[i + 1:]
        elif op == 1 and text:  # duplicate a character
            text = text[:i] + text[i] + text[i:]
        elif op == 2 and len(text) > 1:  # swap two neighbours
            i = min(i, len(text) - 2)
            text = text[:i] + text[i + 1] + text[i] + text[i + 2:]
        elif op == 3:  # replace a number with garbage
            numbers = list(_NUMBER.finditer(text))
            if numbers:
                m = rng.choice(numbers)
                text = text[:m.start()] + rng.choice(GARBAGE) + text[m.end():]
        elif op == 4:  # truncate a line
            j = rng.randrange(len(lines))
            lines[j] = lines[j][: rng.randrange(len(lines[j]) + 1)]
            text = "\n".join(lines)
        elif op == 5:  # delete a line
            del lines[rng.randrange(len(lines))]
            text = "\n".join(lines)
        elif op == 6:  # duplicate a line
            j = rng.randrange(len(lines))
            lines.insert(j, lines[j])
            text = "\n".join(lines)
        elif op == 7 and len(lines) > 1:  # swap two lines
            a, b = rng.sample(range(len(lines)), 2)
            lines[a], lines[b] = lines[b], lines[a]
            text = "\n".join(lines)
        else:  # insert a random character
            text = text[:i] + rng.choice("XYZIJKRFGMPLNOTHQ0123456789.-+*/ ()%;:[]{},#<>=\t\r\"'é@^") + text[i:]
    return text


def check_outcome(parse, text: str, source: str) -> bool:
    """True if accepted; asserts the rejection is a proper InputError."""
    try:
        program = parse(text, source)
    except InputError as err:
        message = str(err)
        assert message, f"empty error for {text!r}"
        for line in message.splitlines():
            assert line.startswith(source), f"{line!r} does not name {source} (input {text!r})"
        return False
    assert isinstance(program, Program)
    for a, b in zip(program.blocks, program.blocks[1:]):
        assert np.allclose(a.end, b.start, atol=1e-6)
    for block in program.blocks:
        curve = block.curve
        assert np.all(np.isfinite(curve.control_points))
        ends = curve.points(np.array([curve.u_min, curve.u_max]))  # the curve really starts/ends there
        np.testing.assert_allclose(ends, [block.start, block.end], atol=1e-9 * (1 + np.abs(ends).max()))
    return True


@pytest.mark.parametrize("kind", ["gcode", "yaml"])
def test_mutated_programs_are_accepted_or_rejected_cleanly(kind):
    rng = random.Random(20261122 + (kind == "yaml"))
    if kind == "gcode":
        seeds = [(EXAMPLES / n).read_text() for n in ("wang_table1.nc", "mixed.nc", "zhang_invalid.nc")] + [EXTRA_GCODE, EXTRA_RS274NGC]
        def parse(text: str, source: str) -> Program:  # a mutated loop may never end: stop it early
            return parse_gcode(text, source, options=ReadOptions(max_loop_lines=10_000))
        source = "fuzz.nc"
    else:
        seeds = [(EXAMPLES / n).read_text() for n in ("wang_table1.yaml", "zhang_invalid.yaml")] + [EXTRA_YAML]
        parse, source = parse_curve_yaml, "fuzz.yaml"
    accepted = 0
    for _ in range(CASES_PER_KIND):
        accepted += check_outcome(parse, mutate(rng.choice(seeds), rng), source)
    assert 0 < accepted < CASES_PER_KIND  # the mutations exercise both outcomes
