"""Ctrl-C and a closed output pipe end a command quietly at any moment (issue 26.1): exit
code 130 after SIGINT, 141 when the reader of stdout left, one line or none on stderr,
never a traceback. Real ``python -m nurbsmotion`` processes against a fake daemon (a Unix
socket answering canned JSON lines), so each moment can be reached on purpose."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from tests.integration.daemon_helpers import subprocess_environment

WAIT_S = 60.0
ROW = {"id": "65aa9203", "name": "p.nc", "submitted_at": "2026-11-24T09:53:23.358", "outcome": "completed",
       "reason": "", "line_reached": "p.nc:3", "motion_time_s": 1.48, "folder": "/var/jobs/x", "running": False}
MANY_ROWS = 3000  # ~300 kB of listing: more than a pipe holds, so the writer meets the closed end
JOB = {"id": "1d6fa14b", "name": "p.nc", "folder": "/var/jobs/y", "cycle": 5, "total": 100, "percent": 5.0,
       "feed_mm_s": 10.0, "override_percent": 100.0, "line": "p.nc:2", "paused": None, "tool": None}
STATUS = {"ok": True, "state": "running", "phase": "streaming", "job": JOB,
          "override": {"requested_percent": 100.0, "effective_percent": 100.0}, "axes": [],
          "cycles": {"count": 1, "late": 0, "missed": 0, "send_errors": 0, "lateness_p99_ms": 0.0,
                     "lateness_max_ms": 0.0},
          "faults": [{"node": 1, "axis": "X", "kind": "emcy", "code": 1, "code_hex": "0x0001", "measured": None,
                      "cycle": i, "master_cycle": i, "message": "x" * 80} for i in range(MANY_ROWS)],
          "last_job": None}


class FakeDaemon:
    """A Unix socket that answers each request line with ``answer(request)``; None: no answer
    (the client waits). Records the requests and whether anybody connected."""

    def __init__(self, answer: Callable[[dict[str, Any]], dict[str, Any] | None]) -> None:
        self.path = Path(tempfile.mkdtemp(prefix="nm-")) / "ctl.sock"
        self.answer = answer
        self.requests: list[str] = []
        self.connected = threading.Event()
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.server.bind(str(self.path))
        self.server.listen(4)
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            self.connected.set()
            threading.Thread(target=self._talk, args=(conn,), daemon=True).start()

    def _talk(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rb") as lines:
            try:
                for line in lines:
                    request = json.loads(line)
                    self.requests.append(request["cmd"])
                    response = self.answer(request)
                    if response is not None:
                        conn.sendall(json.dumps(response).encode() + b"\n")
            except OSError:  # the client went away (it was interrupted): so does this connection
                return

    def close(self) -> None:
        self.server.close()


@pytest.fixture
def fake_daemon() -> Iterator[Callable[..., FakeDaemon]]:
    made: list[FakeDaemon] = []

    def make(answer: Callable[[dict[str, Any]], dict[str, Any] | None]) -> FakeDaemon:
        made.append(FakeDaemon(answer))
        return made[-1]

    yield make
    for daemon in made:
        daemon.close()


def start(*args: str, **popen: Any) -> subprocess.Popen[bytes]:
    """The command as a user at a terminal starts it: SIGINT at its default even when this test
    run was started with it ignored (``nohup ... &``), which the CLI rightly keeps ignored."""
    return subprocess.Popen([sys.executable, *args], env=subprocess_environment(), preexec_fn=_sigint_default,
                            **popen)


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def errors_of(stderr: bytes) -> list[str]:
    """stderr without the lines of ``-X importtime``."""
    return [line for line in stderr.decode().splitlines() if not line.startswith("import time:")]


def listing(request: dict[str, Any]) -> dict[str, Any]:
    return {"ok": True, "total": MANY_ROWS, "root": "/var/jobs", "jobs": [ROW] * MANY_ROWS}


@pytest.mark.parametrize("argv", [["jobs", "-n", str(MANY_ROWS)], ["status", "--json"]], ids=["jobs", "status-json"])
def test_a_reader_that_leaves_after_the_first_bytes_ends_the_command_quietly(fake_daemon, argv):
    daemon = fake_daemon(lambda r: listing(r) if r["cmd"] == "jobs" else STATUS)
    process = start("-m", "nurbsmotion", *argv, "--socket", str(daemon.path), stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE)
    assert process.stdout is not None and process.stderr is not None
    assert process.stdout.read(1)  # head -c1
    process.stdout.close()
    stderr = process.stderr.read()
    assert process.wait(WAIT_S) == 141
    assert errors_of(stderr) == []


def test_a_pipe_closed_before_any_output_ends_the_command_quietly(fake_daemon):
    daemon = fake_daemon(listing)
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the command writes anything
    process = start("-m", "nurbsmotion", "jobs", "-n", "1", "--socket", str(daemon.path), stdout=write_end,
                    stderr=subprocess.PIPE)
    os.close(write_end)
    _, stderr = process.communicate(timeout=WAIT_S)
    assert process.returncode == 141
    assert errors_of(stderr) == []


def interrupt_when(process: subprocess.Popen[bytes], line_says: str) -> None:
    """Send SIGINT once a stderr line contains ``line_says``."""
    assert process.stderr is not None
    for line in process.stderr:
        if line_says in line.decode():
            process.send_signal(signal.SIGINT)
            return
    raise AssertionError(f"no stderr line said {line_says!r}")


# what pip's console script for pyproject's entry point runs
CONSOLE_SCRIPT = "import sys; from nurbsmotion.__main__ import main; sys.exit(main())"


def test_ctrl_c_during_the_start_up_imports_is_one_line_and_130(fake_daemon):
    daemon = fake_daemon(lambda r: STATUS)
    process = start("-X", "importtime", "-c", CONSOLE_SCRIPT, "status", "--socket", str(daemon.path),
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    interrupt_when(process, "nurbsmotion.__main__")  # the entry point is imported: the CLI's imports begin
    _, stderr = process.communicate(timeout=WAIT_S)
    assert not daemon.connected.is_set()  # it was interrupted before it connected: during its imports
    assert process.returncode == 130
    assert errors_of(stderr) == ["nurbsmotion: interrupted"]


def test_ctrl_c_while_waiting_for_the_daemon_is_one_line_and_130(fake_daemon):
    daemon = fake_daemon(lambda r: None)  # connected, never answered
    process = start("-m", "nurbsmotion", "status", "--socket", str(daemon.path), stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE)
    assert daemon.connected.wait(WAIT_S)
    process.send_signal(signal.SIGINT)
    out, stderr = process.communicate(timeout=WAIT_S)
    assert process.returncode == 130
    assert errors_of(stderr) == ["nurbsmotion status: interrupted"] and out == b""


def test_ctrl_c_while_following_stops_the_job_and_a_second_one_leaves_it(fake_daemon):
    stop_sent = threading.Event()

    def answer(request: dict[str, Any]) -> dict[str, Any]:
        if request["cmd"] == "submit":
            return {"ok": True, "job": {"id": JOB["id"], "folder": JOB["folder"], "summary": {}}}
        if request["cmd"] == "stop":
            stop_sent.set()
            return {"ok": True, "job": JOB["id"], "state": "stopping"}
        return {**STATUS, "faults": []}  # the job runs on

    daemon = fake_daemon(answer)
    program = Path(daemon.path.parent / "p.nc")
    program.write_text("G01 X1 F600\n")
    process = start("-m", "nurbsmotion", "run", str(program), "--socket", str(daemon.path), stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE)
    assert process.stdout is not None
    process.stdout.readline()  # following: its first progress line
    process.send_signal(signal.SIGINT)  # the first Ctrl-C asks the daemon to stop the job
    assert stop_sent.wait(WAIT_S)
    process.send_signal(signal.SIGINT)  # the second leaves it running
    out, stderr = process.communicate(timeout=WAIT_S)
    assert process.returncode == 130
    assert errors_of(stderr) == ["stopping the job along the path (Ctrl-C again to leave it running)",
                                 "nurbsmotion run: interrupted"]
