"""The master's side of the CiA-401 machine I/O node: named inputs and outputs by bit.

Pure functions turn the node's 8-bit groups (0x6000:01.. inputs in TPDO1, 0x6200:01..
outputs in RPDO1) into named states and back, with each signal's polarity (``active_low``:
a normally-closed contact such as an e-stop reads 0 when active). :class:`IoNode` does the
bring-up by SDO (device type 401, object sizes, PDO mapping with transmission type 255,
heartbeat), reads the inputs once by SDO before NMT start (an event-driven TPDO need not
come until something changes), then keeps the latest inputs from TPDO1 and sends RPDO1
whenever an output changes. Inputs are unknown (None) until read: a caller must treat an
unknown e-stop as pressed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import canopen
from canopen import objectdictionary as odt
from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from nurbsmotion.can import cia402 as c
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.bringup import sdo_failure
from nurbsmotion.fieldbus.feedback import arrival_perf_s
from nurbsmotion.fieldbus.node_heartbeat import HeartbeatWatch
from nurbsmotion.fieldbus.sdo_arrival import judge_on_arrival
from nurbsmotion.config.io import IoConfig, IoSignal
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

READ_INPUT_8 = 0x6000
WRITE_OUTPUT_8 = 0x6200
CIA_401 = 0x0191  # device type 0x1000, low 16 bits: the device profile number
EVENT_DRIVEN = 255  # transmission type: on change (CiA 301 'event-driven, device profile specific')
SDO_TIMEOUT_S = 0.5
OBJECT_DOES_NOT_EXIST, SUBINDEX_DOES_NOT_EXIST = 0x06020000, 0x06090011  # CiA 301 SDO abort codes


def signal_state(groups: bytes, signal: IoSignal) -> bool:
    """True when ``signal`` is active: its bit, inverted when active low."""
    level = bool(groups[signal.group] >> (signal.bit % 8) & 1)
    return level != signal.active_low


def input_states(groups: bytes, signals: tuple[IoSignal, ...]) -> dict[str, bool]:
    """Named states of the input groups (0x6000:01.. as received)."""
    return {s.name: signal_state(groups, s) for s in signals}


def output_groups(states: Mapping[str, bool], signals: tuple[IoSignal, ...], n_groups: int) -> bytes:
    """0x6200:01.. bytes for named output states (missing names: inactive)."""
    data = bytearray(n_groups)
    for s in signals:
        if states.get(s.name, False) != s.active_low:
            data[s.group] |= 1 << (s.bit % 8)
    return bytes(data)


def cia401_dictionary(io: IoConfig) -> ObjectDictionary:
    """The objects the master uses on a CiA-401 device (CiA 301 PDO 1 parameters, 0x6000 and
    0x6200 sub-indices for the used groups), so canopen's RemoteNode can type SDO values and
    remap PDO 1 with its PdoMap. The device itself is asked for its sizes at bring-up."""
    od = ObjectDictionary()
    u8, u16, u32 = odt.UNSIGNED8, odt.UNSIGNED16, odt.UNSIGNED32
    od.add_object(_variable(c.DEVICE_TYPE, 0, u32, "ro"))
    od.add_object(_variable(c.PRODUCER_HEARTBEAT_TIME, 0, u16, "rw"))
    od.add_object(_record(c.CONSUMER_HEARTBEAT_TIME, [(0, u8, "ro"), (1, u32, "rw")]))
    for comm, mapping in ((c.RPDO_COMM, c.RPDO_MAPPING), (c.TPDO_COMM, c.TPDO_MAPPING)):
        od.add_object(_record(comm, [(0, u8, "ro"), (1, u32, "rw"), (2, u8, "rw")]))
        od.add_object(_record(mapping, [(n, u8 if n == 0 else u32, "rw") for n in range(9)]))
    for index, groups, access in ((READ_INPUT_8, io.input_groups, "ro"), (WRITE_OUTPUT_8, io.output_groups, "rw")):
        od.add_object(_record(index, [(0, u8, "ro")] + [(n, u8, access) for n in range(1, groups + 1)]))
    return od


def _variable(index: int, subindex: int, data_type: int, access: str) -> ODVariable:
    var = ODVariable(f"0x{index:04X}:{subindex:02X}", index, subindex)
    var.data_type, var.access_type, var.pdo_mappable = data_type, access, index in (READ_INPUT_8, WRITE_OUTPUT_8)
    return var


def _record(index: int, subs: list[tuple[int, int, str]]) -> ODRecord:
    record = ODRecord(f"0x{index:04X}", index)
    for subindex, data_type, access in subs:
        record.add_member(_variable(index, subindex, data_type, access))
    return record


class IoNode:
    """The machine's I/O node on a connected ``canopen.Network``.

    ``on_change(name, active)`` is called from the network's receive thread for every input
    that changes after :meth:`bring_up`; keep it short.
    """

    def __init__(self, network: canopen.Network, io: IoConfig,
                 on_change: Callable[[str, bool], None] | None = None, sdo_timeout_s: float = SDO_TIMEOUT_S,
                 on_lost: Callable[[str], None] | None = None,
                 judging_time_s: Callable[[], float] = time.perf_counter) -> None:
        """``judging_time_s``: now on the frames' arrival timeline (the master's
        ``judging_time_s``; perf_counter based) for the heartbeat watch and the SDO time-out;
        SDO answers are matched to their request (fieldbus.sdo_arrival)."""
        self.network = network
        self.judging_time_s = judging_time_s
        self.io = io
        self.on_change = on_change
        self.on_lost = on_lost  # the heartbeat watch found the node lost: one line naming it
        self.node = canopen.RemoteNode(io.node_id, cia401_dictionary(io))
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        judge_on_arrival(self.node.sdo, judging_time_s)  # as the axes' and the spindle's (fieldbus.sdo_arrival)
        network.add_node(self.node)
        self.heartbeat: HeartbeatWatch | None = None  # the master's consumer of its heartbeat (bring_up)
        self.node.nmt.add_heartbeat_callback(self._heard)
        self._lock = threading.Lock()
        self._inputs: dict[str, bool] | None = None
        self._outputs: dict[str, bool] = {s.name: False for s in io.outputs}
        self._output_names = {s.name for s in io.outputs}

    # ------------------------------------------------------------------ bring-up
    def bring_up(self, heartbeat_producer_ms: int, heartbeat_consumer_ms: int | None = None,
                 master_heartbeat: tuple[int, int] | None = None) -> None:
        """Check, configure, read the inputs, start (NMT); FieldbusError names node and step.

        In NMT PRE-OPERATIONAL: 0x1000 is a CiA-401 device; 0x6000:00 / 0x6200:00 hold the
        configured groups; TPDO1 = 0x6000:01..n and RPDO1 = 0x6200:01..m, transmission type
        255 (canopen's PdoMap: disable, count 0, entries, count, enable); 0x1017 heartbeat;
        with ``master_heartbeat`` (master node id, consumer ms) 0x1016:01, so the node
        switches its outputs off when the master dies (a node without 0x1016 is logged, not
        refused: CiA 301 makes the consumer optional). With ``heartbeat_consumer_ms`` the
        master watches the node's heartbeat from the NMT start (fieldbus.node_heartbeat):
        on loss the inputs become unknown and ``on_lost`` gets one line. Callable again to
        bring the node back after a loss.
        """
        if self.heartbeat is not None:
            self.heartbeat.stop()
        device = self._sdo("I/O device type", lambda: self.node.sdo[c.DEVICE_TYPE].raw)
        if device & 0xFFFF != CIA_401:
            raise self._error("I/O device type", f"0x1000 = 0x{device:08X}: not a CiA-401 I/O device")
        self._check_size(READ_INPUT_8, self.io.input_groups, "inputs")
        self._check_size(WRITE_OUTPUT_8, self.io.output_groups, "outputs")
        self._map(self.node.tpdo[1], c.COB_TPDO[0], READ_INPUT_8, self.io.input_groups, "configure TPDO1")
        self._map(self.node.rpdo[1], c.COB_RPDO[0], WRITE_OUTPUT_8, self.io.output_groups, "configure RPDO1")
        self._sdo("set heartbeat producer", lambda: setattr(self.node.sdo[c.PRODUCER_HEARTBEAT_TIME], "raw",
                                                             heartbeat_producer_ms))
        if master_heartbeat is not None:
            self._consume_master_heartbeat(*master_heartbeat)
        self.node.tpdo[1].callbacks.clear()  # a second bring-up (after a loss) adds it again
        self.node.tpdo[1].add_callback(self._on_tpdo)

        def read_group(n: int) -> int:
            return int(self._sdo("read inputs", lambda: self.node.sdo[READ_INPUT_8][n].raw))

        groups = bytes(read_group(n) for n in range(1, self.io.input_groups + 1))
        with self._lock:
            self._inputs = input_states(groups, self.io.inputs)
        self.node.nmt.send_command(c.NmtCommand.START)
        if heartbeat_consumer_ms:
            self.heartbeat = HeartbeatWatch(self.io.node_id, heartbeat_consumer_ms / 1000.0, self._lost,
                                            clock=self.judging_time_s)
            self.heartbeat.start()
        self._send_outputs()
        log.info(kv("io.ready", node=self.io.node_id, inputs=self.inputs, heartbeat_consumer_ms=heartbeat_consumer_ms))

    def _consume_master_heartbeat(self, master_id: int, consumer_ms: int) -> None:
        """0x1016:01 = master node id << 16 | consumer ms (CiA 301 §7.5.2.29)."""
        try:
            self.node.sdo[c.CONSUMER_HEARTBEAT_TIME][1].raw = master_id << 16 | consumer_ms
        except SdoAbortedError as err:
            if err.code not in (OBJECT_DOES_NOT_EXIST, SUBINDEX_DOES_NOT_EXIST):
                raise self._error("watch the master's heartbeat", sdo_failure(err)) from None
            log.warning(kv("io.no_heartbeat_consumer", node=self.io.node_id, abort=f"0x{err.code:08X}"))
        except SdoCommunicationError as err:
            raise self._error("watch the master's heartbeat", sdo_failure(err)) from None

    def _heard(self, state: int) -> None:
        """canopen's heartbeat callback; its NmtMaster stored the frame's timestamp just before."""
        watch = self.heartbeat
        if watch is not None:
            watch.heard(state, arrival_perf_s(self.node.nmt.timestamp or 0.0))

    def _lost(self, reason: str) -> None:
        """The heartbeat watch's verdict (its thread): inputs unknown from now, one line up."""
        with self._lock:
            self._inputs = None
        if self.on_lost is not None:
            self.on_lost(f"io node {self.io.node_id}: {reason}")

    @property
    def lost(self) -> str | None:
        """Why the node's heartbeat was lost (None while watched and fine, or not watched)."""
        return self.heartbeat.lost if self.heartbeat is not None else None

    def _error(self, step: str, message: str) -> FieldbusError:
        return FieldbusError(f"node {self.io.node_id}: bring-up step '{step}': {message}")

    def _sdo(self, step: str, action: Callable[[], Any]) -> Any:
        try:
            return action()
        except (SdoAbortedError, SdoCommunicationError) as err:
            raise self._error(step, sdo_failure(err)) from None

    def _check_size(self, index: int, needed: int, what: str) -> None:
        step = f"I/O {what}"
        have = self._sdo(step, lambda: self.node.sdo[index][0].raw) if needed else 0
        if have < needed:
            raise self._error(step, f"0x{index:04X} has {have} groups of 8 {what}, the io section needs {needed}")

    def _map(self, pdo: Any, cob_base: int, index: int, groups: int, step: str) -> None:
        pdo.clear()
        pdo.cob_id = cob_base + self.io.node_id
        pdo.trans_type = EVENT_DRIVEN
        pdo.enabled = groups > 0
        for n in range(1, groups + 1):
            pdo.add_variable(index, n)
        self._sdo(step, pdo.save)

    def close(self) -> None:
        """Stop watching its heartbeat and taking its TPDO (nothing to undo when the bring-up
        did not get that far)."""
        if self.heartbeat is not None:
            self.heartbeat.stop()
        tpdo = self.node.tpdo[1]
        tpdo.callbacks.clear()
        if tpdo.cob_id is not None:
            try:
                self.network.unsubscribe(tpdo.cob_id, tpdo.on_message)
            except (KeyError, ValueError):  # never subscribed: the mapping step failed
                pass

    # ------------------------------------------------------------------ inputs
    @property
    def inputs(self) -> dict[str, bool] | None:
        """Latest named input states; None before the first read."""
        with self._lock:
            return dict(self._inputs) if self._inputs is not None else None

    def input(self, name: str) -> bool | None:
        with self._lock:
            return None if self._inputs is None else self._inputs[name]

    def _on_tpdo(self, pdo: Any) -> None:
        if self.lost:  # unknown until brought up again, whatever still arrives
            return
        data = bytes(pdo.data)
        if len(data) < self.io.input_groups:
            log.warning(kv("io.tpdo_length", node=self.io.node_id, length=len(data), expected=self.io.input_groups))
            return
        states = input_states(data, self.io.inputs)
        with self._lock:
            previous, self._inputs = self._inputs, states
        changed = [(name, active) for name, active in states.items() if previous is None or previous[name] != active]
        for name, active in changed:
            log.info(kv("io.input", node=self.io.node_id, name=name, active=active))
            if self.on_change is not None:
                self.on_change(name, active)

    # ------------------------------------------------------------------ outputs
    @property
    def outputs(self) -> dict[str, bool]:
        with self._lock:
            return dict(self._outputs)

    def set_outputs(self, states: Mapping[str, bool]) -> None:
        """Change named outputs (others keep their state) and send RPDO1 at once."""
        unknown = set(states) - self._output_names
        if unknown:
            raise KeyError(f"node {self.io.node_id}: no output named {', '.join(sorted(unknown))} in the io section")
        with self._lock:
            self._outputs.update(states)
        self._send_outputs()

    def _send_outputs(self) -> None:
        """RPDO1 through canopen's PdoMap (event driven: sent on every change)."""
        if not self.io.output_groups:
            return
        with self._lock:
            data = output_groups(self._outputs, self.io.outputs, self.io.output_groups)
        rpdo = self.node.rpdo[1]
        for variable, value in zip(rpdo.map, data):
            variable.raw = value
        rpdo.transmit()
