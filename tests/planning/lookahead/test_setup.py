"""The set-up section by section (setup.PathSections) is the whole program's set-up: the same
pieces, runs and set-points on real CAM programs, with corner blending and smoothing; and a
first chunk sets up a bounded number of blocks, whatever the program's length."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import api
from nurbsmotion.planning.lookahead.planner import settings_for
from nurbsmotion.planning.lookahead.runs import ProgramStops, program_pieces, split_runs
from nurbsmotion.planning.lookahead.setup import SECTION_BLOCKS, PathSections, max_program_feed
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import parse_gcode, read_program
from nurbsmotion.program.records import BlockRecords

GCODE = Path(__file__).resolve().parents[2] / "data" / "gcode"
LIMITS = PlanLimits(period_s=0.001, chord_error_mm=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0,
                    feed_mm_s=200.0, rapid_feed_mm_s=200.0)
PROGRAMS = ["fusion360_led_floor_1103_bore_test_27bit_3_rad.nc", "grbl_HSM_test.nc", "camotics_vcarve.ngc"]


def whole_runs(program, limits):
    """The runs as the whole-program set-up makes them (the reference)."""
    stops = ProgramStops.of(program, limits)
    pieces = api.path_pieces(program, limits, stops)
    settings = settings_for(limits, max(p.feed_mm_s for p in pieces), api.DEFAULT_CHUNK_CYCLES)
    return split_runs(pieces, limits, settings.min_pass_mm_s, stops), settings


def piece_key(piece):
    covered = None if piece.covered is None else (piece.covered.blocks.tolist(), piece.covered.u_end.tolist())
    return (piece.block, piece.u_start, piece.u_end, piece.feed_mm_s, piece.ordinal, piece.deviation_mm,
            piece.curve.control_points.tolist(), piece.curve.knots.tolist(), covered)


@pytest.mark.parametrize("name", PROGRAMS)
@pytest.mark.parametrize("tolerance_mm", [0.01, 0.0])
def test_the_sections_give_the_whole_programs_runs(name, tolerance_mm):
    limits = PlanLimits(**{**LIMITS.__dict__, "path_tolerance_mm": tolerance_mm})
    program = read_program(GCODE / name)
    reference, settings = whole_runs(program, limits)
    assert max_program_feed(program, limits) == settings.max_feed_mm_s
    sections = PathSections(program, limits, ProgramStops.of(program, limits), settings.min_pass_mm_s)
    runs = list(sections.runs())
    assert len(runs) == len(reference)
    for got, want in zip(runs, reference):
        assert [piece_key(p) for p in got.pieces] == [piece_key(p) for p in want.pieces]
        assert got.junction_speed_mm_s == want.junction_speed_mm_s
        assert got.rest_cycles_before == want.rest_cycles_before


def test_streamed_set_points_are_the_whole_set_ups_to_the_bit():
    """PlanStream (sections set up as the chunks need them) against the chunks planned on the
    whole program's runs: every set-point and the line reached identical."""
    program = read_program(GCODE / "fusion360_led_floor_1103_bore_test_27bit_3_rad.nc")
    reference, settings = whole_runs(program, LIMITS)
    want = Trajectory.concatenate([c for c, _ in api._chunks(reference, settings, None, api._Figures())])
    got = Trajectory.concatenate(list(api.PlanStream(program, LIMITS)))
    assert np.array_equal(got.position_mm, want.position_mm)
    assert np.array_equal(got.block, want.block)
    assert np.array_equal(got.u, want.u)


def test_a_short_first_window_streams_the_whole_set_ups_set_points():
    """As a streamed job plans (first chunk 200 cycles, then resumed with 2,000): against the
    same two-window scheme on the whole program's runs, to the bit, with the line reached."""
    program = read_program(GCODE / "grbl_HSM_test.nc")
    reference, settings = whole_runs(program, LIMITS)
    short = settings_for(LIMITS, settings.max_feed_mm_s, 200)
    first = api._chunks(reference, short, None, api._Figures())
    head, resume = next(first)
    rest, cursor = api.resume_runs(reference, resume)
    want = Trajectory.concatenate([head] + [c for c, _ in api._chunks(rest, settings, cursor, api._Figures(),
                                                                       resume.before)])
    got = Trajectory.concatenate([c for c, _ in api.PlanStream(program, LIMITS, 2000, 200).chunks()])
    assert np.array_equal(got.position_mm, want.position_mm)
    assert np.array_equal(got.block, want.block)
    assert np.array_equal(got.u, want.u)


def test_the_first_chunk_sets_up_a_bounded_number_of_blocks(tmp_path):
    """A long program (a CAM program 20 times): its first chunk reads a few sections only."""
    text = (GCODE / "grbl_HSM_test.nc").read_text().replace("M30", "").replace("M2", "")
    path = tmp_path / "long.nc"
    path.write_text(text * 20 + "M30\n")
    program = read_program(path)
    stream = api.PlanStream(program, LIMITS, chunk_cycles=2000, first_chunk_cycles=200)
    next(iter(stream.chunks()))
    assert len(program.blocks) > 20 * SECTION_BLOCKS
    assert 0 < stream.blocks_set_up <= 4 * SECTION_BLOCKS


def test_the_program_stops_from_the_columns_are_those_from_the_blocks():
    text = "G64 P0.02\nG1 X10 F600\nG61\nG1 Y10\nG4 P0.5\nG64\nG1 X0\nG64 P0.005\nG1 Y0\nM0\nG1 X5\n"
    program = parse_gcode(text, "stops.nc")
    assert isinstance(program.blocks, BlockRecords)
    as_blocks = replace(program, blocks=tuple(program.blocks))
    got, want = ProgramStops.of(program, LIMITS), ProgramStops.of(as_blocks, LIMITS)
    assert got == want
    assert got.stop_after and got.tolerance_mm and got.dwell_s_before


@pytest.mark.parametrize("text", [
    "G1 X10 F600\nG2 X20 I5 F1200\nG1 X30 F900\n",  # an arc the fastest
    "G1 X10 F600\nG1 X10 F99999\nG1 Y5 F300\n",  # the fastest block does not move
    "G0 X5\nG1 X10 F60\n",  # a rapid the fastest
    "G4 P1\n",  # no motion
])
def test_the_highest_feed_from_the_columns_is_the_pieces(text):
    program = parse_gcode(text, "feeds.nc")
    limits = PlanLimits(rapid_feed_mm_s=150.0)
    want = max((p.feed_mm_s for p in program_pieces(program, limits)), default=1.0)
    assert max_program_feed(program, limits) == want
