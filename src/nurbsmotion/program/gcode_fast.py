"""The G-code reader's fast path: the plain move lines CAM posts write, run without lexing.

A line that ``FAST_LINE`` matches whole holds only an optional line number ``N..``, an
optional ``G17``/``G18``/``G19`` (the plane, set first as in the general path), an optional
``G0``/``G1``/``G2``/``G3`` and then, each at most once and in this order, ``X Y Z
I J K F`` with plain numbers, spaces allowed between letter and number (``G1 X1.5 Y-.2
F300``, ``X185.1 Y58.949 Z-0.5 I-0.9 J0``, ``G1 X 1.5 Y 2``):
about 99 % of a CAM program. While the reader's state allows it (not before a start line,
not inside a NURBS definition), a run of such lines goes through ``run_fast``: the
numbers straight from the match into the block records, the state kept in local floats.

It computes exactly what the general path (lex_line, run_line) computes for such a line,
with the same float operations in the same order: F, the motion mode, the target (offsets
added to absolute words, relative words added to the position), the zero-length move rule
and the arc's centre from I J K; a run's arcs are then computed together by arcs.arc_geometry
(arc_shape's own steps, the radii by one numpy hypot per column). Anything else on a line
(an error, a value out of range, a word the mode refuses, a missing feed, a bad arc) hands
the line back to the general path, which reports it as it always did; nothing of that
line has been applied (F and the motion mode are set again to the same values).
tests/program/test_fast_path.py compares both paths block by block.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from nurbsmotion.program.arcs import PLANES, ArcError, arc_geometry, arc_lengths_in_plane

_NUM = r"([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))"
_FAST = (r"[ \t]*(?:[Nn][0-9]+[ \t]*)?(?:[Gg]0*(1[789])(?![0-9.])[ \t]*)?(?:[Gg]0*([0-3])(?![0-9.])[ \t]*)?"
         + "".join(rf"(?:[{c}{c.lower()}][ \t]*{_NUM}[ \t]*)?" for c in "XYZIJKF") + r"\r?")
FAST_LINE = re.compile(_FAST)
# The lines the lexer must see before the program runs (lexed_first): blank (the lexer calls
# them empty), or holding a character no plain line holds (a comment, an O-word, '%', '/',
# '#', any other letter). The rest is kept as text and matched by FAST_LINE when it runs
# (lexed then if it is not plain after all: 'G90', 'X1 X2').
PLAIN_CHARACTERS = " \t\r0-9.+\\-NnGgXxYyZzIiJjKkFf"
_NOT_PLAIN = re.compile(rf"[^\n{PLAIN_CHARACTERS}]")
_BLANK_AFTER_BREAK = re.compile(r"\n[ \t]*\r?(?=\n|\Z)")
_BLANK_FIRST = re.compile(r"[ \t]*\r?(?:\n|\Z)")
MAX_ABS_VALUE = 1e9  # gcode_words.MAX_ABS_VALUE: larger values go to the general path (its error)
ZERO_MOVE_MM = 1e-9  # gcode_moves.ZERO_MOVE_MM
LINE_CODES = (0, 10)  # G0, G1 as round(10 * value)
NAN = math.nan
UNUSED_CENTRE_WORD = {17: 2, 18: 1, 19: 0}  # K in G17, J in G18, I in G19 (arcs.PLANES' offset letters)
ARC_BATCH = 512  # arcs computed together (finish_arcs)


def lexed_first(line: str) -> bool:
    """The line is one lines_lexed_first finds (the definition its test checks against)."""
    return _BLANK_FIRST.fullmatch(line) is not None or _NOT_PLAIN.search(line) is not None


def lines_lexed_first(text: str) -> list[int]:
    """Indexes (0-based, lines split at '\\n') of the lines ``lexed_first`` takes, in order:
    two scans of the whole text in C (a character no plain line holds, then blank lines),
    not a match per line."""
    starts = [0] if _BLANK_FIRST.match(text) else []
    pos = 0
    while (found := _NOT_PLAIN.search(text, pos)) is not None:
        starts.append(text.rfind("\n", 0, found.start()) + 1)
        pos = text.find("\n", found.end())
        if pos < 0:
            break
    starts.extend(m.start() + 1 for m in _BLANK_AFTER_BREAK.finditer(text))
    indexes, index, at = [], 0, 0
    for start in sorted(set(starts)):
        index += text.count("\n", at, start)
        at = start
        indexes.append(index)
    return indexes


def is_fast_line(raw: str) -> bool:
    """The line is one run_fast can take (whether it does depends on the state then)."""
    return FAST_LINE.fullmatch(raw) is not None and not raw.isspace() and raw != ""


class FastLines:
    """Mixin of GcodeParser: ``run_fast``. Declares what it uses of the parser."""

    source: str
    position: Any
    motion: int | None
    feed_mm_s: float | None
    mm_per_unit: float
    absolute: bool
    arc_absolute: bool
    plane: int
    offsets: Any
    nurbs: Any
    blocks: Any  # RecordsBuilder
    exact_stop_mode: bool
    blend_tolerance_mm: float | None
    smoothing_tolerance_mm: float | None
    arcs_batched: Callable[[], bool]  # arcs may take this path (finish_arcs)

    if TYPE_CHECKING:
        @property
        def skipping(self) -> bool: ...

    def fast_ready(self) -> bool:
        """The state lets plain lines skip the general path: reading for real (not before a
        start line), no NURBS being defined, no G53 in force."""
        return not self.skipping and self.nurbs is None and not self.offsets.machine_mode

    def run_fast(self, lines: list[Any], pc: int, stop: int) -> int:
        """Run the plain lines from index ``pc`` on (before ``stop``); the index of the first
        line not run (``pc`` itself when that line needs the general path)."""
        match = FAST_LINE.fullmatch
        px, py, pz = self.position.tolist()
        ox, oy, oz = self.offsets.total().tolist()
        feed, motion, unit, absolute, plane = self.feed_mm_s, self.motion, self.mm_per_unit, self.absolute, self.plane
        exact, blend, smoothing = self.exact_stop_mode, self.blend_tolerance_mm, self.smoothing_tolerance_mm
        blocks = self.blocks
        add_line = blocks.add_line_numbers
        arcs: list[PendingArc] | None = [] if self.arcs_batched() else None
        dist = math.dist
        failed: PendingArc | None = None
        i = pc
        while i < stop:
            raw = lines[i]
            if raw.__class__ is not str:
                break
            m = match(raw)
            if m is None:
                break
            plane_word, g, x, y, z, ci, cj, ck, f = m.groups()
            plane_before = plane
            if plane_word is not None:
                plane = int(plane_word)  # G17/G18/G19 apply first (set again if the general path takes the line)
            code = motion if g is None else int(g) * 10
            new_feed = feed
            if f is not None:
                fv = float(f)
                if not 0.0 < fv <= MAX_ABS_VALUE:
                    break
                new_feed = fv * unit / 60.0
            centre_words = ci is not None or cj is not None or ck is not None
            if x is None and y is None and z is None and not centre_words and (g is None or code is None):
                feed = new_feed  # F, N or nothing: no move (and no motion mode needed)
                i += 1
                continue
            if code is None:
                break  # axis words without a motion mode: the general path says so
            fx = float(x) if x is not None else 0.0
            fy = float(y) if y is not None else 0.0
            fz = float(z) if z is not None else 0.0
            if not (abs(fx) <= MAX_ABS_VALUE and abs(fy) <= MAX_ABS_VALUE and abs(fz) <= MAX_ABS_VALUE):
                break
            if absolute:
                ex = fx * unit + ox if x is not None else px
                ey = fy * unit + oy if y is not None else py
                ez = fz * unit + oz if z is not None else pz
            else:
                ex = px + fx * unit if x is not None else px
                ey = py + fy * unit if y is not None else py
                ez = pz + fz * unit if z is not None else pz
            if code == 10 or code == 0:
                if centre_words or (code == 10 and new_feed is None):
                    break
                feed, motion = new_feed, code
                if dist((ex, ey, ez), (px, py, pz)) > ZERO_MOVE_MM:
                    add_line(1 if code == 10 else 2, px, py, pz, ex, ey, ez, NAN if code == 0 else feed, exact,
                             blend, smoothing, i + 1)
                    px, py, pz = ex, ey, ez
                i += 1
                continue
            if arcs is None or new_feed is None or not centre_words:
                break
            centre = self.fast_centre(plane, (px, py, pz), (ci, cj, ck), (ox, oy, oz))
            if centre is None:
                break
            arcs.append(PendingArc(i, len(blocks.kinds), len(blocks.arc_axes) + blocks.arcs_reserved, (px, py, pz),
                                   (ex, ey, ez), centre, code == 20, plane, feed, motion, plane_before))
            feed, motion = new_feed, code
            blocks.reserve_arc(px, py, pz, ex, ey, ez, feed, exact, blend, smoothing, i + 1)
            px, py, pz = ex, ey, ez
            i += 1
            if len(arcs) >= ARC_BATCH:  # a bad arc wastes at most a batch's work
                failed = self.finish_arcs(arcs)
                arcs.clear()
                if failed is not None:
                    break
        failed = self.finish_arcs(arcs) if arcs else failed
        if failed is not None:  # from its line on, the general path goes on
            blocks.truncate(failed.blocks_before, failed.arcs_before)
            (px, py, pz), feed, motion, i = failed.start, failed.feed_before, failed.motion_before, failed.index
            plane = failed.plane_before
        self.position = np.array([px, py, pz])
        self.feed_mm_s, self.motion, self.plane = feed, motion, plane
        return i

    def fast_centre(self, plane_code: int, start: tuple[float, float, float],
                    words: tuple[str | None, str | None, str | None], origin: tuple[float, float, float]) -> list[float] | None:
        """The centre of a plain G2/G3 line from I J K as the general path computes it; None
        when the general path must take the line (a centre word outside the plane, a value
        out of range)."""
        if words[UNUSED_CENTRE_WORD[plane_code]] is not None:
            return None
        unit, absolute = self.mm_per_unit, self.arc_absolute
        centre = list(start)
        for axis in (0, 1, 2):
            text = words[axis]
            if text is not None:
                value = float(text)
                if not abs(value) <= MAX_ABS_VALUE:
                    return None
                value *= unit
                centre[axis] = value + origin[axis] if absolute else start[axis] + value
        return centre

    def finish_arcs(self, arcs: list[PendingArc]) -> PendingArc | None:
        """The arcs of a run, computed together (arcs.arc_geometry with the lengths of
        arc_lengths_in_plane) into their reserved rows; the first bad one (its error is the
        general path's to report), or None."""
        inch = self.mm_per_unit != 1.0
        lengths: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * len(arcs)
        for code in {a.plane for a in arcs}:
            rows = [k for k, a in enumerate(arcs) if a.plane == code]
            of_plane = arc_lengths_in_plane(PLANES[code], np.array([arcs[k].start for k in rows]),
                                            np.array([arcs[k].end for k in rows]), np.array([arcs[k].centre for k in rows]))
            for k, values in zip(rows, of_plane):
                lengths[k] = values
        add_arc_row = self.blocks.add_arc_row
        for arc, lengths_mm in zip(arcs, lengths):
            try:
                centre, sweep, rise = arc_geometry(PLANES[arc.plane], arc.start, arc.end, arc.centre, arc.clockwise, True,
                                                   inch, 1, lengths_mm)
            except ArcError:
                return arc
            add_arc_row(centre, sweep, rise, PLANES[arc.plane].normal_axis)
        return None


@dataclass(frozen=True, slots=True)
class PendingArc:
    """An arc of a fast run whose geometry finish_arcs computes; what to go back to if it is bad."""

    index: int  # its line's index in the lines
    blocks_before: int
    arcs_before: int
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    centre: list[float]
    clockwise: bool
    plane: int  # 17, 18, 19
    feed_before: float | None  # the state before its line
    motion_before: int | None
    plane_before: int
