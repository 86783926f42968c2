"""The gateway's side of the daemon's control socket, on asyncio (one connection a request).

A request opens a Unix-socket connection, sends one line (service.protocol) and reads one
line; a subscription keeps its connection and yields the pushed lines. The daemon's own
checks (fields, states, programs) answer every request: the gateway adds none of its own
beyond HTTP's, so the CLI and the web see the same errors.
"""

from __future__ import annotations

import asyncio
import json
import socket
from pathlib import Path
from typing import Any, AsyncGenerator, Sequence

from nurbsmotion.service.protocol import MAX_REQUEST_BYTES, encode

LINE_LIMIT_BYTES = MAX_REQUEST_BYTES + 1024  # a status or job answer is far smaller; a program echo is not


class DaemonUnreachable(Exception):
    """No daemon answers on the socket (not running, or the connection broke)."""


def sent_with_files(sock: socket.socket, line: bytes, files: Sequence[int]) -> int:
    """How much of ``line`` went out with ``files`` on the just-connected ``sock`` (none: 0,
    the stream sends it all); a daemon that refused and closed at once (peer credentials)
    counts as all sent: its answer is read next."""
    if not files:
        return 0
    try:
        return socket.send_fds(sock, [line], list(files))
    except (BrokenPipeError, ConnectionResetError):
        return len(line)


class DaemonLink:
    """Requests and subscriptions to the daemon at ``socket_path``."""

    def __init__(self, socket_path: str | Path, timeout_s: float = 30.0) -> None:
        self.socket_path = str(socket_path)
        self.timeout_s = timeout_s

    async def _open(self, line: bytes = b"",
                    files: Sequence[int] = ()) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """A connection with ``line`` sent on it (``files`` passed along with its first bytes:
        SCM_RIGHTS, as service.client sends them; asyncio's streams cannot)."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.setblocking(False)
            await asyncio.get_running_loop().sock_connect(sock, self.socket_path)
            sent = sent_with_files(sock, line, files)
            reader, writer = await asyncio.open_unix_connection(sock=sock, limit=LINE_LIMIT_BYTES)
        except (FileNotFoundError, ConnectionRefusedError) as err:
            sock.close()
            raise DaemonUnreachable(f"no daemon at {self.socket_path} (is it running?)") from err
        except OSError as err:
            sock.close()
            raise DaemonUnreachable(f"daemon at {self.socket_path}: {err.strerror or err}") from err
        writer.write(line[sent:])
        return reader, writer

    async def request(self, cmd: str, *, files: Sequence[int] = (), **fields: Any) -> dict[str, Any]:
        """The daemon's answer to one request (``ok`` true or false); ``files``: descriptors
        sent along (protocol ``program_fd``: web.upload)."""
        reader, writer = await self._open(encode({"cmd": cmd, **fields}), files)
        try:
            await writer.drain()
            line = await asyncio.wait_for(reader.readline(), self.timeout_s)
        except (OSError, asyncio.IncompleteReadError, asyncio.TimeoutError) as err:
            raise DaemonUnreachable(f"daemon at {self.socket_path}: no answer to {cmd!r} ({err!r})") from err
        finally:
            writer.close()
        if not line:
            raise DaemonUnreachable(f"daemon at {self.socket_path} closed the connection without an answer")
        answer: dict[str, Any] = json.loads(line)
        return answer

    async def subscribe_lines(self, max_hz: float | None = None) -> AsyncGenerator[str, None]:
        """The subscription's answer (full status), then every pushed line, as the daemon's JSON
        text (relayed as it is: web.fanout), until the daemon closes the connection or the
        caller stops iterating."""
        reader, writer = await self._open(encode({"cmd": "subscribe", **({} if max_hz is None else {"max_hz": max_hz})}))
        try:
            await writer.drain()
            while True:
                line = await reader.readline()
                if not line:
                    return
                yield line.decode().rstrip("\n")
        except (OSError, asyncio.IncompleteReadError, ValueError) as err:
            raise DaemonUnreachable(f"daemon at {self.socket_path}: subscription ended ({err!r})") from err
        finally:
            writer.close()
