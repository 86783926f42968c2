"""Shared fixtures: the papers' curves; the root logger restored after each test; the garbage
collector kept from stopping the in-process simulated drives."""

from __future__ import annotations

import gc
import logging
from collections.abc import Iterator

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


@pytest.fixture(autouse=True)
def _restore_root_logger() -> Iterator[None]:
    """A CLI entry point called in-process (nurbsmotion.log.setup_logging) gives the root logger
    a handler on the test's captured stderr, which pytest closes after the test: later threads'
    log lines then print 'Logging error ... I/O operation on closed file' tracebacks."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for handler in list(root.handlers):  # pytest's own capture handlers change per phase: leave them
        if type(handler) is logging.StreamHandler and handler not in handlers:
            root.removeHandler(handler)
    root.setLevel(level)


@pytest.fixture(autouse=True, scope="module")
def _collect_between_modules() -> Iterator[None]:
    """Everything earlier modules left becomes collectable again, and their garbage is freed
    here, where no test's threads run (see _freeze_what_earlier_tests_left)."""
    gc.unfreeze()
    gc.collect()
    yield


@pytest.fixture(autouse=True)
def _freeze_what_earlier_tests_left() -> Iterator[None]:
    """A full collection stops every thread of the process while it scans every object: in
    one pytest process that has run hundreds of tests, 82 full collections took up to 1.13 s
    (52 over 250 ms, measured with gc.callbacks over the whole suite; in tests/fieldbus,
    reliability, integration and service 22 ran inside tests, 100-780 ms each, and none with
    this freeze), and the simulated
    drives, which share the process but stand for drives with their own CPU, stopped sending
    heartbeats with it (CI: 'no heartbeat for 257 ms'; the demo test: 301 ms). The daemon
    freezes the collector during a job for the same reason (runtime.GcQuiet); here each test
    starts with what earlier tests left frozen, so a collection scans only the test's own
    objects (reference counting still frees the rest)."""
    gc.freeze()
    yield
