"""The planned path set up section by section, as the plan reaches it (issue 25).

The set-up (runs.program_pieces, smoothing.smoothed_pieces, blend.blend_pieces,
runs.split_runs) over a whole program costs seconds per 10^4 blocks; a streaming consumer
must move within a second. So the program's pieces are set up in sections cut where the
set-up of one side cannot depend on the other, and a section is set up only when the planner
asks for its runs (each once):

1. smoothing: a cut between program pieces a and b where no chain joins them
   (smoothing.chains: a chain continues over a -> b only when both have a smoothing
   tolerance > 0, one programmed feed and a corner tolerance > 0 between them);
2. blending: the corner between the smoothed pieces on either side of the cut is not a blend
   candidate (blend.blend_pieces): a tolerance of 0 there, an end that is not a line or planar
   arc, a deflection above SHARP_LIMIT_DEG, or above MAX_DEFLECTION_DEG with a blend too slow
   to be worth it, by a margin (CUT_MARGIN_RAD, CUT_MARGIN_SPEED: the candidate test is
   evaluated on other arrays here); then no blend, and no joined line, spans it;
3. runs: split_runs ends a run there (a stop, a dwell, or a junction speed of 0).

A run never spans a cut, so the runs of the sections, in order, are the whole program's
(tests/planning/lookahead/test_setup.py compares pieces and set-points on CAM programs).
The settings depend on the highest feed of the whole program: from the block columns
(max_program_feed), without setting up a piece.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Iterator

import numpy as np

from nurbsmotion.geometry import corner_blend as cb
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead import blend
from nurbsmotion.planning.lookahead.blend import blend_pieces, corner_tolerances, piece_shapes
from nurbsmotion.planning.lookahead.path import BlockPiece
from nurbsmotion.planning.lookahead.runs import (MIN_BLOCK_LENGTH_MM, ProgramStops, Run, end_tangents, junction_speed,
                                                 program_pieces, split_runs)
from nurbsmotion.planning.lookahead.smoothing import program_tolerance, same_programmed_feed, smoothed_pieces, \
    smoothing_tolerance
from nurbsmotion.program import BlockKind, Program
from nurbsmotion.program.records import FORM_LINE, KINDS, BlockRecords

SECTION_BLOCKS = 200  # program blocks read at a time
SECTION_PIECES = 64  # sections end at the first cut after this many smoothed pieces, the first after 1,
# doubling (the first chunk waits for a short one; then fewer, longer sections: the numpy calls per
# section cost more than its pieces; 1 each: 15.7 s of set-up for fusion360 btn8copies x2 under
# cProfile, most of it in 10^4 cut checks on pairs; 64: 9.1 s)
CUT_MARGIN_RAD = 1e-6  # a cut's deflection exceeds the blend limit by this much at least
CUT_MARGIN_SPEED = 1e-6  # relative: a cut's sharp blend is this much slower than the blend limit at least


def max_program_feed(program: Program, limits: PlanLimits) -> float:
    """The highest feed of a block with motion (api.max_feed of program_pieces) from the
    block columns: every line's from its ends; an arc or curve faster than all lines is
    checked on its curve."""
    blocks = program.blocks
    if not isinstance(blocks, BlockRecords) or not len(blocks):
        return max((p.feed_mm_s for p in program_pieces(program, limits)), default=1.0)
    feeds = blocks.feeds_mm_s if limits.feed_mm_s is None else np.full(len(blocks), limits.feed_mm_s)
    feeds = np.where(np.isnan(feeds), limits.default_feed_mm_s, feeds)
    feeds = np.where(blocks.kinds == KINDS.index(BlockKind.RAPID), limits.rapid_feed_mm_s, feeds)
    is_line = blocks.forms == FORM_LINE
    moving = np.abs(blocks.ends - blocks.starts).max(axis=1) > MIN_BLOCK_LENGTH_MM
    best = float(feeds[is_line & moving].max(initial=-math.inf))
    others = np.flatnonzero(~is_line & (feeds > best))
    for i in others[np.argsort(-feeds[others], kind="stable")].tolist():
        if program_pieces(program, limits, i, i + 1):
            best = float(feeds[i])
            break
    return best if best > -math.inf else 1.0


class PathSections:
    """The runs of a program set up section by section (module docstring); ``blocks_set_up``
    counts the program blocks read so far; ``pieces`` are the planned pieces of the sections set up
    so far, in order (blended: api.planned_pieces of the whole program once all are set up)."""

    def __init__(self, program: Program, limits: PlanLimits, stops: ProgramStops, min_pass_mm_s: float) -> None:
        self.program, self.limits, self.stops, self.min_pass_mm_s = program, limits, stops, min_pass_mm_s
        self.blocks_set_up = 0
        self.pending: list[BlockPiece] = []  # program pieces read, not yet smoothed
        self.smoothed: list[BlockPiece] = []  # smoothed pieces, not yet blended
        self.min_pieces = 1  # the next section's pieces at least (doubling up to SECTION_PIECES)
        self.checked = 1  # smoothed[:checked] is the next section at least
        self.ordinal = 0
        self.last: BlockPiece | None = None  # the last piece of the sections set up
        self.pieces: list[BlockPiece] = []  # every planned piece set up so far (lookahead.planned_path.PlannedPath)

    def runs(self) -> Iterator[Run]:
        """Every run of the program, in order."""
        while True:
            section = self.next_section()
            if not section:
                return
            pieces = blend_pieces(section, self.limits, self.stops)
            pieces = [replace(p, ordinal=p.ordinal + self.ordinal) for p in pieces]
            self.ordinal += len(pieces)
            self.pieces.extend(pieces)
            yield from split_runs(pieces, self.limits, self.min_pass_mm_s, self.stops, self.last)
            self.last = pieces[-1]

    def read(self) -> bool:
        """Read the next blocks' pieces and smooth them up to the last chain boundary (all at
        the program's end); False when there was nothing left to read."""
        total = len(self.program.blocks)
        if self.blocks_set_up >= total:
            if self.pending:
                self.smoothed.extend(smoothed_pieces(self.pending, self.program, self.limits, self.stops))
                self.pending = []
            return False
        stop = min(self.blocks_set_up + SECTION_BLOCKS, total)
        self.pending.extend(program_pieces(self.program, self.limits, self.blocks_set_up, stop))
        self.blocks_set_up = stop
        for k in range(len(self.pending) - 1, 0, -1):
            if not self.one_chain(self.pending[k - 1], self.pending[k]):
                done, self.pending = self.pending[:k], self.pending[k:]
                self.smoothed.extend(smoothed_pieces(done, self.program, self.limits, self.stops))
                break
        return True

    def next_section(self) -> list[BlockPiece]:
        """The smoothed pieces of the next section: up to the first cut after ``min_pieces``
        pieces, or to the program's end."""
        while True:
            more = self.read()
            smoothed = self.smoothed
            while self.checked < len(smoothed):
                if self.is_cut(smoothed[self.checked - 1], smoothed[self.checked]):
                    section, self.smoothed = smoothed[:self.checked], smoothed[self.checked:]
                    self.next_minimum()
                    return section
                self.checked += 1
            if not more:
                section, self.smoothed = self.smoothed, []
                self.next_minimum()
                return section

    def next_minimum(self) -> None:
        self.min_pieces = min(2 * self.min_pieces, SECTION_PIECES)
        self.checked = self.min_pieces

    def one_chain(self, a: BlockPiece, b: BlockPiece) -> bool:
        """Whether program pieces a and b may be in one smoothing chain (smoothing.chains)."""
        program, limits, stops = self.program, self.limits, self.stops
        return (smoothing_tolerance(a, program, limits, stops) > 0 and smoothing_tolerance(b, program, limits, stops) > 0
                and same_programmed_feed(program, a, b) and program_tolerance(a.last_block, b.block, limits, stops) > 0)

    def is_cut(self, a: BlockPiece, b: BlockPiece) -> bool:
        """Whether the blends and runs up to smoothed piece ``a`` cannot depend on those from ``b``
        (module docstring): no blend candidate there, and a run ends there."""
        if not self.stays_junction(a, b):
            return False
        stops = self.stops
        if stops.dwell_between(a.last_block, b.block) > 0 or a.last_block in stops.stop_after:
            return True
        deviation = (stops.deviation_mm or {}).get(b.block)
        return junction_speed(end_tangents(a)[1], end_tangents(b)[0], self.limits, self.min_pass_mm_s, deviation) <= 0.0

    def stays_junction(self, a: BlockPiece, b: BlockPiece) -> bool:
        """The corner a -> b is no blend candidate (blend.blend_pieces), with CUT_MARGIN_RAD to spare."""
        pieces = [a, b]
        if float(corner_tolerances(pieces, self.limits, self.stops)[0]) <= 0:
            return True
        shapes, known = piece_shapes(pieces)
        if not known.all():
            return True
        _, t_in, _ = shapes.take(np.array([0])).state_at(shapes.length_mm[:1])
        _, t_out, _ = shapes.take(np.array([1])).state_at(np.zeros(1))
        deflection = float(np.arccos(np.clip(np.dot(t_in[0], t_out[0]), -1.0, 1.0)))
        if deflection > math.radians(blend.SHARP_LIMIT_DEG) + CUT_MARGIN_RAD:  # read at each use: a test may change it
            return True
        if deflection <= math.radians(blend.MAX_DEFLECTION_DEG) + CUT_MARGIN_RAD:
            return False
        return self.too_slow_to_blend(shapes, pieces)

    def too_slow_to_blend(self, shapes: cb.Pieces, pieces: list[BlockPiece]) -> bool:
        """A sharp corner (above MAX_DEFLECTION_DEG) whose blend fails its checks or is not worth
        it by CUT_MARGIN_SPEED at least (blend.worth_blending, as blend.blend_pieces asks)."""
        first, second = shapes.take(np.array([0])), shapes.take(np.array([1]))
        tolerance = corner_tolerances(pieces, self.limits, self.stops)
        d = cb.trim_distances(first, second, tolerance)
        points = cb.blend_points(first, second, d)
        if not (d[0] > 0 and cb.monotone(points)[0]):
            return True
        feed_in, feed_out = np.array([pieces[0].feed_mm_s]), np.array([pieces[1].feed_mm_s])
        one_mode = np.array([not self.stops.mode_change(pieces[0].last_block, pieces[1].block)])
        return not bool(blend.worth_blending(points, feed_in, feed_out, one_mode, self.limits, CUT_MARGIN_SPEED)[0])


