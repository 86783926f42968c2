"""`nurbsmotion demo`, the README's first command, runs Wang's curve end to end."""

import subprocess
import sys

import pytest

from tests.integration.daemon_helpers import subprocess_environment


@pytest.mark.slow
def test_the_demo_runs_wang_on_simulated_drives_and_writes_its_plot(tmp_path):
    result = subprocess.run([sys.executable, "-m", "nurbsmotion", "demo", "--no-progress", "--data-dir",
                             str(tmp_path / "var")], capture_output=True, text=True, timeout=120, env=subprocess_environment(),
                            cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr[-2000:]
    out = result.stdout
    lines = out.splitlines()
    # homing (simulated limit switch and index pulse), a jog and an MDI move come before the program
    assert lines[1] == "homing Y, X, Z (simulated limit switch and index pulses)"
    assert lines[2].startswith("  axis X: homed by negative limit switch, now at -19.99")
    assert lines[5].startswith("jog X+10 at 20 mm/s: completed, axes at X-9.99")
    assert lines[6] == "MDI G01 X5 Y5 F3000: completed, axes at X5.000 Y5.000 Z0.000"
    assert lines[7].startswith("planned wang_table1.nc")
    assert "outcome: completed" in out and "the drives applied exactly the planned sequence" in out
    plot = next(line.split(": ", 1)[1] for line in out.splitlines() if line.startswith("plot: "))
    with open(plot, "rb") as png:
        assert png.read(8) == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_a_demo_that_fails_while_its_job_runs_stops_it_and_the_record_says_why(tmp_path, monkeypatch, capsys):
    """Issue 26.1: a demo crash left a stray 'stopped: the daemon was asked to end' job."""
    import argparse
    import dataclasses
    import uuid

    from nurbsmotion.cli import demo
    from nurbsmotion.config import parse_config
    from nurbsmotion.service.records import JobRecords

    config = parse_config(demo.data.read_text("demo.yaml"), "demo.yaml")  # a private bus: tests may run side by side
    private = dataclasses.replace(config, bus=dataclasses.replace(config.bus, channel=f"demo-{uuid.uuid4().hex}"))
    monkeypatch.setattr(demo, "parse_config", lambda text, name: private)

    def broken_follow(client, job_id, on_status):
        if client.call("status")["job"]["name"] == demo.PROGRAM_NAME:
            raise RuntimeError("boom")
        return follow(client, job_id, on_status)

    follow = demo.follow
    monkeypatch.setattr(demo, "follow", broken_follow)
    args = argparse.Namespace(config=None, data_dir=str(tmp_path / "var"), no_progress=True)
    with pytest.raises(RuntimeError, match="boom"):
        demo.run(args)
    program_jobs = [r for r in JobRecords(tmp_path / "var").all() if (r.plan() or {}).get("program") == demo.PROGRAM_NAME]
    assert len(program_jobs) == 1
    outcome = program_jobs[0].outcome()
    assert outcome["outcome"] == "stopped" and outcome["reason"] == "stopped: the demo failed: RuntimeError: boom"
    assert f"job {program_jobs[0].job_id} stopped; its record: " in capsys.readouterr().err
