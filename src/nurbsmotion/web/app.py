"""``nurbsmotion web``: the gateway's aiohttp application (API, WebSocket, console page).

Security (docs/web.md): on a loopback address with ``require_auth`` off every client is an
operator (as the Unix socket trusts the machine's own users); on any other address, or with
``require_auth``, every request needs an API key (``Authorization: Bearer KEY`` or
``X-Api-Key: KEY``; the WebSocket also takes ``?token=`` a one-shot token or the key in its
first message). No cookies are set, so no CSRF token is needed; no CORS header unless
``web.cors_origins`` names the origin. Every refusal is a 4xx JSON ``{"error": "one line"}``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import socket
import weakref
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Awaitable, Callable

from aiohttp import WSCloseCode, WSMsgType, web

from nurbsmotion.config import GatewayCpus
from nurbsmotion.log import kv
from nurbsmotion.web.auth import FailedAttempts, KeyStore, OneShotTokens, Role
from nurbsmotion.web.daemon_link import DaemonLink, DaemonUnreachable
from nurbsmotion.web.fanout import FanoutClient, StatusFanout
from nurbsmotion.web.openapi import openapi_document
from nurbsmotion.web.priority import lower_own_priority, place_own_threads
from nurbsmotion.web.routes import API, ROUTES, error, job_file_handler, route_handler

log = logging.getLogger(__name__)

# WebSocket requests a client may send, and the role each needs (abort: anyone signed in)
WS_COMMANDS = {"status": Role.OBSERVER, "jobs": Role.OBSERVER, "job": Role.OBSERVER, "abort": Role.OBSERVER,
               "hold": Role.OPERATOR, "resume": Role.OPERATOR, "stop": Role.OPERATOR, "reset": Role.OPERATOR,
               "jog": Role.OPERATOR, "jog_renew": Role.OPERATOR, "jog_stop": Role.OPERATOR, "mdi": Role.OPERATOR,
               "override": Role.OPERATOR, "home": Role.OPERATOR, "offsets": Role.OPERATOR}
WS_AUTH_TIMEOUT_S = 5.0
# A WebSocket's kernel send buffer (autotuned up to 4 MB otherwise), the event loop's write
# buffer above it (64 KiB by default) and how much aiohttp writes before it waits for room
# (256 KiB by default): a client that stops reading soon holds up its own sender, so its queue
# fills and it is resynced with the status of now (web.fanout) instead of reading seconds-old
# positions out of a deep buffer later.
WS_SEND_BUFFER_BYTES = 16 * 1024
ROLE = web.RequestKey("role", Role)  # the caller's role, set by the auth middleware
FANOUT = web.AppKey("fanout", StatusFanout)  # the one daemon subscription every WebSocket shares
SOCKETS = web.AppKey("sockets", weakref.WeakSet[web.WebSocketResponse])  # open WebSockets, closed on shutdown


@dataclass(frozen=True)
class WebSettings:
    """What the gateway needs: where the daemon is, where to listen, who may do what."""

    socket: str
    data_dir: str
    host: str = "127.0.0.1"
    port: int = 8080
    require_auth: bool = False
    max_upload_bytes: int = 64 * 1024 * 1024
    cors_origins: tuple[str, ...] = field(default_factory=tuple)
    nice: int = 10  # added to the gateway's niceness at start-up (web.priority)
    cpus: GatewayCpus | tuple[int, ...] = GatewayCpus.AUTO  # where its threads run (web.priority)

    @property
    def auth_required(self) -> bool:
        """Loopback-only by default; any other address always needs keys."""
        return self.require_auth or not is_loopback(self.host)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class Gate:
    """Who a request is: the role its key (or the loopback default) gives."""

    settings: WebSettings
    keys: KeyStore
    oneshots: OneShotTokens = field(default_factory=OneShotTokens)
    failures: FailedAttempts = field(default_factory=FailedAttempts)

    def role_of(self, request: web.Request, token: str | None = None) -> Role | web.Response:
        """The caller's role, or the 401/429 refusal. ``token``: a key or one-shot token given
        another way than the headers (the WebSocket)."""
        if not self.settings.auth_required:
            return Role.OPERATOR
        address = request.remote or "?"
        if self.failures.blocked(address):
            return error(429, "too many failed attempts from this address: wait a minute")
        key = token or bearer(request)
        if key is None:
            return error(401, "authentication required: send 'Authorization: Bearer KEY' or 'X-Api-Key: KEY' "
                              "(keys: nurbsmotion web keys add NAME --role operator|observer)")
        record = self.keys.role_of(key)
        if record is not None:
            return record.role
        oneshot = self.oneshots.redeem(key)
        if oneshot is not None:
            return oneshot
        count = self.failures.add(address)
        log.warning(kv("web_auth_failed", address=address, path=request.path, failures=count))
        return error(401, "invalid API key")


def bearer(request: web.Request) -> str | None:
    header = request.headers.get("Authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip() or None
    return request.headers.get("X-Api-Key") or None


def needed_role(request: web.Request) -> Role:
    route = request.match_info.route
    return getattr(route.handler, "role", Role.OBSERVER)


def with_role(role: Role, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]) -> Any:
    async def handle(request: web.Request) -> web.StreamResponse:
        return await handler(request)
    handle.role = role  # type: ignore[attr-defined]
    return handle


def make_app(settings: WebSettings) -> web.Application:
    link = DaemonLink(settings.socket)
    gate = Gate(settings, KeyStore(settings.data_dir))
    app = web.Application(client_max_size=settings.max_upload_bytes,
                          middlewares=[errors_as_json(settings.max_upload_bytes), cors(settings.cors_origins),
                                       authenticate(gate)])
    for route in ROUTES:
        app.router.add_route(route.method, route.path, with_role(route.role, route_handler(route, link)))
    app.router.add_get(f"{API}/jobs/{{id}}/files/{{name}}", with_role(Role.OBSERVER, job_file_handler(link)))
    app.router.add_post(f"{API}/access/oneshot", with_role(Role.OBSERVER, oneshot_handler(gate)))
    app.router.add_get(f"{API}/openapi.json", with_role(Role.OBSERVER, openapi_handler))
    fanout = StatusFanout(link)
    app[FANOUT] = fanout
    app[SOCKETS] = weakref.WeakSet()
    app.on_shutdown.append(close_websockets)
    app.router.add_get(f"{API}/ws", websocket_handler(link, gate, fanout))
    app.router.add_get("/", page_handler)
    app.router.add_static("/static/", static_dir(), show_index=False)
    return app


async def close_websockets(app: web.Application) -> None:
    """SIGTERM: close every WebSocket at once (aiohttp's documented pattern; else the shutdown
    waits for each client to hang up), then the daemon subscription."""
    sockets: weakref.WeakSet[web.WebSocketResponse] = app[SOCKETS]
    await asyncio.gather(*(ws.close(code=WSCloseCode.GOING_AWAY, message=b"gateway shutting down")
                           for ws in list(sockets)), return_exceptions=True)  # a stalled one delays no other
    await app[FANOUT].close()


def static_dir() -> Path:
    return Path(str(resources.files("nurbsmotion.web") / "static"))


async def page_handler(request: web.Request) -> web.StreamResponse:
    return web.FileResponse(static_dir() / "index.html", headers={"Cache-Control": "no-cache"})


async def openapi_handler(request: web.Request) -> web.Response:
    return web.json_response(openapi_document(ROUTES))


def oneshot_handler(gate: Gate) -> Callable[[web.Request], Awaitable[web.Response]]:
    async def handle(request: web.Request) -> web.Response:
        role = request.get(ROLE, Role.OPERATOR)
        return web.json_response({"token": gate.oneshots.issue(role), "valid_s": 5.0})
    return handle


def authenticate(gate: Gate) -> Any:
    @web.middleware
    async def middleware(request: web.Request, handler: Any) -> web.StreamResponse:
        if not request.path.startswith(API) or request.path == f"{API}/ws":
            return await handler(request)  # the page and its files; the WebSocket signs in itself
        role = gate.role_of(request)
        if isinstance(role, web.Response):
            return role
        needed = needed_role(request)
        if not role.allows(needed):
            return error(403, f"{request.method} {request.path} needs the {needed.value} role; this key is "
                              f"{role.value}")
        request[ROLE] = role
        return await handler(request)
    return middleware


def cors(origins: tuple[str, ...]) -> Any:
    """CORS headers for the configured origins only (none by default)."""
    @web.middleware
    async def middleware(request: web.Request, handler: Any) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        allowed = origin is not None and origin in origins
        if request.method == "OPTIONS" and allowed:
            response: web.StreamResponse = web.Response(status=204)
        else:
            response = await handler(request)
        if allowed:
            response.headers["Access-Control-Allow-Origin"] = origin or ""
            response.headers["Access-Control-Allow-Headers"] = "Authorization, X-Api-Key, Content-Type"
            response.headers["Access-Control-Allow-Methods"] = "GET, POST, PUT, DELETE"
            response.headers["Vary"] = "Origin"
        return response
    return middleware


def errors_as_json(max_upload_bytes: int) -> Any:
    """aiohttp's own refusals (404, 405, 413) as the API's one-line JSON errors."""
    @web.middleware
    async def middleware(request: web.Request, handler: Any) -> web.StreamResponse:
        try:
            response: web.StreamResponse = await handler(request)
        except web.HTTPRequestEntityTooLarge:
            return error(413, f"upload larger than the {max_upload_bytes / 1048576:g} MB limit (web.max_upload_mb)")
        except web.HTTPException as err:
            if err.status < 400:
                raise
            return error(err.status, f"{request.method} {request.path}: {err.reason}")
        response.headers.setdefault("X-Content-Type-Options", "nosniff")
        return response
    return middleware


def websocket_handler(link: DaemonLink, gate: Gate,
                      fanout: StatusFanout) -> Callable[[web.Request], Awaitable[web.StreamResponse]]:
    """``/api/v1/ws``: the daemon's subscription relayed as JSON messages (one subscription
    shared by every client: web.fanout); the client may send ``{"id": n, "cmd": NAME,
    ...fields}`` (WS_COMMANDS) and gets ``{"id": n, "response": {...}}``."""
    async def handle(request: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(heartbeat=10.0, writer_limit=WS_SEND_BUFFER_BYTES)  # waits for room each 16 KiB
        await ws.prepare(request)
        role = await websocket_role(ws, request, gate)
        if role is None:
            return ws
        bound_send_buffer(request)
        request.app[SOCKETS].add(ws)
        client = fanout.join()
        relay = asyncio.create_task(relay_to(ws, client))
        try:
            async for message in ws:
                if message.type != WSMsgType.TEXT:
                    continue
                await ws.send_json(await websocket_request(message.data, role, link))
        finally:
            fanout.leave(client)
            relay.cancel()
            await ws.close()
        return ws
    return handle


def bound_send_buffer(request: web.Request) -> None:
    transport = request.transport
    if transport is None:
        return
    transport.set_write_buffer_limits(high=WS_SEND_BUFFER_BYTES)
    sock = transport.get_extra_info("socket")
    if sock is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, WS_SEND_BUFFER_BYTES)


async def websocket_role(ws: web.WebSocketResponse, request: web.Request, gate: Gate) -> Role | None:
    """Sign the WebSocket in: ?token=, a header, or ``{"auth": KEY}`` as its first message."""
    token = request.query.get("token")
    if gate.settings.auth_required and token is None and bearer(request) is None:
        try:
            first = await ws.receive_json(timeout=WS_AUTH_TIMEOUT_S)
            token = first.get("auth") if isinstance(first, dict) else None
        except (asyncio.TimeoutError, TypeError, ValueError):
            token = None
    role = gate.role_of(request, token)
    if isinstance(role, web.Response):
        await ws.send_json({"error": json.loads(role.text or "{}").get("error", "refused")})
        await ws.close(code=4401)
        return None
    await ws.send_json({"notify": "welcome", "role": role.value})
    return role


async def websocket_request(data: str, role: Role, link: DaemonLink) -> dict[str, Any]:
    try:
        message = json.loads(data)
    except ValueError:
        return {"error": "message: not JSON"}
    if not isinstance(message, dict):
        return {"error": "message: must be a JSON object"}
    ident, cmd = message.pop("id", None), message.pop("cmd", None)
    needed = WS_COMMANDS.get(cmd) if isinstance(cmd, str) else None
    if needed is None:
        return {"id": ident, "error": f"field 'cmd': one of {', '.join(sorted(WS_COMMANDS))}"}
    if not role.allows(needed):
        return {"id": ident, "error": f"{cmd} needs the {needed.value} role; this connection is {role.value}"}
    try:
        return {"id": ident, "response": await link.request(cmd, **message)}
    except DaemonUnreachable as err:
        return {"id": ident, "error": str(err)}


async def relay_to(ws: web.WebSocketResponse, client: FanoutClient) -> None:
    """Send the client's queued messages in order until its connection closes."""
    try:
        while not ws.closed:
            await ws.send_str(await client.next_text())
    except ConnectionResetError:
        pass


def run_gateway(settings: WebSettings) -> None:
    """Serve until SIGINT/SIGTERM (aiohttp's run_app handles both), on ``settings.cpus`` at
    ``settings.nice`` lower priority than the gateway was started with (web.priority)."""
    cpus = place_own_threads(settings.cpus)
    niceness = lower_own_priority(settings.nice)
    log.info(kv("web_listening", host=settings.host, port=settings.port, auth=settings.auth_required,
                socket=settings.socket, niceness=niceness, cpus=",".join(map(str, sorted(cpus))) or "any"))
    web.run_app(make_app(settings), host=settings.host, port=settings.port, print=None, handle_signals=True,
                access_log=None)
