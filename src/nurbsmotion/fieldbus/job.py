"""One streamed job: its handle (:class:`Job`) and the playback built from its rows.

A job is an (N, n_axes) array of int32 counts given at once (:func:`rows_playback`) or a
:class:`~nurbsmotion.fieldbus.row_source.RowFeed` filled over time (:func:`feed_playback`).
Either way the cycle loop plays it through a :class:`~nurbsmotion.fieldbus.playback.Playback`
whose stop slope comes from the rows' largest steps (fieldbus.stop_ramp.slope_of_steps).
"""

from __future__ import annotations

import threading
from typing import Any, Callable

import numpy as np

from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.controller import Req, Request
from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.reports import FaultReport, JobResult, MasterStatus
from nurbsmotion.fieldbus.row_source import RowChunk, RowFeed
from nurbsmotion.fieldbus.stop_ramp import ramp_slope, slope_of_steps

ProgressCallback = Callable[[int, int], None]


class Job:
    """Handle of one streamed set-point sequence; every method is thread-safe.

    ``request`` hands a request to the cycle loop, ``status`` reads the master's status."""

    def __init__(self, request: Callable[[Request], None], status: Callable[[], MasterStatus], rows: Any,
                 playback: Playback, on_progress: ProgressCallback | None, progress_every: int,
                 feed: RowFeed | None = None) -> None:
        self._request = request
        self._status = status
        self.rows = rows
        self.feed = feed  # a streamed job's rows (fieldbus.row_source), None: all given at the start
        self._length = rows.shape[0]
        self.playback = playback
        self.on_progress = on_progress
        self.progress_every = progress_every
        self.faults: list[FaultReport] = []
        self.start_cycle = -1  # master cycle that sends the job's first set-point (its cycle 0)
        self.finish_cycle = -1  # wire cycle at which the job's end has been sent (-1: not yet planned)
        self.outcome = ""
        self.released = False
        self._done = threading.Event()
        self._result: JobResult | None = None

    @property
    def index(self) -> int:
        """Index of the last planned set-point handed to the bus (queued included)."""
        return self.playback.index

    @property
    def length(self) -> int:
        """Planned rows: all of them, or for a streamed job those received so far."""
        return self.feed.planned_end if self.feed is not None else self._length

    @property
    def fell_behind_row(self) -> int:
        """A streamed job that ran onto a stop tail: its last planned row (-1: it did not)."""
        return self.feed.fell_behind_row if self.feed is not None else -1

    def wait(self, timeout: float | None = None) -> JobResult | None:
        """Block until the job ended (or ``timeout`` s passed: None)."""
        return self._result if self._done.wait(timeout) else None

    def done(self) -> bool:
        return self._done.is_set()

    @property
    def result(self) -> JobResult | None:
        return self._result

    def request_stop(self) -> None:
        """Controlled stop: decelerate along the path within a_max, then hold."""
        self._request(Request(Req.STOP, self))

    def hold(self) -> None:
        """Hold: decelerate along the path with the stop ramp, then wait (phase 'held') with
        the job alive; ignored unless streaming."""
        self._request(Request(Req.HOLD, self))

    def resume(self) -> None:
        """Continue a held job (or one paused at a pause row) from exactly where it rests."""
        self._request(Request(Req.RESUME, self))

    def abort(self) -> None:
        """Quick stop controlword to every axis (drives stop on their own ramp and disable)."""
        self._request(Request(Req.ABORT, self))

    def status(self) -> MasterStatus:
        return self._status()

    def finish(self, result: JobResult) -> None:
        """The cycle loop's last word on the job: wakes :meth:`wait`."""
        self._result = result
        self._done.set()


def checked_rows(counts: np.ndarray, n_axes: int) -> np.ndarray:
    """The set-points as int64, or InputError: shape (N >= 1, n_axes), integers in int32."""
    arr = np.asarray(counts)
    if arr.ndim != 2 or arr.shape[1] != n_axes or arr.shape[0] < 1:
        raise InputError("set-points", f"expected an array of shape (N >= 1, {n_axes}) of counts, "
                         f"got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise InputError("set-points", f"counts must be integers (int32), got dtype {arr.dtype}")
    if arr.size and (arr.min() < -(2**31) or arr.max() > 2**31 - 1):
        raise InputError("set-points", "counts outside the int32 range")
    return np.ascontiguousarray(arr, dtype=np.int64)


def check_start_row(row: np.ndarray, hold: list[int], fe_window: list[int], names: list[str]) -> None:
    """The first set-point is within each axis' following-error window of the held position."""
    for j in range(len(hold)):
        if abs(int(row[j]) - hold[j]) > fe_window[j]:
            raise InputError("set-points", f"axis {names[j]}: the job starts at {int(row[j])} counts "
                             f"but the axis holds {hold[j]} counts (more than the following-error window "
                             f"{fe_window[j]} counts away)")


def rows_playback(as_int64: np.ndarray, accel_counts_s2: np.ndarray, period_s: float, rate: float,
                  pauses: tuple[int, ...]) -> Playback:
    """Playback of rows given at once (checked_rows), with their stop-slope figures."""
    n = as_int64.shape[1]
    # A 2-D memoryview: 8 bytes per set-point, read per cycle as rows[i, j] -> int
    # (nested lists would cost ~10x the memory for a long program).
    rows = as_int64.data
    # per-axis figures for the stop slope, as plain floats for the cycle loop
    max_step = np.abs(np.diff(as_int64, axis=0)).max(axis=0) if len(as_int64) > 1 else np.zeros(n)
    planned_accel = (np.abs(np.diff(as_int64, n=2, axis=0)).max(axis=0) if len(as_int64) > 2
                     else np.zeros(n)) / period_s**2
    return Playback(rows, ramp_slope(as_int64, accel_counts_s2, period_s), rate, max_step.astype(float).tolist(),
                    planned_accel.astype(float).tolist(), tuple(sorted(int(p) for p in pauses)))


def first_chunk_of(feed: RowFeed) -> RowChunk | None:
    """The feed's first chunk (taken from its queue), None when the feed was started already;
    InputError when it has none."""
    if feed.planned_end != 0:
        return None
    first = feed.take_first()
    if first is None or len(first.rows) == 0:
        raise InputError("set-points", "the streamed job has no first chunk of rows")
    return first


def feed_playback(feed: RowFeed, first: RowChunk | None, accel_counts_s2: np.ndarray, period_s: float, rate: float) -> Playback:
    """Playback of a streamed job: the stop slope of the first chunk's steps, lowered as larger
    steps arrive (Playback._adopt)."""
    n = feed.n_axes
    step = list(first.max_step) if first is not None and first.max_step else [0.0] * n
    accel = list(first.max_accel) if first is not None and first.max_accel else [0.0] * n
    limits = [float(a) for a in accel_counts_s2]
    return Playback(feed, slope_of_steps(step, limits, period_s), rate, step, accel,
                    tuple(first.pauses) if first is not None else (), feed=feed, accel_limits=limits,
                    period_s=period_s)
