"""Set-point rows of one job that arrive over time: a bounded queue of chunks from a producer
thread (the service's planner) and the window of rows the cycle loop plays from.

Each chunk is a block of planned rows (int64 counts, cycles x axes) and its *stop tail*: the
planner's verified set-points that bring the axes to rest on the path from the chunk's last
row (planning.lookahead Resume.stop; empty when the chunk ends at rest). The window holds
the planned rows received so far followed by the tail of the newest one, so a controlled
stop (fieldbus.stop_ramp) always has rows to stop on, and a playback that reaches the end
of the planned rows before the next chunk runs onto the tail and comes to rest on the path
instead of running off the end ("planning fell behind").

Threads: :meth:`RowFeed.put` / :meth:`RowFeed.close` on the producer; everything else on
the cycle thread (after :meth:`RowFeed.take_first` on the thread that starts the job). The
queue is a deque (atomic append/popleft) with a semaphore bounding the chunks ahead.

Memory: the window keeps ``keep_rows`` rows behind the playback (the master may rewind its
queued cycles, fieldbus.cycle_loop HISTORY_CYCLES) and up to ``ahead_rows`` planned rows ahead of
it plus the newest chunk and its tail; at most ``max_chunks`` chunks wait in the queue. Nothing grows with the job's length except the
pause rows (one int per program pause).
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass

import numpy as np

KEEP_ROWS = 2048  # rows kept behind the playback: > HISTORY_CYCLES (512) x the highest rate (1.5)
AHEAD_ROWS = 4000  # a chunk joins the window once fewer planned rows than this lie ahead of the playback


@dataclass(frozen=True, eq=False)
class RowChunk:
    """Planned rows [first_row, first_row + len(rows)) of a job and their stop tail."""

    rows: np.ndarray  # (m, n_axes) int64
    stop_tail: np.ndarray  # (t, n_axes) int64: after rows[-1] to rest on the path; (0, n) when at rest
    pauses: tuple[int, ...] = ()  # global rows (within this chunk) where the job holds (M0/M1/M6)
    max_step: tuple[float, ...] = ()  # per axis: largest |row step| in rows and tail, counts per cycle
    max_accel: tuple[float, ...] = ()  # per axis: largest |second difference| / T², counts/s²


def chunk_figures(rows: np.ndarray, before: np.ndarray, period_s: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per axis max |Δc| and max |Δ²c|/T² over ``before`` (the last rows already sent, up to
    two) followed by ``rows``: the figures the stop slope needs (stop_ramp.stop_slope)."""
    joined = np.concatenate([before, rows]) if len(before) else rows
    n = rows.shape[1]
    step = np.abs(np.diff(joined, axis=0)).max(axis=0) if len(joined) > 1 else np.zeros(n)
    accel = np.abs(np.diff(joined, n=2, axis=0)).max(axis=0) / period_s**2 if len(joined) > 2 else np.zeros(n)
    return tuple(float(x) for x in step), tuple(float(x) for x in accel)


class RowFeed:
    """A job's rows arriving over time (see the module docstring)."""

    def __init__(self, n_axes: int, max_chunks: int = 4, keep_rows: int = KEEP_ROWS,
                 ahead_rows: int = AHEAD_ROWS) -> None:
        self.n_axes = n_axes
        self.keep_rows = keep_rows
        self.ahead_rows = ahead_rows
        self._queue: collections.deque[RowChunk] = collections.deque()
        self._space = threading.Semaphore(max_chunks)
        self._closed = False  # the producer sent its last chunk (or gave up)
        self.cancelled = threading.Event()  # the job ended: the producer stops
        # the window (cycle thread)
        self.buf = np.zeros((0, n_axes), np.int64)
        self.view = self.buf.data
        self.base = 0  # global row of buf[0]
        self.window: tuple[np.ndarray, int] = (self.buf, 0)  # (buf, base) in one store: for other threads
        self.planned_end = 0  # one past the last planned row received
        self.end = 0  # one past the last row of the window (planned rows + the newest stop tail)
        self.final = False  # the planned rows are all of the job's
        self.fell_behind_row = -1  # the last planned row before the playback ran onto a stop tail
        self.chunks_taken = 0
        self.offset = np.zeros(n_axes, np.int64)  # counts added to every row as it joins the window (set before the first)

    # ------------------------------------------------------------------ producer
    def put(self, chunk: RowChunk, timeout_s: float | None = None) -> bool:
        """Queue ``chunk`` (blocks while ``max_chunks`` wait); False once the job was cancelled."""
        while not self.cancelled.is_set():
            if self._space.acquire(timeout=0.05 if timeout_s is None else min(timeout_s, 0.05)):
                if self.cancelled.is_set():
                    return False
                self._queue.append(chunk)
                return True
            if timeout_s is not None:
                timeout_s -= 0.05
                if timeout_s <= 0:
                    return False
        return False

    def close(self) -> None:
        """No more chunks (the program's end, or the producer gave up)."""
        self._closed = True

    def cancel(self) -> None:
        """The job ended: the producer's next put returns False."""
        self.cancelled.set()
        self._space.release()

    @property
    def waiting(self) -> int:
        """Chunks queued and not yet in the window."""
        return len(self._queue)

    # ------------------------------------------------------------------ consumer (cycle thread)
    def take_first(self) -> RowChunk | None:
        """Move the first chunk into the window (before the job is handed to the cycle loop)."""
        return self.take(-1.0, False)

    def take(self, position: float, stopping: bool) -> RowChunk | None:
        """Append the next queued chunk to the planned rows unless the playback (at fractional
        row ``position``, -1 before the first) already used a row of the stop tail, or a stop
        is under way (its slope was chosen for the rows it has); the chunk taken, or None."""
        if self.final or stopping:
            return None
        if not self._queue:
            if self._closed and position <= self.planned_end - 1:
                self.final = self.end == self.planned_end  # the last chunk ended at rest: no tail
            return None
        if position > self.planned_end - 1 and self.end > self.planned_end:
            return None  # on the stop tail: too late, it runs to rest
        if self.planned_end - position > self.ahead_rows:
            return None  # enough planned rows ahead: the chunk waits in the queue (bounded memory)
        chunk = self._queue.popleft()
        self._space.release()
        index = int(position)
        keep_from = max(self.base, index - self.keep_rows) if position >= 0 else self.base
        kept = self.buf[keep_from - self.base: self.planned_end - self.base]
        self.buf = np.concatenate([kept, self._shifted(chunk.rows), self._shifted(chunk.stop_tail)]).astype(
            np.int64, copy=False)
        self.view = self.buf.data
        self.base = keep_from
        self.window = (self.buf, keep_from)
        self.planned_end += len(chunk.rows)
        self.end = self.planned_end + len(chunk.stop_tail)
        self.chunks_taken += 1
        if self._closed and not self._queue:
            self.final = len(chunk.stop_tail) == 0
        return chunk

    def _shifted(self, rows: np.ndarray) -> np.ndarray:
        return rows + self.offset if self.offset.any() else rows

    def __getitem__(self, ij: tuple[int, int]) -> int:
        """Row i (global), axis j: the window read as the playback reads a memoryview."""
        i, j = ij
        return int(self.view[i - self.base, j])

    @property
    def shape(self) -> tuple[int, int]:
        """(rows in the window counted from row 0, axes): shape[0] - 1 is the last row."""
        return (self.end, self.n_axes)


__all__ = ["RowFeed", "RowChunk", "chunk_figures", "KEEP_ROWS"]
