"""MDI: G-code lines run from where the axes are, checked and recorded like a program."""

from __future__ import annotations

from pathlib import Path

from nurbsmotion.service.verify import held_plan_held, planned_counts, recorded_counts
from tests.integration.daemon_helpers import DaemonProcess, daemon  # noqa: F401 (fixture)


def _mdi(daemon: DaemonProcess, text: str) -> dict:
    response = daemon.request("mdi", text=text)
    assert response["ok"], response
    return daemon.wait_job_end(response["job"]["id"])


def _commanded(daemon: DaemonProcess) -> list[float]:
    return [round(a["commanded_mm"], 6) for a in daemon.request("status")["axes"]]


def test_mdi_runs_from_the_commanded_position_and_is_recorded_as_a_job(daemon):
    job = _mdi(daemon, "G21 G90 G01 X10 Y5 F3000")
    assert job["outcome"]["outcome"] == "completed" and job["plan"]["program"] == "<mdi>"
    assert _commanded(daemon) == [10.0, 5.0, 0.0]
    folder = Path(job["folder"])
    assert held_plan_held(recorded_counts(folder, daemon.config)[0], planned_counts(folder, daemon.config))
    job = _mdi(daemon, "G01 Y-5 F3000")  # X is not named: it stays where it is
    assert job["outcome"]["outcome"] == "completed" and _commanded(daemon) == [10.0, -5.0, 0.0]
    assert daemon.request("jobs", limit=1)["jobs"][0]["name"] == "<mdi>"
    _mdi(daemon, "G01 X0 Y0 Z0 F3000")


def test_mdi_gets_the_program_checks_and_is_refused_while_a_job_runs(daemon):
    beyond = daemon.request("mdi", text="G01 X150 F3000")
    assert not beyond["ok"] and beyond["error"] == \
        "<mdi>:1: X150: axis X would reach 150 mm, beyond the soft limit 100 mm"
    bad = daemon.request("mdi", text="G01 X1 Q")
    assert not bad["ok"] and bad["error"].startswith("<mdi>:1:")
    assert daemon.request("mdi", text="  ")["error"] == "field 'text': no G-code to run"
    job_id = daemon.request("submit", name="long.nc", program="G21 G90\nG01 X60 Y20 F6000\n")["job"]["id"]
    busy = daemon.request("mdi", text="G01 X1 F600")
    assert not busy["ok"] and busy["error"].startswith("mdi: busy: job")
    daemon.wait_job_end(job_id)
    _mdi(daemon, "G01 X0 Y0 Z0 F3000")
    assert _commanded(daemon) == [0.0, 0.0, 0.0]


def test_the_mdi_command_line(daemon, capsys):
    from nurbsmotion.cli import main

    assert main(["mdi", "--no-progress", "--socket", str(daemon.socket), "G01 X2 F3000", "G01 Y2"]) == 0
    assert "completed" in capsys.readouterr().out
    assert _commanded(daemon) == [2.0, 2.0, 0.0]
    assert main(["mdi", "--socket", str(daemon.socket), "G01 X0 Y0 F3000"]) == 0


def test_an_mdi_line_without_motion_runs_as_a_still_job_where_programs_are_streamed(daemon):
    """This machine (lookahead, no spindle or I/O node) streams programs from its planner
    worker; MDI lines are planned whole, so one without motion (a work offset) runs as
    main's two-row still job instead of being refused as 'the program has no motion'."""
    job = _mdi(daemon, "G55")
    assert job["outcome"]["outcome"] == "completed", job["outcome"]
    refused = daemon.request("submit", name="still.nc", program="G21 G90\nG55\n")
    assert refused["ok"] is False and "no motion" in refused["error"]
