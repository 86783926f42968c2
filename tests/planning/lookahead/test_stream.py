"""PlanStream: the plan as chunks for a streaming consumer, each with a verified way to stop."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nurbsmotion.planning import Trajectory
from nurbsmotion.planning.lookahead import PlanStream, plan_lookahead
from nurbsmotion.program import parse_gcode, read_program
from tests.planning.lookahead.conftest import measure_planned, EXAMPLES, WANG_LIMITS, assert_within_limits

LIMITS = replace(WANG_LIMITS, period_s=0.001)


def test_the_stream_is_the_whole_plan_and_states_its_guarantees():
    program = read_program(EXAMPLES / "mixed.nc")
    stream = PlanStream(program, LIMITS, chunk_cycles=200)
    chunks = list(stream)
    assert len(chunks) > 5
    streamed = Trajectory.concatenate(chunks)
    assert_within_limits(measure_planned(streamed, program, LIMITS), LIMITS)
    notes = stream.notes
    assert notes["verified_max_jerk_mm_s3"] <= LIMITS.max_jerk_mm_s3 * (1 + 1e-9)
    assert notes["windows"] >= len(chunks) and stream.planning_time_s > 0
    whole = plan_lookahead(program, LIMITS)
    # other windows, nearly the same motion: never slower (a repair in the whole plan lowers a
    # wider stretch than the chunks' shorter windows do, so the stream may be faster)
    assert len(streamed) <= 1.01 * len(whole)


def test_every_chunk_can_stop_along_the_path_within_the_limits():
    """A consumer may stop after any chunk: the chunks so far followed by that chunk's stop
    set-points hold every limit and end at rest on the path."""
    program = read_program(EXAMPLES / "wang_table1.nc")
    pairs = list(PlanStream(program, LIMITS, chunk_cycles=500).chunks())
    moving = [k for k, (_, resume) in enumerate(pairs) if resume is not None and resume.stop is not None]
    assert len(moving) >= 3
    curve = program.blocks[0].curve
    for k in moving[:: max(len(moving) // 4, 1)]:
        stop = pairs[k][1].stop
        joined = Trajectory.concatenate([chunk for chunk, _ in pairs[: k + 1]] + [stop])
        m = measure_planned(joined, program, LIMITS)
        ok = 1.0 + 1e-9
        assert m.max_accel_mm_s2 <= LIMITS.max_accel_mm_s2 * ok and m.max_jerk_mm_s3 <= LIMITS.max_jerk_mm_s3 * ok
        assert m.max_chord_error_mm <= LIMITS.chord_error_mm * ok
        end = joined.position_mm[-1]
        assert np.linalg.norm(curve.points(np.array([joined.u[-1]]))[0] - end) < 1e-9  # at rest on the path


def test_a_short_first_window_gives_a_short_first_chunk_and_the_same_guarantees_across_the_join():
    """PlanStream(first_chunk_cycles): the first chunk from a short window (a streaming job
    starts moving on it), the rest resumed from it; the whole still holds every limit, ends
    at the program's end, and the first chunk's stop tail stops within the limits."""
    program = read_program(EXAMPLES / "wang_table1.nc")
    stream = PlanStream(program, LIMITS, chunk_cycles=2000, first_chunk_cycles=200)
    pairs = list(stream.chunks())
    whole_first = next(PlanStream(program, LIMITS, chunk_cycles=2000).chunks())[0]
    assert len(pairs[0][0]) < len(whole_first) / 4  # Wang's whole curve is one chunk otherwise
    streamed = Trajectory.concatenate([chunk for chunk, _ in pairs])
    assert_within_limits(measure_planned(streamed, program, LIMITS), LIMITS)
    assert np.allclose(streamed.position_mm[-1], program.end_position[:3], atol=1e-9)
    assert stream.notes["windows"] >= len(pairs)
    stop = pairs[0][1].stop
    assert stop is not None
    m = measure_planned(Trajectory.concatenate([pairs[0][0], stop]), program, LIMITS)
    assert m.max_accel_mm_s2 <= LIMITS.max_accel_mm_s2 * (1 + 1e-9) and m.max_jerk_mm_s3 <= LIMITS.max_jerk_mm_s3 * (1 + 1e-9)


def test_a_program_shorter_than_the_first_window_keeps_its_trailing_dwell():
    program = parse_gcode("G21 G90\nG01 X1 F600\nG04 P0.5\n", "dwell.nc")
    pairs = list(PlanStream(program, LIMITS, chunk_cycles=2000, first_chunk_cycles=200).chunks())
    whole = plan_lookahead(program, LIMITS)
    assert sum(len(chunk) for chunk, _ in pairs) == len(whole)
    assert np.allclose(pairs[-1][0].position_mm[-1], whole.position_mm[-1])


def test_chunked_planning_of_wangs_curve_throws_no_window_away():
    """The second window starts moving just before a speed peak: its plateau is measured with
    the raw motion before the start (the cursor's history), so it does not come out below the
    start speed; before, the window failed on 2-3x J at the join and the held-back window was
    re-planned with twice the look-ahead (notes: discarded_windows 2, one window in all)."""
    program = read_program(EXAMPLES / "wang_table1.nc")
    limits = replace(LIMITS, axis_max_velocity_mm_s=None, axis_max_accel_mm_s2=None)
    stream = PlanStream(program, limits, chunk_cycles=2000)
    streamed = Trajectory.concatenate(list(stream))
    notes = stream.notes
    assert notes["discarded_windows"] == 0 and notes["windows"] >= 2
    assert_within_limits(measure_planned(streamed, program, limits), limits)
    whole = plan_lookahead(program, limits)
    assert whole.notes["discarded_windows"] == 0
    assert abs(len(whole) - len(streamed)) <= 0.002 * len(whole)
