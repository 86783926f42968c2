"""The planner worker: a separate process, started once with the daemon, that plans streamed
jobs chunk by chunk, so the daemon's process (its cycle thread and, simulating, the drives)
never waits for the planner's hold on the GIL: it only receives and copies rows.

Spawned (multiprocessing 'spawn' context: a fresh interpreter, never a fork of the threaded
daemon); each request carries the machine configuration it is planned for. One job at a time; the conversation is two pipes:

- daemon -> worker (``commands``): :class:`PlanRequest` (a job), :class:`TracePath` (the job
  record exists: write the trace there), :class:`CancelPlan` (the job ended), ``None`` (quit);
- worker -> daemon (``results``): :class:`CheckedProgram` (the parsed program passed every
  check before motion) and its blocks in :class:`ProgramBlocks` slices, one :class:`PlannedChunk` per chunk (int32 counts, their verified
  stop tail, the pauses, the block starts and the feed), one :class:`PathLengths` among
  them, then one :class:`PlanEnd` (a program refused before motion: a PlanEnd with its
  errors and nothing else).

The blocks' arc lengths (adaptive quadrature, ~0.7 ms a NURBS block) are for the job's
progress and plan.json only: no check before motion and no planning needs them, so they
are computed after the first chunk, LENGTHS_BUDGET_S at a time between chunks, and sent once
all are known (before the PlanEnd in any case).

The worker parses the program and checks it (service.streamed_job.check_before_motion); the
daemon gets the parsed program back (unpickling it costs ~1/80 of parsing it, and the
daemon's process parsing it would compete with the cycle thread for the GIL). It plans it
with PlanStream (a short first window: first motion waits for it only),
converts to counts, measures the rows and writes the trace into the job record. Sending a
chunk blocks while the daemon's bounded queue is full (the pipe fills): that bounds memory.
Between chunks it reads its commands; a closed command pipe (the daemon died) ends it.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.connection
import os
import pickle
import threading
import signal
import time
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.fieldbus.row_source import chunk_figures
from nurbsmotion.log import kv
from nurbsmotion.planning.limits import PlanLimits, limits_from_config
from nurbsmotion.planning.lookahead import PlanStream
from nurbsmotion.planning.lookahead.planned_path import PlannedPath
from nurbsmotion.planning.measure import MeasureStream, RowFigures
from nurbsmotion.planning.trace import TraceWriter
from nurbsmotion.runtime import GcQuiet, keep_off_realtime_cpu
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import BlockKind, Program, ReadOptions
from nurbsmotion.program.records import KINDS, BlockRecords
from nurbsmotion.service.block_lines import BlockLinesFile
from nurbsmotion.service.job_common import machine_has_devices, parse, spindle_wait_reason
from nurbsmotion.service.path_bounds import check_before_motion

log = logging.getLogger(__name__)

READY_TIMEOUT_S = 60.0  # a worker that has not started by then (imports under heavy load) is an error
QUIT_TIMEOUT_S = 5.0
IDLE_TIMEOUT_S = 15.0  # a new job waits this long for the last one's PlanEnd (a cancel ends it within a chunk)
BLOCKS_PER_MESSAGE = 1000  # blocks a ProgramBlocks slice carries (~15 ms of the daemon's lock to load)
FEED_ROWS = 65536  # highest_feed_mm_s's slice
LENGTH_POINTS = 65536  # PathLengths' values at most
LENGTHS_BUDGET_S = 0.02  # arc-length work between two chunks (a chunk is 2 s of motion): planning stays ahead


@dataclass(frozen=True)
class PlanRequest:
    """Plan ``text`` (as ``name``) for the machine ``config`` from ``start_xyz`` in chunks of
    ``chunk_cycles`` (the first of ``first_chunk_cycles``); the machine's columns of the
    program's XYZ."""

    config: MachineConfig
    name: str
    text: str | None  # None: withheld, its entry is in the store (the worker asks for it with NeedText if it must read it)
    start_xyz: np.ndarray
    options: ReadOptions
    columns: list[int]
    chunk_cycles: int
    first_chunk_cycles: int
    checked_path: Path | None = None  # the checked-program entry to load, or write once checked (service.checked_store)
    checked_key: str = ""
    text_file: Path | None = None  # with text None: the file holding it, read here if need be (service.program_file)


@dataclass(frozen=True)
class NeedText:
    """The worker must read the program after all (its store entry is gone or unsound): the
    daemon answers with ProgramText."""


@dataclass(frozen=True, eq=False)
class ProgramText:
    text: str


@dataclass(frozen=True)
class TracePath:
    path: Path


@dataclass(frozen=True)
class CancelPlan:
    pass


@dataclass(frozen=True, eq=False)
class CheckedProgram:
    """The request's program, parsed and checked: planning starts. With ``entry`` its blocks
    are in that checked-program store entry (service.checked_store), which the daemon maps as
    the worker does: no block crosses the pipe (a 10^6-block program in 1,003 slices took the
    daemon 1.3 s to receive, 0.7 s of it joining them under one hold of its interpreter lock).
    Without (no store, or the entry could not be written) they follow in ``ProgramBlocks``
    messages (``block_count`` in all): one pickle of a 100,000-block program is 21.5 MB and
    took 1.45 s to load, holding the daemon's interpreter lock that long; slices of
    BLOCKS_PER_MESSAGE hold it about 15 ms each."""

    program: Program  # with blocks=()
    block_count: int
    from_store: bool = False  # loaded from the checked-program store: not read and checked again
    entry: Path | None = None  # the store entry that holds the blocks (written now if not from_store)
    highest_feed_mm_s: float | None = None  # highest_feed_mm_s, so the daemon reads no column of the blocks


@dataclass(frozen=True, eq=False)
class ProgramBlocks:
    """The next blocks of the CheckedProgram's program, in order."""

    blocks: Sequence[Any]  # a slice of the program's blocks (program.records.BlockRecords: arrays)


@dataclass(frozen=True, eq=False)
class PathLengths:
    """The path's length before every ``stride``-th block and at its end, in mm (the running
    sum of the blocks' arc lengths); between those blocks it is interpolated by block. At most
    LENGTH_POINTS values cross the pipe and stay in the daemon: every block's, 8 MB at 10^6
    blocks and twice that while it was received, stayed in the daemon's heap after each job
    (its allocator keeps freed memory, an arena per receiving thread: 67 -> 141 MB in 9 starts)."""

    before_mm: np.ndarray  # float64: before_mm[k] = length before block k * stride; the last: the whole path's
    stride: int
    blocks: int

    @classmethod
    def of(cls, lengths_mm: np.ndarray) -> PathLengths:
        n = len(lengths_mm)
        stride = max(1, -(-(n + 1) // LENGTH_POINTS))
        before = np.zeros(n + 1)
        np.cumsum(lengths_mm, out=before[1:])
        points = before[::stride]
        if n % stride:
            points = np.append(points, before[n])
        return cls(np.ascontiguousarray(points), stride, n)

    @property
    def total_mm(self) -> float:
        return float(self.before_mm[-1])

    def before(self, block: int) -> float:
        """The path's length before ``block`` (0 <= block <= blocks)."""
        k, r = divmod(block, self.stride)
        low = float(self.before_mm[k])
        if r == 0:
            return low
        span = min((k + 1) * self.stride, self.blocks) - k * self.stride
        return low + (float(self.before_mm[k + 1]) - low) * r / span


@dataclass(frozen=True, eq=False)
class PlannedChunk:
    """Rows [first_row, first_row + len(counts)) of the job and what the daemon needs of them."""

    first_row: int
    counts: np.ndarray  # (m, axes) int32
    stop_tail: np.ndarray  # (t, axes) int32, (0, axes) when the chunk ends at rest
    pauses: tuple[tuple[int, str, int | None, bool], ...]  # (row, reason, tool, spindle wait): M0/M1/M6, M3/M4/S
    max_step: tuple[float, ...]
    max_accel: tuple[float, ...]
    block_rows: np.ndarray  # first row of each block reached in this chunk (int64)
    block_ids: np.ndarray  # those blocks (int32)
    feed_mm_s: np.ndarray  # (m,) float32: the planned feed (status)
    planned_s: float  # seconds since the request when this chunk was planned


@dataclass(frozen=True)
class PlanEnd:
    """The job's planning ended: all rows planned (``finished``), cancelled, or failed
    (``errors``: (where, message) of each, one for a planning error, several for a program
    the readers refuse)."""

    planned: int
    finished: bool
    errors: tuple[tuple[str, str], ...] = ()
    planning_time_s: float = 0.0
    notes: dict[str, Any] = field(default_factory=dict)
    measured: dict[str, Any] = field(default_factory=dict)
    trace_rows: int = 0
    max_feed_mm_s: float = 0.0  # the highest planned feed of the rows sent


class WorkerGone(Exception):
    """The daemon's end of a pipe is closed: the worker ends."""


# ---------------------------------------------------------------------- the worker process
def serve(commands: multiprocessing.connection.Connection,
          results: multiprocessing.connection.Connection) -> None:
    """The worker's main loop: one job per PlanRequest until ``None`` or the daemon is gone.
    Ctrl-C in a terminal reaches the whole process group: the daemon decides what it means
    (it stops the job along the path, then this worker), so the worker ignores SIGINT."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    results.send("ready")
    try:
        while True:
            command = commands.recv()
            if command is None:
                return
            if isinstance(command, PlanRequest):
                results.send(WorkerJob(command, commands, results).run())
    except (EOFError, OSError, WorkerGone):
        return


class WorkerJob:
    """One job planned in the worker (module docstring)."""

    def __init__(self, request: PlanRequest, commands: Any, results: Any) -> None:
        self.config, self.request = request.config, request
        self.commands, self.results = commands, results
        self.axis_map = AxisMap.from_config(request.config)
        self.started = time.monotonic()
        self.planned = 0
        self.max_feed_mm_s = 0.0
        self.cancelled = False
        self.trace_path: Path | None = None
        self.trace: TraceWriter | None = None
        self.trace_rows = 0
        self.pending: list[RowFigures] = []
        self.events: list[Any] = []
        self.stream: PlanStream | None = None
        self.measure: MeasureStream | None = None
        self.path: PlannedPath | None = None
        self.lengths: BlockLengths | None = None
        self.block_lines: BlockLinesFile | None = None

    def run(self) -> PlanEnd:
        errors: tuple[tuple[str, str], ...] = ()
        finished = False
        try:
            program, from_store, entry = checked_and_stored(self.request, self._ask_for_text)
            self.request = dataclasses.replace(self.request, text="")  # read: its text is not kept for the job
            send_program(self.results, program, from_store, entry,
                         highest_feed_mm_s(program, limits_from_config(self.config)))
            self.block_lines = BlockLinesFile(program)
            self.lengths = BlockLengths(program)
            self.events = pause_events(program, machine_has_devices(self.config))
            limits = limits_from_config(self.config)
            planner = self.stream = PlanStream(program, limits, self.request.chunk_cycles,
                                               self.request.first_chunk_cycles)
            # the trace measures set-points on the blended path, its pieces as the plan sets them up
            self.path = PlannedPath.streamed(program, lambda: planner.pieces_set_up)
            self.measure = MeasureStream(self.path.program)
            finished = self._plan_all()
            if finished:
                self.block_lines.reach(len(program.blocks))
                self._trace_rows(self._on_program(self.measure.finish()))
                self._wait_for_record()
        except InputError as err:
            errors = tuple(self._named(e) for e in (err.errors if isinstance(err, InputErrors) else [err]))
        except (EOFError, OSError, WorkerGone):
            raise WorkerGone() from None
        except Exception as err:  # a bug: the job must still stop on its tail, with a line saying why
            errors = ((self.request.name, f"planning failed after {self.planned} set-points: {err!r}"),)
        try:
            self._send_lengths(budget_s=None)  # a job that started gets them whatever its end
        except (EOFError, OSError):
            raise WorkerGone() from None
        except Exception as err:  # a bug: the job's progress falls back to blocks, its end is still reported
            log.warning(kv("path_lengths_failed", program=self.request.name, error=repr(err)))
        self._close_trace()
        stream = self.stream
        return PlanEnd(self.planned, finished and not errors, errors,
                       stream.planning_time_s if stream else 0.0, dict(stream.notes) if stream else {},
                       self.measure.measurements().summary() if self.measure and self.planned else {}, self.trace_rows,
                       self.max_feed_mm_s)

    def _on_program(self, figures: RowFigures | None) -> RowFigures | None:
        return figures if figures is None or self.path is None else self.path.on_program(figures)

    def _named(self, err: InputError) -> tuple[str, str]:
        """(where, message) with the program's name in front (a planner error names the line)."""
        name = self.request.name
        return (err.where if err.where.startswith(name) else f"{name}: {err.where}" if err.where else name,
                err.message)

    def _plan_all(self) -> bool:
        """Plan and send every chunk; False when the job was cancelled first."""
        assert self.stream is not None and self.measure is not None and self.path is not None
        before = np.zeros((0, len(self.request.columns)), np.int64)
        for chunk, resume in self.stream.chunks():
            counts = self._counts(chunk)
            tail = self._counts(resume.stop) if resume is not None and resume.stop is not None \
                else np.zeros((0, counts.shape[1]), np.int64)
            step, accel = chunk_figures(np.concatenate([counts, tail]), before, self.config.cycle_period_s)
            rows, ids = block_starts(chunk.block, self.planned)
            self.results.send(PlannedChunk(self.planned, counts.astype(np.int32), tail.astype(np.int32),
                                           self._pauses(chunk), step, accel, rows, ids,
                                           np.asarray(chunk.feed_mm_s, np.float32), time.monotonic() - self.started))
            if len(chunk.feed_mm_s):
                self.max_feed_mm_s = max(self.max_feed_mm_s, float(np.max(chunk.feed_mm_s)))
            self.planned += len(counts)
            before = counts[-2:]
            if len(chunk.block) and self.block_lines is not None:
                self.block_lines.reach(int(chunk.block[-1]) + 1)
            self._trace_rows(self._on_program(self.measure.add(self.path.rows(chunk))))
            self._send_lengths(budget_s=LENGTHS_BUDGET_S)
            if self._read_commands(block=False):
                return False
        return True

    def _send_lengths(self, budget_s: float | None) -> None:
        """Compute block lengths for up to ``budget_s`` (None: all); send them once all are known."""
        lengths = self.lengths
        if lengths is None or lengths.sent:
            return
        if lengths.compute(budget_s):
            self.results.send(PathLengths.of(lengths.lengths_mm))
            lengths.sent = True

    def _counts(self, rows: Trajectory) -> np.ndarray:
        """Set-points in counts; int32 range checked before motion (streamed_job.check_before_motion)."""
        return self.axis_map.to_counts(rows.position_mm[:, self.request.columns]).astype(np.int64)

    def _pauses(self, chunk: Trajectory) -> tuple[tuple[int, str, int | None, bool], ...]:
        """Rows of this chunk where the job holds: the first row of the block the event comes
        before (the planner's exact stop there). One pause a row, the program's own (M0/M1/M6,
        the operator resumes it) before a spindle wait (job_events.with_spindle_waits)."""
        found: dict[int, tuple[int, str, int | None, bool]] = {}
        while self.events and len(chunk.block) and int(chunk.block[-1]) >= self.events[0].before_block:
            event = self.events.pop(0)
            row = self.planned + int(np.searchsorted(chunk.block, event.before_block, side="left"))
            if event.waits_for_spindle:
                found.setdefault(row, (row, spindle_wait_reason(event), None, True))
            elif event.tool is not None and event.kind.value == "tool_change":
                found[row] = (row, f"{event.code} tool change to T{event.tool} at {event.source}", int(event.tool), False)
            else:
                found[row] = (row, f"{event.code} at {event.source}", None, False)
        return tuple(found[row] for row in sorted(found))

    def _ask_for_text(self) -> str:
        """The program's text from the daemon (NeedText, then its ProgramText; InputError if the
        job is cancelled meanwhile, WorkerGone if the daemon is)."""
        self.results.send(NeedText())
        while True:
            command = self.commands.recv()
            if isinstance(command, ProgramText):
                return command.text
            if isinstance(command, CancelPlan):
                self.cancelled = True
                raise InputError(self.request.name, "cancelled before its text came")
            if command is None:
                raise WorkerGone()

    def _read_commands(self, block: bool) -> bool:
        """Apply the commands waiting (or, ``block``, wait for one); True once cancelled."""
        while block or self.commands.poll():
            command = self.commands.recv()  # EOFError: the daemon is gone
            if command is None:
                raise WorkerGone()
            if isinstance(command, TracePath):
                self.trace_path = command.path
                self._trace_rows(None)
            elif isinstance(command, CancelPlan):
                self.cancelled = True
            block = block and not self.cancelled and self.trace_path is None
        return self.cancelled

    def _wait_for_record(self) -> None:
        """All planned: the trace needs the record's folder (or the job ended without one)."""
        if self.trace_path is None and not self.cancelled:
            self._read_commands(block=True)

    def _trace_rows(self, figures: RowFigures | None) -> None:
        """Write measured rows to the trace once its path is known (until then they wait: at
        most the chunks planned ahead of the record's creation)."""
        if figures is not None:
            self.pending.append(figures)
        if self.trace is None and self.trace_path is not None:
            self.trace = TraceWriter(self.trace_path)
        if self.trace is not None:
            for f in self.pending:
                self.trace.write(f)
                self.trace_rows += len(f.rows.block)
            self.trace.out.flush()  # a daemon killed later loses no planned row of the record
            self.pending.clear()
        if self.block_lines is not None and self.trace_path is not None:
            self.block_lines.write(self.trace_path.parent)

    def _close_trace(self) -> None:
        try:
            if self.block_lines is not None:
                self.block_lines.close()
            if self.trace is not None:
                self.trace.close()
        except InputError as err:
            log.warning(kv("trace_not_written", program=self.request.name, error=err))


class BlockLengths:
    """The program's block lengths, computed a slice at a time (module docstring)."""

    def __init__(self, program: Program) -> None:
        self.blocks = program.blocks
        self.lengths_mm = np.zeros(len(program.blocks))
        self.done = 0
        self.sent = False

    def compute(self, budget_s: float | None) -> bool:
        """Go on for about ``budget_s`` (None: to the end); True once every length is known.
        Lines and arcs only: all in closed form at the first call, after the first chunk (10^6
        blocks: ~0.1 s that first motion does not wait for)."""
        if self.done == 0 and isinstance(self.blocks, BlockRecords) and not self.blocks.curves:
            self.lengths_mm = self.blocks.lengths_mm()
            self.done = len(self.blocks)
        deadline = None if budget_s is None else time.monotonic() + budget_s
        while self.done < len(self.blocks) and (deadline is None or time.monotonic() < deadline):
            self.lengths_mm[self.done] = self.blocks[self.done].length_mm
            self.done += 1
        return self.done == len(self.blocks)


def read_and_check(request: PlanRequest) -> Program:
    """The request's program, parsed and checked before motion (InputError otherwise)."""
    r = request
    if r.text is None:
        raise InputError(r.name, "the program's text was not sent")  # read_or_load asks for a withheld text first
    # No cyclic collection while parsing: it keeps ~10 objects a word, and the collector's
    # passes over the worker's heap took ~0.1 s of a long program's parse (Wang x 460 in the
    # worker: checked program back in 0.88-1.13 s with them, 0.79-0.80 s without; x 100
    # 0.37 -> 0.17 s). Collected afterwards as usual.
    with GcQuiet("disable"):
        program = parse(r.name, r.text, r.start_xyz, r.options)
        check_before_motion(r.name, program, r.config, r.columns, AxisMap.from_config(r.config))
    return program


def read_or_load(request: PlanRequest, text_of: Callable[[], str] | None = None) -> tuple[Program, bool]:
    """(the checked program, True) from the store when its entry is there and sound (mapped,
    and touched: the store prunes the least recently used), else (read and checked now,
    False) (service.checked_store); a request whose text was withheld gets it from
    ``text_of`` then."""
    if request.checked_path is not None:
        from nurbsmotion.service.checked_store import load_checked

        program = load_checked(request.checked_path, request.checked_key)
        if program is not None:
            touch(request.checked_path)
            return program, True
    if request.text is None:
        if request.text_file is not None:
            text_of = lambda: read_text_file(request)  # noqa: E731 - the file the daemon named
        if text_of is None:
            raise InputError(request.name, "the program's text was not sent and its checked entry cannot be read")
        request = dataclasses.replace(request, text=text_of())
    return read_and_check(request), False


def read_text_file(request: PlanRequest) -> str:
    """The text of the request's ``text_file`` (the daemon's spool: UTF-8 already checked)."""
    assert request.text_file is not None
    try:
        return request.text_file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(request.name, f"cannot read the program's file {request.text_file}: {err}") from None


def touch(path: Path) -> None:
    try:
        os.utime(path)
    except OSError:
        pass  # gone meanwhile: the program is mapped already


def store_checked(request: PlanRequest, program: Program) -> Program | None:
    """Write ``program`` to the request's store entry and map it back: the stored program
    (None when there is no entry or it cannot be written: logged, the next start reads again)."""
    if request.checked_path is None:
        return None
    from nurbsmotion.service.checked_store import load_checked, save_checked

    try:
        save_checked(request.checked_path, request.checked_key, program)
    except (OSError, pickle.PicklingError) as err:
        log.warning(kv("checked_program_not_stored", program=request.name, error=err))
        return None
    return load_checked(request.checked_path, request.checked_key)


def checked_and_stored(request: PlanRequest, text_of: Callable[[], str] | None = None
                       ) -> tuple[Program, bool, Path | None]:
    """The request's checked program (from the store, or read, checked and stored now), whether
    it came from the store, and the entry that holds it (None: no store, or not writable).
    A program just read is planned from its entry too, the copy read dropped: the worker's
    memory holds the pages it plans, not the whole program. ``text_of``: read_or_load's."""
    program, from_store = read_or_load(request, text_of)
    if from_store:
        return program, True, request.checked_path
    stored = store_checked(request, program)
    return (program, False, None) if stored is None else (stored, False, request.checked_path)


def highest_feed_mm_s(program: Program, limits: PlanLimits) -> float:
    """The highest Block.feed_or_default_mm_s of the program's blocks; from the block columns
    (a slice at a time) when it has them (a Block per block took 1.6 s of the daemon's CPU at 10^5 blocks, before
    first motion and holding the cycle thread's interpreter lock)."""
    blocks = program.blocks
    if not isinstance(blocks, BlockRecords):
        return max(b.feed_or_default_mm_s(limits.default_feed_mm_s, limits.rapid_feed_mm_s) for b in blocks)
    highest = -np.inf
    for first in range(0, len(blocks), FEED_ROWS):  # a slice at a time: no column-sized temporaries (10^6 blocks: 25 MB)
        kinds, feeds = blocks.kinds[first:first + FEED_ROWS], blocks.feeds_mm_s[first:first + FEED_ROWS]
        machine = np.where(kinds == KINDS.index(BlockKind.RAPID), limits.rapid_feed_mm_s, limits.default_feed_mm_s)
        highest = max(highest, float(np.where(np.isnan(feeds), machine, feeds).max()))
    return highest


def send_program(results: Any, program: Program, from_store: bool = False, entry: Path | None = None,
                 highest_feed: float | None = None) -> None:
    """The checked program to the daemon: its outline and the store ``entry`` holding its
    blocks, or (no entry) its outline, then its blocks in slices (CheckedProgram), with its
    ``highest_feed`` (highest_feed_mm_s)."""
    blocks = program.blocks
    results.send(CheckedProgram(dataclasses.replace(program, blocks=()), len(blocks), from_store, entry, highest_feed))
    if entry is not None:
        return
    for first in range(0, len(blocks), BLOCKS_PER_MESSAGE):
        results.send(ProgramBlocks(blocks[first:first + BLOCKS_PER_MESSAGE]))


def receive_program(results: Any, outline: CheckedProgram, timeout_s: float, key: str = "") -> Program:
    """The daemon's side of send_program: the program mapped from its store entry (``key``:
    its key; EntryGone when it cannot be), or its blocks joined to the outline (TimeoutError
    when a slice is not there within ``timeout_s``; EOFError/OSError when the worker is gone)."""
    if outline.entry is not None:
        return mapped_entry(outline, key)
    slices: list[Any] = []
    received = 0
    while received < outline.block_count:
        if not results.poll(timeout_s):
            raise TimeoutError(f"the program's blocks after {received} of {outline.block_count}")
        message = results.recv()  # one slice: the lock is held while it loads, then free again
        if not isinstance(message, ProgramBlocks):
            raise TypeError(f"expected the program's blocks, got {type(message).__name__}")
        slices.append(message.blocks)
        received += len(message.blocks)
    if slices and all(isinstance(part, BlockRecords) for part in slices):  # a reader's: kept as columns
        return dataclasses.replace(outline.program, blocks=BlockRecords.concatenate(slices))
    return dataclasses.replace(outline.program, blocks=tuple(b for part in slices for b in part))


class EntryGone(Exception):
    """The store entry the worker named cannot be mapped in the daemon."""


def mapped_entry(outline: CheckedProgram, key: str) -> Program:
    """The daemon's map of the entry the worker wrote or loaded (the same blocks, the same key)."""
    from nurbsmotion.service.checked_store import load_checked

    assert outline.entry is not None
    program = load_checked(outline.entry, key)
    if program is None or len(program.blocks) != outline.block_count:
        raise EntryGone(f"the checked program's store entry {outline.entry} cannot be read")
    return program


def pause_events(program: Program, spindle_waits: bool) -> list[Any]:
    """The program's events the job holds at, by block: M0/M1/M6, and (``spindle_waits``: a
    machine with devices) M3/M4/S waiting for the spindle at speed."""
    return sorted((e for e in program.events if e.holds or (spindle_waits and e.waits_for_spindle)),
                  key=lambda e: e.before_block)


def block_starts(blocks: np.ndarray, first_row: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, blocks) where the block changes in ``blocks`` (its first row included)."""
    blocks = np.asarray(blocks)
    if not len(blocks):
        return np.zeros(0, np.int64), np.zeros(0, np.int32)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(blocks)) + 1])
    return (first_row + starts).astype(np.int64), blocks[starts].astype(np.int32)


# ---------------------------------------------------------------------- the daemon's side
class PlannerWorker:
    """The daemon's handle on its planner worker process (module docstring). Not thread-safe:
    the controller runs one job at a time."""

    def __init__(self) -> None:
        self._context = multiprocessing.get_context("spawn")
        self._process: Any = None
        self._commands: Any = None
        self._results: Any = None
        self._ready = False
        self._lock = threading.Lock()
        self._idle = threading.Event()  # no job's receiver reads the results pipe
        self._idle.set()
        self._started_s = 0.0

    def start(self) -> None:
        """Spawn the worker (it imports the planner meanwhile; the first job waits for it)."""
        commands_read, self._commands = self._context.Pipe(duplex=False)
        self._results, results_write = self._context.Pipe(duplex=False)
        self._process = self._context.Process(target=serve, args=(commands_read, results_write),
                                              name="nurbsmotion-planner", daemon=True)
        self._process.start()
        commands_read.close()  # the worker holds these ends: a dead worker closes them
        results_write.close()
        self._ready = False
        self._started_s = time.monotonic()
        cpus = keep_off_realtime_cpu(self._process.pid) if self._process.pid is not None else None
        log.debug(kv("planner_worker_started", pid=self._process.pid,
                     cpus=",".join(map(str, sorted(cpus))) if cpus else "all"))

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.is_alive()

    @property
    def ready(self) -> bool:
        """The worker answered that its imports are done (a job starts planning at once)."""
        return self._ready

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    def exit_description(self) -> str:
        """How the worker ended: 'exit code N' or 'signal N' (waits up to 1 s for it to end)."""
        if self._process is not None:
            self._process.join(1.0)
        code = self._process.exitcode if self._process is not None else None
        return f"exit code {code}" if code is not None and code >= 0 else f"signal {-code}" if code else "no exit code"

    def connect(self, request: PlanRequest) -> tuple[Any, Any]:
        """Send ``request`` to a ready worker (restarted if it died): the (commands, results)
        connections of this job. InputError when no worker can be had."""
        with self._lock:
            if not self._idle.wait(IDLE_TIMEOUT_S):  # the last job's worker never said it ended
                log.error(kv("planner_worker_stuck", pid=self.pid, waited_s=IDLE_TIMEOUT_S))
                self._end_process()
            if not self.alive:
                if self._process is not None:
                    log.warning(kv("planner_worker_restarted", previous=self.exit_description()))
                self.start()
            if not self._ready:
                self._wait_ready()
            try:
                self._commands.send(request)
            except OSError as err:
                raise InputError(request.name, f"the planner worker is not reachable: {err}") from None
            self._idle.clear()
            return self._commands, self._results

    def abandon(self, timeout_s: float = IDLE_TIMEOUT_S) -> None:
        """The job just sent is refused before any chunk was used: cancel it and read the
        worker's answers up to its PlanEnd (ended and restarted if it does not answer)."""
        try:
            self._commands.send(CancelPlan())
            deadline = time.monotonic() + timeout_s
            while self._results.poll(max(deadline - time.monotonic(), 0.0)):
                if isinstance(self._results.recv(), PlanEnd):
                    self.job_ended()
                    return
        except (EOFError, OSError):
            pass
        with self._lock:
            self._end_process()  # silent or gone: the next job starts a new worker

    def job_ended(self) -> None:
        """The job's receiver read its PlanEnd (or the worker's death): the next job may start."""
        self._idle.set()

    def wait_ready(self) -> None:
        """Block until the worker has started (its imports done): InputError if it cannot."""
        with self._lock:
            if not self._ready:
                self._wait_ready()

    def _wait_ready(self) -> None:
        try:
            if not self._results.poll(READY_TIMEOUT_S):
                raise InputError("planner worker", f"did not start within {READY_TIMEOUT_S:g} s")
            self._results.recv()
        except (EOFError, OSError):
            raise InputError("planner worker", f"ended while starting ({self.exit_description()})") from None
        self._ready = True
        log.debug(kv("planner_worker_ready", pid=self.pid, after_s=round(time.monotonic() - self._started_s, 3)))

    def close(self) -> None:
        """Ask the worker to quit; end it if it does not (the daemon stops)."""
        if self._process is None:
            return
        try:
            self._commands.send(None)
        except OSError:
            pass
        self._end_process()

    def _end_process(self) -> None:
        """Wait for the worker to end (terminate it after QUIT_TIMEOUT_S); close the pipes."""
        process, self._process = self._process, None
        if process is None:
            return
        process.join(QUIT_TIMEOUT_S)
        if process.is_alive():
            process.terminate()
            process.join(QUIT_TIMEOUT_S)
        self._commands.close()
        self._results.close()
        self._idle.set()
        log.debug(kv("planner_worker_stopped", pid=process.pid, exit=process.exitcode))


def as_error(errors: tuple[tuple[str, str], ...]) -> InputError:
    """The InputError (InputErrors for several) of a PlanEnd's ``errors``."""
    found = [InputError(where, message) for where, message in errors]
    return found[0] if len(found) == 1 else InputErrors(found)


__all__ = ["PlannerWorker", "PlanRequest", "NeedText", "ProgramText", "CheckedProgram", "ProgramBlocks", "send_program", "receive_program", "PathLengths", "PlannedChunk", "PlanEnd", "as_error", "TracePath", "CancelPlan", "serve"]
