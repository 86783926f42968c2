"""SDO client time-outs judged on the frames' arrival timeline (nurbsmotion.can.arrival_clock).

canopen's ``SdoClient`` waits ``RESPONSE_TIMEOUT`` for an answer on the waiting thread's own
clock (``queue.get``), and the answer reaches that queue only once the master's receive thread
has handed it over. When that thread is late (the CPU or the GIL taken by other work), an
answer that arrived in time reads as silence: on the 2-core test host under load the drive's
answer was stamped 6 ms after the request and handed over 462 ms later (a 554 ms round trip
against the 500 ms default time-out; docs/reliability.md, "Flakes").

CiA 301's SDO time-out is how long the server takes to answer on the bus. So here it runs out
only when the bus is known past ``request sent + RESPONSE_TIMEOUT`` on the arrival timeline:
``judging_time_s()`` is the master's (while frames wait unread, the arrival of the last frame
handled; then real time on from there), as its heartbeat consumer judges. A receive thread that
hands nothing over for STUCK_S past the deadline (process clock) ends the wait too: it is hung,
not late.

Answers are matched to their request on the way (fieldbus.sdo_match): a frame that answers
another request (a late answer to one that timed out) is dropped with one log line, and the
wait goes on to the same deadline.
"""

from __future__ import annotations

import logging
import queue
import struct
import time
from typing import Callable

from canopen.sdo import SdoAbortedError, SdoClient, SdoCommunicationError
from canopen.sdo.constants import REQUEST_ABORTED, RESPONSE_ABORTED

from nurbsmotion.fieldbus import sdo_match
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

STUCK_S = 5.0  # a receive thread silent this long past the deadline is hung: give up on the process clock
MIN_WAIT_S = 0.005  # least wait while the arrival timeline stands still (frames wait unread)


def judge_on_arrival(sdo: SdoClient, judging_time_s: Callable[[], float],
                     clock: Callable[[], float] = time.perf_counter) -> None:
    """Make ``sdo`` (one node's canopen client) time its answers out on ``judging_time_s()``
    (the ``clock`` timeline, perf_counter: Feedback.judging_time_s) from the moment each
    request is sent, or the last answer was taken (module docstring); an answer to another
    request is dropped; an abort is raised as canopen raises it."""
    plain_send = sdo.send_request
    sent_s = [0.0]  # the last request's send time, or the last answer's (a block transfer's next segment)
    transfer_obj = [sdo_match.NO_OBJECT]  # the object of the transfer under way (its initiate request's)
    expected: list[sdo_match.ExpectedAnswer | None] = [None]

    def send_request(request: bytes) -> None:
        if request[0] & sdo_match.COMMAND_MASK != REQUEST_ABORTED:  # the client's abort has no answer
            if sdo_match.is_initiate(request):
                transfer_obj[0] = sdo_match.multiplexer(request)
            expected[0] = sdo_match.expected_answer(request, transfer_obj[0])
        sent_s[0] = clock()
        plain_send(request)

    def read_response() -> bytes:
        deadline_s = sent_s[0] + sdo.RESPONSE_TIMEOUT
        while True:
            try:
                response = sdo.responses.get(timeout=max(deadline_s - judging_time_s(), MIN_WAIT_S))
            except queue.Empty:
                if judging_time_s() >= deadline_s or clock() >= deadline_s + STUCK_S:
                    raise SdoCommunicationError("No SDO response received") from None
                continue
            want = expected[0]
            if want is None or want.accepts(response):
                break
            log.warning(kv("sdo_answer_dropped", node=sdo.rx_cobid - 0x600, answer=sdo_match.describe(response),
                           waiting_for=f"0x{want.obj[0]:04X}:{want.obj[1]:02X}",
                           reason="answers another request (a late answer to one that timed out?)"))
        sent_s[0] = clock()  # a block upload's segments come without a request each: time the next from here
        if response[0] == RESPONSE_ABORTED:  # as canopen's read_response: the server's abort code
            raise SdoAbortedError(struct.unpack_from("<L", response, 4)[0])
        return response

    sdo.send_request = send_request  # type: ignore[method-assign]
    sdo.read_response = read_response  # type: ignore[method-assign]
