"""G-code reader: G00/G01, G02/G03 arcs, Fanuc G06.2 and LinuxCNC G5.2/G5.3 NURBS -> Program.

The accepted language, with every error, is described in docs/programs.md. Lines are
read in order with a modal state (motion G, plane, G90/G91, G20/G21, F); the first bad
line raises InputError naming ``file:line: WORD`` and nothing after it is read. Problems of
one NURBS definition (weights, knots, ...) are all reported together (InputErrors).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve, clamped_uniform_knots
from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.program.arcs import PLANES, ArcError, arc_nurbs, centre_from_radius
from nurbsmotion.program.curve_check import CurveProblem, build_curve
from nurbsmotion.program.gcode_words import Word, split_words
from nurbsmotion.program.model import Block, BlockKind, Program, SourceRef

MM_PER_INCH = 25.4
SAME_POSITION_MM = 1e-6  # first NURBS control point vs current position
ZERO_MOVE_MM = 1e-9  # shorter G00/G01 moves are skipped

# G codes as round(10 * value): motion (modal group 01) and the others we understand
RAPID, LINE, ARC_CW, ARC_CCW, NURBS_FANUC, NURBS_LINUXCNC, NURBS_LINUXCNC_END = 0, 10, 20, 30, 62, 52, 53
MOTION_CODES = {RAPID, LINE, ARC_CW, ARC_CCW, NURBS_FANUC, NURBS_LINUXCNC, NURBS_LINUXCNC_END}
PLANE_CODES = {170: 17, 180: 18, 190: 19}
UNIT_CODES = {200: MM_PER_INCH, 210: 1.0}
DISTANCE_CODES = {900: True, 910: False}
FEED_MODE_CODES = {940}
NO_OP_CODES = {400, 490, 800, 540}  # cancel cutter/length compensation and canned cycles, default work offset
END_CODES = {2, 30}  # M02, M30
IGNORED_M_CODES = {3, 4, 5, 8, 9}  # spindle and coolant: no spindle here
IGNORED_LETTERS = {"N", "S"}  # line numbers; spindle speed

MOTION_WORDS = {
    RAPID: "XYZ", LINE: "XYZ", ARC_CW: "XYZIJKR", ARC_CCW: "XYZIJKR",
    NURBS_FANUC: "KXYZRP", NURBS_LINUXCNC: "XYPL", NURBS_LINUXCNC_END: "",
}
NURBS_ORDERS = (2, 4)  # G06.2 P and G5.2 L: order = degree + 1


G_NAMES = {RAPID: "G00", LINE: "G01", ARC_CW: "G02", ARC_CCW: "G03", NURBS_FANUC: "G06.2",
           NURBS_LINUXCNC: "G5.2", NURBS_LINUXCNC_END: "G5.3"}


def g_name(code: int) -> str:
    return G_NAMES.get(code, f"G{code / 10:g}")


@dataclass
class _Line:
    """One parsed line: where it is, its words sorted by kind."""

    file: str
    number: int
    text: str
    g_words: list[Word] = field(default_factory=list)
    m_words: list[Word] = field(default_factory=list)
    words: dict[str, Word] = field(default_factory=dict)
    unsupported: list[Word] = field(default_factory=list)

    @property
    def where(self) -> str:
        return f"{self.file}:{self.number}"

    def at(self, word: Word | str | None) -> str:
        return f"{self.where}: {word}" if word else self.where

    @property
    def source(self) -> SourceRef:
        return SourceRef(self.file, self.number, self.text.strip())


@dataclass
class _Nurbs:
    """A NURBS being collected block by block, with the place of every value."""

    kind: int  # NURBS_FANUC | NURBS_LINUXCNC
    order: int
    feed_mm_s: float | None
    first: _Line
    points: list[NDArray[np.float64]] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)
    knots: list[float] = field(default_factory=list)
    point_at: list[str] = field(default_factory=list)
    weight_at: list[str] = field(default_factory=list)
    knot_at: list[str] = field(default_factory=list)
    closing: int = 0  # G06.2 blocks holding only K seen so far
    last: _Line | None = None

    def add_point(self, line: _Line, point: NDArray[np.float64], weight: Word | None, knot: Word | None) -> None:
        self.points.append(point)
        self.weights.append(weight.value if weight else 1.0)
        self.point_at.append(line.where)
        self.weight_at.append(line.at(weight))
        if knot is not None:
            self.knots.append(knot.value)
            self.knot_at.append(line.at(knot))
        self.last = line

    def locate(self, problem: CurveProblem) -> str:
        places = {"control_points": self.point_at, "weights": self.weight_at, "knots": self.knot_at}.get(problem.field)
        if places and problem.index is not None and problem.index < len(places):
            return places[problem.index]
        return self.first.at(self.first.words.get("P" if self.kind == NURBS_FANUC else "L"))


class GcodeParser:
    """Reads one program; ``parse`` returns the Program or raises InputError."""

    def __init__(self, source: str, start_position: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        self.source = source
        start = np.asarray(start_position, dtype=float)
        if start.shape != (3,) or not np.all(np.isfinite(start)):
            raise InputError(f"{source}: start position", f"must be 3 finite numbers X Y Z in mm, got {start_position!r}")
        self.start = start
        self.position = self.start.copy()
        self.motion: int | None = None
        self.plane = 17
        self.absolute = True
        self.mm_per_unit = 1.0
        self.feed_mm_s: float | None = None
        self.nurbs: _Nurbs | None = None
        self.blocks: list[Block] = []

    # ---- driver ------------------------------------------------------------------------
    def parse(self, text: str) -> Program:
        for number, raw in enumerate(text.split("\n"), start=1):
            if self.read_line(number, raw):
                break
        if self.nurbs is not None:
            self.fail_unfinished_nurbs(None)
        name = Path(self.source).stem or self.source
        return Program(name, tuple(self.blocks), self.start.copy())

    def read_line(self, number: int, raw: str) -> bool:
        """Interpret one line; True when it ends the program (M02/M30)."""
        if not raw.strip() or raw.strip().startswith("%"):
            return False
        line = _Line(self.source, number, raw)
        self.sort_words(line, split_words(raw, line.where))
        motion = self.apply_g_codes(line)
        ends = self.apply_m_codes(line)
        if line.unsupported:
            w = line.unsupported[0]
            raise InputError(line.at(w), f"unsupported word {w.letter}")
        if motion is not None:
            self.change_motion(line, motion)
        self.apply_feed(line)
        self.move(line, motion)
        return ends

    def sort_words(self, line: _Line, words: Sequence[Word]) -> None:
        for w in words:
            if w.letter == "G":
                line.g_words.append(w)
            elif w.letter == "M":
                line.m_words.append(w)
            elif w.letter in IGNORED_LETTERS:
                continue
            elif w.letter in line.words:
                raise InputError(line.at(w), f"{w.letter} appears twice in one block")
            elif w.letter not in "XYZIJKRFPL":
                line.unsupported.append(w)
            else:
                line.words[w.letter] = w

    # ---- modal codes ------------------------------------------------------------------
    def apply_m_codes(self, line: _Line) -> bool:
        ends = False
        for w in line.m_words:
            code = int(w.value) if w.value == int(w.value) else -1
            if code in END_CODES:
                ends = True
            elif code not in IGNORED_M_CODES:
                raise InputError(line.at(w), f"unsupported M code {w.text}")
        return ends

    def apply_g_codes(self, line: _Line) -> int | None:
        """Set plane, units, distance mode; return this line's motion code, if any."""
        motion = None
        seen: dict[str, Word] = {}
        for w in line.g_words:
            code = round(w.value * 10)
            if abs(w.value * 10 - code) > 1e-6:
                raise InputError(line.at(w), f"unsupported G code {w.text}")
            group = ("motion" if code in MOTION_CODES else "plane" if code in PLANE_CODES else
                     "units" if code in UNIT_CODES else "distance" if code in DISTANCE_CODES else
                     "feed mode" if code in FEED_MODE_CODES else "none" if code in NO_OP_CODES else None)
            if group is None:
                raise InputError(line.at(w), f"unsupported G code {w.text}")
            if group in seen and group != "none":
                raise InputError(line.at(w), f"{w.text} and {seen[group].text} in one block: both set the {group}")
            seen[group] = w
            if group == "motion":
                motion = code
            elif group == "plane":
                self.plane = PLANE_CODES[code]
            elif group == "units":
                self.mm_per_unit = UNIT_CODES[code]
            elif group == "distance":
                self.absolute = DISTANCE_CODES[code]
        return motion

    def apply_feed(self, line: _Line) -> None:
        f = line.words.get("F")
        if f is None:
            return
        if f.value <= 0:
            raise InputError(line.at(f), f"feed must be > 0, got {f.value:g}")
        if self.nurbs is not None and self.nurbs.points:
            raise InputError(line.at(f), "F inside a NURBS definition: give the feed on its first block")
        self.feed_mm_s = f.value * self.mm_per_unit / 60.0

    def change_motion(self, line: _Line, motion: int) -> None:
        """A motion G code on this line: ends G06.2 mode; G5.2 ... G5.3 must be closed first."""
        word = next(w for w in line.g_words if round(w.value * 10) == motion)
        if self.nurbs is not None:
            if self.nurbs.kind == NURBS_LINUXCNC and motion != NURBS_LINUXCNC_END:
                raise InputError(line.at(word), f"{word.text} inside G5.2 (line {self.nurbs.first.number}): close the NURBS with G5.3 first")
            if self.nurbs.kind == NURBS_FANUC:
                self.fail_unfinished_nurbs(line, word)
        if motion == NURBS_LINUXCNC_END and (self.nurbs is None or self.nurbs.kind != NURBS_LINUXCNC):
            raise InputError(line.at(word), "G5.3 without an open G5.2")
        self.motion = motion

    # ---- moves ------------------------------------------------------------------------
    def move(self, line: _Line, motion_on_line: int | None) -> None:
        axis_words = {k: w for k, w in line.words.items() if k != "F"}
        if self.motion is None:
            if axis_words:
                w = next(iter(axis_words.values()))
                raise InputError(line.at(w), "no motion mode: give G00, G01, G02, G03, G06.2 or G5.2 first")
            return
        allowed = MOTION_WORDS[self.motion]
        for letter, w in axis_words.items():
            if letter not in allowed:
                raise InputError(line.at(w), f"{letter} not allowed in a {g_name(self.motion)} block")
        if not axis_words and motion_on_line is None and self.motion != NURBS_LINUXCNC_END:
            return
        handler = {RAPID: self.straight, LINE: self.straight, ARC_CW: self.arc, ARC_CCW: self.arc,
                   NURBS_FANUC: self.fanuc_nurbs, NURBS_LINUXCNC: self.linuxcnc_nurbs,
                   NURBS_LINUXCNC_END: self.linuxcnc_end}[self.motion]
        handler(line, motion_on_line is not None)

    def need_feed(self, line: _Line) -> float:
        if self.feed_mm_s is None:
            raise InputError(line.where, f"no feed rate: F missing for {g_name(self.motion or 0)}")
        return self.feed_mm_s

    def target(self, line: _Line, base: NDArray[np.float64], letters: str = "XYZ") -> NDArray[np.float64]:
        """Programmed point: G90 absolute or G91 relative to ``base``; missing axes keep base."""
        point = base.copy()
        for axis, letter in enumerate("XYZ"):
            w = line.words.get(letter)
            if w is not None and letter in letters:
                value = w.value * self.mm_per_unit
                point[axis] = value if self.absolute else base[axis] + value
        return point

    def add_block(self, kind: BlockKind, curve: NurbsCurve, feed_mm_s: float | None, line: _Line) -> None:
        self.blocks.append(Block(kind, curve, feed_mm_s, line.source))
        self.position = curve.end_point

    def straight(self, line: _Line, _explicit: bool) -> None:
        rapid = self.motion == RAPID
        feed = None if rapid else self.need_feed(line)
        end = self.target(line, self.position)
        if np.linalg.norm(end - self.position) <= ZERO_MOVE_MM:
            return
        self.add_block(BlockKind.RAPID if rapid else BlockKind.LINE, line_curve(self.position, end), feed, line)

    def arc(self, line: _Line, _explicit: bool) -> None:
        feed = self.need_feed(line)
        plane = PLANES[self.plane]
        clockwise = self.motion == ARC_CW
        start = self.position
        end = self.target(line, start)
        offsets = [line.words[k] for k in "IJK" if k in line.words]
        radius = line.words.get("R")
        for w in offsets:
            if w.letter not in plane.offset_letters:
                raise InputError(line.at(w), f"{w.letter} not allowed in a {plane.code} arc (centre offsets {' '.join(plane.offset_letters)})")
        if radius is not None and offsets:
            raise InputError(line.at(radius), "give either R or I J K for an arc, not both")
        gword = next((w for w in line.g_words if round(w.value * 10) == self.motion), None)
        try:
            if radius is not None:
                centre = centre_from_radius(plane, start, end, radius.value * self.mm_per_unit, clockwise, radius.text)
                curve = arc_nurbs(plane, start, end, centre, clockwise, full_circle_if_closed=False)
            elif offsets:
                centre = start.copy()
                for w in offsets:
                    centre["XYZ".index({"I": "X", "J": "Y", "K": "Z"}[w.letter])] += w.value * self.mm_per_unit
                curve = arc_nurbs(plane, start, end, centre, clockwise, full_circle_if_closed=True)
            else:
                raise ArcError(f"an arc needs centre offsets {' '.join(plane.offset_letters)} or a radius R", gword.text if gword else "")
        except ArcError as err:
            word = line.words[err.word].text if err.word in line.words else err.word
            word = word or " ".join(w.text for w in offsets) or (radius.text if radius else "")
            raise InputError(line.at(word), str(err)) from None
        self.add_block(BlockKind.ARC, curve, feed, line)

    # ---- Fanuc G06.2 ------------------------------------------------------------------
    def fanuc_nurbs(self, line: _Line, _explicit: bool) -> None:
        knot = line.words.get("K")
        if knot is None:
            raise InputError(line.where, "K missing: every G06.2 block gives one knot")
        if self.nurbs is None:
            self.start_fanuc_nurbs(line, knot)
            return
        nurbs = self.nurbs
        for letter in "PF":
            if letter in line.words:
                raise InputError(line.at(line.words[letter]), f"{letter} only allowed on the first block of a G06.2 NURBS")
        point_words = [line.words[k] for k in "XYZR" if k in line.words]
        if not point_words:
            nurbs.knots.append(knot.value)
            nurbs.knot_at.append(line.at(knot))
            nurbs.closing += 1
            nurbs.last = line
            if nurbs.closing == nurbs.order:
                self.finish_nurbs(BlockKind.NURBS)
            return
        if nurbs.closing:
            raise InputError(line.at(point_words[0]), f"control point after a closing K block: the last {nurbs.order} blocks hold only K")
        point = self.target(line, nurbs.points[-1])
        nurbs.add_point(line, point, line.words.get("R"), knot)

    def start_fanuc_nurbs(self, line: _Line, knot: Word) -> None:
        order = self.nurbs_order(line, line.words.get("P"), default=4)
        feed = self.need_feed(line)
        nurbs = _Nurbs(NURBS_FANUC, order, feed, line)
        first = self.target(line, self.position)
        if np.linalg.norm(first - self.position) > SAME_POSITION_MM:
            word = next(line.words[k] for k in "XYZ" if k in line.words)
            raise InputError(line.at(word), f"the first NURBS control point {_fmt(first)} must be the current position {_fmt(self.position)}")
        nurbs.add_point(line, self.position.copy(), line.words.get("R"), knot)
        self.nurbs = nurbs

    def nurbs_order(self, line: _Line, word: Word | None, default: int) -> int:
        if word is None:
            return default
        lo, hi = NURBS_ORDERS
        if word.value != int(word.value) or not lo <= word.value <= hi:
            raise InputError(line.at(word), f"NURBS order must be an integer from {lo} to {hi} (degree {lo - 1} to {hi - 1}), got {word.value:g}")
        return int(word.value)

    def fail_unfinished_nurbs(self, line: _Line | None, word: Word | None = None) -> None:
        nurbs = self.nurbs
        assert nurbs is not None
        if nurbs.kind == NURBS_LINUXCNC:
            where = (nurbs.last or nurbs.first).where
            raise InputError(where, f"G5.2 NURBS of line {nurbs.first.number} not closed with G5.3 at the end of the program")
        what = f"{word.text} ends" if word else "the program ends"
        where = line.at(word) if line else (nurbs.last or nurbs.first).where
        raise InputError(where, f"missing K blocks: {what} the NURBS of line {nurbs.first.number} after "
                                f"{nurbs.closing} of its {nurbs.order} closing K blocks")

    def finish_nurbs(self, kind: BlockKind) -> None:
        nurbs = self.nurbs
        assert nurbs is not None
        self.nurbs = None
        curve = build_curve(nurbs.order - 1, nurbs.points, nurbs.weights, nurbs.knots, nurbs.locate,
                            min_degree=NURBS_ORDERS[0] - 1, max_degree=NURBS_ORDERS[1] - 1, zero_length_mm=SAME_POSITION_MM)
        self.add_block(kind, curve, nurbs.feed_mm_s, nurbs.first)

    # ---- LinuxCNC G5.2 / G5.3 ---------------------------------------------------------
    def linuxcnc_nurbs(self, line: _Line, explicit: bool) -> None:
        if explicit:
            if self.plane != 17:
                word = next(w for w in line.g_words if round(w.value * 10) == NURBS_LINUXCNC)
                raise InputError(line.at(word), f"G5.2 works in the XY plane only (G17), not G{self.plane}")
            order = self.nurbs_order(line, line.words.get("L"), default=3)
            self.nurbs = _Nurbs(NURBS_LINUXCNC, order, self.need_feed(line), line)
            self.nurbs.add_point(line, self.position.copy(), None, None)
        elif "L" in line.words:
            raise InputError(line.at(line.words["L"]), "L only allowed on the G5.2 line")
        nurbs = self.nurbs
        assert nurbs is not None
        if "X" in line.words or "Y" in line.words:
            nurbs.add_point(line, self.target(line, nurbs.points[-1], "XY"), line.words.get("P"), None)
        elif "P" in line.words:
            raise InputError(line.at(line.words["P"]), "a weight P needs its control point X Y")

    def linuxcnc_end(self, line: _Line, explicit: bool) -> None:
        nurbs = self.nurbs
        assert nurbs is not None and explicit
        if len(nurbs.points) < nurbs.order:
            raise InputError(line.where, f"the G5.2 NURBS of line {nurbs.first.number} (order {nurbs.order}) needs at least "
                                         f"{nurbs.order} control points (the current position + {nurbs.order - 1} X Y lines), "
                                         f"got {len(nurbs.points)}")
        nurbs.knots = list(clamped_uniform_knots(len(nurbs.points), nurbs.order - 1))
        nurbs.knot_at = [line.where] * len(nurbs.knots)
        nurbs.last = line
        self.finish_nurbs(BlockKind.NURBS)
        self.motion = None


def _fmt(point: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in point) + ")"


def parse_gcode(text: str, source: str = "<gcode>", start_position: ArrayLike = (0.0, 0.0, 0.0)) -> Program:
    """Parse G-code text into a Program starting at ``start_position`` (machine XYZ, mm)."""
    return GcodeParser(source, start_position).parse(text)
