"""Optional record of every frame on the bus (sent and received) for diagnosis.

The format follows the file extension through python-can's :class:`can.Logger`
(``.log`` candump, ``.asc`` Vector ASCII, ``.blf``, ``.csv`` ...). Frames are queued and
written by a writer thread so the cyclic loop never waits for the disk; sent frames are
copied (the loop reuses its messages), so logging costs one small copy per sent frame.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import can


class TrafficLog(can.Listener):
    """A can.Listener for received frames plus :meth:`sent` for the master's own frames."""

    def __init__(self, path: str | Path) -> None:
        self._writer = can.Logger(str(path))
        self._queue: queue.SimpleQueue[can.Message | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._drain, name="nurbsmotion-traffic-log", daemon=True)
        self._thread.start()

    def on_message_received(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def sent(self, msg: can.Message) -> None:
        self._queue.put(can.Message(timestamp=time.time(), arbitration_id=msg.arbitration_id, is_extended_id=False,
                                    data=bytes(msg.data), is_rx=False, channel=msg.channel))

    def _drain(self) -> None:
        while (msg := self._queue.get()) is not None:
            self._writer.on_message_received(msg)

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=5.0)
        self._writer.stop()
