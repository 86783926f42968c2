"""Pushed status and events (service.subscriptions): the diffs, the rate limit, slow clients,
the log records as events; the daemon's socket end to end in tests/integration/test_subscribe.py."""

from __future__ import annotations

import json
import logging
import threading
import time

import pytest

from nurbsmotion.fieldbus.cycle_slack import CycleSlack
from nurbsmotion.log import kv, parse_kv
from nurbsmotion.service import subscriptions
from nurbsmotion.service.subscriptions import (AFTER_WAKE_S, MAX_PENDING_LINES, STEP_ROOM_S, StatusHub, Subscription,
                                               attach_event_log, merge_changes, status_changes, wait_before_step_s)


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakeStatus:
    def __init__(self) -> None:
        self.value = {"state": "idle", "axes": [{"name": "X", "actual_mm": 0.0}], "override": {"requested_percent": 100.0}}
        self.reads = 0

    def __call__(self) -> dict:
        self.reads += 1
        return json.loads(json.dumps(self.value))  # a fresh object each read, as the controller's


def lines(sub) -> list[dict]:
    return [json.loads(line) for line in sub.take(0.0)]


def test_status_changes_names_only_what_changed_nested_by_key_and_lists_whole():
    old = {"state": "idle", "job": None, "override": {"requested_percent": 100.0, "effective_percent": 100.0},
           "axes": [{"name": "X", "actual_mm": 0.0}, {"name": "Y", "actual_mm": 0.0}], "gone": 1}
    new = {"state": "running", "job": {"id": "a"}, "override": {"requested_percent": 100.0, "effective_percent": 80.0},
           "axes": [{"name": "X", "actual_mm": 0.5}, {"name": "Y", "actual_mm": 0.0}]}
    assert status_changes(old, new) == {"state": "running", "job": {"id": "a"}, "override": {"effective_percent": 80.0},
                                        "axes": new["axes"], "gone": None}
    assert status_changes(new, new) == {}
    assert status_changes(None, new) == new


def test_merged_changes_keep_the_newest_value_of_each_field():
    assert merge_changes({"state": "running", "override": {"a": 1, "b": 2}}, {"override": {"b": 3}, "job": None}) == \
        {"state": "running", "override": {"a": 1, "b": 3}, "job": None}


def test_kv_lines_read_back_as_the_event_and_its_fields():
    line = kv("job_ended", job="a1", outcome="fault", line="x.nc:3", reason='drive "2" lost', t=1.5, empty="")
    assert parse_kv(line) == ("job_ended", {"job": "a1", "outcome": "fault", "line": "x.nc:3",
                                            "reason": 'drive "2" lost', "t": "1.5", "empty": ""})
    assert parse_kv("free text here") == ("free", {"_1": "text", "_2": "here"})
    assert parse_kv("") == ("", {})


def test_a_subscriber_gets_the_full_status_then_only_changes_at_its_rate():
    status, clock = FakeStatus(), FakeClock()
    hub = StatusHub(status, clock=clock, wall_clock=lambda: 5.0, publisher_thread=False)
    sub, first = hub.subscribe(max_hz=10.0)
    assert first["state"] == "idle"
    hub.publish_once()
    assert lines(sub) == []  # nothing changed
    status.value["axes"][0]["actual_mm"] = 1.0
    hub.publish_once()
    assert lines(sub) == []  # changed, but its 0.1 s have not passed: merged, not sent
    status.value["axes"][0]["actual_mm"] = 2.0
    clock.now += 0.1
    hub.publish_once()
    [line] = lines(sub)
    assert line["notify"] == "status" and line["changes"] == {"axes": [{"name": "X", "actual_mm": 2.0}]}
    assert line["seq"] == 1 and line["t"] == 5.0


def test_an_event_is_pushed_at_once_with_the_status_it_changed():
    status, clock = FakeStatus(), FakeClock()
    hub = StatusHub(status, clock=clock, publisher_thread=False)
    sub, _ = hub.subscribe(max_hz=1.0)
    status.value["state"] = "running"
    hub.publish_event({"event": "job_started", "fields": {"job": "j1"}})
    hub.publish_once()  # well within the 1 s rate: the event brings its status along
    event, change = lines(sub)
    assert (event["notify"], event["event"], event["fields"]) == ("event", "job_started", {"job": "j1"})
    assert (change["notify"], change["changes"]) == ("status", {"state": "running"})
    assert (event["seq"], change["seq"]) == (1, 2)


def test_every_subscriber_gets_every_event_and_the_status_is_read_once_for_all():
    status = FakeStatus()
    hub = StatusHub(status, clock=FakeClock(), publisher_thread=False)
    subs = [hub.subscribe()[0] for _ in range(10)]
    reads = status.reads
    hub.publish_event({"event": "fault", "fields": {"node": "2"}})
    hub.publish_once()
    assert status.reads == reads + 1
    for sub in subs:
        assert [line["event"] for line in lines(sub) if line["notify"] == "event"] == ["fault"]


def test_a_client_that_falls_behind_is_dropped_with_a_reason_and_the_others_go_on():
    hub = StatusHub(FakeStatus(), clock=FakeClock(), publisher_thread=False)
    slow, _ = hub.subscribe()
    fast, _ = hub.subscribe()
    for i in range(MAX_PENDING_LINES + 1):
        hub.publish_event({"event": "tick", "fields": {"i": str(i)}})
        hub.publish_once()
        lines(fast)  # the fast one reads as it goes
    assert slow.dropped and "too slow" in slow.dropped
    [last] = lines(slow)
    assert last["notify"] == "dropped" and "too slow" in last["error"]
    assert fast.dropped is None


def test_no_subscriber_no_status_read_and_no_queued_event():
    status = FakeStatus()
    hub = StatusHub(status, clock=FakeClock(), publisher_thread=False)
    sub, _ = hub.subscribe()
    hub.unsubscribe(sub)
    reads = status.reads
    hub.publish_event({"event": "ignored"})
    hub.publish_once()
    assert status.reads == reads and not sub.take(0.0)


def test_package_log_records_at_info_become_events_and_stderr_stays_as_quiet(capsys):
    hub = StatusHub(FakeStatus(), clock=FakeClock(), publisher_thread=False)
    sub, _ = hub.subscribe()
    logger = logging.getLogger("nurbsmotion.service.test_events")
    detach = attach_event_log(hub)
    try:
        logger.info(kv("job_started", job="j7", name="part.nc"))
        logger.debug(kv("not_an_event"))
        hub.publish_once()
    finally:
        detach()
    [event] = [line for line in lines(sub) if line["notify"] == "event"]
    assert event["event"] == "job_started" and event["fields"] == {"job": "j7", "name": "part.nc"}
    assert event["level"] == "INFO" and event["line"].startswith("job_started job=j7")
    logger.info(kv("after_detach"))
    hub.publish_once()
    assert not [line for line in lines(sub) if line["notify"] == "event"]


@pytest.mark.parametrize("bad", [0.1, 1000.0])
def test_max_hz_outside_its_range_is_refused_by_the_server(bad, tmp_path):
    from nurbsmotion.service.protocol import Request
    from nurbsmotion.service.server import ControlServer

    server = ControlServer(tmp_path / "s.sock", lambda r: {"ok": True}, hub=StatusHub(FakeStatus(), publisher_thread=False))
    refusal = server._subscription_refusal(Request("subscribe", {"max_hz": bad}))
    assert refusal is not None and "max_hz" in refusal["error"]


class SocketStandIn:
    """A non-blocking send: takes at most ``room`` bytes a call (None: all), BlockingIOError
    when it has none, OSError once ``gone``."""

    def __init__(self, room: int | None = None) -> None:
        self.room = room
        self.gone = False
        self.received = b""

    def __call__(self, data: bytes) -> int:
        if self.gone:
            raise BrokenPipeError("peer went away")
        taken = data if self.room is None else data[:self.room]
        if not taken and data:
            raise BlockingIOError
        self.received += taken
        return len(taken)

    def lines(self) -> list[dict]:
        return [json.loads(line) for line in self.received.splitlines()]


def test_the_publisher_writes_every_attached_subscribers_lines_itself():
    """One round of the publisher sends to every client: no per-client thread has to wake."""
    status = FakeStatus()
    hub = StatusHub(status, clock=FakeClock(), publisher_thread=False)
    sockets = [SocketStandIn() for _ in range(10)]
    subs = [hub.subscribe()[0] for _ in sockets]
    for sub, sock in zip(subs, sockets):
        sub.attach(sock)
    hub.publish_event({"event": "fault", "fields": {"node": "2"}})
    hub.publish_once()
    for sub, sock in zip(subs, sockets):
        assert [line["event"] for line in sock.lines() if line["notify"] == "event"] == ["fault"]
        assert sub.take(0.0) == []  # nothing left for anyone to take


def test_what_a_full_socket_did_not_take_goes_first_in_the_next_round():
    clock = FakeClock()
    hub = StatusHub(FakeStatus(), clock=clock, publisher_thread=False)
    sub, _ = hub.subscribe()
    sock = SocketStandIn(room=7)
    sub.attach(sock)
    for i in range(3):
        hub.publish_event({"event": "tick", "fields": {"i": str(i)}})
        hub.publish_once()
    sock.room = None
    hub.publish_once()
    events = [line["fields"]["i"] for line in sock.lines() if line["notify"] == "event"]
    seqs = [line["seq"] for line in sock.lines()]
    assert events == ["0", "1", "2"] and seqs == sorted(seqs)


def test_an_attached_client_whose_socket_stays_full_is_dropped_with_a_reason():
    from nurbsmotion.service.subscriptions import MAX_UNSENT_BYTES

    hub = StatusHub(FakeStatus(), clock=FakeClock(), publisher_thread=False)
    slow, _ = hub.subscribe()
    fast, _ = hub.subscribe()
    slow_socket, fast_socket = SocketStandIn(room=0), SocketStandIn()
    slow.attach(slow_socket)
    fast.attach(fast_socket)
    big = "x" * 100_000
    for _ in range(MAX_UNSENT_BYTES // 100_000 + 2):
        hub.publish_event({"event": "big", "fields": {"text": big}})
        hub.publish_once()
    assert slow.dropped and "too slow" in slow.dropped and not slow.unsent
    [notice] = [json.loads(line) for line in slow.take(0.0)]
    assert notice["notify"] == "dropped" and "too slow" in notice["error"]
    assert fast.dropped is None and len(fast_socket.lines()) > MAX_UNSENT_BYTES // 100_000


def test_a_client_dropped_after_taking_part_of_a_line_gets_its_rest_before_the_notice():
    from nurbsmotion.service.subscriptions import MAX_UNSENT_BYTES

    hub = StatusHub(FakeStatus(), clock=FakeClock(), publisher_thread=False)
    sub, _ = hub.subscribe()
    sock = SocketStandIn(room=50)  # part of the first line, then nothing more
    sub.attach(sock)
    big = "x" * 100_000
    hub.publish_event({"event": "big", "fields": {"text": big}})
    hub.publish_once()
    sock.room = 0
    for _ in range(MAX_UNSENT_BYTES // 100_000 + 2):
        hub.publish_event({"event": "big", "fields": {"text": big}})
        hub.publish_once()
    assert sub.dropped and "too slow" in sub.dropped
    stream = sock.received + sub.unsent + b"".join(sub.take(0.0))  # what the connection's thread sends last
    first, notice = [json.loads(line) for line in stream.splitlines()]
    assert first["fields"]["text"] == big and notice["notify"] == "dropped"


def test_a_client_gone_while_the_publisher_writes_is_dropped():
    hub = StatusHub(FakeStatus(), clock=FakeClock(), publisher_thread=False)
    sub, _ = hub.subscribe()
    sock = SocketStandIn()
    sub.attach(sock)
    sock.gone = True
    hub.publish_event({"event": "tick"})
    hub.publish_once()
    assert sub.dropped is not None and "connection lost" in sub.dropped


class FastAndSlow:
    """A status whose ``axes`` move (read by ``fast``) and whose ``override`` does not."""

    def __init__(self) -> None:
        self.value = {"state": "idle", "axes": [{"name": "X", "actual_mm": 0.0}], "override": {"requested_percent": 100.0}}
        self.full_reads = self.fast_reads = 0

    def full(self) -> dict:
        self.full_reads += 1
        return json.loads(json.dumps(self.value))

    def fast(self) -> dict:
        self.fast_reads += 1
        return {k: json.loads(json.dumps(self.value[k])) for k in ("state", "axes")}


def test_between_events_only_the_moving_fields_are_read_and_the_rest_every_full_read_period():
    from nurbsmotion.service.subscriptions import FULL_READ_PERIOD_S

    status, clock = FastAndSlow(), FakeClock()
    hub = StatusHub(status.full, clock=clock, publisher_thread=False, read_fast=status.fast)
    sub, _ = hub.subscribe(max_hz=20.0)
    hub.publish_once()  # the first round reads the whole status
    full_reads = status.full_reads
    status.value["axes"][0]["actual_mm"] = 1.5
    status.value["override"]["requested_percent"] = 50.0  # changed without an event
    clock.now += 0.05
    hub.publish_once()
    assert (status.full_reads, status.fast_reads) == (full_reads, 1)
    [line] = lines(sub)
    assert line["changes"] == {"axes": [{"name": "X", "actual_mm": 1.5}]}  # the override waits for a whole read
    clock.now += FULL_READ_PERIOD_S
    hub.publish_once()
    assert status.full_reads == full_reads + 1
    [line] = lines(sub)
    assert line["changes"] == {"override": {"requested_percent": 50.0}}


def test_an_event_has_the_whole_status_read_in_its_round_and_the_next():
    status, clock = FastAndSlow(), FakeClock()
    hub = StatusHub(status.full, clock=clock, publisher_thread=False, read_fast=status.fast)
    sub, _ = hub.subscribe(max_hz=20.0)
    hub.publish_once()
    full_reads = status.full_reads
    status.value["override"]["requested_percent"] = 80.0
    hub.publish_event({"event": "override_changed", "fields": {"requested_percent": "80"}})
    hub.publish_once()
    status.value["override"]["requested_percent"] = 90.0  # set just after its log line
    clock.now += 0.05
    hub.publish_once()
    clock.now += 0.05
    hub.publish_once()
    assert status.full_reads == full_reads + 2 and status.fast_reads == 1
    changes = [line["changes"] for line in lines(sub) if line["notify"] == "status"]
    assert changes == [{"override": {"requested_percent": 80.0}}, {"override": {"requested_percent": 90.0}}]


def test_a_subscriber_following_the_changes_has_what_a_status_request_gives(tmp_path):
    """The daemon's hub on a controller (fake drives): whole reads and fast reads alike leave
    the subscriber with the ``status`` answer, field for field."""
    from pathlib import Path

    from nurbsmotion.config import load_config
    from nurbsmotion.service.controller import Controller
    from nurbsmotion.service.protocol import encode
    from nurbsmotion.service.records import JobRecords
    from tests.service.fakes import FakeLink, fake_planner

    config = load_config(Path(__file__).resolve().parents[2] / "config" / "demo.yaml")
    link = FakeLink(config)
    controller = Controller(config, link, fake_planner(config), JobRecords(tmp_path))
    clock = FakeClock()
    hub = StatusHub(controller.status, clock=clock, publisher_thread=False,
                    read_fast=lambda: controller.status(fast_only=True))
    detach = attach_event_log(hub)
    try:
        sub, merged = hub.subscribe(max_hz=20.0)

        def follow_and_compare() -> None:
            nonlocal merged
            clock.now += 0.05
            hub.publish_once()
            for line in lines(sub):
                if line["notify"] == "status":
                    merged = merge_changes(merged, line["changes"])
            assert merged == json.loads(encode(controller.status()))

        hub.publish_once()
        link.held[0] = 2500  # the machine moved: a fast read
        follow_and_compare()
        controller.override(40.0)  # a logged change: a whole read
        follow_and_compare()
        assert merged["override"]["requested_percent"] == 40.0 and merged["axes"][0]["actual_mm"] == 2.5
    finally:
        detach()
        controller.shutdown(2.0)


def test_subscribers_at_one_rate_fall_due_together_whenever_they_subscribed():
    status, clock = FakeStatus(), FakeClock()
    hub = StatusHub(status, clock=clock, publisher_thread=False)
    first, _ = hub.subscribe(max_hz=20.0)
    clock.now += 0.03
    second, _ = hub.subscribe(max_hz=20.0)
    assert first.next_status_s == second.next_status_s  # the same tick of the 50 ms grid
    status.value["axes"][0]["actual_mm"] = 3.0
    clock.now = first.next_status_s
    hub.publish_once()
    assert [line["changes"] for line in lines(first)] == [line["changes"] for line in lines(second)] == \
        [{"axes": [{"name": "X", "actual_mm": 3.0}]}]


def test_a_due_subscriber_with_nothing_changed_waits_for_its_next_tick():
    """Not due again at once: the publisher would go round without sleeping while the
    status stands still (it did: ~76,000 rounds a second for ten idle subscribers)."""
    status, clock = FakeStatus(), FakeClock()
    hub = StatusHub(status, clock=clock, publisher_thread=False)
    sub, _ = hub.subscribe(max_hz=20.0)
    clock.now = sub.next_status_s
    hub.publish_once()
    assert lines(sub) == [] and sub.next_status_s >= clock.now + 0.049


def test_a_publisher_step_starts_only_with_room_before_the_cycle_threads_wake_up():
    """Else after it: a cycle thread that wakes into a step waits for the lock until it ends
    (and after a sleep(0), for the switch interval)."""
    now_s = 50.0
    assert wait_before_step_s(None, now_s) == 0.0  # no cycle loop: only let go of the lock
    assert wait_before_step_s(now_s + 2 * STEP_ROOM_S, now_s) == 0.0  # room for a step
    # woke already and waits for the lock the publisher holds: a real sleep, not sleep(0)
    assert wait_before_step_s(now_s - 1e-5, now_s) == AFTER_WAKE_S
    assert wait_before_step_s(now_s + STEP_ROOM_S / 2, now_s) == pytest.approx(STEP_ROOM_S / 2 + AFTER_WAKE_S)


def test_the_publisher_asks_when_the_cycle_thread_wakes_before_the_read_and_the_send():
    calls: list[str] = []
    status = FakeStatus()

    def read() -> dict:
        calls.append("read")
        return status()

    def next_wake_s() -> float | None:
        calls.append("ask")
        return None

    def send(data: bytes) -> int:
        calls.append("send")
        return len(data)

    hub = StatusHub(read, clock=FakeClock(), publisher_thread=False, next_cycle_wake_s=next_wake_s)
    sub, _ = hub.subscribe()
    sub.attach(send)
    calls.clear()
    hub.publish_event({"event": "fault", "fields": {"node": "2"}})
    hub.publish_once()
    assert "read" in calls and "send" in calls
    assert calls[calls.index("read") - 1] == "ask" and calls[calls.index("send") - 1] == "ask"


class CycleThread:
    """A stand-in for the master's cycle thread: runs the slack's steps with room to spare."""

    def __init__(self, slack: CycleSlack) -> None:
        self.slack = slack
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, name="nurbsmotion-cycle", daemon=True)

    def _run(self) -> None:
        while not self.stopping.wait(1e-3):
            self.slack.run(time.perf_counter() + 1.0)

    def __enter__(self) -> CycleThread:
        self.slack.start()
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stopping.set()
        self.thread.join(5.0)
        self.slack.stop()


def subscribed_on_a_slack(status: FakeStatus) -> tuple[StatusHub, Subscription, CycleSlack]:
    """A hub on a cycle thread's slack with one subscriber, the slack accepting work from then on."""
    slack = CycleSlack()
    hub = StatusHub(status, clock=FakeClock(), publisher_thread=False, slack=slack)
    sub, _ = hub.subscribe()
    slack.start()
    return hub, sub, slack


def test_with_a_cycle_thread_running_the_round_runs_in_its_slack(monkeypatch):
    monkeypatch.setattr(subscriptions, "SLACK_WAIT_S", 30.0)  # however loaded the host: no fallback
    status, readers = FakeStatus(), []

    def read() -> dict:
        readers.append(threading.current_thread().name)
        return status()

    slack = CycleSlack()
    hub = StatusHub(read, clock=FakeClock(), publisher_thread=False, slack=slack)
    sub, _ = hub.subscribe()
    readers.clear()
    with CycleThread(slack):
        hub.publish_event({"event": "job_started", "fields": {}})
        hub.publish_once()
    assert readers == ["nurbsmotion-cycle"]
    assert [line["notify"] for line in lines(sub)] == ["event"]
    assert slack.steps_run >= 3  # the round's pauses: after the subscribers, after the read, ...
    assert slack.withdrawn == 0


def test_a_cycle_thread_without_slack_for_a_while_leaves_the_round_to_the_publisher(monkeypatch):
    monkeypatch.setattr(subscriptions, "SLACK_WAIT_S", 0.01)
    status = FakeStatus()
    hub, sub, slack = subscribed_on_a_slack(status)  # the cycle thread runs, but never has room (nobody calls run)
    status.value["state"] = "running"
    hub.publish_event({"event": "job_started", "fields": {}})
    hub.publish_once()
    assert [line["notify"] for line in lines(sub)] == ["event", "status"]
    assert slack.withdrawn == 1
    slack.run(time.perf_counter() + 1.0)
    assert slack.steps_run == 0  # withdrawn: the cycle thread does not run it twice


def test_a_round_handed_back_by_an_ending_cycle_thread_finishes_in_the_publisher(monkeypatch):
    monkeypatch.setattr(subscriptions, "SLACK_WAIT_S", 30.0)
    status = FakeStatus()
    hub, sub, slack = subscribed_on_a_slack(status)
    status.value["state"] = "fault"
    hub.publish_event({"event": "fault", "fields": {}})
    ender = threading.Timer(0.02, slack.stop)  # the drives are disabled: the cycle thread ends
    ender.start()
    hub.publish_once()
    ender.join()
    assert [line["notify"] for line in lines(sub)] == ["event", "status"]
    assert slack.withdrawn == 0


def test_a_read_that_fails_in_the_slack_fails_the_publishers_round():
    def read() -> dict:
        raise RuntimeError("a bug in the status read")

    status = FakeStatus()
    calls = iter([status, read])
    slack = CycleSlack()
    hub = StatusHub(lambda: next(calls)(), clock=FakeClock(), publisher_thread=False, slack=slack)
    hub.subscribe()
    hub.publish_event({"event": "fault", "fields": {}})
    with CycleThread(slack), pytest.raises(RuntimeError, match="a bug in the status read"):
        hub.publish_once()
