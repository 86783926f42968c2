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
from collections.abc import Callable, Mapping
from typing import Any

import canopen
from canopen.objectdictionary import ObjectDictionary

from nurbsmotion import cia402 as c
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.pdo import SdoWrite, mapping_entry, pdo_writes
from nurbsmotion.io_config import IoConfig, IoSignal
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

READ_INPUT_8 = 0x6000
WRITE_OUTPUT_8 = 0x6200
CIA_401 = 0x0191  # device type 0x1000, low 16 bits: the device profile number
EVENT_DRIVEN = 255  # transmission type: on change (CiA 301 'event-driven, device profile specific')


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


def io_configuration(io: IoConfig, heartbeat_producer_ms: int) -> list[SdoWrite]:
    """SDO writes of the I/O node's bring-up (PRE-OPERATIONAL): TPDO1 = the used input
    groups, RPDO1 = the used output groups, both event driven; the rest disabled."""
    node = io.node_id
    inputs = [mapping_entry(READ_INPUT_8, n, 8) for n in range(1, io.input_groups + 1)] or None
    outputs = [mapping_entry(WRITE_OUTPUT_8, n, 8) for n in range(1, io.output_groups + 1)] or None
    writes = pdo_writes("TPDO", 1, node, inputs, EVENT_DRIVEN) + pdo_writes("RPDO", 1, node, outputs, EVENT_DRIVEN)
    for n in (2, 3, 4):
        writes += pdo_writes("TPDO", n, node, None, EVENT_DRIVEN) + pdo_writes("RPDO", n, node, None, EVENT_DRIVEN)
    writes.append(SdoWrite("set heartbeat producer", c.PRODUCER_HEARTBEAT_TIME, 0, "<H", heartbeat_producer_ms))
    return writes


class IoNode:
    """The machine's I/O node on a connected ``canopen.Network``.

    ``on_change(name, active)`` is called from the network's receive thread for every input
    that changes after :meth:`bring_up`; keep it short.
    """

    def __init__(self, network: canopen.Network, io: IoConfig,
                 on_change: Callable[[str, bool], None] | None = None) -> None:
        self.network = network
        self.io = io
        self.on_change = on_change
        self.node = canopen.RemoteNode(io.node_id, ObjectDictionary())
        network.add_node(self.node)
        self._lock = threading.Lock()
        self._inputs: dict[str, bool] | None = None
        self._outputs: dict[str, bool] = {s.name: False for s in io.outputs}
        self._output_names = {s.name for s in io.outputs}
        self._subscribed = False

    # ------------------------------------------------------------------ bring-up
    def bring_up(self, heartbeat_producer_ms: int) -> None:
        """Check, configure, read the inputs, start (NMT); FieldbusError names node and step."""
        sdo, node_id = self.node.sdo, self.io.node_id
        device = bringup.sdo_upload(sdo, node_id, "I/O device type", c.DEVICE_TYPE, 0, "<I")
        if device & 0xFFFF != CIA_401:
            raise bringup.step_error(node_id, "I/O device type", f"0x1000 = 0x{device:08X}: not a CiA-401 I/O device")
        self._check_size(READ_INPUT_8, self.io.input_groups, "inputs")
        self._check_size(WRITE_OUTPUT_8, self.io.output_groups, "outputs")
        bringup.configure_drive(sdo, node_id, io_configuration(self.io, heartbeat_producer_ms))
        self.network.subscribe(c.COB_TPDO[0] + node_id, self._on_tpdo)
        self._subscribed = True
        groups = bytes(bringup.sdo_upload(sdo, node_id, "read inputs", READ_INPUT_8, n, "<B")
                       for n in range(1, self.io.input_groups + 1))
        with self._lock:
            self._inputs = input_states(groups, self.io.inputs)
        self.node.nmt.send_command(c.NmtCommand.START)
        self._send_outputs()
        log.info(kv("io.ready", node=node_id, inputs=self.inputs))

    def _check_size(self, index: int, needed: int, what: str) -> None:
        if needed == 0:
            return
        step = f"I/O {what}"
        have = bringup.sdo_upload(self.node.sdo, self.io.node_id, step, index, 0, "<B")
        if have < needed:
            raise bringup.step_error(self.io.node_id, step, f"0x{index:04X} has {have} groups of 8 {what}, "
                                     f"the io section needs {needed}")

    def close(self) -> None:
        if self._subscribed:
            self.network.unsubscribe(c.COB_TPDO[0] + self.io.node_id, self._on_tpdo)
            self._subscribed = False

    # ------------------------------------------------------------------ inputs
    @property
    def inputs(self) -> dict[str, bool] | None:
        """Latest named input states; None before the first read."""
        with self._lock:
            return dict(self._inputs) if self._inputs is not None else None

    def input(self, name: str) -> bool | None:
        with self._lock:
            return None if self._inputs is None else self._inputs[name]

    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < self.io.input_groups:
            log.warning(kv("io.tpdo_length", node=self.io.node_id, length=len(data), expected=self.io.input_groups))
            return
        states = input_states(bytes(data), self.io.inputs)
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

    def _send_outputs(self) -> Any:
        if self.io.output_groups:
            with self._lock:
                data = output_groups(self._outputs, self.io.outputs, self.io.output_groups)
            self.network.send_message(c.COB_RPDO[0] + self.io.node_id, data)
