"""SDO answers time out on the frames' arrival timeline (fieldbus.sdo_arrival), not on the
waiting thread's clock: an answer the master's receive thread hands over late is still the
answer; silence on the bus past the time-out, or a receive thread hung past it, is not."""

from __future__ import annotations

import threading

import can
import pytest
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError, SdoClient, SdoCommunicationError

from nurbsmotion.fieldbus import sdo_arrival
from tests.fieldbus.test_master_sim import rig

TIMEOUT_S = 0.02
SENT_S = 100.0  # the request's send time on the (injected) process clock
UPLOAD = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])  # initiate upload of 0x1000:00
ANSWER = bytes([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00])  # expedited, 4 bytes


class Wire:
    """What the master knows of the bus: the arrival timeline (``known_s``), and an answer the
    receive thread hands over at the ``hand_over_at``-th look at that timeline."""

    def __init__(self, sdo: SdoClient, known_s: list[float], hand_over_at: int | None = None) -> None:
        self.sdo, self.known_s, self.hand_over_at, self.looks = sdo, known_s, hand_over_at, 0

    def judging_time_s(self) -> float:
        self.looks += 1
        if self.looks == self.hand_over_at:
            self.sdo.responses.put(ANSWER)
        return self.known_s[min(self.looks, len(self.known_s)) - 1]


class Network:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.sent.append(bytes(data))


def client() -> SdoClient:
    sdo = SdoClient(0x601, 0x581, ObjectDictionary())
    sdo.network = Network()  # type: ignore[assignment]
    sdo.RESPONSE_TIMEOUT = TIMEOUT_S
    return sdo


def judged(known_s: list[float], hand_over_at: int | None = None) -> SdoClient:
    sdo = client()
    wire = Wire(sdo, known_s, hand_over_at)
    sdo_arrival.judge_on_arrival(sdo, wire.judging_time_s, clock=lambda: SENT_S)
    return sdo


def test_an_answer_handed_over_after_the_waiting_threads_time_out_is_the_answer():
    """Frames wait unread: the bus is known only up to the request, so the time-out has not run
    out on the bus, however long the waiting thread waited (canopen alone raises after 20 ms)."""
    sdo = judged(known_s=[SENT_S], hand_over_at=4)
    assert sdo.request_response(UPLOAD) == ANSWER


def test_silence_on_the_bus_past_the_time_out_is_no_answer():
    sdo = judged(known_s=[SENT_S, SENT_S + TIMEOUT_S / 2, SENT_S + TIMEOUT_S])
    with pytest.raises(SdoCommunicationError, match="No SDO response received"):
        sdo.request_response(UPLOAD)


def test_a_receive_thread_that_hands_nothing_over_is_given_up_on_the_process_clock():
    """The timeline stands still (frames wait and nothing is handled) and the process clock is
    past the deadline by STUCK_S: hung, not late."""
    sdo = client()
    clock = iter([SENT_S])  # the send; every look after it: past the deadline by STUCK_S
    sdo_arrival.judge_on_arrival(sdo, lambda: SENT_S,
                                 clock=lambda: next(clock, SENT_S + TIMEOUT_S + sdo_arrival.STUCK_S))
    with pytest.raises(SdoCommunicationError):
        sdo.request_response(UPLOAD)


def test_an_abort_is_raised_with_its_code():
    sdo = judged(known_s=[SENT_S])
    sdo.responses.put(bytes([0x80, 0x00, 0x10, 0x00, 0x20, 0x00, 0x00, 0x08]))
    with pytest.raises(SdoAbortedError) as err:
        sdo.read_response()
    assert err.value.code == 0x08000020


def test_bring_up_passes_when_the_masters_receive_thread_hands_an_answer_over_late():
    """Forced ordering: a frame queued just before the first SDO request holds the master's
    receive thread up for 3 SDO time-outs; the drive answers at once and its answer waits
    unread behind that frame. Before the fix: "node 1: bring-up step ...: no SDO answer"."""
    sdo_timeout_s = 0.5  # the master's default (bus.sdo_timeout_ms)
    hold_up = can.Message(arbitration_id=0x0F0, is_extended_id=False, data=b"\x00")
    with rig(bring_up=False, sdo_timeout_s=sdo_timeout_s) as (master, sim, probe):
        master.connect()
        network = master.network
        assert network is not None
        held = threading.Event()

        def receive_thread_held_up(can_id: int, data: bytearray, timestamp: float) -> None:
            if not held.is_set():
                held.set()
                threading.Event().wait(3 * sdo_timeout_s)

        network.subscribe(hold_up.arbitration_id, receive_thread_held_up)
        plain_send = network.send_message

        def send_message(can_id: int, data: bytes, remote: bool = False) -> None:
            if can_id == 0x601 and not held.is_set():
                probe.send(hold_up)  # queued ahead of the request, so ahead of the answer
                held.wait(5.0)
            plain_send(can_id, data, remote)

        network.send_message = send_message  # type: ignore[method-assign]
        master.bring_up()
        assert held.is_set() and master.status().phase == "holding"
