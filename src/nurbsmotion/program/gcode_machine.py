"""The machine's codes of a G-code line, in RS274NGC's order of execution: S, T, M6/M61,
M3-M5, M7-M9, M62-M65 (digital output P), G4, G43/G49 (LinuxCNC "M-codes", "G-codes").

``MachineCommands`` (mixed into GcodeParser) keeps the spindle, tool and coolant state and
turns each code into the Program's events (SPINDLE, TOOL_CHANGE, COOLANT, OUTPUT, DWELL).
"""

from __future__ import annotations

from typing import Any, Callable

from nurbsmotion.errors import InputError
from nurbsmotion.program.coordinates import Offsets
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_words import Word
from nurbsmotion.program.model import CoolantMode, EventKind, SpindleDirection


class MachineCommands:
    """The spindle, tool, coolant, output and dwell part of the G-code reader (mixed into
    GcodeParser)."""

    options: Any  # ReadOptions
    offsets: Offsets
    tool_selected: int | None
    tool_loaded: int | None
    spindle: SpindleDirection
    spindle_rpm: float
    constant_surface_speed: bool
    coolant: set[CoolantMode]
    add_event: Callable[..., None]  # provided by GcodeParser

    def apply_spindle_speed(self, line: GcodeLine, spindle_code_on_line: bool) -> None:
        s = line.claim("S").get("S")
        if s is None:
            return
        if s.value < 0:
            raise InputError(line.at(s), f"spindle speed must be >= 0, got {s.value:g}")
        changed = s.value != self.spindle_rpm
        self.spindle_rpm = s.value
        if changed and self.spindle is not SpindleDirection.OFF and not spindle_code_on_line:
            self.add_event(line, EventKind.SPINDLE, s.text, spindle=self.spindle, spindle_rpm=self.spindle_rpm,
                           constant_surface_speed=self.constant_surface_speed)

    def tool_number(self, line: GcodeLine, w: Word) -> int:
        if w.value != int(w.value) or w.value < 0:
            raise InputError(line.at(w), f"a tool number is a whole number >= 0, got {w.value:g}")
        number = int(w.value)
        table = self.options.tool_table
        if table is not None and number != 0 and table.get(number) is None:
            raise InputError(line.at(w), f"tool {number} is not in the tool table {table.source}")
        return number

    def apply_tool(self, line: GcodeLine, m_codes: dict[str, Word]) -> None:
        t = line.claim("T").get("T")
        if t is not None:
            self.tool_selected = self.tool_number(line, t)
        m = m_codes.get("tool change")
        if m is None:
            return
        if int(m.value) == 61:
            q = line.claim("Q").get("Q")
            if q is None:
                raise InputError(line.at(m), "M61 needs Q (the tool now in the spindle)")
            self.tool_loaded = self.tool_number(line, q)
            return
        tool = self.tool_selected if self.tool_selected is not None else 0
        if tool != self.tool_loaded:
            self.add_event(line, EventKind.TOOL_CHANGE, m.text, tool=tool)
        self.tool_loaded = tool

    def apply_spindle_and_coolant(self, line: GcodeLine, m_codes: dict[str, Word]) -> None:
        m = m_codes.get("spindle")
        if m is not None:
            self.spindle = {3: SpindleDirection.CW, 4: SpindleDirection.CCW, 5: SpindleDirection.OFF}[int(m.value)]
            self.add_event(line, EventKind.SPINDLE, m.text, spindle=self.spindle,
                           spindle_rpm=None if self.spindle is SpindleDirection.OFF else self.spindle_rpm,
                           constant_surface_speed=self.constant_surface_speed)
        for key in ("coolant", "coolant 2"):
            m = m_codes.get(key)
            if m is not None:
                mode = {7: CoolantMode.MIST, 8: CoolantMode.FLOOD, 9: CoolantMode.OFF}[int(m.value)]
                self.coolant = set() if mode is CoolantMode.OFF else self.coolant | {mode}
                self.add_event(line, EventKind.COOLANT, m.text, coolant=mode)

    def apply_digital_output(self, line: GcodeLine, m: Word | None, groups: dict[str, Word]) -> None:
        """LinuxCNC's M62/M63 (output P on/off with the next motion) and M64/M65 (at once): an
        OUTPUT event; P is the output's bit in the io node's outputs (0x6200)."""
        if m is None:
            return
        g = groups.get("non-modal")
        if g is not None and round(g.value * 10) == 40:
            raise InputError(line.at(m), "takes P, and so does the G4 on this line: write them on two lines")
        p = line.claim("P").get("P")
        if p is None:
            raise InputError(line.at(m), "needs P: the output number")
        if p.value != int(p.value) or p.value < 0:
            raise InputError(line.at(p), f"an output number is a whole number >= 0, got {p.value:g}")
        code = int(m.value)
        self.add_event(line, EventKind.OUTPUT, m.text, output=int(p.value), output_on=code in (62, 64),
                       output_synchronized=code in (62, 63))

    def apply_dwell(self, line: GcodeLine, groups: dict[str, Word]) -> None:
        g = groups.get("non-modal")
        if g is None or round(g.value * 10) != 40:
            return
        if "X" in line.words and "motion" not in groups:  # Fanuc's 'G04 X1.5': would move the modal motion here
            raise InputError(line.at(line.words["X"]), "G4 takes P, the dwell in seconds (Fanuc's G04 X is not read)")
        p = line.claim("P").get("P")
        if p is None:
            raise InputError(line.at(g), "G4 needs P: the dwell time in seconds")
        if p.value < 0:
            raise InputError(line.at(p), f"dwell time must be >= 0 s, got {p.value:g}")
        self.add_event(line, EventKind.DWELL, g.text, dwell_s=p.value)

    def apply_tool_length(self, line: GcodeLine, g: Word | None) -> None:
        if "H" in line.words and (g is None or round(g.value * 10) != 430):
            raise InputError(line.at(line.words["H"]), "H without G43 (tool length offset from the tool table)")
        if g is None:
            return
        code = round(g.value * 10)
        if code == 490:
            self.offsets.tool_length_mm = 0.0
        elif code == 430:
            h = line.claim("H").get("H")
            number = self.tool_number(line, h) if h is not None else (self.tool_loaded or 0)
            table = self.options.tool_table
            if number != 0 and table is None:
                raise InputError(line.at(h or g), f"G43 needs a tool table for tool {number} (none given)")
            self.offsets.tool_length_mm = table.length_mm(number) if table is not None else 0.0
