"""Starting a G-code program from line N (program.gcode_start): the modal state rebuilt from
the lines before N, the approach (spindle, coolant, up to safe Z, across, down at feed),
and the refusals, one line each naming file:N."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import (BlockKind, CoolantMode, CoordinateState, EventKind, Program, ReadOptions,
                                 SpindleDirection, parse_gcode, parse_tool_table)

TOOLS = parse_tool_table("tools:\n  - number: 2\n    length_mm: 12.5\n    diameter_mm: 3\n"
                         "  - number: 5\n    length_mm: 40\n    diameter_mm: 6\n")
G55_MM = (100.0, 50.0, -30.0)
COORDINATES = CoordinateState().with_work_offset(2, G55_MM)
SAFE_Z_MM = 60.0
START_MM = (5.0, -4.0, 20.0)

# Modal state set before line 12 in inches, G55, G92, T2 M6 G43 H2, M3 S1000, M8, F300;
# the program then mixes G91 moves, an arc and a feed change, so every piece of the state counts.
PROGRAM = """\
G20 G90 G17
G55
G0 X1 Y1 Z1
G92 X0 Y0 Z0
T2 M6
G43 H2
M3 S1000
M8
F300
G1 Z-0.1
G1 X0.5 Y0.2
G91 G1 X0.5
G2 X0.5 Y0.5 I0 J0.5
G90 G1 X2 Y2 F150
G0 Z0.5
M5 M9
M30
"""
N = 12


def read(text: str = PROGRAM, start_line: int | None = None, **options) -> Program:
    options.setdefault("tool_table", TOOLS)
    options.setdefault("coordinates", COORDINATES)
    return parse_gcode(text, "part.nc", START_MM, ReadOptions(start_line=start_line, safe_z_mm=SAFE_Z_MM, **options))


def program_blocks(program: Program):
    return [b for b in program.blocks if b.source.text != "(approach)"]


def assert_same_block(a, b):
    assert (a.kind, a.feed_mm_s, a.source, a.exact_stop, a.blend_tolerance_mm) == \
        (b.kind, b.feed_mm_s, b.source, b.exact_stop, b.blend_tolerance_mm)
    assert a.curve.degree == b.curve.degree
    for field in ("control_points", "weights", "knots"):
        np.testing.assert_allclose(getattr(a.curve, field), getattr(b.curve, field), rtol=0, atol=1e-12)


def test_from_line_n_the_blocks_are_those_of_the_whole_program_from_line_n():
    whole = read()
    started = read(start_line=N)
    expected = [b for b in whole.blocks if b.source.line >= N]
    got = program_blocks(started)
    assert len(got) == len(expected) == 4
    for a, b in zip(got, expected):
        assert_same_block(a, b)


def test_from_line_n_the_events_are_those_of_the_whole_program_from_line_n():
    whole = read()
    started = read(start_line=N)
    first_whole = next(i for i, b in enumerate(whole.blocks) if b.source.line >= N)
    first_started = len(started.blocks) - len(program_blocks(started))
    own = [e for e in started.events if e.source.text != "(approach)"]
    expected = [e for e in whole.events if e.source.line >= N]
    assert [(e.kind, e.code, e.source, e.before_block - first_started) for e in own] == \
        [(e.kind, e.code, e.source, e.before_block - first_whole) for e in expected]
    assert [e.code for e in own] == ["M5", "M9"]


def test_the_resume_state_is_the_modal_state_before_line_n():
    whole = read()
    state = read(start_line=N).resume
    assert state is not None
    assert (state.line, state.source, state.mm_per_unit, state.absolute, state.plane) == (N, "part.nc", 25.4, True, 17)
    assert state.coordinates.active_system == 2 and state.coordinates.work_offsets_mm[1] == G55_MM
    assert state.coordinates.g92_applied
    np.testing.assert_allclose(state.coordinates.g92_mm, (25.4, 25.4, 25.4), atol=1e-12)  # G92 at X1 Y1 Z1 (inch)
    assert (state.tool, state.tool_length_mm) == (2, 12.5)
    assert state.feed_mm_s == pytest.approx(300 * 25.4 / 60)
    assert (state.spindle, state.spindle_rpm, state.coolant) == (SpindleDirection.CW, 1000.0, frozenset({CoolantMode.FLOOD}))
    before_n = [b for b in whole.blocks if b.source.line < N]
    np.testing.assert_allclose(state.position_mm, before_n[-1].end, rtol=0, atol=1e-12)
    assert state.as_dict()["units"] == "inch" and state.as_dict()["coolant"] == ["flood"]


def test_the_approach_starts_tool_spindle_and_coolant_then_rises_crosses_and_feeds_down():
    started = read(start_line=N)
    state = started.resume
    assert state is not None
    approach = [b for b in started.blocks if b.source.text == "(approach)"]
    assert [b.kind for b in approach] == [BlockKind.RAPID, BlockKind.RAPID, BlockKind.LINE]
    assert all(str(b.source) == f"part.nc:{N}" for b in approach)
    up, across, down = approach
    target = np.array(state.position_mm)
    np.testing.assert_allclose(up.start, START_MM, atol=1e-12)
    np.testing.assert_allclose(up.end, (START_MM[0], START_MM[1], SAFE_Z_MM), atol=1e-12)
    np.testing.assert_allclose(across.end, (target[0], target[1], SAFE_Z_MM), atol=1e-12)
    np.testing.assert_allclose(down.end, target, atol=1e-12)
    assert down.feed_mm_s == pytest.approx(state.feed_mm_s)
    assert all(b.exact_stop for b in approach)  # no corner of the approach blended
    np.testing.assert_allclose(program_blocks(started)[0].start, target, atol=1e-12)
    first = [e for e in started.events if e.before_block == 0]
    assert [(e.kind, e.code) for e in first] == [(EventKind.TOOL_CHANGE, "M6"), (EventKind.SPINDLE, "M3"),
                                                  (EventKind.COOLANT, "M8")]
    assert first[0].tool == 2 and first[1].spindle_rpm == 1000.0 and first[2].coolant is CoolantMode.FLOOD
    assert all(e.source.text == "(approach)" for e in first)


def test_no_tool_change_when_the_tool_is_already_in_the_spindle():
    started = read(start_line=N, tool_in_spindle=2)
    assert EventKind.TOOL_CHANGE not in [e.kind for e in started.events]


def test_lines_before_n_emit_nothing_themselves():
    started = read(start_line=N)
    assert all(e.source.line >= N for e in started.events)
    assert all(b.source.line >= N for b in started.blocks)


def test_the_clearance_height_is_never_below_where_the_tool_is():
    high = (0.0, 0.0, SAFE_Z_MM + 15.0)
    started = parse_gcode("G0 X10 Z5\nG1 X20 F100\nG1 X30\n", "p.nc", high, ReadOptions(start_line=3, safe_z_mm=SAFE_Z_MM))
    across = started.blocks[0]
    assert across.kind is BlockKind.RAPID
    np.testing.assert_allclose(across.start, high)
    np.testing.assert_allclose(across.end, (20.0, 0.0, high[2]))  # no rise: already above safe Z


def test_a_spindle_turning_while_the_program_had_it_off_is_stopped_before_the_approach():
    started = parse_gcode("M5\nG0 X10\nG1 X20 F100\n", "p.nc", (0, 0, 0),
                          ReadOptions(start_line=3, safe_z_mm=SAFE_Z_MM, spindle=SpindleDirection.CW, spindle_rpm=500))
    assert [(e.code, e.spindle, e.before_block) for e in started.events] == [("M5", SpindleDirection.OFF, 0)]


def test_a_spindle_the_machine_turns_carries_over_as_in_a_whole_run():
    """The reader starts from the machine's spindle (ReadOptions.spindle): at line N it still
    turns, so the approach starts it at that speed (and waits for it)."""
    started = parse_gcode("G0 X10\nG1 X20 F100\n", "p.nc", (0, 0, 0),
                          ReadOptions(start_line=2, safe_z_mm=SAFE_Z_MM, spindle=SpindleDirection.CW, spindle_rpm=500))
    assert [(e.code, e.spindle_rpm, e.before_block) for e in started.events] == [("M3", 500.0, 0)]


def test_an_arc_at_line_n_starts_from_the_previous_end_point():
    text = "G0 X10 Y0\nG1 F100 X20\nG3 X20 Y20 R10\nG1 X0\n"
    whole = parse_gcode(text, "p.nc")
    started = parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=3, safe_z_mm=SAFE_Z_MM))
    assert_same_block(program_blocks(started)[0], whole.blocks[2])


def test_starting_at_line_one_gives_the_whole_program_after_the_approach():
    whole = read()
    started = read(start_line=1)
    for a, b in zip(program_blocks(started), whole.blocks, strict=True):
        assert_same_block(a, b)


LOOP = """\
G0 X0 Y0
#1 = 0
o100 while [#1 LT 3]
  G1 X[#1] F100
  #1 = [#1 + 1]
o100 endwhile
G1 Y10
M30
"""
SUB = """\
o<pocket> sub
  G1 X5 F100
o<pocket> endsub
G0 X0
o<pocket> call
G1 Y5 F100
M30
"""
REPEAT = "G0 X0\no7 repeat [2]\nG91 G1 X1 F100\no7 endrepeat\nG90 G1 Y3\n"
NURBS = "G0 X0 Y0\nF100\nG5.2 X0 Y1 P1 L3\nX1 Y1 P1\nX2 Y0 P1\nG5.3\nG1 X5\n"
BRANCH = "G0 X0\n#1 = 0\no1 if [#1 GT 0]\nG1 X5 F100\no1 endif\nG1 Y5 F100\n"


@pytest.mark.parametrize("text, line, says", [
    (LOOP, 4, "inside the O-word loop o100 while (lines 3-6): start at line 3 (the loop's head) or after line 6"),
    (LOOP, 6, "inside the O-word loop o100 while (lines 3-6)"),
    (REPEAT, 3, "inside the O-word loop o7 repeat (lines 2-4)"),
    (SUB, 2, "inside the body of subroutine o<pocket> (lines 1-3): start at a line of the main program"),
    (LOOP, 9, "past the end of the program: the file has 8 lines"),
    (LOOP, 40, "past the end of the program: the file has 8 lines"),
    ("G0 X1\nG1 X2 F100", 3, "past the end of the program: the file has 2 lines"),
    ("G0 X1\nM30\nG1 X5 F100\n", 3, "past the end of the program: it ends at line 2 (M2/M30)"),
    ("G0 X1\nG1 X2 F100\nM5\n(end)\n", 3, "no motion from this line on: nothing to start"),
    (NURBS, 4, "inside the NURBS of line 3: start at line 3"),
    (BRANCH, 4, "the program never runs this line"),
])
def test_refused_with_one_line_naming_file_and_line(text, line, says):
    with pytest.raises(InputError) as err:
        parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=line, safe_z_mm=SAFE_Z_MM))
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"p.nc:{line}: ") and says in message


@pytest.mark.parametrize("text, line, tail", [(LOOP, 3, 3), (LOOP, 7, 1), (SUB, 4, 2), (SUB, 6, 1), (NURBS, 3, 2),
                                             (BRANCH, 6, 1)])
def test_allowed_start_lines_next_to_the_refused_ones(text, line, tail):
    """The blocks from line N on are the whole program's last ``tail`` blocks (a call from
    line N runs its sub's lines, numbered before N)."""
    whole = parse_gcode(text, "p.nc")
    started = parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=line, safe_z_mm=SAFE_Z_MM))
    for a, b in zip(program_blocks(started), whole.blocks[-tail:], strict=True):
        assert_same_block(a, b)


def test_the_program_own_errors_come_before_a_start_line():
    with pytest.raises(InputError, match=r"p.nc:1: .*feed"):
        parse_gcode("G1 X5\nG1 X6 F100\n", "p.nc", (0, 0, 0), ReadOptions(start_line=2, safe_z_mm=SAFE_Z_MM))


@pytest.mark.parametrize("options, says", [
    (ReadOptions(start_line=0, safe_z_mm=10.0), "p.nc: start line: must be a line number >= 1, got 0"),
    (ReadOptions(start_line=2), "p.nc:2: starting from a line needs a safe Z for the approach (machine.safe_z_mm)"),
])
def test_bad_start_line_options(options, says):
    with pytest.raises(InputError) as err:
        parse_gcode("G0 X1\nG1 X2 F100\n", "p.nc", (0, 0, 0), options)
    assert str(err.value) == says


def test_a_line_in_an_if_branch_taken_can_be_the_start_line():
    text = "G0 X0\n#1 = 1\no1 if [#1 GT 0]\nG1 X5 F100\nG1 Y5\no1 else\nG1 X9 F100\no1 endif\nG1 X0\n"
    whole = parse_gcode(text, "p.nc")
    started = parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=5, safe_z_mm=SAFE_Z_MM))
    for a, b in zip(program_blocks(started), whole.blocks[1:], strict=True):
        assert_same_block(a, b)
    with pytest.raises(InputError, match=r"^p.nc:7: the program never runs this line .*start at a line it runs$"):
        parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=7, safe_z_mm=SAFE_Z_MM))


def test_percent_delimited_programs_start_from_their_line_too():
    text = "%\nG0 X1 Y1\nG1 X2 F100\nG1 Y2\n%\nG1 X50\n"
    whole = parse_gcode(text, "p.nc")
    started = parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=4, safe_z_mm=SAFE_Z_MM))
    assert_same_block(program_blocks(started)[0], whole.blocks[-1])
    assert len(program_blocks(started)) == 1
    with pytest.raises(InputError, match=r"^p.nc:6: the program never runs this line"):
        parse_gcode(text, "p.nc", (0, 0, 0), ReadOptions(start_line=6, safe_z_mm=SAFE_Z_MM))


def test_a_yaml_curve_file_has_no_start_line(tmp_path):
    from nurbsmotion.program import read_program

    path = tmp_path / "c.yaml"
    path.write_text("curves: []\n")
    with pytest.raises(InputError) as err:
        read_program(path, options=ReadOptions(start_line=2, safe_z_mm=SAFE_Z_MM))
    assert str(err.value) == f"{path}: a start line is for G-code: a YAML curve program has no lines to start from"
