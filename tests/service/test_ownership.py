"""One daemon per bus: a second one names the first (pid, socket) and touches nothing."""

import os
import socket

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.service.ownership import BusOwnership, BusTaken


def _config(tmp_path, interface="socketcan"):
    text = (f"cycle_period_ms: 4\nbus: {{interface: {interface}, channel: can7}}\n"
            f"control: {{socket: {tmp_path / 'ctl.sock'}}}\ndata_dir: {tmp_path / 'data'}\n"
            "axes:\n  - {name: X, node_id: 1}\n")
    return parse_config(text, "m.yaml")


def test_a_second_owner_of_the_bus_is_refused_with_the_first_ones_pid_and_socket(tmp_path):
    config = _config(tmp_path)
    first = BusOwnership(config, lock_dirs=(tmp_path,))
    first.acquire()
    try:
        with pytest.raises(BusTaken, match=rf"bus socketcan:can7 is owned by another daemon \(pid={os.getpid()} "
                                           rf"socket=.*ctl.sock\) .*kill -TERM {os.getpid()}"):
            BusOwnership(config, lock_dirs=(tmp_path,)).acquire()
    finally:
        first.release()
    BusOwnership(config, lock_dirs=(tmp_path,)).acquire()  # free again once released


def test_a_live_control_socket_is_refused_before_the_bus_is_locked(tmp_path):
    config = _config(tmp_path)
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(tmp_path / "ctl.sock"))
    server.listen(1)
    try:
        with pytest.raises(BusTaken) as refused:
            BusOwnership(config, lock_dirs=(tmp_path,)).acquire()
        # the pid of the process serving it, and how to end a daemon (nurbsmotion stop only stops a job)
        assert str(refused.value) == (f"another daemon (pid {os.getpid()}) serves {tmp_path / 'ctl.sock'}; this one "
                                      f"touches nothing (to end that daemon: kill -TERM {os.getpid()}, or systemctl "
                                      f"stop nurbsmotion where systemd runs it)")
        assert not list(tmp_path.glob("*.lock"))
    finally:
        server.close()


def test_a_daemon_on_a_taken_bus_opens_no_bus_and_leaves_the_job_records_alone(tmp_path, monkeypatch):
    config = _config(tmp_path)
    monkeypatch.setattr("nurbsmotion.service.ownership.LOCK_DIRS", (tmp_path,))
    first = BusOwnership(config, lock_dirs=(tmp_path,))
    first.acquire()
    opened = []
    daemon = Daemon(config, lambda cfg: opened.append(cfg))  # would open the bus
    daemon.ownership = BusOwnership(config, lock_dirs=(tmp_path,))
    marked = []
    monkeypatch.setattr(daemon.records, "mark_interrupted", lambda: marked.append(1) or [])
    try:
        with pytest.raises(BusTaken, match=f"pid={os.getpid()}"):
            daemon.start()
        daemon.close()
    finally:
        first.release()
    assert opened == [] and marked == []


def test_the_in_process_virtual_bus_is_not_locked(tmp_path):
    config = _config(tmp_path, interface="virtual")
    BusOwnership(config, lock_dirs=(tmp_path,)).acquire()
    BusOwnership(config, lock_dirs=(tmp_path,)).acquire()
