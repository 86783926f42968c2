"""The gateway's side of the daemon's control socket, on asyncio (one connection a request).

A request opens a Unix-socket connection, sends one line (service.protocol) and reads one
line; a subscription keeps its connection and yields the pushed lines. The daemon's own
checks (fields, states, programs) answer every request: the gateway adds none of its own
beyond HTTP's, so the CLI and the web see the same errors.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any, AsyncGenerator

from nurbsmotion.service.protocol import MAX_REQUEST_BYTES, encode

LINE_LIMIT_BYTES = MAX_REQUEST_BYTES + 1024  # a status or job answer is far smaller; a program echo is not


class DaemonUnreachable(Exception):
    """No daemon answers on the socket (not running, or the connection broke)."""


class DaemonLink:
    """Requests and subscriptions to the daemon at ``socket_path``."""

    def __init__(self, socket_path: str | Path, timeout_s: float = 30.0) -> None:
        self.socket_path = str(socket_path)
        self.timeout_s = timeout_s

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        try:
            return await asyncio.open_unix_connection(self.socket_path, limit=LINE_LIMIT_BYTES)
        except (FileNotFoundError, ConnectionRefusedError) as err:
            raise DaemonUnreachable(f"no daemon at {self.socket_path} (is it running?)") from err
        except OSError as err:
            raise DaemonUnreachable(f"daemon at {self.socket_path}: {err.strerror or err}") from err

    async def request(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """The daemon's answer to one request (``ok`` true or false)."""
        reader, writer = await self._open()
        try:
            writer.write(encode({"cmd": cmd, **fields}))
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
        reader, writer = await self._open()
        try:
            writer.write(encode({"cmd": "subscribe", **({} if max_hz is None else {"max_hz": max_hz})}))
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
