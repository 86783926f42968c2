"""What planned and streamed jobs share, read by the planner, the planner worker, the
streamed job and the job events: the pause record, the job planned whole, the program
names of MDI lines and jogs, reading a submitted program by its name, the axis columns.

A leaf of the service layer: it imports no other service module (no import circle).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.planning import Trajectory
from nurbsmotion.planning.measure import Measurements
from nurbsmotion.planning.trace import write_trace
from nurbsmotion.program import AXES, Program, ProgramEvent, ReadOptions, parse_curve_yaml, parse_gcode
from nurbsmotion.program.records import BlockRecords
from nurbsmotion.program.reader import GCODE_SUFFIXES, YAML_SUFFIXES, check_no_start_line
from nurbsmotion.config.spindle import SpindleConfig


@dataclass(frozen=True)
class RunningJob:
    """The job running now, as others see it (Controller.running_job)."""

    job_id: str
    name: str


def running_job_id(job: RunningJob | None) -> str | None:
    return job.job_id if job is not None else None


@dataclass(frozen=True)
class JobPause:
    """A planned set-point row where the job holds until ``resume`` (M0, M1, M6)."""

    row: int  # the first row of the block the event comes before: at rest (the planner's exact stop)
    reason: str  # 'M0 at part.nc:12', 'M6 tool change to T3 at part.nc:20'
    tool: int | None = None  # the tool asked for (M6)
    spindle_wait: bool = False  # held for the spindle at speed (M3/M4/S): resumed by the job's events, not the operator


@dataclass(eq=False)
class PlannedJob:
    trajectory: Trajectory
    counts: np.ndarray  # (N, n_axes) int32, one row per cycle
    summary: dict[str, Any]
    max_rate: float  # highest playback rate (feed override) within the axis limits
    program: Program | None = field(default=None, repr=False)
    measurements: Measurements | None = field(default=None, repr=False)
    pauses: tuple[JobPause, ...] = ()  # rows where the job holds until resume (M0/M1/M6)

    def write_trace(self, path: Path) -> None:
        """The same CSV as ``nurbsmotion plan --trace`` (planning.trace)."""
        assert self.measurements is not None
        write_trace(path, self.trajectory, self.measurements)

    # the job interface the controller uses (service.streamed_job.StreamedJob has the same)
    @property
    def total_cycles(self) -> int | None:
        return len(self.counts)

    def block_at(self, index: int) -> int | None:
        blocks = self.trajectory.block
        return None if index < 0 or not len(blocks) else int(blocks[min(index, len(blocks) - 1)])

    def percent_at(self, index: int) -> float:
        return 100.0 * max(index + 1, 0) / len(self.counts) if len(self.counts) else 0.0

    def feed_at(self, index: int) -> float:
        feed = self.trajectory.feed_mm_s
        return float(feed[min(max(index, 0), len(feed) - 1)]) if len(feed) else 0.0

    def axis_step(self, axis: int, index: int, rows: int) -> int:
        """Counts axis ``axis`` moves from ``rows`` rows before row ``index`` to ``rows`` after
        (clamped to the job's rows): the way the job moves it there."""
        last = len(self.counts) - 1
        return int(self.counts[min(index + rows, last)][axis]) - int(self.counts[min(max(index - rows, 0), last)][axis])

    def write_records(self, record: Any) -> None:
        """blocks.csv, plan.json and the whole trace, before any motion."""
        if self.program is not None:  # the lines an interrupted job's record names (records.py)
            record.write_block_lines(block_lines(self.program))
        record.write_plan(self.summary, self.write_trace)

    def start(self, link: Any, shift: Callable[[np.ndarray], None]) -> Any:
        """Stream the counts after ``shift`` (in place: onto the offsets in force, service.homing)."""
        shift(self.counts)
        return link.stream(self.counts, pauses=tuple(p.row for p in self.pauses))

    def cancel(self) -> None:
        """Nothing runs beside the job."""

    def wait_closed(self) -> None:
        """Nothing writes into the record beside the job."""

    def end_reason(self, fell_behind_row: int) -> str:
        return ""

    def finish_records(self, record: Any) -> None:
        """Everything was written before the motion."""

    def release(self) -> None:
        """The job is over and nobody asks it anything more: its trajectory is kept (a whole
        plan's is the job's own)."""


MDI_NAME = "<mdi>"  # the program name of MDI lines (G-code, errors read '<mdi>:1: ...')
JOG_NAME = "<jog>"  # a jog's one G53 line (service.jog)


def parse(name: str, text: str, start_mm: np.ndarray, options: ReadOptions | None = None) -> Program:
    """The program readers, chosen by the name's suffix as ``read_program`` does for files;
    a G-code program starts at ``start_mm`` (where the axes hold) with ``options``."""
    suffix = Path(name).suffix.lower()
    if suffix in YAML_SUFFIXES:
        check_no_start_line(name, options)
        return parse_curve_yaml(text, name)
    if suffix in GCODE_SUFFIXES or name in (MDI_NAME, JOG_NAME):
        return parse_gcode(text, name, start_mm, options)
    raise InputError(name, f"unknown program type {suffix or '(no extension)'!r}: "
                           f"expected one of {' '.join(GCODE_SUFFIXES + YAML_SUFFIXES)}")


def block_lines(program: Program, first: int = 0, last: int | None = None) -> list[int]:
    """The program line of each block ``first`` to ``last`` (excluded; None: to the end), its
    SourceRef's; from the block columns when the program has them (a Block per block took 1.5 s
    of the daemon's CPU at 10^5 blocks, before first motion: the job record's blocks.csv)."""
    blocks = program.blocks
    last = len(blocks) if last is None else min(last, len(blocks))
    if not isinstance(blocks, BlockRecords):
        return [blocks[i].source.line for i in range(first, last)]
    lines = np.array(blocks.lines[first:last], dtype=np.int64)
    for i, ref in blocks.source_overrides.items():
        if first <= i < last:
            lines[i - first] = ref.line
    return lines.tolist()


def axis_columns(config: MachineConfig) -> list[int]:
    """Column of the program's XYZ for each configured axis (axes must be named X, Y or Z)."""
    columns = []
    for axis in config.axes:
        if axis.name not in AXES:
            raise InputError(config.where("axes"), f"axis {axis.name!r}: programs move {', '.join(AXES)} only")
        columns.append(AXES.index(axis.name))
    return columns


def spindle_wait_reason(event: ProgramEvent) -> str:
    """The pause reason of a spindle start/change the job holds at (service.job_events)."""
    return f"{event.code} at {event.source}: waiting for the spindle at speed"


def machine_has_devices(config: MachineConfig) -> bool:
    """A spindle drive or an I/O node (service.devices): jobs then hold for the spindle at speed
    after M3/M4/S (service.job_events)."""
    return isinstance(config.spindle, SpindleConfig) or config.io is not None
