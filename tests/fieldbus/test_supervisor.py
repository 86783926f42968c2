"""The supervisor's heartbeat consumer judges heartbeats as they arrived on the bus
(nurbsmotion.can.arrival_clock): a heartbeat that arrived in time but waits unread behind a late
receive thread is not a lost drive; a drive that really fell silent is reported."""

from __future__ import annotations

import time

import can

from nurbsmotion.fieldbus.controller import Phase
from nurbsmotion.fieldbus.feedback import Feedback
from nurbsmotion.fieldbus.supervisor import CycleHistory, Supervisor

HB_TIMEOUT_S = 0.25
PERIOD_S = 0.004
NODE = 1


def supervisor(feedback: Feedback) -> Supervisor:
    return Supervisor([NODE], ["X"], [1000], [10], HB_TIMEOUT_S, PERIOD_S, feedback, CycleHistory(64, 1))


def frame_handled(feedback: Feedback, arrived_ago_s: float, handled_ago_s: float, cob_id: int = 0x700 + NODE) -> None:
    """The master's notifier handled, ``handled_ago_s`` ago, a frame (by default node 1's
    heartbeat, OPERATIONAL) that arrived ``arrived_ago_s`` ago."""
    wall_s, perf_s = time.time(), time.perf_counter()
    if cob_id == 0x700 + NODE:
        feedback.heartbeat_callback(0, lambda state: None)(cob_id, bytearray(b"\x05"), wall_s - arrived_ago_s)
    feedback.arrival.arrived(perf_s - arrived_ago_s, perf_s - handled_ago_s)


def heartbeat_faults(sup: Supervisor) -> list[str]:
    sup.check(100, Phase.DISABLED, None)
    return [f.message for f in sup.faults if f.kind == "heartbeat"]


def test_a_heartbeat_that_arrived_in_time_but_waits_unread_is_not_a_loss() -> None:
    feedback = Feedback(1)
    feedback.watch_reception(lambda: True)
    # the receive thread was held 0.3 s: it handles now a heartbeat that arrived 0.3 s ago,
    # and the next ones (sent every 0.1 s) still wait in the socket
    frame_handled(feedback, arrived_ago_s=0.3, handled_ago_s=0.0)
    assert heartbeat_faults(supervisor(feedback)) == []


def test_a_silent_drive_is_reported_once_nothing_waits() -> None:
    feedback = Feedback(1)
    feedback.watch_reception(lambda: False)
    frame_handled(feedback, arrived_ago_s=0.3, handled_ago_s=0.3)  # handled at once, nothing since
    faults = heartbeat_faults(supervisor(feedback))
    assert len(faults) == 1 and "node 1 (axis X): no heartbeat for" in faults[0], faults
    silent_ms = float(faults[0].split("no heartbeat for ")[1].split(" ms")[0])
    assert 290 <= silent_ms < 400, faults


def test_a_drive_silent_while_other_frames_keep_arriving_is_reported() -> None:
    """Frames of other nodes that arrived after the consumer time show the bus up to there:
    the heartbeat missing between them is a loss even while more frames wait."""
    feedback = Feedback(1)
    feedback.watch_reception(lambda: True)
    frame_handled(feedback, arrived_ago_s=0.5, handled_ago_s=0.2)
    frame_handled(feedback, arrived_ago_s=0.01, handled_ago_s=0.0, cob_id=0x181)  # a TPDO1 of node 1
    assert len(heartbeat_faults(supervisor(feedback))) == 1


def test_the_listener_stamps_each_frame_with_its_receive_timestamp() -> None:
    """Both clocks injected: perf_counter 100 s and wall clock 5000 s when the frame is handled."""
    feedback = Feedback(1)
    perf_now, wall_now = 100.0, 5000.0
    listener = feedback.watch_reception(lambda: True, read_time=lambda: perf_now, wall_time=lambda: wall_now)
    listener.on_message_received(can.Message(arbitration_id=0x181, data=bytes(6), timestamp=wall_now - 0.2))
    assert 0.19 < perf_now - feedback.arrival.arrival_s < 0.3  # type: ignore[operator]
    assert 0.19 < feedback.arrival.lag_s < 0.3


def silent_since(heartbeat_ago_s: float, tpdo1_ago_s: float) -> Supervisor:
    """Axis X enabled and caught up; its last heartbeat and last TPDO1 arrived that long ago,
    the TPDO1 more than the consumer time in cycles before cycle 100."""
    feedback = Feedback(1)
    feedback.watch_reception(lambda: False)
    frame_handled(feedback, arrived_ago_s=heartbeat_ago_s, handled_ago_s=heartbeat_ago_s)
    feedback.status[0] = 0x0027  # OPERATION ENABLED
    feedback.time[0] = time.time() - tpdo1_ago_s
    feedback.cycle[0] = 100 - int(HB_TIMEOUT_S / PERIOD_S) - 2
    return supervisor(feedback)


def kinds_at_cycle_100(sup: Supervisor) -> list[str]:
    sup.check(100, Phase.HOLDING, None)
    return [f.kind for f in sup.faults]


def test_a_drive_silent_altogether_is_a_heartbeat_loss_not_a_missing_tpdo1() -> None:
    """Its last heartbeat came before its last TPDO1 (a killed drives' process): the TPDO1
    check leaves it to the heartbeat check, whatever tens of ms decide which runs out first."""
    assert kinds_at_cycle_100(silent_since(heartbeat_ago_s=0.2, tpdo1_ago_s=0.15)) == []
    assert kinds_at_cycle_100(silent_since(heartbeat_ago_s=0.3, tpdo1_ago_s=0.25)) == ["heartbeat"]


def test_a_drive_whose_heartbeat_goes_on_without_tpdo1_is_reported_as_missing_tpdo1() -> None:
    assert kinds_at_cycle_100(silent_since(heartbeat_ago_s=0.05, tpdo1_ago_s=0.3)) == ["following_error"]
