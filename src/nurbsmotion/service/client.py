"""Client side of the control socket: one connection, one request line, one response line."""

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any, Iterator, NoReturn, Sequence

from nurbsmotion.errors import NurbsmotionError
from nurbsmotion.service.protocol import encode


class DaemonUnavailable(NurbsmotionError):
    """Nobody answers on the socket: ``no daemon at PATH (is it running?)``; or the daemon
    went away during a request (``lost``): ``the daemon at PATH ended the connection ...``."""

    def __init__(self, path: Path | str, detail: str = "", lost: bool = False) -> None:
        if lost:
            super().__init__(f"the daemon at {path} ended the connection ({detail}; is it shutting down?)")
        else:
            super().__init__(f"no daemon at {path} (is it running?){f' [{detail}]' if detail else ''}")


class RequestFailed(NurbsmotionError):
    """The daemon answered ``ok: false``; ``errors`` holds one line per problem."""

    def __init__(self, response: dict[str, Any]) -> None:
        self.response = response
        self.errors = [str(e) for e in response.get("errors") or [response.get("error", "request failed")]]
        super().__init__(str(response.get("error", "request failed")))


class Client:
    """A connection to the daemon; ``request`` returns the response dict (ok or not)."""

    def __init__(self, path: str | Path, timeout_s: float = 60.0) -> None:
        self.path = Path(path)
        self.timeout_s = timeout_s
        self._sock: socket.socket | None = None
        self._file: Any = None

    def connect(self) -> "Client":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout_s)
        try:
            sock.connect(str(self.path))
        except (FileNotFoundError, ConnectionRefusedError) as err:
            sock.close()
            raise DaemonUnavailable(self.path) from err
        except OSError as err:
            sock.close()
            raise DaemonUnavailable(self.path, err.strerror or str(err)) from err
        self._sock = sock
        self._file = sock.makefile("rb")
        return self

    def request(self, cmd: str, *, files: Sequence[int] = (), **fields: Any) -> dict[str, Any]:
        """Send one request (``files``: descriptors to pass along, protocol ``program_fd``) and
        return its answer."""
        if self._sock is None:
            self.connect()
        assert self._sock is not None
        send_error: OSError | None = None
        try:
            data = encode({"cmd": cmd, **fields})
            sent = socket.send_fds(self._sock, [data], list(files)) if files else 0
            self._sock.sendall(data[sent:])
        except (BrokenPipeError, ConnectionResetError) as err:
            # The daemon may have answered and closed before reading (a refusal by peer
            # credentials is sent at once): its line is still in our receive queue.
            send_error = err
        except OSError as err:
            self._lost(err)
        try:
            line = self._file.readline()
        except OSError as err:
            self._lost(send_error or err)
        if not line:
            self._lost(send_error)
        return json.loads(line)

    def _lost(self, err: OSError | None) -> NoReturn:
        """Close and raise DaemonUnavailable(lost) for a connection that ended mid-request."""
        self.close()
        detail = f"connection lost: {err.strerror or err}" if err is not None else "closed without an answer"
        raise DaemonUnavailable(self.path, detail, lost=True) from err

    def call(self, cmd: str, *, files: Sequence[int] = (), **fields: Any) -> dict[str, Any]:
        """``request`` that raises RequestFailed for ``ok: false``."""
        response = self.request(cmd, files=files, **fields)
        if not response.get("ok"):
            raise RequestFailed(response)
        return response

    def subscribe(self, max_hz: float | None = None) -> Iterator[dict[str, Any]]:
        """Subscribe this connection (protocol ``subscribe``): yields the answer with the full
        status first, then every pushed line, until the daemon closes the connection.
        RequestFailed when the daemon refuses the subscription."""
        first = self.call("subscribe", files=(), **({} if max_hz is None else {"max_hz": max_hz}))
        assert self._sock is not None
        self._sock.settimeout(None)  # a quiet machine pushes nothing for a while: not a lost daemon
        yield first
        while True:
            try:
                line = self._file.readline()
            except OSError as err:
                self._lost(err)
            if not line:
                return
            yield json.loads(line)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "Client":
        return self.connect()

    def __exit__(self, *exc: object) -> None:
        self.close()
