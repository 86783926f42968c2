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


@pytest.fixture
def demo_on_a_private_bus(monkeypatch):
    """cli.demo with its configuration on a private virtual channel (tests may run side by side)."""
    import dataclasses
    import uuid

    from nurbsmotion.cli import demo
    from nurbsmotion.config import parse_config

    config = parse_config(demo.data.read_text("demo.yaml"), "demo.yaml")
    private = dataclasses.replace(config, bus=dataclasses.replace(config.bus, channel=f"demo-{uuid.uuid4().hex}"))
    monkeypatch.setattr(demo, "parse_config", lambda text, name: private)
    return demo


def _failing_on_the_program(demo, monkeypatch, failure) -> None:
    """The demo's follow() calls ``failure()`` when it follows the program's job."""
    follow = demo.follow

    def broken_follow(client, job_id, on_status):
        if client.call("status")["job"]["name"] == demo.PROGRAM_NAME:
            failure()
        return follow(client, job_id, on_status)

    monkeypatch.setattr(demo, "follow", broken_follow)


def _program_job(data_dir):
    from nurbsmotion.cli import demo
    from nurbsmotion.service.records import JobRecords

    records = JobRecords(data_dir).all()
    assert all(r.outcome() is not None for r in records)  # no job left without its outcome
    [job] = [r for r in records if (r.plan() or {}).get("program") == demo.PROGRAM_NAME]
    return job


@pytest.mark.slow
def test_a_demo_that_fails_while_its_job_runs_stops_it_and_the_record_says_why(tmp_path, monkeypatch, capsys,
                                                                                 demo_on_a_private_bus):
    """Issue 26.1: a demo crash left a stray 'stopped: the daemon was asked to end' job."""
    import argparse

    demo = demo_on_a_private_bus

    def boom():
        raise RuntimeError("boom")

    _failing_on_the_program(demo, monkeypatch, boom)
    args = argparse.Namespace(config=None, data_dir=str(tmp_path / "var"), no_progress=True)
    with pytest.raises(RuntimeError, match="boom"):
        demo.run(args)
    job = _program_job(tmp_path / "var")
    outcome = job.outcome()
    assert outcome["outcome"] == "stopped" and outcome["reason"] == "stopped: the demo failed: RuntimeError: boom"
    assert f"job {job.job_id} stopped; its record: " in capsys.readouterr().err


@pytest.mark.slow
def test_sigterm_ends_the_demo_as_ctrl_c_does_and_leaves_nothing_behind(tmp_path, monkeypatch, demo_on_a_private_bus):
    """Issue 26.1: SIGTERM (``timeout``, ``kill``) ended the demo at once: its job folder had
    no outcome and its socket's folder stayed in the temporary directory."""
    import argparse
    import os
    import signal
    import tempfile

    demo = demo_on_a_private_bus

    def reached_the_test(signum, frame):
        raise AssertionError("SIGTERM reached the test's handler: the demo did not handle it")

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    _failing_on_the_program(demo, monkeypatch, lambda: os.kill(os.getpid(), signal.SIGTERM))
    previous = signal.signal(signal.SIGTERM, reached_the_test)
    try:
        args = argparse.Namespace(config=None, data_dir=str(tmp_path / "var"), no_progress=True)
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            demo.run(args)
        assert signal.getsignal(signal.SIGTERM) is reached_the_test  # restored
    finally:
        signal.signal(signal.SIGTERM, previous)
    outcome = _program_job(tmp_path / "var").outcome()
    assert outcome["outcome"] == "stopped" and outcome["reason"] == "stopped: the demo was interrupted (SIGTERM)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["var"]  # the socket's folder removed
