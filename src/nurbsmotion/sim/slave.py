"""CiA-301 slave pieces every simulated node needs (the I/O node and the drive use them).

- :class:`GatedLocalNode`: canopen's ``LocalNode`` (object dictionary + SDO server) whose
  SDO writes go through the owner (``_before_sdo_write`` may refuse with an SDO abort,
  ``_after_sdo_write`` applies effects), whose reads may be live (``_on_sdo_read``), and
  whose own SDO/NMT handlers are off so the owner can gate them by NMT state.
- :class:`Subscriptions`: the CAN ids a node listens to, removed together on detach.
- :class:`ConsumedHeartbeats`: the heartbeat consumer (0x1016) on the bus.
- :func:`addressed_command`: the NMT command of a frame if it is for this node.
- :func:`od_value`: an object's current value, decoded with its OD entry.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import canopen
from canopen.objectdictionary import ObjectDictionary, ODArray
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import NmtCommand
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.heartbeat import HeartbeatConsumer

ABORT_NO_SUBINDEX = 0x06090011
EMCY_STRUCT = struct.Struct("<HB5x")  # CiA 301 EMCY: error code, error register, 5 bytes


class SdoHooks(Protocol):
    def _before_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None: ...
    def _after_sdo_write(self, index: int, subindex: int) -> None: ...
    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> Any: ...


class GatedLocalNode(canopen.LocalNode):
    """LocalNode whose SDO traffic the owner validates, completes and gates."""

    def __init__(self, node_id: int, od: ObjectDictionary, owner: SdoHooks) -> None:
        super().__init__(node_id, od)
        self._owner = owner
        self._write_callbacks.clear()  # LocalNode's NmtSlave heartbeat is replaced by the owner's
        self.add_write_callback(owner._before_sdo_write)
        self.add_read_callback(owner._on_sdo_read)

    def set_data(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        super().set_data(index, subindex, data, check_writable)
        if check_writable:  # an SDO write from the bus
            self._owner._after_sdo_write(index, subindex)

    def _find_object(self, index: int, subindex: int) -> Any:
        """As LocalNode, but an ARRAY has only the sub-indices the OD declares."""
        obj = super()._find_object(index, subindex)
        parent = self.object_dictionary[index]
        if isinstance(parent, ODArray) and subindex not in parent.subindices:
            raise SdoAbortedError(ABORT_NO_SUBINDEX)
        return obj

    def associate_network(self, network: canopen.Network) -> None:
        """Join without LocalNode's own SDO and NMT handlers (the owner gates them)."""
        super().associate_network(network)
        network.unsubscribe(self.sdo.rx_cobid, self.sdo.on_request)
        network.unsubscribe(0, self.nmt.on_command)

    def remove_network(self) -> None:
        if self.has_network():  # LocalNode.remove_network unsubscribes what it subscribed
            self.network.subscribe(self.sdo.rx_cobid, self.sdo.on_request)
            self.network.subscribe(0, self.nmt.on_command)
        super().remove_network()


class Subscriptions:
    """Callbacks a node registered on a network, so that detach removes exactly those."""

    def __init__(self) -> None:
        self.network: canopen.Network | None = None
        self._items: list[tuple[int, Callable[..., None]]] = []

    def add(self, can_id: int, callback: Callable[..., None]) -> None:
        assert self.network is not None
        self.network.subscribe(can_id, callback)
        self._items.append((can_id, callback))

    def remove(self, can_id: int, callback: Callable[..., None]) -> None:
        if (can_id, callback) in self._items:
            self._items.remove((can_id, callback))
            assert self.network is not None
            self.network.unsubscribe(can_id, callback)

    def clear(self) -> None:
        for can_id, callback in list(self._items):
            self.remove(can_id, callback)


class ConsumedHeartbeats:
    """The producers a node watches (0x1016) and their heartbeat frames: each frame is
    stamped by ``frame_time(timestamp)`` under ``lock``."""

    def __init__(self, subscriptions: Subscriptions, lock: threading.RLock,
                 frame_time: Callable[[float], float]) -> None:
        self.consumer = HeartbeatConsumer()
        self.rx_lag_s: dict[int, float] = {}  # producer -> reception lag of its last heartbeat
        self._subscriptions = subscriptions
        self._lock = lock
        self._frame_time = frame_time
        self._cobs: list[int] = []

    def configure(self, entries: list[int]) -> None:
        """Watch the producers of these 0x1016 entries (subscribed if attached)."""
        self.consumer.configure(entries)
        for cob in self._cobs:
            self._subscriptions.remove(cob, self.on_heartbeat)
        self._cobs = [c.COB_HEARTBEAT + n for n in self.consumer.timeouts_s]
        if self._subscriptions.network is not None:
            for cob in self._cobs:
                self._subscriptions.add(cob, self.on_heartbeat)

    def forget(self) -> None:
        """Detached: the subscriptions are gone."""
        self._cobs = []

    def on_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            producer = can_id - c.COB_HEARTBEAT
            self.consumer.seen(producer, self._frame_time(timestamp))
            # how late this process handles the frame after the kernel received it (SocketCAN
            # stamps frames with wall-clock time; a process inside a starved guest lags by seconds)
            self.rx_lag_s[producer] = time.time() - timestamp if timestamp > 1e9 else 0.0


def addressed_command(data: bytes, node_id: int) -> NmtCommand | None:
    """The NMT command of a frame on COB-ID 0 if it addresses ``node_id`` or all (0)."""
    if len(data) < 2 or data[1] not in (0, node_id):
        return None
    try:
        return NmtCommand(data[0])
    except ValueError:
        return None


def od_value(node: canopen.LocalNode, od: ObjectDictionary, index: int, subindex: int = 0) -> Any:
    """The current value of (index, subindex), as an SDO upload would read it."""
    var = pdo_layout.find_variable(od, index, subindex)
    assert var is not None, (hex(index), subindex)
    return var.decode_raw(node.get_data(index, subindex))
