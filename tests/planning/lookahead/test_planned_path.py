"""PlannedPath.streamed (the pieces made blocks as PlanStream sets them up) and MeasureStream's
curves gathered per chunk against the whole program's PlannedPath.of and ProgramCurves: the
same set-points on the same pieces, the same chord errors and trace blocks to the bit, on real
CAM programs; and the first chunk makes blocks of the sections set up only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.chord_error import ProgramCurves, chord_errors
from nurbsmotion.planning.lookahead import PlanStream
from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning.lookahead.path import BlockPiece
from nurbsmotion.planning.lookahead.planned_path import PlannedPath, groups, trimmed_curve
from nurbsmotion.planning.measure import MeasureStream
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import read_program

GCODE = Path(__file__).resolve().parents[2] / "data" / "gcode"
LIMITS = PlanLimits(period_s=0.001, chord_error_mm=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0,
                    feed_mm_s=200.0, rapid_feed_mm_s=200.0)
PROGRAMS = ["fusion360_led_floor_1103_bore_test_27bit_3_rad.nc", "grbl_HSM_test.nc", "camotics_vcarve.ngc"]


def streamed(program, limits):
    """(the chunks, the streamed path's rows of each, the measured figures of each, the stream's summary)."""
    stream = PlanStream(program, limits, 2000, 200)
    path = PlannedPath.streamed(program, lambda: stream.pieces_set_up)
    measure = MeasureStream(path.program)
    chunks, moved, figures = [], [], []
    for chunk, _ in stream.chunks():
        chunks.append(chunk)
        moved.append(path.rows(chunk))
        figures.append(path.on_program(measure.add(moved[-1])) if len(chunk) else None)
    figures.append(path.on_program(measure.finish()))
    return chunks, moved, [f for f in figures if f is not None], measure.measurements().summary()


@pytest.mark.parametrize("name", PROGRAMS)
@pytest.mark.parametrize("tolerance_mm", [0.01, 0.0])
def test_the_streamed_path_measures_as_the_whole_programs(name, tolerance_mm):
    limits = PlanLimits(**{**LIMITS.__dict__, "path_tolerance_mm": tolerance_mm})
    program = read_program(GCODE / name)
    chunks, moved, figures, summary = streamed(program, limits)
    whole = PlannedPath.of(program, limits)
    plan = Trajectory.concatenate(chunks)
    reference = whole.rows(plan)
    rows = Trajectory.concatenate(moved)
    if whole.blended:
        np.testing.assert_array_equal(rows.block, reference.block)
        np.testing.assert_array_equal(rows.u, reference.u)
    want = chord_errors(reference.block, reference.u, reference.position_mm, ProgramCurves.of(whole.program))
    got = np.concatenate([f.chord_error_mm for f in figures])
    np.testing.assert_array_equal(got, want)
    trace_blocks = np.concatenate([f.rows.block for f in figures])
    expected = whole.on_program(MeasureStream(whole.program).add(reference)).rows.block if whole.blended else plan.block
    np.testing.assert_array_equal(trace_blocks[:len(expected)], expected)
    reference_stream = MeasureStream(whole.program)
    for chunk in chunks:
        reference_stream.add(whole.rows(chunk))
    reference_stream.finish()
    assert summary == reference_stream.measurements().summary()


def test_the_first_chunk_makes_blocks_of_the_sections_set_up_only():
    program = read_program(GCODE / "grbl_HSM_test.nc")
    stream = PlanStream(program, LIMITS, 2000, 200)
    path = PlannedPath.streamed(program, lambda: stream.pieces_set_up)
    chunk, _ = next(stream.chunks())
    path.rows(chunk)
    assert 0 < len(path.program.blocks) == len(stream.pieces_set_up) < len(PlannedPath.of(program, LIMITS).pieces)


def test_a_trimmed_line_ends_exactly_where_its_block_ends():
    """A line trimmed at its start only (a blend before it) keeps the block's end point to the
    bit: evaluated at u = 1 it was off by 2.8e-17 mm here, so a plan that stops exactly on the
    program's end measured an end error (hypothesis found it in test_no_give_ups)."""
    a, b = np.array([1.9378248434212895, 0.4948079185090459, 0.0]), np.array([5.906615512338605, -0.0038910150318648695, 0.0])
    curve = line_curve(a, b)
    assert not np.array_equal(curve.points(np.array([curve.u_max]))[0], b)  # the rounding this is about
    trimmed, _ = trimmed_curve(BlockPiece(0, curve, 0.045755056372016545, curve.u_max, 20.0))
    assert np.array_equal(trimmed.end_point, b)
    head, _ = trimmed_curve(BlockPiece(0, curve, curve.u_min, 0.5, 20.0))
    assert np.array_equal(head.control_points[0], a)


def test_groups_are_each_values_rows_in_order():
    values = np.array([3, 1, 3, 0, 1, 1, 7, 3], dtype=np.int32)
    found = groups(values)
    assert [v for v, _ in found] == [0, 1, 3, 7]
    for value, at in found:
        assert at.tolist() == np.flatnonzero(values == value).tolist()
    assert groups(np.array([], dtype=np.int32)) == []
