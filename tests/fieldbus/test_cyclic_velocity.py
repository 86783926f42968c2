"""The csv spindle's per-SYNC 0x60FF: ramped per cycle, a pure function of the cycle."""

from __future__ import annotations

import math

from nurbsmotion.fieldbus.cyclic_velocity import TARGET_VELOCITY_FORMAT, CyclicVelocity, RampSegment


def test_a_segment_ramps_by_at_most_its_step_per_cycle_and_holds_the_target():
    s = RampSegment(10, 100.0, 350.0, 100.0)
    assert [s.value_at(x) for x in range(9, 15)] == [100.0, 100.0, 200.0, 300.0, 350.0, 350.0]
    assert s.end_cycle() == 13
    assert RampSegment(10, 100.0, -50.0, math.inf).value_at(10) == -50.0


def test_a_new_target_starts_where_the_old_ramp_is_at_that_cycle_and_earlier_cycles_keep_their_values():
    cv = CyclicVelocity(5, 0x205, 100.0)
    notified = []
    cv.notify = lambda: notified.append(True)
    cv.request(1000)
    assert notified and cv.value_at(3) == 0  # not applied yet: nothing changes
    assert cv.apply(3)
    before = [cv.value_at(x) for x in range(0, 9)]
    assert before == [0, 0, 0, 0, 100, 200, 300, 400, 500]
    cv.request(-200)
    cv.apply(6)  # the first cycle the writer packs again
    assert [cv.value_at(x) for x in range(0, 6)] == before[:6]  # packed again: the same frames
    assert [cv.value_at(x) for x in range(6, 14)] == [300, 200, 100, 0, -100, -200, -200, -200]
    steps = [cv.value_at(x + 1) - cv.value_at(x) for x in range(0, 20)]
    assert max(abs(d) for d in steps) <= 100  # never more than one step per cycle


def test_a_quick_stop_is_at_once_and_ramp_done_follows_the_wire():
    cv = CyclicVelocity(5, 0x205, 100.0)
    wire = [0]
    cv.wire_cycle = lambda: wire[0]
    cv.request(250)
    assert not cv.ramp_done()  # pending
    cv.apply(1)
    assert not cv.ramp_done() and cv.target_counts_s == 250
    wire[0] = 4
    assert cv.ramp_done()
    cv.request(0, at_once=True)
    cv.apply(5)
    assert cv.value_at(4) == 250 and cv.value_at(5) == 0
    data = bytearray(4)
    cv.pack(data, 4)
    assert TARGET_VELOCITY_FORMAT.unpack(data) == (250,)


def test_a_postponed_ramp_starts_later_from_the_value_the_wire_had_and_the_earlier_cycles_are_unchanged():
    """The kernel queue found the wire past the new segment's start (fieldbus.bcm_queue): the
    segment moves to the first free cycle; before it the older ramp's frames stay."""
    cv = CyclicVelocity(5, 0x205, 100.0)
    cv.request(1000)
    cv.apply(3)
    before = [cv.value_at(x) for x in range(0, 20)]
    cv.request(-200)
    cv.apply(6)
    assert cv.postpone(6, 9)
    assert [cv.value_at(x) for x in range(0, 10)] == before[:10]  # 0 0 0 0 100 ... 500 600
    assert [cv.value_at(x) for x in range(10, 13)] == [500, 400, 300]  # one step a cycle from there
    assert cv.target_counts_s == -200
    assert not cv.postpone(6, 9)  # it starts at 9 now: nothing before 9 to move
    assert not cv.postpone(12, 20)  # the newest segment starts before 12: not this change's


def test_a_ramp_already_in_the_kernel_queue_is_never_postponed():
    """Once a TX_SETUP carried the segment (queued), the wire may have sent its first frames:
    moving it then would send an old 0x60FF after a new one."""
    cv = CyclicVelocity(5, 0x205, 100.0)
    cv.request(1000)
    cv.apply(6)
    cv.queued()
    assert not cv.postpone(4, 12)
    assert [cv.value_at(x) for x in (6, 7)] == [0, 100]
