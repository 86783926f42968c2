"""A job planned while it runs: the program is checked completely up front, then a producer
thread plans it chunk by chunk (planning.lookahead PlanStream) and feeds the master
(fieldbus.row_source.RowFeed) while the axes move.

Before any motion (prepare_streamed_job): syntax and geometry (the readers), the program
gate (service.program_gate), the machine's axes (a program axis without a machine axis must
not move), the soft limits from the path's verified bounding box (service.path_bounds: the
set-points lie on the path) and the int32 count range, then the first chunk is planned: a
program the planner refuses at its start is refused with that line. Later the producer runs
ahead of the axes by at most ``MAX_CHUNKS_AHEAD`` chunks (bounded memory); the trace and the
plan record are written as it goes (service.records). If planning fails part-way (it should
not: the planner has no give-ups) or falls behind, the axes stop on the verified stop tail
of the last chunk and the outcome names the program line.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.row_source import RowChunk, RowFeed, chunk_figures
from nurbsmotion.log import kv
from nurbsmotion.planning.limits import PlanLimits, limits_from_config
from nurbsmotion.planning.lookahead import PlanStream
from nurbsmotion.planning.lookahead.verify import FLUCTUATION_LIMIT, TOLERANCE
from nurbsmotion.planning.measure import MeasureStream, RowFigures
from nurbsmotion.planning.trace import TraceWriter
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import AXES, Program, ReadOptions
from nurbsmotion.service.path_bounds import hull_box, moving_unconfigured_axis, soft_limit_violation
from nurbsmotion.service.program_gate import check_machine_can_run
from nurbsmotion.service.rate import max_rate

log = logging.getLogger(__name__)

CHUNK_CYCLES = 2000  # set-points per planned chunk (2 s at 1 ms): the first motion waits for one
MAX_CHUNKS_AHEAD = 4  # chunks planned ahead of the axes (bounded memory; ~8 s at 1 ms)
FIRST_CHUNK_TIMEOUT_S = 60.0
FEEDS_KEPT = 8  # chunks whose feed column is kept for the status' feed


def streamed_max_rate(program: Program, limits: PlanLimits, config: MachineConfig, columns: list[int]) -> float:
    """The highest feed override rate for a plan not yet made, from bounds that hold for any
    plan of it: an axis moves no faster than the path (<= the highest feed of its blocks, the
    planner's fluctuation guarantee included) and accelerates no more than the path's
    resultant limit; the axis limits cap both (the planner keeps them)."""
    feed = max(b.feed_or_default_mm_s(limits.default_feed_mm_s, limits.rapid_feed_mm_s) for b in program.blocks)
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


def check_before_motion(name: str, program: Program, config: MachineConfig, columns: list[int],
                        axis_map: AxisMap) -> None:
    """Everything about the program knowable without planning it (module docstring)."""
    check_machine_can_run(program, config)
    if not program.blocks:
        raise InputError(name, "the program has no motion")
    moved = moving_unconfigured_axis(program, columns)
    if moved is not None:
        raise InputError(name, f"the program moves {AXES[moved]}, which this machine has no axis for")
    beyond = soft_limit_violation(program, config, columns)
    if beyond is not None:
        raise beyond
    low, high = hull_box(program, columns)
    try:
        axis_map.to_counts(np.array([low, high]), check_limits=False)
    except InputError as err:
        raise InputError(f"{name}: {err.where}", err.message) from None


class StreamedJob:
    """One streamed job: its checks passed, its producer planning ahead (see module docstring).

    The controller uses the same members as service.planner.PlannedJob: ``summary``,
    ``max_rate``, ``program``, ``pauses``, ``total_cycles``, ``block_at``, ``feed_at``,
    ``write_records``, ``start``, ``finish_records``, ``cancel``, ``end_reason``."""

    def __init__(self, name: str, program: Program, config: MachineConfig, columns: list[int],
                 chunk_cycles: int = CHUNK_CYCLES, max_chunks: int = MAX_CHUNKS_AHEAD) -> None:
        from nurbsmotion.service.planner import JobPause  # the shared pause record

        self._pause_type = JobPause
        self.name = name
        self.program = program
        self.config = config
        self.columns = columns
        self.axis_map = AxisMap.from_config(config)
        self.limits = limits_from_config(config)
        self.stream = PlanStream(program, self.limits, chunk_cycles)
        self.max_rate = streamed_max_rate(program, self.limits, config, columns)
        self.feed = RowFeed(len(config.axes), max_chunks, ahead_rows=2 * chunk_cycles)
        self.pauses: list[Any] = []  # JobPause, in row order, as the chunks are planned
        self.error: InputError | None = None  # planning failed part-way (the program line)
        self.planned = 0  # rows planned so far
        self.finished = False  # every row planned
        self.submitted_s = time.monotonic()
        self.first_chunk_s = float("nan")
        self._block_rows: list[int] = []  # first row of each block reached, in order
        self._block_ids: list[int] = []
        self._feeds: collections.deque[tuple[int, np.ndarray]] = collections.deque(maxlen=FEEDS_KEPT)
        self._length_before = np.concatenate([[0.0], np.cumsum([b.length_mm for b in program.blocks])])
        self._events = sorted((e for e in program.events if e.holds), key=lambda e: e.before_block)
        self._trace_path: Path | None = None
        self._trace: TraceWriter | None = None
        self._pending: list[RowFigures] = []
        self._trace_lock = threading.Lock()  # the producer writes the trace; write_records may finish it
        self._produced = False  # the producer ended (its trace rows are all pending or written)
        self._measure = MeasureStream(program)
        self._first = threading.Event()
        self._thread = threading.Thread(target=self._produce, name="job-planner", daemon=True)
        start = program.blocks[0].start
        self.summary: dict[str, Any] = {
            "program": name, "blocks": len(program.blocks), "length_mm": round(program.length_mm, 6),
            "algorithm": "lookahead", "streamed": True, "period_s": config.cycle_period_s,
            "chunk_cycles": chunk_cycles, "cycles": None, "duration_s": None,
            "axes": [{"name": a.name, "node": a.node_id} for a in config.axes],
            "start_mm": [round(float(x), 6) for x in start], "end_mm": [round(float(x), 6) for x in program.end_position],
            "max_override_percent": round(max(1.0, self.max_rate) * 100.0, 3), "pauses": []}

    # ------------------------------------------------------------------ before motion
    def begin(self, timeout_s: float = FIRST_CHUNK_TIMEOUT_S) -> None:
        """Start the producer and wait for the first chunk; InputError if it cannot plan it."""
        self._thread.start()
        if not self._first.wait(timeout_s):
            self.cancel()
            raise InputError(self.name, f"planning the first {self.stream.chunk_cycles} set-points took more "
                             f"than {timeout_s:g} s")
        if self.error is not None and self.planned == 0:
            self.cancel()
            raise self.error
        self.summary["first_chunk_s"] = round(self.first_chunk_s, 6)

    def write_records(self, record: Any) -> None:
        """plan.json now (what is known before motion); the trace follows as it is planned."""
        record.write_plan_summary(self.summary)
        with self._trace_lock:
            self._trace_path = record.folder / "trace.csv"
            if self._produced:  # planned completely before the record existed
                self._write_pending(close=True)

    def start(self, link: Any) -> Any:
        """Hand the feed to the master (the first chunk is queued): the job's handle."""
        return link.stream_feed(self.feed)

    def cancel(self) -> None:
        """The job ended or never started: the producer stops at its next chunk."""
        self.feed.cancel()

    # ------------------------------------------------------------------ while it runs
    @property
    def total_cycles(self) -> int | None:
        """Rows of the whole job once planned (None while planning goes on)."""
        return self.planned if self.finished else None

    def block_at(self, index: int) -> int | None:
        """The program block of planned row ``index`` (None before the first)."""
        if index < 0 or not self._block_rows:
            return None
        i = int(np.searchsorted(np.asarray(self._block_rows), index, side="right")) - 1
        return self._block_ids[max(i, 0)]

    def feed_at(self, index: int) -> float:
        """Planned feed (mm/s) at row ``index`` when it is recent, else 0."""
        for first, feed in reversed(self._feeds):
            if first <= index < first + len(feed):
                return float(feed[index - first])
        return 0.0

    def percent_at(self, index: int) -> float:
        """Progress: of the rows once all are planned, else of the path's length up to the
        start of the block reached."""
        if index < 0:
            return 0.0
        if self.finished and self.planned:
            return 100.0 * (index + 1) / self.planned
        block = self.block_at(index)
        total = float(self._length_before[-1])
        return 100.0 * float(self._length_before[block]) / total if block is not None and total > 0 else 0.0

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
        """After the job: the producer stopped, the trace closed, plan.json with the figures of
        the rows planned."""
        self.cancel()
        self._thread.join(10.0)
        measured = self._measure.measurements()
        self.summary.update({
            "cycles": self.planned, "planned_all": self.finished,
            "duration_s": round(max(self.planned - 1, 0) * self.config.cycle_period_s, 6),
            "planning_time_s": round(self.stream.planning_time_s, 6),
            "first_chunk_s": round(self.first_chunk_s, 6), "notes": dict(self.stream.notes),
            "measured": measured.summary(), "pauses": [{"row": p.row, "reason": p.reason} for p in self.pauses]})
        if self.error is not None:
            self.summary["error"] = str(self.error)
        record.write_plan_summary(self.summary)

    # ------------------------------------------------------------------ the producer thread
    def _produce(self) -> None:
        before = np.zeros((0, len(self.columns)), np.int64)
        try:
            for chunk, resume in self.stream.chunks():
                counts = self._counts(chunk)
                tail = self._counts(resume.stop) if resume is not None and resume.stop is not None \
                    else np.zeros((0, counts.shape[1]), np.int64)
                pauses = self._pause_rows(chunk)
                step, accel = chunk_figures(np.concatenate([counts, tail]), before, self.config.cycle_period_s)
                self._index(chunk)
                if not self.feed.put(RowChunk(counts, tail, pauses, step, accel)):
                    return  # the job ended
                if self.planned == 0:
                    self.first_chunk_s = time.monotonic() - self.submitted_s
                self.planned += len(counts)
                before = counts[-2:]
                self._first.set()
                self._trace_rows(self._measure.add(chunk))
            self._trace_rows(self._measure.finish())
            self.finished = True
        except InputError as err:
            self.error = err if err.where.startswith(self.name) else InputError(
                f"{self.name}: {err.where}" if err.where else self.name, err.message)
            log.warning(kv("planning_failed", program=self.name, row=self.planned, error=self.error))
        except Exception as err:  # a bug: the job must still stop on its tail, with a line saying why
            log.exception("job planner failed")
            self.error = InputError(self.name, f"planning failed after {self.planned} set-points: {err!r}")
        finally:
            self.feed.close()
            self._first.set()
            self._close_trace()

    def _counts(self, rows: Trajectory) -> np.ndarray:
        return self.axis_map.to_counts(rows.position_mm[:, self.columns]).astype(np.int64)

    def _pause_rows(self, chunk: Trajectory) -> tuple[int, ...]:
        """Rows of this chunk where a holding event (M0/M1/M6) happens: the first row of the
        block it comes before (the planner's exact stop there)."""
        rows = []
        while self._events and len(chunk.block) and int(chunk.block[-1]) >= self._events[0].before_block:
            event = self._events.pop(0)
            row = self.planned + int(np.searchsorted(chunk.block, event.before_block, side="left"))
            if event.tool is not None and event.kind.value == "tool_change":
                reason, tool = f"{event.code} tool change to T{event.tool} at {event.source}", event.tool
            else:
                reason, tool = f"{event.code} at {event.source}", None
            self.pauses.append(self._pause_type(row, reason, tool))
            rows.append(row)
        return tuple(rows)

    def _index(self, chunk: Trajectory) -> None:
        """Remember where each block starts (line reached) and the chunk's feed (status)."""
        blocks = np.asarray(chunk.block)
        if len(blocks):
            changes = np.flatnonzero(np.diff(blocks)) + 1
            starts = np.concatenate([[0], changes])
            for s in starts:
                if not self._block_ids or self._block_ids[-1] != int(blocks[s]):
                    self._block_rows.append(self.planned + int(s))
                    self._block_ids.append(int(blocks[s]))
        self._feeds.append((self.planned, np.asarray(chunk.feed_mm_s, float)))

    def _trace_rows(self, figures: RowFigures | None) -> None:
        """Write measured rows to the trace once the record exists (kept until then: at most
        the chunks planned ahead before the job started)."""
        with self._trace_lock:
            if figures is not None:
                self._pending.append(figures)
            self._write_pending(close=False)

    def _write_pending(self, close: bool) -> None:
        try:
            if self._trace is None and self._trace_path is not None:
                self._trace = TraceWriter(self._trace_path)
            if self._trace is not None:
                for f in self._pending:
                    self._trace.write(f)
                self._pending.clear()
                if close:
                    self._trace.close()
        except InputError as err:
            log.warning(kv("trace_not_written", program=self.name, error=err))
            self._trace_path = None
            self._trace = None

    def _close_trace(self) -> None:
        with self._trace_lock:
            self._produced = True
            if self._trace_path is not None:
                self._write_pending(close=True)


def prepare_streamed_job(name: str, text: str, config: MachineConfig, start_mm: np.ndarray | None = None,
                         options: ReadOptions | None = None, chunk_cycles: int = CHUNK_CYCLES) -> StreamedJob:
    """Parse and check ``text`` completely, start planning it, and return once the first chunk
    is planned (InputError naming file:line for anything refused; nothing moves)."""
    from nurbsmotion.service.planner import axis_columns, parse

    axis_map = AxisMap.from_config(config)
    columns = axis_columns(config)
    start_xyz = np.zeros(len(AXES))
    if start_mm is not None:
        start_xyz[columns] = start_mm
    program = parse(name, text, start_xyz, options or ReadOptions(tool_table=config.tool_table))
    check_before_motion(name, program, config, columns, axis_map)
    job = StreamedJob(name, program, config, columns, chunk_cycles)
    job.begin()
    return job
