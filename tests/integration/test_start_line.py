"""Starting a program from line N through the daemon (in-process, simulated drives and
spindle): the spindle started before any motion, the approach (up to machine.safe_z_mm,
across at that height, down at the program's feed) in the job's trace, the record and
status naming the start line, line numbers the file's own, refusals one line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.cli.status import format_status
from nurbsmotion.planning.lookahead.verify import FLUCTUATION_LIMIT
from nurbsmotion.planning.trace import read_trace
from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

SAFE_Z_MM = 10.0
MACHINE = f"""\
spindle: {{node_id: 5, counts_per_rev: 4096, max_rpm: 12000, accel_rpm_s: 20000, at_speed_timeout_s: 3.0}}
machine: {{safe_z_mm: {SAFE_Z_MM}}}
"""
PROGRAM = """\
G21 G90
G0 X10 Y5 Z5
S3000 M3
F1200
G1 Z-2
G1 X20
G1 Y15
G1 X10
M5
M30
"""
N = 7  # G1 Y15: starts at X20 Y5 Z-2 with M3 S3000 and F1200 (20 mm/s) in effect
START_POINT = (20.0, 5.0, -2.0)
FEED_MM_S = 20.0
EPS_MM = 1e-6


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[Daemon]:
    with daemon_in_process(tmp_path / "data", MACHINE, "sl") as daemon:
        yield daemon


def submit(daemon: Daemon, **fields) -> dict:
    with Client(daemon.config.control.socket) as client:
        return client.request("submit", name="part.nc", program=PROGRAM, **fields)


def wait_job(daemon: Daemon, job_id: str, timeout_s: float = 30.0) -> dict:
    assert daemon.controller is not None
    return wait_for(lambda: (info := daemon.controller.job_info(job_id)["job"]).get("outcome") and info, timeout_s,
                      f"job {job_id} end")


def test_a_start_line_job_starts_the_spindle_then_rises_crosses_and_feeds_down(machine):
    assert machine.controller is not None
    response = submit(machine, start_line=N)
    assert response["ok"], response
    job_id = response["job"]["id"]
    status = machine.controller.status()
    assert status["job"]["start_line"] == N
    assert any(line.startswith(f"job {job_id} part.nc from line {N}: ") for line in format_status(status))
    info = wait_job(machine, job_id)
    outcome = info["outcome"]
    assert outcome["outcome"] == "completed", outcome["reason"]
    assert outcome["start_line"] == N and info["plan"]["start_line"]["line"] == N
    assert info["plan"]["start_line"]["spindle"] == "cw" and info["plan"]["start_line"]["spindle_rpm"] == 3000
    assert outcome["line_reached"]["where"] == "part.nc:8"  # line numbers are the file's own

    trace = read_trace(Path(info["folder"]) / "trace.csv")
    x, y, z, feed = trace["x"], trace["y"], trace["z"], trace["feed"]
    moving_xy = np.flatnonzero(np.hypot(x, y) > EPS_MM)
    assert len(moving_xy), "the job never moved in X/Y"
    first_xy = moving_xy[0]
    assert z[first_xy] >= SAFE_Z_MM - EPS_MM  # up to safe Z before any X/Y motion
    assert z[:first_xy].max() == pytest.approx(SAFE_Z_MM, abs=EPS_MM)
    descending = first_xy + np.flatnonzero(z[first_xy:] < SAFE_Z_MM - EPS_MM)[0]
    np.testing.assert_allclose((x[descending], y[descending]), START_POINT[:2], atol=1e-3)  # across at safe Z first
    assert np.all(z[first_xy:descending] >= SAFE_Z_MM - EPS_MM)
    at_start = descending + np.flatnonzero(np.abs(z[descending:] - START_POINT[2]) < EPS_MM)[0]
    assert feed[descending:at_start].max() <= FEED_MM_S * (1 + FLUCTUATION_LIMIT)  # down at the program's feed
    assert feed[first_xy:descending].max() > 2 * FEED_MM_S  # across at rapid
    np.testing.assert_allclose((x[-1], y[-1], z[-1]), (10.0, 15.0, -2.0), atol=1e-3)  # lines 7 and 8 ran

    spindle = [e for e in outcome["machine_events"] if e.get("code") == "M3"]
    assert spindle and spindle[0]["at"] == f"part.nc:{N}" and spindle[0]["at_speed"]
    first_motion = min(np.flatnonzero(np.abs(z) > EPS_MM)[0], first_xy)
    assert spindle[0]["row"] <= first_motion  # the spindle was started (and waited for) before any motion


@pytest.mark.parametrize("start_line, says", [
    (40, "part.nc:40: past the end of the program: the file has 10 lines"),
    (10, "part.nc:10: no motion from this line on: nothing to start"),
    (0, "field 'start_line': must be a line number >= 1, got 0"),
    (2.5, "field 'start_line': must be a line number >= 1, got 2.5"),
])
def test_a_start_line_that_cannot_be_used_is_refused_with_one_line(machine, start_line, says):
    response = submit(machine, start_line=start_line)
    assert not response["ok"]
    assert response["error"] == says
    assert machine.controller is not None and machine.controller.status()["job"] is None


def test_a_yaml_curve_program_has_no_start_line(machine):
    with Client(machine.config.control.socket) as client:
        response = client.request("submit", name="curve.yaml", program="curves: []\n", start_line=3)
    assert not response["ok"]
    assert response["error"] == "curve.yaml: a start line is for G-code: a YAML curve program has no lines to start from"
