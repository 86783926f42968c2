"""One daemon subscription shared by every WebSocket client (Moonraker keeps one connection to
Klippy and fans its updates out to all of its clients).

The gateway holds a single ``subscribe`` connection to the daemon while any client is there
(and LINGER_S after the last one left, so a page reload does not churn it), so ten browser
tabs cost the daemon one subscriber, not ten. It keeps the daemon's latest full status (the
subscription's first answer with every ``changes`` since applied: protocol.merge_changes), so
a client that joins later first gets a complete snapshot in the same shape as the daemon's
answer (``{"ok": true, "subscribed": true, "max_hz", "status"}``), then the same lines every
client gets, relayed as the daemon wrote them (decoded once, never re-encoded per client).

A slow client never holds the others or the daemon link: each has a bounded queue; when it is
full, what waits is thrown away and replaced by one fresh snapshot marked ``"resynced": true,
"skipped_messages": N`` (logged ``web_client_resynced``), which is complete by itself. When
the daemon goes away every client gets ``{"notify": "daemon_gone", "error"}`` once, and the
link tries again every RESUBSCRIBE_S: when the daemon is back, every client gets a new
snapshot.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from dataclasses import dataclass, field
from typing import Any

from nurbsmotion.log import kv
from nurbsmotion.service.protocol import Status, merge_changes
from nurbsmotion.web.daemon_link import DaemonLink, DaemonUnreachable

log = logging.getLogger(__name__)

CLIENT_QUEUE_MESSAGES = 256  # about 10 s of status lines at 20 Hz with events: a client this far behind resyncs
RESUBSCRIBE_S = 1.0  # after the daemon went away, try again this often
LINGER_S = 5.0  # keep the daemon subscription this long after the last client left


@dataclass(eq=False)
class FanoutClient:
    """One WebSocket client's queue of JSON texts to send, in order."""

    name: str
    queue: asyncio.Queue[str]
    resyncs: int = 0

    def offer(self, text: str) -> bool:
        """Queue ``text``; False when the queue is full (the client fell behind)."""
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:
            return False
        return True

    def drop_waiting(self) -> int:
        """Throw away what waits (the client fell behind); the number of messages skipped."""
        skipped = 0
        while not self.queue.empty():
            self.queue.get_nowait()
            skipped += 1
        self.resyncs += 1
        return skipped

    async def next_text(self) -> str:
        return await self.queue.get()


@dataclass(eq=False)
class StatusFanout:
    """The daemon's subscription, held once and relayed to every joined client."""

    link: DaemonLink
    queue_messages: int = CLIENT_QUEUE_MESSAGES
    resubscribe_s: float = RESUBSCRIBE_S
    linger_s: float = LINGER_S
    subscriptions: int = 0  # daemon subscriptions opened so far (one for many clients)
    _clients: set[FanoutClient] = field(default_factory=set)
    _answer: dict[str, Any] | None = None  # the daemon's subscription answer without its status
    _status: Status | None = None  # the daemon's full status now, while subscribed
    _gone: str | None = None  # why there is no daemon, once a subscription failed
    _task: asyncio.Task[None] | None = None
    _idle: asyncio.TimerHandle | None = None
    _joined: int = 0

    @property
    def clients(self) -> int:
        return len(self._clients)

    def join(self) -> FanoutClient:
        """A new client: its queue starts with the full status (or ``daemon_gone``) when known,
        and the daemon subscription is opened if it was not."""
        self._joined += 1
        client = FanoutClient(f"ws{self._joined}", asyncio.Queue(self.queue_messages))
        self._clients.add(client)
        if self._status is not None:
            client.offer(self._snapshot())
        elif self._gone is not None:
            client.offer(gone_message(self._gone))
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._follow(), name="daemon-subscription")
        return client

    def leave(self, client: FanoutClient) -> None:
        """The client is gone; the last one out closes the subscription LINGER_S later."""
        self._clients.discard(client)
        if not self._clients and self._idle is None:
            self._idle = asyncio.get_running_loop().call_later(self.linger_s, self._close_if_idle)

    async def close(self) -> None:
        """Close the daemon subscription (the gateway's shutdown)."""
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        task = self._unsubscribe()
        if task is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await task

    def _close_if_idle(self) -> None:
        self._idle = None
        if not self._clients:
            self._unsubscribe()

    def _unsubscribe(self) -> asyncio.Task[None] | None:
        """Cancel the subscription's task (its connection closes as it ends); that task."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
        self._status = self._answer = None
        return task

    # ------------------------------------------------------------------ the daemon side
    async def _follow(self) -> None:
        """Subscribe, relay, and subscribe again whenever the daemon went away."""
        while True:
            try:
                reason = await self._relay_one_subscription()
            except DaemonUnreachable as err:
                reason = str(err)
            except ValueError as err:  # a line that is not JSON: start again from a fresh snapshot
                reason = f"the daemon sent a line that is not JSON ({err})"
            self._status = self._answer = None
            if self._gone is None:  # told once when it goes; a client joining later gets the latest reason
                log.warning(kv("web_daemon_gone", reason=reason, clients=len(self._clients)))
                self._broadcast(gone_message(reason))
            self._gone = reason
            await asyncio.sleep(self.resubscribe_s)

    async def _relay_one_subscription(self) -> str:
        """Relay one daemon subscription until it ends; why it ended."""
        self.subscriptions += 1
        first = True
        async with contextlib.aclosing(self.link.subscribe_lines()) as lines:  # closed at once when cancelled
            async for text in lines:
                message = json.loads(text)
                if first:
                    first = False
                    if not message.get("ok"):
                        return f"the daemon refused the subscription: {message.get('error', '?')}"
                    self._subscribed(message)
                    continue
                if message.get("notify") == "status" and self._status is not None:
                    self._status = merge_changes(self._status, message.get("changes") or {})
                self._broadcast(text)
                await asyncio.sleep(0)  # let the clients' senders run between the lines of a burst
        return "the daemon closed the connection"

    def _subscribed(self, answer: dict[str, Any]) -> None:
        self._status = answer.pop("status", None) or {}
        self._answer = answer
        if self._gone is not None:
            log.info(kv("web_daemon_back", clients=len(self._clients)))
        self._gone = None
        self._broadcast(self._snapshot())

    def _snapshot(self, **extra: Any) -> str:
        return json.dumps({**(self._answer or {"ok": True, "subscribed": True}), "status": self._status, **extra})

    def _broadcast(self, text: str) -> None:
        """``text`` to every client; one that cannot take it gets a fresh snapshot instead."""
        for client in self._clients:
            if client.offer(text):
                continue
            skipped = client.drop_waiting()
            client.offer(text if self._status is None else self._snapshot(resynced=True, skipped_messages=skipped))
            log.warning(kv("web_client_resynced", client=client.name, skipped_messages=skipped,
                           queue=self.queue_messages, resyncs=client.resyncs))


def gone_message(reason: str) -> str:
    return json.dumps({"notify": "daemon_gone", "error": reason})
