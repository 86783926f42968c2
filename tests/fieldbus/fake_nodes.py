"""Nodes that answer a scan partly or wrongly, built from raw frames on a canopen network:
a heartbeat without any SDO server, an SDO server that knows only some objects (the others
answer with an abort), and anything in between. Expedited uploads only (values of at most 4
bytes); a request for anything else is aborted with 0x06020000."""

from __future__ import annotations

import struct
from typing import Any

import canopen

ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_HARDWARE = 0x06060000


class FakeNode:
    """``objects`` {(index, subindex): int value (4 bytes) | bytes (1-4) | ("abort", code)};
    ``sdo`` False: no SDO server at all; ``heartbeat_state`` not None: that state byte every
    ``heartbeat_period_s``."""

    def __init__(self, network: canopen.Network, node_id: int, objects: dict[tuple[int, int], Any] | None = None,
                 *, sdo: bool = True, heartbeat_state: int | None = None, heartbeat_period_s: float = 0.05) -> None:
        self.network, self.node_id = network, node_id
        self.objects = dict(objects or {})
        self.requests: list[tuple[int, int]] = []
        self.other_frames: list[bytes] = []
        self._heartbeat = None
        if sdo:
            network.subscribe(0x600 + node_id, self._on_request)
        if heartbeat_state is not None:
            self._heartbeat = network.send_periodic(0x700 + node_id, bytes([heartbeat_state]), heartbeat_period_s)

    def close(self) -> None:
        if self._heartbeat is not None:
            self._heartbeat.stop()

    def _on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data[0] != 0x40:  # not an initiate upload: a download or the client's abort
            self.other_frames.append(bytes(data))
            return
        index, subindex = struct.unpack_from("<HB", data, 1)
        self.requests.append((index, subindex))
        value = self.objects.get((index, subindex), ("abort", ABORT_NO_OBJECT))
        if isinstance(value, tuple):
            answer = struct.pack("<BHBI", 0x80, index, subindex, value[1])
        else:
            raw = value.to_bytes(4, "little") if isinstance(value, int) else bytes(value)
            command = 0x43 | (4 - len(raw)) << 2
            answer = struct.pack("<BHB", command, index, subindex) + raw.ljust(4, b"\x00")
        self.network.send_message(0x580 + self.node_id, answer)


def drive_objects(vendor: int, product: int, *, modes: int | None = 0x1E4) -> dict[tuple[int, int], Any]:
    """A minimal CiA 402 servo: 0x1000, 0x1018:01/02 and (if given) 0x6502."""
    objects: dict[tuple[int, int], Any] = {(0x1000, 0): 0x00020192, (0x1018, 1): vendor, (0x1018, 2): product}
    if modes is not None:
        objects[(0x6502, 0)] = modes
    return objects
