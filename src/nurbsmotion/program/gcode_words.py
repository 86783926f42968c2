"""G-code lexing: one line of text -> its words (letter + number), comments removed.

A word is a letter followed directly by a number: ``[+-]digits[.digits]`` with an optional
exponent (``1e3``); letters are case-insensitive and spaces between words are optional
(``G1X10Y5``). ``( ... )`` comments (not nested) and ``;`` comments to the end of the line
are removed. Anything else is an error naming the offending text.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from nurbsmotion.errors import InputError

MAX_ABS_VALUE = 1e9  # larger numbers are typos; keeps arc arithmetic far from overflow

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_WORD = re.compile(r"([A-Za-z])([^A-Za-z\s]*(?:[eE][+-]?\d[^A-Za-z\s]*)?)")


@dataclass(frozen=True)
class Word:
    letter: str  # upper case
    value: float
    text: str  # as written, for error messages

    def __str__(self) -> str:
        return self.text


def strip_comments(text: str, where: str) -> str:
    """Remove ``( ... )`` and ``; ...`` comments; an unclosed ``(`` is an error."""
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


def parse_number(letter: str, raw: str, where: str) -> float:
    """The value of a word; malformed, non-finite and absurdly large numbers are errors."""
    word = f"{where}: {letter}{raw}"
    if not raw:
        raise InputError(word, f"{letter} needs a number")
    if not _NUMBER.match(raw):
        raise InputError(word, f"malformed number {raw!r}")
    value = float(raw)
    if not math.isfinite(value):
        raise InputError(word, f"number {raw!r} is not finite")
    if abs(value) > MAX_ABS_VALUE:
        raise InputError(word, f"number {raw!r} is out of range (|value| <= {MAX_ABS_VALUE:g})")
    return value


def split_words(text: str, where: str) -> list[Word]:
    """Words of one line (comments removed). ``where`` is ``file:line``."""
    body = strip_comments(text, where)
    words = []
    pos = 0
    while pos < len(body):
        if body[pos].isspace():
            pos += 1
            continue
        match = _WORD.match(body, pos)
        if match is None:
            bad = body[pos:].split()[0]
            if body[pos] == "#":
                raise InputError(f"{where}: {bad}", "unsupported: parameters (#)")
            raise InputError(f"{where}: {bad}", f"unexpected character {body[pos]!r}; expected a word like X10.5")
        letter, raw = match.group(1).upper(), match.group(2)
        if not raw:
            following = body[match.end():].split()
            hint = f", got {following[0][:20]!r}" if following else ""
            raise InputError(f"{where}: {letter}", f"{letter} needs a number{hint}")
        words.append(Word(letter, parse_number(letter, raw, where), f"{letter}{raw}"))
        pos = match.end()
    return words
