"""Tools, program flow and timing: T, M6, M61, G43 H / G43.1 / G49 with a tool table, G4 dwell,
M0/M1 with the optional-stop switch, M2/M30, spindle and coolant commands as program events."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.program import (CoolantMode, EventKind, ReadOptions, SpindleDirection, load_tool_table, parse_gcode,
                                 parse_tool_table)

TOOLS = parse_tool_table("tools:\n  - number: 1\n    length_mm: 50\n    diameter_mm: 6\n"
                         "  - number: 2\n    length_mm: 42.5\n    diameter_mm: 3.175\n    name: small\n", "tools.yaml")


def read(text: str, **options):
    return parse_gcode(text, "t.nc", options=ReadOptions(**options))


def test_tool_table_reads_length_and_diameter():
    assert TOOLS.get(2).length_mm == 42.5 and TOOLS.get(2).diameter_mm == 3.175 and TOOLS.get(2).name == "small"
    assert TOOLS.length_mm(0) == 0.0 and TOOLS.get(3) is None


@pytest.mark.parametrize("text,where,message", [
    ("tools:\n  - number: 1\n    length_mm: x\n    diameter_mm: 6\n", "tools.yaml:3: tools[0].length_mm", "must be a finite number"),
    ("tools:\n  - number: 0\n    length_mm: 1\n    diameter_mm: 6\n", "tools.yaml:2: tools[0].number", "from 1 to"),
    ("tools:\n  - number: 1\n    length_mm: 1\n", "tools.yaml:2: tools[0]", "missing diameter_mm"),
    ("tools:\n  - number: 1\n    length_mm: 1\n    diameter_mm: 6\n    colour: red\n", "tools.yaml:5: tools[0].colour", "unknown key"),
    ("tools:\n  - {number: 1, length_mm: 1, diameter_mm: 1}\n  - {number: 1, length_mm: 2, diameter_mm: 1}\n",
     "tools.yaml:3: tools[1].number", "listed twice"),
    ("tool: []\n", "tools.yaml:1", "one key, tools"),
    ("tools: [\n", "tools.yaml:2", "YAML syntax error"),
])
def test_tool_table_errors_name_the_line(text, where, message):
    with pytest.raises(InputError) as info:
        parse_tool_table(text, "tools.yaml")
    errors = getattr(info.value, "errors", [info.value])
    assert errors[0].where == where and message in errors[0].message


def test_missing_tool_table_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="cannot read tool table"):
        load_tool_table(tmp_path / "none.yaml")


def test_m6_is_a_holding_event_with_the_tool_and_stops_the_block_before():
    program = read("G1 X1 F100\nT2 M6\nG1 X2\nM6\nM61 Q1\nT1 M6\nG1 X3", tool_table=TOOLS)
    changes = [e for e in program.events if e.kind is EventKind.TOOL_CHANGE]
    assert [(e.tool, e.before_block, e.source.line, e.holds) for e in changes] == [(2, 1, 2, True)]
    assert program.blocks[0].exact_stop and not program.blocks[1].exact_stop
    assert program.tool_at_end == 1  # M6 of T2 again: no hold; M61 Q1 says tool 1 is in; T1 M6: nothing to change


def test_m6_of_the_tool_already_in_the_spindle_needs_no_hold():
    assert not read("T1 M6", tool_table=TOOLS, tool_in_spindle=1).events
    assert [e.tool for e in read("T1 M6", tool_table=TOOLS).events] == [1]


def test_unknown_tools_are_refused_when_there_is_a_table():
    with pytest.raises(InputError, match=r"t.nc:1: T7: tool 7 is not in the tool table tools.yaml"):
        read("T7 M6", tool_table=TOOLS)
    assert read("T7 M6").events[0].tool == 7  # without a table any tool number goes


def test_g43_h_adds_the_tool_length_to_z_in_machine_coordinates():
    program = read("G43 H1 G0 Z10\nG1 X5 F100\nG43 H2\nG1 X6\nZ10\nG49\nG1 Z10\nT2 M6 G43\nG1 Z0", tool_table=TOOLS)
    z = [round(float(b.end[2]), 9) for b in program.blocks]
    assert z == [60, 60, 60, 52.5, 10, 42.5]  # X moves keep the machine Z; the new offset applies on the next Z


def test_g43_1_dynamic_offset_and_g43_without_a_table():
    assert read("G43.1 Z5\nG0 Z1").blocks[0].end[2] == pytest.approx(6)
    assert read("G43 H0\nG0 Z1").blocks[0].end[2] == pytest.approx(1)
    with pytest.raises(InputError, match="G43.1 takes one Z word"):
        read("G43.1 X1")


def test_g4_dwell_is_an_exact_event_after_an_exact_stop():
    program = read("G1 X1 F100\nG4 P0.5\nG1 X2\nG4 P0.25\nG4 P0.25\nG1 X3")
    dwells = [(e.dwell_s, e.before_block) for e in program.events if e.kind is EventKind.DWELL]
    assert dwells == [(0.5, 1), (0.25, 2), (0.25, 2)]
    assert program.dwell_s_before() == {1: 0.5, 2: 0.5}
    assert [b.exact_stop for b in program.blocks] == [True, True, False]


def test_g4_with_a_motion_on_its_line_dwells_then_moves():
    """LinuxCNC's nc_files/skeleton.ngc: 'G04 P.001 G0 X1.0 Y1.0' (dwell, then the rapid)."""
    program = read("G1 X0.5 F100\nG04 P.001 G0 X1.0 Y1.0")
    assert [(e.kind, e.before_block) for e in program.events] == [(EventKind.DWELL, 1)]
    assert program.blocks[1].end.tolist() == [1.0, 1.0, 0.0] and program.blocks[0].exact_stop


def test_m0_pauses_m1_pauses_only_with_the_optional_stop_switch():
    text = "G1 X1 F100\nM0\nG1 X2\nM1\nG1 X3\n"
    assert [(e.code, e.before_block) for e in read(text).events] == [("M0", 1), ("M1", 2)]
    assert [e.code for e in read(text, optional_stop=False).events] == ["M0"]
    assert all(e.holds for e in read(text).events)


def test_m2_and_m30_end_the_program():
    assert len(read("G1 X1 F100\nM2\nG1 X2").blocks) == 1
    assert len(read("G1 X1 F100\nM30\nG1 X2").blocks) == 1


def test_spindle_and_coolant_commands_are_events_with_their_lines():
    program = read("S1200 M3\nG1 X1 F100 M8\nS2400\nM7\nM9 M5\nM4 S100\n")
    got = [(e.kind, e.spindle, e.spindle_rpm, e.coolant, e.source.line) for e in program.events]
    assert got == [
        (EventKind.SPINDLE, SpindleDirection.CW, 1200, None, 1),
        (EventKind.COOLANT, None, None, CoolantMode.FLOOD, 2),
        (EventKind.SPINDLE, SpindleDirection.CW, 2400, None, 3),
        (EventKind.COOLANT, None, None, CoolantMode.MIST, 4),
        (EventKind.SPINDLE, SpindleDirection.OFF, None, None, 5),
        (EventKind.COOLANT, None, None, CoolantMode.OFF, 5),
        (EventKind.SPINDLE, SpindleDirection.CCW, 100, None, 6),
    ]
    assert program.requires_spindle and program.requires_coolant
    plain = read("G1 X1 F100\nM5 M9")
    assert not plain.requires_spindle and not plain.requires_coolant


def test_events_inside_a_nurbs_definition_are_refused():
    with pytest.raises(InputError, match=r"^t.nc:3: M0: M0 inside the NURBS of line 2: finish the NURBS first$"):
        read("F100\nG06.2 P2 K0\nK0 X1 M0\nK1\nK1")


def test_summary_counts_events():
    from nurbsmotion.program.summary import summarize
    s = summarize(read("T1 M6\nS100 M3\nG1 X1 F100\nG4 P2\nM0\nM30", tool_table=TOOLS))
    assert s.events_by_kind == {"tool_change": 1, "spindle": 1, "dwell": 1, "pause": 1}
    assert s.dwell_s == 2 and s.tools == (1,) and s.requires_spindle and s.exact_stops == 1


def test_m70_m72_save_and_restore_the_modal_state():
    text = "G21 G90 F100\nM70\nG20 G91 F10\nG1 X1\nM72\nG1 X1\n"
    program = read(text)
    np.testing.assert_allclose([b.end[0] for b in program.blocks], [25.4, 1.0])
    assert [b.feed_mm_s for b in program.blocks] == pytest.approx([25.4 * 10 / 60, 100 / 60])
    with pytest.raises(InputError, match="M72 without a state saved by M70"):
        read("M70\nM71\nM72")


def test_m73_restores_the_callers_state_when_the_sub_returns():
    """As LinuxCNC's nc_files/m73-demo.ngc: the sub switches to G20 G91 and the spindle."""
    text = ("o<sub> sub\nM73\nG20 G91 F5 S300 M3\nG1 X1\no<sub> endsub\n"
            "G21 G90 F100 S1000 M3\no<sub> call\nG1 X10\n")
    program = read(text)
    np.testing.assert_allclose([b.end[0] for b in program.blocks], [25.4, 10.0])
    assert program.blocks[1].feed_mm_s == pytest.approx(100 / 60)
    assert [(e.spindle_rpm, e.source.line) for e in program.events] == [(1000, 6), (300, 3), (1000, 5)]
    with pytest.raises(InputError, match="M73 outside a subroutine"):
        read("M73")
