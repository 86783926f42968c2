"""The gateway's fan-out (web.fanout) against a real daemon with simulated drives, over real
HTTP and WebSockets on loopback: ten clients share one daemon subscription and see the same
lines; a client that joins later starts from a complete status; a client that stops reading
holds nobody else and is resynced; the daemon going away and coming back."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import os
import socket
import struct
import tempfile
import uuid
from pathlib import Path
from typing import Any, AsyncIterator

import aiohttp
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.service.client import Client
from nurbsmotion.service.protocol import merge_changes
from nurbsmotion.web.app import FANOUT, WebSettings, make_app
from nurbsmotion.web.fanout import StatusFanout
from tests.helpers import wait_for
from tests.integration.daemon_helpers import CONFIG, daemon_in_process
from tests.web.ports import free_port
from tests.web.serving import serving

WAIT_S = 30.0


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with daemon_in_process(tmp_path_factory.mktemp("fanout") / "data", "", "fanout") as d:
        yield d


@contextlib.asynccontextmanager
async def gateway(daemon: Any, **fanout: Any) -> AsyncIterator[tuple[str, StatusFanout]]:
    """A gateway for ``daemon`` on a free loopback port; its fan-out set up with ``fanout``."""
    settings = WebSettings(socket=str(daemon.config.control.socket), data_dir=str(daemon.config.data_dir),
                           port=free_port())
    app = make_app(settings)
    for name, value in fanout.items():
        setattr(app[FANOUT], name, value)
    async with serving(app, settings.host, settings.port) as base:
        yield base, app[FANOUT]


class Follower:
    """One WebSocket client that keeps the status the way the console page does: the
    ``subscribed`` snapshot replaces it, each ``changes`` is merged into it."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.messages: list[dict[str, Any]] = []
        self.status: dict[str, Any] | None = None

    async def read_until(self, done: Any, what: str, timeout_s: float | None = WAIT_S) -> dict[str, Any]:
        """Read messages until ``done(message)``; that message."""
        async def loop() -> dict[str, Any]:
            while True:
                message = await self.ws.receive_json()
                self.messages.append(message)
                if message.get("subscribed"):
                    self.status = message["status"]
                elif message.get("notify") == "status" and self.status is not None:
                    self.status = merge_changes(self.status, message["changes"])
                if done(message):
                    return message
        try:
            return await asyncio.wait_for(loop(), timeout_s)
        except asyncio.TimeoutError:
            events = sum(m.get("notify") == "event" for m in self.messages)
            resyncs = sum(bool(m.get("resynced")) for m in self.messages)
            raise AssertionError(f"timed out waiting for {what}; {len(self.messages)} messages, {events} events, "
                                 f"{resyncs} resyncs, the last {self.messages[-3:]}") from None

    def relayed_seqs(self) -> list[int]:
        return [m["seq"] for m in self.messages if "seq" in m]


def status_request(daemon: Any) -> dict[str, Any]:
    """The daemon's answer to ``status`` on its socket (what a subscription starts from)."""
    with Client(daemon.config.control.socket) as client:
        return client.call("status")


def is_event(name: str) -> Any:
    return lambda m: m.get("notify") == "event" and m.get("event") == name


async def follower(session: aiohttp.ClientSession, base: str) -> Follower:
    """A connected client past its welcome and first snapshot."""
    f = Follower(await session.ws_connect(f"{base}/api/v1/ws"))
    assert (await f.read_until(lambda m: True, "welcome"))["notify"] == "welcome"
    await f.read_until(lambda m: m.get("subscribed"), "the first snapshot")
    return f


async def mdi(session: aiohttp.ClientSession, base: str, text: str) -> str:
    async with session.post(f"{base}/api/v1/machine/mdi", json={"text": text}) as response:
        answer = await response.json()
        assert response.status == 200, answer
        return str(answer["job"]["id"])


def test_ten_clients_share_one_daemon_subscription_and_see_the_same_lines(daemon):
    async def body() -> None:
        async with gateway(daemon) as (base, fanout), aiohttp.ClientSession() as s:
            clients = [await follower(s, base) for _ in range(10)]
            for c in clients:
                assert c.status is not None and c.status["state"] == "idle" and len(c.status["axes"]) == 3
            assert fanout.subscriptions == 1 and fanout.clients == 10
            assert daemon.hub.subscribers == 1  # the daemon encodes and writes one stream, not ten
            job = await mdi(s, base, "G21 G90 G01 X3 F600")
            for c in clients:
                ended = await c.read_until(is_event("job_ended"), "job_ended on every client")
                assert ended["fields"]["job"] == job and ended["fields"]["outcome"] == "completed"
                assert any(is_event("job_started")(m) for m in c.messages)
            seqs = clients[0].relayed_seqs()
            assert len(seqs) > 3 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # nothing lost
            for c in clients[1:]:  # the same daemon lines, in the same order, to every client
                assert c.relayed_seqs()[-len(seqs):] == seqs[-len(c.relayed_seqs()):]
            await mdi(s, base, "G21 G90 G01 X0 F600")
            await clients[0].read_until(is_event("job_ended"), "the return to X0")
            for c in clients:
                await c.ws.close()
    asyncio.run(body())


def test_the_daemon_subscription_is_closed_after_the_last_client_left_and_opened_again(daemon):
    async def body() -> None:
        async with gateway(daemon, linger_s=0.3) as (base, fanout), aiohttp.ClientSession() as s:
            first = await follower(s, base)
            assert daemon.hub.subscribers == 1
            await first.ws.close()
            await asyncio.to_thread(wait_for, lambda: daemon.hub.subscribers == 0, WAIT_S,
                                    "the daemon subscription closed after the last client")
            again = await follower(s, base)
            assert again.status is not None and again.status["state"] == "idle"
            assert fanout.subscriptions == 2 and daemon.hub.subscribers == 1
    asyncio.run(body())


def test_the_gateway_shutting_down_closes_open_websockets_and_its_subscription(daemon):
    async def body() -> None:
        async with aiohttp.ClientSession() as s:
            async with gateway(daemon) as (base, fanout):
                c = await follower(s, base)
                assert daemon.hub.subscribers == 1
            # the block's end is the gateway's shutdown (SIGTERM in `nurbsmotion web`)
            closing = await asyncio.wait_for(c.ws.receive(), WAIT_S)
            while closing.type == aiohttp.WSMsgType.TEXT:  # a status line sent before the shutdown
                closing = await asyncio.wait_for(c.ws.receive(), WAIT_S)
            assert closing.type == aiohttp.WSMsgType.CLOSE and closing.data == aiohttp.WSCloseCode.GOING_AWAY
            await asyncio.to_thread(wait_for, lambda: daemon.hub.subscribers == 0, WAIT_S, "the subscription closed")
    asyncio.run(body())


def test_a_client_that_joins_later_first_gets_the_complete_status(daemon):
    async def body() -> None:
        async with gateway(daemon) as (base, fanout), aiohttp.ClientSession() as s:
            early = await follower(s, base)
            job = await mdi(s, base, "G21 G90 G01 X2.5 Y-1 F600")
            await early.read_until(lambda m: early.status is not None and early.status["state"] == "idle"
                                   and early.status["job"] is None and (early.status.get("last_job") or {}).get("id")
                                   == job, "the idle state after the job")
            late = await follower(s, base)
            assert fanout.subscriptions == 1
            assert late.status is not None and set(late.status) == set(await asyncio.to_thread(status_request, daemon))
            assert [a["commanded_mm"] for a in late.status["axes"]][:2] == [2.5, -1.0]
            # both clients at the same relayed line: the early one's status, merged from every
            # line since it joined, equals the late one's, merged from its snapshot on
            await early.ws.send_json({"id": "mark", "cmd": "override", "percent": 99})
            marked = is_event("override_changed")
            mark = await early.read_until(marked, "the marker event")
            assert (await late.read_until(marked, "the marker event on the late client"))["seq"] == mark["seq"]
            assert late.status == early.status
            await mdi(s, base, "G21 G90 G01 X0 Y0 F600")  # then the same changes as everyone
            await late.read_until(is_event("job_ended"), "the return to the origin")
            await late.read_until(lambda m: late.status is not None and late.status["state"] == "idle"
                                  and [a["commanded_mm"] for a in late.status["axes"]][:2] == [0.0, 0.0],
                                  "the origin in the late client's merged status")
    asyncio.run(body())


class StalledWebSocket:
    """A WebSocket client that stops reading after the handshake, with a tiny receive buffer,
    so the gateway's writes to it soon block (a tab on a dead Wi-Fi link); ``frames`` reads
    what waited, later."""

    def __init__(self, base: str) -> None:
        host, port = base.removeprefix("http://").split(":")
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
        self.sock.connect((host, int(port)))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET /api/v1/ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
                          .encode())
        self.stream = self.sock.makefile("rb")
        while self.stream.readline() not in (b"\r\n", b""):
            pass  # the 101 answer and its headers

    def frames(self) -> Any:
        """The text frames the gateway sent, as JSON, until it closes (server frames: unmasked)."""
        while True:
            head = self.stream.read(2)
            if len(head) < 2:
                return
            opcode, length = head[0] & 0x0F, head[1] & 0x7F
            if length == 126:
                length = struct.unpack(">H", self.stream.read(2))[0]
            elif length == 127:
                length = struct.unpack(">Q", self.stream.read(8))[0]
            payload = self.stream.read(length)
            if opcode == 8:
                return
            if opcode == 1:
                yield json.loads(payload)

    def close(self) -> None:
        self.stream.close()
        self.sock.close()


def test_a_client_that_stops_reading_holds_nobody_and_is_resynced(daemon, caplog):
    overrides = 300

    async def body() -> None:
        async with gateway(daemon, queue_messages=16) as (base, fanout), aiohttp.ClientSession() as s:
            fast = await follower(s, base)
            stalled = await asyncio.to_thread(StalledWebSocket, base)
            await asyncio.to_thread(wait_for, lambda: fanout.clients == 2, WAIT_S, "the stalled client joined")
            for i in range(overrides):  # an event (override_changed) and a status change each
                await fast.ws.send_json({"id": i, "cmd": "override", "percent": 100 - i % 2})
            await fast.read_until(lambda m: m.get("id") == overrides - 1, "the last override's answer")
            await fast.read_until(lambda m: sum(map(is_event("override_changed"), fast.messages)) == overrides,
                                  "every override_changed event on the client that reads")  # (status: 20 Hz)
            seqs = fast.relayed_seqs()
            assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # all of them, in order
            assert not any(m.get("resynced") for m in fast.messages)
            # the status lines (20 a second) go on filling the stalled client's socket and queue
            await asyncio.to_thread(wait_for, lambda: any(c.resyncs for c in fanout._clients), WAIT_S,
                                    "the stalled client resynced")
            [stalled_client] = [c for c in fanout._clients if c.resyncs]
            assert stalled_client.queue.qsize() <= 16  # bounded, however far behind
            frames = stalled.frames()
            snapshot = await asyncio.to_thread(next, (m for m in frames if m.get("resynced")))
            assert snapshot["subscribed"] and snapshot["skipped_messages"] > 0
            assert set(snapshot["status"]) == set(fast.status or {})  # complete by itself
            await asyncio.to_thread(stalled.close)
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.web.fanout"):
        asyncio.run(body())
    assert any("web_client_resynced" in r.getMessage() and "skipped_messages=" in r.getMessage()
               for r in caplog.records)


def test_the_daemon_going_away_is_told_and_its_return_resubscribes(tmp_path):
    from nurbsmotion.service.daemon import Daemon

    folder = Path(tempfile.mkdtemp(prefix="nm-fan-"))
    path = folder / "machine.yaml"
    path.write_text(CONFIG.format(channel=f"fangone-{uuid.uuid4().hex}", socket=folder / "ctl.sock",
                                  data_dir=tmp_path / "data"))
    config = load_config(path)
    first = Daemon(config)
    first.start()
    restarted: list[Any] = []

    async def body() -> None:
        async with gateway(first, resubscribe_s=0.2) as (base, fanout), aiohttp.ClientSession() as s:
            c = await follower(s, base)
            await asyncio.to_thread(first.close)
            gone = await c.read_until(lambda m: m.get("notify") == "daemon_gone", "daemon_gone")
            assert gone["error"]
            meanwhile = Follower(await s.ws_connect(f"{base}/api/v1/ws"))  # joins while there is none
            await meanwhile.read_until(lambda m: m.get("notify") == "daemon_gone", "daemon_gone for a new client")
            second = Daemon(config)
            restarted.append(second)
            # both clients keep reading while the daemon starts (a client answers the gateway's pings
            # only while it reads); the wait for the snapshot starts when the daemon is up
            reads = asyncio.gather(*(f.read_until(lambda m: m.get("subscribed"), "a new snapshot", timeout_s=None)
                                     for f in (c, meanwhile)))
            await asyncio.to_thread(second.start)
            try:
                backs = await asyncio.wait_for(reads, WAIT_S)
            except asyncio.TimeoutError:
                raise AssertionError(f"no snapshot from the restarted daemon; the last {c.messages[-3:]}") from None
            for back in backs:
                assert back["status"]["state"] == "idle" and len(back["status"]["axes"]) == 3
            assert sum(m.get("notify") == "daemon_gone" for m in c.messages) == 1  # told once, not every retry
            assert fanout.subscriptions >= 2 and second.hub is not None and second.hub.subscribers == 1
    try:
        asyncio.run(body())
    finally:
        for d in restarted:
            d.close()
