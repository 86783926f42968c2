"""The daemon as a user runs it: a subprocess with in-process simulated drives, driven over
its control socket (and by the CLI client)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.cli import main
from nurbsmotion.service.protocol import MAX_REQUEST_BYTES
from nurbsmotion.service.records import JobRecords
from nurbsmotion.service.verify import held_plan_held, planned_counts, recorded_counts
from tests.integration.daemon_helpers import DaemonProcess, daemon  # noqa: F401 (fixture)
from tests.helpers import wait_for

SHORT = "G21 G90\nG01 X4 Y2 F3000\nG01 X0 Y3 Z1\n"  # ~0.3 s at 50 mm/s
LONG = "G21 G90\nG01 X60 Y20 F6000\n"  # ~0.8 s, 100 mm/s at cruise
# Stopped by SIGTERM: long enough that a signal delayed by a loaded machine still lands in the
# cruise (a controlled stop during the plan's own deceleration adds both: fieldbus issue).
LONGER = "G21 G90\nG01 X90 Y40 F6000\n"  # ~1.1 s



@pytest.fixture(autouse=True)
def _a_machine_ready_for_the_test(request):
    """Tests share one daemon: one that failed midway may have left it in fault; reset it
    first (as an operator would) so that one failure stays one failure."""
    if "daemon" in request.fixturenames:
        shared = request.getfixturevalue("daemon")
        if shared.request("status")["state"] == "fault":
            assert shared.request("reset")["ok"]
            wait_for(lambda: shared.request("status")["state"] == "idle", what="the shared daemon idle after reset")
    yield


def _back_home(daemon: DaemonProcess) -> None:
    """Return the axes to the origin with a short program (the tests share one daemon)."""
    status = daemon.request("status")
    if status["state"] == "idle" and any(abs(a["commanded_mm"]) > 1e-6 for a in status["axes"]):
        job = daemon.request("submit", name="home.nc", program="G01 X0 Y0 Z0 F3000\n")["job"]
        daemon.wait_job_end(job["id"])


def test_a_job_completes_and_the_drives_applied_exactly_the_plan(daemon):
    response = daemon.request("submit", name="short.nc", program=SHORT)
    assert response["ok"], response
    job = daemon.wait_job_end(response["job"]["id"])
    assert job["outcome"]["outcome"] == "completed"
    assert job["outcome"]["sent"] == job["outcome"]["planned"] == job["plan"]["cycles"]
    folder = Path(job["folder"])
    assert (folder / "program.nc").read_text() == SHORT
    plan = planned_counts(folder, daemon.config)
    recorded, _ = recorded_counts(folder, daemon.config)
    assert len(plan) == job["plan"]["cycles"] and len(recorded) > len(plan)
    assert held_plan_held(recorded, plan)
    sync_frames = [line for line in (folder / "traffic.log").read_text().splitlines() if " 080#" in line]
    assert len(sync_frames) >= len(plan)  # monitoring.traffic_log: the job's frames in its record
    assert daemon.request("status")["state"] == "idle"
    _back_home(daemon)


def daemon_threads(pid: int) -> list[tuple[int, int, set[int]]]:
    """(policy, SCHED_FIFO priority, CPUs) of every thread of process ``pid`` still running."""
    threads = []
    for entry in Path(f"/proc/{pid}/task").iterdir():
        tid = int(entry.name)
        try:
            threads.append((os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority,
                            os.sched_getaffinity(tid)))
        except OSError:  # it ended meanwhile
            continue
    return threads


def test_the_daemons_normal_threads_stay_off_the_realtime_cpu_during_a_job(daemon):
    """runtime.reserve_realtime_cpu: only the SCHED_FIFO threads above the publisher's
    priority run on the last CPU; every other thread (control clients, job watcher, planner
    side, publisher) on the others, including those started for the job."""
    cpus = os.sched_getaffinity(0)
    if len(cpus) < 2 or not hasattr(os, "sched_getscheduler"):
        pytest.skip("needs two CPUs and Linux scheduling calls")
    realtime, normal = max(cpus), cpus - {max(cpus)}
    assert f"cpus realtime={realtime} normal={','.join(map(str, sorted(normal)))}" in daemon.log()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as subscriber:  # the publisher's thread too
        subscriber.connect(str(daemon.socket))
        subscriber.sendall(b'{"cmd": "subscribe"}\n')
        job = daemon.request("submit", name="long.nc", program=LONG)["job"]
        daemon.wait_progress(0.2)
        assert daemon.proc is not None
        threads = daemon_threads(daemon.proc.pid)
    daemon.wait_job_end(job["id"])
    fifo_above_publisher = [t for t in threads if t[0] == os.SCHED_FIFO and t[1] > 1]
    others = [t for t in threads if t not in fifo_above_publisher]
    assert others and all(t[2] == normal for t in others), others
    assert all(t[2] == {realtime} for t in fifo_above_publisher), fifo_above_publisher
    if os.geteuid() == 0:  # SCHED_FIFO allowed: the cycle, receive and simulated drives' threads
        assert len(fifo_above_publisher) >= 3
    _back_home(daemon)


def test_a_bad_program_is_rejected_with_its_lines_and_nothing_moves(daemon):
    before = daemon.request("status")
    jobs_before = sorted(JobRecords(daemon.data_dir).root.glob("*"))
    response = daemon.request("submit", name="bad.nc", program="G01 X1 F3000\nG01 Q7\nG01 X500\n")
    assert response["ok"] is False
    assert any(line.startswith("bad.nc:2") for line in response["errors"]), response
    after = daemon.request("status")
    assert after["state"] == "idle" and after["job"] is None
    assert [a["commanded_mm"] for a in after["axes"]] == [a["commanded_mm"] for a in before["axes"]]
    [rejected] = sorted(set(JobRecords(daemon.data_dir).root.glob("*")) - set(jobs_before))
    outcome = json.loads((rejected / "outcome.json").read_text())  # the rejection leaves a record, nothing else
    assert outcome["outcome"] == "rejected" and outcome["errors"] == response["errors"]
    assert sorted(p.name for p in rejected.iterdir()) == ["outcome.json", "program.nc"]


def test_soft_limits_are_checked_before_motion_and_name_the_program_line(daemon):
    response = daemon.request("submit", name="far.nc", program="G21 G90\nG01 X150 F3000\n")
    assert response["ok"] is False
    assert response["error"] == "far.nc:2: X150: axis X would reach 150 mm, beyond the soft limit 100 mm"
    assert daemon.request("status")["job"] is None


def test_the_socket_refuses_bad_requests_and_keeps_serving(daemon):
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(30.0)
        s.connect(str(daemon.socket))
        reader = s.makefile("rb")
        for line, field in ((b"{not json\n", "request"), (b'{"cmd": "override", "percent": "x"}\n', "'percent'"),
                            (b'{"cmd": "launch"}\n', "'cmd'"), (b'{"cmd": "submit", "name": "a.nc"}\n', "'program'")):
            s.sendall(line)
            response = json.loads(reader.readline())
            assert response["ok"] is False and field in response["error"]
        s.sendall(b'{"cmd": "submit", "name": "big.nc", "program": "' + b"G" * (MAX_REQUEST_BYTES + 1) + b'"}\n')
        response = json.loads(reader.readline())
        assert response["ok"] is False and f"{MAX_REQUEST_BYTES // 1048576} MB limit" in response["error"]
        s.sendall(b'{"cmd": "status"}\n')
        assert json.loads(reader.readline())["ok"] is True
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:  # leaves mid-request
        s.connect(str(daemon.socket))
        s.sendall(b'{"cmd": "sub')
    assert daemon.request("status")["ok"] is True


def test_the_cli_client_runs_a_program_and_reports_status(daemon, tmp_path, capsys):
    program = tmp_path / "part.nc"
    program.write_text(SHORT)
    assert main(["run", "--socket", str(daemon.socket), "--no-progress", str(program)]) == 0
    assert "completed" in capsys.readouterr().out
    bad = tmp_path / "bad.nc"
    bad.write_text("G01 Q7\n")
    assert main(["run", "--socket", str(daemon.socket), str(bad)]) == 2
    assert "bad.nc:1" in capsys.readouterr().err
    assert main(["status", "--json", "--socket", str(daemon.socket)]) == 0
    assert json.loads(capsys.readouterr().out)["state"] == "idle"
    assert main(["stop", "--socket", str(daemon.socket)]) == 2  # nothing to stop
    assert "no job is running" in capsys.readouterr().err
    assert main(["status", "--socket", str(tmp_path / "none.sock")]) == 3
    assert capsys.readouterr().err.strip().endswith(f"no daemon at {tmp_path / 'none.sock'} (is it running?)")
    _back_home(daemon)


def test_a_fault_during_a_job_is_recorded_then_reset_allows_a_new_job(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONG)["job"]["id"]
    daemon.wait_progress(0.3)
    assert daemon.request("inject_fault", spec="node=2,kind=fault,code=0x2310")["ok"]
    job = daemon.wait_job_end(job_id)
    outcome = job["outcome"]
    assert outcome["outcome"] == "fault" and outcome["fault"]["node"] == 2
    assert outcome["fault"]["code"] == 0x2310 and outcome["fault"]["code_hex"] == "0x2310"  # the EMCY code
    assert 0 < outcome["fault"]["cycle"] < outcome["fault"]["master_cycle"]  # job-relative
    assert 0 < outcome["sent"] < outcome["planned"]
    status = daemon.request("status")
    assert status["state"] == "fault" and status["faults"]
    assert all(a["drive_state"] != "OPERATION ENABLED" for a in status["axes"] if a["node"] == 2)
    positions = [a["actual_mm"] for a in status["axes"]]
    wait_for(lambda: daemon.request("status")["phase"] == "disabled", 5.0, "the drives to be disabled")
    refused = daemon.request("submit", name="short.nc", program=SHORT)
    assert refused["ok"] is False and "reset" in refused["error"]
    assert daemon.request("reset")["ok"]
    status = daemon.request("status")
    assert status["state"] == "idle" and status["faults"] == []
    assert np.allclose([a["actual_mm"] for a in status["axes"]], positions, atol=0.05)
    again = daemon.request("submit", name="short.nc", program=SHORT)
    assert again["ok"], again
    assert daemon.wait_job_end(again["job"]["id"])["outcome"]["outcome"] == "completed"
    _back_home(daemon)


def test_a_stop_during_the_plans_deceleration_stays_within_the_axis_limits(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONG)["job"]["id"]
    daemon.wait_progress(0.85)
    assert daemon.request("stop")["ok"]
    job = daemon.wait_job_end(job_id)
    assert job["outcome"]["outcome"] in ("stopped", "completed")  # the job may end before the stop lands
    _assert_within_axis_limits(recorded_counts(Path(job["folder"]), daemon.config)[0], daemon.config)
    _back_home(daemon)


def test_abort_quick_stops_and_reset_brings_the_drives_back(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONG)["job"]["id"]
    daemon.wait_progress(0.3)
    assert daemon.request("abort")["ok"]
    outcome = daemon.wait_job_end(job_id)["outcome"]
    assert outcome["outcome"] == "aborted" and outcome["sent"] < outcome["planned"]
    wait_for(lambda: daemon.request("status")["phase"] == "disabled", 5.0, "the drives to be disabled")
    first = [a["actual_mm"] for a in daemon.request("status")["axes"]]
    assert daemon.request("status")["state"] == "fault"
    assert daemon.request("submit", name="short.nc", program=SHORT)["ok"] is False
    assert daemon.request("reset")["ok"]
    status = daemon.request("status")
    assert status["state"] == "idle"
    assert np.allclose([a["actual_mm"] for a in status["axes"]], first, atol=0.05)  # stopped where it was
    _back_home(daemon)


def test_feed_override_changes_the_playback_rate_within_the_axis_limits(daemon):
    job_id = daemon.request("submit", name="long.nc", program=LONG)["job"]["id"]
    daemon.wait_progress(0.2)
    slow = daemon.request("override", percent=50)
    assert slow["ok"] and slow["effective_percent"] == pytest.approx(50.0)
    assert daemon.request("status")["override"]["effective_percent"] == pytest.approx(50.0)
    daemon.wait_progress(0.4)
    fast = daemon.request("override", percent=150)
    max_percent = daemon.request("status")["override"]["max_percent"]
    assert fast["effective_percent"] == pytest.approx(min(150.0, max_percent))
    job = daemon.wait_job_end(job_id)
    assert job["outcome"]["outcome"] == "completed"
    folder = Path(job["folder"])
    recorded, _ = recorded_counts(folder, daemon.config)
    plan = planned_counts(folder, daemon.config)
    assert len(recorded) > len(plan)  # half speed for a while: more cycles than planned
    assert (recorded[-1] == plan[-1]).all()
    _assert_within_axis_limits(recorded, daemon.config)
    assert daemon.request("override", percent=100)["ok"]
    _back_home(daemon)


def test_sigterm_mid_job_stops_along_the_path_and_exits_cleanly(tmp_path):
    records = JobRecords(tmp_path)
    orphan = records.create("old.nc", "G01 X1\n")  # a job a killed daemon left without outcome
    proc = DaemonProcess(tmp_path)
    proc.notify_socket = proc.folder / "notify"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(proc.notify_socket))
    notify.settimeout(5.0)
    try:
        proc.start()
        assert notify.recv(64) == b"READY=1"  # systemd Type=notify
        assert orphan.outcome()["outcome"] == "interrupted"
        job_id = proc.request("submit", name="longer.nc", program=LONGER)["job"]["id"]
        proc.wait_progress(0.3)
        assert proc.proc is not None
        proc.proc.send_signal(signal.SIGTERM)
        assert proc.proc.wait(15.0) == 0, proc.log()[-2000:]
        assert not proc.socket.exists()
        record = records.find(job_id)
        assert record is not None
        outcome = record.outcome()
        assert outcome["outcome"] == "stopped", outcome
        assert outcome["sent"] < outcome["planned"]
        _assert_within_axis_limits(recorded_counts(record.folder, proc.config)[0], proc.config)
        assert notify.recv(64) == b"STOPPING=1"
    finally:
        notify.close()
        proc.close()


def test_no_drives_on_the_bus_is_one_error_line_and_nothing_left_behind(tmp_path):
    proc = DaemonProcess(tmp_path)
    proc.config_path.write_text(proc.config_path.read_text().replace("simulate: true", "simulate: false"))
    try:
        result = subprocess.run([sys.executable, "-m", "nurbsmotion", "daemon", "--config", str(proc.config_path)],
                                capture_output=True, text=True, timeout=30, env=proc.environment())
    finally:
        proc.close()
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "node 1" in lines[0] and "boot-up" in lines[0], result.stderr
    assert not proc.socket.exists()


def _assert_within_axis_limits(counts: np.ndarray, config) -> None:
    """No set-point jump: per-SYNC velocity and acceleration within each axis' limits (plus
    the rounding of set-points to whole counts: 1 count per step, 2 per second difference)."""
    period = config.cycle_period_s
    for j, axis in enumerate(config.axes):
        mm = counts[:, j] / axis.counts_per_mm
        v = np.abs(np.diff(mm)) / period
        a = np.abs(np.diff(mm, n=2)) / period**2
        count_mm = 1.0 / axis.counts_per_mm
        assert v.max() <= axis.max_velocity_mm_s + count_mm / period, f"axis {axis.name}: {v.max():.1f} mm/s"
        assert a.max() <= axis.max_accel_mm_s2 + 2 * count_mm / period**2, f"axis {axis.name}: {a.max():.0f} mm/s²"
