"""A Program: the toolpath as blocks, every block a NURBS curve with its feed and source line.

Lines are degree-1 NURBS and arcs exact rational quadratics (geometry.primitives), so the
planners only ever see NurbsCurve. Positions are machine XYZ in mm; feeds in mm/s.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve

AXES = ("X", "Y", "Z")


class BlockKind(str, enum.Enum):
    NURBS = "nurbs"
    LINE = "line"  # G01: feed move
    RAPID = "rapid"  # G00: moves at the machine's rapid feed
    ARC = "arc"  # G02/G03, stored as an exact rational quadratic NURBS


@dataclass(frozen=True)
class SourceRef:
    """Where a block came from: ``file:line`` and the text of that line."""

    file: str
    line: int
    text: str = ""

    def __str__(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass(frozen=True, eq=False)
class Block:
    kind: BlockKind
    curve: NurbsCurve
    feed_mm_s: float | None  # None: the machine's feed applies (rapid feed for RAPID, default feed otherwise)
    source: SourceRef

    def feed_or_default_mm_s(self, default_feed_mm_s: float, rapid_feed_mm_s: float) -> float:
        """The programmed feed, or the machine's: rapid feed for RAPID blocks, default feed otherwise."""
        if self.feed_mm_s is not None:
            return self.feed_mm_s
        return rapid_feed_mm_s if self.kind is BlockKind.RAPID else default_feed_mm_s

    @property
    def start(self) -> NDArray[np.float64]:
        return self.curve.start_point

    @property
    def end(self) -> NDArray[np.float64]:
        return self.curve.end_point

    @property
    def length_mm(self) -> float:
        return self.curve.length


@dataclass(frozen=True, eq=False)
class Program:
    """An ordered list of blocks; consecutive blocks meet (end of one = start of the next)."""

    name: str
    blocks: tuple[Block, ...]
    start_position: NDArray[np.float64]

    @property
    def length_mm(self) -> float:
        return float(sum(b.length_mm for b in self.blocks))

    @property
    def end_position(self) -> NDArray[np.float64]:
        return self.blocks[-1].end if self.blocks else self.start_position.copy()
