"""Seeded random programs (lines, arcs, NURBS; random limits, T = 1-4 ms): every cycle holds
every limit, whole or in chunks. Deterministic: the seeds fix the programs."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning import PlanLimits, Trajectory
from nurbsmotion.planning.lookahead import plan_lookahead, plan_lookahead_chunks
from nurbsmotion.program import Block, BlockKind, Program, SourceRef
from tests.planning.lookahead.conftest import measure_planned, assert_within_limits


def random_program(rng: np.random.Generator) -> Program:
    blocks, point = [], np.zeros(3)
    for index in range(int(rng.integers(2, 6))):
        kind = int(rng.integers(0, 3))
        if kind == 0:
            curve = line_curve(point, point + rng.normal(0.0, 20.0, 3))
        elif kind == 1:
            n = int(rng.integers(4, 9))
            points = np.vstack([point, point + np.cumsum(rng.normal(0.0, 10.0, (n - 1, 3)), axis=0)])
            curve = NurbsCurve.create(int(rng.integers(2, 4)), points, rng.uniform(0.5, 3.0, n))
        else:
            centre = point + np.array([*rng.normal(0.0, 10.0, 2), 0.0])
            curve = arc_curve(centre, point, float(rng.uniform(-3.0, 3.0)))
        blocks.append(Block(BlockKind.NURBS, curve, float(rng.uniform(20.0, 300.0)), SourceRef("random", index + 1)))
        point = curve.end_point
    return Program("random", tuple(blocks), np.zeros(3))


def random_limits(rng: np.random.Generator) -> PlanLimits:
    axis_v = tuple(rng.uniform(80.0, 300.0, 3)) if rng.random() < 0.5 else None
    return PlanLimits(period_s=float(rng.choice([0.001, 0.002, 0.004])),
                      chord_error_mm=float(rng.choice([0.001, 0.01, 0.05])),
                      max_accel_mm_s2=float(rng.uniform(500.0, 5000.0)),
                      max_jerk_mm_s3=None if rng.random() < 0.3 else float(rng.uniform(2e4, 2e5)),
                      axis_max_velocity_mm_s=axis_v,
                      axis_max_accel_mm_s2=None if axis_v is None else tuple(rng.uniform(800.0, 3000.0, 3)),
                      junction_deviation_mm=float(rng.choice([0.0, 0.01, 0.1])))


@pytest.mark.parametrize("seed", range(8))
def test_random_program_holds_every_limit(seed):
    rng = np.random.default_rng(seed)
    program, limits = random_program(rng), random_limits(rng)
    assert_within_limits(measure_planned(plan_lookahead(program, limits), program, limits), limits)


@pytest.mark.parametrize("seed", range(100, 104))
def test_random_program_in_small_chunks_holds_every_limit(seed):
    rng = np.random.default_rng(seed)
    program, limits = random_program(rng), random_limits(rng)
    chunks = list(plan_lookahead_chunks(program, limits, chunk_cycles=int(rng.integers(50, 300))))
    assert_within_limits(measure_planned(Trajectory.concatenate(chunks), program, limits), limits)
