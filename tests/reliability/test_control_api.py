"""Abuse of the control API of a real daemon (a subprocess with simulated drives): every bad
request gets one clear error line, and a status request on a fresh connection is answered
after each abuse. Also: who may connect (SO_PEERCRED, socket mode and group) and that the
daemon never opens a network port."""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import threading
from pathlib import Path

import pytest

from nurbsmotion.service.protocol import MAX_REQUEST_BYTES
from tests.integration.daemon_helpers import DaemonProcess, daemon  # noqa: F401 (fixture)

NOBODY = 65534
TIMEOUT_S = 30.0

BAD_LINES = {
    "not json": b"{not json",
    "binary": bytes(range(256)).replace(b"\n", b""),
    "not utf-8": b'{"cmd": "status", "x": "\xff\xfe"}',
    "json array": b'["status"]',
    "json string": b'"status"',
    "json null": b"null",
    "deeply nested": b'{"cmd": "status", "x": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
    "cmd missing": b'{"name": "a.nc"}',
    "cmd not a string": b'{"cmd": 7}',
    "unknown command": b'{"cmd": "self_destruct"}',
    "unknown field": b'{"cmd": "status", "verbose": true}',
    "field missing": b'{"cmd": "submit", "name": "a.nc"}',
    "wrong type": b'{"cmd": "submit", "name": 3, "program": "G0 X1"}',
    "bool as number": b'{"cmd": "override", "percent": true}',
    "NaN": b'{"cmd": "override", "percent": NaN}',
    "infinite": b'{"cmd": "override", "percent": 1e999}',
    "huge integer": b'{"cmd": "override", "percent": ' + b"9" * 400 + b"}",
    "integer beyond int()": b'{"cmd": "override", "percent": ' + b"9" * 5000 + b"}",
    "out of range": b'{"cmd": "override", "percent": -5}',
    "empty name": b'{"cmd": "submit", "name": "", "program": "G0 X1"}',
    "control char in name": b'{"cmd": "submit", "name": "a\\u0000.nc", "program": "G0 X1"}',
    "lone surrogate id": b'{"cmd": "job", "id": "\\ud800"}',
    "path as id": b'{"cmd": "job", "id": "../../../etc"}',
    "bad program": b'{"cmd": "submit", "name": "bad.nc", "program": "G01 X1 F100\\nQ7\\n"}',
    "bad fault spec": b'{"cmd": "inject_fault", "spec": "node=9,kind=melt"}',
    "stop without job": b'{"cmd": "stop"}',
}



def connect(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(TIMEOUT_S)
    s.connect(str(path))
    return s


def ask(s: socket.socket, line: bytes) -> dict:
    s.sendall(line + b"\n")
    return json.loads(s.makefile("rb").readline())


def assert_serving(daemon: DaemonProcess) -> None:
    status = daemon.request("status")
    assert status["ok"] is True and status["state"] in ("idle", "running"), status


@pytest.mark.parametrize("name", list(BAD_LINES))
def test_a_bad_request_gets_one_error_line_and_the_daemon_keeps_serving(daemon, name):
    with connect(daemon.socket) as s:
        response = ask(s, BAD_LINES[name])
        assert response["ok"] is False, response
        assert response["error"] and "\n" not in response["error"]
        assert "internal error" not in response["error"], response["error"]
        assert ask(s, b'{"cmd": "status"}')["ok"] is True  # the same connection stays usable
    assert_serving(daemon)


def test_a_request_over_the_limit_is_refused_and_the_connection_stays_usable(daemon):
    with connect(daemon.socket) as s:
        program = b"G01 X1 F100\n" * (MAX_REQUEST_BYTES // 10)
        line = b'{"cmd": "submit", "name": "big.nc", "program": "' + program.replace(b"\n", b"\\n") + b'"}'
        response = ask(s, line)
        assert response["ok"] is False and f"{MAX_REQUEST_BYTES // 1048576} MB limit" in response["error"]
        assert ask(s, b'{"cmd": "status"}')["ok"] is True
    assert_serving(daemon)
    assert daemon.request("status")["job"] is None


@pytest.mark.parametrize("partial", [b'{"cmd": "sub', b'{"cmd": "submit", "name": "a.nc", "program": "' + b"G" * 3_000_000,
                                     b'{"cmd": "status"}\n'])
def test_clients_that_leave_mid_request_only_end_their_own_connection(daemon, partial):
    for _ in range(5):
        with connect(daemon.socket) as s:
            s.sendall(partial)  # and gone, without reading an answer
    assert_serving(daemon)


def test_many_concurrent_clients_are_served_or_told_busy(daemon):
    held = [connect(daemon.socket) for _ in range(24)]  # more than the 16 served at once
    try:
        answers = []
        for s in held:
            s.sendall(b'{"cmd": "status"}\n')
        for s in held:
            line = s.makefile("rb").readline()
            answers.append(json.loads(line) if line else None)
        served = [a for a in answers if a and a["ok"]]
        busy = [a for a in answers if a and not a["ok"]]
        assert len(served) >= 1 and all("busy" in a["error"] for a in busy)
        assert len(served) + len(busy) == len(held)  # nobody is left without an answer
    finally:
        for s in held:
            s.close()
    errors: list[BaseException] = []

    def hammer() -> None:
        try:
            with connect(daemon.socket) as s:
                for _ in range(25):
                    assert ask(s, b'{"cmd": "status"}')["ok"] is True
        except BaseException as err:  # noqa: BLE001 - reported by the main thread
            errors.append(err)

    threads = [threading.Thread(target=hammer) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(TIMEOUT_S * 2)
    assert not errors and not any(t.is_alive() for t in threads)
    assert_serving(daemon)


# ---------------------------------------------------------------------- access


def _as_nobody(path: Path, gid: int = NOBODY) -> str:
    """Connect as uid 65534 in a forked child; returns the answer line or the OSError name."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: become nobody, ask, pass what happened up the pipe, exit at once
        code = 0
        try:
            os.setgroups([])
            os.setgid(gid)
            os.setuid(NOBODY)
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                s.settimeout(10.0)
                s.connect(str(path))
                try:
                    s.sendall(b'{"cmd": "status"}\n')
                except BrokenPipeError:  # refused at once: the daemon's one line is still there to read
                    pass
                os.write(write_end, s.makefile("rb").readline() or b"closed")
        except OSError as err:
            os.write(write_end, f"OSError {err.errno}".encode())
        except BaseException as err:  # noqa: BLE001 - never run the parent's code in the child
            os.write(write_end, f"child failed: {err!r}".encode())
            code = 1
        finally:
            os._exit(code)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as pipe:
        answer = pipe.read().decode(errors="replace")
    os.waitpid(pid, 0)
    return answer


def _open_folder_to_others(daemon: DaemonProcess) -> None:
    os.chmod(daemon.folder, 0o755)  # mkdtemp is 0700: let others reach the socket file itself


needs_root = pytest.mark.skipif(os.getuid() != 0, reason="needs root to act as another user")


@needs_root
def test_the_socket_is_0660_owned_by_the_daemon_user_and_refuses_other_users(daemon):
    info = os.stat(daemon.socket)
    assert stat.S_ISSOCK(info.st_mode) and stat.S_IMODE(info.st_mode) == 0o660
    assert info.st_uid == os.getuid() and info.st_gid == os.getgid()
    _open_folder_to_others(daemon)
    assert _as_nobody(daemon.socket) == f"OSError {13}"  # EACCES: the file mode keeps others out
    os.chmod(daemon.socket, 0o666)  # even with the file opened up, SO_PEERCRED refuses
    try:
        answer = json.loads(_as_nobody(daemon.socket))
    finally:
        os.chmod(daemon.socket, 0o660)
    assert answer["ok"] is False and answer["error"].startswith("permission denied: uid 65534")
    assert_serving(daemon)


@needs_root
def test_the_configured_group_lets_its_members_in(tmp_path):
    proc = DaemonProcess(tmp_path)
    proc.config_path.write_text(proc.config_path.read_text().replace("control: {", "control: {group: nogroup, "))
    try:
        proc.start()
        _open_folder_to_others(proc)
        info = os.stat(proc.socket)
        assert info.st_gid == NOBODY and stat.S_IMODE(info.st_mode) == 0o660
        assert json.loads(_as_nobody(proc.socket, gid=NOBODY))["ok"] is True
    finally:
        proc.close()
        shutil.rmtree(proc.folder, ignore_errors=True)


def _socket_inodes(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    return inodes


def _network_inodes(pid: int) -> set[str]:
    """Inodes of every TCP/UDP socket (v4 and v6) in the process' network namespace."""
    inodes = set()
    for table in ("tcp", "tcp6", "udp", "udp6", "raw", "raw6"):
        path = Path(f"/proc/{pid}/net/{table}")
        if path.exists():
            for row in path.read_text().splitlines()[1:]:
                inodes.add(row.split()[9])
    return inodes


def test_the_daemon_opens_no_network_port(daemon):
    assert daemon.proc is not None
    pid = daemon.proc.pid
    ours = _socket_inodes(pid)
    assert ours, "the daemon should at least have its control socket"
    assert not ours & _network_inodes(pid)


def test_abuse_during_a_job_does_not_disturb_the_motion(daemon):
    from nurbsmotion.service.verify import held_plan_held, planned_counts, recorded_counts

    response = daemon.request("submit", name="run.nc", program="G21 G90\nG01 X30 Y-20 Z4 F3000\n")
    assert response["ok"], response
    daemon.wait_progress(0.1)
    for name, line in BAD_LINES.items():
        if name == "stop without job":  # with a job running, that one is a valid request
            continue
        with connect(daemon.socket) as s:
            answer = ask(s, line)
            assert answer["ok"] is False and "internal error" not in answer["error"]
    busy = daemon.request("submit", name="second.nc", program="G01 X1 F100\n")
    assert busy["ok"] is False and "busy" in busy["error"]
    job = daemon.wait_job_end(response["job"]["id"])
    assert job["outcome"]["outcome"] == "completed", job["outcome"]
    folder = Path(job["folder"])
    assert held_plan_held(recorded_counts(folder, daemon.config)[0], planned_counts(folder, daemon.config))
    home = daemon.request("submit", name="home.nc", program="G01 X0 Y0 Z0 F3000\n")
    assert daemon.wait_job_end(home["job"]["id"])["outcome"]["outcome"] == "completed"
