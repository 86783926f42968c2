"""The program's own stops in the look-ahead: G4 dwell holds the axes at rest ceil(P / T) cycles,
G61 / a pause / a tool change end the motion at rest, G64 P tightens the junction deviation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.planning import plan
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead_chunks
from nurbsmotion.program import parse_gcode

LIMITS = PlanLimits(period_s=0.004, max_accel_mm_s2=2500.0)


def rest_stretches(positions: np.ndarray) -> list[tuple[int, int]]:
    """(first row, steps) of every stretch of consecutive set-points at the same place."""
    still = np.linalg.norm(np.diff(positions, axis=0), axis=1) == 0
    out, start = [], None
    for i, s in enumerate(still):
        if s and start is None:
            start = i
        if not s and start is not None:
            out.append((start, i - start))
            start = None
    if start is not None:
        out.append((start, len(still) - start))
    return out


@pytest.mark.parametrize("dwell_s", [0.004, 0.01, 0.1, 0.5])
def test_a_dwell_between_two_moves_rests_ceil_p_over_t_cycles(dwell_s):
    program = parse_gcode(f"G1 X5 F600\nG4 P{dwell_s}\nG1 X10\n", "t.nc")  # collinear: only the dwell stops
    trajectory = plan(program, LIMITS)
    stretches = rest_stretches(trajectory.position_mm)
    assert [steps for _, steps in stretches] == [math.ceil(dwell_s / LIMITS.period_s - 1e-9)]
    row = stretches[0][0]
    np.testing.assert_allclose(trajectory.position_mm[row], [5, 0, 0], atol=1e-9)


def test_dwells_before_the_first_and_after_the_last_move():
    trajectory = plan(parse_gcode("G4 P0.02\nG1 X5 F600\nG4 P0.05\n", "t.nc"), LIMITS)
    assert [steps for _, steps in rest_stretches(trajectory.position_mm)] == [5, 13]


def test_g61_and_holding_events_end_the_block_at_rest():
    text = "G1 X5 F600\nG61 X10\nG64 X15\nM0\nX20\nT2 M6\nX25\n"  # all collinear: only the program stops
    trajectory = plan(parse_gcode(text, "t.nc"), LIMITS)
    rests = [trajectory.position_mm[row][0] for row, _ in rest_stretches(trajectory.position_mm)]
    assert rests == pytest.approx([10, 15, 20])


def test_without_program_stops_a_straight_line_never_rests():
    trajectory = plan(parse_gcode("G1 X5 F600\nX10\nX15\n", "t.nc"), LIMITS)
    assert rest_stretches(trajectory.position_mm) == []


def test_g64_p_tighter_than_the_machine_slows_a_corner():
    corner = "G1 X5 F3000\nG1 X10 Y0.5\n"  # 5.7 deg turn: blended at the machine's 0.01 mm
    loose = plan(parse_gcode(corner, "t.nc"), LIMITS)
    tight = plan(parse_gcode("G64 P0.0001\n" + corner, "t.nc"), LIMITS)
    assert tight.duration_s > loose.duration_s
    assert plan(parse_gcode("G64 P1\n" + corner, "t.nc"), LIMITS).duration_s <= loose.duration_s  # a wider blend


def test_chunked_plan_holds_the_same_dwell():
    program = parse_gcode("G1 X5 F600\nG4 P0.1\nG1 X10\n", "t.nc")
    rows = np.concatenate([c.position_mm for c in plan_lookahead_chunks(program, LIMITS, chunk_cycles=50)])
    assert [steps for _, steps in rest_stretches(rows)] == [25]


def test_a_helical_ramp_is_planned_within_the_chord_error_and_acceleration():
    """Helical arcs are NURBS like any other curve: the look-ahead's verified figures hold."""
    limits = PlanLimits(period_s=0.004, chord_error_mm=0.001, max_accel_mm_s2=1000.0)
    program = parse_gcode("G0 X5 Y0 Z1\nG17 G3 X5 Y0 I-5 J0 Z-2 P3 F1200\nG1 X0 Y0\n", "t.nc")
    trajectory = plan(program, limits)
    assert trajectory.notes["verified_max_chord_error_mm"] <= limits.chord_error_mm * (1 + 1e-6)
    assert trajectory.notes["verified_max_accel_mm_s2"] <= limits.max_accel_mm_s2 * (1 + 1e-6)
    np.testing.assert_allclose(trajectory.position_mm[-1], [0, 0, -2], atol=1e-9)
