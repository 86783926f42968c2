"""A Program: the toolpath as blocks, every block a curve with its feed and source line.

A block's ``curve`` is a NurbsCurve: lines are degree-1 NURBS and arcs exact rational
quadratics (geometry.primitives), so the planners only ever see NurbsCurve. A reader keeps
lines and arcs as what they are (program.records: arrays, closed-form lengths) and builds
that curve only when a block is asked for it. Positions are machine XYZ in mm (work, G92 and tool
offsets already applied); feeds in mm/s.

What happens between moves (dwell, pause, tool change, spindle, coolant) is a
``ProgramEvent`` anchored before a block index: it takes place once ``blocks[:before_block]``
are done. Events that stop motion mark the block before them ``exact_stop``.
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import ArcShape, LineShape
from nurbsmotion.program.coordinates import CoordinateState

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


class Block:
    """One move: its kind, geometry, feed and source line.

    ``Block(kind, curve, ...)`` holds a NurbsCurve; a reader's blocks hold a LineShape or
    ArcShape instead (``shape``: a few numbers) and build ``curve`` from it when asked (kept
    on this Block, never in the program: program.records). Start, end and length come from
    the shape without building the curve."""

    __slots__ = ("kind", "shape", "feed_mm_s", "source", "exact_stop", "blend_tolerance_mm", "smoothing_tolerance_mm",
                 "_curve")

    def __init__(self, kind: BlockKind, curve: NurbsCurve | LineShape | ArcShape, feed_mm_s: float | None,
                 source: SourceRef, exact_stop: bool = False, blend_tolerance_mm: float | None = None,
                 smoothing_tolerance_mm: float | None = None) -> None:
        self.kind = kind
        self.shape = curve
        self.feed_mm_s = feed_mm_s  # None: the machine's feed applies (rapid feed for RAPID, default feed otherwise)
        self.source = source
        self.exact_stop = exact_stop  # come to rest at the end of this block (G61/G61.1, or a stopping event follows)
        self.blend_tolerance_mm = blend_tolerance_mm  # G64 P: path tolerance at this block's start; None: the machine's
        self.smoothing_tolerance_mm = smoothing_tolerance_mm  # G64 Q: short-segment smoothing tolerance; 0: off; None: the machine's
        self._curve: NurbsCurve | None = curve if isinstance(curve, NurbsCurve) else None

    def __repr__(self) -> str:
        return (f"Block({self.kind.value}, {self.shape!r}, feed_mm_s={self.feed_mm_s}, source={self.source}, "
                f"exact_stop={self.exact_stop}, blend_tolerance_mm={self.blend_tolerance_mm}, "
                f"smoothing_tolerance_mm={self.smoothing_tolerance_mm})")

    def __getstate__(self) -> tuple[object, ...]:
        return (self.kind, self.shape, self.feed_mm_s, self.source, self.exact_stop, self.blend_tolerance_mm,
                self.smoothing_tolerance_mm)

    def __setstate__(self, state: tuple[object, ...]) -> None:
        self.__init__(*state)  # type: ignore[misc]

    def replace(self, **changes: object) -> Block:
        """A copy with some fields changed (``exact_stop=True``), as dataclasses.replace."""
        values = {"kind": self.kind, "curve": self.shape, "feed_mm_s": self.feed_mm_s, "source": self.source,
                  "exact_stop": self.exact_stop, "blend_tolerance_mm": self.blend_tolerance_mm,
                  "smoothing_tolerance_mm": self.smoothing_tolerance_mm, **changes}
        return Block(**values)  # type: ignore[arg-type]

    @property
    def curve(self) -> NurbsCurve:
        """The block's NURBS: a line's degree-1 segment, an arc's exact rational quadratic."""
        if self._curve is None:
            self._curve = self.shape.curve()  # type: ignore[union-attr]
        return self._curve

    def feed_or_default_mm_s(self, default_feed_mm_s: float, rapid_feed_mm_s: float) -> float:
        """The programmed feed, or the machine's: rapid feed for RAPID blocks, default feed otherwise."""
        if self.feed_mm_s is not None:
            return self.feed_mm_s
        return rapid_feed_mm_s if self.kind is BlockKind.RAPID else default_feed_mm_s

    @property
    def start(self) -> NDArray[np.float64]:
        shape = self.shape
        return shape.start_point if isinstance(shape, NurbsCurve) else shape.start.copy()

    @property
    def end(self) -> NDArray[np.float64]:
        shape = self.shape
        return shape.end_point if isinstance(shape, NurbsCurve) else shape.end.copy()

    @property
    def length_mm(self) -> float:
        """Arc length: closed form for a line or arc (geometry.primitives), the NURBS length otherwise."""
        return self.shape.length if isinstance(self.shape, NurbsCurve) else self.shape.length_mm


class EventKind(str, enum.Enum):
    DWELL = "dwell"  # G4 P: the axes rest dwell_s
    PAUSE = "pause"  # M0, or M1 with the optional-stop switch on: hold until resume
    TOOL_CHANGE = "tool_change"  # M6: manual tool change to ``tool``, hold until resume
    SPINDLE = "spindle"  # M3/M4/M5, or S while the spindle turns
    COOLANT = "coolant"  # M7/M8/M9
    OUTPUT = "output"  # M62/M63 (with the next motion), M64/M65 (at once): digital output P on/off


class SpindleDirection(str, enum.Enum):
    CW = "cw"  # M3
    CCW = "ccw"  # M4
    OFF = "off"  # M5


class CoolantMode(str, enum.Enum):
    MIST = "mist"  # M7
    FLOOD = "flood"  # M8
    OFF = "off"  # M9


HOLDING_EVENTS = (EventKind.PAUSE, EventKind.TOOL_CHANGE)
STOPPING_EVENTS = HOLDING_EVENTS + (EventKind.DWELL,)


@dataclass(frozen=True)
class ProgramEvent:
    """Something between moves, with the line it came from."""

    kind: EventKind
    before_block: int
    source: SourceRef
    code: str  # as written: 'G4', 'M0', 'M1', 'M6', 'M3', 'M8', 'S'
    dwell_s: float | None = None
    tool: int | None = None
    spindle: SpindleDirection | None = None
    spindle_rpm: float | None = None  # the S value: rpm, or surface speed (units/min) under G96
    constant_surface_speed: bool = False  # G96 in effect
    coolant: CoolantMode | None = None
    output: int | None = None  # M62-M65 P: the output number
    output_on: bool | None = None  # M62/M64 on, M63/M65 off
    output_synchronized: bool = False  # M62/M63 (LinuxCNC: with the next motion)

    @property
    def holds(self) -> bool:
        """The job waits for the operator (resume) here."""
        return self.kind in HOLDING_EVENTS

    @property
    def waits_for_spindle(self) -> bool:
        """M3/M4, or S while the spindle turns: the next move waits for the spindle at speed."""
        return self.kind is EventKind.SPINDLE and self.spindle is not SpindleDirection.OFF

    @property
    def stops_motion(self) -> bool:
        return self.kind in STOPPING_EVENTS or self.waits_for_spindle


@dataclass(frozen=True)
class ResumeState:
    """The program's modal state on arrival at its start line (program.gcode_start): what a
    whole run would have in effect just before line ``line`` runs.

    ``position_mm``: machine XYZ where the move before ``line`` ends (line ``line`` starts
    there). ``coordinates``: work offsets, active system and G92 then; ``tool`` and
    ``tool_length_mm``: the tool in the spindle and the G43 offset in effect.
    """

    line: int
    source: str
    mm_per_unit: float  # 1.0 G21, 25.4 G20
    absolute: bool  # G90 (False: G91)
    plane: int  # 17, 18, 19
    coordinates: CoordinateState
    tool: int | None
    tool_length_mm: float
    feed_mm_s: float | None
    spindle: SpindleDirection
    spindle_rpm: float
    constant_surface_speed: bool
    coolant: frozenset[CoolantMode]
    position_mm: tuple[float, float, float]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready, for the job's record and status."""
        return {"line": self.line, "units": "mm" if self.mm_per_unit == 1.0 else "inch",
                "distance": "G90" if self.absolute else "G91", "plane": f"G{self.plane}",
                "coordinates": self.coordinates.as_dict(), "tool": self.tool, "tool_length_mm": self.tool_length_mm,
                "feed_mm_min": None if self.feed_mm_s is None else self.feed_mm_s * 60.0,
                "spindle": self.spindle.value, "spindle_rpm": self.spindle_rpm,
                "constant_surface_speed": self.constant_surface_speed,
                "coolant": sorted(m.value for m in self.coolant), "position_mm": list(self.position_mm)}


@dataclass(frozen=True)
class ReadExtent:
    """How much of its file a reader read: a program is never shorter than its file without
    saying so. Reading ends at the file's end, at M2/M30 (LinuxCNC ignores what follows) or at
    the closing ``%`` tape mark of a file that opens with one."""

    lines_total: int  # lines in the file
    last_line: int  # the line reading ended at (lines_total at the end of the file)
    ended_by: str  # 'end of file', or the program end or tape mark as written: 'M30', 'M2', '%'
    lines_not_read: int  # lines after last_line with anything on them (blank lines and a bare '%' left out)


@runtime_checkable
class BlocksWithLengths(Protocol):
    """Blocks that know every block's length at once (program.records.BlockRecords)."""

    def lengths_mm(self) -> NDArray[np.float64]: ...


@dataclass(frozen=True, eq=False)
class Program:
    """An ordered list of blocks; consecutive blocks meet (end of one = start of the next).

    ``coordinates`` are the offsets in effect at the end (G10/G92/G28.1 may change them):
    hand them to the next reader (ReadOptions.coordinates) to carry them over.
    """

    name: str
    blocks: Sequence[Block]  # a reader's: program.records.BlockRecords (compact); any sequence of Blocks works
    start_position: NDArray[np.float64]
    events: tuple[ProgramEvent, ...] = ()
    coordinates: CoordinateState | None = None
    tool_at_end: int | None = None  # tool in the spindle after the last M6/M61 (None: never changed)
    resume: ResumeState | None = None  # started from a line (ReadOptions.start_line): the state there
    reading: ReadExtent | None = None  # G-code: the lines read of the file's (YAML curves: None)

    @property
    def requires_spindle(self) -> bool:
        """M3 or M4 somewhere: refuse to run on a machine without a spindle."""
        return any(e.kind is EventKind.SPINDLE and e.spindle is not SpindleDirection.OFF for e in self.events)

    @property
    def requires_coolant(self) -> bool:
        return any(e.kind is EventKind.COOLANT and e.coolant is not CoolantMode.OFF for e in self.events)

    def dwell_s_before(self) -> dict[int, float]:
        """Total G4 dwell before each block index (the planner holds the axes that long)."""
        out: dict[int, float] = {}
        for e in self.events:
            if e.kind is EventKind.DWELL and e.dwell_s:
                out[e.before_block] = out.get(e.before_block, 0.0) + e.dwell_s
        return out

    @property
    def length_mm(self) -> float:
        if isinstance(self.blocks, BlocksWithLengths):  # program.records.BlockRecords: in closed form
            return float(self.blocks.lengths_mm().sum())
        return float(sum(b.length_mm for b in self.blocks))

    @property
    def end_position(self) -> NDArray[np.float64]:
        return self.blocks[-1].end if len(self.blocks) else self.start_position.copy()


def with_feeds_capped(program: Program, cap_mm_s: float) -> Program:
    """The program with every programmed feed at most ``cap_mm_s`` (a machine's top speed, as
    LinuxCNC's MAX_LINEAR_VELOCITY caps F); the blocks as Block objects."""
    blocks = tuple(b.replace(feed_mm_s=cap_mm_s) if b.feed_mm_s is not None and b.feed_mm_s > cap_mm_s else b
                   for b in program.blocks)
    return dataclasses.replace(program, blocks=blocks)
