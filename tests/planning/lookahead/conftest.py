"""Programs and limits of the lookahead tests: Wang's Table 1 and a near-cusp zigzag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.measure import Measurements
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
