"""Subscribed clients of a real daemon (simulated drives, Unix socket): the full status first,
then only changes, and the job's events, for ten clients at once; a fault reaches them with
its node; a client that hangs up ends only its own connection."""

from __future__ import annotations

import json
import socket
import threading
from typing import Any

from nurbsmotion.service.client import Client
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

PROGRAM = "G21 G90\nG01 X5 Y2 F3000\nG01 X0 Y0\n"


class Listener:
    """One subscribed connection read by its own thread until the daemon closes it."""

    def __init__(self, socket_path: Any, max_hz: float | None = None) -> None:
        self.client = Client(socket_path)
        self.lines: list[dict[str, Any]] = []
        self.stream = self.client.subscribe(max_hz)
        self.first = next(self.stream)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        for line in self.stream:
            self.lines.append(line)

    def hang_up(self) -> None:
        """End the connection from this side, as a client that goes away does."""
        assert self.client._sock is not None
        self.client._sock.shutdown(socket.SHUT_RDWR)
        self.thread.join(5.0)
        self.client.close()

    def events(self, name: str) -> list[dict[str, Any]]:
        return [line for line in list(self.lines) if line.get("notify") == "event" and line["event"] == name]

    def states(self) -> list[str]:
        return [line["changes"]["state"] for line in list(self.lines)
                if line.get("notify") == "status" and "state" in line["changes"]]


def test_ten_subscribers_see_the_job_start_and_end_and_its_state_changes(tmp_path):
    with daemon_in_process(tmp_path / "data", "", "sub") as daemon:
        listeners = [Listener(daemon.config.control.socket) for _ in range(10)]
        for listener in listeners:
            assert listener.first["ok"] and listener.first["subscribed"]
            assert listener.first["status"]["state"] == "idle" and len(listener.first["status"]["axes"]) == 3
        with Client(daemon.config.control.socket) as client:
            job = client.call("submit", name="sq.nc", program=PROGRAM)["job"]["id"]
        for listener in listeners:
            wait_for(lambda: listener.events("job_ended"), 30.0, "job_ended pushed to every subscriber")
        for listener in listeners:
            [started] = listener.events("job_started")
            [ended] = listener.events("job_ended")
            assert started["fields"]["job"] == job and started["fields"]["name"] == "sq.nc"
            assert ended["fields"]["job"] == job and ended["fields"]["outcome"] == "completed"
            assert "running" in listener.states()
            seqs = [line["seq"] for line in listener.lines]
            assert seqs == list(range(1, len(seqs) + 1))  # nothing lost, in order
            positions = [line["changes"]["axes"] for line in listener.lines
                         if line.get("notify") == "status" and "axes" in line["changes"]]
            assert positions and positions[-1][0]["commanded_mm"] == 0.0
        wait_for(lambda: all(listener.states()[-1:] == ["idle"] for listener in listeners), 10.0,
                   "the idle state pushed after the job")
        assert daemon.hub.subscribers == 10
        for listener in listeners:
            listener.hang_up()
        wait_for(lambda: daemon.hub.subscribers == 0, 10.0, "hung-up subscribers removed")
        with Client(daemon.config.control.socket) as client:
            assert client.call("status")["state"] == "idle"  # the daemon serves on


def test_a_fault_is_pushed_with_its_node_and_the_status_says_fault(tmp_path):
    with daemon_in_process(tmp_path / "data", "", "subf") as daemon:
        listener = Listener(daemon.config.control.socket, max_hz=5.0)
        with Client(daemon.config.control.socket) as client:
            client.call("submit", name="long.nc", program="G21 G90\nG01 X60 F1200\n")
            wait_for(lambda: "running" in listener.states(), 20.0, "the job running")
            client.call("inject_fault", spec="node=2,kind=fault,code=0x2310")
            wait_for(lambda: listener.events("fault"), 20.0, "the fault pushed")
            [fault, *_] = listener.events("fault")
            assert fault["fields"]["node"] == "2" and fault["level"] == "WARNING"
            wait_for(lambda: "fault" in listener.states(), 20.0, "state fault pushed")
        listener.hang_up()


def test_a_subscriber_that_stops_reading_is_dropped_with_a_notice_and_nobody_else_waits(tmp_path, monkeypatch):
    """The hub drops an attached subscriber whose socket keeps too much unsent; its connection's
    thread (asleep until then) is woken by the drop, sends the 'dropped' line after what was
    queued, and closes; a subscriber that reads gets every event meanwhile."""
    from nurbsmotion.service import subscriptions

    monkeypatch.setattr(subscriptions, "MAX_UNSENT_BYTES", 4096)  # a socket's buffer and then some
    with daemon_in_process(tmp_path / "data", "", "subd") as daemon:
        stalled = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        stalled.connect(str(daemon.config.control.socket))
        stalled.sendall(b'{"cmd": "subscribe"}\n')
        reader = Listener(daemon.config.control.socket)
        wait_for(lambda: daemon.hub.subscribers == 2, 10.0, "both subscribed")
        overrides = 0
        with Client(daemon.config.control.socket) as client:
            while not dropped(daemon) and overrides < 20000:  # events until the stalled one is dropped
                client.call("override", percent=100 - overrides % 2)
                overrides += 1
        assert dropped(daemon), f"not dropped after {overrides} events"
        with stalled.makefile("rb") as stream:  # read now: the notice waits a second for room in the socket
            lines = [json.loads(raw) for raw in stream]  # up to the daemon closing it
        assert lines[0]["subscribed"] and lines[-1]["notify"] == "dropped" and "too slow" in lines[-1]["error"]
        wait_for(lambda: len(reader.events("override_changed")) == overrides, 20.0, "every event on the reader")
        seqs = [line["seq"] for line in reader.lines]
        assert seqs == list(range(1, len(seqs) + 1))
        wait_for(lambda: daemon.hub.subscribers == 1, 10.0, "the dropped subscriber removed")
        reader.hang_up()
        stalled.close()


def dropped(daemon: Any) -> bool:
    return any(sub.dropped is not None for sub in daemon.hub._subscribers)


def test_a_subscriber_following_the_changes_has_every_field_of_a_status_request(tmp_path):
    """Fast reads between events, whole reads after them (service.subscriptions): once the
    machine rests after a job and an offsets change, the subscriber's status is a ``status``
    answer, field for field (the cycle counters, which move every cycle, left out)."""
    from nurbsmotion.service.protocol import merge_changes

    with daemon_in_process(tmp_path / "data", "", "subeq") as daemon:
        listener = Listener(daemon.config.control.socket)
        with Client(daemon.config.control.socket) as client:
            client.call("submit", name="sq.nc", program=PROGRAM)
            wait_for(lambda: listener.events("job_ended"), 30.0, "job_ended pushed")
            client.call("override", percent=70)

            def same_as_a_status_request() -> bool:
                merged = listener.first["status"]
                for line in list(listener.lines):
                    if line.get("notify") == "status":
                        merged = merge_changes(merged, line["changes"])
                answer = client.call("status")
                return {k: v for k, v in merged.items() if k != "cycles"} == \
                    {k: v for k, v in answer.items() if k != "cycles"} and set(merged) == set(answer)

            wait_for(same_as_a_status_request, 10.0, "the subscriber's status to be the status answer")
        listener.hang_up()
