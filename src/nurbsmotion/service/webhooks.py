"""Webhook notifications: job ends and faults POSTed as JSON to the URLs in ``notify:``.

The daemon's log lines are its events (service.subscriptions reads them the same way): a
``job_ended`` line becomes ``{"event": "job_ended", "job", "program", "outcome",
"motion_time_s", "line_reached", "reason", ...}``, a ``fault`` line ``{"event": "fault",
"node", "axis", "kind", "code", "message", ...}``; each also carries ``machine`` (the
configuration file) and ``t`` (ISO time). A log call only queues the payload (never blocks;
a full queue drops the newest and counts it); one sender thread at normal priority POSTs
each payload to every URL, and retries a failed delivery (no answer, or not 2xx) after
``retry_s``, 2x, 4x ... that, up to ``attempts`` times, then logs ``webhook_failed`` once.
Deliveries to one URL keep their order only as far as retries allow (each is independent).
"""

from __future__ import annotations

import datetime as dt
import heapq
import itertools
import json
import logging
import queue
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from typing import Any, Callable

from nurbsmotion.config import NotifyConfig
from nurbsmotion.log import attach_handler, kv, parse_kv

log = logging.getLogger(__name__)

QUEUE_LIMIT = 1000
NUMBER_FIELDS = ("sent", "planned", "motion_time_s", "node", "cycle", "code")


def payload_of(event: str, fields: dict[str, str], machine: str, now: Callable[[], float] = time.time) -> dict[str, Any]:
    """The JSON body for one logged event: its fields (numbers as numbers), renamed where the
    log is terse (``line`` -> ``line_reached``, ``name`` -> ``program``)."""
    body: dict[str, Any] = {"event": event, "machine": machine,
                            "t": dt.datetime.fromtimestamp(now(), dt.timezone.utc).isoformat(timespec="milliseconds")}
    renames = {"line": "line_reached", "name": "program"}
    for key, value in fields.items():
        if key.startswith("_"):
            continue
        out: Any = None if value == "-" else value
        if key in NUMBER_FIELDS and out is not None:
            try:
                out = int(out, 0) if key in ("node", "cycle", "code", "sent", "planned") else float(out)
            except ValueError:
                pass
        body[renames.get(key, key)] = out
    return body


@dataclass(order=True)
class Delivery:
    due_s: float
    order: int
    url: str = field(compare=False)
    body: bytes = field(compare=False)
    attempt: int = field(compare=False, default=1)


class WebhookSender:
    """The sender thread (module docstring). ``post(url, body, timeout_s)`` is injectable."""

    def __init__(self, config: NotifyConfig, machine: str,
                 post: Callable[[str, bytes, float], int] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.machine = machine
        self._post = post or http_post
        self._clock = clock
        self._incoming: queue.Queue[dict[str, Any] | None] = queue.Queue(QUEUE_LIMIT)
        self._pending: list[Delivery] = []
        self._order = itertools.count()
        self.dropped = 0
        self.delivered = 0
        self.failed = 0
        self._thread: threading.Thread | None = None

    def notify(self, payload: dict[str, Any]) -> None:
        """Queue a payload for every URL (any thread; never blocks)."""
        try:
            self._incoming.put_nowait(payload)
        except queue.Full:
            self.dropped += 1

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="webhooks", daemon=True)
        self._thread.start()

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop after a last try of what is due now (the daemon stops)."""
        self._incoming.put(None)
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def _run(self) -> None:
        while True:
            wait_s = max(self._pending[0].due_s - self._clock(), 0.0) if self._pending else None
            try:
                payload = self._incoming.get(timeout=wait_s)
            except queue.Empty:
                payload = {}
            if payload is None:
                return
            if payload:
                body = json.dumps(payload).encode("utf-8")
                for url in self.config.webhooks:
                    heapq.heappush(self._pending, Delivery(self._clock(), next(self._order), url, body))
            self.send_due()

    def send_due(self) -> None:
        """Try every delivery whose time has come; reschedule the failures (the thread's step)."""
        while self._pending and self._pending[0].due_s <= self._clock():
            delivery = heapq.heappop(self._pending)
            error = self._try(delivery)
            if error is None:
                self.delivered += 1
            elif delivery.attempt >= self.config.attempts:
                self.failed += 1
                log.warning(kv("webhook_failed", url=delivery.url, attempts=delivery.attempt, error=error))
            else:
                delay = self.config.retry_s * 2 ** (delivery.attempt - 1)
                heapq.heappush(self._pending, Delivery(self._clock() + delay, next(self._order), delivery.url,
                                                       delivery.body, delivery.attempt + 1))

    def _try(self, delivery: Delivery) -> str | None:
        try:
            status = self._post(delivery.url, delivery.body, self.config.timeout_s)
        except (OSError, ValueError) as err:
            return str(getattr(err, "reason", err))
        return None if 200 <= status < 300 else f"HTTP {status}"


def http_post(url: str, body: bytes, timeout_s: float) -> int:
    request = urllib.request.Request(url, data=body, method="POST",
                                     headers={"Content-Type": "application/json", "User-Agent": "nurbsmotion"})
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:  # noqa: S310 - URLs from the YAML
            return int(response.status)
    except urllib.error.HTTPError as err:
        return int(err.code)


class WebhookLogHandler(logging.Handler):
    """Feeds the notified events of the package's log to a WebhookSender."""

    def __init__(self, sender: WebhookSender) -> None:
        super().__init__(logging.INFO)
        self.sender = sender

    def emit(self, record: logging.LogRecord) -> None:
        try:
            event, fields = parse_kv(record.getMessage())
            if event in self.sender.config.events:
                self.sender.notify(payload_of(event, fields, self.sender.machine))
        except Exception:  # noqa: BLE001 - logging must never raise into the caller
            self.handleError(record)


def start_webhooks(config: NotifyConfig, machine: str, logger_name: str = "nurbsmotion") -> Callable[[], None] | None:
    """Start the sender and route the log to it; returns the function that stops both (None:
    no webhooks configured)."""
    if not config.webhooks:
        return None
    sender = WebhookSender(config, machine)
    sender.start()
    detach = attach_handler(WebhookLogHandler(sender), logger_name)

    def stop() -> None:
        detach()
        sender.close()

    return stop
