"""Optional record of every frame on the bus (sent and received) for diagnosis.

The format follows the file extension through python-can's :class:`can.Logger`
(``.log`` candump, ``.asc`` Vector ASCII, ``.blf``, ``.csv`` ...). Frames are queued and
written by a writer thread so the cyclic loop never waits for the disk; sent frames are
copied (the loop reuses its messages), so logging costs one small copy per sent frame.
The record can be switched to another file (one per job) or paused with :meth:`switch`.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Union

import can

_Item = Union[can.Message, tuple[str, Union[str, Path, None], threading.Event], None]


class TrafficLog(can.Listener):
    """A can.Listener for received frames plus :meth:`sent` for the master's own frames.

    ``path`` None starts paused: frames are dropped until :meth:`switch` names a file.
    """

    def __init__(self, path: str | Path | None) -> None:
        self._writer: can.Listener | None = None
        self._recording = False
        self._queue: queue.SimpleQueue[_Item] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._drain, name="nurbsmotion-traffic-log", daemon=True)
        self._thread.start()
        if path is not None:
            self.switch(path)

    @property
    def recording(self) -> bool:
        return self._recording

    def on_message_received(self, msg: can.Message) -> None:
        if self._recording:
            self._queue.put(msg)

    def sent(self, msg: can.Message) -> None:
        if self._recording:
            self._queue.put(can.Message(timestamp=time.time(), arbitration_id=msg.arbitration_id,
                                        is_extended_id=False, data=bytes(msg.data), is_rx=False, channel=msg.channel))

    def switch(self, path: str | Path | None, timeout_s: float = 5.0) -> None:
        """Close the current file (every frame queued so far is written) and record into
        ``path`` from now on; None pauses. Returns once the writer thread has switched."""
        if path is None:
            self._recording = False
        done = threading.Event()
        self._queue.put(("switch", path, done))
        done.wait(timeout_s)
        if path is not None:
            self._recording = True

    def _drain(self) -> None:
        while (item := self._queue.get()) is not None:
            if isinstance(item, tuple):
                _, path, done = item
                self._close_writer()
                if path is not None:
                    self._writer = can.Logger(str(path))
                done.set()
            elif self._writer is not None:
                self._writer.on_message_received(item)
        self._close_writer()

    def _close_writer(self) -> None:
        if self._writer is not None:
            self._writer.stop()
            self._writer = None

    def stop(self) -> None:
        self._recording = False
        self._queue.put(None)
        self._thread.join(timeout=5.0)
