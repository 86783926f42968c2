"""SDO answers are matched to their request (fieldbus.sdo_match, used by fieldbus.sdo_arrival):
a late answer to an earlier request that arrives while another request waits is dropped with
one log line, and the client waits on for its own answer until its time-out."""

from __future__ import annotations

import logging

import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from nurbsmotion.fieldbus import sdo_match
from tests.fieldbus.test_sdo_arrival import SENT_S, TIMEOUT_S, client
from nurbsmotion.fieldbus import sdo_arrival

READ_6041 = bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0])
ANSWER_6041 = bytes([0x4B, 0x41, 0x60, 0x00, 0x37, 0x06, 0, 0])  # expedited upload, 2 bytes
READ_606C = bytes([0x40, 0x6C, 0x60, 0x00, 0, 0, 0, 0])
ANSWER_606C = bytes([0x43, 0x6C, 0x60, 0x00, 0x00, 0x20, 0x03, 0x00])  # expedited upload, 4 bytes
WRITE_60FF = bytes([0x23, 0xFF, 0x60, 0x00, 0x00, 0x20, 0x03, 0x00])  # expedited download, 4 bytes
ANSWER_60FF = bytes([0x60, 0xFF, 0x60, 0x00, 0, 0, 0, 0])
ABORT_60FF = bytes([0x80, 0xFF, 0x60, 0x00, 0x20, 0x00, 0x00, 0x08])
ABORT_6041 = bytes([0x80, 0x41, 0x60, 0x00, 0x20, 0x00, 0x00, 0x08])


@pytest.mark.parametrize(("request_frame", "answer", "belongs"), [
    (WRITE_60FF, ANSWER_60FF, True),
    (WRITE_60FF, ANSWER_6041, False),  # the vcan lane's "Unexpected response 0x4B"
    (WRITE_60FF, ANSWER_606C, False),  # ... and 0x43
    (WRITE_60FF, bytes([0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0]), False),  # a download answer for 0x6040
    (READ_606C, ANSWER_606C, True),
    (READ_606C, ANSWER_6041, False),  # canopen would return 0x6041's value as 0x606C's... or refuse it
    (READ_606C, ANSWER_60FF, False),
    (WRITE_60FF, ABORT_60FF, True),
    (WRITE_60FF, ABORT_6041, False),
    (WRITE_60FF, bytes([0x80, 0, 0, 0, 0x20, 0, 0, 0x08]), True),  # an abort that names no object
    (WRITE_60FF, bytes([0x60, 0xFF]), False),  # too short to name anything
])
def test_an_initiate_request_takes_only_its_own_answer(request_frame, answer, belongs):
    expected = sdo_match.expected_answer(request_frame, sdo_match.NO_OBJECT)
    assert expected is not None and expected.accepts(answer) is belongs


def test_a_segment_takes_the_answer_of_its_own_toggle_and_an_abort_of_its_transfer():
    transfer = (0x1008, 0)
    upload_segment = bytes([0x70, 0, 0, 0, 0, 0, 0, 0])  # ccs 3, toggle 1
    expected = sdo_match.expected_answer(upload_segment, transfer)
    assert expected is not None
    assert expected.accepts(bytes([0x10, 0x61, 0x62, 0, 0, 0, 0, 0]))  # scs 0, toggle 1
    assert not expected.accepts(bytes([0x00, 0x61, 0x62, 0, 0, 0, 0, 0]))  # toggle 0: the segment before
    assert not expected.accepts(ANSWER_6041)
    assert expected.accepts(bytes([0x80, 0x08, 0x10, 0x00, 0x20, 0, 0, 0x08]))
    assert not expected.accepts(ABORT_6041)
    download_segment = bytes([0x00, 1, 2, 3, 4, 5, 6, 7])  # ccs 0, toggle 0
    expected = sdo_match.expected_answer(download_segment, transfer)
    assert expected is not None and expected.accepts(bytes([0x20, 0, 0, 0, 0, 0, 0, 0]))
    assert not expected.accepts(bytes([0x30, 0, 0, 0, 0, 0, 0, 0]))


def test_block_transfers_and_the_clients_abort_are_not_judged():
    assert sdo_match.expected_answer(bytes([0xA4, 0x08, 0x10, 0, 127, 0, 0, 0]), sdo_match.NO_OBJECT) is None
    assert sdo_match.expected_answer(bytes([0x80, 0, 0, 0, 0, 0, 0x04, 0x05]), sdo_match.NO_OBJECT) is None


class StaleWire:
    """The bus as the waiting client sees it: ``stale`` answers arrive after the client has
    emptied its queue and sent, then (``own``) its own answer; the arrival timeline stands at
    the send until everything queued is taken, then runs past the time-out."""

    def __init__(self, stale: list[bytes], own: bytes | None) -> None:
        self.sdo = client()
        self.frames = [*stale, *([own] if own is not None else [])]
        sdo_arrival.judge_on_arrival(self.sdo, self.judging_time_s, clock=lambda: SENT_S)
        plain_send = self.sdo.network.send_message

        def send_message(can_id: int, data: bytes, remote: bool = False) -> None:
            plain_send(can_id, data, remote)
            if data[0] != 0x80:  # not the client's own abort
                for frame in self.frames:
                    self.sdo.on_response(0x581, frame, 0.0)

        self.sdo.network.send_message = send_message  # type: ignore[method-assign]

    def judging_time_s(self) -> float:
        return SENT_S if not self.sdo.responses.empty() else SENT_S + TIMEOUT_S


def test_a_late_upload_answer_during_a_download_is_dropped_and_the_own_answer_taken(caplog):
    """Before the match: SdoCommunicationError('Unexpected response 0x4B')."""
    wire = StaleWire([ANSWER_6041], ANSWER_60FF)
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.fieldbus.sdo_arrival"):
        wire.sdo.download(0x60FF, 0, WRITE_60FF[4:8])
    dropped = [r.getMessage() for r in caplog.records if "sdo_answer_dropped" in r.getMessage()]
    assert len(dropped) == 1 and "4b 41 60 00 37 06 00 00" in dropped[0] and "0x60FF:00" in dropped[0]


def test_a_late_answer_of_another_object_is_not_read_as_this_ones_value():
    wire = StaleWire([ANSWER_6041], ANSWER_606C)
    assert wire.sdo.upload(0x606C, 0) == ANSWER_606C[4:8]


def test_only_a_late_answer_and_then_silence_is_a_time_out_not_a_wrong_answer():
    wire = StaleWire([ANSWER_6041, ANSWER_606C], None)
    with pytest.raises(SdoCommunicationError, match="No SDO response received"):
        wire.sdo.download(0x60FF, 0, WRITE_60FF[4:8])
    assert wire.sdo.network.sent[-1][0] == 0x80  # canopen aborts the transfer it gave up


def test_the_abort_of_the_own_request_is_still_raised():
    wire = StaleWire([ABORT_6041], ABORT_60FF)
    with pytest.raises(SdoAbortedError) as err:
        wire.sdo.download(0x60FF, 0, WRITE_60FF[4:8])
    assert err.value.code == 0x08000020
