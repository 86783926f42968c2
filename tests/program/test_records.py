"""program.records: the blocks kept as columns give what the blocks' NURBS give.

Oracles: the curves themselves (line_curve / arc_curve, built from each block's shape), their
Gauss-quadrature lengths, sampled points and control points, on real CAM programs of the
corpus with lines, arcs in every plane, helices and NURBS blocks.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import ArcShape, LineShape, line_curve
from nurbsmotion.program import Block, BlockKind, Program, ReadOptions, SourceRef, read_program
from nurbsmotion.program.records import BlockRecords, SourceText
from nurbsmotion.program.summary import curve_samples, summarize
from tests.program.test_corpus import CORPUS, TOOLS

PROGRAMS = ["grbl_HSM_test.nc", "fusion360_led_floor_1121_btn8copies_20bit.nc", "linuxcnc_arcspiral.ngc",
            "linuxcnc_nurbs_G6_homer_1-1.ngc"]
MIXED = CORPUS.parents[2] / "examples" / "mixed.nc"


@pytest.fixture(scope="module")
def programs() -> list[Program]:
    return [read_program(CORPUS / name, options=ReadOptions(tool_table=TOOLS)) for name in PROGRAMS] + [read_program(MIXED)]


def test_a_reader_keeps_lines_and_arcs_as_numbers_and_nurbs_as_curves(programs):
    kinds = set()
    for program in programs:
        records = program.blocks
        assert isinstance(records, BlockRecords)
        for block in records:
            kinds.add(block.kind)
            expected = NurbsCurve if block.kind is BlockKind.NURBS else ArcShape if block.kind is BlockKind.ARC else LineShape
            assert isinstance(block.shape, expected)
        assert len(records.curves) == int(np.sum(records.kinds == 0))
    assert kinds == set(BlockKind)


def test_lengths_in_closed_form_equal_the_curves_lengths(programs):
    for program in programs:
        lengths = program.blocks.lengths_mm()
        for block, length in zip(program.blocks, lengths):
            assert length == pytest.approx(block.curve.length, rel=1e-6, abs=1e-9)
            assert block.length_mm == pytest.approx(length, rel=1e-12, abs=1e-12)


def test_boxes_hold_every_sampled_point_within_the_control_points_box(programs):
    """boxes_mm (per block) and extent_mm (the path's): line ends and arc extremes exact,
    NURBS blocks their control points' box, the path's NURBS sampled as curve_samples samples them."""
    for program in programs:
        lows, highs = program.blocks.boxes_mm()
        for i, block in enumerate(program.blocks):
            points = block.curve.control_points
            assert np.all(lows[i] >= points.min(axis=0) - 1e-9) and np.all(highs[i] <= points.max(axis=0) + 1e-9)
            if block.kind is BlockKind.NURBS:
                np.testing.assert_array_equal(lows[i], points.min(axis=0))
                np.testing.assert_array_equal(highs[i], points.max(axis=0))
            else:
                samples = curve_samples(block.curve, 256)
                assert np.all(samples >= lows[i] - 1e-9) and np.all(samples <= highs[i] + 1e-9)
                scale = 1e-9 + (np.abs(samples).max() * 1e-5 if block.kind is BlockKind.ARC else 0.0)  # r (1 - cos(pi / 1024))
                assert np.all(samples.min(axis=0) - lows[i] <= scale) and np.all(highs[i] - samples.max(axis=0) <= scale)
        low, high = program.blocks.extent_mm(curve_samples)
        per_span = {BlockKind.NURBS: 64, BlockKind.ARC: 2048}  # lines: their ends
        samples = np.vstack([curve_samples(b.curve, per_span.get(b.kind, 1)) for b in program.blocks])
        assert np.all(samples >= low - 1e-9) and np.all(samples <= high + 1e-9)
        assert np.all(samples.min(axis=0) - low <= 2e-6) and np.all(high - samples.max(axis=0) <= 2e-6)  # r (1 - cos(pi / 8192))


ARC_CASES = [  # (normal, start angle deg, sweep deg, rise mm, end moved by mm)
    *((normal, start, sweep, 0.0, 0.0) for normal in ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
      for start, sweep in ((0, 360), (0, -360), (37, 360), (-10, 20), (80, 20), (170, 20), (260, 20), (350, 20),
                           (10, -20), (100, -20), (190, -20), (280, -20), (45, 90), (45, 270), (-135, -300), (0, 90),
                           (90, 90), (0, 0.5), (120, 179))),
    ((0.0, 0.0, 1.0), 30, 720, 5.0, 0.0), ((0.0, 0.0, 1.0), 30, -450, -3.0, 0.0), ((0.0, 1.0, 0.0), 200, 200, 2.0, 0.0),
    ((1.0, 0.0, 0.0), -60, -150, 7.0, 0.0), ((0.0, 0.0, 1.0), 60, 60, 0.0, 0.002), ((0.0, 1.0, 0.0), -95, 100, 1.0, 0.002),
]


@pytest.mark.parametrize("normal, start_deg, sweep_deg, rise_mm, moved_mm", ARC_CASES)
def test_arc_boxes_in_closed_form_against_dense_sampling(normal, start_deg, sweep_deg, rise_mm, moved_mm):
    """An arc's or helix' box (G17, G18, G19; full turns, sweeps crossing 0/90/180/270 deg
    either way, an end off the circle by the reader's tolerance) against 20,000 points of
    the curve arc_curve builds, the one the planner follows."""
    n = int(np.flatnonzero(normal)[0])
    a, b = (n + 1) % 3, (n + 2) % 3
    centre, radius = np.array([3.0, -2.0, 1.5]), 7.0

    def at(angle_deg: float, lift: float) -> np.ndarray:
        point = centre.copy()
        point[a] += radius * math.cos(math.radians(angle_deg))
        point[b] += radius * math.sin(math.radians(angle_deg))
        point[n] += lift
        return point

    start = at(start_deg, 0.0)
    end = at(start_deg + sweep_deg, rise_mm) + moved_mm * np.array([0.6, -0.48, 0.64])
    shape = ArcShape(start, end, centre, math.radians(sweep_deg), normal, rise_mm)
    records = BlockRecords.of_blocks((Block(BlockKind.ARC, shape, 1.0, SourceRef("t", 1)),))
    lows, highs = records.boxes_mm()
    curve = shape.curve()
    points = curve.points(np.linspace(curve.knots[0], curve.knots[-1], 20001))
    assert np.all(points >= lows[0] - 1e-9) and np.all(points <= highs[0] + 1e-9)
    slack = radius * (1 - math.cos(math.radians(abs(sweep_deg)) / 20000)) + 1e-9 + abs(moved_mm)
    assert np.all(points.min(axis=0) - lows[0] <= slack) and np.all(highs[0] - points.max(axis=0) <= slack)
    low, high = records.extent_mm(curve_samples)
    np.testing.assert_array_equal(low, lows[0])
    np.testing.assert_array_equal(high, highs[0])


def test_summary_of_records_equals_the_summary_of_the_same_blocks_as_a_tuple(programs):
    for program in programs:
        as_tuple = Program(program.name, tuple(program.blocks), program.start_position, program.events)
        a, b = summarize(program), summarize(as_tuple)
        assert (a.blocks, a.blocks_by_kind, a.feed_min_mm_min, a.feed_max_mm_min, a.exact_stops) == \
               (b.blocks, b.blocks_by_kind, b.feed_min_mm_min, b.feed_max_mm_min, b.exact_stops)
        assert a.length_mm == pytest.approx(b.length_mm, rel=1e-12)
        np.testing.assert_allclose(a.bbox_min_mm, b.bbox_min_mm, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.bbox_max_mm, b.bbox_max_mm, rtol=0, atol=1e-12)


def test_slices_and_pickles_are_records_of_their_own_rows(programs):
    for program in programs:
        records = program.blocks
        n = len(records)
        for part, rows in ((records[10:40], range(n)[10:40]), (records[-7:], range(n)[-7:]), (records[::97], range(n)[::97])):
            assert isinstance(part, BlockRecords) and len(part) == len(rows)
            again = pickle.loads(pickle.dumps(part))
            for block, i in zip(again, rows):
                original = records[i]
                assert (block.kind, block.feed_mm_s, block.source, block.exact_stop) == \
                       (original.kind, original.feed_mm_s, original.source, original.exact_stop)
                np.testing.assert_array_equal(block.curve.control_points, original.curve.control_points)
        assert len(pickle.dumps(records[:100])) < len(pickle.dumps(records)) / 3 or n < 400
        assert records[-1].source == records[n - 1].source
        with pytest.raises(IndexError):
            records[n]


def test_records_of_any_blocks_keep_kind_feed_source_and_curve():
    line = line_curve((0, 0, 0), (3, 4, 0))
    blocks = (Block(BlockKind.LINE, line, 5.0, SourceRef("t", 1, "G1 X3 Y4")),
              Block(BlockKind.NURBS, NurbsCurve.create(2, [(3, 4, 0), (5, 5, 0), (6, 0, 1)]), None, SourceRef("u", 9), True, 0.01))
    records = BlockRecords.of_blocks(blocks)
    assert [b.kind for b in records] == [BlockKind.LINE, BlockKind.NURBS]
    assert [b.source for b in records] == [b.source for b in blocks]
    assert [(b.feed_mm_s, b.exact_stop, b.blend_tolerance_mm) for b in records] == [(5.0, False, None), (None, True, 0.01)]
    assert records[0].curve is line and records.lengths_mm()[0] == pytest.approx(5.0)
    assert records == BlockRecords.of_blocks(blocks) and records != BlockRecords.of_blocks(blocks[:1])
    assert BlockRecords.of_blocks(()) == ()


def test_a_block_builds_its_curve_once_and_only_when_asked():
    block = Block(BlockKind.LINE, LineShape(np.zeros(3), np.array([1.0, 2.0, 2.0])), 1.0, SourceRef("t", 1))
    assert block.length_mm == 3.0 and block.end.tolist() == [1.0, 2.0, 2.0]
    assert block._curve is None
    assert block.curve is block.curve and block.curve.degree == 1
    assert pickle.loads(pickle.dumps(block)).curve.control_points.tolist() == [[0, 0, 0], [1, 2, 2]]
    assert block.replace(exact_stop=True).exact_stop and not block.exact_stop


def test_source_text_gives_each_line_and_windows_of_lines():
    text = "a\nbb\n\nccc é\r\nd\n"
    lines = text.split("\n")
    source = SourceText.of(text)
    for number in range(0, len(lines) + 2):
        assert source.line(number) == (lines[number - 1] if 1 <= number <= len(lines) else "")
    for first in range(1, len(lines) + 1):
        for last in range(first, len(lines) + 1):
            window = source.window(first, last)
            for number in range(0, len(lines) + 2):
                assert window.line(number) == (lines[number - 1] if first <= number <= last else "")


def test_arc_extents_in_closed_form_on_quarter_and_full_turns():
    for sweep in (math.pi / 2, -math.pi / 2, 2 * math.pi, 0.3, -5.0):
        start, end = np.array([1.0, 0.0, 0.0]), np.array([math.cos(sweep), math.sin(sweep), 0.0])
        shape = ArcShape(start, end, np.zeros(3), sweep, (0.0, 0.0, 1.0), 0.0)
        records = BlockRecords.of_blocks((Block(BlockKind.ARC, shape, 1.0, SourceRef("t", 1)),))
        low, high = records.extent_mm(curve_samples)
        points = curve_samples(shape.curve(), 2000)
        np.testing.assert_allclose(low, points.min(axis=0), atol=1e-6)
        np.testing.assert_allclose(high, points.max(axis=0), atol=1e-6)


def test_slices_joined_again_give_the_same_blocks(programs):
    """BlockRecords.concatenate (the daemon joins the ProgramBlocks slices it receives)."""
    for program in programs:
        records = program.blocks
        for size in (1, 7, 1000):
            parts = [pickle.loads(pickle.dumps(records[i:i + size])) for i in range(0, len(records), size)]
            joined = BlockRecords.concatenate(parts)
            assert joined.signature()[0] == records.signature()[0] and joined.source_overrides == records.source_overrides
            for a, b in zip(joined, records):
                assert (a.kind, a.source, a.feed_mm_s) == (b.kind, b.source, b.feed_mm_s)
                np.testing.assert_array_equal(a.curve.control_points, b.curve.control_points)
    assert len(BlockRecords.concatenate([])) == 0
