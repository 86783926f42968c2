"""A program's consecutive G01 blocks as polylines: the input of short-segment smoothing
(geometry/polyline_fit.py, docs/smoothing.md).

A chain is a maximal sequence of LINE blocks: any other block (rapid, arc, NURBS) ends it.
Per segment it carries the programmed feed; per vertex a break flag where motion must stop
or a run must not cross: a stopping event (dwell, pause, tool change, spindle wait) before
the next block, or an exact stop (G61) at the end of a block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.program.model import BlockKind, Program

NO_FEED = -1.0  # a block without F (the machine's feed): equal to other such blocks only


@dataclass(frozen=True)
class LineChain:
    """Blocks ``first_block`` .. ``first_block + len(points) - 2``: vertices (N, 3), one feed
    per segment (mm/s, NO_FEED for the machine's), one break flag per vertex."""

    first_block: int
    points: NDArray[np.float64]
    feeds_mm_s: NDArray[np.float64]
    breaks: NDArray[np.bool_]

    def block_of_segment(self, segment: int) -> int:
        return self.first_block + segment


def line_chains(program: Program) -> list[LineChain]:
    """Every maximal chain of consecutive LINE blocks of the program, in order."""
    stops = {e.before_block for e in program.events if e.stops_motion}
    chains: list[LineChain] = []
    first = None
    for i, block in enumerate((*program.blocks, None)):
        is_line = block is not None and block.kind is BlockKind.LINE
        if first is not None and (not is_line or i in stops):
            chains.append(_chain(program, first, i))
            first = None
        if is_line and first is None:
            first = i
    return chains


def _chain(program: Program, first: int, end: int) -> LineChain:
    """The chain of blocks first .. end - 1."""
    blocks = program.blocks[first:end]
    points = np.array([blocks[0].start] + [b.end for b in blocks])
    feeds = np.array([NO_FEED if b.feed_mm_s is None else b.feed_mm_s for b in blocks])
    breaks = np.zeros(len(points), dtype=bool)
    breaks[1:] = [b.exact_stop for b in blocks]
    return LineChain(first, points, feeds, breaks)
