"""NURBS blocks of G-code: Fanuc G06.2 (and LinuxCNC's G6.2 dialect), LinuxCNC G5.2/G5.3.

A NURBS is collected block by block with the place of every value, then validated as a
whole (curve_check.build_curve: every problem, each on its line). Formats, in
docs/programs.md:

- G06.2 (Fanuc; LinuxCNC nc_files/nurbs/G6): first block ``G6.2 P<order> K X Y Z R [F] [Q]``
  at the current position, one block per control point with its knot K and weight R,
  then ``order`` blocks holding only K. LinuxCNC repeats ``G6.2`` on those blocks and
  gives Q (its interpolation method, 1-3: we interpolate the exact curve whatever Q).
- G5.2 ... G5.3 (LinuxCNC): ``G5.2 [X Y] [P] L<order>`` opens (without X Y, P is the weight
  of the current position, the first control point), ``X Y [P]`` lines add control
  points, ``G5.3`` closes; knots are clamped uniform. In G18/G19 the words are X Z / Y Z.

Orders 2 to 10 (degree 1 to 9) as LinuxCNC allows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.geometry import clamped_uniform_knots
from nurbsmotion.program.arcs import PLANES
from nurbsmotion.program.curve_check import CurveProblem, build_curve, decreasing_knot_problems, weight_problems
from nurbsmotion.program.gcode_words import Word
from nurbsmotion.program.model import BlockKind

if TYPE_CHECKING:
    from nurbsmotion.program.gcode_line import GcodeLine as _Line

NURBS_FANUC, NURBS_LINUXCNC, NURBS_LINUXCNC_END = 62, 52, 53
NURBS_ORDERS = (2, 10)  # G06.2 P and G5.2 L: order = degree + 1
SAME_POSITION_MM = 1e-6  # first NURBS control point vs current position
LINUXCNC_Q = (1, 3)


@dataclass
class _Nurbs:
    """A NURBS being collected block by block, with the place of every value."""

    kind: int  # NURBS_FANUC | NURBS_LINUXCNC
    order: int
    feed_mm_s: float | None
    first: "_Line"
    points: list[NDArray[np.float64]] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)
    knots: list[float] = field(default_factory=list)
    point_at: list[str] = field(default_factory=list)
    weight_at: list[str] = field(default_factory=list)
    knot_at: list[str] = field(default_factory=list)
    closing: int = 0  # G06.2 blocks holding only K seen so far
    last: "_Line | None" = None

    def add_point(self, line: "_Line", point: NDArray[np.float64], weight: Word | None, knot: Word | None,
                  default_weight: float = 1.0) -> None:
        self.points.append(point)
        self.weights.append(weight.value if weight else default_weight)
        self.point_at.append(line.where)
        self.weight_at.append(line.at(weight))
        if knot is not None:
            self.add_knot(line, knot)
        self.last = line

    def add_knot(self, line: "_Line", knot: Word) -> None:
        self.knots.append(knot.value)
        self.knot_at.append(line.at(knot))
        self.last = line

    def locate(self, problem: CurveProblem) -> str:
        places = {"control_points": self.point_at, "weights": self.weight_at, "knots": self.knot_at}.get(problem.field)
        if places and problem.index is not None and problem.index < len(places):
            return places[problem.index]
        return self.first.at(self.first.claimed.get("P") or self.first.words.get("P" if self.kind == NURBS_FANUC else "L"))


class NurbsReading:
    """The NURBS part of the G-code reader (mixed into GcodeParser)."""

    position: NDArray[np.float64]
    motion: int | None
    plane: int
    absolute: bool
    feed_mm_s: float | None
    # provided by GcodeParser
    target: Callable[..., NDArray[np.float64]]
    need_feed: Callable[["_Line"], float]
    add_block: Callable[..., None]

    def init_nurbs(self) -> None:
        self.nurbs: _Nurbs | None = None

    def change_motion(self, line: "_Line", motion: int) -> None:
        """A motion G code on this line: ends G06.2 mode (unless it is G6.2 again, LinuxCNC's
        closing blocks); G5.2 ... G5.3 must be closed first."""
        word = line.g(motion)
        nurbs = self.nurbs
        if nurbs is not None and motion != nurbs.kind:
            if nurbs.kind == NURBS_LINUXCNC and motion != NURBS_LINUXCNC_END:
                raise InputError(line.at(word), f"{word} inside G5.2 (line {nurbs.first.number}): close the NURBS with G5.3 first")
            if nurbs.kind == NURBS_FANUC:
                self.fail_unfinished_nurbs(line, word)
        if motion == NURBS_LINUXCNC_END and (nurbs is None or nurbs.kind != NURBS_LINUXCNC):
            raise InputError(line.at(word), "G5.3 without an open G5.2")
        self.motion = motion

    # ---- Fanuc G06.2 ------------------------------------------------------------------
    def fanuc_nurbs(self, line: "_Line", _explicit: bool) -> None:
        knot = line.words.get("K")
        if knot is None:
            raise InputError(line.where, "K missing: every G06.2 block gives one knot")
        if self.nurbs is None:
            self.start_fanuc_nurbs(line, knot)
            return
        nurbs = self.nurbs
        for letter in "PFQ":
            w = line.words.get(letter) or line.claimed.get(letter)
            if w is not None:
                raise InputError(line.at(w), f"{letter} only allowed on the first block of a G06.2 NURBS")
        point_words = [line.words[k] for k in "XYZR" if k in line.words]
        if not point_words:
            nurbs.add_knot(line, knot)
            nurbs.closing += 1
            if nurbs.closing == nurbs.order:
                self.finish_nurbs()
            return
        if nurbs.closing:
            raise InputError(line.at(point_words[0]), f"control point after a closing K block: the last {nurbs.order} blocks hold only K")
        point = self.target(line, nurbs.points[-1])
        nurbs.add_point(line, point, line.words.get("R"), knot)

    def start_fanuc_nurbs(self, line: "_Line", knot: Word) -> None:
        order = self.nurbs_order(line, line.words.get("P"), default=4)
        q = line.words.get("Q")
        if q is not None and (q.value != int(q.value) or not LINUXCNC_Q[0] <= q.value <= LINUXCNC_Q[1]):
            raise InputError(line.at(q), f"G6.2 Q (LinuxCNC's interpolation method) must be 1, 2 or 3, got {q.value:g}")
        nurbs = _Nurbs(NURBS_FANUC, order, self.feed_mm_s, line)
        first = self.target(line, self.position)
        if np.linalg.norm(first - self.position) > SAME_POSITION_MM:
            word = next(line.words[k] for k in "XYZ" if k in line.words)
            raise InputError(line.at(word), f"the first NURBS control point {_fmt(first)} must be the current position {_fmt(self.position)}")
        nurbs.add_point(line, self.position.copy(), line.words.get("R"), knot)
        self.nurbs = nurbs
        self.need_feed(line)  # after opening it: without F the rest of the NURBS is still read (one error)

    def nurbs_order(self, line: "_Line", word: Word | None, default: int) -> int:
        if word is None:
            return default
        lo, hi = NURBS_ORDERS
        if word.value != int(word.value) or not lo <= word.value <= hi:
            raise InputError(line.at(word), f"NURBS order must be an integer from {lo} to {hi} (degree {lo - 1} to {hi - 1}), got {word.value:g}")
        return int(word.value)

    def fail_unfinished_nurbs(self, line: "_Line | None", word: Word | None = None) -> None:
        """The NURBS is cut short: say so, together with the problems of the values read so far."""
        nurbs = self.nurbs
        assert nurbs is not None
        self.nurbs = None
        if nurbs.points:
            self.position = nurbs.points[-1]
        if nurbs.kind == NURBS_LINUXCNC:
            where = (nurbs.last or nurbs.first).where
            structural = InputError(where, f"G5.2 NURBS of line {nurbs.first.number} not closed with G5.3 at the end of the program")
        else:
            what = f"{word.text} ends" if word else "the program ends"
            where = line.at(word) if line else (nurbs.last or nurbs.first).where
            structural = InputError(where, f"missing K blocks: {what} the NURBS of line {nurbs.first.number} after "
                                           f"{nurbs.closing} of its {nurbs.order} closing K blocks")
        values = weight_problems(nurbs.weights, len(nurbs.weights)) + decreasing_knot_problems(nurbs.knots)
        errors = [InputError(nurbs.locate(p), p.message) for p in values]
        raise InputErrors(errors + [structural]) if errors else structural

    def finish_nurbs(self) -> None:
        nurbs = self.nurbs
        assert nurbs is not None
        self.nurbs = None
        self.position = nurbs.points[-1]
        curve = build_curve(nurbs.order - 1, nurbs.points, nurbs.weights, nurbs.knots, nurbs.locate,
                            min_degree=NURBS_ORDERS[0] - 1, max_degree=NURBS_ORDERS[1] - 1, zero_length_mm=SAME_POSITION_MM)
        self.add_block(BlockKind.NURBS, curve, nurbs.feed_mm_s, nurbs.first)

    # ---- LinuxCNC G5.2 / G5.3 ---------------------------------------------------------
    def plane_letters(self) -> str:
        return "".join("XYZ"[a] for a in sorted(PLANES[self.plane].axes))

    def linuxcnc_nurbs(self, line: "_Line", explicit: bool) -> None:
        letters = self.plane_letters()
        point_given = any(k in line.words for k in letters)
        weight = line.words.get("P")
        if self.nurbs is None:
            order = self.nurbs_order(line, line.words.get("L"), default=3)
            self.nurbs = _Nurbs(NURBS_LINUXCNC, order, self.feed_mm_s, line)
            first_weight = weight if not point_given else None  # 'G5.2 P1 L3': P weighs the current position
            self.nurbs.add_point(line, self.position.copy(), first_weight, None)
            if not point_given:
                self.need_feed(line)  # after opening it: without F the rest of the NURBS is still read (one error)
                return
        elif "L" in line.words:
            raise InputError(line.at(line.words["L"]), "L only allowed on the G5.2 line")
        nurbs = self.nurbs
        if point_given:
            point = self.target(line, nurbs.points[-1], letters)
            if len(nurbs.points) == 1 and np.linalg.norm(point - nurbs.points[0]) <= SAME_POSITION_MM:
                word = " ".join(line.words[k].text for k in letters if k in line.words)
                raise InputError(line.at(word), "this point repeats the current position, which G5.2 already takes as its first "
                                                "control point: the curve would stop dead at its start (zero speed); leave it out")
            nurbs.add_point(line, point, weight, None)
        elif weight is not None:
            raise InputError(line.at(weight), f"a weight P needs its control point {' '.join(letters)}")
        if explicit and nurbs.first is line:
            self.need_feed(line)

    def linuxcnc_end(self, line: "_Line", explicit: bool) -> None:
        nurbs = self.nurbs
        assert nurbs is not None and explicit
        if len(nurbs.points) < nurbs.order:
            self.nurbs = None
            self.position = nurbs.points[-1]
            self.motion = None
            raise InputError(line.where, f"the G5.2 NURBS of line {nurbs.first.number} (order {nurbs.order}) needs at least "
                                         f"{nurbs.order} control points (the current position + {nurbs.order - 1} more), "
                                         f"got {len(nurbs.points)}")
        nurbs.knots = list(clamped_uniform_knots(len(nurbs.points), nurbs.order - 1))
        nurbs.knot_at = [line.where] * len(nurbs.knots)
        nurbs.last = line
        self.motion = None
        self.finish_nurbs()


def _fmt(point: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in point) + ")"
