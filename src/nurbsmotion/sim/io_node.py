"""A simulated CiA-401 digital I/O node on any python-can bus (through a canopen Network).

Objects (CiA 401): 0x6000 sub 1..n 'read input 8-bit' (UNSIGNED8, ro, mappable), 0x6200
sub 1..m 'write output 8-bit' (rw, mappable); default PDOs: TPDO1 = 0x6000:01..n, RPDO1 =
0x6200:01..m, both transmission type 255 (event driven). CiA 301 around it, as strict as
the simulated drive: its own NMT slave (boot-up, PDOs only in OPERATIONAL, SDO silent in
STOPPED, reset restores the defaults), heartbeat producer 0x1017 (python-can periodic
send), heartbeat consumer 0x1016, PDO remapping by the CiA 301 procedure (``sim.pdo``).

TPDO1 goes out per its transmission type (0x1800:02): 254/255 at once when an input
changes (and not on entering OPERATIONAL: CiA 301 does not require it, so a master must
read 0x6000 by SDO to know the inputs before the first change); 1..240 on every n-th SYNC; 0 on the SYNC after a change. RPDO1 data is applied at
once for types 254/255, at the next SYNC for 0..240. Outputs take the error value 0
(0x6206 'error mode' all set, 0x6207 'error value' 0 in CiA 401 terms) when the node is
stopped or reset, or when a watched heartbeat is lost (then also EMCY 0x8130).

Test API: :meth:`set_input`, :meth:`set_inputs`, :meth:`input`, :attr:`outputs`,
:meth:`output`. :meth:`tick` must be called periodically (heartbeat consumer), as
``SimNetwork`` does for drives.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import canopen
from canopen import objectdictionary as odt
from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import EmcyCode, NmtCommand, NmtState
from nurbsmotion.log import kv
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.io_pdos import ERROR_REGISTER_COMMUNICATION, READ_INPUT_8, WRITE_OUTPUT_8, IoPdos
from nurbsmotion.sim.slave import (
    EMCY_STRUCT,
    ConsumedHeartbeats,
    GatedLocalNode,
    Subscriptions,
    addressed_command,
    od_value,
)

log = logging.getLogger(__name__)

DEVICE_TYPE_DIGITAL_IO = 0x0003_0191  # CiA 401 (0x191), bit 16 digital inputs, bit 17 digital outputs
MAX_GROUPS = 8  # one 8-byte PDO
CONSUMER_ENTRIES = 4


def _var(name: str, index: int, subindex: int, data_type: int, access: str, default: int,
         mappable: bool = False) -> ODVariable:
    var = ODVariable(name, index, subindex)
    var.data_type, var.access_type, var.default, var.pdo_mappable = data_type, access, default, mappable
    return var


def _record(name: str, index: int, members: list[ODVariable]) -> ODRecord:
    record = ODRecord(name, index)
    for member in members:
        record.add_member(member)
    return record


def io_object_dictionary(node_id: int, input_groups: int, output_groups: int) -> ObjectDictionary:
    """The node's objects with the CiA 401 default PDO mapping (what its EDS would declare)."""
    od = ObjectDictionary()
    u8, u16, u32 = odt.UNSIGNED8, odt.UNSIGNED16, odt.UNSIGNED32
    od.add_object(_var("Device type", c.DEVICE_TYPE, 0, u32, "ro", DEVICE_TYPE_DIGITAL_IO))
    od.add_object(_var("Error register", c.ERROR_REGISTER, 0, u8, "ro", 0))
    od.add_object(_var("COB-ID EMCY", c.EMCY_COB_ID, 0, u32, "rw", c.COB_EMCY + node_id))
    od.add_object(_record("Consumer heartbeat time", c.CONSUMER_HEARTBEAT_TIME,
                          [_var("Number of entries", c.CONSUMER_HEARTBEAT_TIME, 0, u8, "ro", CONSUMER_ENTRIES)]
                          + [_var(f"Consumer {n}", c.CONSUMER_HEARTBEAT_TIME, n, u32, "rw", 0)
                             for n in range(1, CONSUMER_ENTRIES + 1)]))
    od.add_object(_var("Producer heartbeat time", c.PRODUCER_HEARTBEAT_TIME, 0, u16, "rw", 0))
    od.add_object(_record("Identity", c.IDENTITY, [_var("Number of entries", c.IDENTITY, 0, u8, "ro", 2),
                                                   _var("Vendor-ID", c.IDENTITY, 1, u32, "ro", 0),
                                                   _var("Product code", c.IDENTITY, 2, u32, "ro", 0x401)]))
    for kind, comm, mapping, cob, obj, groups in (
            ("RPDO1", c.RPDO_COMM, c.RPDO_MAPPING, c.COB_RPDO[0], WRITE_OUTPUT_8, output_groups),
            ("TPDO1", c.TPDO_COMM, c.TPDO_MAPPING, c.COB_TPDO[0], READ_INPUT_8, input_groups)):
        od.add_object(_record(f"{kind} communication", comm, [
            _var("Highest sub-index", comm, 0, u8, "ro", 2),
            _var("COB-ID", comm, 1, u32, "rw", (cob + node_id) | (0 if groups else c.PDO_COB_ID_INVALID)),
            _var("Transmission type", comm, 2, u8, "rw", 255)]))
        od.add_object(_record(f"{kind} mapping", mapping,
                              [_var("Number of entries", mapping, 0, u8, "rw", groups)]
                              + [_var(f"Entry {n}", mapping, n, u32, "rw", (obj << 16 | n << 8 | 8) if n <= groups else 0)
                                 for n in range(1, MAX_GROUPS + 1)]))
    for index, name, access, groups in ((READ_INPUT_8, "Read input 8-bit", "ro", input_groups),
                                        (WRITE_OUTPUT_8, "Write output 8-bit", "rw", output_groups)):
        if groups:
            od.add_object(_record(name, index, [_var("Number of entries", index, 0, u8, "ro", groups)]
                                  + [_var(f"{name} {n}", index, n, u8, access, 0, mappable=True)
                                     for n in range(1, groups + 1)]))
    return od


class SimIoNode:
    """A CiA-401 node with ``input_groups`` x 8 digital inputs and ``output_groups`` x 8
    outputs (each 0..8). :meth:`attach` it to a connected ``canopen.Network``."""

    def __init__(self, node_id: int, input_groups: int = 1, output_groups: int = 1, *, name: str | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} outside 1..127")
        if not (0 <= input_groups <= MAX_GROUPS and 0 <= output_groups <= MAX_GROUPS):
            raise ValueError(f"input/output groups must be 0..{MAX_GROUPS}")
        self.node_id = node_id
        self.name = name or f"io{node_id}"
        self.input_groups, self.output_groups = input_groups, output_groups
        self.od = io_object_dictionary(node_id, input_groups, output_groups)
        self.node = GatedLocalNode(node_id, self.od, self)
        self.network: canopen.Network | None = None
        self.nmt_state = NmtState.BOOTUP
        self._inputs = bytearray(input_groups)
        self._outputs = bytearray(output_groups)
        self._clock = clock
        self._lock = threading.RLock()
        self._subscriptions = Subscriptions()
        self._heartbeat_task: Any = None
        self._heartbeats = ConsumedHeartbeats(self._subscriptions, self._lock, lambda timestamp: self._clock())
        self._heartbeat_consumer = self._heartbeats.consumer  # the one object; tests wait on it
        self.tpdos_sent = 0
        self._pdos = IoPdos(self, self.od, self._value, self._inputs, self._outputs, self._subscriptions, self._lock)

    # ------------------------------------------------------------------ test API
    def set_input(self, bit: int, active: bool) -> None:
        """Set digital input ``bit`` (0-based over the 8-bit groups) and report it if due."""
        group, mask = divmod(bit, 8)
        with self._lock:
            if not 0 <= group < self.input_groups:
                raise ValueError(f"{self.name}: no input bit {bit} ({self.input_groups * 8} inputs)")
            value = self._inputs[group] | 1 << mask if active else self._inputs[group] & ~(1 << mask)
            self._set_group(group, value)

    def set_inputs(self, groups: bytes) -> None:
        """Set every input group at once (one TPDO for the whole change)."""
        with self._lock:
            if len(groups) != self.input_groups:
                raise ValueError(f"{self.name}: expected {self.input_groups} input bytes, got {len(groups)}")
            if bytes(groups) != bytes(self._inputs):
                self._inputs[:] = groups
                self._pdos.inputs_changed()

    def input(self, bit: int) -> bool:
        group, mask = divmod(bit, 8)
        return bool(self._inputs[group] >> mask & 1)

    @property
    def outputs(self) -> bytes:
        """The output groups as the outputs drive them now (0x6200:01..)."""
        return bytes(self._outputs)

    def output(self, bit: int) -> bool:
        group, mask = divmod(bit, 8)
        return bool(self._outputs[group] >> mask & 1)

    # ------------------------------------------------------------------ network
    def attach(self, network: canopen.Network) -> None:
        """Join a connected network and boot (boot-up message, PRE-OPERATIONAL)."""
        with self._lock:
            if self.network is not None:
                raise RuntimeError(f"{self.name} is already attached")
            self.network = self._subscriptions.network = network
            self.node.associate_network(network)
            self._subscriptions.add(c.COB_NMT, self._on_nmt)
            self._subscriptions.add(self.node.sdo.rx_cobid, self._on_sdo_request)
            self._subscriptions.add(c.COB_SYNC, self._pdos.on_sync)
            self._boot(reset_application=True)

    def detach(self) -> None:
        with self._lock:
            if self.network is None:
                return
            self._stop_heartbeat()
            self._subscriptions.clear()
            self._heartbeats.forget()
            self.node.remove_network()
            self.network = self._subscriptions.network = None

    def tick(self, now: float) -> float:
        """Watch consumed heartbeats; returns when to be called again."""
        with self._lock:
            for producer in self._heartbeat_consumer.newly_failed(now):
                log.warning(kv("sim.io.heartbeat_lost", node=self.node_id, producer=producer))
                self._error_outputs()
                self.send_emcy(EmcyCode.HEARTBEAT, ERROR_REGISTER_COMMUNICATION)
            return min(now + 0.05, self._heartbeat_consumer.next_deadline())

    # ------------------------------------------------------------------ NMT
    def _boot(self, reset_application: bool) -> None:
        self.nmt_state = NmtState.BOOTUP
        for index in list(self.node.data_store):
            if reset_application or 0x1000 <= index <= 0x1FFF:
                del self.node.data_store[index]
        if reset_application:
            self._error_outputs()
        self._pdos.pending_outputs = None
        self._pdos.rebuild()
        self._configure_consumer()
        self.send(c.COB_HEARTBEAT + self.node_id, bytes([NmtState.BOOTUP]))
        self._enter(NmtState.PRE_OPERATIONAL)
        self._start_heartbeat()

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        command = addressed_command(data, self.node_id)
        if command is None:
            return
        with self._lock:
            if command == NmtCommand.START:
                self._enter(NmtState.OPERATIONAL)
            elif command == NmtCommand.STOP:
                self._error_outputs()  # outputs off before STOPPED is visible (no window with both)
                self._enter(NmtState.STOPPED)
            elif command == NmtCommand.PRE_OPERATIONAL:
                self._enter(NmtState.PRE_OPERATIONAL)
            elif command == NmtCommand.RESET_NODE:
                self._boot(reset_application=True)
            elif command == NmtCommand.RESET_COMMUNICATION:
                self._boot(reset_application=False)

    def _enter(self, state: NmtState) -> None:
        if state == self.nmt_state:
            return
        log.info(kv("sim.io.nmt", node=self.node_id, state=state.name, previous=self.nmt_state.name))
        self.nmt_state = state
        self._pdos.sync_count = 0
        if self._heartbeat_task is not None:
            self._heartbeat_task.update([int(state)])

    def _start_heartbeat(self) -> None:
        self._stop_heartbeat()
        period_ms = self._value(c.PRODUCER_HEARTBEAT_TIME)
        if period_ms and self.network is not None:
            self._heartbeat_task = self.network.send_periodic(
                c.COB_HEARTBEAT + self.node_id, bytes([int(self.nmt_state)]), period_ms / 1000.0)

    def _stop_heartbeat(self) -> None:
        if self._heartbeat_task is not None:
            self._heartbeat_task.stop()
            self._heartbeat_task = None

    def _configure_consumer(self) -> None:
        self._heartbeats.configure([self._value(c.CONSUMER_HEARTBEAT_TIME, n) for n in range(1, CONSUMER_ENTRIES + 1)])

    # ------------------------------------------------------------------ SDO
    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self.nmt_state in (NmtState.STOPPED, NmtState.BOOTUP):
                return
            self.node.sdo.on_request(can_id, data, timestamp)

    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> Any:
        if index == READ_INPUT_8 and subindex >= 1:
            return self._inputs[subindex - 1]
        if index == WRITE_OUTPUT_8 and subindex >= 1:
            return self._outputs[subindex - 1]
        return None

    def _before_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        value = od.decode_raw(data)
        pdo_layout.check_parameter_write(self.od, self._value, index, subindex, value)
        if index == c.EMCY_COB_ID and value & pdo_layout.COB_ID_EXTENDED_BIT:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        if index == WRITE_OUTPUT_8:
            self._outputs[subindex - 1] = value

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        if pdo_layout.is_pdo_parameter(index):
            self._pdos.rebuild()
        elif index == c.PRODUCER_HEARTBEAT_TIME:
            self._start_heartbeat()
        elif index == c.CONSUMER_HEARTBEAT_TIME:
            self._configure_consumer()

    def _value(self, index: int, subindex: int = 0) -> Any:
        return od_value(self.node, self.od, index, subindex)

    # ------------------------------------------------------------------ PDOs
    def _set_group(self, group: int, value: int) -> None:
        if self._inputs[group] != value:
            self._inputs[group] = value
            self._pdos.inputs_changed()

    # ------------------------------------------------------------------ helpers
    def _error_outputs(self) -> None:
        """CiA 401 error reaction of the outputs: the error value 0."""
        if any(self._outputs):
            log.warning(kv("sim.io.outputs_off", node=self.node_id))
        self._outputs[:] = bytes(self.output_groups)

    def send(self, can_id: int, data: bytes) -> None:
        if self.network is not None:
            self.network.send_message(can_id, data)

    def send_emcy(self, code: int, register: int) -> None:
        cob = self._value(c.EMCY_COB_ID)
        if not cob & pdo_layout.COB_ID_INVALID_BIT and self.nmt_state != NmtState.STOPPED:
            self.send(cob & 0x7FF, EMCY_STRUCT.pack(code, register))
