"""Shared fixtures: the papers' curves."""

from __future__ import annotations

import pytest

from nurbsmotion.geometry import NurbsCurve

WANG_POINTS = [(0, 0, 0), (-50, 80, 80), (0, 100, 100), (50, 80, 80), (0, 0, 0), (80, 30, 30), (100, 0, 0),
               (80, -30, -30), (0, 0, 0), (50, -80, -80), (0, -100, -100), (-50, -80, -80), (0, 0, 0),
               (-80, -30, -30), (-100, 0, 0), (-80, 30, 30), (0, 0, 0)]
WANG_WEIGHTS = [1] + [25] * 15 + [1]
WANG_KNOTS = [0, 0, 0, 0.06, 0.09, 0.15, 0.20, 0.24, 0.32, 0.40, 0.56, 0.60, 0.66, 0.72, 0.80, 0.88, 0.94, 1, 1, 1]
WANG_LENGTH_MM = 1028.1  # reference §1: "about 1028.1 mm"


@pytest.fixture(scope="session")
def wang_curve() -> NurbsCurve:
    return NurbsCurve.create(2, WANG_POINTS, WANG_WEIGHTS, WANG_KNOTS)


@pytest.fixture(scope="session")
def planner_worker():
    """One planner worker process (service.planner_worker) for the streamed jobs of the session."""
    from nurbsmotion.service.planner_worker import PlannerWorker

    worker = PlannerWorker()
    worker.start()
    yield worker
    worker.close()
