"""The master's heartbeat on a bus without a kernel sender (python-can's ``virtual``) is sent
by a thread of this process: it runs SCHED_FIFO at the priority it is given, as the threads
judging it do (issue 26.1: beside a CPU burner the demo's drives lost it, EMCY 0x8130)."""

from __future__ import annotations

import os
import time
import uuid

import can
import pytest

from nurbsmotion.fieldbus.heartbeat import MasterHeartbeat


def policy_of(thread_id: int) -> tuple[int, int]:
    return os.sched_getscheduler(thread_id), os.sched_getparam(thread_id).sched_priority


def fifo_allowed() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler") or not fifo_allowed(), reason="SCHED_FIFO not allowed here")
def test_the_heartbeat_threads_run_at_the_priority_given():
    channel = f"hb-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as bus, can.Bus(interface="virtual", channel=channel) as drive:
        heartbeat = MasterHeartbeat(bus, 127, 0.01, lambda: True, renew_s=0.05, thread_priority=7)
        heartbeat.start()
        try:
            assert drive.recv(2.0) is not None  # it is sent
            sender = heartbeat._task.thread  # type: ignore[union-attr]
            assert policy_of(sender.native_id) == (os.SCHED_FIFO, 7)
            deadline = time.monotonic() + 2.0
            while policy_of(heartbeat._thread.native_id) != (os.SCHED_FIFO, 7):  # type: ignore[union-attr]
                assert time.monotonic() < deadline, "the watchdog thread never became SCHED_FIFO 7"
                time.sleep(0.01)
        finally:
            heartbeat.stop()
