"""The simulated drive's PDOs (CiA 301 §7.2.2): layouts from the mapping the master wrote,
RPDO data kept until the next SYNC (synchronous) or applied at once, TPDOs sent on SYNC.

A PDO counts when both its communication and mapping objects exist in the EDS. Every
remap (an SDO write to 0x14xx-0x1Axx) rebuilds all of them: the structs, the value setters
and getters (live objects of the axis, else the object dictionary) and the subscriptions.
Called with the drive's lock held (sim.drive).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
from canopen.sdo import SdoAbortedError

from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.drive_objects import DriveObjects
from nurbsmotion.sim.rpdo_timers import RpdoTimers
from nurbsmotion.sim.slave import Subscriptions
from nurbsmotion.sim.stats import DriveStats

RPDO_EVENT_TIMER_SUB = 5  # 0x14xx:05, ms: deadline for the next RPDO (0 = none)


@dataclass
class TpdoSlot:
    layout: pdo_layout.PdoLayout
    message: can.Message
    getters: list[Callable[[], Any]]
    sync_count: int = 0
    last_data: bytes = b""


@dataclass
class RpdoSlot:
    layout: pdo_layout.PdoLayout
    setters: list[Callable[[Any], None]]


def apply_values(setters: list[Callable[[Any], None]], values: tuple, stats: DriveStats) -> None:
    """RPDO values into the drive; a value the object refuses is counted, not applied."""
    for setter, value in zip(setters, values):
        try:
            setter(value)
        except SdoAbortedError:
            stats.pdo_values_refused += 1


class DrivePdos:
    """RPDOs by COB-ID, TPDOs in order, and the RPDO data waiting for the next SYNC."""

    def __init__(self, objects: DriveObjects, subscriptions: Subscriptions, stats: DriveStats,
                 rpdo_timers: RpdoTimers, on_rpdo: Callable[[int, bytes, float], None],
                 parameters_changed: Callable[[], None]) -> None:
        """``on_rpdo``: the drive's handler subscribed for each RPDO; ``parameters_changed``:
        a stored value written by a PDO (the drive reloads what SYNC handling uses)."""
        self.objects = objects
        self.subscriptions = subscriptions
        self.stats = stats
        self.rpdo_timers = rpdo_timers
        self.on_rpdo = on_rpdo
        self.parameters_changed = parameters_changed
        self.rpdo_by_cob: dict[int, RpdoSlot] = {}
        self.tpdos: list[TpdoSlot] = []
        self.pending: dict[int, tuple[list[Callable[[Any], None]], tuple]] = {}

    # ------------------------------------------------------------------ layouts
    def _layout(self, comm_index: int, number: int) -> pdo_layout.PdoLayout:
        value_or = self.objects.value_or
        cob_id = value_or(comm_index, 1, pdo_layout.COB_ID_INVALID_BIT)
        transmission_type = value_or(comm_index, 2, 255)
        map_index = comm_index + pdo_layout.MAPPING_OFFSET
        mapping = [value_or(map_index, n, 0) for n in range(1, self.objects.value(map_index, 0) + 1)]
        return pdo_layout.build_layout(self.objects.od, number, cob_id, transmission_type, mapping)

    def _numbers(self, comm_range: range) -> list[tuple[int, int]]:
        """(number, communication index) of the PDOs the EDS has (both objects present)."""
        od = self.objects.od
        return [(index - comm_range.start + 1, index) for index in comm_range
                if index in od and index + pdo_layout.MAPPING_OFFSET in od]

    def rebuild(self, attached: bool) -> None:
        """Recompute every PDO's struct, setters/getters and subscription (after a remap)."""
        for cob_id in list(self.rpdo_by_cob):
            self.subscriptions.remove(cob_id, self.on_rpdo)
        self.rpdo_by_cob.clear()
        self.tpdos = []
        event_timers: dict[int, float] = {}
        for number, comm in self._numbers(pdo_layout.RPDO_COMM_RANGE):
            layout = self._layout(comm, number)
            if layout.enabled and layout.keys:
                if layout.cob_id not in self.rpdo_by_cob and attached:
                    self.subscriptions.add(layout.cob_id, self.on_rpdo)
                self.rpdo_by_cob[layout.cob_id] = RpdoSlot(layout, [self._setter(key) for key in layout.keys])
                event_timers[number] = self.objects.value_or(comm, RPDO_EVENT_TIMER_SUB, 0) / 1000.0
        for number, comm in self._numbers(pdo_layout.TPDO_COMM_RANGE):
            layout = self._layout(comm, number)
            if layout.enabled and layout.keys:
                message = can.Message(arbitration_id=layout.cob_id, is_extended_id=False, data=bytearray(layout.size))
                self.tpdos.append(TpdoSlot(layout, message, [self.objects.getter(key) for key in layout.keys]))
        self.rpdo_timers.configure(event_timers)
        self.pending.clear()

    def _setter(self, key: tuple[int, int]) -> Callable[[Any], None]:
        store = self.objects.setter(key)
        if key in self.objects.live_write:
            return store

        def store_value(value: Any) -> None:
            store(value)
            self.parameters_changed()

        return store_value

    def forget(self) -> None:
        """Detached: no RPDO is subscribed any more."""
        self.rpdo_by_cob.clear()

    def restart(self) -> None:
        """NMT OPERATIONAL entered: nothing pending, TPDO counters from zero."""
        self.pending.clear()
        for slot in self.tpdos:
            slot.sync_count = 0
            slot.last_data = b""

    # ------------------------------------------------------------------ traffic
    def receive(self, slot: RpdoSlot, data: bytes) -> None:
        """A valid RPDO: a synchronous one waits for the next SYNC (the last one wins), an
        asynchronous one is applied at once."""
        values = slot.layout.codec.unpack_from(data)
        if slot.layout.synchronous:
            if slot.layout.number in self.pending:
                self.stats.rpdos_overwritten += 1
            self.pending[slot.layout.number] = (slot.setters, values)
        else:
            apply_values(slot.setters, values, self.stats)

    def apply_pending(self) -> None:
        """At SYNC: the RPDO data received since the previous SYNC (CiA 301)."""
        for setters, values in self.pending.values():
            apply_values(setters, values, self.stats)
        self.pending.clear()

    def send_tpdos(self, network: Any) -> None:
        """TPDOs of this SYNC: type 1..240 every n-th SYNC; 0, 254, 255 when the data
        changed; 241..253 never."""
        for slot in self.tpdos:
            kind = slot.layout.transmission_type
            if 1 <= kind <= 240:
                slot.sync_count += 1
                if slot.sync_count < kind:
                    continue
                slot.sync_count = 0
            elif 241 <= kind <= 253:
                continue
            data = slot.message.data
            slot.layout.codec.pack_into(data, 0, *[getter() for getter in slot.getters])
            if kind == 0 or kind >= 254:
                if data == slot.last_data:
                    continue
                slot.last_data = bytes(data)
            with network.send_lock:
                if network.bus is not None:
                    network.bus.send(slot.message)
            self.stats.tpdos_sent += 1
