"""Motion blocks of G-code: G00/G01 lines, G02/G03 arcs (G53 for a straight move), each a
block of the Program in machine mm (LinuxCNC "G-codes" G0, G1, G2/G3, G53).

``MoveBuilding`` (mixed into GcodeParser) checks the motion words of a line, computes the
programmed target (G90 absolute plus the offsets, or G91 relative) and adds the block; the
NURBS motions are gcode_nurbs', which it dispatches to.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import ArcShape, LineShape
from nurbsmotion.program.arcs import PLANES, ArcError, arc_shape, centre_from_radius
from nurbsmotion.program.coordinates import Offsets
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_nurbs import NURBS_FANUC, NURBS_LINUXCNC, NURBS_LINUXCNC_END
from nurbsmotion.program.gcode_words import Word
from nurbsmotion.program.model import BlockKind

# The arc builder every G02/G03 goes through, by this name: an ArcShape (a NurbsCurve is
# taken too: tests/program/test_arcs.py puts the NURBS oracle in its place).
arc_nurbs: Callable[..., ArcShape | NurbsCurve] = arc_shape
ZERO_MOVE_MM = 1e-9  # shorter G00/G01 moves are skipped

# G codes as round(10 * value)
RAPID, LINE, ARC_CW, ARC_CCW = 0, 10, 20, 30
MOTION_WORDS = {
    RAPID: "XYZ", LINE: "XYZ", ARC_CW: "XYZIJKRP", ARC_CCW: "XYZIJKRP",
    NURBS_FANUC: "KXYZRPQ", NURBS_LINUXCNC: "XYZPL", NURBS_LINUXCNC_END: "",
}
G_NAMES = {RAPID: "G00", LINE: "G01", ARC_CW: "G02", ARC_CCW: "G03", NURBS_FANUC: "G06.2",
           NURBS_LINUXCNC: "G5.2", NURBS_LINUXCNC_END: "G5.3"}


def g_name(code: int) -> str:
    return G_NAMES.get(code, f"G{code / 10:g}")


class MoveBuilding:
    """The motion part of the G-code reader (mixed into GcodeParser)."""

    position: NDArray[np.float64]
    motion: int | None
    plane: int
    absolute: bool
    arc_absolute: bool
    mm_per_unit: float
    feed_mm_s: float | None
    offsets: Offsets
    blocks: Any  # program.records.RecordsBuilder
    exact_stop_mode: bool
    blend_tolerance_mm: float | None
    smoothing_tolerance_mm: float | None

    # provided by GcodeParser's other parts
    apply_stored_offsets: Callable[[int | None], None]
    fanuc_nurbs: Callable[[GcodeLine, bool], None]
    linuxcnc_nurbs: Callable[[GcodeLine, bool], None]
    linuxcnc_end: Callable[[GcodeLine, bool], None]

    if TYPE_CHECKING:
        @property
        def skipping(self) -> bool: ...

    def move_with_g53(self, line: GcodeLine, motion_on_line: bool, non_modal: Word | None) -> None:
        code = round(non_modal.value * 10) if non_modal is not None else None
        self.apply_stored_offsets(code)
        if code != 530:
            self.move(line, motion_on_line)
            return
        assert non_modal is not None
        if self.motion not in (RAPID, LINE):
            raise InputError(line.at(non_modal), "G53 needs G0 or G1 (machine coordinates for a straight move)")
        if not self.absolute:
            raise InputError(line.at(non_modal), "G53 needs G90: machine coordinates are absolute")
        self.offsets.machine_mode = True
        try:
            self.move(line, motion_on_line)
        finally:
            self.offsets.machine_mode = False

    def move(self, line: GcodeLine, motion_on_line: bool) -> None:
        axis_words = {k: w for k, w in line.words.items() if k != "F"}
        if self.motion is None:
            return
        allowed = MOTION_WORDS[self.motion]
        for letter, w in axis_words.items():
            if letter not in allowed or (self.motion == NURBS_LINUXCNC and letter == "XYZ"[PLANES[self.plane].normal_axis]):
                raise InputError(line.at(w), f"{letter} not allowed in a {g_name(self.motion)} block")
        if not motion_on_line and (not axis_words or self.motion == NURBS_LINUXCNC_END):
            return
        handler = {RAPID: self.straight, LINE: self.straight, ARC_CW: self.arc, ARC_CCW: self.arc,
                   NURBS_FANUC: self.fanuc_nurbs, NURBS_LINUXCNC: self.linuxcnc_nurbs,
                   NURBS_LINUXCNC_END: self.linuxcnc_end}[self.motion]
        handler(line, motion_on_line)

    def need_feed(self, line: GcodeLine) -> float:
        if self.feed_mm_s is None:
            raise InputError(line.where, f"no feed rate: F missing for {g_name(self.motion or 0)}")
        return self.feed_mm_s

    def target(self, line: GcodeLine, base: NDArray[np.float64], letters: str = "XYZ") -> NDArray[np.float64]:
        """Programmed point in machine mm: G90 absolute (+ offsets) or G91 relative to ``base``."""
        point = base.copy()
        offset = self.offsets.total()
        for axis, letter in enumerate("XYZ"):
            w = line.words.get(letter)
            if w is not None and letter in letters:
                value = w.value * self.mm_per_unit
                point[axis] = value + offset[axis] if self.absolute else base[axis] + value
        return point

    def add_block(self, kind: BlockKind, shape: NurbsCurve | LineShape | ArcShape, feed_mm_s: float | None,
                  line: GcodeLine) -> None:
        if not self.skipping:  # before the start line: only where the move ends counts
            self.blocks.add(kind, shape, feed_mm_s, line.source, self.exact_stop_mode, self.blend_tolerance_mm,
                            self.smoothing_tolerance_mm)
        self.position = shape.end_point if isinstance(shape, NurbsCurve) else shape.end.copy()

    def arcs_batched(self) -> bool:
        """gcode_fast computes arcs a run at a time (arcs.arc_geometry, as arc_shape) when the
        reader's arc builder is arc_shape; another (a test's oracle) takes every arc itself."""
        return arc_nurbs is arc_shape

    def add_straight(self, line: GcodeLine, end: NDArray[np.float64], rapid: bool) -> None:
        feed = None if rapid else self.need_feed(line)
        if math.dist(end.tolist(), self.position.tolist()) <= ZERO_MOVE_MM:
            return
        if self.skipping:  # before the start line: no curve to build, only where it ends
            self.position = end
            return
        self.add_block(BlockKind.RAPID if rapid else BlockKind.LINE, LineShape(self.position, end), feed, line)

    def straight(self, line: GcodeLine, _explicit: bool) -> None:
        self.add_straight(line, self.target(line, self.position), rapid=self.motion == RAPID)

    def arc(self, line: GcodeLine, _explicit: bool) -> None:
        feed = self.need_feed(line)
        plane = PLANES[self.plane]
        clockwise = self.motion == ARC_CW
        start = self.position
        end = self.target(line, start)
        offsets = [line.words[k] for k in "IJK" if k in line.words]
        radius = line.words.get("R")
        turns = line.words.get("P")
        for w in offsets:
            if w.letter not in plane.offset_letters:
                raise InputError(line.at(w), f"{w.letter} not allowed in a {plane.code} arc (centre offsets {' '.join(plane.offset_letters)})")
        if radius is not None and offsets:
            raise InputError(line.at(radius), "give either R or I J K for an arc, not both")
        if turns is not None and (turns.value != int(turns.value) or turns.value < 1):
            raise InputError(line.at(turns), f"P (turns) must be a whole number >= 1, got {turns.value:g}")
        inch = self.mm_per_unit != 1.0
        start_xyz, end_xyz = start.tolist(), end.tolist()  # plain floats: arcs.py computes on them
        try:
            if radius is not None:
                centre = centre_from_radius(plane, start_xyz, end_xyz, radius.value * self.mm_per_unit, clockwise, radius.text)
                shape = arc_nurbs(plane, start_xyz, end_xyz, centre, clockwise, False, inch, int(turns.value) if turns else 1)
            elif offsets:
                centre = start_xyz.copy()
                origin = self.offsets.total().tolist() if self.arc_absolute else None
                for w in offsets:
                    axis = "IJK".index(w.letter)
                    value = w.value * self.mm_per_unit
                    centre[axis] = value + origin[axis] if origin is not None else start_xyz[axis] + value
                shape = arc_nurbs(plane, start_xyz, end_xyz, centre, clockwise, True, inch, int(turns.value) if turns else 1)
            else:
                gword = line.g(self.motion or 0)
                raise ArcError(f"an arc needs centre offsets {' '.join(plane.offset_letters)} or a radius R", gword.text if gword else "")
        except ArcError as err:
            self.position = end  # the next line starts where this one was meant to end
            word = line.words[err.word].text if err.word in line.words else err.word
            word = word or " ".join(w.text for w in offsets) or (radius.text if radius else "")
            raise InputError(line.at(word), str(err)) from None
        self.add_block(BlockKind.ARC, shape, feed, line)
