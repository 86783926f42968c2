"""What the machine lacks refuses the program at its line: spindle, coolant; holds pass as pause rows."""

import dataclasses
from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.config.io import IoConfig, IoSignal
from nurbsmotion.program import ReadOptions, parse_gcode
from nurbsmotion.service.planner import plan_job
from nurbsmotion.service.program_gate import check_machine_can_run
from nurbsmotion.config.spindle import SpindleConfig

ROOT = Path(__file__).resolve().parents[2]
CONFIG = load_config(ROOT / "config" / "demo.yaml")


def _errors(text: str, config=CONFIG, **options) -> list[str]:
    program = parse_gcode(text, "part.nc", options=ReadOptions(**options))
    try:
        check_machine_can_run(program, config)
    except InputError as err:
        return str(err).splitlines()
    return []


def test_spindle_on_without_a_spindle_is_refused_at_its_line():
    errors = _errors("G21 G90\nS1000 M3\nG1 X1 F600\nM4\nM5\n")
    assert errors == ["part.nc:2: M3 needs a spindle, and this machine has none (no spindle: key in "
                      f"{CONFIG.source})", f"part.nc:4: M4 needs a spindle, and this machine has none (no spindle: "
                      f"key in {CONFIG.source})"]
    stated = dataclasses.replace(CONFIG, spindle="none")
    assert _errors("M3 S100\nG1 X1 F600\n", stated)[0].endswith("has none (spindle: none in " f"{CONFIG.source})")


def test_spindle_off_and_coolant_off_alone_pass():
    assert _errors("G21 G90\nM5\nM9\nG1 X1 F600\n") == []


@pytest.mark.parametrize("outputs, m7, m8", [
    ((), None, None), (("coolant",), "coolant", "coolant"), (("mist",), "mist", None),
    (("coolant_flood",), None, "coolant_flood"), (("spindle_enable",), None, None)])
def test_coolant_needs_an_output_of_that_kind(outputs, m7, m8):
    io = IoConfig(10, outputs=tuple(IoSignal(n, i) for i, n in enumerate(outputs)))
    config = dataclasses.replace(CONFIG, io=io)
    for code, output in (("M7", m7), ("M8", m8)):
        errors = _errors(f"{code}\nG1 X1 F600\n", config)
        assert errors == [] if output is not None else len(errors) == 1  # the daemon switches the output
    if m8 is None:
        assert _errors("M8\nG1 X1 F600\n", config) == [
            f"part.nc:1: M8 needs flood coolant, and this machine has no output named coolant, flood or coolant_flood "
            f"(io.outputs in {CONFIG.source})"]


SPINDLE = dataclasses.replace(CONFIG, spindle=SpindleConfig(5, 4096, max_rpm=12000, accel_rpm_s=6000),
                              lines={**CONFIG.lines, "spindle.max_rpm": 47})


def test_with_a_spindle_m3_m4_and_s_pass_within_max_rpm():
    assert _errors("G21 G90\nS1000 M3\nG1 X1 F600\nS12000\nM4\nM5\nS20000\n", SPINDLE) == []  # S with M5: nothing


def test_with_a_spindle_s_above_max_rpm_and_m3_without_s_are_refused_at_their_line():
    assert _errors("G21\nM3\nG1 X1 F600\n", SPINDLE) == ["part.nc:2: M3 needs S (the spindle speed in rpm): no S > 0 "
                                                          "before it"]
    assert _errors("S100 M3\nG1 X1 F600\nS12500\nG1 X2\n", SPINDLE) == [
        f"part.nc:3: S12500 is above the spindle's max_rpm 12000 ({CONFIG.source}:47: spindle.max_rpm)"]
    assert _errors("S13000 M4\n", SPINDLE)[0].startswith("part.nc:1: S13000 is above the spindle's max_rpm 12000")
    assert _errors("G96 S200 M3\n", SPINDLE)[0].startswith("part.nc:1: M3 under G96")


def test_a_spindle_start_is_an_exact_stop_where_motion_waits():
    program = parse_gcode("G21 G90\nG1 X1 F600\nS1000 M3\nG1 X2\nS2000\nG1 X3\nM5\nG1 X4\n", "part.nc")
    assert [b.exact_stop for b in program.blocks] == [True, True, False, False]  # M5 does not stop motion
    assert [e.waits_for_spindle for e in program.events] == [True, True, False]


def test_holds_pass_the_gate_and_become_pause_rows_at_rest():
    text = "G21 G90\nG1 X1 F600\nT1 M6\nM0\nG1 X2\nM01\nG1 X3\n"
    assert _errors(text) == []
    job = plan_job("part.nc", text, CONFIG)
    assert [p.reason for p in job.pauses] == ["M6 tool change to T1 at part.nc:3", "M0 at part.nc:4",
                                              "M01 at part.nc:6"]
    assert [p.tool for p in job.pauses] == [1, None, None]
    for pause in job.pauses:  # the axes are at rest there: the row before holds the same position
        assert (job.counts[pause.row] == job.counts[pause.row - 1]).all()
    assert [p.row for p in plan_job("part.nc", text, CONFIG, options=ReadOptions(optional_stop=False)).pauses] \
        == [p.row for p in job.pauses[:2]]


def test_plan_job_applies_the_gate_before_planning():
    with pytest.raises(InputError, match=r"^part.nc:2: M3 needs a spindle"):
        plan_job("part.nc", "G21 G90\nM3 S8000\nG1 X1 F600\n", CONFIG)


def test_digital_outputs_m62_to_m65_are_events_with_their_output_number():
    program = parse_gcode("G21 G90\nM62 P3\nG1 X1 F600\nM65 P3\nM64 P0\nM63 P0\n", "part.nc")
    assert [(e.code, e.output, e.output_on, e.output_synchronized) for e in program.events] == [
        ("M62", 3, True, True), ("M65", 3, False, False), ("M64", 0, True, False), ("M63", 0, False, True)]
    for text, message in (("M62\n", "part.nc:1: M62: needs P: the output number"),
                          ("M64 P1.5\n", "part.nc:1: P1.5: an output number is a whole number >= 0, got 1.5"),
                          ("G4 M62 P1\n", "part.nc:1: M62: takes P, and so does the G4 on this line: write them on "
                                          "two lines")):
        with pytest.raises(InputError) as err:
            parse_gcode(text, "part.nc")
        assert str(err.value) == message


def test_a_digital_output_needs_an_io_output_at_that_bit():
    io = IoConfig(10, outputs=(IoSignal("clamp", 3),))
    assert _errors("M62 P3\nG1 X1 F600\n", dataclasses.replace(CONFIG, io=io)) == []
    assert _errors("M64 P4\n", dataclasses.replace(CONFIG, io=io)) == [
        f"part.nc:1: M64 P4: this machine has no digital output 4 (io.outputs in {CONFIG.source})"]
    assert _errors("M65 P0\n") == [f"part.nc:1: M65 P0: this machine has no digital output 0 (no io: node in "
                                   f"{CONFIG.source})"]
