"""The LinuxCNC race's pieces that need no LinuxCNC (benchmarks/linuxcnc_peer.py): the INI
and HAL it generates, halsampler's output, rs274's canonical calls and the program text
both planners read."""

from __future__ import annotations

import configparser
import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks.linuxcnc_peer import (RaceLimits, RunFiles, SamplesError, canon_resolution_mm, hal_text, ini_text,
                                      parse_canon, parse_samples, with_tolerance)

# halsampler -t of a cfg=ffff sampler: tag, X, Y, Z, current-vel; rest, three moving samples, rest
SAMPLES = """\
100 0.000000 0.000000 0.000000 0.000000
101 0.000000 0.000000 0.000000 0.000000
102 0.001250 0.000000 0.000000 2.500000
103 0.005000 0.000000 0.000000 5.000000
104 0.005000 0.001000 0.000000 1.000000
105 0.005000 0.001000 0.000000 0.000000
106 0.005000 0.001000 0.000000 0.000000
"""

CANON = """\
    1 N..... USE_LENGTH_UNITS(CANON_UNITS_MM)
    2 N..... SET_G5X_OFFSET(1, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
    3 N..... STRAIGHT_TRAVERSE(1.0000, 2.0000, 3.0000, 0.0000, 0.0000, 0.0000)
    4 N..... USE_LENGTH_UNITS(CANON_UNITS_INCHES)
    5 N..... SET_G5X_OFFSET(1, 1.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
    6 N..... SET_FEED_RATE(24.0000)
    7 N..... STRAIGHT_FEED(1.0000, -1.0000, 0.5000, 0.0000, 0.0000, 0.0000)
    8 N..... ARC_FEED(1.6133, -1.1787, 0.0119, 0.0161, -1, -0.1000, 0.0000, 0.0000, 0.0000)
    9 N..... USE_TOOL_LENGTH_OFFSET(0.0000 0.0000 0.0000, 0.0000, 0.0000, 0.0000)
    9 N..... SELECT_PLANE(CANON_PLANE_XZ)
   10 N..... ARC_FEED(1.0000, 1.0000, 0.0000, 0.0000, 1, 0.0000, 0.0000, 0.0000, 0.0000)
"""


def ini_for(tmp_path: Path) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(inline_comment_prefixes=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(ini_text(RaceLimits(), RunFiles.inside(tmp_path), 90.0, Path("/x/display.py")))
    return parser


def test_ini_has_the_race_limits_per_axis_and_on_the_trajectory(tmp_path):
    ini = ini_for(tmp_path)
    assert ini["EMCMOT"]["SERVO_PERIOD"] == "1000000"
    assert ini["TRAJ"]["MAX_LINEAR_VELOCITY"] == "200"
    assert ini["TRAJ"]["MAX_LINEAR_ACCELERATION"] == "2500"
    assert ini["TRAJ"]["ARC_BLEND_ENABLE"] == "1" and ini["TRAJ"]["NO_FORCE_HOMING"] == "1"
    assert ini["KINS"]["KINEMATICS"] == "trivkins" and ini["KINS"]["JOINTS"] == "3"
    for section in ("AXIS_X", "AXIS_Y", "AXIS_Z", "JOINT_0", "JOINT_1", "JOINT_2"):
        assert float(ini[section]["MAX_ACCELERATION"]) == pytest.approx(2500 / math.sqrt(2), abs=1e-4)
        assert float(ini[section]["MAX_VELOCITY"]) == 200
    assert ini["DISPLAY"]["DISPLAY"] == "/x/display.py"
    assert ini["RACE"]["PROGRAM"] == str(tmp_path / "program.ngc")
    assert ini["RACE"]["SAMPLES"] == str(tmp_path / "samples.txt") and ini["RACE"]["TIMEOUT_S"] == "90"
    assert ini["HAL"]["HALFILE"] == "race.hal"


def test_hal_loops_the_joints_back_and_samples_axis_commands_and_speed():
    lines = hal_text(depth=1000).splitlines()
    assert "loadrt sampler depth=1000 cfg=ffff" in lines
    for j in range(3):
        assert f"net j{j}pos joint.{j}.motor-pos-cmd => joint.{j}.motor-pos-fb" in lines
    for i, axis in enumerate("xyz"):
        assert f"net {axis}cmd axis.{axis}.pos-cmd => sampler.0.pin.{i}" in lines
    assert "net speed motion.current-vel => sampler.0.pin.3" in lines
    functions = [line.split()[1] for line in lines if line.startswith("addf")]
    assert functions == ["motion-command-handler", "motion-controller", "sampler.0"]  # sampled after the motion


def test_samples_give_positions_speed_and_the_moving_span():
    samples = parse_samples(SAMPLES)
    assert samples.position_mm.shape == (7, 3) and samples.speed_mm_s[3] == 5.0
    assert samples.moving_span() == (2, 4)
    assert samples.motion_cycles() == 3
    assert samples.moving_positions()[0] == pytest.approx([0, 0, 0])
    assert samples.moving_positions()[-1] == pytest.approx([0.005, 0.001, 0])
    assert parse_samples("1 0 0 0 0\n2 0 0 0 0\n").moving_span() is None


@pytest.mark.parametrize("text, message", [
    (SAMPLES.replace("103 ", "overrun\n103 "), "s.txt:4: sampler FIFO overrun"),
    (SAMPLES.replace("104 ", "105 ", 1), "s.txt:5: sample 105 follows 103 (1 lost)"),
    (SAMPLES.replace("103 ", "109 "), "s.txt:4: sample 109 follows 102 (6 lost)"),
    ("1 0 0 0\n", "s.txt:1: expected 'tag x y z v'"),
    ("1 0 0 zero 0\n", "s.txt:1: not numbers"),
])
def test_lost_or_bad_samples_are_one_error_naming_the_line(text, message):
    with pytest.raises(SamplesError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        parse_samples(text, "s.txt")


def test_canon_end_points_in_machine_millimetres():
    moves = parse_canon(CANON)
    assert [m.kind for m in moves] == ["STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "ARC_FEED"]  # the XZ arc is left out
    ends = np.array([m.end_mm for m in moves])
    assert ends[0] == pytest.approx([1, 2, 3])
    assert ends[1] == pytest.approx([2 * 25.4, -25.4, 0.5 * 25.4])
    assert ends[2] == pytest.approx([2.6133 * 25.4, -1.1787 * 25.4, -0.1 * 25.4])
    assert canon_resolution_mm(CANON) == pytest.approx(0.5e-4 * 25.4 * math.sqrt(3))


def test_tolerance_line_goes_first_and_replaces_the_programs_own():
    text = "G21 G64 P0.005 Q0.1\nG1 X1 F100\ng64\nG640 (not a G64)\nG64.1\nM2\n"
    out = with_tolerance(text, 0.01)
    assert out.splitlines() == ["G64 P0.01", "G21 G64 P0.01", "G1 X1 F100", "G64 P0.01", "G640 (not a G64)",
                                "G64.1", "M2"]


def test_tolerance_in_inches_after_a_g20_even_on_the_same_line():
    out = with_tolerance("g20 g64\nG1 X1 F10 (G21 in a comment)\nG64 P0.001\nG21\nG64\nM2\n", 0.01)
    assert out.splitlines() == ["G64 P0.01", "g20 G64 P0.0003937", "G1 X1 F10 (G21 in a comment)", "G64 P0.0003937",
                                "G21", "G64 P0.01", "M2"]


def test_tolerance_after_a_percent_line_and_a_program_end_added_when_missing():
    assert with_tolerance("%\r\nG1 X1 F100\r\n%", 0.01) == "%\r\nG64 P0.01\r\nG1 X1 F100\r\n%\r\n"
    assert with_tolerance("G1 X1 F100", 0.02) == "G64 P0.02\nG1 X1 F100\nM2\n"
    assert with_tolerance("\ufeffG1 X1 F100\nM2\n", 0.01) == "\ufeffG64 P0.01\nG1 X1 F100\nM2\n"
    assert with_tolerance("G1 X1 F100\nM30\n", 0.01).endswith("M30\n")
    assert with_tolerance("G1 X1 F100\nM2\n", 0.01).count("M2") == 1
    assert with_tolerance("(M2 ends it)\nG1 X1 F100 ; M30\n", 0.01).endswith("; M30\nM2\n")


def test_race_limits_key_names_every_limit():
    assert RaceLimits().key() == "T0.001-F200-A2500-a1767.77-P0.01"
    assert RaceLimits(tolerance_mm=0.02).key() != RaceLimits().key()
