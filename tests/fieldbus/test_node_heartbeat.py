"""The master's heartbeat consumer for a node outside the set-point rows (the I/O node)."""

from __future__ import annotations

import threading

from nurbsmotion.fieldbus.node_heartbeat import HeartbeatSeen, HeartbeatWatch, heartbeat_problem

OP, PRE_OP, STOPPED, BOOTUP = 0x05, 0x7F, 0x04, 0x00


def seen(state: int | None, last_s: float = 10.0, operational: bool = True, bootup: bool = False) -> HeartbeatSeen:
    return HeartbeatSeen(started_s=9.0, last_s=last_s, state=state, operational_seen=operational, bootup_seen=bootup)


def test_silence_longer_than_the_consumer_time_is_a_loss_and_not_before():
    assert heartbeat_problem(seen(OP, last_s=10.0), 10.29, 0.3) is None
    assert heartbeat_problem(seen(OP, last_s=10.0), 10.31, 0.3) == "no heartbeat for 310 ms (consumer time 300 ms)"


def test_a_boot_up_or_leaving_operational_is_a_loss():
    assert heartbeat_problem(seen(PRE_OP, bootup=True), 10.0, 0.3).startswith("heartbeat reports boot-up: the node "
                                                                              "restarted")
    assert heartbeat_problem(seen(STOPPED), 10.0, 0.3) == "heartbeat reports NMT state STOPPED instead of OPERATIONAL"


def test_pre_operational_right_after_the_nmt_start_is_waited_for_one_consumer_time():
    early = seen(PRE_OP, operational=False)  # a heartbeat sent before the node took the NMT start
    assert heartbeat_problem(early, 9.2, 0.3) is None
    assert heartbeat_problem(early, 9.31, 0.3) == ("heartbeat reports NMT state PRE-OPERATIONAL, not OPERATIONAL "
                                                   "300 ms after the NMT start")


def test_the_watch_reports_once_and_is_armed_again_by_start():
    now = [0.0]
    lost: list[str] = []
    called = threading.Event()
    watch = HeartbeatWatch(7, 0.2, lambda m: (lost.append(m), called.set()), clock=lambda: now[0])
    watch.start()
    try:
        watch.heard(OP)
        assert not called.wait(0.15)
        now[0] = 0.25  # silent 250 ms
        assert called.wait(2.0)
        assert lost == ["no heartbeat for 250 ms (consumer time 200 ms)"] and watch.lost == lost[0]
        watch.heard(OP)  # heard again: still lost until started again
        assert watch.lost == lost[0]
        watch.start()
        assert watch.lost is None
    finally:
        watch.stop()
