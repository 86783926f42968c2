"""The fast paths of the G-code reader give exactly what the general paths give (issue 17's
first motion: the whole program is read before motion, so reading got faster, not looser).

Oracles, kept in the package or here:
- lexing: gcode_words.read_item (the general reader) for every line, the one-expression
  fast path (_PLAIN_LINE) switched off;
- the zero-speed check: the check as it was (arc length always computed), copied below;
- whole programs: the parsed blocks and events with and without the fast lexer.

On every file of the real CAM corpus (tests/data/gcode), every example and Wang's curve
repeated 460 times (the one-hour program of benchmarks/bench_first_motion.py).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.program import Program, ReadOptions, gcode_words, parse_gcode
from nurbsmotion.program.curve_check import CurveProblem, cusp_problems, span_samples, zero_speed_problems
from nurbsmotion.program.reader import GCODE_SUFFIXES
from tests.program.test_corpus import TOOLS

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted(p for folder in (ROOT / "tests" / "data" / "gcode", ROOT / "examples")
               for p in folder.iterdir() if p.suffix.lower() in GCODE_SUFFIXES)
NEVER = re.compile(r"(?!)")


def wang_x460() -> str:
    from benchmarks.bench_plan_command import wang_copies

    return wang_copies(460)


def texts() -> list[tuple[str, str]]:
    return [(p.name, p.read_text(errors="replace")) for p in FILES] + [("wang_x460.nc", wang_x460())]


def lexed(text: str, name: str) -> list[object]:
    out: list[object] = []
    for number, raw in enumerate(text.split("\n"), start=1):
        try:
            out.append(gcode_words.lex_line(number, raw, name))
        except InputError as err:
            out.append((err.where, err.message))
    return out


@pytest.fixture
def general_lexer(monkeypatch):
    """Every line through read_item: the reader as it was before the fast path."""
    monkeypatch.setattr(gcode_words, "_PLAIN_LINE", NEVER)


def test_the_inputs_are_there():
    assert len(FILES) >= 60


def test_fast_lexer_equals_general_lexer_on_every_line(monkeypatch):
    fast = {name: lexed(text, name) for name, text in texts()}
    monkeypatch.setattr(gcode_words, "_PLAIN_LINE", NEVER)
    for name, text in texts():
        assert fast[name] == lexed(text, name), name


LINES = [
    "G1 X1 Y2", "g1x1y2", "N10 G1 X-1.5 Y+.5 Z3.", "N10.5 X1", "X1e3 Y2E-2", "X1e5.", "X1.2.3", "X1,5",
    "X1e999", "X-2e9", "X1000000001", "X", "XY1", "X1 Y", "N10", "n10x", "nx1", "N1e5X1", "N1.E5X1",
    "X[1+2]", "X#1", "#1=2 X1", "X1 ; c", "X1 (c) Y2", "G1 X1 O100", "O100 if [1]", "x 1 0 y 2", "X1é2",
    "G1 X\u0661", "X1\tY2", "/X1", "%", "", "K1 R2 X0", "M30", "X1-2", "X+-1", "X1Y2Z3A4",
]


@pytest.mark.parametrize("line", LINES)
def test_fast_lexer_equals_general_lexer_on_edge_cases(line, monkeypatch):
    fast = lexed(line, "t.nc")
    monkeypatch.setattr(gcode_words, "_PLAIN_LINE", NEVER)
    assert fast == lexed(line, "t.nc")


def test_fast_lexer_takes_the_common_lines():
    """The fast path is the one the corpus and the long program take (or nothing got faster)."""
    lines = [ln for _, text in texts() for ln in text.split("\n")]
    plain = sum(1 for ln in lines if gcode_words._PLAIN_LINE.fullmatch("".join(ln.split()).lower()))
    assert plain > 0.9 * len(lines)


def signature(program: Program) -> tuple:
    """Everything a parsed program holds, as comparable values."""
    blocks = tuple((b.kind, b.feed_mm_s, b.source, b.exact_stop, b.blend_tolerance_mm, b.curve.degree,
                    b.curve.control_points.tobytes(), b.curve.weights.tobytes(), b.curve.knots.tobytes())
                   for b in program.blocks)
    return (program.name, blocks, program.start_position.tobytes(), program.events, program.coordinates,
            program.tool_at_end)


def outcome(text: str, name: str) -> tuple | str:
    try:
        return signature(parse_gcode(text, name, options=ReadOptions(tool_table=TOOLS)))
    except InputError as err:
        return str(err)


def test_fast_reader_parses_the_same_programs(monkeypatch):
    fast = {name: outcome(text, name) for name, text in texts()}
    assert sum(isinstance(o, tuple) for o in fast.values()) >= 45
    monkeypatch.setattr(gcode_words, "_PLAIN_LINE", NEVER)
    for name, text in texts():
        assert fast[name] == outcome(text, name), name


def zero_speed_problems_before(curve: NurbsCurve) -> list[CurveProblem]:
    """The check as it was: the mean speed from the arc length, always."""
    breaks = curve.breakpoints
    u = np.unique(np.concatenate([np.linspace(a, b, 65) for a, b in zip(breaks[:-1], breaks[1:])]))
    speed = np.linalg.norm(curve.derivatives(u, 1)[1], axis=1)
    return cusp_problems(curve, u, speed, curve.length / (curve.u_max - curve.u_min))


CORPUS_CURVES = 1500  # every kind of block of the corpus, spread over its files (all: ~50 s)


def corpus_curves() -> list[NurbsCurve]:
    blocks = []
    for name, text in texts()[:-1]:
        try:
            blocks += parse_gcode(text, name, options=ReadOptions(tool_table=TOOLS)).blocks
        except InputError:
            continue
    step = max(len(blocks) // CORPUS_CURVES, 1)
    return [NurbsCurve.create(b.curve.degree, b.curve.control_points, b.curve.weights, b.curve.knots)
            for b in blocks[::step]]  # fresh curves: nothing cached by the parse


def cusp_curves() -> list[NurbsCurve]:
    """Curves with a zero or a tiny speed somewhere (found or not found by either check)."""
    rng = np.random.default_rng(17)
    out = []
    for scale in (0.0, 1e-9, 1e-7, 1e-6, 1e-5, 1e-3):
        for degree in (2, 3):
            for _ in range(5):
                pts = rng.normal(size=(6, 3)) * 10.0
                pts[3] = pts[2] + scale * rng.normal(size=3)  # two (nearly) coincident control points
                weights = rng.uniform(0.2, 5.0, size=6)
                out.append(NurbsCurve.create(degree, pts, weights))
    return out


def test_zero_speed_check_equals_the_check_before():
    curves = corpus_curves() + cusp_curves()
    assert len(curves) > 1000
    found = 0
    for curve in curves:
        before = zero_speed_problems_before(curve)
        assert zero_speed_problems(curve) == before
        found += bool(before)
    assert found >= 5  # the oracle does find cusps among them: the comparison means something


def test_span_samples_equal_linspace_per_span():
    rng = np.random.default_rng(3)
    for _ in range(200):
        breaks = np.unique(np.concatenate([[0.0, 1.0], rng.random(rng.integers(1, 40))])) * rng.choice([1.0, 7.3, 1e-3])
        expected = np.concatenate([np.linspace(a, b, 65) for a, b in zip(breaks[:-1], breaks[1:])])
        assert np.array_equal(span_samples(breaks, 64), expected)


def test_plain_words_are_shared_between_the_lines_of_one_program():
    """A plain word read once is the same immutable object on the program's later lines;
    a refused word is never kept; without a store every word is built anew."""
    words_read: dict[str, gcode_words.RawWord] = {}
    first = gcode_words.lex_line(1, "G1 X1.5 Y2", "a.nc", words_read)
    second = gcode_words.lex_line(2, "g1 x1.5 Y3", "a.nc", words_read)
    assert first.words[0] is second.words[0] and first.words[1] is second.words[1]
    assert [w.text for w in second.words] == ["G1", "X1.5", "Y3"]
    with pytest.raises(InputError, match="out of range"):
        gcode_words.lex_line(3, "X2e9", "a.nc", words_read)
    assert "X2e9" not in words_read and set(words_read) == {"G1", "X1.5", "Y2", "Y3"}
    assert gcode_words.lex_line(4, "G1", "a.nc").words[0] is not first.words[0]
