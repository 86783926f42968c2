"""The control socket keeps serving through bad, oversized and abandoned requests."""

import json
import os
import select
import shutil
import socket
import stat
import tempfile
from pathlib import Path

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.service.access import PeerCredentials, peer_allowed
from nurbsmotion.service.client import Client, DaemonUnavailable
from nurbsmotion.service.protocol import MAX_REQUEST_BYTES, EncodedResponse
from nurbsmotion.service.server import ControlServer


def _handler(request):
    if request.cmd == "reset":
        raise InputError("reset", "nothing to reset")
    if request.cmd == "status":  # encoded ahead (as the daemon does in the cycle thread's slack): its line is sent
        answer = EncodedResponse({"ok": True, "cmd": "status"})
        answer.line = b'{"ok":true,"cmd":"status","encoded":"ahead"}\n'
        return answer
    return {"ok": True, "cmd": request.cmd}


@pytest.fixture
def server(tmp_path):
    srv = ControlServer(tmp_path / "ctl.sock", _handler, idle_timeout_s=10.0)
    srv.start()
    try:
        yield srv
    finally:
        srv.close()


def _raw(path, data: bytes) -> dict:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10.0)
        s.connect(str(path))
        s.sendall(data)
        return json.loads(s.makefile("rb").readline())


def test_socket_is_group_rw_only_and_answers(server):
    assert stat.S_IMODE(os.stat(server.path).st_mode) == 0o660
    with Client(server.path) as client:
        assert client.request("status") == {"ok": True, "cmd": "status", "encoded": "ahead"}
        assert client.request("jobs") == {"ok": True, "cmd": "jobs"}
        refused = client.request("reset")
        assert refused["ok"] is False and refused["error"] == "reset: nothing to reset"


def test_malformed_and_unknown_requests_get_errors_on_the_same_connection(server):
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10.0)
        s.connect(str(server.path))
        s.sendall(b'{"cmd": "status"\n{"cmd": "fly"}\n{"cmd": "override", "percent": "x"}\n{"cmd": "status"}\n')
        reader = s.makefile("rb")
        lines = [json.loads(reader.readline()) for _ in range(4)]
    assert [r["ok"] for r in lines] == [False, False, False, True]
    assert "malformed JSON" in lines[0]["error"]
    assert "'cmd'" in lines[1]["error"] and "'percent'" in lines[2]["error"]


def test_oversized_request_is_refused_and_the_server_keeps_serving(server):
    response = _raw(server.path, b'{"cmd": "submit", "name": "a", "program": "' + b"x" * (MAX_REQUEST_BYTES + 10)
                    + b'"}\n{"cmd": "status"}\n')
    assert response["ok"] is False and f"{MAX_REQUEST_BYTES // (1024 * 1024)} MB limit" in response["error"]
    assert _raw(server.path, b'{"cmd": "status"}\n')["ok"] is True


def test_a_client_leaving_mid_request_does_not_hurt(server):
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.connect(str(server.path))
        s.sendall(b'{"cmd": "sta')
    assert _raw(server.path, b'{"cmd": "status"}\n')["ok"] is True


def test_a_live_socket_is_not_taken_over_but_a_stale_one_is(server, tmp_path):
    with pytest.raises(InputError, match="already serving"):
        ControlServer(server.path, _handler).start()
    stale = tmp_path / "stale.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.bind(str(stale))  # bound, never listening: what a crashed daemon leaves
    other = ControlServer(stale, _handler)
    other.start()
    try:
        assert _raw(stale, b'{"cmd": "status"}\n')["ok"] is True
    finally:
        other.close()
    assert not stale.exists()


def test_no_daemon_is_one_clear_line(tmp_path):
    with pytest.raises(DaemonUnavailable) as info:
        Client(tmp_path / "none.sock").connect()
    assert str(info.value) == f"no daemon at {tmp_path / 'none.sock'} (is it running?)"


@pytest.mark.parametrize("uid, gid, groups, allowed", [
    (1000, 1000, (), True),  # the daemon's own user
    (0, 0, (), True),  # root
    (2000, 2000, (), False),
    (2000, 50, (), True),  # primary group is the control group
    (2000, 2000, (7, 50), True),  # supplementary group
])
def test_peer_access_rule(uid, gid, groups, allowed):
    peer = PeerCredentials(1, uid, gid, frozenset(groups))
    assert peer_allowed(peer, daemon_uid=1000, control_gid=50) is allowed
    assert peer_allowed(peer, daemon_uid=1000, control_gid=None) is (uid in (0, 1000))


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to connect as another user")
@pytest.mark.parametrize("send_after_close", [False, True])
def test_a_peer_of_another_user_is_refused_by_its_credentials(send_after_close):
    """The refusal reaches the client even when the server has answered and closed before the
    client sent its request (under load the server's thread can run first: the client's send
    then fails with EPIPE, and the client must still read the line waiting for it)."""
    folder = tempfile.mkdtemp(prefix="nm-peer-")  # under /tmp: the other user must reach it
    server = ControlServer(Path(folder) / "ctl.sock", _handler)
    server.start()
    try:
        os.chmod(folder, 0o755)
        os.chmod(server.path, 0o666)  # let the file system pass it: SO_PEERCRED must still refuse
        line = _ask_as_nobody(server.path, send_after_close)
    finally:
        server.close()
        shutil.rmtree(folder, ignore_errors=True)
    assert line.startswith(b"{"), line  # otherwise the child's error
    response = json.loads(line)
    assert response["ok"] is False and "permission denied: uid 65534" in response["error"]


def _ask_as_nobody(path: Path, send_after_close: bool) -> bytes:
    """As uid 65534 in a forked child, ask ``status`` through the project's Client; return the
    JSON response line (or the child's error). ``send_after_close``: wait until the server has
    closed its end (POLLRDHUP) before sending."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: become nobody, ask, pass the answer up the pipe
        try:
            os.setgroups([])
            os.setgid(65534)
            os.setuid(65534)
            with Client(path, timeout_s=10.0) as client:
                if send_after_close:
                    waiter = select.poll()
                    waiter.register(client._sock, select.POLLRDHUP)
                    if not waiter.poll(10_000):
                        raise TimeoutError("the server did not close its end")
                os.write(write_end, json.dumps(client.request("status")).encode())
        except BaseException as err:  # noqa: BLE001 - the parent shows why the child got no answer
            os.write(write_end, f"child failed: {err!r}".encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as answer:
        line = answer.read()
    os.waitpid(pid, 0)
    return line


def test_descriptors_sent_with_a_request_reach_its_handler_and_are_closed_after(tmp_path):
    """protocol ``program_fd``: the file a client sends with its request line (SCM_RIGHTS) is
    the handler's to read for that request only; the server closes it after answering."""
    seen: list[tuple[str, tuple[int, ...], bytes]] = []

    def handler(request):
        seen.append((request.cmd, request.files, b"".join(os.pread(fd, 100, 0) for fd in request.files)))
        return {"ok": True}

    program = tmp_path / "part.nc"
    program.write_bytes(b"G21 G90\nG01 X1 F600\n")
    srv = ControlServer(tmp_path / "ctl.sock", handler, idle_timeout_s=10.0)
    srv.start()
    try:
        with Client(srv.path) as client, open(program, "rb") as src:
            assert client.request("submit", files=[src.fileno()], name="part.nc", program_fd=0)["ok"]
            assert client.request("status")["ok"]  # the next request carries none
            too_many = [src.fileno()] * 3  # more than protocol.MAX_FDS: none is kept
            assert client.request("submit", files=too_many, name="part.nc", program_fd=0)["ok"]
    finally:
        srv.close()
    assert [(cmd, len(files), data) for cmd, files, data in seen] == \
        [("submit", 1, b"G21 G90\nG01 X1 F600\n"), ("status", 0, b""), ("submit", 0, b"")]
    for fd in seen[0][1]:
        with pytest.raises(OSError):
            os.fstat(fd)  # closed by the server (not reused meanwhile: no other descriptor opened since)
