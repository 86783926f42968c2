"""Which SDO answer belongs to the request under way (CiA 301 §7.2.4.3).

canopen's ``SdoClient`` takes the first frame on the node's response COB-ID as the answer to
its request: it empties its queue before sending, but an answer that comes after that (a late
answer to an earlier request that had timed out) is taken as this request's. Then a download
reads "Unexpected response 0x4B" (a 2-byte expedited upload answer) and a read of 0x606C may
return 0x6041's value. Seen on vcan0 with the spindle node (docs/reliability.md, "Flakes").

An answer belongs to a request when its server command specifier (bits 7-5) is the one
CiA 301 gives for the request's client command specifier and it names the same object:

====================== ====================== ========================================
request (ccs)          answer (scs)           must carry
====================== ====================== ========================================
initiate download (1)  initiate download (3)  the request's index and subindex
initiate upload (2)    initiate upload (2)    the request's index and subindex
download segment (0)   download segment (1)   the request's toggle bit (bit 4)
upload segment (3)     upload segment (0)     the request's toggle bit (bit 4)
====================== ====================== ========================================

An abort (scs 4) belongs to any of them when it names the transfer's object (the initiate
request's index and subindex), or none (0x0000:00, a server that leaves it out). Block
transfers and the client's own abort are not judged (None): canopen's checks apply as before.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from canopen.sdo.constants import (REQUEST_DOWNLOAD, REQUEST_SEGMENT_DOWNLOAD,
                                   REQUEST_SEGMENT_UPLOAD, REQUEST_UPLOAD, RESPONSE_ABORTED, RESPONSE_DOWNLOAD,
                                   RESPONSE_SEGMENT_DOWNLOAD, RESPONSE_SEGMENT_UPLOAD, RESPONSE_UPLOAD, TOGGLE_BIT)

COMMAND_MASK = 0xE0  # bits 7-5: the command specifier
MULTIPLEXER = struct.Struct("<HB")  # index, subindex in bytes 1-3
NO_OBJECT = (0, 0)

ANSWER_OF = {  # client command specifier -> the server command specifier that answers it
    REQUEST_DOWNLOAD: RESPONSE_DOWNLOAD,
    REQUEST_UPLOAD: RESPONSE_UPLOAD,
    REQUEST_SEGMENT_DOWNLOAD: RESPONSE_SEGMENT_DOWNLOAD,
    REQUEST_SEGMENT_UPLOAD: RESPONSE_SEGMENT_UPLOAD,
}
INITIATES = (REQUEST_DOWNLOAD, REQUEST_UPLOAD)


def multiplexer(frame: bytes) -> tuple[int, int]:
    """(index, subindex) of an initiate or abort frame."""
    return MULTIPLEXER.unpack_from(frame, 1)


@dataclass(frozen=True)
class ExpectedAnswer:
    """What the answer to one request looks like (module docstring)."""

    command: int  # the server command specifier (bits 7-5 set as in the frame)
    obj: tuple[int, int]  # the transfer's index, subindex
    toggle: int | None  # a segment's toggle bit (bit 4), None for an initiate

    def accepts(self, answer: bytes) -> bool:
        if len(answer) < 4:
            return False
        command = answer[0] & COMMAND_MASK
        if command == RESPONSE_ABORTED:
            return multiplexer(answer) in (self.obj, NO_OBJECT)
        if command != self.command:
            return False
        if self.toggle is None:
            return multiplexer(answer) == self.obj
        return answer[0] & TOGGLE_BIT == self.toggle


def expected_answer(request: bytes, transfer_obj: tuple[int, int]) -> ExpectedAnswer | None:
    """The answer ``request`` waits for; ``transfer_obj``: the object of the transfer under
    way (a segment's request does not name it). None: not judged (block transfer, abort)."""
    command = request[0] & COMMAND_MASK
    answer = ANSWER_OF.get(command)
    if answer is None:
        return None
    if command in INITIATES:
        return ExpectedAnswer(answer, multiplexer(request), None)
    return ExpectedAnswer(answer, transfer_obj, request[0] & TOGGLE_BIT)


def is_initiate(request: bytes) -> bool:
    """An initiate upload or download: it names the transfer's object."""
    return request[0] & COMMAND_MASK in INITIATES


def describe(frame: bytes) -> str:
    """A frame as hex bytes for a log line."""
    return frame.hex(" ")
