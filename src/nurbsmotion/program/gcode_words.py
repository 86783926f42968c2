"""G-code lexing: one line of text -> its words, parameter assignments and O-word.

RS274NGC (LinuxCNC "G-code overview" §2-§4): letters are case-insensitive and spaces and
tabs count nowhere outside comments, so ``G 0 1 X 1 0`` is ``G01 X10``. A word is a letter
and a value: a number ``[+-]digits[.digits]`` (with an optional exponent ``1e3``), a
``#`` parameter, a ``[...]`` expression or a function (expressions.py). ``( ... )``
comments (not nested) and ``;`` comments to the end of the line are removed. A ``/`` first
on the line marks it for block delete. ``#n = value`` assigns a parameter. A line starting
with ``O`` is an O-word (``o100 if [...]``, ``o<name> sub``) or, alone, a program number.
Values stay unevaluated (parameters change while the program runs). Anything else is an
error naming the offending text as written.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import cached_property

from nurbsmotion.errors import InputError
from nurbsmotion.program.expressions import Expr, ExpressionError, Number, ParamRef, read_parameter, read_value

MAX_ABS_VALUE = 1e9  # larger numbers are typos; keeps arc arithmetic far from overflow
O_KEYWORDS = ("endsub", "sub", "call", "return", "elseif", "else", "endif", "if", "endwhile", "while", "do",
              "break", "continue", "endrepeat", "repeat")
_O_LABEL = re.compile(r"o(\d+|<[^<>]*>)")
_PLAIN_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?")
_LINE_NUMBER = re.compile(r"n\d+(?:\.\d*)?")
# The common line, in one match: an optional line number, then only words of a letter and a
# plain number, each number followed by the next letter or the end. Atomic number and
# possessive line number take exactly what read_item's greedy _PLAIN_NUMBER match and
# lex_line's line-number skip take (no backtracking into another split of the same text);
# any other line goes through read_item.
_PLAIN_WORD = r"([a-z])((?>[+-]?(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?))"
_PLAIN_LINE = re.compile(rf"(?:n\d+(?:\.\d*)?)?+(?:{_PLAIN_WORD})*")
_PLAIN_WORDS = re.compile(_PLAIN_WORD)


@dataclass(frozen=True)
class Word:
    """An evaluated word: ``letter`` upper case, ``text`` as written (spaces removed)."""

    letter: str
    value: float
    text: str

    def __str__(self) -> str:
        return self.text


@dataclass(frozen=True)
class RawWord:
    """A word as read: its value may still depend on parameters."""

    letter: str
    expr: Expr
    text: str


@dataclass(frozen=True)
class Assignment:
    target: ParamRef
    expr: Expr
    text: str


@dataclass(frozen=True)
class OWord:
    """``o<label> <keyword> [args]``; label is an int or a lower-case name."""

    label: int | str
    keyword: str
    args: tuple[Expr, ...]
    text: str

    @property
    def name(self) -> str:
        return f"o{self.label}" if isinstance(self.label, int) else f"o<{self.label}>"


@dataclass
class LexedLine:
    number: int
    text: str
    block_delete: bool = False
    words: list[RawWord] = field(default_factory=list)
    assignments: list[Assignment] = field(default_factory=list)
    oword: OWord | None = None
    program_number: int | None = None
    percent: bool = False
    empty: bool = False


def strip_comments(text: str, where: str) -> str:
    """Remove ``( ... )`` and ``; ...`` comments; an unclosed ``(`` is an error."""
    if "(" not in text and ")" not in text:
        return text.split(";", 1)[0]
    out = []
    i = 0
    while i < len(text):
        ch = text[i]
        if ch == ";":
            break
        if ch == "(":
            end = text.find(")", i + 1)
            if end < 0:
                raise InputError(where, "comment '(' is not closed with ')' on the same line")
            if "(" in text[i + 1:end]:
                raise InputError(where, "nested comments are not supported")
            out.append(" ")
            i = end + 1
            continue
        if ch == ")":
            raise InputError(where, "')' without an opening '('")
        out.append(ch)
        i += 1
    return "".join(out)


class _Text:
    """A line's code without spaces, lower case, remembering where each character was."""

    def __init__(self, body: str) -> None:
        self.body = body
        self.raw = "".join(body.split())  # as written, spaces removed: same positions as code
        self.code = self.raw.lower()

    @cached_property
    def origin(self) -> list[int]:
        return [i for i, ch in enumerate(self.body) if not ch.isspace()]

    def written(self, start: int, end: int) -> str:
        """The text as written between two code positions, spaces removed."""
        return self.raw[start:end] if end > start else ""

    def token_at(self, pos: int) -> str:
        """The written text from ``pos`` to the next space (for 'got ...' messages)."""
        if pos >= len(self.origin):
            return ""
        return self.body[self.origin[pos]:].split()[0]


def check_number(value: float, letter: str, raw: str, where: str) -> float:
    """Non-finite and absurdly large values are errors naming the word."""
    word = f"{where}: {letter}{raw}"
    if not math.isfinite(value):
        raise InputError(word, f"number {raw!r} is not finite")
    if abs(value) > MAX_ABS_VALUE:
        raise InputError(word, f"number {raw!r} is out of range (|value| <= {MAX_ABS_VALUE:g})")
    return value


def lex_line(number: int, raw: str, source: str, words_read: dict[str, RawWord] | None = None) -> LexedLine:
    """Lex one line; InputError (file:line: text) for anything that is not G-code.

    ``words_read``: the plain words of the program's earlier lines, by text (read_plain_words
    shares them and adds this line's); None: every word is built anew."""
    where = f"{source}:{number}"
    line = LexedLine(number, raw)
    stripped = raw.strip()
    if not stripped:
        line.empty = True
        return line
    if stripped.startswith("%"):
        if stripped != "%":  # LinuxCNC: "Bad character '%' used"; taken as the tape end it cut the program
            raise InputError(f"{where}: {stripped}", "a '%' line is the tape mark and holds nothing else "
                                                    f"(as a comment: ({stripped[1:].strip()}))")
        line.percent = True
        return line
    if stripped.startswith("/"):
        line.block_delete = True
        raw = raw.replace("/", " ", 1)
    text = _Text(strip_comments(raw, where))
    if not text.code:
        line.empty = True
        return line
    pos = 0
    if text.code.startswith("n"):  # line number first: skip it (also allowed elsewhere)
        m = _LINE_NUMBER.match(text.code)
        if m:
            pos = m.end()
    if text.code.startswith("o", pos):
        read_oword(line, text, pos, where)
        return line
    if _PLAIN_LINE.fullmatch(text.code):
        read_plain_words(line, text, pos, where, {} if words_read is None else words_read)
        return line
    while pos < len(text.code):
        pos = read_item(line, text, pos, where)
    return line


def read_plain_words(line: LexedLine, text: _Text, pos: int, where: str, known: dict[str, RawWord]) -> None:
    """The words of a line _PLAIN_LINE matched: what read_item gives for each, in one pass
    (the words are contiguous from ``pos``: each one's place follows from the lengths).

    A word already in ``known`` (by its text as written) is shared, not built again: CAM
    programs repeat words (G1, F300, Z-1.7, I0: 60 % of the corpus' words repeat one of
    their file), a RawWord is immutable and fully given by its text, and building one (with
    its Number) cost ~0.7 us, most of a plain line's lexing."""
    raw, append = text.raw, line.words.append
    for letter, number in _PLAIN_WORDS.findall(text.code, pos):
        start = pos + 1
        pos = start + len(number)
        written = raw[start:pos]  # as written: an exponent's 'E' stays upper case
        upper = letter.upper()
        text_as_written = upper + written
        word = known.get(text_as_written)
        if word is None:
            value = float(number)
            if not -MAX_ABS_VALUE <= value <= MAX_ABS_VALUE:  # also inf: check_number words the error
                check_number(value, upper, written, where)
            word = RawWord(upper, Number(value), text_as_written)
            known[text_as_written] = word
        append(word)


def read_item(line: LexedLine, text: _Text, pos: int, where: str) -> int:
    ch = text.code[pos]
    if ch == "#":
        return read_assignment(line, text, pos, where)
    if ch in "@^":
        raise InputError(f"{where}: {text.token_at(pos)}", "unsupported: polar coordinates (LinuxCNC's @ radius and ^ angle)")
    if not ch.isalpha():
        bad = text.token_at(pos)
        raise InputError(f"{where}: {bad}", f"unexpected character {text.body[text.origin[pos]]!r}; expected a word like X10.5")
    letter = ch.upper()
    start = pos + 1
    if start >= len(text.code) or (text.code[start].isalpha() and not _function_at(text.code, start)):
        following = text.token_at(start)
        hint = f", got {following[:20]!r}" if following else ""
        raise InputError(f"{where}: {letter}", f"{letter} needs a number{hint}")
    plain = _PLAIN_NUMBER.match(text.code, start)  # the common case, without the expression reader
    if plain is not None and (plain.end() == len(text.code) or text.code[plain.end()].isalpha()):
        expr: Expr = Number(float(plain.group()))
        end = plain.end()
    else:
        try:
            expr, end = read_value(text.code, start)
        except ExpressionError as err:
            raise InputError(f"{where}: {letter}{text.token_at(start)}", _value_message(text, start, err)) from None
    if end < len(text.code) and (text.code[end].isdigit() or text.code[end] in ".,"):
        bad = re.match(r"[^a-z#\[\]]*", text.code[start:]).group()  # type: ignore[union-attr]
        raw_bad = text.written(start, start + len(bad))
        raise InputError(f"{where}: {letter}{raw_bad}", f"malformed number {raw_bad!r}")
    written = text.written(start, end)
    if isinstance(expr, Number):
        check_number(expr.value, letter, written, where)
    line.words.append(RawWord(letter, expr, letter + written))
    return end


def _function_at(code: str, pos: int) -> bool:
    from nurbsmotion.program.expressions import FUNCTIONS
    return any(code.startswith(name + "[", pos) for name in FUNCTIONS)


def _value_message(text: _Text, start: int, err: ExpressionError) -> str:
    written = text.token_at(start)
    if _PLAIN_NUMBER.fullmatch(written.lower()) is None and not any(c in written for c in "#[") and written:
        return f"malformed number {written!r}"
    return str(err)


def read_assignment(line: LexedLine, text: _Text, pos: int, where: str) -> int:
    start = pos
    try:
        target, pos = read_parameter(text.code, pos)
        if not text.code.startswith("=", pos):
            raise ExpressionError(f"'#{text.written(start + 1, pos)}' outside a word must be an assignment '#... = value'")
        expr, pos = read_value(text.code, pos + 1)
    except ExpressionError as err:
        raise InputError(f"{where}: {text.token_at(start)}", str(err)) from None
    if pos < len(text.code) and text.code[pos] in "+-*/":
        raise InputError(f"{where}: {text.written(start, pos + 1)}", "write the expression in brackets: #1 = [#2 + 1]")
    line.assignments.append(Assignment(target, expr, text.written(start, pos)))
    return pos


def read_oword(line: LexedLine, text: _Text, pos: int, where: str) -> None:
    """``o<label> keyword [args]`` or a bare program number ``O1234``."""
    code = text.code
    m = _O_LABEL.match(code, pos)
    if m is None:
        raise InputError(f"{where}: {text.token_at(pos)}", "O needs a number or <name> (O-word or program number)")
    label_text = m.group(1)
    label: int | str = int(label_text) if label_text.isdigit() else label_text[1:-1]
    pos = m.end()
    if pos == len(code):
        if isinstance(label, str):
            raise InputError(f"{where}: {text.written(0, pos)}", "O-word without a keyword (sub, call, if, while, ...)")
        line.program_number = label
        return
    keyword = next((k for k in O_KEYWORDS if code.startswith(k, pos)), None)
    if keyword is None:
        raise InputError(f"{where}: {text.written(0, len(code))}",
                         f"unsupported: O-word {text.token_at(pos)!r}; known: {' '.join(sorted(O_KEYWORDS))}")
    pos += len(keyword)
    args = []
    while pos < len(code):
        if code[pos] != "[":
            raise InputError(f"{where}: {text.written(0, len(code))}",
                             f"O-word '{keyword}' arguments must be [expressions], got {text.token_at(pos)!r}")
        try:
            expr, pos = read_value(code, pos)
        except ExpressionError as err:
            raise InputError(f"{where}: {text.written(0, len(code))}", str(err)) from None
        args.append(expr)
    line.oword = OWord(label, keyword, tuple(args), text.written(0, len(code)))
