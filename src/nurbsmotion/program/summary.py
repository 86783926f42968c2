"""What a program does, in numbers: blocks by kind, length, bounding box, feed range, and
what happens between moves (dwell, pauses, tool changes, spindle, coolant)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.program.model import EventKind, Program

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
    """Summary of a program; the bounding box is of sampled curve points (not control points)."""
    by_kind: dict[str, int] = {}
    length_by_kind: dict[str, float] = {}
    points = [program.start_position.reshape(1, 3)]
    feeds = []
    for block in program.blocks:
        kind = block.kind.value
        by_kind[kind] = by_kind.get(kind, 0) + 1
        length_by_kind[kind] = length_by_kind.get(kind, 0.0) + block.length_mm
        points.append(curve_samples(block.curve))
        if block.feed_mm_s is not None:
            feeds.append(block.feed_mm_s * 60.0)
    cloud = np.vstack(points)
    start, end = program.start_position, program.end_position

    def triple(v: np.ndarray) -> tuple[float, float, float]:
        return (float(v[0]), float(v[1]), float(v[2]))

    return ProgramSummary(
        name=program.name, blocks=len(program.blocks), blocks_by_kind=by_kind,
        length_mm=float(sum(length_by_kind.values())), length_by_kind_mm=length_by_kind,
        start_mm=triple(start), end_mm=triple(end),
        bbox_min_mm=triple(cloud.min(axis=0)), bbox_max_mm=triple(cloud.max(axis=0)),
        feed_min_mm_min=min(feeds) if feeds else None, feed_max_mm_min=max(feeds) if feeds else None,
        blocks_at_machine_feed=len(program.blocks) - len(feeds),
        events_by_kind=events_by_kind(program), dwell_s=float(sum(program.dwell_s_before().values())),
        tools=tuple(e.tool for e in program.events if e.kind is EventKind.TOOL_CHANGE and e.tool is not None),
        requires_spindle=program.requires_spindle, requires_coolant=program.requires_coolant,
        exact_stops=sum(b.exact_stop for b in program.blocks),
        reading=reading_dict(program))


def reading_dict(program: Program) -> dict[str, Any] | None:
    """The lines read of the file's (model.ReadExtent) as a plain dict: check --json, plan.json."""
    return asdict(program.reading) if program.reading is not None else None



def events_by_kind(program: Program) -> dict[str, int]:
    counts: dict[str, int] = {}
    for e in program.events:
        counts[e.kind.value] = counts.get(e.kind.value, 0) + 1
    return counts
