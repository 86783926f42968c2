"""READY=1 reaches $NOTIFY_SOCKET as one datagram; without it nothing is sent."""

import socket

from nurbsmotion.service.notify import sd_notify


def test_ready_is_sent_to_the_notify_socket(tmp_path, monkeypatch):
    path = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind(str(path))
        receiver.settimeout(2.0)
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        assert sd_notify("READY=1")
        assert receiver.recv(100) == b"READY=1"


def test_without_notify_socket_nothing_happens(monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert not sd_notify("READY=1")
