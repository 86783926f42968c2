"""nurbsmotion/can/socketcan_batch.py without SocketCAN (its vcan0 tests: tests/vcan/test_socketcan_batch.py)."""

from __future__ import annotations


import can

from nurbsmotion.can.socketcan_batch import BatchNotifier
from tests.helpers import wait_for


def test_the_batch_notifier_leaves_other_buses_to_python_can():
    """On python-can's virtual bus (in-process tests) the notifier is python-can's."""
    with can.Bus(interface="virtual", channel="batch-notifier-test") as a, \
            can.Bus(interface="virtual", channel="batch-notifier-test") as b:
        got: list[int] = []
        notifier = BatchNotifier(b, [lambda m: got.append(m.arbitration_id)], 0.1)
        try:
            for i in range(50):
                a.send(can.Message(arbitration_id=0x100 + i, is_extended_id=False))
            wait_for(lambda: len(got) >= 50, 5.0, "50 frames received")
        finally:
            notifier.stop()
    assert got == [0x100 + i for i in range(50)]
