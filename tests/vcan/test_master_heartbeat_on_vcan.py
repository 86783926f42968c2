"""The master's heartbeat on a real kernel vcan0: SIGKILL of the daemon mid-motion, and every
simulated drive (a separate `nurbsmotion sim` process, its 0x1016 written at bring-up)
reports the loss and goes to FAULT by itself within its consumer time."""

from __future__ import annotations

import time

import pytest

from tests.integration.daemon_helpers import wait_until
from tests.vcan.test_daemon_on_vcan import JOB_TIMEOUT_S, daemon_and_drives, submit_wang  # noqa: F401 (fixture)

pytestmark = pytest.mark.vcan
# Slack for the drives' log lines to cross the pipe to this test inside User-Mode Linux;
# the drives' own detection is bounded by the consumer time.
LOG_DELIVERY_S = 1.0


def test_sigkill_of_the_daemon_faults_every_drive_within_the_consumer_time(daemon_and_drives):  # noqa: F811
    daemon, sim = daemon_and_drives
    mon = daemon.config.monitoring
    consumer_s = mon.master_heartbeat_ms * mon.master_heartbeat_consumer_multiple / 1000.0
    nodes = [a.node_id for a in daemon.config.axes]
    submit_wang(daemon)
    daemon.wait_progress(0.1, timeout_s=JOB_TIMEOUT_S)
    assert not [line for line in sim.log if "sim.heartbeat_lost" in line]

    assert daemon.proc is not None
    daemon.proc.kill()  # SIGKILL: no shutdown, no NMT stop; the kernel drops its BCM heartbeat task
    killed = time.monotonic()

    def lost() -> set[int]:
        wanted = {f"sim.heartbeat_lost node={n} producer={daemon.config.master.node_id}": n for n in nodes}
        return {n for text, n in wanted.items() for line in sim.log if text in line}
    wait_until(lambda: lost() == set(nodes), consumer_s + LOG_DELIVERY_S + 5.0, "every drive to report the loss")
    assert time.monotonic() - killed <= consumer_s + LOG_DELIVERY_S
    sim.stop()
    for n in nodes:  # each drive's closing summary: it went to FAULT by itself
        assert any(f"sim.summary node={n} state=FAULT" in line for line in sim.log), sim.summary()
