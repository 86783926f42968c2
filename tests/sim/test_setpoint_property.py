"""Property: whatever the pattern of RPDOs between SYNCs, the drive applies exactly the last
set-point received before each SYNC, at that SYNC, and records each once.

Frames are fed straight into the drive's canopen Network (no receive thread), so every
example is deterministic."""

from __future__ import annotations

import struct
import uuid

import can
import canopen
from hypothesis import given, settings
from hypothesis import strategies as st

from nurbsmotion.sim import SimDrive

NODE = 1
intervals = st.lists(st.lists(st.integers(-(2**31), 2**31 - 1), max_size=3), min_size=1, max_size=25)


@settings(max_examples=40, deadline=None)
@given(intervals=intervals, csp=st.booleans())
def test_last_setpoint_before_each_sync_is_applied_once_at_that_sync(intervals: list[list[int]], csp: bool) -> None:
    bus = can.Bus(interface="virtual", channel=uuid.uuid4().hex)
    network = canopen.Network(bus)
    drive = SimDrive(NODE, lag_cycles=0)  # no velocity limit: actual = set-point
    try:
        drive.attach(network)
        rpdo_cob, controlword = (0x200 + NODE, 0x0F) if csp else (0x300 + NODE, 0x1F)
        network.notify(0x000, bytes([0x01, NODE]), 0.0)
        drive.axis.set_mode(8 if csp else 7)
        for word in (0x06, 0x07, controlword):
            drive.axis.set_controlword(word)
        network.notify(0x80, b"", 0.0)  # SYNC 1
        for values in intervals:
            for value in values:
                network.notify(rpdo_cob, struct.pack("<Hi", controlword, value), 0.0)
            network.notify(0x80, b"", 0.0)
        expected = [(k + 2, values[-1]) for k, values in enumerate(intervals) if values]
        assert [(r.sync_index, r.setpoint_counts) for r in drive.recorder.records()] == expected
        assert drive.stats.rpdos_overwritten == sum(max(len(v) - 1, 0) for v in intervals)
        if expected:
            assert drive.position_actual == expected[-1][1]
    finally:
        drive.detach()
        bus.shutdown()
