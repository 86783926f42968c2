"""Bring-up steps done by SDO and NMT before the cyclic loop starts (blocking, per node).

Order (CiA 301/402): NMT reset communication -> wait for every boot-up message -> identity
check (0x1018) -> supported modes (0x6502) -> configuration writes in PRE-OPERATIONAL (see
:func:`nurbsmotion.fieldbus.pdo.drive_configuration`) -> read position actual. Every failure
raises FieldbusError naming the node and the step.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Any, Iterable

from canopen.sdo import SdoAbortedError, SdoCommunicationError

from nurbsmotion import cia402 as c
from nurbsmotion.config import AxisConfig
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.pdo import ABORT_OBJECT_DOES_NOT_EXIST, ABORT_SUBINDEX_DOES_NOT_EXIST, SdoWrite


def step_error(node_id: int, step: str, message: str) -> FieldbusError:
    return FieldbusError(f"node {node_id}: bring-up step '{step}': {message}")


class BootupWatch:
    """Boot-up messages (heartbeat state 0x00) seen per node since :meth:`arm`."""

    def __init__(self, node_ids: Iterable[int]) -> None:
        self._events = {n: threading.Event() for n in node_ids}
        self.count = {n: 0 for n in node_ids}  # boot-ups per node: 2 or more = two devices with one id

    def arm(self) -> None:
        for event in self._events.values():
            event.clear()
        self.count = dict.fromkeys(self.count, 0)

    def heard(self, node_id: int, state_byte: int) -> None:
        if state_byte & 0x7F == c.NmtState.BOOTUP and node_id in self._events:
            self.count[node_id] += 1
            self._events[node_id].set()

    def wait(self, timeout_s: float) -> list[int]:
        """Wait until every node booted or the time-out passed; return the missing nodes."""
        end = time.monotonic() + timeout_s
        for event in self._events.values():
            event.wait(max(0.0, end - time.monotonic()))
        return [n for n, e in self._events.items() if not e.is_set()]


def _describe_abort(err: SdoAbortedError) -> str:
    return f"SDO abort {err}"


def sdo_upload(sdo: Any, node_id: int, step: str, index: int, subindex: int, fmt: str) -> int:
    try:
        data = sdo.upload(index, subindex)
    except SdoAbortedError as err:
        raise step_error(node_id, step, f"{_describe_abort(err)} reading 0x{index:04X}:{subindex:02X}") from None
    except SdoCommunicationError as err:
        raise step_error(node_id, step, f"no SDO answer reading 0x{index:04X}:{subindex:02X} ({err})") from None
    size = struct.calcsize(fmt)
    if len(data) < size:
        raise step_error(node_id, step, f"0x{index:04X}:{subindex:02X} answered {len(data)} bytes, expected {size}")
    return struct.unpack_from(fmt, data)[0]


def sdo_download(sdo: Any, node_id: int, write: SdoWrite) -> None:
    try:
        sdo.download(write.index, write.subindex, write.data())
    except SdoAbortedError as err:
        if write.optional and err.code in (ABORT_OBJECT_DOES_NOT_EXIST, ABORT_SUBINDEX_DOES_NOT_EXIST):
            return
        raise step_error(node_id, write.step, f"{_describe_abort(err)} writing 0x{write.index:04X}:"
                         f"{write.subindex:02X} = {write.value}") from None
    except SdoCommunicationError as err:
        raise step_error(node_id, write.step, f"no SDO answer writing 0x{write.index:04X}:{write.subindex:02X} "
                         f"({err})") from None


def check_identity(sdo: Any, axis: AxisConfig) -> None:
    if axis.identity is None:
        return
    vendor = sdo_upload(sdo, axis.node_id, "identity check", c.IDENTITY, 1, "<I")
    product = sdo_upload(sdo, axis.node_id, "identity check", c.IDENTITY, 2, "<I")
    if (vendor, product) != (axis.identity.vendor_id, axis.identity.product_code):
        raise step_error(axis.node_id, "identity check", f"drive reports vendor 0x{vendor:08X} product 0x{product:08X}, "
                         f"axis {axis.name} expects vendor 0x{axis.identity.vendor_id:08X} "
                         f"product 0x{axis.identity.product_code:08X}")


def check_supported_mode(sdo: Any, axis: AxisConfig, mode: c.Mode) -> None:
    modes = sdo_upload(sdo, axis.node_id, "check supported modes", c.SUPPORTED_DRIVE_MODES, 0, "<I")
    if not modes >> c.SUPPORTED_MODE_BIT[mode] & 1:
        raise step_error(axis.node_id, "check supported modes", f"0x6502 = 0x{modes:08X}: the drive does not support "
                         f"mode {mode.name} ({int(mode)}) configured for axis {axis.name}")


def configure_drive(sdo: Any, node_id: int, writes: list[SdoWrite]) -> None:
    for write in writes:
        sdo_download(sdo, node_id, write)


def read_position(sdo: Any, node_id: int) -> int:
    return sdo_upload(sdo, node_id, "read position actual", c.POSITION_ACTUAL, 0, "<i")


def mode_of_axis(axis: AxisConfig) -> c.Mode:
    return c.Mode.INTERPOLATED_POSITION if axis.mode == "ip" else c.Mode.CYCLIC_SYNC_POSITION
