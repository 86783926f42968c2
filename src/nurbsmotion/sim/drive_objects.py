"""The simulated drive's object dictionary as the bus sees it: the EDS's objects, the drive's
stored parameters, the live objects of the CiA-402 axis, and the SDO server's checks.

canopen's ``LocalNode`` (sim.slave.GatedLocalNode) serves SDO; this module is its owner:
a write is validated before it is stored (CiA 301 rules the EDS cannot express, the drive's
own refusals, injected SDO aborts) and its effect applied after (``written``: the drive
rebuilds its PDOs, its heartbeat consumer or its cached parameters). An entry never written
reads as its EDS value, or 0 if the EDS gives none.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c
from nurbsmotion.sim import eds as eds_rules
from nurbsmotion.sim import homing, velocity
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.axis import Cia402Axis, UnsupportedMode
from nurbsmotion.sim.eds import find_variable
from nurbsmotion.sim.slave import GatedLocalNode, od_value

ABORT_WRITE_ONLY = 0x06010001
ABORT_PARAMETER_INCOMPATIBLE = 0x06040043
ABORT_VALUE_RANGE = 0x06090030  # CiA 301: value range of parameter exceeded
IP_LINEAR = 0  # 0x60C0 sub-mode
SYNC_COUNTER_OVERFLOW = 0x1019  # 0 = SYNC without counter, 2..240 = counter 1..value


def subindices(entry: ODArray | ODRecord | ODVariable) -> list[int]:
    """The sub-indices of a record or array entry (none for a plain variable)."""
    return list(entry.subindices) if isinstance(entry, (ODArray, ODRecord)) else []


class DriveNode(GatedLocalNode):
    """The drive's gated LocalNode (sim.slave): SDO writes validated before and applied after
    by DriveObjects; an entry never written reads as its EDS value."""

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        """As LocalNode, but an entry never written holds its EDS value, or 0 if the EDS gives
        none (``eds.initial_data``), instead of an abort."""
        obj = self._find_object(index, subindex)
        if check_readable and not obj.readable:
            raise SdoAbortedError(ABORT_WRITE_ONLY)
        for callback in self._read_callbacks:
            result = callback(index=index, subindex=subindex, od=obj)
            if result is not None:
                return obj.encode_raw(result)
        stored = self.data_store.get(index, {}).get(subindex)
        return stored if stored is not None else eds_rules.initial_data(obj)


class DriveObjects:
    """Object dictionary, stored parameters and SDO hooks of drive ``node_id`` (module docstring)."""

    def __init__(self, node_id: int, eds_path: Path, parameters: dict[tuple[int, int], int],
                 identity: tuple[int, int] | None) -> None:
        self.node_id = node_id
        self.eds_path = eds_path
        self.od = canopen.import_od(str(eds_path), node_id)
        self.node = DriveNode(node_id, self.od, self)
        self.stored = self._encode_parameters(parameters)  # restored on every reset
        if identity is not None:
            self.stored[(c.IDENTITY, 1)] = struct.pack("<I", identity[0])
            self.stored[(c.IDENTITY, 2)] = struct.pack("<I", identity[1])
        self.live_read: dict[tuple[int, int], Callable[[], Any]] = {}
        self.live_write: dict[tuple[int, int], Callable[[Any], None]] = {}
        self.axis: Cia402Axis | None = None
        self.refusal: Callable[[int, int], None] = lambda index, subindex: None  # injected SDO aborts
        self.written: Callable[[int, int], None] = lambda index, subindex: None  # the drive applies a write

    def serve(self, axis: Cia402Axis) -> None:
        """The axis whose objects (statusword, set-points, mode ...) are read and written live."""
        self.axis = axis
        self.live_read = {
            (c.STATUSWORD, 0): lambda: axis.statusword,
            (c.CONTROLWORD, 0): lambda: axis.controlword,
            (c.MODES_OF_OPERATION, 0): lambda: axis.mode,
            (c.MODES_OF_OPERATION_DISPLAY, 0): lambda: axis.mode_display,
            (c.POSITION_ACTUAL, 0): lambda: axis.position_actual,
            (c.FOLLOWING_ERROR_ACTUAL, 0): lambda: axis.following_error,
            (c.TARGET_POSITION, 0): lambda: axis.target_position,
            (c.IP_DATA_RECORD, 1): lambda: axis.ip_setpoint,
            (velocity.TARGET_VELOCITY, 0): lambda: axis.target_velocity,
            (velocity.VELOCITY_ACTUAL, 0): lambda: axis.velocity_actual,
            (c.ERROR_CODE, 0): lambda: axis.error_code,
            (c.ERROR_REGISTER, 0): lambda: axis.error_register,
            (c.PREDEFINED_ERROR_FIELD, 0): lambda: len(axis.error_history),
        }
        self.live_write = {
            (c.CONTROLWORD, 0): axis.set_controlword,
            (c.MODES_OF_OPERATION, 0): self._set_mode,
            (c.TARGET_POSITION, 0): axis.set_target_position,
            (c.IP_DATA_RECORD, 1): axis.set_ip_setpoint,
            (velocity.TARGET_VELOCITY, 0): axis.set_target_velocity,
        }

    # ------------------------------------------------------------------ values
    def value(self, index: int, subindex: int = 0) -> Any:
        """An object's current value, as an SDO upload would read it."""
        return od_value(self.node, self.od, index, subindex)

    def value_or(self, index: int, subindex: int, missing: Any) -> Any:
        """An object's value, ``missing`` if the EDS does not have it."""
        if find_variable(self.od, index, subindex) is None:
            return missing
        return self.value(index, subindex)

    def getter(self, key: tuple[int, int]) -> Callable[[], Any]:
        """How a TPDO reads the object: live from the axis, else from the dictionary."""
        live = self.live_read.get(key)
        if live is not None:
            return live
        return lambda: self.value(*key)

    def setter(self, key: tuple[int, int]) -> Callable[[Any], None]:
        """How an RPDO writes the object: live into the axis, else stored in the dictionary."""
        live = self.live_write.get(key)
        if live is not None:
            return live
        var = find_variable(self.od, *key)
        assert var is not None
        store = self.node.data_store

        def store_value(value: Any) -> None:
            store.setdefault(key[0], {})[key[1]] = var.encode_raw(value)

        return store_value

    def _encode_parameters(self, parameters: dict[tuple[int, int], int]) -> dict[tuple[int, int], bytes]:
        encoded = {}
        for (index, subindex), value in parameters.items():
            var = find_variable(self.od, index, subindex)
            if var is None:
                raise ValueError(f"node {self.node_id}: no object 0x{index:04X} sub {subindex} in {self.eds_path}")
            encoded[(index, subindex)] = var.encode_raw(value)
        return encoded

    def stored_mode(self) -> int:
        """0x6060 after a reset: the stored value, the EDS value or default, else 0 (no mode)."""
        var = find_variable(self.od, c.MODES_OF_OPERATION, 0)
        if var is None:
            return 0
        stored = self.stored.get((c.MODES_OF_OPERATION, 0))
        if stored:
            return int(var.decode_raw(stored))
        value = var.value if var.value is not None else var.default
        return int(value or 0)

    def reset(self, reset_application: bool) -> None:
        """Stored values back: all of them, or the communication objects only (0x1000-0x1FFF)."""
        store = self.node.data_store
        for index in list(store):
            if reset_application or 0x1000 <= index <= 0x1FFF:
                del store[index]
        for (index, subindex), data in self.stored.items():
            if reset_application or 0x1000 <= index <= 0x1FFF:
                store.setdefault(index, {})[subindex] = data

    def consumer_entries(self) -> list[int]:
        """The 0x1016 entries (none if the EDS has no 0x1016)."""
        if c.CONSUMER_HEARTBEAT_TIME not in self.od:
            return []
        subs = [n for n in subindices(self.od[c.CONSUMER_HEARTBEAT_TIME]) if n > 0]
        return [self.value(c.CONSUMER_HEARTBEAT_TIME, n) for n in subs]

    def _set_mode(self, mode: int) -> None:
        assert self.axis is not None
        try:
            self.axis.set_mode(mode)
        except UnsupportedMode:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID) from None

    def _homing_method_accepted(self, method: int) -> bool:
        """0x6098 takes the methods ``sim.homing`` implements and the drive's own default
        (a drive takes back what it reports; starting an unimplemented one is a homing error)."""
        var = find_variable(self.od, homing.HOMING_OBJECTS[0][0], 0)
        default = var.value if var is not None and var.value is not None else (var.default if var is not None else None)
        return homing.supported(method) or method == default

    # ------------------------------------------------------------------ SDO server hooks (sim.slave.SdoHooks)
    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> Any:
        getter = self.live_read.get((index, subindex))
        if getter is not None:
            return getter()
        if index == c.PREDEFINED_ERROR_FIELD and self.axis is not None:
            history = self.axis.error_history
            return history[subindex - 1] if subindex <= len(history) else 0
        return None

    def _before_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Validate an SDO write (raise SdoAbortedError to refuse) and apply live objects."""
        self.refusal(index, subindex)
        value = od.decode_raw(data)
        pdo_layout.check_parameter_write(self.od, self.value, index, subindex, value)
        eds_rules.check_range(od, value)
        if index == c.CONSUMER_HEARTBEAT_TIME and subindex > 0:
            self._check_consumer_entry(subindex, value)
        elif index == SYNC_COUNTER_OVERFLOW:
            self._check_sync_counter_overflow(value)
        elif index == c.PREDEFINED_ERROR_FIELD:
            if subindex != 0 or value != 0:
                raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
            assert self.axis is not None
            self.axis.error_history.clear()
        elif index in (c.SYNC_COB_ID, c.EMCY_COB_ID) and value & pdo_layout.COB_ID_EXTENDED_BIT:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        elif index == c.IP_SUB_MODE and value != IP_LINEAR:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)  # only linear interpolation
        elif index == homing.HOMING_OBJECTS[0][0] and not self._homing_method_accepted(value):
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # a method this drive does not have (as Elmo beyond 35)
        setter = self.live_write.get((index, subindex))
        if setter is not None:
            setter(value)

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        self.written(index, subindex)

    def _check_consumer_entry(self, subindex: int, value: int) -> None:
        """CiA 301 7.5.2.33: two 0x1016 entries with the same producer and a time > 0 are
        refused (0x06040043)."""
        producer = (value >> 16) & 0xFF
        if producer == 0 or value & 0xFFFF == 0:
            return
        subs = [n for n in subindices(self.od[c.CONSUMER_HEARTBEAT_TIME]) if n > 0 and n != subindex]
        for n in subs:
            other = self.value(c.CONSUMER_HEARTBEAT_TIME, n)
            if (other >> 16) & 0xFF == producer and other & 0xFFFF:
                raise SdoAbortedError(ABORT_PARAMETER_INCOMPATIBLE)

    def _check_sync_counter_overflow(self, value: int) -> None:
        """CiA 301 7.5.2.22: 0x1019 changes only while 0x1006 is 0 (0x08000022); 0 or 2..240."""
        if self.value_or(c.COMM_CYCLE_PERIOD, 0, 0) != 0:
            raise SdoAbortedError(pdo_layout.ABORT_DEVICE_STATE)
        if value == 1 or value > 240:
            raise SdoAbortedError(eds_rules.ABORT_VALUE_INVALID)
