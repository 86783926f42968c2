"""No give-ups: where the repair rounds fail, the planner falls back to a slower verified
plan (a stop, an exact stop after a block, a lower feed) instead of raising; what errors
remain name the program line."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nurbsmotion.cli import main
from nurbsmotion.planning import PlanLimits, Trajectory
from nurbsmotion.planning.lookahead import PlanningError, PlanStream, plan_lookahead, plan_lookahead_resumable
from nurbsmotion.planning.lookahead import planner as lookahead_planner
from nurbsmotion.program import parse_gcode, read_program
from tests.planning.lookahead.conftest import measure_planned, EXAMPLES, WANG_LIMITS, assert_within_limits, polyline

WANG_NC = str(EXAMPLES / "wang_table1.nc")
BRAID = Path(__file__).resolve().parents[2] / "data" / "gcode" / "braid_cut2d.nc"


def braid_program():
    """grbl's braid_cut2d.nc (tests/data/gcode/SOURCES-planner.md) with the two lines the
    dialect does not take yet: line 1 (T1M6, a tool change) becomes a comment, line 6 (the
    first G1, before the program's F7000 on line 8) gets F7000. Every other line as published."""
    lines = BRAID.read_text().splitlines()
    assert lines[0] == "T1M6" and lines[5] == "G1Z-1.000" and lines[7] == "F7000.0"
    lines[0], lines[5] = "(T1M6)", "G1Z-1.000F7000"
    return parse_gcode("\n".join(lines) + "\n", "braid_cut2d.nc")


@pytest.fixture(scope="module")
def braid():
    return braid_program()


@pytest.mark.parametrize("period_ms", [1, 2, 4])
def test_the_braid_program_plans_within_every_limit(braid, period_ms):
    """At T = 1 ms with every corner a junction (path tolerance 0) the repairs used to give up
    at block 1532 (1.0013 x the accel limit), and with repairs reaching only the micrometre
    grid intervals where the short lines meet, in 12-30 windows, each a fallback stop and a
    re-plan of the rest (planner.repair_reach_mm, runs_from_rest): the plan holds every limit
    on every cycle either way. (Which windows need a fallback is tested with forced failures:
    test_repairs_that_always_fail..., test_a_run_failing_far_ahead...)"""
    limits = PlanLimits(period_s=period_ms / 1000.0, path_tolerance_mm=0.0 if period_ms == 1 else 0.01)
    trajectory = plan_lookahead(braid, limits)
    assert_within_limits(measure_planned(trajectory, braid, limits), limits)


def test_repairs_that_always_fail_fall_back_to_slower_verified_plans(monkeypatch):
    """No repair round at all: every window that violates falls back (stops, exact stops
    after a block, lower feeds) and the plan still holds every limit on every cycle. (Cases
    whose first round violates somewhere: mixed.nc at T = 1 ms with J no longer does, its first
    round holds every limit; the near-cusp zigzag at T = 4 ms with J takes its place. Wang's
    curve at T = 1 ms with J no longer does either since dips are widened by +-v tau / 2, not
    0.75 v tau: at T = 2 ms it still does.)"""
    monkeypatch.setattr(lookahead_planner, "MAX_REPAIR_ROUNDS", 0)
    cases = [("sharp_corners.yaml", WANG_LIMITS),
             ("mixed.nc", replace(WANG_LIMITS, max_jerk_mm_s3=None, period_s=0.001)),
             ("wang_table1.nc", replace(WANG_LIMITS, period_s=0.002))]
    for name, limits in cases:
        program = read_program(EXAMPLES / name)
        trajectory = plan_lookahead(program, limits)
        notes = trajectory.notes
        assert notes["fallback_stops"] + notes["fallback_slower_blocks"] >= 1
        assert_within_limits(measure_planned(trajectory, program, limits), limits)


def test_the_resume_after_a_fallback_stop_continues_the_plan(monkeypatch):
    monkeypatch.setattr(lookahead_planner, "MAX_REPAIR_ROUNDS", 0)
    program = read_program(EXAMPLES / "mixed.nc")
    limits = replace(WANG_LIMITS, period_s=0.001, path_tolerance_mm=0.0)  # the fallback stops of the corners
    whole = list(plan_lookahead_resumable(program, limits, chunk_cycles=200))
    for k in (len(whole) // 3, len(whole) // 2):
        head = [chunk for chunk, _ in whole[: k + 1]]
        tail = [chunk for chunk, _ in plan_lookahead_resumable(program, limits, 200, whole[k][1])]
        joined = Trajectory.concatenate(head + tail)
        assert_within_limits(measure_planned(joined, program, limits), limits)


def test_a_plan_that_cannot_exist_names_the_program_line(monkeypatch):
    """No repairs and no lower feed allowed: Wang's curve with a jerk limit at T = 2 ms violates
    in its first round (the path's own jerk terms; at 4 ms no longer since dips are widened by
    +-v tau / 2), and the error names the G-code line."""
    monkeypatch.setattr(lookahead_planner, "MAX_REPAIR_ROUNDS", 0)
    monkeypatch.setattr(lookahead_planner, "MAX_FEED_HALVINGS", 0)
    program = read_program(WANG_NC)
    with pytest.raises(PlanningError) as err:
        plan_lookahead(program, replace(WANG_LIMITS, period_s=0.002))
    line = program.blocks[err.value.block].source.line
    assert err.value.where == f"{WANG_NC}:{line}" and "lookahead cannot hold" in err.value.message


def test_plan_json_writes_an_error_object_when_planning_fails(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(lookahead_planner, "MAX_REPAIR_ROUNDS", 0)
    monkeypatch.setattr(lookahead_planner, "MAX_FEED_HALVINGS", 0)
    path = tmp_path / "wang.nc"
    path.write_text(Path(WANG_NC).read_text())
    trace = tmp_path / "out.csv"
    assert main(["plan", str(path), "--period-ms", "2", "--max-jerk-mm-s3", "50000",
                 "--trace", str(trace), "--json"]) == 2
    out = capsys.readouterr()
    error = json.loads(out.out)["error"]
    assert error["where"].startswith(f"{path}:") and "lookahead cannot hold" in error["message"]
    assert out.err.count("\n") == 1 and "error:" in out.err
    assert list(tmp_path.iterdir()) == [path]  # no trace, not even a partial one


segment = st.tuples(st.floats(0.02, 3.0), st.floats(-np.pi, np.pi))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(segment, min_size=5, max_size=60), period_ms=st.sampled_from([1, 2, 4]),
       jerk=st.sampled_from([None, 50000.0]), feed=st.floats(20.0, 250.0), turn=st.floats(0.0, 1.0))
def test_random_short_line_programs_plan_within_every_limit(steps, period_ms, jerk, feed, turn):
    """Programs of short lines (20 um - 3 mm, turning by up to +-turn x 180 deg): never a
    give-up, every cycle within every limit."""
    points, heading = [np.zeros(3)], 0.0
    for length, angle in steps:
        heading += turn * angle
        points.append(points[-1] + length * np.array([np.cos(heading), np.sin(heading), 0.0]))
    program = polyline(points, feed_mm_s=feed)
    limits = PlanLimits(period_s=period_ms / 1000.0, max_jerk_mm_s3=jerk)
    stream = PlanStream(program, limits, chunk_cycles=500)
    trajectory = Trajectory.concatenate(list(stream))
    assert_within_limits(measure_planned(trajectory, program, limits), limits)


def gentle_arc(count: int) -> list[np.ndarray]:
    """``count`` 2 mm lines turning 2 deg each: one run (every corner passed moving)."""
    heading = np.radians(2.0) * np.arange(count)
    steps = 2.0 * np.stack([np.cos(heading), np.sin(heading), np.zeros(count)], axis=1)
    return list(np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)]))


def test_a_run_failing_far_ahead_from_rest_stops_before_the_failing_block(monkeypatch):
    """A run that cannot be planned from rest at block TROUBLE (here: the first window that
    contains it past its first block fails) stops before that block and starts again from rest
    there, in one fallback (planner.runs_from_rest); stopping after the run's first block
    instead re-planned the whole rest of the run once per block."""
    trouble = 30
    points = gentle_arc(40)
    program = polyline(points, feed_mm_s=100.0)
    limits = PlanLimits(period_s=0.001, path_tolerance_mm=0.0)
    original = lookahead_planner.plan_window
    windows: list[int] = []
    failed: list[int] = []

    def failing_once(run, cursor, settings, length_mm):
        blocks = [p.block for p in run.pieces]
        windows.append(blocks[0])
        if not failed and cursor.at_rest and trouble in blocks[1:]:
            failed.append(blocks[0])
            raise PlanningError(f"block {trouble + 1}", "test: cannot hold a limit here", trouble)
        return original(run, cursor, settings, length_mm)

    monkeypatch.setattr(lookahead_planner, "plan_window", failing_once)
    trajectory = plan_lookahead(program, limits)
    assert failed == [0] and trajectory.notes["fallback_stops"] == 1
    at = np.flatnonzero(np.all(trajectory.position_mm == points[trouble], axis=1))
    assert len(at) >= 2 and np.any(np.diff(at) == 1)  # at rest where block TROUBLE starts
    assert len(windows) == 3  # the failure, the run to the stop, the rest from there
    assert_within_limits(measure_planned(trajectory, program, limits), limits)


def test_a_repair_that_does_not_lower_the_worst_violation_gives_up_early(monkeypatch):
    """Repairs that change nothing: each window stops after MAX_STALLED_REPAIRS rounds without
    progress (not MAX_REPAIR_ROUNDS), and the fallbacks still give a plan within every limit."""
    checks: list[int] = []
    original_check = lookahead_planner.check

    def counting_check(*args, **kwargs):
        checks.append(1)
        return original_check(*args, **kwargs)

    windows: list[int] = []
    original_window = lookahead_planner.plan_window

    def counting_window(*args, **kwargs):
        windows.append(1)
        return original_window(*args, **kwargs)

    monkeypatch.setattr(lookahead_planner, "repair", lambda *args, **kwargs: None)
    monkeypatch.setattr(lookahead_planner, "check", counting_check)
    monkeypatch.setattr(lookahead_planner, "plan_window", counting_window)
    program = read_program(WANG_NC)
    limits = replace(WANG_LIMITS, period_s=0.002)  # violates in its first round
    trajectory = plan_lookahead(program, limits)
    assert trajectory.notes["fallback_stops"] + trajectory.notes["fallback_slower_blocks"] >= 1
    assert len(checks) <= len(windows) * (lookahead_planner.MAX_STALLED_REPAIRS + 1)
    assert_within_limits(measure_planned(trajectory, program, limits), limits)
