"""O-word program flow (LinuxCNC "O Codes"): the structure of sub/if/while/do/repeat.

``index_owords`` pairs every O-word line with its partners before the program runs, the
way LinuxCNC requires them: the same label opens and closes a construct
(``o100 if`` ... ``o100 elseif`` ... ``o100 else`` ... ``o100 endif``; ``o101 while``
... ``o101 endwhile``; ``o102 do`` ... ``o102 while``; ``o103 repeat [n]`` ...
``o103 endrepeat``; ``o<name> sub`` ... ``o<name> endsub``), ``break``/``continue``
name their loop's label and ``return`` lies inside a ``sub``. The interpreter then jumps
by these indices.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from nurbsmotion.errors import InputError
from nurbsmotion.program.gcode_words import LexedLine, OWord

OPENERS = {"sub": "endsub", "if": "endif", "while": "endwhile", "do": "while", "repeat": "endrepeat"}
LOOPS = ("while", "do", "repeat")


@dataclass
class Construct:
    """One sub/if/loop: the line that opens it, its branch lines and the line that closes it."""

    kind: str  # sub | if | while | do | repeat
    label: int | str
    start: int
    branches: list[int] = field(default_factory=list)  # elseif / else lines of an if
    end: int = -1


@dataclass
class Flow:
    constructs: dict[int, Construct] = field(default_factory=dict)  # any member line -> its construct
    subs: dict[int | str, Construct] = field(default_factory=dict)
    loop_of: dict[int, Construct] = field(default_factory=dict)  # break/continue line -> its loop
    in_sub: set[int] = field(default_factory=set)  # return lines inside a sub


def _name(label: int | str) -> str:
    return f"o{label}" if isinstance(label, int) else f"o<{label}>"


def index_owords(lines: list[LexedLine | None], source: str) -> tuple[Flow, list[InputError]]:
    """Pair the O-word lines; errors for every line that does not fit."""
    flow = Flow()
    errors: list[InputError] = []
    stack: list[Construct] = []

    def fail(i: int, o: OWord, message: str) -> None:
        errors.append(InputError(f"{source}:{lines[i].number}: {o.text}", message))  # type: ignore[union-attr]

    for i, line in enumerate(lines):
        if line is None or line.oword is None:
            continue
        o = line.oword
        top = stack[-1] if stack else None
        same = top is not None and top.label == o.label
        if o.keyword == "while" and same and top is not None and top.kind == "do":
            top.end = i
            flow.constructs[i] = stack.pop()
        elif o.keyword in OPENERS:
            if o.keyword == "sub" and any(c.kind == "sub" for c in stack):
                fail(i, o, "a sub cannot be defined inside another sub")
            c = Construct(o.keyword, o.label, i)
            stack.append(c)
            flow.constructs[i] = c
            if o.keyword == "sub":
                if o.label in flow.subs:
                    fail(i, o, f"{_name(o.label)} sub is defined twice")
                flow.subs[o.label] = c
        elif o.keyword in ("elseif", "else"):
            if not (same and top is not None and top.kind == "if"):
                fail(i, o, f"{o.keyword} without an open {_name(o.label)} if")
            else:
                top.branches.append(i)
                flow.constructs[i] = top
        elif o.keyword in OPENERS.values():
            if not same or top is None or OPENERS[top.kind] != o.keyword:
                fail(i, o, f"{o.keyword} does not close an open {_name(o.label)} "
                           f"{next(k for k, v in OPENERS.items() if v == o.keyword)}")
            else:
                top.end = i
                flow.constructs[i] = stack.pop()
        elif o.keyword in ("break", "continue"):
            loop = next((c for c in reversed(stack) if c.label == o.label and c.kind in LOOPS), None)
            if loop is None:
                fail(i, o, f"{o.keyword} outside an {_name(o.label)} loop (while, do or repeat)")
            else:
                flow.loop_of[i] = loop
        elif o.keyword == "return":  # LinuxCNC returns from the innermost sub whatever the label
            if not any(c.kind == "sub" for c in stack):
                fail(i, o, "return outside a sub")
            else:
                flow.in_sub.add(i)
    for c in stack:
        line = lines[c.start]
        assert line is not None and line.oword is not None
        fail(c.start, line.oword, f"{_name(c.label)} {c.kind} is never closed with {_name(c.label)} {OPENERS[c.kind]}")
    return flow, errors
