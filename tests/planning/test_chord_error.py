"""planning.chord_error: the vertex search gives the figures of the former point-by-point
sampling (the oracle, ``sampled=True``, with the pieces' end points it may miss) on real plans
and hard cases, to the rounding of either method."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.geometry.nurbs import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve
from nurbsmotion.planning import PlanLimits, algorithm
from nurbsmotion.planning.chord_error import ProgramCurves, chord_errors, segment_distances, step_pieces
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Block, BlockKind, Program, SourceRef, read_program

ROOT = Path(__file__).resolve().parents[2]
GCODE = ROOT / "tests" / "data" / "gcode"
# the sampled search is accurate to about 1e-6 relative, with a floor of a few 1e-13 mm where
# the set-points' own rounding (coordinates of 100 mm: 1.4e-14 mm per ulp) dominates
RTOL, ATOL_MM = 1e-5, 1e-12


def piece_end_distances(trajectory: Trajectory, program: Program) -> np.ndarray:
    """Per row, the largest distance of its pieces' end points from the chord: the sampled
    search does not always reach them (a corner at a block junction is one)."""
    p = trajectory.position_mm
    pieces = step_pieces(trajectory.block, trajectory.u, program)
    out = np.zeros(len(p))
    for block, lo, hi, row in zip(pieces.block, pieces.lo, pieces.hi, pieces.row):
        ends = program.blocks[int(block)].curve.points(np.array([lo, hi]))
        out[row] = max(out[row], segment_distances(ends[None], p[row - 1: row], p[row: row + 1]).max())
    return out


def assert_same_as_sampled(trajectory: Trajectory, program: Program) -> np.ndarray:
    curves = ProgramCurves.of(program)
    args = (trajectory.block, trajectory.u, trajectory.position_mm, curves)
    new = chord_errors(*args)
    old = np.maximum(chord_errors(*args, sampled=True), piece_end_distances(trajectory, program))
    np.testing.assert_allclose(new, old, rtol=RTOL, atol=ATOL_MM)
    assert new.max() == pytest.approx(old.max(), rel=1e-6)
    return new


@pytest.mark.parametrize("path, name, period_s, jerk", [
    (ROOT / "examples" / "wang_table1.nc", "lookahead", 0.001, None),
    (ROOT / "examples" / "wang_table1.nc", "lookahead", 0.001, 50000.0),
    (ROOT / "examples" / "wang_table1.nc", "taylor2", 0.004, None),
    (ROOT / "examples" / "mixed.nc", "lookahead", 0.002, 50000.0),
    (GCODE / "linuxcnc_nurbs_G5_butterfly-xy.ngc", "lookahead", 0.004, None),
    (GCODE / "linuxcnc_arcspiral.ngc", "lookahead", 0.004, 50000.0),
])
def test_vertex_search_equals_sampling_on_plans(path, name, period_s, jerk):
    program = read_program(path)
    trajectory = algorithm(name)(program, PlanLimits(period_s=period_s, max_jerk_mm_s3=jerk))
    assert assert_same_as_sampled(trajectory, program).max() > 1e-6  # real chord errors, not noise


def program_of(*curves: NurbsCurve) -> Program:
    blocks = tuple(Block(BlockKind.NURBS, c, 10.0, SourceRef("t", i + 1)) for i, c in enumerate(curves))
    return Program("t", blocks, curves[0].start_point)


def steps_on(program: Program, block: np.ndarray, u: np.ndarray, offset_mm: np.ndarray | float = 0.0) -> Trajectory:
    points = np.array([program.blocks[int(b)].curve.points(float(x)) for b, x in zip(block, u)]) + offset_mm
    return Trajectory("test", 0.001, block.astype(np.int32), u.astype(float), points, np.zeros(len(u)))


def s_curve() -> NurbsCurve:
    """A cubic with an inflection: long steps on it have their largest distance on either side."""
    return NurbsCurve.create(3, [(0, 0, 0), (10, 20, 0), (20, -20, 5), (30, 0, 0), (40, 10, 0)])


@pytest.mark.parametrize("steps", [2, 3, 7, 50])
def test_coarse_steps_across_knots_and_inflections(steps):
    program = program_of(s_curve())
    u = np.linspace(0.0, 1.0, steps + 1)
    assert_same_as_sampled(steps_on(program, np.zeros(steps + 1), u), program)


def test_set_points_off_the_curve_and_steps_across_junctions():
    """Set-points beside the curve (the chord ends are not on it, the curve may project beyond
    them) and steps over a whole block: both pieces of every junction step count."""
    program = program_of(arc_curve((0, 0, 0), (10, 0, 0), np.pi / 2), s_curve().reparameterised(0.0, 1.0),
                         arc_curve((40, 0, 0), (40, 10, 0), np.pi))
    block = np.array([0, 0, 0, 1, 1, 2, 2, 2])
    u = np.array([0.0, 0.3, 0.8, 0.2, 0.9, 0.1, 0.5, 1.0])
    rng = np.random.default_rng(7)
    assert_same_as_sampled(steps_on(program, block, u, rng.normal(0.0, 0.05, (len(u), 3))), program)
    assert_same_as_sampled(steps_on(program, block, u), program)


def test_at_rest_and_zero_length_chords():
    program = program_of(s_curve())
    u = np.array([0.0, 0.0, 0.0, 0.1, 0.1, 0.2, 0.2000000001, 0.2000000001])
    errors = assert_same_as_sampled(steps_on(program, np.zeros(len(u)), u), program)
    assert errors[0] == 0.0 and errors[1] == 0.0 and errors[4] == 0.0


def test_rest_across_a_junction_is_measured_as_the_sampled_search_does():
    """A rest across a block junction (zero-length chord, pieces of zero parameter length at
    both blocks' ends): the one point's distance, bit for bit what the sampled search finds."""
    onward = NurbsCurve.create(3, [(40, 10, 0), (50, 0, 0), (60, 10, 0), (70, 0, 0)])
    program = program_of(s_curve(), onward)
    block = np.array([0, 0, 0, 1, 1, 1])
    u = np.array([0.8, 0.9, 1.0, 0.0, 0.1, 0.2])
    trajectory = steps_on(program, block, u)
    trajectory.position_mm[2:4] += (0.0, 1e-9, 0.0)  # at rest beside the junction, on both sides of it
    curves = ProgramCurves.of(program)
    args = (trajectory.block, trajectory.u, trajectory.position_mm, curves)
    new, old = chord_errors(*args), chord_errors(*args, sampled=True)
    assert new[3] == old[3] and new[3] == pytest.approx(1e-9)
