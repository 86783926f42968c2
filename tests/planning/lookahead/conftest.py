"""Programs and limits of the lookahead tests: Wang's Table 1 and a near-cusp zigzag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead.planned_path import PlannedPath
from nurbsmotion.planning.measure import Measurements, measure
from nurbsmotion.program import Block, BlockKind, Program, SourceRef, read_program

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
# Wang's experiment (F = 12 m/min, T = 4 ms, 10 um, 2.5 m/s^2) plus a jerk and axis limits
WANG_LIMITS = PlanLimits(period_s=0.004, chord_error_mm=0.01, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0,
                         feed_mm_s=200.0, axis_max_velocity_mm_s=(150.0, 150.0, 150.0),
                         axis_max_accel_mm_s2=(2000.0, 2000.0, 2000.0))
TOLERANCE = 1e-9  # the planner's stated check tolerance (relative)


def single_block(curve, feed_mm_s: float = 200.0, name: str = "test") -> Program:
    return Program(name, (Block(BlockKind.NURBS, curve, feed_mm_s, SourceRef(name, 1)),), curve.start_point)


def polyline(points, feed_mm_s: float = 200.0) -> Program:
    blocks = tuple(Block(BlockKind.LINE, line_curve(a, b), feed_mm_s, SourceRef("lines", i + 1))
                   for i, (a, b) in enumerate(zip(points[:-1], points[1:])))
    return Program("lines", blocks, np.asarray(points[0], float))


@pytest.fixture(scope="session")
def wang_program(wang_curve) -> Program:
    return single_block(wang_curve, name="wang")


@pytest.fixture(scope="session")
def sharp_program() -> Program:
    return read_program(EXAMPLES / "sharp_corners.yaml")


def assert_within_limits(m: Measurements, limits: PlanLimits) -> None:
    """Every measured cycle holds every limit (with the planner's stated tolerance)."""
    ok = 1.0 + TOLERANCE
    assert m.max_chord_error_mm <= limits.chord_error_mm * ok
    assert m.max_accel_mm_s2 <= limits.max_accel_mm_s2 * ok
    if limits.max_jerk_mm_s3 is not None:
        assert m.max_jerk_mm_s3 <= limits.max_jerk_mm_s3 * ok
    if limits.axis_max_velocity_mm_s is not None:
        assert all(lim is None or v <= lim * ok for v, lim in zip(m.axis_max_velocity_mm_s, limits.axis_max_velocity_mm_s))
    if limits.axis_max_accel_mm_s2 is not None:
        assert all(lim is None or a <= lim * ok for a, lim in zip(m.axis_max_accel_mm_s2, limits.axis_max_accel_mm_s2))
    assert m.start_error_mm == 0.0
    assert m.end_error_mm == 0.0


def planned_arc_lengths(trajectory, program, limits) -> np.ndarray:
    """Arc length along the planned path (planned_pieces: corners blended) of every set-point:
    what PlanState.s_mm means."""
    path = PlannedPath.of(program, limits)
    pieces = path.pieces
    rows = path.piece_rows(trajectory)
    first = np.array([float(p.curve.arc_length(p.u_start)) for p in pieces])
    lengths = np.array([float(p.curve.arc_length(p.u_end)) for p in pieces]) - first
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    return np.array([starts[k] + float(pieces[k].curve.arc_length(u)) - first[k]
                     for k, u in zip(rows.tolist(), trajectory.u.tolist())])


def measure_planned(trajectory, program, limits):
    """planning.measure against the path the planner plans along (corners blended)."""
    path = PlannedPath.of(program, limits)
    return measure(path.rows(trajectory), path.program)


def curve_distances(p: np.ndarray, curve) -> np.ndarray:
    """Distance of points p (n, 3) from a curve, brute force: the nearest of 2001 samples
    equal in u, then 401 samples across the two sample intervals around it."""
    u = np.linspace(curve.u_min, curve.u_max, 2001)
    coarse = curve.points(u)[:, :3]
    nearest = np.empty(len(p), dtype=np.intp)
    for start in range(0, len(p), 256):
        rows = p[start:start + 256]
        d2 = ((rows[:, None, :] - coarse[None, :, :]) ** 2).sum(axis=2)
        nearest[start:start + 256] = np.argmin(d2, axis=1)
    lo, hi = u[np.maximum(nearest - 1, 0)], u[np.minimum(nearest + 1, len(u) - 1)]
    fine = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, 401)[None, :]
    points = curve.points(fine.ravel())[:, :3].reshape(len(p), 401, 3)
    return np.sqrt(((points - p[:, None, :]) ** 2).sum(axis=2).min(axis=1))


def path_deviation_mm(trajectory, program) -> float:
    """Largest distance of a set-point from the program's path: the nearest of its blocks
    (lines by projection, other curves by dense sampling), brute force."""
    p = trajectory.position_mm
    best = np.full(len(p), np.inf)
    for block in program.blocks:
        curve = block.curve
        if curve.degree == 1 and len(curve.control_points) == 2:
            a, b = curve.control_points[0][:3], curve.control_points[1][:3]
            ab = b - a
            t = np.clip((p - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
            d = np.linalg.norm(p - a - t[:, None] * ab, axis=1)
        else:
            d = curve_distances(p, curve)
        best = np.minimum(best, d)
    return float(best.max(initial=0.0))
