"""Every figure the daemon may send as null (not known yet, or non-finite on the wire:
docs/daemon.md) is shown as '-' by the clients, never an internal error (issue 26.1: the
demo formatted a streamed job's ``length_mm``, null until the planner worker sent it)."""

from __future__ import annotations

import copy
from typing import Any, Callable, Iterator

import pytest

from nurbsmotion.cli.demo import plan_line
from nurbsmotion.cli.jobs import list_lines, show_lines
from nurbsmotion.cli.run import describe_outcome, progress_text
from nurbsmotion.cli.status import format_status

AXES = [{"name": "X", "node": 1, "drive_state": "OPERATION ENABLED", "statusword": 4663, "commanded_mm": 12.522,
         "actual_mm": 11.985, "following_error_mm": 0.179, "emcy_count": 0}]
JOB = {"id": "1d6fa14b", "name": "part.nc", "folder": "/var/x", "cycle": 76, "total": 459, "percent": 16.56,
       "feed_mm_s": 50.0, "override_percent": 100.0, "line": "part.nc:2", "paused": None, "tool": None}
STATUS: dict[str, Any] = {
    "ok": True, "state": "running", "phase": "streaming", "job": JOB,
    "override": {"requested_percent": 150.0, "effective_percent": 120.0, "max_percent": 120.0}, "axes": AXES,
    "cycles": {"count": 420, "late": 40, "missed": 2, "send_errors": 0, "lateness_p99_ms": 2.276,
               "lateness_max_ms": 38.265},
    "faults": [{"node": 2, "axis": "Y", "kind": "following_error", "code": None, "code_hex": None,
                "measured": {"following_error_counts": -2345, "following_error_mm": -2.345}, "cycle": 311,
                "master_cycle": 311, "message": "following error"}],
    "last_job": {"id": "aa", "name": "p.nc", "folder": "/f", "outcome": "completed", "reason": "", "sent": 459,
                 "planned": 459, "motion_time_s": 1.85, "line_reached": "p.nc:2"},
    "homing": {"required": False, "busy": False, "error": None, "axes": {"X": "homed"}},
    "coordinates": {"active": "G55", "active_offset_mm": [3.0, -2.0, 0.0], "g92_mm": [1.0, 0.0, 0.0],
                    "g92_applied": True, "tool": None},
    "spindle": {"node": 4, "drive_state": "OPERATION ENABLED", "commanded_rpm": 6000.0, "actual_rpm": 5990.0,
                "at_speed": True, "fault": None},
}
OUTCOME = {"outcome": "stopped", "name": "p.nc", "reason": "stopped on request", "sent": 80, "planned": 459,
           "motion_time_s": 1.0, "line_reached": {"where": "p.nc:7", "text": "G01 X1"},
           "started_at": "2026-11-24T10:12:03.250+00:00", "ended_at": "2026-11-24T10:12:04.250+00:00",
           "late_cycles": 1, "missed_cycles": 0,
           "final_position": {"X": {"commanded_mm": 1.5, "actual_mm": 1.5}},
           "overrides": [{"at_s": 0.0, "setpoint": -1, "by": "job_start", "requested_percent": 100.0,
                          "effective_percent": 100.0}], "faults": STATUS["faults"]}
PLAN = {"program": "p.nc", "blocks": 2, "length_mm": 1035.2, "algorithm": "lookahead", "streamed": True,
        "cycles": 1729, "duration_s": 6.9, "first_chunk_s": 0.01, "planning_time_s": 0.3}
RECORD = {"id": "aa", "folder": "/f", "running": False, "plan": PLAN, "outcome": OUTCOME, "files": ["plan.json"]}
LISTING = {"total": 1, "root": "/f", "jobs": [{"id": "aa", "name": "p.nc", "submitted_at": "2026-11-24T09:53:23.358",
                                               "outcome": "stopped", "reason": "r", "line_reached": "p.nc:3",
                                               "motion_time_s": 1.48, "folder": "/f", "running": False}]}


# fields docs/daemon.md says are null at times (besides every float: non-finite is sent as null)
DOCUMENTED_NULL = {"cycles", "line", "line_reached", "motion_time_s", "sent", "planned", "late_cycles",
                   "missed_cycles", "tool"}


def nullable_paths(tree: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """The path of every float and documented nullable field in ``tree``."""
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for key, value in items:
        if key in DOCUMENTED_NULL and not isinstance(value, dict):
            yield path + (key,)
        elif isinstance(value, (dict, list)):
            yield from nullable_paths(value, path + (key,))
        elif isinstance(value, float):
            yield path + (key,)


def with_null(tree: Any, path: tuple[Any, ...]) -> Any:
    out = copy.deepcopy(tree)
    node = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = None
    return out


FORMATTERS: dict[str, tuple[Callable[[Any], Any], Any]] = {
    "status": (format_status, STATUS),
    "progress": (progress_text, STATUS),
    "outcome": (lambda info: describe_outcome(info), RECORD),
    "record": (show_lines, RECORD),
    "listing": (list_lines, LISTING),
    "demo plan": (plan_line, PLAN),
    "demo plan, whole": (plan_line, {**PLAN, "streamed": False}),
}
CASES = [(name, path) for name, (_, sample) in FORMATTERS.items() for path in nullable_paths(sample)]


@pytest.mark.parametrize(("name", "path"), CASES, ids=[f"{n}:{'.'.join(map(str, p))}" for n, p in CASES])
def test_a_null_figure_is_shown_as_a_dash(name, path):
    formatter, sample = FORMATTERS[name]
    text = formatter(with_null(sample, path))
    assert "None" not in str(text)


def test_a_streamed_job_without_its_length_yet_is_announced():
    line = plan_line({**PLAN, "length_mm": None})
    assert line == "planned wang_table1.nc while it runs: -, 2 blocks, first chunk in 0.01 s (lookahead, streamed)"


def test_the_samples_cover_the_figures():
    assert len(CASES) > 60
