"""A job planned while it runs: the program is checked completely up front, then the planner
worker (service.planner_worker: a separate process) plans it chunk by chunk while the axes
move, and a receiver thread here feeds the chunks to the master (fieldbus.row_source.RowFeed).

Before any motion (prepare_streamed_job; the worker parses and checks, then plans at once):
syntax and geometry (the readers), the program
gate (service.program_gate), the machine's axes (a program axis without a machine axis must
not move), the soft limits from the path's verified bounding box (service.path_bounds: the
set-points lie on the path) and the int32 count range, then the first chunk is planned (a
short window, PlanStream's first_chunk_cycles): a program the planner refuses at its start is
refused with that line. Later the worker runs ahead of the axes by at most ``MAX_CHUNKS_AHEAD``
chunks (bounded memory: sending blocks while the queue is full) and writes the trace into the
record as it goes; plan.json is written before motion and at the end (a killed daemon's is
completed from the trace by the next daemon, service.records). If planning fails part-way, the
worker dies or planning falls behind, the axes stop on the verified stop tail of the last
chunk and the outcome names the program line (or the worker's end).

The daemon's process only receives, copies and indexes rows: the planner never holds its GIL.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.row_source import RowChunk, RowFeed
from nurbsmotion.log import kv
from nurbsmotion.planning.limits import PlanLimits, limits_from_config
from nurbsmotion.planning.lookahead.verify import FLUCTUATION_LIMIT, TOLERANCE
from nurbsmotion.program import AXES, Program, ReadOptions
from nurbsmotion.program.summary import reading_dict
from nurbsmotion.service.job_common import JobPause, axis_columns
from nurbsmotion.service.job_events import DEVICE_EVENTS, RowEvent
from nurbsmotion.service.checked_store import CheckedStore, text_digest
from nurbsmotion.service.planner_worker import (CancelPlan, CheckedProgram, EntryGone, NeedText, PathLengths,
                                                PlanEnd, PlannedChunk, PlannerWorker, PlanRequest, ProgramText, TracePath,
                                                as_error, highest_feed_mm_s, receive_program)
from nurbsmotion.service.program_file import ProgramFile
from nurbsmotion.service.rate import max_rate

if TYPE_CHECKING:
    from nurbsmotion.service.program_check import ProgramChecker

log = logging.getLogger(__name__)

CHUNK_CYCLES = 2000  # set-points per planned chunk after the first (2 s at 1 ms)
FIRST_CHUNK_CYCLES = 200  # the first chunk's window: first motion waits for it only
MAX_CHUNKS_AHEAD = 4  # chunks planned ahead of the axes (bounded memory; ~8 s at 1 ms)
FIRST_CHUNK_TIMEOUT_S = 60.0
END_TIMEOUT_S = 10.0  # the worker's last word after a cancel (it finishes the chunk it plans)
FEEDS_KEPT = 8  # chunks whose feed column is kept for the status' feed
LARGE_PROGRAM_CHARS = 4_000_000  # ~130,000 CAM lines: read and checked apart (checked_apart), not in the worker


def streamed_max_rate(program: Program, limits: PlanLimits, config: MachineConfig, columns: list[int],
                      highest_feed: float | None = None) -> float:
    """The highest feed override rate for a plan not yet made, from bounds that hold for any
    plan of it: an axis moves no faster than the path (<= the highest feed of its blocks, the
    planner's fluctuation guarantee included) and accelerates no more than the path's
    resultant limit; the axis limits cap both (the planner keeps them)."""
    feed = highest_feed_mm_s(program, limits) if highest_feed is None else highest_feed
    if limits.feed_mm_s is not None:
        feed = limits.feed_mm_s
    v_bound, a_bound = [], []
    for axis in config.axes:
        v = feed * (1.0 + FLUCTUATION_LIMIT)
        a = limits.max_accel_mm_s2 * (1.0 + TOLERANCE)
        v_bound.append(min(v, axis.max_velocity_mm_s) if axis.max_velocity_mm_s else v)
        axis_a = axis.max_accel_mm_s2
        a_bound.append(min(a, axis_a) if axis_a else a)
    return max_rate(np.array(v_bound), np.array(a_bound), [a.max_velocity_mm_s for a in config.axes],
                    [a.max_accel_mm_s2 or config.interpolation.max_accel_mm_s2 for a in config.axes])


class BlockStarts:
    """The first row of each block reached, in order, and that block: numpy arrays grown by
    doubling (a 10^6-block job: 12-24 MB; lists of Python ints held 72 MB and every status
    read converted one to an array, ~50 ms of the daemon's interpreter lock late in the job)."""

    def __init__(self) -> None:
        self.rows = np.zeros(1024, np.int64)
        self.blocks = np.zeros(1024, np.int32)
        self.count = 0

    def add(self, rows: np.ndarray, blocks: np.ndarray) -> None:
        """A chunk's block starts (planner_worker.block_starts), its first one dropped when it
        continues the last block here."""
        if len(blocks) and self.count and int(blocks[0]) == int(self.blocks[self.count - 1]):
            rows, blocks = rows[1:], blocks[1:]
        end = self.count + len(rows)
        if end > len(self.rows):
            size = max(end, 2 * len(self.rows))
            self.rows = np.concatenate([self.rows[:self.count], np.zeros(size - self.count, np.int64)])
            self.blocks = np.concatenate([self.blocks[:self.count], np.zeros(size - self.count, np.int32)])
        self.rows[self.count:end], self.blocks[self.count:end] = rows, blocks
        self.count = end

    def block_at(self, row: int) -> int | None:
        """The block of ``row`` (None before the first block start)."""
        if row < 0 or not self.count:
            return None
        i = int(np.searchsorted(self.rows[:self.count], row, side="right")) - 1
        return int(self.blocks[max(i, 0)])


class StreamedJob:
    """One streamed job: its checks passed, the worker planning ahead (see module docstring).

    The controller uses the same members as service.planner.PlannedJob: ``summary``,
    ``max_rate``, ``program``, ``pauses``, ``total_cycles``, ``block_at``, ``feed_at``,
    ``write_records``, ``start``, ``finish_records``, ``cancel``, ``end_reason``."""

    def __init__(self, name: str, program: Program, config: MachineConfig, columns: list[int],
                 worker: PlannerWorker, connection: tuple[Any, Any], chunk_cycles: int = CHUNK_CYCLES,
                 max_chunks: int = MAX_CHUNKS_AHEAD, first_chunk_cycles: int = FIRST_CHUNK_CYCLES,
                 highest_feed: float | None = None) -> None:
        self.name = name
        self.program = program
        self.config = config
        self.columns = columns
        self.worker = worker
        self.chunk_cycles = chunk_cycles
        self.first_chunk_cycles = min(first_chunk_cycles, chunk_cycles)
        self.limits = limits_from_config(config)
        self.max_rate = streamed_max_rate(program, self.limits, config, columns, highest_feed)
        self.feed = RowFeed(len(config.axes), max_chunks, ahead_rows=2 * chunk_cycles)
        self.pauses: list[Any] = []  # JobPause, in row order, as the chunks are planned
        # spindle / coolant / output events with their rows (service.job_events), as the chunks
        # are planned; events_complete once no more will come (the worker's end)
        self.row_events: list[RowEvent] = []
        self.events_complete = threading.Event()
        self._device_events = [e for e in program.events if e.kind in DEVICE_EVENTS]  # program order
        self.error: InputError | None = None  # planning failed part-way (the program line) or the worker died
        self.planned = 0  # rows planned so far
        self.finished = False  # every row planned
        self.submitted_s = time.monotonic()
        self.first_chunk_s = float("nan")
        self.end: PlanEnd | None = None  # the worker's last word on this job
        self._starts = BlockStarts()  # first row of each block reached, in order
        self._feeds: collections.deque[tuple[int, np.ndarray]] = collections.deque(maxlen=FEEDS_KEPT)
        self._lengths: PathLengths | None = None  # the path's length before the blocks, once the worker sent it
        self._commands, self._results = connection  # the worker got this job's PlanRequest
        self._cancel_sent = False
        self._send_lock = threading.Lock()
        self._first = threading.Event()
        self._ended = threading.Event()
        self._thread = threading.Thread(target=self._receive, name="job-receiver", daemon=True)
        start = program.blocks[0].start
        self.summary: dict[str, Any] = {
            "program": name, "blocks": len(program.blocks), "reading": reading_dict(program),
            "length_mm": None,  # set once the worker sends it
            "algorithm": "lookahead", "streamed": True, "period_s": config.cycle_period_s,
            "chunk_cycles": chunk_cycles, "first_chunk_cycles": self.first_chunk_cycles,
            "cycles": None, "duration_s": None,
            "axes": [{"name": a.name, "node": a.node_id} for a in config.axes],
            "start_mm": [round(float(x), 6) for x in start], "end_mm": [round(float(x), 6) for x in program.end_position],
            "max_override_percent": round(max(1.0, self.max_rate) * 100.0, 3), "pauses": []}

    # ------------------------------------------------------------------ before motion
    def begin(self, timeout_s: float = FIRST_CHUNK_TIMEOUT_S) -> None:
        """Receive the worker's chunks and wait for the first; InputError if it cannot plan it."""
        self._thread.start()
        if not self._first.wait(timeout_s):
            self.cancel()
            raise InputError(self.name, f"planning the first {self.first_chunk_cycles} set-points took more "
                             f"than {timeout_s:g} s")
        if self.error is not None and self.planned == 0:
            self.cancel()
            self._ended.wait(END_TIMEOUT_S)
            raise self.error
        self.summary["first_chunk_s"] = round(self.first_chunk_s, 6)

    def write_records(self, record: Any) -> None:
        """plan.json now (what is known before motion); the worker writes the trace as it plans."""
        record.write_plan_summary(self.summary)
        self._send(TracePath(record.folder / "trace.csv"))

    def start(self, link: Any, shift: Callable[[np.ndarray], None]) -> Any:
        """Hand the feed to the master (the first chunk is queued): the job's handle. ``shift``
        moves counts onto the offsets in force (service.homing, in place): the same for every
        row, so the feed adds it to each chunk as it joins the window."""
        offset = np.zeros((1, len(self.columns)), np.int64)
        shift(offset)
        self.feed.offset = offset[0]
        return link.stream_feed(self.feed)

    def cancel(self) -> None:
        """The job ended or never started: the worker stops after the chunk it plans."""
        self.feed.cancel()
        with self._send_lock:
            if self._cancel_sent or self._ended.is_set():
                return
            self._cancel_sent = True
        self._send(CancelPlan())

    def wait_closed(self, timeout_s: float = END_TIMEOUT_S) -> None:
        """After :meth:`cancel`: wait for the worker's last word (it has closed the job's trace),
        so a folder removed now is not written again: a submission refused at the start of
        streaming left a folder holding only the trace, marked 'interrupted' later."""
        self._ended.wait(timeout_s)

    def _send(self, command: Any) -> None:
        if self._commands is None or self._ended.is_set():
            return
        try:
            self._commands.send(command)
        except OSError:
            pass  # the worker is gone: the receiver says so

    # ------------------------------------------------------------------ while it runs
    @property
    def total_cycles(self) -> int | None:
        """Rows of the whole job once planned (None while planning goes on)."""
        return self.planned if self.finished else None

    def block_at(self, index: int) -> int | None:
        """The program block of planned row ``index`` (None before the first)."""
        return self._starts.block_at(index)

    def feed_at(self, index: int) -> float:
        """Planned feed (mm/s) at row ``index`` when it is recent, else 0."""
        for first, feed in reversed(self._feeds):
            if first <= index < first + len(feed):
                return float(feed[index - first])
        return 0.0

    def percent_at(self, index: int) -> float:
        """Progress: of the rows once all are planned, else of the path's length up to the
        start of the block reached (of the blocks, until the worker has sent their lengths:
        the first seconds of a long program)."""
        if index < 0:
            return 0.0
        if self.finished and self.planned:
            return 100.0 * (index + 1) / self.planned
        block = self.block_at(index)
        if block is None:
            return 0.0
        lengths = self._lengths
        if lengths is None:
            return 100.0 * block / len(self.program.blocks)
        total = lengths.total_mm
        return 100.0 * lengths.before(block) / total if total > 0 else 0.0

    def axis_step(self, axis: int, index: int, rows: int) -> int:
        """Counts axis ``axis`` moves from ``rows`` rows before row ``index`` to ``rows`` after,
        within the rows the master holds now (RowFeed.window): the way the job moves it there."""
        buf, base = self.feed.window
        if not len(buf):
            return 0
        last = len(buf) - 1
        ahead = min(max(index + rows - base, 0), last)
        behind = min(max(index - rows - base, 0), last)
        return int(buf[ahead, axis]) - int(buf[behind, axis])

    def end_reason(self, fell_behind_row: int) -> str:
        """Why a job ended before its program's end although nobody stopped it ('' if it did not)."""
        if self.error is not None:
            return str(self.error)
        if fell_behind_row >= 0:
            block = self.block_at(fell_behind_row)
            where = str(self.program.blocks[block].source) if block is not None else self.name
            return f"planning fell behind at {where}"
        return ""

    def finish_records(self, record: Any) -> None:
        """After the job: the worker stopped and closed the trace; plan.json with the figures
        of the rows planned."""
        self.cancel()
        if not self._ended.wait(END_TIMEOUT_S):
            log.warning(kv("planner_worker_silent", program=self.name, waited_s=END_TIMEOUT_S))
        end = self.end or PlanEnd(self.planned, False, trace_rows=record.adopt_trace_part())  # the worker died
        self.summary.update({
            "cycles": end.trace_rows, "planned_all": self.finished,
            "duration_s": round(max(self.planned - 1, 0) * self.config.cycle_period_s, 6),
            "planning_time_s": round(end.planning_time_s, 6), "max_feed_mm_s": round(end.max_feed_mm_s, 6),
            "first_chunk_s": round(self.first_chunk_s, 6), "notes": end.notes,
            "measured": end.measured, "pauses": [{"row": p.row, "reason": p.reason} for p in self.pauses]})
        if self.error is not None:
            self.summary["error"] = str(self.error)
        record.write_plan_summary(self.summary)

    def release(self) -> None:
        """The job is over and the controller let go of it: drop what grows with the program
        (the path's running length, the block starts, the recent feeds) now. The job object
        itself is in reference cycles that only a full collection frees, and the daemon
        collects rarely (its master freezes the collector's objects during a job): 10^6-line
        jobs left ~8.5 MB each in the daemon until then (9 starts in a row: 67 -> 175 MB)."""
        self._lengths = None
        self._starts = BlockStarts()
        self._feeds.clear()

    # ------------------------------------------------------------------ the receiver thread
    def _receive(self) -> None:
        """Chunks from the worker into the feed until its PlanEnd (or its death)."""
        try:
            while True:
                message = self._results.recv()
                if isinstance(message, PlannedChunk):
                    self._take(message)
                elif isinstance(message, PathLengths):
                    self._take_lengths(message)
                elif isinstance(message, PlanEnd):
                    self._finish(message)
                    return
        except (EOFError, OSError):
            self.error = InputError(self.name, f"the planner worker ended unexpectedly "
                                    f"({self.worker.exit_description()}) after {self.planned} set-points")
            log.error(kv("planner_worker_died", program=self.name, row=self.planned, error=self.error))
        finally:
            self.events_complete.set()
            self.feed.close()
            self._ended.set()
            self._first.set()
            self.worker.job_ended()

    def _take(self, chunk: PlannedChunk) -> None:
        """Index the chunk (lines, pauses, feed) before the master can reach it, then queue it
        (blocks while the queue is full; dropped once the job ended)."""
        if self.feed.cancelled.is_set():
            return
        self.pauses.extend(JobPause(row, reason, tool, wait) for row, reason, tool, wait in chunk.pauses)
        self._take_events(chunk.block_rows, chunk.block_ids)
        self._starts.add(chunk.block_rows, chunk.block_ids)
        self._feeds.append((chunk.first_row, chunk.feed_mm_s))
        rows = RowChunk(chunk.counts.astype(np.int64), chunk.stop_tail.astype(np.int64),
                        tuple(row for row, _, _, _ in chunk.pauses), chunk.max_step, chunk.max_accel)
        if not self.feed.put(rows):
            return  # the job ended
        if self.planned == 0:
            self.first_chunk_s = time.monotonic() - self.submitted_s
        self.planned += len(chunk.counts)
        self._first.set()

    def _take_events(self, block_rows: np.ndarray, block_ids: np.ndarray) -> None:
        """The device events whose block starts in this chunk (or earlier): the first row of the
        first block at or after the one they come before, as job_events.event_rows finds it."""
        events = self._device_events
        taken = 0
        while taken < len(events) and len(block_ids) and events[taken].before_block <= int(block_ids[-1]):
            i = int(np.searchsorted(block_ids, events[taken].before_block, side="left"))
            self.row_events.append(RowEvent(int(block_rows[i]), events[taken]))
            taken += 1
        del events[:taken]

    def _take_lengths(self, message: PathLengths) -> None:
        """The blocks' arc lengths: progress by path length, plan.json's length_mm."""
        self._lengths = message
        self.summary["length_mm"] = round(message.total_mm, 6)

    def _finish(self, end: PlanEnd) -> None:
        self.end = end
        self.finished = end.finished
        if end.finished:  # the events after the last move (M5 M9 before M30): done at the job's end
            self.row_events.extend(RowEvent(self.planned, e) for e in self._device_events)
            self._device_events.clear()
        if end.errors:
            self.error = as_error(end.errors)
            log.warning(kv("planning_failed", program=self.name, row=self.planned, error=self.error))


def prepare_streamed_job(name: str, text: str | ProgramFile, config: MachineConfig, worker: PlannerWorker,
                         start_mm: np.ndarray | None = None, options: ReadOptions | None = None,
                         chunk_cycles: int = CHUNK_CYCLES, first_chunk_cycles: int = FIRST_CHUNK_CYCLES,
                         store: CheckedStore | None = None, checker: ProgramChecker | None = None) -> StreamedJob:
    """Have the worker parse and check ``text`` (or the file holding it: the daemon never reads
    it, service.program_file) completely (or load it checked from ``store``,
    service.checked_store; a large program not there is read and checked by ``checker`` first,
    checked_apart) and start planning it; return once the first chunk is planned (InputError
    naming file:line for anything refused; nothing moves)."""
    request = plan_request(name, text, config, start_mm, options, store, chunk_cycles, first_chunk_cycles)
    checked_now = checked_apart(request, checker)
    connection = worker.connect(withheld(request))
    program, from_store, highest_feed = checked_program(name, worker, connection, key=request.checked_key,
                                                        text=text if isinstance(text, str) else "")
    from_store = from_store and not checked_now
    if store is not None:
        store.note(from_store, name)
    job = StreamedJob(name, program, config, request.columns, worker, connection, chunk_cycles,
                      first_chunk_cycles=request.first_chunk_cycles, highest_feed=highest_feed)
    job.summary["checked_from_store"] = from_store
    job.begin()
    return job


def withheld(request: PlanRequest) -> PlanRequest:
    """The request without its text when its store entry is there: the worker loads the entry
    and asks for the text (NeedText) only if it cannot (a 10^6-line program's 30 MB pickled,
    sent and unpickled again took ~0.4 s before the first chunk, and held twice in memory)."""
    if request.checked_path is None or not request.checked_path.exists():
        return request
    return dataclasses.replace(request, text=None)


def checked_apart(request: PlanRequest, checker: ProgramChecker | None) -> bool:
    """Read and check a program of LARGE_PROGRAM_CHARS or more that is not in the store in the
    checker process (service.program_check), which stores it, so that the planner worker loads
    it from the store as any stored program: reading a 10^6-line program peaks at ~350 MB
    (issue 25: the worker < 300 MB, `check` < 500 MB), and the checker's time-out is the
    check's (minutes), not the first chunk's. True when it checked it (InputError: refused)."""
    if checker is None or request.checked_path is None or program_chars(request) < LARGE_PROGRAM_CHARS \
            or request.checked_path.exists():
        return False
    report = checker.check(request, tuple(a.name for a in request.config.axes))
    if report.errors:
        raise as_error(report.errors)
    return not report.from_store


def program_chars(request: PlanRequest) -> int:
    """The program's size: its text's characters, or its file's bytes (about as many)."""
    if request.text is None and request.text_file is not None:
        return request.text_file.stat().st_size
    return len(request.text or "")


def plan_request(name: str, text: str | ProgramFile, config: MachineConfig, start_mm: np.ndarray | None = None,
                 options: ReadOptions | None = None, store: CheckedStore | None = None,
                 chunk_cycles: int = CHUNK_CYCLES, first_chunk_cycles: int = FIRST_CHUNK_CYCLES) -> PlanRequest:
    """The worker's request for ``text`` (or the file holding it: sent as its path) started at
    ``start_mm`` (machine axes; None: 0) with ``options``, with its entry in the
    checked-program ``store`` (service.checked_store)."""
    columns = axis_columns(config)
    start_xyz = np.zeros(len(AXES))
    if start_mm is not None:
        start_xyz[columns] = start_mm
    options = options or ReadOptions(tool_table=config.tool_table)
    held = text if isinstance(text, ProgramFile) else None
    key = "" if store is None else store.key(name, held.sha256 if held else text_digest(str(text)), start_xyz, options)
    return PlanRequest(config, name, None if held else str(text), start_xyz, options, columns, chunk_cycles,
                       min(first_chunk_cycles, chunk_cycles), store.path(key) if store is not None else None, key,
                       held.path if held else None)


def checked_program(name: str, worker: PlannerWorker, connection: tuple[Any, Any],
                    timeout_s: float = FIRST_CHUNK_TIMEOUT_S, key: str = "", text: str = ""
                    ) -> tuple[Program, bool, float | None]:
    """The worker's first answer: (the program parsed and checked, mapped from its store entry
    ``key`` or received in slices, whether it came from the checked-program store, its highest
    feed), or the
    errors refusing it. A worker that asks for the program's ``text`` (NeedText) gets it."""
    commands, results = connection
    try:
        answer = NeedText()
        while isinstance(answer, NeedText):
            if not results.poll(timeout_s):
                worker.abandon()
                raise InputError(name, f"parsing and checking the program took more than {timeout_s:g} s")
            answer = results.recv()
            if isinstance(answer, NeedText):
                commands.send(ProgramText(text))
    except (EOFError, OSError):
        worker.job_ended()
        raise InputError(name, f"the planner worker ended unexpectedly ({worker.exit_description()})") from None
    if isinstance(answer, CheckedProgram):
        try:
            return receive_program(results, answer, timeout_s, key), answer.from_store, answer.highest_feed_mm_s
        except EntryGone as err:
            worker.abandon()
            raise InputError(name, str(err)) from None
        except TimeoutError as err:
            worker.abandon()
            raise InputError(name, f"the planner worker did not send {err}") from None
        except (EOFError, OSError, TypeError) as err:
            worker.job_ended()
            raise InputError(name, f"the planner worker ended unexpectedly ({worker.exit_description()}): "
                                   f"{err}") from None
    worker.job_ended()
    if isinstance(answer, PlanEnd) and answer.errors:
        raise as_error(answer.errors)
    raise InputError(name, f"the planner worker answered {type(answer).__name__} instead of the checked program")
