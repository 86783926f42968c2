"""No record is lost when the daemon itself dies: SIGKILL in the middle of a job, then a new
daemon on the same data directory marks that job 'interrupted', and every file the job had
written is complete (written to a temporary name and renamed)."""

from __future__ import annotations

import json
import signal

from nurbsmotion.planning.trace import read_trace
from nurbsmotion.service.records import JobRecords
from tests.integration.daemon_helpers import DaemonProcess

LONG = "G21 G90\nG01 X60 Y20 F4800\n"


def test_a_killed_daemon_loses_no_record(tmp_path):
    first = DaemonProcess(tmp_path)
    try:
        first.start()
        job_id = first.request("submit", name="long.nc", program=LONG)["job"]["id"]
        first.wait_progress(0.4)
        assert first.proc is not None
        first.proc.send_signal(signal.SIGKILL)
        first.proc.wait(15.0)
    finally:
        first.close()
    record = JobRecords(tmp_path).find(job_id)
    assert record is not None and record.outcome() is None  # killed: no outcome written
    second = DaemonProcess(tmp_path)
    try:
        second.start()
        job = second.request("job", id=job_id)["job"]
        assert job["outcome"]["outcome"] == "interrupted"
        assert second.request("status")["state"] == "idle"
    finally:
        second.close()
    assert (record.folder / "program.nc").read_text() == LONG
    plan = json.loads((record.folder / "plan.json").read_text())
    assert len(read_trace(record.folder / "trace.csv")["x"]) == plan["cycles"]
    assert not list(record.folder.glob(".*.tmp"))
