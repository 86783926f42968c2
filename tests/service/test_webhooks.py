"""Webhooks (service.webhooks): payloads from the daemon's log lines, retries with back-off,
never blocking the caller; a real HTTP receiver on loopback; a daemon's job end delivered."""

from __future__ import annotations

import http.server
import json
import logging
import socket
import threading
from typing import Any, Iterator

import pytest

from nurbsmotion.config import NotifyConfig
from nurbsmotion.log import kv
from nurbsmotion.service.client import Client
from nurbsmotion.service.webhooks import QUEUE_LIMIT, WebhookLogHandler, WebhookSender, http_post, payload_of
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for


class Receiver(http.server.ThreadingHTTPServer):
    """A webhook endpoint on loopback: answers the next ``fail`` POSTs with 500, then 204."""

    def __init__(self, fail: int = 0) -> None:
        self.bodies: list[dict[str, Any]] = []
        self.fail = fail
        receiver = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                if receiver.fail > 0:
                    receiver.fail -= 1
                    self.send_response(500)
                else:
                    receiver.bodies.append(body)
                    self.send_response(204)
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        super().__init__(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server_address[1]}/hook"


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    server = Receiver()
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    server.server_close()


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_job_end_line_becomes_a_payload_with_numbers_and_plain_names():
    _, fields = ("", {"job": "a1", "name": "part.nc", "outcome": "fault", "sent": "120", "planned": "400",
                      "line": "part.nc:12", "motion_time_s": "0.48", "reason": "-"})
    body = payload_of("job_ended", fields, "mill.yaml", now=lambda: 0.0)
    assert body == {"event": "job_ended", "machine": "mill.yaml", "t": "1970-01-01T00:00:00.000+00:00",
                    "job": "a1", "program": "part.nc", "outcome": "fault", "sent": 120, "planned": 400,
                    "line_reached": "part.nc:12", "motion_time_s": 0.48, "reason": None}


def test_failed_deliveries_are_retried_with_doubling_delays_then_given_up_once(caplog):
    calls: list[tuple[float, str]] = []
    answers = iter([500, 0, 204])  # HTTP 500, no answer, then delivered
    clock = FakeClock()

    def post(url: str, body: bytes, timeout_s: float) -> int:
        calls.append((clock.now, url))
        status = next(answers)
        if status == 0:
            raise OSError("connection refused")
        return status

    sender = WebhookSender(NotifyConfig(webhooks=("http://a/x",), retry_s=2.0, attempts=3), "m.yaml", post, clock)
    sender._pending.append(sender_delivery(sender, "http://a/x"))
    sender.send_due()
    clock.now = 1.9
    sender.send_due()
    clock.now = 2.0
    sender.send_due()
    clock.now = 5.9
    sender.send_due()
    clock.now = 6.0
    sender.send_due()
    assert [t for t, _ in calls] == [0.0, 2.0, 6.0] and sender.delivered == 1 and sender.failed == 0

    never = WebhookSender(NotifyConfig(webhooks=("http://b/x",), retry_s=1.0, attempts=2), "m.yaml",
                          lambda *a: 503, clock)
    never._pending.append(sender_delivery(never, "http://b/x"))
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.service.webhooks"):
        for now in (6.0, 7.0, 9.0, 20.0):
            clock.now = now
            never.send_due()
    assert never.failed == 1 and not never._pending
    [line] = [r.getMessage() for r in caplog.records if "webhook_failed" in r.getMessage()]
    assert "http://b/x" in line and "HTTP 503" in line


def sender_delivery(sender: WebhookSender, url: str) -> Any:
    from nurbsmotion.service.webhooks import Delivery

    return Delivery(sender._clock(), 0, url, b"{}")


def test_logging_never_blocks_a_full_queue_drops_and_counts():
    sender = WebhookSender(NotifyConfig(webhooks=("http://a/x",)), "m.yaml", lambda *a: 204)  # not started
    handler = WebhookLogHandler(sender)
    logger = logging.getLogger("nurbsmotion.test_webhooks_full")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        for i in range(QUEUE_LIMIT + 5):
            logger.info(kv("job_ended", job=str(i), outcome="completed"))
        logger.info(kv("job_started", job="x"))  # not a notified event
    finally:
        logger.removeHandler(handler)
    assert sender.dropped == 5 and sender._incoming.qsize() == QUEUE_LIMIT


def test_a_real_receiver_gets_the_json_and_an_unreachable_one_fails_fast(receiver):
    assert http_post(receiver.url, b'{"event": "fault"}', 2.0) == 204
    assert receiver.bodies == [{"event": "fault"}]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    with pytest.raises(OSError):
        http_post(f"http://127.0.0.1:{closed}/x", b"{}", 2.0)


def test_the_daemon_posts_a_job_end_and_retries_a_receiver_that_failed(receiver, tmp_path):
    receiver.fail = 1  # the first try answers 500: delivered on the retry
    extra = f"notify: {{webhooks: [{receiver.url}], retry_s: 0.2}}\n"
    with daemon_in_process(tmp_path / "data", extra, "hook") as daemon, Client(daemon.config.control.socket) as client:
        job = client.call("submit", name="hook.nc", program="G21 G90\nG01 X2 F1200\nG01 X0\n")["job"]["id"]
        wait_for(lambda: receiver.bodies, 30.0, "the webhook")
    [body] = receiver.bodies
    assert body["event"] == "job_ended" and body["job"] == job and body["program"] == "hook.nc"
    assert body["outcome"] == "completed" and body["machine"].endswith("machine.yaml")
    assert body["motion_time_s"] > 0
