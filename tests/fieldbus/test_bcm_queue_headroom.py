"""The kernel queue's headroom counter (fieldbus.bcm_queue.QueueHeadroom): cycles still
queued beyond the wire at each wake-up while moving, as min / percentiles, and wake-ups that
found the wire already in the stop tail."""

from __future__ import annotations

from nurbsmotion.fieldbus.bcm_queue import QueueHeadroom


def test_min_and_percentiles_of_the_headroom() -> None:
    headroom = QueueHeadroom(64)
    for h in [53] * 90 + [49] * 9 + [12]:
        headroom.add(h)
    assert (headroom.samples, headroom.min) == (100, 12)
    assert headroom.percentile(0.01) == 12
    assert headroom.percentile(0.05) == 49
    assert headroom.percentile(0.5) == 53
    assert headroom.into_tail == 0


def test_a_wire_past_the_horizon_counts_as_zero_and_into_the_tail() -> None:
    headroom = QueueHeadroom(64)
    headroom.add(-3)  # the kernel sent 3 cycles of the stop tail before the thread came back
    headroom.add(70)  # beyond the ring: clipped
    assert (headroom.min, headroom.into_tail) == (0, 1)
    assert headroom.counts[0] == 1 and headroom.counts[64] == 1


def test_no_samples_gives_zero() -> None:
    assert QueueHeadroom(64).percentile(0.5) == 0
