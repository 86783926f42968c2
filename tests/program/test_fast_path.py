"""gcode_fast's path gives exactly what the general path gives (issue 25: reading 1,000,000
lines fast, and exactly as before): every program of the CAM corpus (tests/data/gcode), every
example, Wang's curve repeated, and edge cases, read with the fast path and with it off
(GcodeParser.fast_lines = False: every line lexed and run by the general path, the oracle),
compared block by block: kind, how the geometry is kept, the numbers (to the bit), feed,
source (file, line, text), exact stop, G64 P; the curves built from them; events, offsets,
tool, reading extent; and every error with its file:line.
"""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import Program, ReadOptions, gcode, gcode_words
from nurbsmotion.program.gcode_fast import is_fast_line, lexed_first, lines_lexed_first
from nurbsmotion.program.records import BlockRecords
from tests.program.test_corpus import TOOLS
from tests.program.test_fast_reader import texts


class GeneralParser(gcode.GcodeParser):
    fast_lines = False


def read(text: str, name: str, fast: bool, options: ReadOptions | None = None) -> Program | str:
    parser = (gcode.GcodeParser if fast else GeneralParser)(name, (1.0, -2.0, 3.0), options or ReadOptions(tool_table=TOOLS))
    try:
        return parser.parse(text)
    except InputError as err:
        return str(err)


def block_rows(program: Program) -> list[tuple]:
    out = []
    for b in program.blocks:
        curve = b.curve
        out.append((b.kind, type(b.shape).__name__, b.start.tobytes(), b.end.tobytes(), b.feed_mm_s, b.source,
                    b.exact_stop, b.blend_tolerance_mm, curve.degree, curve.control_points.tobytes(),
                    curve.weights.tobytes(), curve.knots.tobytes()))
    return out


def assert_same(text: str, name: str, options: ReadOptions | None = None) -> Program | str:
    fast, general = read(text, name, True, options), read(text, name, False, options)
    if isinstance(general, str):
        assert fast == general, name
        return general
    assert isinstance(fast, Program), (name, fast)
    assert isinstance(fast.blocks, BlockRecords) and fast.blocks == general.blocks, name
    fast_rows, general_rows = block_rows(fast), block_rows(general)
    assert len(fast_rows) == len(general_rows), name
    for i, (a, b) in enumerate(zip(fast_rows, general_rows)):
        assert a == b, (name, i, a, b)
    assert fast.events == general.events and fast.coordinates == general.coordinates, name
    assert (fast.tool_at_end, fast.resume, fast.reading) == (general.tool_at_end, general.resume, general.reading), name
    assert np.array_equal(fast.start_position, general.start_position), name
    return general


def test_every_corpus_file_and_example_reads_the_same_on_both_paths():
    outcomes = [assert_same(text, name) for name, text in texts()]
    assert sum(isinstance(o, Program) for o in outcomes) >= 45  # the comparison covers real programs
    assert sum(isinstance(o, str) for o in outcomes) >= 10  # and real refusals


def test_the_fast_path_takes_most_lines_of_the_corpus():
    lines = [ln for _, text in texts() for ln in text.split("\n") if ln.strip()]
    assert sum(map(is_fast_line, lines)) > 0.8 * len(lines)


EDGE_PROGRAMS = {
    "modal continuation": "G21 G90\nG1 X1 Y2 F300\nX3\nY4 Z-1\n Z-2 \nN10 X5\nn20x6y7\n",
    "rapids and zero moves": "G0 X1\nX1\nG1 X1 F100\nG1\nG0\nG00 Y2\nG01 Y2.0000000001 F200\n",
    "no feed": "G1 X1\nX2 F100\n",
    "no feed on a zero move": "G1\n",
    "bad feed": "F0\nG1 X1 F-5\nG1 X1 F100\n",
    "no motion mode": "X1\nF100\nG1 X2\n",
    "centre words on a line": "G1 X1 I2 F100\n",
    "out of range": "G1 X1e9 F100\nX2000000000\nX1000000000\nX1000000000.1\n",
    "inch and relative": "G20 G91 G1 X1 Y1 F10\nX-.5\nG90\nX.25\nG21 X1\n",
    "work offsets and G92": "G10 L2 P1 X10 Y20 Z30\nG54 G1 X1 F100\nG92 X0\nX5\nG92.2\nX5\nG53 G0 X0\nX1\n",
    "arcs": "G17 G1 X0 Y0 F100\nG2 X2 Y0 I1 J0\nX0 Y0 I-1 J0\nG3 X0 Y0 I1 J0\nX1 Y1 Z1 I1\nG18 G2 X2 Z1 I1 K0\n"
            "G19 G3 Y3 Z1 J.5 K0\nG17 G2 X5 Y5 I0 J0\nG2 X5 Y5 K1\nG2 X5 Y5\nG2 X10 Y0 I2 J2\nG90.1 G2 X0 Y0 I5 J0\n",
    "exact stop and tolerance": "G61 G1 X1 F100\nX2\nG64 P0.1\nX3\nG4 P1\nX4\nM0\nX5\n",
    "events between": "S1000 M3\nG1 X1 F100\nX2\nM8\nX3\nM5\nM30\nX9\n",
    "spaces and case": "g1 x1 y2 f100\nG1X2Y3\n\tX3\t Y4 \r\nX 4\nX1.5.5\n",
    "comments and block delete": "G1 X1 F100 (c)\n/X2\nX3 ; c\n%\n",
    "o-words": "o100 sub\nG1 X#1 F100\nX1 Y1\no100 endsub\no100 call [5]\nX2\no200 repeat [3]\nG91 X1\no200 endrepeat\nG90 X0\n",
    "parameters": "#1=5\nG1 X#1 F100\nX[#1+1]\nY#<_x>\n",
    "NURBS between lines": "G1 X0 Y0 F100\nG5.2 X1 Y1 P1 L3\nX2 Y0 P1\nX3 Y1 P1\nX4 Y0 P1\nG5.3\nG1 X5 Y5\n",
}


@pytest.mark.parametrize("name", sorted(EDGE_PROGRAMS))
def test_edge_programs_read_the_same_on_both_paths(name):
    assert_same(EDGE_PROGRAMS[name], f"{name}.nc")


def test_a_start_line_reads_the_same_on_both_paths():
    text = "G21 G90 G1 X0 Y0 F100\n" + "".join(f"X{i} Y{i % 3}\n" for i in range(1, 60)) + "M30\n"
    for line in (2, 17, 40):
        options = ReadOptions(start_line=line, safe_z_mm=5.0)
        assert isinstance(assert_same(text, "start.nc", options), Program)


def test_the_block_records_pickle_small():
    import pickle

    text = "G21 G90 G1 F3000\n" + "\n".join(f"X{(i % 2) * 50} Y{i * 0.01:.2f}" for i in range(20_000))
    program = read(text, "zigzag.nc", True)
    assert isinstance(program, Program) and len(program.blocks) == 20_000
    assert len(pickle.dumps(program)) < 120 * 20_000  # ~100 bytes a line (a NURBS each: ~2 KB)
    again = pickle.loads(pickle.dumps(program))
    assert block_rows(again) == block_rows(program)


def test_the_lines_left_unlexed_until_they_run_need_nothing_before():
    """GcodeParser.lex lexes up front only the lines lines_lexed_first finds; every
    other line is no O-word, no '%', not empty (what the reader needs of every line before
    running), or a lexing error; every plain line is left for gcode_fast."""
    cases = [text for _, text in texts()] + ["\n\n  \n\t\r\nX1\r\n\x0c\nG1 X1\n \u3000\nX1 \r", "X1", "", "\n", "%\nX1\n%",
                                               "G90\nX1 X2\nX1.2.3\nX\nN10\n.\nG1 X1 (c)\no100 sub\nG10 L2 P1 X0"]
    left = 0
    for text in cases:
        lines = text.split("\n")
        found = set(lines_lexed_first(text))
        assert found == {i for i, line in enumerate(lines) if lexed_first(line)}
        for i, line in enumerate(lines):
            if is_fast_line(line):
                assert i not in found, line
            if i in found:
                continue
            left += 1
            try:
                lexed = gcode_words.lex_line(i + 1, line, "t.nc")
            except InputError:
                continue
            assert lexed.oword is None and not lexed.percent and not lexed.empty and lexed.program_number is None, line
    assert left > 80_000
