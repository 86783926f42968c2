"""planning.measure: the ruler every algorithm is judged by, checked on analytic cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning.measure import measure
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Block, BlockKind, Program, SourceRef


def program_of(*curves) -> Program:
    blocks = tuple(Block(BlockKind.NURBS, c, 10.0, SourceRef("t", i + 1)) for i, c in enumerate(curves))
    return Program("t", blocks, curves[0].start_point)


def trajectory_on(program: Program, block: np.ndarray, u: np.ndarray, period_s: float, feed=None) -> Trajectory:
    points = np.array([program.blocks[b].curve.points(float(x)) for b, x in zip(block, u)])
    feed = np.zeros(len(u)) if feed is None else feed
    return Trajectory("test", period_s, block.astype(np.int32), u.astype(float), points, np.asarray(feed, float))


def circle_chord_error(radius: float, chord: float) -> float:
    return radius - math.sqrt(radius**2 - chord**2 / 4)


@pytest.mark.parametrize("steps", [7, 40, 333])
def test_chord_error_on_a_circle_is_the_sagitta(steps):
    radius = 25.0
    arc = arc_curve((0, 0, 0), (radius, 0, 0), 0.75 * 2 * math.pi)
    prog = program_of(arc)
    # equal angles: the rational parameter is not proportional to angle, so place points by arc length
    s = np.linspace(0, arc.length, steps + 1)
    u = arc.u_at_arc_length(s)
    m = measure(trajectory_on(prog, np.zeros(steps + 1, int), u, 0.001), prog)
    chord = np.linalg.norm(np.diff(arc.points(u), axis=0), axis=1)
    expected = np.array([circle_chord_error(radius, c) for c in chord])
    assert m.chord_error_mm[0] == 0.0
    np.testing.assert_allclose(m.chord_error_mm[1:], expected, rtol=1e-3)
    assert m.max_chord_error_mm == pytest.approx(expected.max(), rel=1e-3)


def test_chord_error_of_a_step_across_a_junction_uses_both_blocks():
    radius = 10.0
    quarter1 = arc_curve((0, 0, 0), (radius, 0, 0), math.pi / 2)
    quarter2 = arc_curve((0, 0, 0), (0, radius, 0), math.pi / 2)
    prog = program_of(quarter1, quarter2)
    # one step from 45 deg in block 0 to 135 deg in block 1: a 90-degree chord centred on the junction
    u0 = quarter1.u_at_arc_length(quarter1.length / 2)
    u1 = quarter2.u_at_arc_length(quarter2.length / 2)
    traj = trajectory_on(prog, np.array([0, 1]), np.array([u0, u1]), 0.001)
    chord = radius * math.sqrt(2)
    assert measure(traj, prog).chord_error_mm[1] == pytest.approx(circle_chord_error(radius, chord), rel=1e-3)


def test_constant_acceleration_on_a_line():
    accel, period, n = 500.0, 0.002, 200
    line = line_curve((0, 0, 0), (100, 0, 0))
    prog = program_of(line)
    t = np.arange(n) * period
    x = 0.5 * accel * t**2
    traj = trajectory_on(prog, np.zeros(n, int), x / 100.0, period, feed=np.r_[0, np.diff(x) / period])
    m = measure(traj, prog)
    np.testing.assert_allclose(m.accel_mm_s2[1:-1], accel, rtol=1e-6)
    assert np.abs(m.jerk_mm_s3[2:-1]).max() < 1e-3 * accel / period
    assert m.accel_mm_s2[0] == pytest.approx(accel / 2, rel=1e-6)  # from rest: half a cycle of a
    np.testing.assert_allclose(m.speed_mm_s[1:], accel * (t[1:] - period / 2), rtol=1e-9)
    assert m.max_fluctuation < 1e-9  # planned feed equals the step speed here
    assert m.max_chord_error_mm < 1e-12
    assert m.axis_max_accel_mm_s2[1] == 0.0 and m.axis_max_velocity_mm_s[0] == pytest.approx(m.max_speed_mm_s)
    # coming to rest from full speed after the last row is measured too
    assert m.max_accel_mm_s2 == pytest.approx(m.speed_mm_s[-1] / period, rel=1e-9)


def test_fluctuation_and_end_error():
    line = line_curve((0, 0, 0), (10, 0, 0))
    prog = program_of(line)
    u = np.array([0.0, 0.1, 0.2, 0.3])
    traj = trajectory_on(prog, np.zeros(4, int), u, 0.01, feed=[0.0, 100.0, 80.0, 100.0])
    m = measure(traj, prog)
    np.testing.assert_allclose(m.fluctuation, [0.0, 0.0, 0.25, 0.0], atol=1e-12)
    assert m.end_error_mm == pytest.approx(7.0)
    assert m.start_error_mm == 0.0
    assert m.cycles == 3 and m.length_mm == pytest.approx(3.0)
