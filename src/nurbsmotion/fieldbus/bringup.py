"""Bring-up of one drive through canopen, as its authors intend: an EDS-backed RemoteNode,
typed ``sdo[...]`` access, its PDO maps (clear/add_variable/save), ``nmt`` and ``emcy``.

Order (CiA 301/402): NMT reset communication -> every boot-up message -> identity (0x1018)
-> supported modes (0x6502, where readable) -> the steps of the drive's
:class:`~nurbsmotion.fieldbus.bringup_plan.DrivePlan` in PRE-OPERATIONAL -> read 0x6064 and
0x6041. Every failure raises FieldbusError naming the node, the step and the object, e.g.
``node 1: bring-up step 'map RPDO1': SDO abort 0x06040041 (Object cannot be mapped to the PDO)
writing 0x1600:02 = 0x60C10120 (0x60C1:01, 32 bit)``.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Iterable

import canopen
from canopen.objectdictionary import ObjectDictionary, datatypes
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from nurbsmotion.can import cia402 as c
from nurbsmotion.can import drive_od
from nurbsmotion.config import AxisConfig
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.bringup_plan import DrivePlan, PdoSetup, ReadBack, Write, describe_value
from nurbsmotion.fieldbus.sdo_arrival import judge_on_arrival
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

READ_BACK_TIMEOUT_S = 0.2  # a drive may show the new mode in 0x6061 a little later


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

    def twin_error(self) -> FieldbusError | None:
        """Two boot-ups of one node after one NMT reset: two devices with that node id."""
        for node_id, count in self.count.items():
            if count > 1:
                return FieldbusError(f"node {node_id}: bring-up step 'boot-up': {count} boot-up messages after one "
                                     f"NMT reset: two devices with the same node id?")
        return None


def reset_and_await_bootup(network: canopen.Network, bootup: BootupWatch, axes: Iterable[AxisConfig],
                           timeout_s: float) -> None:
    """NMT reset communication to every axis, then each one's boot-up, or a FieldbusError
    naming the missing nodes."""
    axes = list(axes)
    bootup.arm()
    for axis in axes:
        network[axis.node_id].nmt.send_command(c.NmtCommand.RESET_COMMUNICATION)
    missing = bootup.wait(timeout_s)
    if missing:
        names = {a.node_id: a.name for a in axes}
        listed = ", ".join(f"{n} (axis {names[n]})" for n in missing)
        raise FieldbusError(f"node {missing[0]}: bring-up step 'boot-up': no boot-up message within "
                            f"{timeout_s * 1000:.0f} ms after NMT reset communication "
                            f"(missing: node {listed}; unpowered, unplugged or wrong node id?)")


class SdoTrail:
    """Remembers the SDO access under way on a node, so an abort raised deep inside canopen
    (e.g. PdoMap.save) names the object and value: wraps the client's upload/download."""

    def __init__(self, node: canopen.RemoteNode) -> None:
        self.node = node
        self.node_id = int(node.id or 0)  # a RemoteNode always has its id (canopen types it Optional)
        self.last: tuple[int, int, bytes | None] = (0, 0, None)  # index, subindex, data (None: an upload)
        sdo = node.sdo
        plain_download, plain_upload = sdo.download, sdo.upload

        def download(index: int, subindex: int, data: bytes, force_segment: bool = False) -> None:
            self.last = (index, subindex, bytes(data))
            plain_download(index, subindex, data, force_segment)

        def upload(index: int, subindex: int) -> bytes:
            self.last = (index, subindex, None)
            return plain_upload(index, subindex)

        sdo.download, sdo.upload = download, upload

    def describe(self) -> str:
        index, subindex, data = self.last
        od = self.node.object_dictionary
        if data is None:
            return f"reading 0x{index:04X}:{subindex:02X}"
        var = drive_od.find(od, index, subindex)
        signed = var is not None and var.data_type in datatypes.SIGNED_TYPES
        value = int.from_bytes(data[:8], "little", signed=signed)
        return f"writing {describe_value(od, index, subindex, value)}"


def open_node(network: canopen.Network, node_id: int, od: ObjectDictionary, sdo_timeout_s: float,
              judging_time_s: Callable[[], float] | None = None) -> tuple[canopen.RemoteNode, SdoTrail]:
    """The node on ``network`` with its SDO time-out; given ``judging_time_s`` (the master's
    arrival timeline), SDO answers time out on it (fieldbus.sdo_arrival), not on the waiting
    thread's clock."""
    node = canopen.RemoteNode(node_id, od)
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    if judging_time_s is not None:
        judge_on_arrival(node.sdo, judging_time_s)
    network.add_node(node)
    return node, SdoTrail(node)


def _variable(node: canopen.RemoteNode, index: int, subindex: int) -> Any:
    """The typed SDO variable of (index, subindex) from the node's EDS; a step naming an
    object the EDS lacks is refused before any frame (the plan never does: a safety net)."""
    try:
        obj = node.sdo[index]
        return obj if isinstance(obj, canopen.sdo.SdoVariable) else obj[subindex]
    except KeyError:
        raise FieldbusError(f"node {node.id}: the drive's EDS has no 0x{index:04X}:{subindex:02X}") from None


def sdo_failure(err: SdoAbortedError | SdoCommunicationError) -> str:
    """One line for an SDO that failed: the abort code and its CiA 301 meaning, or silence."""
    if isinstance(err, SdoAbortedError):
        return f"SDO abort 0x{err.code:08X} ({SdoAbortedError.CODES.get(err.code, 'unknown')})"
    return f"no SDO answer ({err})"


def _sdo(trail: SdoTrail, step: str, action: Any) -> Any:
    """Run one SDO action; an abort or silence becomes the step's one-line error."""
    node_id = trail.node_id
    try:
        return action()
    except SdoAbortedError as err:
        text = SdoAbortedError.CODES.get(err.code, "unknown abort code")
        raise step_error(node_id, step, f"SDO abort 0x{err.code:08X} ({text}) {trail.describe()}") from None
    except SdoCommunicationError as err:
        raise step_error(node_id, step, f"no SDO answer {trail.describe()} ({err})") from None


def read(trail: SdoTrail, step: str, index: int, subindex: int = 0) -> int:
    return _sdo(trail, step, lambda: _variable(trail.node, index, subindex).raw)


def check_identity(trail: SdoTrail, axis: AxisConfig) -> None:
    if axis.identity is None:
        return
    vendor = read(trail, "identity check", c.IDENTITY, 1)
    product = read(trail, "identity check", c.IDENTITY, 2)
    if (vendor, product) != (axis.identity.vendor_id, axis.identity.product_code):
        raise step_error(axis.node_id, "identity check", f"drive reports vendor 0x{vendor:08X} product 0x{product:08X}, "
                         f"axis {axis.name} expects vendor 0x{axis.identity.vendor_id:08X} "
                         f"product 0x{axis.identity.product_code:08X}")


def check_supported_mode(trail: SdoTrail, plan: DrivePlan) -> None:
    """0x6502 must have the mode's bit. A drive answering 0 reports no modes at all (EDS
    entries without a default, e.g. Elmo, EPOS2, Schunk): then the 0x6061 read-back after
    0x6060 is what proves the mode."""
    if not plan.check_supported_modes:
        return
    modes = read(trail, "check supported modes", c.SUPPORTED_DRIVE_MODES)
    if modes == 0:
        log.info(kv("supported_modes_not_reported", node=plan.node_id, axis=plan.axis))
        return
    if not modes >> c.SUPPORTED_MODE_BIT[plan.mode] & 1:
        raise step_error(plan.node_id, "check supported modes", f"0x6502 = 0x{modes:08X}: the drive does not support "
                         f"mode {plan.mode.name} ({int(plan.mode)}) configured for axis {plan.axis}")


def _write(trail: SdoTrail, step: Write) -> None:
    def action() -> None:
        _variable(trail.node, step.index, step.subindex).raw = step.value
    _sdo(trail, step.step, action)


def _read_back(trail: SdoTrail, step: ReadBack) -> None:
    end = time.monotonic() + READ_BACK_TIMEOUT_S
    while True:
        value = read(trail, step.step, step.index, step.subindex)
        if value == step.expect:
            return
        if time.monotonic() > end:
            raise step_error(trail.node_id, step.step, f"0x{step.index:04X}:{step.subindex:02X} reads {value}, "
                             f"expected {step.expect}: the drive did not take the mode")
        time.sleep(0.01)


def _map_pdo(trail: SdoTrail, step: PdoSetup) -> None:
    """canopen's PdoMap: clear, add the entries, save (disable, count 0, entries, count,
    enable: CiA 301 order). The cycle loop reads and writes these frames itself (hand-written
    per-cycle path), so canopen's own listener on the COB-ID is removed again."""
    node = trail.node
    maps = node.rpdo if step.kind == "RPDO" else node.tpdo
    pdo = maps[step.number]
    assert step.frame is not None
    pdo.clear()
    pdo.cob_id = step.cob_id
    pdo.trans_type = c.TRANSMISSION_SYNC_EVERY
    pdo.enabled = True
    for fld in step.frame.fields:
        pdo.add_variable(fld.index, fld.subindex)
    if isinstance(pdo.map_array, canopen.sdo.SdoArray):
        _sdo(trail, step.step, lambda: _save_array_mapped(pdo))
    else:
        _sdo(trail, step.step, pdo.save)
        node.network.unsubscribe(step.cob_id, pdo.on_message)  # save() subscribed it


def _save_array_mapped(pdo: Any) -> None:
    """PdoMap.save for a mapping object of type ARRAY (ZeroErr's 0x1600/0x1A00), in the same
    CiA 301 order. canopen 2.4.1's save() iterates an SdoArray over 1..sub0 read back from the
    drive right after it wrote sub0 = 0, so it writes no entry, then a count over entries that
    were never written (a strict drive refuses it, a lax one maps stale entries)."""
    pdo.com_record[1].raw = pdo.cob_id | c.PDO_COB_ID_INVALID
    pdo.com_record[2].raw = pdo.trans_type
    pdo.map_array[0].raw = 0
    for subindex, var in enumerate(pdo.map, 1):
        pdo.map_array[subindex].raw = var.index << 16 | var.subindex << 8 | var.length
    pdo.map_array[0].raw = len(pdo.map)
    pdo.com_record[1].raw = pdo.cob_id


def configure(trail: SdoTrail, plan: DrivePlan) -> None:
    """Every step of the plan, in order."""
    for step in plan.steps:
        if isinstance(step, Write):
            _write(trail, step)
        elif isinstance(step, ReadBack):
            _read_back(trail, step)
        else:
            _map_pdo(trail, step)


def read_position(trail: SdoTrail) -> int:
    return read(trail, "read position actual", c.POSITION_ACTUAL)


def read_statusword(trail: SdoTrail) -> int:
    return read(trail, "read statusword", c.STATUSWORD)


def set_up_drive(network: canopen.Network, trail: SdoTrail, axis: AxisConfig, plan: DrivePlan,
                 master_heartbeat: bool) -> tuple[int, int]:
    """Check identity and mode, write the plan, read where the drive stands: (position actual,
    statusword). ``master_heartbeat``: the master sends one, so a drive that cannot watch it
    is named."""
    network[axis.node_id].emcy.reset()  # canopen keeps every EMCY in a list: start it empty
    check_identity(trail, axis)
    check_supported_mode(trail, plan)
    configure(trail, plan)
    position, statusword = read_position(trail), read_statusword(trail)
    log.info(kv("drive_configured", node=axis.node_id, axis=axis.name, mode=axis.mode,
                rpdos=len(plan.layout.rpdos), tpdos=len(plan.layout.tpdos),
                skipped=",".join(s.what for s in plan.skipped), position=position,
                statusword=f"0x{statusword:04X}"))
    unwatched = next((s for s in plan.skipped if s.what == "0x1016:01" and master_heartbeat), None)
    if unwatched is not None:  # an operator must know which drive keeps moving if the daemon dies
        log.warning(kv("master_heartbeat_unwatched", node=axis.node_id, axis=axis.name, reason=unwatched.reason))
    return position, statusword
