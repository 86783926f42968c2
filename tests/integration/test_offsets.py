"""Offsets survive a daemon restart; the CLI shows and sets them; the gate refuses at submit."""

from __future__ import annotations

import pytest

from nurbsmotion.cli import main
from tests.integration.daemon_helpers import DaemonProcess


@pytest.fixture
def process(tmp_path):
    proc = DaemonProcess(tmp_path / "data")
    try:
        yield proc
    finally:
        proc.close()


def test_offsets_survive_a_restart_and_the_cli_shows_them(process, capsys):
    process.start()
    job = process.request("submit", name="setup.nc", program="G21 G90\nG10 L2 P2 X3 Y-2\nG55\nG1 X1 Y1 F3000\n")
    assert job["ok"], job
    assert process.wait_job_end(job["job"]["id"])["outcome"]["outcome"] == "completed"
    socket = ["--socket", str(process.socket)]
    assert main(["offsets", "G56", "X10", "Y-5", "Z0", *socket]) == 0
    process.close()

    process.start()  # a new daemon process: the offsets come from DATA_DIR/offsets.json
    capsys.readouterr()
    assert main(["offsets", *socket]) == 0
    shown = capsys.readouterr().out.splitlines()
    assert shown[0] == "active G55, tool unknown"
    assert "* G55    X3 Y-2 Z0" in shown and "  G56    X10 Y-5 Z0" in shown
    assert main(["status", *socket]) == 0
    assert "coordinates G55 (offset X3 Y-2 Z0 mm), G92 off, tool unknown" in capsys.readouterr().out
    job = process.request("submit", name="next.nc", program="G21 G90\nG1 X0 Y0 F3000\n")  # G55 X0 Y0 = machine 3 -2
    assert job["ok"] and job["job"]["summary"]["end_mm"][:2] == [3.0, -2.0]
    process.wait_job_end(job["job"]["id"])


def test_a_program_needing_a_spindle_is_refused_at_submit_and_recorded(process, capsys):
    process.start()
    response = process.request("submit", name="mill.nc", program="G21 G90\nG1 X1 F600\nM3 S12000\nG1 X2\nM6 T2\n")
    assert not response["ok"]
    assert response["errors"] == [  # the M6 on line 5 is no refusal: it becomes a pause
        f"mill.nc:3: M3 needs a spindle, and this machine has none (no spindle: key in {process.config_path})"]
    assert process.request("status")["state"] == "idle"
    assert main(["offsets", "--clear", "G99", "--socket", str(process.socket)]) == 2
    assert "field 'clear': must be one of G54" in capsys.readouterr().err
