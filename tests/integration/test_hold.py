"""Hold/resume and program pauses (M0, M6) through the daemon with simulated drives."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nurbsmotion.service.verify import on_planned_path, plan_with_holds, planned_counts, recorded_counts
from tests.integration.daemon_helpers import DaemonProcess, daemon  # noqa: F401 (fixture)
from tests.helpers import wait_for

LONGER = "G21 G90\nG01 X90 Y40 F6000\nG01 X0 Y0\n"  # ~2 s
PAUSES = "G21 G90\nG01 X10 Y5 F3000\nM0\nG01 X20 Y5\nT3 M6\nG01 X20 Y15\nG01 X0 Y0\nM30\n"


def _state(daemon: DaemonProcess, wanted: str) -> dict:
    return wait_for(lambda: (s := daemon.request("status"))["state"] == wanted and s, 20.0, f"state {wanted}")


def test_hold_rests_on_the_path_and_resume_completes_every_row(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONGER)["job"]["id"]
    daemon.wait_progress(0.3)
    assert daemon.request("hold")["state"] == "pausing"
    held = _state(daemon, "held")
    cycle = held["job"]["cycle"]
    wait_for(lambda: daemon.request("status")["cycles"]["count"] > held["cycles"]["count"] + 50, 20.0, "50 cycles")
    later = daemon.request("status")
    assert later["state"] == "held" and later["job"]["cycle"] == cycle and later["job"]["paused"] is None
    assert [a["commanded_mm"] for a in later["axes"]] == [a["commanded_mm"] for a in held["axes"]]
    assert all(abs(a["actual_mm"] - a["commanded_mm"]) < 1e-3 for a in later["axes"])  # at rest
    assert held["job"]["feed_mm_s"] == 0.0 and later["job"]["feed_mm_s"] == 0.0  # at rest: no feed, not the plan's
    assert daemon.request("resume")["ok"]
    job = daemon.wait_job_end(job_id)
    assert job["outcome"]["outcome"] == "completed"
    assert job["outcome"]["sent"] == job["outcome"]["planned"]
    folder = Path(job["folder"])
    plan = planned_counts(folder, daemon.config)
    recorded, _ = recorded_counts(folder, daemon.config)
    assert on_planned_path(recorded, plan)
    assert not plan_with_holds(recorded, plan)  # the ramps send points between the rows
    # rows are exact again after the resume ramp: the last 200 planned rows arrive as planned
    tail = plan[-200:]
    assert any(np.array_equal(recorded[i:i + 200], tail) for i in range(len(recorded) - 199))
    assert daemon.request("resume")["ok"] is False


def test_stop_while_held_ends_the_job_where_it_rests(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONGER)["job"]["id"]
    daemon.wait_progress(0.3)
    daemon.request("hold")
    _state(daemon, "held")
    assert daemon.request("stop")["ok"]
    job = daemon.wait_job_end(job_id)
    assert job["outcome"]["outcome"] == "stopped"
    assert daemon.request("status")["state"] == "idle"
    _home(daemon)


def test_a_program_with_m0_and_m6_pauses_at_its_rows_and_completes_after_two_resumes(daemon):
    _home(daemon)
    job_id = daemon.request("submit", name="part.nc", program=PAUSES)["job"]["id"]
    first = _state(daemon, "held")
    assert first["job"]["paused"] == "M0 at part.nc:3" and first["job"]["tool"] is None
    assert [round(a["commanded_mm"], 6) for a in first["axes"]] == [10.0, 5.0, 0.0]
    assert daemon.request("resume")["ok"]
    second = wait_for(lambda: (s := daemon.request("status"))["state"] == "held" and s["job"]["paused"] != first[
        "job"]["paused"] and s, 20.0, "the M6 pause")
    assert second["job"]["paused"] == "M6 tool change to T3 at part.nc:5" and second["job"]["tool"] == 3
    assert [round(a["commanded_mm"], 6) for a in second["axes"]] == [20.0, 5.0, 0.0]
    assert daemon.request("resume")["ok"]
    job = daemon.wait_job_end(job_id)
    assert job["outcome"]["outcome"] == "completed"
    folder = Path(job["folder"])
    plan = planned_counts(folder, daemon.config)
    recorded, _ = recorded_counts(folder, daemon.config)
    assert plan_with_holds(recorded, plan)  # every planned row once, in order; repeats only while held


def _home(daemon: DaemonProcess) -> None:
    status = daemon.request("status")
    if status["state"] == "idle" and any(abs(a["commanded_mm"]) > 1e-6 for a in status["axes"]):
        job = daemon.request("submit", name="home.nc", program="G01 X0 Y0 Z0 F3000\n")["job"]
        daemon.wait_job_end(job["id"])


def test_the_cli_holds_and_resumes(daemon, capsys):
    from nurbsmotion.cli import main

    _home(daemon)
    job_id = daemon.request("submit", name="long.nc", program=LONGER)["job"]["id"]
    daemon.wait_progress(0.2)
    assert main(["hold", "--socket", str(daemon.socket)]) == 0
    _state(daemon, "held")
    assert main(["resume", "--socket", str(daemon.socket)]) == 0
    assert daemon.wait_job_end(job_id)["outcome"]["outcome"] == "completed"
    out = capsys.readouterr().out
    assert f"job {job_id}: holding" in out and f"job {job_id}: resumed" in out
    assert main(["resume", "--socket", str(daemon.socket)]) == 2
    assert "resume: no job is running" in capsys.readouterr().err
    _home(daemon)
