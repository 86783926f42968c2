"""Start a G-code program from line N (issue 22: "start from line N", LinuxCNC's "run from line").

Every line before N runs for its modal and coordinate effects only: no blocks and no events
(an M0, M6, G4 or M3 before N does nothing by itself), but units, distance mode, plane,
work offset and G92, tool and tool length offset, feed, spindle and coolant are tracked
exactly as in a whole run, and so is the position each move would end at. On arrival at
line N the reader records that state (``ResumeState``), then emits the approach (source
``file:N (approach)``) and reads on from line N as usual:

1. an M6 when the tool the program holds at N is not the one in the spindle (a hold, so
   the operator loads it), then the spindle (M3/M4 at its speed, or M5 when the program
   had it off while it turns) and the coolant (M7/M8) as the program had them at N: events,
   so the job's spindle at-speed wait applies before any motion;
2. a rapid straight up to the clearance height ``max(safe_z_mm, Z now, Z at N)`` (machine
   mm), a rapid in X/Y to line N's start point at that height, then a feed move down to the
   start point's Z at the program's feed at N (the machine's default feed if none); each
   comes to rest at its end (exact stop), so no corner of the approach is blended away.

Refused, one line naming ``file:N``, where that is not safe or not meaningful: N inside an
O-word loop (while, do, repeat) or subroutine body, N inside a G5.2 ... G5.3 or G06.2
NURBS definition, N past the program's end (the file's last line, or after M2/M30), N on
a line the program never runs (an ``if`` branch not taken, after a closing ``%``), and N
with no motion after it. A G02/G03 at line N starts from the previous move's end point as
programmed: fine. Canned cycles (G81-G89) are not read at all (docs/programs.md), so there
are no canned-cycle repeats to start inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.geometry.primitives import LineShape
from nurbsmotion.program.coordinates import Offsets
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.model import BlockKind, CoolantMode, EventKind, ResumeState, SpindleDirection
from nurbsmotion.program.owords import Construct, Flow

APPROACH_TEXT = "(approach)"
APPROACH_ZERO_MM = 1e-9  # shorter approach moves are left out
LOOP_KINDS = ("while", "do", "repeat")


def _label(c: Construct) -> str:
    return f"o{c.label}" if isinstance(c.label, int) else f"o<{c.label}>"


def enclosing_refusal(flow: Flow, index: int) -> str | None:
    """Why line ``index`` (0-based) cannot be a start line because of the O-word construct it
    lies in (a loop's or a subroutine's body), or None."""
    seen: set[int] = set()
    for c in flow.constructs.values():
        if id(c) in seen or not c.start < index <= c.end:
            continue
        seen.add(id(c))
        first, last = c.start + 1, c.end + 1  # line numbers
        if c.kind == "sub":
            return (f"inside the body of subroutine {_label(c)} (lines {first}-{last}): start at a line of the "
                    f"main program")
        if c.kind in LOOP_KINDS:
            return (f"inside the O-word loop {_label(c)} {c.kind} (lines {first}-{last}): start at line {first} "
                    f"(the loop's head) or after line {last}")
    return None


@dataclass
class StartLine:
    """The reader's bookkeeping for a start line: its index, whether it was reached, where."""

    number: int
    reached: bool = False
    ended_at: int | None = None  # the line of the M2/M30 that ended the program, if it did
    blocks_at_start: int = 0  # blocks before the program's own (the approach)
    state: ResumeState | None = None


class StartLineReading:
    """The start-line part of the G-code reader (mixed into GcodeParser)."""

    source: str
    options: Any  # ReadOptions
    start: NDArray[np.float64]
    position: NDArray[np.float64]
    mm_per_unit: float
    absolute: bool
    plane: int
    offsets: Offsets
    tool_loaded: int | None
    feed_mm_s: float | None
    spindle: SpindleDirection
    spindle_rpm: float
    constant_surface_speed: bool
    coolant: set[CoolantMode]
    nurbs: Any
    blocks: Any  # program.records.RecordsBuilder
    frames: list[Any]
    add_event: Callable[..., None]
    add_block: Callable[..., None]

    def init_start_line(self) -> None:
        number = self.options.start_line
        self.start_line: StartLine | None = None if number is None else StartLine(number)
        if number is not None:
            if isinstance(number, bool) or not isinstance(number, int) or number < 1:
                raise InputError(f"{self.source}: start line", f"must be a line number >= 1, got {number!r}")
            if self.options.safe_z_mm is None or np.isnan(self.options.safe_z_mm):
                raise InputError(f"{self.source}:{number}", "starting from a line needs a safe Z for the approach "
                                                            "(machine.safe_z_mm)")

    @property
    def skipping(self) -> bool:
        """Lines before the start line: modal and coordinate effects only."""
        return self.start_line is not None and not self.start_line.reached

    def start_line_where(self) -> str:
        assert self.start_line is not None
        return f"{self.source}:{self.start_line.number}"

    def check_start_line_place(self, flow: Flow, line_count: int) -> None:
        """The refusals knowable from the text alone (before running it)."""
        s = self.start_line
        if s is None:
            return
        if s.number > line_count:
            raise InputError(self.start_line_where(), f"past the end of the program: the file has {line_count} lines")
        why = enclosing_refusal(flow, s.number - 1)
        if why is not None:
            raise InputError(self.start_line_where(), why)

    def arrive_at(self, pc: int) -> None:
        """Called before line index ``pc`` runs: at the start line (the first time), record the
        state and emit the approach."""
        s = self.start_line
        if s is None or s.reached or pc != s.number - 1:
            return
        if self.frames:  # cannot happen outside a sub body (refused before): kept as a guard
            raise InputError(self.start_line_where(), "reached inside a subroutine call: start at a line of the "
                                                      "main program")
        if self.nurbs is not None:
            first = self.nurbs.first.number
            raise InputError(self.start_line_where(), f"inside the NURBS of line {first}: start at line {first}")
        s.state = self.resume_state(s.number)
        s.reached = True
        self.emit_approach(s.state)
        s.blocks_at_start = len(self.blocks)

    def resume_state(self, number: int) -> ResumeState:
        return ResumeState(
            line=number, source=self.source, mm_per_unit=self.mm_per_unit, absolute=self.absolute, plane=self.plane,
            coordinates=self.offsets.state(), tool=self.tool_loaded, tool_length_mm=self.offsets.tool_length_mm,
            feed_mm_s=self.feed_mm_s, spindle=self.spindle, spindle_rpm=self.spindle_rpm,
            constant_surface_speed=self.constant_surface_speed, coolant=frozenset(self.coolant),
            position_mm=tuple(float(v) for v in self.position))  # type: ignore[arg-type]

    def emit_approach(self, state: ResumeState) -> None:
        """Tool, spindle and coolant events, then up to the clearance height, across, down at feed."""
        line = GcodeLine(self.source, state.line, APPROACH_TEXT)
        if state.tool is not None and state.tool != self.options.tool_in_spindle:
            self.add_event(line, EventKind.TOOL_CHANGE, "M6", tool=state.tool)
        if state.spindle is not SpindleDirection.OFF:
            code = "M3" if state.spindle is SpindleDirection.CW else "M4"
            self.add_event(line, EventKind.SPINDLE, code, spindle=state.spindle, spindle_rpm=state.spindle_rpm,
                           constant_surface_speed=state.constant_surface_speed)
        elif self.options.spindle is not SpindleDirection.OFF:
            self.add_event(line, EventKind.SPINDLE, "M5", spindle=SpindleDirection.OFF, spindle_rpm=None)
        for mode in sorted(state.coolant, key=lambda m: m.value):
            self.add_event(line, EventKind.COOLANT, "M7" if mode is CoolantMode.MIST else "M8", coolant=mode)
        target = np.array(state.position_mm, dtype=float)
        here = self.start.copy()
        clear_z = max(float(self.options.safe_z_mm), float(here[2]), float(target[2]))
        up = np.array([here[0], here[1], clear_z])
        across = np.array([target[0], target[1], clear_z])
        for a, b, kind in ((here, up, BlockKind.RAPID), (up, across, BlockKind.RAPID), (across, target, BlockKind.LINE)):
            if float(np.linalg.norm(b - a)) > APPROACH_ZERO_MM:
                self.add_block(kind, LineShape(a, b), None if kind is BlockKind.RAPID else self.feed_mm_s, line)
                self.blocks.mark_exact_stop_last()  # no corner blended away
        self.position = target

    def check_start_line_reached(self) -> None:
        """After the run: the refusals only running the program can tell."""
        s = self.start_line
        if s is None:
            return
        if not s.reached:
            if s.ended_at is not None:
                raise InputError(self.start_line_where(), f"past the end of the program: it ends at line {s.ended_at} "
                                                          f"(M2/M30)")
            raise InputError(self.start_line_where(), "the program never runs this line (an O-word branch not taken, "
                                                      "an else/endif line its flow jumps over, or after the closing "
                                                      "%): start at a line it runs")
        if len(self.blocks) == s.blocks_at_start:
            raise InputError(self.start_line_where(), "no motion from this line on: nothing to start")

