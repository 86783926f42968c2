"""RS274NGC values: numbers, ``#`` parameters and ``[...]`` expressions, parsed then evaluated.

A value (LinuxCNC G-code manual, "Overview" §5 Parameters, §6 Expressions, §7 Binary
Operators, §8 Functions) is a number, a parameter reference (``#5``, ``#<name>``, ``##2``,
``#[1+2]``), a bracketed expression, a function (``sin[30]``, ``atan[1]/[2]``,
``exists[#<x>]``) or one of these after a unary ``+``/``-``. Binary operators, loosest
last, all left-associative: ``**``; ``* / MOD``; ``+ -``; ``EQ NE GT GE LT LE``;
``AND OR XOR``. Angles are in degrees. Logical results are 1.0 or 0.0; any non-zero is true.

Text reaches this module lower-cased and without spaces (RS274NGC ignores spaces outside
comments), so ``[#1 GT 2]`` arrives as ``[#1gt2]``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Callable, Protocol, Union

_NUMBER = re.compile(r"(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?")
_NAME = re.compile(r"<([^<>]*)>")

BINARY_LEVELS = (  # loosest first
    ("and", "or", "xor"),
    ("eq", "ne", "gt", "ge", "lt", "le"),
    ("+", "-"),
    ("*", "/", "mod"),
    ("**",),
)
OPERATORS = sorted({op for level in BINARY_LEVELS for op in level}, key=len, reverse=True)
FUNCTIONS = ("abs", "acos", "asin", "atan", "cos", "exp", "fix", "fup", "round", "ln", "sin", "sqrt", "tan", "exists")


class ExpressionError(ValueError):
    """A value that cannot be read or computed; the message names what is wrong."""


class Parameters(Protocol):
    def get(self, key: int | str) -> float: ...

    def exists(self, key: int | str) -> bool: ...


@dataclass(frozen=True)
class Number:
    value: float

    def evaluate(self, params: Parameters) -> float:
        return self.value


@dataclass(frozen=True)
class ParamRef:
    """``#n``, ``#<name>`` (name lower-cased) or ``#<value>`` (an expression giving n)."""

    key: Union[int, str, "Expr"]

    def resolve(self, params: Parameters) -> int | str:
        if isinstance(self.key, (int, str)):
            return self.key
        return parameter_number(self.key.evaluate(params))

    def evaluate(self, params: Parameters) -> float:
        return params.get(self.resolve(params))


@dataclass(frozen=True)
class Unary:
    name: str  # a function name, or 'neg'
    arg: "Expr"
    arg2: "Expr | None" = None  # atan[a]/[b]

    def evaluate(self, params: Parameters) -> float:
        if self.name == "exists":
            assert isinstance(self.arg, ParamRef)
            return 1.0 if params.exists(self.arg.resolve(params)) else 0.0
        a = self.arg.evaluate(params)
        if self.name == "atan":
            assert self.arg2 is not None
            return math.degrees(math.atan2(a, self.arg2.evaluate(params)))
        return UNARY[self.name](a)


@dataclass(frozen=True)
class Binary:
    op: str
    left: "Expr"
    right: "Expr"

    def evaluate(self, params: Parameters) -> float:
        return binary(self.op, self.left.evaluate(params), self.right.evaluate(params))


Expr = Union[Number, ParamRef, Unary, Binary]


def parameter_number(value: float) -> int:
    """A computed parameter number must be a whole number from 1 to 5602 (LinuxCNC's range)."""
    n = round(value)
    if abs(value - n) > 1e-6 or not 1 <= n <= 5602:
        raise ExpressionError(f"parameter number must be a whole number from 1 to 5602, got {value:g}")
    return n


def _domain(name: str, ok: Callable[[float], bool], f: Callable[[float], float]) -> Callable[[float], float]:
    def checked(a: float) -> float:
        if not ok(a):
            raise ExpressionError(f"{name.upper()}[{a:g}] is undefined")
        return f(a)
    return checked


UNARY: dict[str, Callable[[float], float]] = {
    "neg": lambda a: -a,
    "abs": abs,
    "acos": _domain("acos", lambda a: -1 <= a <= 1, lambda a: math.degrees(math.acos(a))),
    "asin": _domain("asin", lambda a: -1 <= a <= 1, lambda a: math.degrees(math.asin(a))),
    "cos": lambda a: math.cos(math.radians(a)),
    "sin": lambda a: math.sin(math.radians(a)),
    "tan": _domain("tan", lambda a: abs(math.cos(math.radians(a))) > 1e-12, lambda a: math.tan(math.radians(a))),
    "exp": _domain("exp", lambda a: a < 700, math.exp),
    "fix": lambda a: float(math.floor(a)),
    "fup": lambda a: float(math.ceil(a)),
    "round": lambda a: float(math.floor(a + 0.5)),  # RS274NGC rounds halves up
    "ln": _domain("ln", lambda a: a > 0, math.log),
    "sqrt": _domain("sqrt", lambda a: a >= 0, math.sqrt),
}


def binary(op: str, a: float, b: float) -> float:
    """One binary operation (RS274NGC §7); comparisons and logic give 1.0 or 0.0."""
    if op in ("/", "mod") and b == 0:
        raise ExpressionError("division by zero" if op == "/" else "MOD by zero")
    if op == "**":
        if a < 0 and b != int(b):
            raise ExpressionError(f"{a:g} ** {b:g}: a negative base needs a whole exponent")
        try:
            return float(a ** b)
        except (OverflowError, ZeroDivisionError):
            raise ExpressionError(f"{a:g} ** {b:g} is out of range") from None
    arithmetic = {"+": a + b, "-": a - b, "*": a * b, "/": a / b if b else 0.0, "mod": math.fmod(a, b) if b else 0.0}
    if op in arithmetic:
        value = arithmetic[op]
        if op == "mod" and value < 0:
            value += abs(b)  # LinuxCNC: the result of MOD is >= 0
        return value
    truth = {"eq": a == b, "ne": a != b, "gt": a > b, "ge": a >= b, "lt": a < b, "le": a <= b,
             "and": bool(a) and bool(b), "or": bool(a) or bool(b), "xor": bool(a) != bool(b)}
    return 1.0 if truth[op] else 0.0


class _Reader:
    """Recursive-descent reader over one line's text (lower case, no spaces)."""

    def __init__(self, text: str, pos: int) -> None:
        self.text = text
        self.pos = pos

    def peek(self, s: str) -> bool:
        return self.text.startswith(s, self.pos)

    def expect(self, s: str, what: str) -> None:
        if not self.peek(s):
            got = self.text[self.pos:self.pos + 10] or "the end of the line"
            raise ExpressionError(f"expected {what}, got {got!r}")
        self.pos += len(s)

    def value(self) -> Expr:
        """A real value (number, parameter, expression, function), with optional sign."""
        if self.peek("-") or self.peek("+"):
            sign = self.text[self.pos]
            self.pos += 1
            inner = self.value()
            if isinstance(inner, Number):
                return Number(-inner.value if sign == "-" else inner.value)
            return Unary("neg", inner) if sign == "-" else inner
        if self.peek("["):
            return self.bracketed()
        if self.peek("#"):
            return self.parameter()
        for name in FUNCTIONS:
            if self.peek(name + "["):
                self.pos += len(name)
                return self.function(name)
        match = _NUMBER.match(self.text, self.pos)
        if match is None:
            got = self.text[self.pos:self.pos + 10]
            raise ExpressionError(f"expected a number, parameter or [expression], got {got!r}" if got else "a number is missing")
        self.pos = match.end()
        return Number(float(match.group()))

    def parameter(self) -> ParamRef:
        self.expect("#", "'#'")
        named = _NAME.match(self.text, self.pos)
        if named is not None:
            self.pos = named.end()
            if not named.group(1):
                raise ExpressionError("empty parameter name #<>")
            return ParamRef(named.group(1))
        if self.peek("<"):
            raise ExpressionError("parameter name not closed with '>'")
        index = self.value() if (self.peek("#") or self.peek("[")) else None
        if index is None:
            match = re.compile(r"\d+(?:\.\d*)?").match(self.text, self.pos)
            if match is None:
                raise ExpressionError("'#' needs a parameter number or <name>")
            self.pos = match.end()
            return ParamRef(parameter_number(float(match.group())))
        return ParamRef(index)

    def bracketed(self) -> Expr:
        self.expect("[", "'['")
        expr = self.expression(0)
        self.expect("]", "']' closing the expression")
        return expr

    def function(self, name: str) -> Expr:
        if name == "exists":
            self.expect("[", "'['")
            ref = self.parameter()
            self.expect("]", "']' after EXISTS[#<name>")
            return Unary("exists", ref)
        arg = self.bracketed()
        if name == "atan":
            self.expect("/", "'/' in ATAN[y]/[x]")
            return Unary("atan", arg, self.bracketed())
        return Unary(name, arg)

    def expression(self, level: int) -> Expr:
        if level == len(BINARY_LEVELS):
            return self.value()
        left = self.expression(level + 1)
        while True:
            op = next((o for o in OPERATORS if o in BINARY_LEVELS[level] and self.peek(o)), None)
            if op is None or (op == "*" and self.peek("**") and level != len(BINARY_LEVELS) - 1):
                return left
            self.pos += len(op)
            left = Binary(op, left, self.expression(level + 1))


def read_value(text: str, pos: int) -> tuple[Expr, int]:
    """Read one real value of ``text`` (lower case, no spaces) at ``pos``; (value, end)."""
    reader = _Reader(text, pos)
    return reader.value(), reader.pos


def read_parameter(text: str, pos: int) -> tuple[ParamRef, int]:
    """Read a ``#...`` parameter reference at ``pos`` (an assignment's target)."""
    reader = _Reader(text, pos)
    return reader.parameter(), reader.pos


def is_constant(expr: Expr) -> bool:
    return isinstance(expr, Number)
