"""G-code reader: RS274NGC as LinuxCNC runs it, plus Fanuc G06.2 NURBS -> Program.

The accepted language, with every error, is described in docs/programs.md. The text is
lexed line by line (gcode_words), O-word constructs are paired (owords), then the lines
run in program order with a modal state, ``#`` parameters and a call stack. Each line
follows RS274NGC's order of execution (LinuxCNC "G-code overview", Order of Execution):
F, S, T, M6/M61, M3-M5, M7-M9, M62-M65 (digital output P), G4, plane, units, G43/G49, G54-G59.3, G61/G64, G90/G91,
G10/G28/G30/G92, motion (G53 applies to it), M0/M1/M2/M30.

Every problem is reported (up to ``ReadOptions.max_errors``), one line each, in line
order: a bad line is skipped and reading goes on. Positions in the Program are machine
coordinates: work offsets, G92 and tool length offsets are applied here.

The reader is one class from parts: this module (driver, words, modal codes, events),
gcode_moves (G0-G3 blocks, G53), gcode_machine (S, T, M6, M3-M9, M62-M65, G4, G43),
gcode_flow (O-word flow), gcode_offsets (G10/G28/G30/G92/G43.1), gcode_nurbs (G6.2,
G5.2/G5.3), gcode_modal (M70-M73), gcode_start (start line), gcode_fast (plain move
lines); gcode_line is the evaluated line they share.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.program.coordinates import CoordinateState, Offsets
from nurbsmotion.program.expressions import ExpressionError, Number
from nurbsmotion.program.gcode_fast import FastLines, lines_lexed_first
from nurbsmotion.program.gcode_flow import OwordRunning, _Frame, lines_is_loop_body
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_machine import MachineCommands
from nurbsmotion.program.gcode_modal import ModalSnapshot, ModalStateCommands
from nurbsmotion.program.gcode_moves import ARC_CCW, ARC_CW, LINE, RAPID, MoveBuilding
from nurbsmotion.program.gcode_nurbs import NURBS_FANUC, NURBS_LINUXCNC, NURBS_LINUXCNC_END, NurbsReading
from nurbsmotion.program.gcode_offsets import OffsetCommands
from nurbsmotion.program.gcode_start import StartLineReading
from nurbsmotion.program.gcode_words import LexedLine, RawWord, Word, check_number, lex_line
from nurbsmotion.program.model import (CoolantMode, EventKind, Program, ProgramEvent, ReadExtent,
                                       SpindleDirection)
from nurbsmotion.program.owords import Flow, index_owords
from nurbsmotion.program.parameters import ParameterStore
from nurbsmotion.program.records import RecordsBuilder, SourceText
from nurbsmotion.program.tools import ToolTable

MM_PER_INCH = 25.4

# G codes as round(10 * value)
G_GROUPS: dict[int, str] = {
    RAPID: "motion", LINE: "motion", ARC_CW: "motion", ARC_CCW: "motion",
    NURBS_FANUC: "motion", NURBS_LINUXCNC: "motion", NURBS_LINUXCNC_END: "motion",
    170: "plane", 180: "plane", 190: "plane", 200: "units", 210: "units",
    900: "distance", 910: "distance", 901: "arc distance", 911: "arc distance", 940: "feed mode",
    400: "cutter compensation", 430: "tool length", 431: "tool length", 490: "tool length",
    540: "coordinate system", 550: "coordinate system", 560: "coordinate system", 570: "coordinate system",
    580: "coordinate system", 590: "coordinate system", 591: "coordinate system", 592: "coordinate system",
    593: "coordinate system", 610: "path control", 611: "path control", 640: "path control",
    980: "retract mode", 990: "retract mode", 800: "canned cycle", 960: "spindle mode", 970: "spindle mode",
    40: "non-modal", 100: "non-modal", 280: "non-modal", 281: "non-modal", 300: "non-modal", 301: "non-modal",
    530: "non-modal", 920: "non-modal", 921: "non-modal", 922: "non-modal", 923: "non-modal",
}
UNSUPPORTED_G = {
    50: "cubic spline G5", 51: "quadratic spline G5.1", 70: "lathe diameter mode", 80: "lathe radius mode",
    330: "spindle-synchronised motion", 331: "rigid tapping", 382: "probing", 383: "probing", 384: "probing",
    385: "probing", 410: "cutter radius compensation", 411: "cutter radius compensation",
    420: "cutter radius compensation", 421: "cutter radius compensation", 432: "additional tool length offset",
    520: "local coordinate offset", 730: "canned cycle", 760: "threading cycle", 930: "inverse time feed",
    950: "feed per revolution", 150: "polar coordinates",
    160: "polar coordinates", 680: "coordinate rotation", 690: "coordinate rotation", 500: "scaling", 510: "scaling",
    **{c: "canned cycle" for c in range(810, 900, 10)},
}
SYSTEM_CODES = {540: 1, 550: 2, 560: 3, 570: 4, 580: 5, 590: 6, 591: 7, 592: 8, 593: 9}
AXIS_USERS = {100: "G10", 280: "G28", 300: "G30", 920: "G92", 431: "G43.1"}  # use the block's axis words
M_GROUPS = {0: "stopping", 1: "stopping", 2: "stopping", 30: "stopping", 6: "tool change", 61: "tool change",
            70: "modal state", 71: "modal state", 72: "modal state", 73: "modal state",
            3: "spindle", 4: "spindle", 5: "spindle", 7: "coolant", 8: "coolant", 9: "coolant",
            62: "digital output", 63: "digital output", 64: "digital output", 65: "digital output"}
END_CODES = {2, 30}
ROTARY_LETTERS = "ABCUVW"
WORD_LETTERS = "XYZIJKRFPLQSTHND"
@dataclass
class ReadOptions:
    """What a G-code reader starts from besides the text (all optional).

    ``coordinates``: work offsets, G92 and G28/G30 positions in effect at the start (the
    service passes the persisted ones; Program.coordinates are those at the end).
    ``tool_in_spindle``: the tool the machine holds (M6 of that tool then needs no hold).
    ``spindle`` / ``spindle_rpm``: the spindle as the machine runs it (an earlier MDI's M3):
    an ``S`` alone then changes its speed, as in LinuxCNC, where the modal state carries over.
    ``start_line`` / ``safe_z_mm``: start from that line, approaching it over ``safe_z_mm``
    (program.gcode_start); the Program's ``resume`` then holds the state at that line.
    """

    tool_table: ToolTable | None = None
    coordinates: CoordinateState | None = None
    tool_in_spindle: int | None = None
    spindle: SpindleDirection = SpindleDirection.OFF
    spindle_rpm: float = 0.0
    block_delete: bool = True  # '/' lines are skipped (the switch on)
    optional_stop: bool = True  # M1 pauses like M0 (the switch on)
    max_errors: int = 50
    max_loop_lines: int = 1_000_000  # lines run beyond the file's length (loops, calls): more is an endless loop
    start_line: int | None = None  # start from this line (program.gcode_start); None: from the first
    safe_z_mm: float | None = None  # machine Z the approach to the start line rises to (-inf: no rise)


class _Stop(Exception):
    """Too many problems: stop reading."""


class GcodeParser(MoveBuilding, MachineCommands, NurbsReading, OwordRunning, OffsetCommands, ModalStateCommands,
                  StartLineReading, FastLines):
    """Reads one program; ``parse`` returns the Program or raises InputError(s).

    ``fast_lines``: plain move lines take gcode_fast's path (False: every line is lexed and
    run by the general path, the fast path's oracle)."""

    fast_lines = True

    def __init__(self, source: str, start_position: ArrayLike = (0.0, 0.0, 0.0), options: ReadOptions | None = None) -> None:
        self.source = source
        self.options = options or ReadOptions()
        start = np.asarray(start_position, dtype=float)
        if start.shape != (3,) or not np.all(np.isfinite(start)):
            raise InputError(f"{source}: start position", f"must be 3 finite numbers X Y Z in mm, got {start_position!r}")
        self.start = start
        self.position = self.start.copy()
        self.motion: int | None = None
        self.plane = 17
        self.absolute = True
        self.arc_absolute = False  # G90.1 / G91.1 (default): I J K relative to the start
        self.mm_per_unit = 1.0
        self.feed_mm_s: float | None = None
        self.offsets = Offsets.from_state(self.options.coordinates or CoordinateState())
        self.exact_stop_mode = False
        self.blend_tolerance_mm: float | None = None
        self.smoothing_tolerance_mm: float | None = None  # G64 Q (0: Q0, no smoothing; None: the machine's)
        self.tool_selected: int | None = None
        self.tool_loaded: int | None = self.options.tool_in_spindle
        self.spindle = self.options.spindle
        self.spindle_rpm = self.options.spindle_rpm
        self.constant_surface_speed = False  # G96: S is a surface speed (G97: rpm)
        self.coolant: set[CoolantMode] = set()
        self.saved_states: list[ModalSnapshot | None] = [None]  # M70 per call level
        self.frames: list[_Frame] = []
        self.blocks = RecordsBuilder(source, self.line_text)
        self.raw_lines: list[str] = []
        self.events: list[ProgramEvent] = []
        self.params = ParameterStore(self.system_parameter)
        self.errors: list[tuple[int, InputError]] = []
        self.lines: list[LexedLine | InputError | str] = []  # str: a plain line for gcode_fast, lexed if it must be
        self.words_read: dict[str, RawWord] = {}  # the program's plain words, shared between its lines
        self.top_repeats: dict[int, int] = {}
        self.ended: tuple[int, str] | None = None  # (line, 'M30' / 'M2' / '%'): where reading ended early
        self.end_word = ""  # the program end of the last line run, as 'M30' / 'M2'
        self.init_nurbs()
        self.init_start_line()

    # ---- driver ------------------------------------------------------------------------
    def parse(self, text: str) -> Program:
        text = text.removeprefix("\ufeff")  # a byte-order mark (Windows editors, CAM posts) is not part of line 1
        self.raw_lines = text.split("\n")
        self.lines = lines = self.lex(self.raw_lines, text)
        flow, structure = index_owords([ln if isinstance(ln, LexedLine) else None for ln in lines], self.source)
        if not structure:
            self.check_start_line_place(flow, len(lines) - (1 if text.endswith("\n") else 0))  # as editors count
        try:
            for err in structure:  # the program cannot run: say so, with every unreadable line
                self.record(err_line(err), err)
            for number, line in enumerate(lines, start=1):
                if structure and isinstance(line, str):
                    line = self.lex_one(number, line)
                if structure and isinstance(line, InputError):
                    self.record(number, line)
            if not structure:
                self.run(lines, flow)
        except _Stop:
            pass
        if self.errors:
            raise self.collected_errors()
        self.check_start_line_reached()
        name = Path(self.source).stem or self.source
        return Program(name, self.blocks.build(SourceText.of(text)), self.start.copy(), tuple(self.events), self.offsets.state(),
                       self.tool_loaded, self.start_line.state if self.start_line is not None else None,
                       read_extent(lines, self.ended, text.endswith("\n")))

    def lex(self, raw_lines: list[str], text: str) -> list[LexedLine | InputError | str]:
        """Every line lexed, except those that may be plain move lines (made only of their
        characters, gcode_fast.lines_lexed_first): kept as their text, lexed only if the general path
        must run them (lex_one). The lines to lex are found by one scan of the whole text."""
        if not self.fast_lines:
            return [self.lex_one(number, raw) for number, raw in enumerate(raw_lines, start=1)]
        lines: list[LexedLine | InputError | str] = list(raw_lines)
        for index in lines_lexed_first(text):
            lines[index] = self.lex_one(index + 1, raw_lines[index])
        return lines

    def lex_one(self, number: int, raw: str) -> LexedLine | InputError:
        try:
            return lex_line(number, raw, self.source, self.words_read)
        except InputError as err:
            return err

    def line_text(self, number: int) -> str:
        """Line ``number`` (1-based) of the text being read, as written."""
        return self.raw_lines[number - 1] if 1 <= number <= len(self.raw_lines) else ""

    def record(self, number: int, err: InputError) -> None:
        for e in getattr(err, "errors", [err]):
            if not any(e.where == old.where and e.message == old.message for _, old in self.errors):
                self.errors.append((err_line(e) or number, e))
        if len(self.errors) >= self.options.max_errors:
            raise _Stop

    def collected_errors(self) -> InputError:
        ordered = [e for _, e in sorted(self.errors, key=lambda item: item[0])][: self.options.max_errors]
        if len(self.errors) >= self.options.max_errors:
            ordered.append(InputError(self.source, f"stopped after {self.options.max_errors} problems; fix these and check again"))
        return ordered[0] if len(ordered) == 1 else InputErrors(ordered)

    def run(self, lines: list[LexedLine | InputError | str], flow: Flow) -> None:
        """Run the lines in program order (O-word jumps and calls); stop at M2/M30 or a closing '%'."""
        frames = self.frames
        first = next((ln for ln in lines if not (isinstance(ln, LexedLine) and ln.empty)), None)
        percent_ends = isinstance(first, LexedLine) and first.percent
        seen_percent = False
        pc, executed, looped_to = 0, 0, 0
        while pc < len(lines):
            line = lines[pc]
            executed += 1
            if self.skipping:
                try:
                    self.arrive_at(pc)
                except InputError as err:
                    self.record(pc + 1, err)
                    raise _Stop from None
            if executed > len(lines) + self.options.max_loop_lines:
                number = looped_to + 1  # the line the last backward jump went to: the loop's head
                self.record(number, InputError(f"{self.source}:{number}", f"more than {self.options.max_loop_lines:,} lines run in loops and calls: "
                                                                        f"an O-word loop that never ends?"))
                raise _Stop
            if isinstance(line, str):
                if self.fast_ready():
                    after = self.run_fast(lines, pc, min(len(lines), pc + 1 + len(lines) + self.options.max_loop_lines - executed))
                    if after > pc:
                        executed += after - pc - 1
                        pc = after
                        continue
                line = self.lex_one(pc + 1, line)
            if isinstance(line, InputError):
                self.record(pc + 1, line)
                pc += 1
                continue
            if line.percent:
                if percent_ends and seen_percent:
                    self.ended = (line.number, "%")
                    break
                seen_percent = True
                pc += 1
                continue
            if line.empty or (line.block_delete and self.options.block_delete) or line.program_number is not None:
                pc += 1
                continue
            try:
                if line.oword is not None:
                    after = self.run_oword(pc, line, flow, frames)
                    if after <= pc:
                        looped_to = after - 1 if lines_is_loop_body(after, flow) else after
                    pc = after
                    continue
                if self.run_line(line):
                    self.ended = (line.number, self.end_word)
                    if self.start_line is not None:
                        self.start_line.ended_at = line.number
                    break
            except InputError as err:
                self.params.discard()
                self.record(line.number, err)
                self.recover_position(line)
                pc = self.after_failed(pc, line, flow)
                continue
            pc += 1
        if self.ended is None and pc < len(lines):  # no other way out of the loop: a reader bug, never a shorter program
            self.record(pc + 1, InputError(f"{self.source}:{pc + 1}", "reading stopped here without M2, M30 or a closing %: "
                                                                     "the program would be cut short (a reader bug)"))
        if self.nurbs is not None:
            try:
                self.fail_unfinished_nurbs(None)
            except InputError as err:
                self.record(err_line(err), err)

    def recover_position(self, lexed: LexedLine) -> None:
        """After a bad move line, go on from where it was meant to end (fewer follow-on errors)."""
        if self.nurbs is not None or self.motion not in (RAPID, LINE, ARC_CW, ARC_CCW) or lexed.oword is not None:
            return
        line = GcodeLine(self.source, lexed.number, lexed.text)
        for raw in lexed.words:
            if raw.letter in "XYZ":
                try:
                    line.words[raw.letter] = Word(raw.letter, self.evaluate(raw.expr, ""), raw.text)
                except InputError:
                    return
        self.position = self.target(line, self.position)

    def evaluate(self, expr: object, where: str) -> float:
        try:
            value = expr.evaluate(self.params)  # type: ignore[attr-defined]
        except ExpressionError as err:
            raise InputError(where, str(err)) from None
        if not np.isfinite(value):
            raise InputError(where, "the value is not finite")
        return float(value)

    def system_parameter(self, key: int | str) -> float | None:
        """LinuxCNC's read-only parameters: offsets #5161-#5390, tool #5400, position #5420-#5422, #<_x> ..."""
        if isinstance(key, int):
            if 5420 <= key <= 5422:
                return float(self.program_position()[key - 5420])
            if key == 5400:
                return float(self.tool_loaded or 0)
            if key >= 5161:
                return self.offsets.parameter(key)
            return None
        if not key.startswith("_"):  # a program's own named parameter
            return None
        named: dict[str, Callable[[], float]] = {
            "_x": lambda: float(self.program_position()[0]), "_y": lambda: float(self.program_position()[1]),
            "_z": lambda: float(self.program_position()[2]),
            "_metric": lambda: float(self.mm_per_unit == 1.0), "_imperial": lambda: float(self.mm_per_unit != 1.0),
            "_absolute": lambda: float(self.absolute), "_incremental": lambda: float(not self.absolute),
            "_feed": lambda: (self.feed_mm_s or 0.0) * 60.0 / self.mm_per_unit, "_rpm": lambda: self.spindle_rpm,
            "_current_tool": lambda: float(self.tool_loaded or 0), "_selected_tool": lambda: float(self.tool_selected or -1),
            "_coord_system": lambda: float(next(c for c, s in SYSTEM_CODES.items() if s == self.offsets.active)),
        }
        return named[key]() if key in named else None

    def program_position(self) -> NDArray[np.float64]:
        """Where the tool is in the program's coordinates and units (offsets removed)."""
        return (self.position - self.offsets.total()) / self.mm_per_unit

    # ---- one line ----------------------------------------------------------------------
    def run_line(self, lexed: LexedLine) -> bool:
        """Interpret one line in RS274NGC order; True when it ends the program (M02/M30)."""
        line = GcodeLine(self.source, lexed.number, lexed.text)
        self.sort_words(line, self.evaluate_words(lexed, line))
        for a in lexed.assignments:
            where = line.at(a.text)
            try:
                self.params.stage(a.target.resolve(self.params), self.evaluate(a.expr, where))
            except ExpressionError as err:
                raise InputError(where, str(err)) from None
        groups = self.group_g_codes(line)
        if "D" in line.words:
            raise InputError(line.at(line.words["D"]), "unsupported word D (cutter radius compensation)")
        m_codes = self.group_m_codes(line)
        self.apply_modes(line, groups)
        self.apply_feed(line)
        self.apply_spindle_speed(line, "spindle" in m_codes)
        self.apply_tool(line, m_codes)
        self.apply_modal_state(line, m_codes.get("modal state"), self.frames[-1].autorestore if self.frames else [None])
        self.apply_spindle_and_coolant(line, m_codes)
        self.apply_digital_output(line, m_codes.get("digital output"), groups)
        self.apply_dwell(line, groups)
        self.apply_tool_length(line, groups.get("tool length"))
        self.apply_path_control(line, groups.get("path control"))
        axis_user = self.axis_user(line, groups)
        motion = groups.get("motion")
        if motion is not None:
            self.change_motion(line, round(motion.value * 10))
        self.check_leftover_words(line, axis_user is not None)
        if axis_user is not None:
            self.run_axis_user(line, axis_user)
        else:
            self.move_with_g53(line, motion is not None, groups.get("non-modal"))
        self.params.commit()
        return self.apply_stop(line, m_codes)

    def evaluate_words(self, lexed: LexedLine, line: GcodeLine) -> list[Word]:
        words = []
        for raw in lexed.words:
            if isinstance(raw.expr, Number):  # checked by the lexer
                words.append(Word(raw.letter, raw.expr.value, raw.text))
                continue
            value = self.evaluate(raw.expr, line.at(raw.text))
            check_number(value, raw.letter, raw.text[1:], line.where)
            words.append(Word(raw.letter, value, raw.text))
        return words

    def sort_words(self, line: GcodeLine, words: list[Word]) -> None:
        for w in words:
            if w.letter == "G":
                line.g_words.append(w)
            elif w.letter == "M":
                line.m_words.append(w)
            elif w.letter == "N":
                continue
            elif w.letter in ROTARY_LETTERS:
                raise InputError(line.at(w), f"unsupported: axis {w.letter} (this machine has X Y Z)")
            elif w.letter not in WORD_LETTERS:
                raise InputError(line.at(w), f"unsupported word {w.letter}")
            elif w.letter in line.words:
                raise InputError(line.at(w), f"{w.letter} appears twice in one block")
            else:
                line.words[w.letter] = w

    def group_g_codes(self, line: GcodeLine) -> dict[str, Word]:
        seen: dict[str, Word] = {}
        for w in line.g_words:
            code = round(w.value * 10)
            group = G_GROUPS.get(code) if abs(w.value * 10 - code) <= 1e-6 else None
            if group is None:
                what = UNSUPPORTED_G.get(code) if abs(w.value * 10 - code) <= 1e-6 else None
                raise InputError(line.at(w), f"unsupported G code {w.text}" + (f" ({what})" if what else ""))
            if group in seen:
                raise InputError(line.at(w), f"{w.text} and {seen[group].text} in one block: both set the {group}")
            seen[group] = w
        return seen

    def group_m_codes(self, line: GcodeLine) -> dict[str, Word]:
        seen: dict[str, Word] = {}
        for w in line.m_words:
            code = int(w.value) if w.value == int(w.value) else -1
            group = M_GROUPS.get(code)
            if group is None:
                raise InputError(line.at(w), f"unsupported M code {w.text}")
            if group in seen and not (group == "coolant" and {code, int(seen[group].value)} == {7, 8}):
                raise InputError(line.at(w), f"{w.text} and {seen[group].text} in one block: both set the {group}")
            seen[group if group not in seen else group + " 2"] = w
        return seen

    # ---- modal codes ------------------------------------------------------------------
    def apply_modes(self, line: GcodeLine, groups: dict[str, Word]) -> None:
        """Plane, units, distance modes, coordinate system (they apply before F and the move)."""
        for group, w in groups.items():
            code = round(w.value * 10)
            if group == "plane":
                if self.nurbs is not None and self.plane != code // 10:
                    raise InputError(line.at(w), f"{w.text} inside the NURBS of line {self.nurbs.first.number}")
                self.plane = code // 10
            elif group == "units":
                self.mm_per_unit = MM_PER_INCH if code == 200 else 1.0
            elif group == "distance":
                self.absolute = code == 900
            elif group == "arc distance":
                self.arc_absolute = code == 901
            elif group == "coordinate system":
                self.offsets.active = SYSTEM_CODES[code]
            elif group == "spindle mode":
                self.constant_surface_speed = code == 960

    def apply_feed(self, line: GcodeLine) -> None:
        f = line.claim("F").get("F")
        if f is None:
            return
        if f.value <= 0:
            raise InputError(line.at(f), f"feed must be > 0, got {f.value:g}")
        if self.nurbs is not None and self.nurbs.points:
            raise InputError(line.at(f), "F inside a NURBS definition: give the feed on its first block")
        self.feed_mm_s = f.value * self.mm_per_unit / 60.0

    def apply_path_control(self, line: GcodeLine, g: Word | None) -> None:
        if g is None:
            return
        code = round(g.value * 10)
        self.exact_stop_mode = code in (610, 611)
        if code != 640:
            return
        words = line.claim("PQ")
        p, q = words.get("P"), words.get("Q")
        for w in (p, q):
            if w is not None and w.value < 0:
                raise InputError(line.at(w), f"G64 {w.letter} is a tolerance: >= 0, got {w.value:g}")
        self.blend_tolerance_mm = p.value * self.mm_per_unit if p is not None and p.value > 0 else None  # P0: no limit
        self.smoothing_tolerance_mm = q.value * self.mm_per_unit if q is not None else None

    def axis_user(self, line: GcodeLine, groups: dict[str, Word]) -> Word | None:
        """G10/G28/G30/G92/G43.1 take the axis words; a motion G code with them is an error."""
        users = [w for w in (groups.get("non-modal"), groups.get("tool length")) if w is not None and round(w.value * 10) in AXIS_USERS]
        if not users:
            return None
        user = users[0]
        motion = groups.get("motion")
        if motion is not None:
            raise InputError(line.at(motion), f"{motion.text} and {user.text} in one block: both use the axis words")
        return user

    def check_leftover_words(self, line: GcodeLine, axis_user: bool) -> None:
        """Words no code of this block uses (the motion's are checked by move)."""
        if axis_user:
            return
        if self.motion is None:
            leftover = [w for k, w in line.words.items() if k != "F"]
            if leftover:
                w = leftover[0]
                if w.letter in "XYZ":
                    raise InputError(line.at(w), "no motion mode: give G00, G01, G02, G03, G06.2 or G5.2 first")
                raise InputError(line.at(w), f"{w.letter} is not used by any code of this block")

    def apply_stop(self, line: GcodeLine, m_codes: dict[str, Word]) -> bool:
        m = m_codes.get("stopping")
        if m is None:
            return False
        code = int(m.value)
        if code in END_CODES:
            self.end_word = f"M{code}"
            return True
        if code == 0 or self.options.optional_stop:
            self.add_event(line, EventKind.PAUSE, m.text)
        return False

    def add_event(self, line: GcodeLine, kind: EventKind, code: str, **values: object) -> None:
        if self.nurbs is not None:
            raise InputError(line.at(code), f"{code} inside the NURBS of line {self.nurbs.first.number}: "
                                            f"finish the NURBS first")
        if self.skipping:  # before the start line: its state counts, not the event
            return
        event = ProgramEvent(kind, len(self.blocks), line.source, code, **values)  # type: ignore[arg-type]
        self.events.append(event)
        if event.stops_motion and len(self.blocks) and not self.blocks.last_exact_stop:
            self.blocks.mark_exact_stop_last()


def err_line(err: InputError) -> int:
    parts = err.where.split(":")
    try:
        return int(parts[1].split()[0]) if len(parts) > 1 else 0
    except ValueError:
        return 0


def parse_gcode(text: str, source: str = "<gcode>", start_position: ArrayLike = (0.0, 0.0, 0.0),
                options: ReadOptions | None = None) -> Program:
    """Parse G-code text into a Program starting at ``start_position`` (machine XYZ, mm)."""
    return GcodeParser(source, start_position, options).parse(text)


def read_extent(lines: list[LexedLine | InputError | str], ended: tuple[int, str] | None, final_newline: bool) -> ReadExtent:
    """The lines read of the file's: to its end, or to the M2/M30 or closing % that ``ended``
    it, with the lines after that which hold anything (never run: LinuxCNC ignores them)."""
    total = len(lines) - (1 if final_newline else 0)  # 'a\nb\n' splits into 3: two lines
    last, by = ended if ended is not None else (total, "end of file")
    not_read = sum(1 for ln in lines[last:total] if isinstance(ln, (InputError, str)) or not (ln.empty or ln.percent))
    return ReadExtent(total, last, by, not_read)
