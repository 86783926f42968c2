"""The simulated CiA-401 I/O node's PDOs (CiA 301): TPDO1 with the inputs, sent per its
transmission type (254/255 on a change, 1..240 on every n-th SYNC, 0 on the SYNC after a
change); RPDO1 with the outputs, applied at once (254/255) or at the next SYNC (0..240).

Runs under the node's lock, in the network's receive thread (SYNC, RPDO) or the caller's
(an input change).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Protocol

import canopen
from canopen.objectdictionary import ObjectDictionary

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import EmcyCode, NmtState
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.slave import Subscriptions

READ_INPUT_8 = 0x6000
WRITE_OUTPUT_8 = 0x6200
EVENT_DRIVEN = (254, 255)
ERROR_REGISTER_COMMUNICATION = 0x11  # generic + communication error


class IoHost(Protocol):
    """What the PDOs use of their node (``sim.io_node.SimIoNode``)."""

    nmt_state: NmtState
    network: canopen.Network | None
    tpdos_sent: int

    def send(self, can_id: int, data: bytes) -> None: ...
    def send_emcy(self, code: int, register: int) -> None: ...


class IoPdos:
    """TPDO1 and RPDO1 of ``host`` over its ``inputs`` and ``outputs`` (one byte per group)."""

    def __init__(self, host: IoHost, od: ObjectDictionary, value: Callable[..., Any], inputs: bytearray,
                 outputs: bytearray, subscriptions: Subscriptions, lock: threading.RLock) -> None:
        self._host = host
        self._od = od
        self._value = value
        self._inputs = inputs
        self._outputs = outputs
        self._subscriptions = subscriptions
        self._lock = lock
        self._tpdo: pdo_layout.PdoLayout | None = None
        self._rpdo: pdo_layout.PdoLayout | None = None
        self.sync_count = 0
        self._changed_since_sync = False
        self.pending_outputs: tuple | None = None

    def _layout(self, comm: int, mapping: int) -> pdo_layout.PdoLayout | None:
        entries = [self._value(mapping, n) for n in range(1, self._value(mapping, 0) + 1)]
        layout = pdo_layout.build_layout(self._od, 1, self._value(comm, 1), self._value(comm, 2), entries)
        return layout if layout.enabled and layout.keys else None

    def rebuild(self) -> None:
        """Both PDOs from their objects again (after boot or a remap)."""
        if self._rpdo is not None:
            self._subscriptions.remove(self._rpdo.cob_id, self.on_rpdo)
        self._rpdo = self._layout(c.RPDO_COMM, c.RPDO_MAPPING)
        self._tpdo = self._layout(c.TPDO_COMM, c.TPDO_MAPPING)
        if self._rpdo is not None and self._host.network is not None:
            self._subscriptions.add(self._rpdo.cob_id, self.on_rpdo)

    def inputs_changed(self) -> None:
        self._changed_since_sync = True
        if self._tpdo is not None and self._tpdo.transmission_type in EVENT_DRIVEN:
            self._send_tpdo()

    def _send_tpdo(self) -> None:
        if self._tpdo is None or self._host.nmt_state != NmtState.OPERATIONAL:
            return
        values = [self._inputs[sub - 1] if index == READ_INPUT_8 else self._value(index, sub)
                  for index, sub in self._tpdo.keys]
        self._host.send(self._tpdo.cob_id, self._tpdo.codec.pack(*values))
        self._host.tpdos_sent += 1

    def on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            rpdo = self._rpdo
            if rpdo is None or self._host.nmt_state != NmtState.OPERATIONAL:
                return
            if len(data) < rpdo.size:
                self._host.send_emcy(EmcyCode.PDO_LENGTH, ERROR_REGISTER_COMMUNICATION)
                return
            values = rpdo.codec.unpack_from(data)
            if rpdo.synchronous:
                self.pending_outputs = values
            else:
                self._apply_outputs(values)

    def _apply_outputs(self, values: tuple) -> None:
        assert self._rpdo is not None
        for (index, sub), value in zip(self._rpdo.keys, values):
            if index == WRITE_OUTPUT_8:
                self._outputs[sub - 1] = value

    def on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self._host.nmt_state != NmtState.OPERATIONAL:
                return
            if self.pending_outputs is not None and self._rpdo is not None:
                self._apply_outputs(self.pending_outputs)
            self.pending_outputs = None
            tpdo = self._tpdo
            if tpdo is None:
                return
            kind = tpdo.transmission_type
            if 1 <= kind <= 240:
                self.sync_count += 1
                if self.sync_count >= kind:
                    self.sync_count = 0
                    self._send_tpdo()
            elif kind == 0 and self._changed_since_sync:
                self._send_tpdo()
            self._changed_since_sync = False
