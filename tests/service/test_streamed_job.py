"""streamed_job: the highest feed of a program from its block columns (computed by the planner worker) is the one of its Blocks; the index of block starts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.program import Program, read_program
from nurbsmotion.program.records import BlockRecords
from nurbsmotion.service import planner_worker
from nurbsmotion.service.planner_worker import highest_feed_mm_s

GCODE = Path(__file__).resolve().parents[1] / "data" / "gcode"
LIMITS = PlanLimits(period_s=0.001, chord_error_mm=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0,
                    default_feed_mm_s=7.0, rapid_feed_mm_s=333.0)


@pytest.mark.parametrize("name", ["fusion360_led_floor_1121_btn8copies_20bit.nc", "grbl_HSM_test.nc",
                                  "linuxcnc_nurbs_G5_butterfly-xy.ngc", "camotics_vcarve.ngc"])
@pytest.mark.parametrize("rapid_feed_mm_s", [333.0, 1.0])
def test_the_highest_feed_from_the_columns_is_the_blocks(name, rapid_feed_mm_s):
    limits = PlanLimits(**{**LIMITS.__dict__, "rapid_feed_mm_s": rapid_feed_mm_s})
    program = read_program(GCODE / name)
    assert isinstance(program.blocks, BlockRecords)
    blocks = Program(program.name, tuple(program.blocks), program.start_position)
    assert highest_feed_mm_s(program, limits) == highest_feed_mm_s(blocks, limits)


def test_the_highest_feed_is_the_same_a_slice_at_a_time(monkeypatch):
    program = read_program(GCODE / "fusion360_led_floor_1121_btn8copies_20bit.nc")
    whole = highest_feed_mm_s(program, LIMITS)
    monkeypatch.setattr(planner_worker, "FEED_ROWS", 7)
    assert highest_feed_mm_s(program, LIMITS) == whole


def test_block_starts_give_the_block_of_any_row_across_chunks_and_growth():
    """StreamedJob's index of block starts (the status' line, the end's reason) against a
    list of (row, block) pairs: chunks continuing their last block, growth past its size."""
    from nurbsmotion.service.planner_worker import block_starts
    from nurbsmotion.service.streamed_job import BlockStarts

    rng = np.random.default_rng(3)
    blocks = np.repeat(np.arange(3000), rng.integers(1, 5, 3000)).astype(np.int32)  # each block 1-4 rows
    starts, first = BlockStarts(), 0
    for size in rng.integers(1, 50, 400):
        chunk = blocks[first:first + size]
        if len(chunk):
            starts.add(*block_starts(chunk, first))
        first += size
    assert first >= len(blocks) and starts.count == 3000 and len(starts.rows) >= 3000
    assert [starts.block_at(row) for row in range(len(blocks))] == blocks.tolist()
    assert starts.block_at(-1) is None and BlockStarts().block_at(5) is None
    assert starts.block_at(10 ** 9) == 2999
