"""Playback of a job's rows without a bus: rate ramps, stop length estimate, snapshots."""

import numpy as np
import pytest

from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.stop_ramp import RATE_RAMP_SHARE, ramp_slope


def playback(n=3000, rate=1.0):
    arr = np.column_stack([np.arange(n) * 50, np.arange(n) * -20]).astype(np.int64)
    steps = np.abs(np.diff(arr, axis=0)).max(axis=0).astype(float).tolist()
    return Playback(memoryview(arr), ramp_slope(arr, np.array([2e5, 2e5]), 0.004), rate, steps, [0.0, 0.0]), arr


def test_rate_one_hands_out_every_row_in_order():
    pb, arr = playback(10)
    out = [0, 0]
    rows = []
    for _ in range(10):
        last = pb.advance(out)
        rows.append(list(out))
    assert rows == arr.tolist() and last


def test_rate_change_ramps_by_a_share_of_the_stop_slope():
    pb, _ = playback()
    out = [0, 0]
    pb.advance(out)
    pb.target = 0.5
    pb.advance(out)
    assert pb.r == pytest.approx(1.0 - pb.ramp_dr * RATE_RAMP_SHARE)


def test_stop_ends_at_rest_within_the_estimated_cycles():
    pb, _ = playback()
    out = [0, 0]
    for _ in range(100):
        pb.advance(out)
    estimate = pb.stop_cycles([2e5, 2e5], 0.004)
    pb.start_stop([2e5, 2e5], 0.004)
    cycles = 1
    while pb.stop_step(out):
        cycles += 1
    assert cycles <= estimate and pb.r == 0.0


def test_snapshot_restore_round_trips():
    pb, _ = playback()
    out = [0, 0]
    for _ in range(7):
        pb.advance(out)
    snap = pb.snapshot()
    ahead = [pb.advance(out) or list(out) for _ in range(5)]
    pb.restore(snap)
    assert [pb.advance(out) or list(out) for _ in range(5)] == ahead
