"""What a user reads after a job, against the daemon subprocess (simulated drives, the real
fieldbus master): the daemon's log lines at its default level, the job record with the
drives' feedback from the TPDOs, `nurbsmotion jobs`, and `run` while the daemon ends."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from nurbsmotion.cli import main
from nurbsmotion.sim import read_csv
from nurbsmotion.service.records import DRIVES_DIR
from tests.integration.daemon_helpers import DaemonProcess
from tests.helpers import wait_for

SHORT = "G21 G90\nG01 X4 Y2 F3000\n(a comment)\nG01 X0 Y3 Z1\n"
LONGER = "G21 G90\nG01 X90 Y40 F6000\n"  # ~1.1 s
BACK = "G21 G90\nG01 X0 Y0 Z0 F6000\n"


@pytest.fixture(scope="module")
def quiet_daemon(tmp_path_factory):
    """A daemon started without -v: what an operator sees by default."""
    proc = DaemonProcess(tmp_path_factory.mktemp("data"))
    proc.verbose = []
    try:
        yield proc.start()
    finally:
        proc.close()


def _events(log: str) -> list[str]:
    return [line.split(" ", 4)[4] for line in log.splitlines() if " INFO " in line]


def test_the_daemon_logs_ready_jobs_rejections_and_overrides_at_its_default_level(quiet_daemon):
    daemon = quiet_daemon
    # the socket answers a moment before the line is written (the start-up's last step)
    wait_for(lambda: any(e.startswith("daemon_ready ") for e in _events(daemon.log())), 5.0, "daemon_ready")
    rejected = daemon.request("submit", name="bad.nc", program="G01 Q7\n")
    assert not rejected["ok"]
    daemon.request("override", percent=80)
    job = daemon.request("submit", name="short.nc", program=SHORT)["job"]
    daemon.wait_job_end(job["id"])
    events = wait_for(lambda: [e for e in _events(daemon.log()) if e.startswith("job_ended ")] and
                        _events(daemon.log()), 5.0, "the job_ended line")
    [rejection] = [e for e in events if e.startswith("submit_rejected ")]
    assert "name=bad.nc" in rejection and 'first="bad.nc:1: Q7' in rejection
    assert any(e.startswith("override_changed requested_percent=80 ") for e in events)
    assert any(e.startswith("override_changed requested_percent=100 ") and "reason=new_job" in e for e in events)
    [started] = [e for e in events if e.startswith(f"job_started job={job['id']} ")]
    [ended] = [e for e in events if e.startswith(f"job_ended job={job['id']} ")]
    assert "name=short.nc" in started and "outcome=completed" in ended and "line=short.nc:4" in ended
    back = daemon.request("submit", name="back.nc", program=BACK)["job"]
    daemon.wait_job_end(back["id"])


def test_a_record_shows_what_the_drives_did_not_only_the_plan(quiet_daemon):
    daemon = quiet_daemon
    job = daemon.request("submit", name="short.nc", program=SHORT)["job"]
    info = daemon.wait_job_end(job["id"])
    folder, outcome = Path(info["folder"]), info["outcome"]
    assert json.loads((folder / "config.json").read_text())["axes"][2]["mode"] == "ip"
    assert outcome["line_reached"]["where"] == "short.nc:4"
    assert outcome["started_at"] < outcome["ended_at"]
    assert [o["by"] for o in outcome["overrides"]] == ["job_start"]
    end = info["plan"]["end_mm"]
    for name, value in zip("XYZ", end):
        assert outcome["final_position"][name]["commanded_mm"] == pytest.approx(value, abs=1e-3)
        assert outcome["final_position"][name]["actual_mm"] == pytest.approx(value, abs=0.05)
    with open(folder / "feedback.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == outcome["feedback_rows"] >= 3 * info["plan"]["cycles"]
    cycles = [int(r["job_cycle"]) for r in rows]
    assert cycles == sorted(cycles) and min(cycles) <= 0 < info["plan"]["cycles"] <= max(cycles)
    by_axis: dict[str, list[int]] = defaultdict(list)
    for r in rows:
        assert int(r["statusword"]) & 0x6F == 0x27  # OPERATION ENABLED throughout
        by_axis[r["axis"]].append(int(r["position_counts"]))
    for axis in daemon.config.axes:  # the TPDOs carry the positions the simulated drives recorded
        drive = {r.position_actual_counts for r in read_csv(folder / DRIVES_DIR / f"node{axis.node_id}.csv")}
        seen = set(by_axis[axis.name])
        assert len(seen & drive) >= 0.9 * len(seen), axis.name
    back = daemon.request("submit", name="back.nc", program=BACK)["job"]
    daemon.wait_job_end(back["id"])


def test_jobs_lists_and_shows_records(quiet_daemon, capsys):
    daemon = quiet_daemon
    sock = ["--socket", str(daemon.socket)]
    assert main(["jobs", *sock]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert listing[0].startswith("id ") and any(" rejected " in line and "bad.nc" in line for line in listing)
    newest = listing[1].split()[0]
    assert main(["jobs", newest, *sock]) == 0
    shown = capsys.readouterr().out
    assert f"job {newest}  back.nc" in shown and "reached     back.nc:2: G01 X0 Y0 Z0 F6000" in shown
    assert "feedback.csv" in shown and "config.json" in shown
    assert main(["jobs", "--json", "-n", "1", *sock]) == 0
    assert [j["id"] for j in json.loads(capsys.readouterr().out)["jobs"]] == [newest]
    assert main(["jobs", "0123abcd", *sock]) == 2
    assert "no job '0123abcd'" in capsys.readouterr().err


def test_run_while_the_daemon_gets_sigterm_prints_the_outcome_not_an_internal_error(tmp_path):
    """Issue 15.8, end to end: `run` following a job while the daemon is told to end."""
    proc = DaemonProcess(tmp_path)
    program = proc.folder / "longer.nc"
    program.write_text(LONGER)
    try:
        proc.start()
        env = {**proc.environment(), "NURBSMOTION_SOCKET": str(proc.socket)}
        run = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "run", "--no-progress", str(program)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        proc.wait_progress(0.3)
        assert proc.proc is not None
        proc.proc.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=30)
        assert proc.proc.wait(15.0) == 0
    finally:
        proc.close()
    assert "internal error" not in err and "Traceback" not in err, err
    assert run.returncode == 1, out + err
    assert "stopped" in out and "the daemon was asked to end" in out and "reached longer.nc:2" in out, out + err
