"""Running O-word flow (LinuxCNC "O Codes"): conditions, loops, calls and returns.

owords.index_owords pairs the lines before the program runs; ``OwordRunning`` (mixed into
GcodeParser) decides, line by line, where the program goes next.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from nurbsmotion.errors import InputError
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_words import LexedLine, OWord
from nurbsmotion.program.owords import Flow
from nurbsmotion.program.parameters import ParameterStore

MAX_CALL_DEPTH = 100


@dataclass
class _Frame:
    return_pc: int
    label: int | str
    repeats: dict[int, int] = field(default_factory=dict)
    autorestore: list = field(default_factory=lambda: [None])  # M73's saved state, restored on return



def lines_is_loop_body(index: int, flow: Flow) -> bool:
    """A backward jump to the first line of a do/repeat body: its head is the line before."""
    c = flow.constructs.get(index - 1)
    return c is not None and c.start == index - 1 and c.kind in ("do", "repeat")



class OwordRunning:
    """The O-word part of the G-code reader (mixed into GcodeParser)."""

    source: str
    lines: list[LexedLine | InputError | str]  # str: a plain line (gcode_fast)
    params: ParameterStore
    top_repeats: dict[int, int]

    saved_states: list  # M70 states per call level (gcode_modal)
    # provided by GcodeParser
    evaluate: Callable[[object, str], float]
    restore: Callable[..., None]

    @staticmethod
    def after_failed(pc: int, line: LexedLine, flow: Flow) -> int:
        """Where to go on after a bad line: past the construct a bad if/while/repeat opens."""
        c = flow.constructs.get(pc)
        if line.oword is not None and c is not None and c.start == pc and c.kind in ("if", "while", "repeat"):
            return c.end + 1
        return pc + 1

    def condition(self, line: LexedLine, o: OWord) -> float:
        if len(o.args) != 1:
            raise InputError(f"{self.source}:{line.number}: {o.text}", f"{o.keyword} needs one [condition]")
        return self.evaluate(o.args[0], f"{self.source}:{line.number}: {o.text}")

    def run_oword(self, pc: int, line: LexedLine, flow: Flow, frames: list[_Frame]) -> int:
        """Next line to run after O-word line ``pc``."""
        o = line.oword
        assert o is not None
        c = flow.constructs.get(pc)
        k = o.keyword
        if k == "sub":
            assert c is not None
            return c.end + 1  # a definition met in the flow is skipped
        if k in ("endsub", "return"):
            return self.leave_sub(line, o, frames, pc)
        if k == "call":
            return self.call(pc, line, o, flow, frames)
        if k == "if":
            assert c is not None
            if self.condition(line, o):
                return pc + 1
            for branch in c.branches:
                b = self.oword_at(branch)
                if b.keyword == "else":
                    return branch + 1
                if self.condition(self.lexed_at(branch), b):
                    return branch + 1
            return c.end + 1
        if k in ("elseif", "else"):
            assert c is not None
            return c.end + 1  # the branch before was taken
        if k == "endif" or k == "do":
            return pc + 1
        if k == "while":
            assert c is not None
            if c.kind == "do":  # closes a do: loop back while true
                return c.start + 1 if self.condition(line, o) else pc + 1
            return pc + 1 if self.condition(line, o) else c.end + 1
        if k == "endwhile":
            assert c is not None
            return c.start
        if k == "repeat":
            assert c is not None
            if len(o.args) != 1:
                raise InputError(f"{self.source}:{line.number}: {o.text}", "repeat needs one [count]")
            count = round(self.evaluate(o.args[0], f"{self.source}:{line.number}: {o.text}"))
            repeats = frames[-1].repeats if frames else self.top_repeats
            repeats[pc] = count
            return pc + 1 if count > 0 else c.end + 1
        if k == "endrepeat":
            assert c is not None
            repeats = frames[-1].repeats if frames else self.top_repeats
            repeats[c.start] = repeats.get(c.start, 1) - 1
            return c.start + 1 if repeats[c.start] > 0 else pc + 1
        loop = flow.loop_of[pc]
        closing = loop.end
        if k == "break":
            return closing + 1
        return loop.start if loop.kind == "while" else closing  # continue

    def lexed_at(self, index: int) -> LexedLine:
        line = self.lines[index]
        assert isinstance(line, LexedLine)
        return line

    def oword_at(self, index: int) -> OWord:
        o = self.lexed_at(index).oword
        assert o is not None
        return o

    def call(self, pc: int, line: LexedLine, o: OWord, flow: Flow, frames: list[_Frame]) -> int:
        where = f"{self.source}:{line.number}: {o.text}"
        sub = flow.subs.get(o.label)
        if sub is None:
            raise InputError(where, f"unsupported: O-word call of {o.name}: no {o.name} sub in this file "
                                    f"(subroutine files are not read)")
        if len(frames) >= MAX_CALL_DEPTH:
            raise InputError(where, f"calls nested deeper than {MAX_CALL_DEPTH}: endless recursion?")
        args = [self.evaluate(a, where) for a in o.args]
        self.params.enter_call(args)
        self.saved_states.append(None)
        frames.append(_Frame(pc + 1, o.label))
        return sub.start + 1

    def leave_sub(self, line: LexedLine, o: OWord, frames: list[_Frame], pc: int) -> int:
        where = f"{self.source}:{line.number}: {o.text}"
        value = self.evaluate(o.args[0], where) if o.args else None
        if not frames:
            raise InputError(where, f"{o.keyword} of {o.name} reached without a call")
        frame = frames.pop()
        self.params.leave_call()
        self.saved_states.pop()
        if frame.autorestore[0] is not None:
            self.restore(GcodeLine(self.source, line.number, line.text), "M73", frame.autorestore[0])
        if value is not None:
            self.params.set_now("_value", value)
        return frame.return_pc

