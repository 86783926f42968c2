"""G10 L2/L20, G28/G30 (and .1), G92 (and .1/.2/.3), G43.1: codes that use the axis words
without moving along them, or change the offsets between program and machine coordinates
(LinuxCNC "Coordinate Systems", G10, G28, G30, G92; coordinates.py holds the state).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.program.coordinates import Offsets
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_words import Word

_NurbsState = Any


class OffsetCommands:
    """The offset part of the G-code reader (mixed into GcodeParser)."""

    offsets: Offsets
    position: NDArray[np.float64]
    mm_per_unit: float
    nurbs: _NurbsState

    # provided by GcodeParser
    target: Callable[..., NDArray[np.float64]]
    add_straight: Callable[..., None]

    def apply_stored_offsets(self, code: int | None) -> None:
        """G28.1/G30.1 store the position; G92.1 clears, G92.2 suspends, G92.3 restores G92."""
        if code in (281, 301):
            (self.offsets.g28 if code == 281 else self.offsets.g30)[:] = self.position
        elif code == 921:
            self.offsets.g92, self.offsets.g92_applied = np.zeros(3), False
        elif code == 922:
            self.offsets.g92_applied = False
        elif code == 923:
            self.offsets.g92_applied = True

    def axis_values_mm(self, line: GcodeLine) -> dict[int, float]:
        words = line.claim("XYZ")
        return {"XYZ".index(k): w.value * self.mm_per_unit for k, w in words.items()}

    def run_axis_user(self, line: GcodeLine, g: Word) -> None:
        code = round(g.value * 10)
        if code == 100:
            self.set_work_offset(line, g)
        elif code in (280, 300):
            self.go_home(line, g, self.offsets.g28 if code == 280 else self.offsets.g30)
        elif code == 920:
            values = self.axis_values_mm(line)
            if not values:
                raise InputError(line.at(g), "G92 needs at least one axis word: the current position's new coordinates")
            base = self.offsets.work[self.offsets.active - 1] + np.array([0.0, 0.0, self.offsets.tool_length_mm])
            if not self.offsets.g92_applied:
                self.offsets.g92 = np.zeros(3)
            for axis, value in values.items():
                self.offsets.g92[axis] = self.position[axis] - base[axis] - value
            self.offsets.g92_applied = True
        elif code == 431:
            values = self.axis_values_mm(line)
            if set(values) != {2}:
                raise InputError(line.at(g), "G43.1 takes one Z word: the tool length offset (X and Y offsets: unsupported)")
            self.offsets.tool_length_mm = values[2]
        self.check_unused(line, g)

    def check_unused(self, line: GcodeLine, g: Word) -> None:
        leftover = [w for k, w in line.words.items() if k != "F"]
        if leftover:
            raise InputError(line.at(leftover[0]), f"{leftover[0].letter} not allowed with {g.text}")

    def set_work_offset(self, line: GcodeLine, g: Word) -> None:
        words = line.claim("LPR")
        l, p, r = words.get("L"), words.get("P"), words.get("R")
        if l is None or l.value not in (2, 20):
            raise InputError(line.at(l or g), "unsupported: G10 " + (f"L{l.value:g}" if l else "without L")
                             + " (only L2 and L20 set work offsets; the tool table is edited outside the program)")
        if p is None or p.value != int(p.value) or not 0 <= p.value <= 9:
            raise InputError(line.at(p or g), "G10 L2/L20 needs P0 (the active system) or P1..P9 (G54..G59.3)")
        if r is not None and r.value != 0:
            raise InputError(line.at(r), "unsupported: coordinate system rotation (G10 R)")
        system = int(p.value) or self.offsets.active
        offset = self.offsets.work[system - 1].copy()
        others = (self.offsets.g92 if self.offsets.g92_applied else 0.0) + np.array([0.0, 0.0, self.offsets.tool_length_mm])
        for axis, value in self.axis_values_mm(line).items():
            offset[axis] = value if l.value == 2 else self.position[axis] - others[axis] - value
        self.offsets.work[system - 1] = offset

    def go_home(self, line: GcodeLine, g: Word, stored: NDArray[np.float64]) -> None:
        """G28/G30: rapid through the programmed point (if any) to the stored position of those axes."""
        if self.nurbs is not None:
            raise InputError(line.at(g), f"{g.text} inside the NURBS of line {self.nurbs.first.number}")
        words = {k: line.words[k] for k in "XYZ" if k in line.words}
        home = stored.copy()
        if words:
            via = self.target(line, self.position)
            line.claim("XYZ")
            self.add_straight(line, via, rapid=True)
            home = self.position.copy()
            for k in words:
                home["XYZ".index(k)] = stored["XYZ".index(k)]
        self.add_straight(line, home, rapid=True)

