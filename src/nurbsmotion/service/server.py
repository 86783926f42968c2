"""The control socket: a Unix stream socket (mode 0660, no TCP), one thread per client.

Each line a client sends is one request (see protocol); each gets one response line.
A malformed, oversized or refused request gets an error line and the daemon keeps serving;
a client that disappears mid-request only ends its own thread. A ``subscribe`` request turns
its connection into a push stream (service.subscriptions): the hub's publisher writes every
subscriber's lines without blocking (what a socket cannot take waits in that client's own
queue, so a slow subscriber delays nobody) and the client's thread only waits for it to
hang up.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import select
import socket
import stat
import threading
from pathlib import Path
from typing import Any, Callable, Iterator

from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.service import access
from nurbsmotion.service.protocol import (MAX_FDS, MAX_REQUEST_BYTES, EncodedResponse, ProtocolError, Request, encode,
                                         error_response, parse_request)
from nurbsmotion.service.subscriptions import DEFAULT_MAX_HZ, MAX_HZ_RANGE, StatusHub, Subscription

log = logging.getLogger(__name__)

Handler = Callable[[Request], dict[str, Any]]
SOCKET_MODE = 0o660
_CHUNK = 1 << 20


class ControlServer:
    """Serves ``handler`` on the Unix socket ``path`` until :meth:`close`."""

    def __init__(self, path: str | Path, handler: Handler, control_group: str | None = None,
                 max_clients: int = 48, idle_timeout_s: float = 600.0, hub: StatusHub | None = None,
                 max_subscribers: int = 32) -> None:
        self.path = Path(path)
        self.handler = handler
        self.hub = hub
        self._subscriber_slots = threading.BoundedSemaphore(max_subscribers)
        self.control_group = control_group
        try:
            self.control_gid = access.group_id(control_group)
        except KeyError:
            raise InputError("control.group", f"unknown group {control_group!r}") from None
        self.daemon_uid = os.getuid()
        self.idle_timeout_s = idle_timeout_s
        self._slots = threading.BoundedSemaphore(max_clients)
        self._listener: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._clients: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stopping = threading.Event()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Bind (replacing a stale socket file, refusing a live one), set the mode, listen."""
        self._remove_stale_socket()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old_umask = os.umask(0o117)  # the socket is created 0660, never wider, even for a moment
        try:
            listener.bind(str(self.path))
        except OSError as err:
            listener.close()
            raise InputError("control.socket", f"cannot bind {self.path}: {err.strerror or err}") from None
        finally:
            os.umask(old_umask)
        os.chmod(self.path, SOCKET_MODE)
        if self.control_gid is not None:
            try:
                os.chown(self.path, -1, self.control_gid)
            except OSError as err:
                log.warning(kv("socket_group_not_set", path=self.path, group=self.control_group, error=err.strerror))
        listener.listen(64)  # a burst of clients must not see EAGAIN
        listener.settimeout(0.2)
        self._listener = listener
        self._thread = threading.Thread(target=self._accept_loop, name="control-accept", daemon=True)
        self._thread.start()
        log.info(kv("control_socket", path=self.path))

    def _remove_stale_socket(self) -> None:
        if not self.path.exists() and not self.path.is_symlink():
            return
        if not stat.S_ISSOCK(self.path.lstat().st_mode):
            raise InputError("control.socket", f"{self.path} exists and is not a socket")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        probe.settimeout(1.0)
        try:
            probe.connect(str(self.path))
        except OSError:
            self.path.unlink()  # nobody listens: left over from a daemon that died
            return
        finally:
            probe.close()
        raise InputError("control.socket", f"another daemon is already serving {self.path}")

    def close(self) -> None:
        """Stop accepting, drop the clients, remove the socket file."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._listener is not None:
            self._listener.close()
            self._listener = None
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass
        with self._lock:
            clients = list(self._clients)
        for conn in clients:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # ------------------------------------------------------------------ clients
    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stopping.is_set():
            try:
                conn, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                if self._stopping.is_set():
                    return
                continue
            if not self._slots.acquire(blocking=False):
                self._send(conn, error_response("busy: too many control clients connected"))
                conn.close()
                continue
            threading.Thread(target=self._client, args=(conn,), name="control-client", daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with self._lock:
            self._clients.add(conn)
        try:
            peer = access.peer_credentials(conn)
            if not access.peer_allowed(peer, self.daemon_uid, self.control_gid):
                log.warning(kv("control_refused", pid=peer.pid, uid=peer.uid, gid=peer.gid))
                self._send(conn, error_response(access.refusal(peer, self.control_group)))
                return
            conn.settimeout(self.idle_timeout_s)
            for line, files in _request_lines(conn):
                try:
                    request = self._parse(line)
                    if isinstance(request, Request) and request.cmd == "subscribe":
                        self._serve_subscription(conn, request)
                        return
                    response = self.handle(dataclasses.replace(request, files=tuple(files))) \
                        if isinstance(request, Request) else request
                finally:
                    _close_all(files)
                if not self._send(conn, response):
                    return
        except OSError:
            pass  # the client went away or idled out: only its own connection ends
        finally:
            with self._lock:
                self._clients.discard(conn)
            conn.close()
            self._slots.release()

    @staticmethod
    def _parse(line: bytes | None) -> Request | dict[str, Any]:
        """The checked request, or the error response for a line that is not one."""
        if line is None:
            return error_response(f"request: longer than the {MAX_REQUEST_BYTES // (1024 * 1024)} MB limit")
        try:
            return parse_request(line)
        except ProtocolError as err:
            return error_response(str(err))

    def handle(self, request: Request) -> dict[str, Any]:
        """The handler's response; an InputError or a bug becomes an error line."""
        try:
            return self.handler(request)
        except InputError as err:
            return error_response(str(err).splitlines()[0], str(err).splitlines())
        except Exception as err:  # noqa: BLE001 - one bad request must not end the daemon
            log.exception("control request %s failed", request.cmd)
            return error_response(f"internal error: {type(err).__name__}: {err}")

    # ------------------------------------------------------------------ subscribers
    def _serve_subscription(self, conn: socket.socket, request: Request) -> None:
        """Answer with the full status, then push this client's lines until it closes, the
        daemon stops, or it falls too far behind."""
        refusal = self._subscription_refusal(request)
        if refusal is not None:
            self._send(conn, refusal)
            return
        assert self.hub is not None
        max_hz = float(request.fields.get("max_hz", DEFAULT_MAX_HZ))
        try:
            try:
                sub, status = self.hub.subscribe(max_hz)
            except InputError as err:  # the status read refused (as a status request would be)
                self._send(conn, error_response(str(err).splitlines()[0]))
                return
            try:
                if self._send(conn, {"ok": True, "subscribed": True, "max_hz": max_hz, "status": status}):
                    self._push(conn, sub)
            finally:
                self.hub.unsubscribe(sub)
        finally:
            self._subscriber_slots.release()

    def _subscription_refusal(self, request: Request) -> dict[str, Any] | None:
        if self.hub is None:
            return error_response("subscribe: this daemon does not push status")
        max_hz = float(request.fields.get("max_hz", DEFAULT_MAX_HZ))
        low, high = MAX_HZ_RANGE
        if not low <= max_hz <= high:
            return error_response(f"field 'max_hz': must be within {low:g}-{high:g} status lines a second, got {max_hz:g}")
        if not self._subscriber_slots.acquire(blocking=False):
            return error_response("busy: too many subscribed clients")
        return None

    def _push(self, conn: socket.socket, sub: Subscription) -> None:
        """The hub's publisher sends this client's lines (Subscription.attach, non-blocking);
        this thread sleeps until the client hangs up, the daemon stops (close shuts every
        connection down) or the hub drops the client (its on_drop shuts the reading side
        down): no periodic wake-up, so ten subscribers add no thread that takes the
        interpreter lock while nothing happens."""
        conn.setblocking(False)
        sub.attach(conn.send, on_drop=lambda: _stop_reading(conn))
        while not self._stopping.is_set() and sub.dropped is None:
            try:
                readable, _, _ = select.select([conn], [], [])
            except (OSError, ValueError):
                return
            if sub.dropped is None and readable and _peer_closed(conn):
                return
        if sub.dropped is not None:
            conn.setblocking(True)
            conn.settimeout(1.0)
            _send_lines(conn, [sub.unsent, *sub.take(0.0)])  # the 'dropped' line, after what was queued

    @staticmethod
    def _send(conn: socket.socket, response: dict[str, Any]) -> bool:
        try:
            conn.sendall(response.line if isinstance(response, EncodedResponse) else encode(response))
            return True
        except OSError:
            return False


def _send_lines(conn: socket.socket, lines: list[bytes]) -> bool:
    try:
        conn.sendall(b"".join(lines))
        return True
    except OSError:
        return False


def _stop_reading(conn: socket.socket) -> None:
    """Wake the subscriber's thread from its select (EOF on the reading side); the 'dropped'
    line can still be sent."""
    try:
        conn.shutdown(socket.SHUT_RD)
    except OSError:
        pass


def _peer_closed(conn: socket.socket) -> bool:
    """The subscriber hung up (EOF); anything it sends after subscribing is ignored."""
    try:
        data = conn.recv(4096, socket.MSG_DONTWAIT)
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True
    return not data


def _close_all(files: list[int]) -> None:
    for fd in files:
        try:
            os.close(fd)
        except OSError:
            pass
    files.clear()


def _request_lines(conn: socket.socket) -> Iterator[tuple[bytes | None, list[int]]]:
    """Yield each complete line (without the newline) with the descriptors received while it
    arrived (protocol ``program_fd``: a client sends its request and waits for the answer, so
    they are that line's; the caller closes them); None as soon as a line passes the size
    limit: the rest of that line is read and dropped, so the connection stays usable."""
    buf = bytearray()
    files: list[int] = []
    scanned = 0
    dropping = False
    try:
        while True:
            newline = buf.find(b"\n", scanned)
            if newline >= 0:
                line = bytes(buf[:newline])
                del buf[:newline + 1]
                scanned = 0
                if not dropping and line.strip():
                    taken, files = files, []
                    yield line, taken
                dropping = False
                continue
            if len(buf) > MAX_REQUEST_BYTES:
                if not dropping:
                    yield None, []
                dropping = True
                buf.clear()
            scanned = len(buf)
            chunk, received, flags, _ = socket.recv_fds(conn, _CHUNK, MAX_FDS, socket.MSG_CMSG_CLOEXEC)
            files.extend(received)
            if len(files) > MAX_FDS or flags & socket.MSG_CTRUNC:
                _close_all(files)  # more than a request may carry (the kernel dropped the rest): none is used
            if not chunk:
                return
            buf += chunk
    finally:
        _close_all(files)
