"""What a program does, in numbers: blocks by kind, length, bounding box, feed range, and
what happens between moves (dwell, pauses, tool changes, spindle, coolant). Computed over
the blocks' records (program.records), vectorised: no curve is built for a line or arc."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.program.model import EventKind, Program
from nurbsmotion.program.records import KINDS, BlockRecords

SAMPLES_PER_SPAN = 64


@dataclass(frozen=True)
class ProgramSummary:
    name: str
    blocks: int
    blocks_by_kind: dict[str, int]
    length_mm: float
    length_by_kind_mm: dict[str, float]
    start_mm: tuple[float, float, float]
    end_mm: tuple[float, float, float]
    bbox_min_mm: tuple[float, float, float]
    bbox_max_mm: tuple[float, float, float]
    feed_min_mm_min: float | None  # over blocks with a programmed feed (rapids excluded)
    feed_max_mm_min: float | None
    blocks_at_machine_feed: int  # rapids and YAML curves without feed_mm_min
    events_by_kind: dict[str, int]  # dwell, pause, tool_change, spindle, coolant
    dwell_s: float  # total G4 dwell
    tools: tuple[int, ...]  # tools of the M6 tool changes, in order
    requires_spindle: bool
    requires_coolant: bool
    exact_stops: int  # blocks that end at rest (G61, or before a dwell/pause/tool change)
    reading: dict[str, Any] | None = None  # G-code: lines_total, last_line, ended_by, lines_not_read (model.ReadExtent)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def curve_samples(curve: NurbsCurve, per_span: int = SAMPLES_PER_SPAN) -> np.ndarray:
    """Points along the curve: ``per_span`` per knot span plus the span ends."""
    ends = curve.breakpoints
    u = np.concatenate([np.linspace(a, b, per_span, endpoint=False) for a, b in zip(ends[:-1], ends[1:])] + [ends[-1:]])
    return curve.points(u)


def summarize(program: Program) -> ProgramSummary:
    """Summary of a program, over its records' arrays (program.records): lengths in closed
    form for lines and arcs; the bounding box holds the end points, each arc's extremes and
    sampled points of every NURBS curve (curve_samples)."""
    records = BlockRecords.of_blocks(program.blocks)
    codes, first = np.unique(records.kinds, return_index=True)
    lengths = records.lengths_mm()
    by_kind: dict[str, int] = {}
    length_by_kind: dict[str, float] = {}
    for code in codes[np.argsort(first)].tolist():  # in order of first appearance
        of_kind = records.kinds == code
        by_kind[KINDS[code].value] = int(of_kind.sum())
        length_by_kind[KINDS[code].value] = float(lengths[of_kind].sum())
    low, high = records.extent_mm(curve_samples)
    start, end = program.start_position, program.end_position
    low, high = np.minimum(low, start), np.maximum(high, start)
    feeds = records.feeds_mm_s[~np.isnan(records.feeds_mm_s)] * 60.0

    def triple(v: np.ndarray) -> tuple[float, float, float]:
        return (float(v[0]), float(v[1]), float(v[2]))

    return ProgramSummary(
        name=program.name, blocks=len(records), blocks_by_kind=by_kind,
        length_mm=float(sum(length_by_kind.values())), length_by_kind_mm=length_by_kind,
        start_mm=triple(start), end_mm=triple(end), bbox_min_mm=triple(low), bbox_max_mm=triple(high),
        feed_min_mm_min=float(feeds.min()) if len(feeds) else None, feed_max_mm_min=float(feeds.max()) if len(feeds) else None,
        blocks_at_machine_feed=len(records) - len(feeds),
        events_by_kind=events_by_kind(program), dwell_s=float(sum(program.dwell_s_before().values())),
        tools=tuple(e.tool for e in program.events if e.kind is EventKind.TOOL_CHANGE and e.tool is not None),
        requires_spindle=program.requires_spindle, requires_coolant=program.requires_coolant,
        exact_stops=int(records.exact_stops.sum()), reading=reading_dict(program))


def reading_dict(program: Program) -> dict[str, Any] | None:
    """The lines read of the file's (model.ReadExtent) as a plain dict: check --json, plan.json."""
    return asdict(program.reading) if program.reading is not None else None



def events_by_kind(program: Program) -> dict[str, int]:
    counts: dict[str, int] = {}
    for e in program.events:
        counts[e.kind.value] = counts.get(e.kind.value, 0) + 1
    return counts
