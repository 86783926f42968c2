"""A quick stop is the drive's own ramp (0x6085), not set-points from the master, so the
no-jump check of the recorded set-points cannot see it: here the motor's positions reported
in TPDO1 during a quick stop are checked against the axis' a_max."""

from __future__ import annotations

import struct
import threading

import numpy as np
import pytest

from tests.reliability.rig import A_MAX_MM_S2, COUNTS_PER_MM, PERIOD_MS, WAIT_S, held_counts, rig, smooth_move
from tests.helpers import wait_for


@pytest.mark.parametrize("cause", ["abort", "fault"])
def test_a_quick_stop_decelerates_within_a_max(cause):
    from nurbsmotion.sim import FaultInjection

    with rig() as r:
        positions: list[int] = []
        stop = threading.Event()

        def listen() -> None:  # TPDO1 of node 1: statusword, position actual, once per SYNC
            while not stop.is_set():
                msg = r.probe.recv(0.05)
                if msg is not None and msg.arbitration_id == 0x181 and len(msg.data) == 6:
                    positions.append(struct.unpack("<Hi", bytes(msg.data))[1])

        thread = threading.Thread(target=listen)
        thread.start()
        try:
            job = r.master.stream(smooth_move(held_counts(r.master), [40.0, 0.0, 0.0], duration_s=0.8))
            wait_for(lambda: (r.master.status().job_index or 0) > 100, what="full speed")  # ~78 mm/s
            if cause == "abort":
                job.abort()
            else:
                r.sim.inject(FaultInjection("fault", node_id=2))
            assert job.wait(WAIT_S) is not None
            wait_for(lambda: r.master.status().phase == "disabled", what="the quick stop to end")
        finally:
            stop.set()
            thread.join(WAIT_S)
        mm = np.array(positions, dtype=float) / COUNTS_PER_MM
        accel = np.abs(np.diff(mm, n=2)) / (PERIOD_MS / 1000) ** 2
        rounding = 2 / COUNTS_PER_MM / (PERIOD_MS / 1000) ** 2
        assert accel.max() <= A_MAX_MM_S2 * 1.02 + rounding, f"{accel.max():.0f} mm/s² during the quick stop"
