"""One simulated CiA-402 servo drive on a canopen Network.

canopen's ``LocalNode`` provides the object dictionary (from the EDS) and the SDO server.
This module adds what a real drive does and ``LocalNode`` does not (reference, section 4):
its own NMT slave (boot-up, heartbeat, PDOs only in OPERATIONAL, SDO silent in STOPPED),
RPDO data written into the drive at the next SYNC (CiA 301), TPDOs on SYNC per the mapping
and transmission type the master wrote, the CiA-402 state machine, IP and CSP set-points,
the servo model, EMCY, set-point recording and fault injection.

All handlers run in the network's receive thread (SYNC, RPDO, SDO, NMT) or in the
network's ticker thread (heartbeat, timed faults); one lock per drive serialises them.
"""

from __future__ import annotations

import bisect
import logging
import math
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import can
import canopen
from canopen.objectdictionary import ODArray, ObjectDictionary
from canopen.sdo import SdoAbortedError

from nurbsmotion import cia402 as c
from nurbsmotion.cia402 import EmcyCode, Mode, NmtCommand, NmtState, State
from nurbsmotion.log import kv
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.eds import default_eds_path
from nurbsmotion.sim.heartbeat import HeartbeatConsumer
from nurbsmotion.sim.faults import DEFAULT_FAULT_CODE, DEFAULT_SDO_ABORT_CODE, FaultInjection
from nurbsmotion.sim.recording import SetpointRecorder
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.statemachine import apply_controlword, quick_stop_stays_active

log = logging.getLogger(__name__)

SUPPORTED_MODES = (int(Mode.INTERPOLATED_POSITION), int(Mode.CYCLIC_SYNC_POSITION))
FE_WINDOW_DISABLED = 0xFFFF_FFFF
ERROR_HISTORY_LENGTH = 8
EMCY_STRUCT = struct.Struct("<HB5x")
STATES_WITH_VOLTAGE = (State.SWITCHED_ON, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)
_FOREVER = math.inf


@dataclass
class DriveStats:
    """Counters a test or the log can check (all since the drive was created)."""

    syncs: int = 0
    syncs_ignored: int = 0
    rpdos_received: int = 0
    rpdos_dropped: int = 0
    rpdos_overwritten: int = 0  # a synchronous RPDO replaced by a newer one before the SYNC
    rpdo_length_errors: int = 0
    pdo_values_refused: int = 0  # e.g. an unsupported mode written by RPDO
    setpoints_applied: int = 0
    setpoints_ignored: int = 0  # received while not enabled / not in the mode
    setpoints_refused: int = 0  # outside the software position limits
    tpdos_sent: int = 0
    emcys_sent: int = 0
    heartbeats_sent: int = 0


@dataclass
class _TpdoSlot:
    layout: pdo_layout.PdoLayout
    message: can.Message
    getters: list[Callable[[], Any]]
    sync_count: int = 0
    last_data: bytes = b""


@dataclass
class _RpdoSlot:
    layout: pdo_layout.PdoLayout
    setters: list[Callable[[Any], None]]


def error_register_bits(code: int) -> int:
    """0x1001 bits for an EMCY code (CiA 301: bit 0 generic, 1 current, 2 voltage,
    3 temperature, 4 communication, 5 device profile, 7 manufacturer)."""
    bits = 0x01
    group = code >> 12
    if group == 0x2:
        bits |= 0x02
    elif group == 0x3:
        bits |= 0x04
    elif group == 0x4:
        bits |= 0x08
    elif code >> 8 in (0x81, 0x82):
        bits |= 0x10
    elif code >> 8 == 0x86:
        bits |= 0x20
    elif code >> 8 == 0xFF:
        bits |= 0x80
    return bits


class _DriveNode(canopen.LocalNode):
    """LocalNode whose SDO writes go through the drive (validation before, effects after)."""

    def __init__(self, node_id: int, od: ObjectDictionary, drive: "SimDrive") -> None:
        super().__init__(node_id, od)
        self._drive = drive
        self._write_callbacks.clear()  # LocalNode's NmtSlave heartbeat is replaced by the drive's
        self.add_write_callback(drive._before_sdo_write)
        self.add_read_callback(drive._on_sdo_read)

    def set_data(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        super().set_data(index, subindex, data, check_writable)
        if check_writable:  # an SDO write from the bus
            self._drive._after_sdo_write(index, subindex)

    def _find_object(self, index: int, subindex: int) -> Any:
        """As LocalNode, but an ARRAY has only the sub-indices the EDS declares."""
        obj = super()._find_object(index, subindex)
        parent = self.object_dictionary[index]
        if isinstance(parent, ODArray) and subindex not in parent.subindices:
            raise SdoAbortedError(0x06090011)
        return obj

    def associate_network(self, network: canopen.Network) -> None:
        """Join without LocalNode's own SDO and NMT handlers (the drive gates them)."""
        super().associate_network(network)
        network.unsubscribe(self.sdo.rx_cobid, self.sdo.on_request)
        network.unsubscribe(0, self.nmt.on_command)

    def remove_network(self) -> None:
        if self.has_network():  # LocalNode.remove_network unsubscribes what it subscribed
            self.network.subscribe(self.sdo.rx_cobid, self.sdo.on_request)
            self.network.subscribe(0, self.nmt.on_command)
        super().remove_network()


class SimDrive:
    """A simulated CiA-402 servo drive (IP and CSP) with node id ``node_id``.

    Create it, then :meth:`attach` it to a connected ``canopen.Network`` (``SimNetwork`` does
    both). ``lag_cycles`` and ``max_velocity_counts_s`` set the servo model; ``identity``
    (vendor id, product code) overrides 0x1018 sub 1/2; ``parameters`` {(index, subindex):
    value} are the drive's stored values, restored instead of the EDS defaults on every reset.
    """

    def __init__(
        self,
        node_id: int,
        eds: str | Path | None = None,
        *,
        lag_cycles: int = 1,
        max_velocity_counts_s: float = 1e9,
        identity: tuple[int, int] | None = None,
        parameters: dict[tuple[int, int], int] | None = None,
        name: str | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} outside 1..127")
        self.node_id = node_id
        self.name = name or f"node{node_id}"
        self.eds_path = Path(eds) if eds else default_eds_path()
        self.od = canopen.import_od(str(self.eds_path), node_id)
        self.identity = identity
        self.node = _DriveNode(node_id, self.od, self)
        self._stored = self._encode_parameters(parameters or {})
        if identity is not None:
            self._stored[(c.IDENTITY, 1)] = struct.pack("<I", identity[0])
            self._stored[(c.IDENTITY, 2)] = struct.pack("<I", identity[1])
        self.servo = ServoModel(lag_cycles, max_velocity_counts_s)
        self.recorder = SetpointRecorder()
        self.stats = DriveStats()
        self.network: canopen.Network | None = None
        self._clock = clock
        self._lock = threading.RLock()
        self._subscriptions: list[tuple[int, Callable[..., None]]] = []
        self._rpdo_by_cob: dict[int, _RpdoSlot] = {}
        self._rpdos: dict[int, _RpdoSlot] = {}
        self._tpdos: list[_TpdoSlot] = []
        self._pending: dict[int, tuple[list[Callable[[Any], None]], tuple]] = {}
        self._time_faults: list[tuple[float, int, FaultInjection]] = []
        self._sync_faults: list[tuple[int, int, FaultInjection]] = []
        self._fault_seq = 0
        self._t0 = clock()
        self._heartbeat_consumer = HeartbeatConsumer()
        self._consumed_cobs: list[int] = []
        self.nmt_state = NmtState.BOOTUP
        self.silent = False
        self._init_application()
        self._init_injections()
        self._live_read: dict[tuple[int, int], Callable[[], Any]] = {
            (c.STATUSWORD, 0): lambda: self.statusword,
            (c.CONTROLWORD, 0): lambda: self.controlword,
            (c.MODES_OF_OPERATION, 0): lambda: self.mode,
            (c.MODES_OF_OPERATION_DISPLAY, 0): lambda: self.mode_display,
            (c.POSITION_ACTUAL, 0): lambda: self.position_actual,
            (c.FOLLOWING_ERROR_ACTUAL, 0): lambda: self.following_error,
            (c.TARGET_POSITION, 0): lambda: self.target_position,
            (c.IP_DATA_RECORD, 1): lambda: self.ip_setpoint,
            (c.ERROR_CODE, 0): lambda: self.error_code,
            (c.ERROR_REGISTER, 0): lambda: self.error_register,
            (c.PREDEFINED_ERROR_FIELD, 0): lambda: len(self.error_history),
        }
        self._live_write: dict[tuple[int, int], Callable[[Any], None]] = {
            (c.CONTROLWORD, 0): self._set_controlword,
            (c.MODES_OF_OPERATION, 0): self._set_mode,
            (c.TARGET_POSITION, 0): self._set_target_position,
            (c.IP_DATA_RECORD, 1): self._set_ip_setpoint,
        }

    # ------------------------------------------------------------------ public API
    @property
    def state(self) -> State:
        """The CiA-402 state."""
        return self._state

    @property
    def sync_index(self) -> int:
        """SYNCs received since the drive last entered NMT OPERATIONAL (first SYNC = 1)."""
        return self._sync_index

    def attach(self, network: canopen.Network) -> None:
        """Join a connected network and boot (boot-up message, then PRE-OPERATIONAL)."""
        with self._lock:
            if self.network is not None:
                raise RuntimeError(f"{self.name} is already attached")
            self.network = network
            self.node.associate_network(network)
            self._subscribe(c.COB_NMT, self._on_nmt)
            self._subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
            self._t0 = self._clock()
            self._boot(reset_application=True)

    def detach(self) -> None:
        """Leave the network (no more frames in or out)."""
        with self._lock:
            if self.network is None:
                return
            self._unsubscribe_all()
            self._rpdo_by_cob.clear()
            del self._sync_cob
            self.node.remove_network()
            self.network = None

    def inject(self, fault: FaultInjection) -> None:
        """Inject ``fault`` now, at its SYNC index or at its time (seconds after attach)."""
        with self._lock:
            self._fault_seq += 1
            if fault.at_sync is not None:
                bisect.insort(self._sync_faults, (fault.at_sync, self._fault_seq, fault))
            elif fault.at_s is not None:
                bisect.insort(self._time_faults, (self._t0 + fault.at_s, self._fault_seq, fault))
            else:
                self._apply_injection(fault)

    def clear_injections(self) -> None:
        """Cancel pending and active injections (ignore SYNC, drops, SDO refusals, stall)."""
        with self._lock:
            self._init_injections()
            self.servo.stalled = False

    def power_on(self) -> None:
        """Power back on after a power loss: boots like a reset node (position is kept)."""
        with self._lock:
            self.silent = False
            self._boot(reset_application=True)

    def tick(self, now: float) -> float:
        """Send a due heartbeat and fire due timed faults; returns the next deadline."""
        with self._lock:
            while self._time_faults and self._time_faults[0][0] <= now:
                _, _, fault = self._time_faults.pop(0)
                self._apply_injection(fault)
            if self._heartbeat_period_s > 0 and not self.silent and now >= self._next_heartbeat:
                self._send_heartbeat()
                self._next_heartbeat = max(self._next_heartbeat + self._heartbeat_period_s, now)
            for producer in self._heartbeat_consumer.newly_failed(now):
                if not self.silent:
                    log.warning(kv("sim.heartbeat_lost", node=self.node_id, producer=producer))
                    self._raise_fault(EmcyCode.HEARTBEAT)
            deadline = min(now + 0.05, self._heartbeat_consumer.next_deadline())
            if self._heartbeat_period_s > 0:
                deadline = min(deadline, self._next_heartbeat)
            if self._time_faults:
                deadline = min(deadline, self._time_faults[0][0])
            return deadline

    def write_recording(self, path: str | Path) -> Path:
        """Write the applied set-points as CSV (see ``recording``)."""
        return self.recorder.write_csv(path)

    # ------------------------------------------------------------------ boot and NMT
    def _init_application(self) -> None:
        """Application state after power-on or reset node (the motor position is kept)."""
        self._state = State.SWITCH_ON_DISABLED  # transitions 0 and 1 are automatic
        self.transitions: list[int] = [0, 1]
        self.controlword = 0
        stored_mode = self._stored.get((c.MODES_OF_OPERATION, 0))
        self.mode = self.od[c.MODES_OF_OPERATION].decode_raw(stored_mode) if stored_mode else int(self.od[c.MODES_OF_OPERATION].default)
        self.mode_display = self.mode
        self.target_position = 0
        self.ip_setpoint = 0
        self._fresh_target = False
        self._fresh_ip = False
        self._demand = self.servo.actual
        self.position_actual = int(round(self.servo.actual))
        self.following_error = 0
        self._fe_cycles = 0
        self._fe_flag = False
        self.error_code = 0
        self.error_register = 0
        self.error_history: list[int] = []
        self.statusword = 0
        self._sync_index = 0
        self._update_statusword()

    def _init_injections(self) -> None:
        self._ignore_syncs: float = 0
        self._drop_rpdos = 0
        self._sdo_refusals: list[list[Any]] = []  # [index|None, subindex|None, code, remaining]
        self._time_faults = []
        self._sync_faults = []

    def _boot(self, reset_application: bool) -> None:
        """Reset communication (and the application): defaults back, boot-up, PRE-OPERATIONAL."""
        self.nmt_state = NmtState.BOOTUP
        store = self.node.data_store
        for index in list(store):
            if reset_application or 0x1000 <= index <= 0x1FFF:
                del store[index]
        for (index, subindex), data in self._stored.items():
            if reset_application or 0x1000 <= index <= 0x1FFF:
                store.setdefault(index, {})[subindex] = data
        if reset_application:
            self._init_application()
        self._pending.clear()
        self._load_parameters()
        self._rebuild_all_pdos()
        self._configure_heartbeat_consumer()
        self._send(c.COB_HEARTBEAT + self.node_id, bytes([NmtState.BOOTUP]))
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._next_heartbeat = self._clock() + self._heartbeat_period_s
        log.info(kv("sim.boot", node=self.node_id, reset_application=reset_application))

    def _encode_parameters(self, parameters: dict[tuple[int, int], int]) -> dict[tuple[int, int], bytes]:
        encoded = {}
        for (index, subindex), value in parameters.items():
            var = pdo_layout.find_variable(self.od, index, subindex)
            if var is None:
                raise ValueError(f"node {self.node_id}: no object 0x{index:04X} sub {subindex} in {self.eds_path}")
            encoded[(index, subindex)] = var.encode_raw(value)
        return encoded

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        with self._lock:
            if self.silent:
                return
            command = data[0]
            if command == NmtCommand.START:
                self._enter_nmt(NmtState.OPERATIONAL)
            elif command == NmtCommand.STOP:
                self._enter_nmt(NmtState.STOPPED)
            elif command == NmtCommand.PRE_OPERATIONAL:
                self._enter_nmt(NmtState.PRE_OPERATIONAL)
            elif command == NmtCommand.RESET_NODE:
                self._boot(reset_application=True)
            elif command == NmtCommand.RESET_COMMUNICATION:
                self._boot(reset_application=False)

    def _enter_nmt(self, new: NmtState) -> None:
        if new == self.nmt_state:
            return
        if new == NmtState.OPERATIONAL:
            self._sync_index = 0
            self._pending.clear()
            for slot in self._tpdos:
                slot.sync_count = 0
                slot.last_data = b""
        log.info(kv("sim.nmt", node=self.node_id, state=new.name, previous=self.nmt_state.name))
        self.nmt_state = new

    def _configure_heartbeat_consumer(self) -> None:
        """Watch the producers listed in 0x1016 (EMCY 0x8130 and fault when one goes silent)."""
        entries = [self._od_value(c.CONSUMER_HEARTBEAT_TIME, n) for n in range(1, self._od_value(c.CONSUMER_HEARTBEAT_TIME, 0) + 1)]
        self._heartbeat_consumer.configure(entries)
        for cob in self._consumed_cobs:
            self._unsubscribe(cob, self._on_peer_heartbeat)
        self._consumed_cobs = [c.COB_HEARTBEAT + n for n in self._heartbeat_consumer.timeouts_s]
        if self.network is not None:
            for cob in self._consumed_cobs:
                self._subscribe(cob, self._on_peer_heartbeat)

    def _on_peer_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            self._heartbeat_consumer.seen(can_id - c.COB_HEARTBEAT, self._clock())

    def _send_heartbeat(self) -> None:
        if self.nmt_state != NmtState.BOOTUP:
            self._send(c.COB_HEARTBEAT + self.node_id, bytes([self.nmt_state]))
            self.stats.heartbeats_sent += 1

    def _send(self, can_id: int, data: bytes) -> None:
        if self.network is not None and not self.silent:
            self.network.send_message(can_id, data)

    def _subscribe(self, can_id: int, callback: Callable[..., None]) -> None:
        assert self.network is not None
        self.network.subscribe(can_id, callback)
        self._subscriptions.append((can_id, callback))

    def _unsubscribe(self, can_id: int, callback: Callable[..., None]) -> None:
        if (can_id, callback) in self._subscriptions:
            self._subscriptions.remove((can_id, callback))
            assert self.network is not None
            self.network.unsubscribe(can_id, callback)

    def _unsubscribe_all(self) -> None:
        for can_id, callback in list(self._subscriptions):
            self._unsubscribe(can_id, callback)

    # ------------------------------------------------------------------ parameters
    def _od_value(self, index: int, subindex: int = 0) -> Any:
        var = pdo_layout.find_variable(self.od, index, subindex)
        assert var is not None, (hex(index), subindex)
        return var.decode_raw(self.node.get_data(index, subindex))

    def _load_parameters(self) -> None:
        """Cache the parameters the SYNC handler uses (refreshed after every SDO write)."""
        value, exponent = self._od_value(c.IP_TIME_PERIOD, 1), self._od_value(c.IP_TIME_PERIOD, 2)
        period_s = value * 10.0**exponent
        if period_s <= 0:
            period_s = self._od_value(c.COMM_CYCLE_PERIOD) * 1e-6
        self.period_s = period_s if period_s > 0 else 1e-3
        self._fe_window = self._od_value(c.FOLLOWING_ERROR_WINDOW)
        self._fe_timeout_ms = self._od_value(c.FOLLOWING_ERROR_TIMEOUT)
        self._quick_stop_option = self._od_value(c.QUICK_STOP_OPTION)
        self._quick_stop_decel = float(self._od_value(c.QUICK_STOP_DECELERATION))
        self._limit_min = self._od_value(c.SOFTWARE_POSITION_LIMIT, 1)
        self._limit_max = self._od_value(c.SOFTWARE_POSITION_LIMIT, 2)
        self._emcy_cob = self._od_value(c.EMCY_COB_ID)
        self._heartbeat_period_s = self._od_value(c.PRODUCER_HEARTBEAT_TIME) / 1000.0
        sync_cob = self._od_value(c.SYNC_COB_ID) & 0x7FF
        if getattr(self, "_sync_cob", None) != sync_cob and self.network is not None:
            if hasattr(self, "_sync_cob"):
                self._unsubscribe(self._sync_cob, self._on_sync)
            self._subscribe(sync_cob, self._on_sync)
            self._sync_cob = sync_cob

    # ------------------------------------------------------------------ SDO server
    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self.silent or self.nmt_state in (NmtState.STOPPED, NmtState.BOOTUP):
                return
            self.node.sdo.on_request(can_id, data, timestamp)

    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> Any:
        getter = self._live_read.get((index, subindex))
        if getter is not None:
            return getter()
        if index == c.PREDEFINED_ERROR_FIELD:
            history = self.error_history
            return history[subindex - 1] if subindex <= len(history) else 0
        return None

    def _before_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Validate an SDO write (raise SdoAbortedError to refuse) and apply live objects."""
        self._check_refusal(index, subindex)
        value = od.decode_raw(data)
        if 0x1400 <= index <= 0x1403 or 0x1800 <= index <= 0x1803:
            self._check_pdo_comm_write(index, subindex, value)
        elif 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
            self._check_pdo_mapping_write(index, subindex, value)
        elif index == c.PREDEFINED_ERROR_FIELD:
            if subindex != 0 or value != 0:
                raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
            self.error_history.clear()
        elif index == c.SYNC_COB_ID and value & pdo_layout.COB_ID_EXTENDED_BIT:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        setter = self._live_write.get((index, subindex))
        if setter is not None:
            setter(value)

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        if 0x1400 <= index <= 0x1A03:
            self._rebuild_all_pdos()
        elif index == c.CONSUMER_HEARTBEAT_TIME:
            self._configure_heartbeat_consumer()
        else:
            self._load_parameters()

    def _check_refusal(self, index: int, subindex: int) -> None:
        for refusal in self._sdo_refusals:
            want_index, want_sub, code, remaining = refusal
            if (want_index is None or want_index == index) and (want_sub is None or want_sub == subindex):
                refusal[3] = remaining - 1
                if refusal[3] <= 0:
                    self._sdo_refusals.remove(refusal)
                raise SdoAbortedError(code)

    def _check_pdo_comm_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301: the CAN id of a valid PDO cannot change; disable it (bit 31) first."""
        if subindex == 1:
            current = self._od_value(index, 1)
            if value & pdo_layout.COB_ID_EXTENDED_BIT:
                raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
            both_valid = not current & pdo_layout.COB_ID_INVALID_BIT and not value & pdo_layout.COB_ID_INVALID_BIT
            if both_valid and (current & 0x7FF) != (value & 0x7FF):
                raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        elif subindex == 2 and 241 <= value <= 251:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)

    def _check_pdo_mapping_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301 mapping procedure: PDO disabled, count 0, entries, count, enable."""
        receive = index < 0x1A00
        comm_index = index - 0x200
        if not self._od_value(comm_index, 1) & pdo_layout.COB_ID_INVALID_BIT:
            raise SdoAbortedError(pdo_layout.ABORT_DEVICE_STATE)
        if subindex == 0:
            entries = [self._od_value(index, n) for n in range(1, value + 1)] if value <= 8 else [0] * value
            pdo_layout.check_entries(self.od, entries, receive)
        else:
            if self._od_value(index, 0) != 0:
                raise SdoAbortedError(pdo_layout.ABORT_DEVICE_STATE)
            pdo_layout.check_entry(self.od, value, receive)

    # ------------------------------------------------------------------ PDO layouts
    def _mapping(self, map_index: int) -> list[int]:
        count = self._od_value(map_index, 0)
        return [self._od_value(map_index, n) for n in range(1, count + 1)]

    def _rebuild_all_pdos(self) -> None:
        """Recompute every PDO's struct, setters/getters and subscription (after a remap)."""
        for slot in list(self._rpdo_by_cob.values()):
            self._unsubscribe(slot.layout.cob_id, self._on_rpdo)
        self._rpdo_by_cob.clear()
        self._rpdos.clear()
        self._tpdos = []
        for n in range(1, 5):
            layout = pdo_layout.build_layout(
                self.od, n, self._od_value(0x1400 + n - 1, 1), self._od_value(0x1400 + n - 1, 2), self._mapping(0x1600 + n - 1)
            )
            if layout.enabled and layout.keys:
                slot = _RpdoSlot(layout, [self._setter(key) for key in layout.keys])
                self._rpdos[n] = slot
                if layout.cob_id not in self._rpdo_by_cob and self.network is not None:
                    self._subscribe(layout.cob_id, self._on_rpdo)
                self._rpdo_by_cob[layout.cob_id] = slot
            layout = pdo_layout.build_layout(
                self.od, n, self._od_value(0x1800 + n - 1, 1), self._od_value(0x1800 + n - 1, 2), self._mapping(0x1A00 + n - 1)
            )
            if layout.enabled and layout.keys:
                message = can.Message(arbitration_id=layout.cob_id, is_extended_id=False, data=bytearray(layout.size))
                self._tpdos.append(_TpdoSlot(layout, message, [self._getter(key) for key in layout.keys]))
        self._pending.clear()
        self._load_parameters()

    def _setter(self, key: tuple[int, int]) -> Callable[[Any], None]:
        live = self._live_write.get(key)
        if live is not None:
            return live
        var = pdo_layout.find_variable(self.od, *key)
        assert var is not None
        store = self.node.data_store

        def store_value(value: Any) -> None:
            store.setdefault(key[0], {})[key[1]] = var.encode_raw(value)
            self._load_parameters()

        return store_value

    def _getter(self, key: tuple[int, int]) -> Callable[[], Any]:
        live = self._live_read.get(key)
        if live is not None:
            return live
        return lambda: self._od_value(*key)

    # ------------------------------------------------------------------ PDO traffic
    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self.silent or self.nmt_state != NmtState.OPERATIONAL:
                return
            slot = self._rpdo_by_cob.get(can_id)
            if slot is None:
                return
            self.stats.rpdos_received += 1
            if self._drop_rpdos > 0:
                self._drop_rpdos -= 1
                self.stats.rpdos_dropped += 1
                return
            if len(data) < slot.layout.size:
                self.stats.rpdo_length_errors += 1
                self._send_emcy(EmcyCode.PDO_LENGTH, self.error_register)
                return
            values = slot.layout.codec.unpack_from(data)
            if slot.layout.synchronous:
                if slot.layout.number in self._pending:
                    self.stats.rpdos_overwritten += 1
                self._pending[slot.layout.number] = (slot.setters, values)
            else:
                self._apply_values(slot.setters, values)
                self._update_statusword()

    def _apply_values(self, setters: list[Callable[[Any], None]], values: tuple) -> None:
        for setter, value in zip(setters, values):
            try:
                setter(value)
            except SdoAbortedError:
                self.stats.pdo_values_refused += 1

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        """CiA 301 SYNC: apply RPDO data received since the last SYNC, move, send TPDOs."""
        with self._lock:
            if self.silent or self.nmt_state != NmtState.OPERATIONAL:
                return
            try:
                self._handle_sync(data[0] if data else -1)
            finally:
                self.stats.syncs += 1  # counted once the SYNC's TPDOs are out

    def _handle_sync(self, sync_counter: int) -> None:
        self._sync_index += 1
        while self._sync_faults and self._sync_faults[0][0] <= self._sync_index:
            self._apply_injection(self._sync_faults.pop(0)[2])
            if self.silent:
                return
        if self._ignore_syncs > 0:
            self._ignore_syncs -= 1
            self.stats.syncs_ignored += 1
            return
        if self._pending:
            for setters, values in self._pending.values():
                self._apply_values(setters, values)
            self._pending.clear()
        self._motion_step(sync_counter)
        self._send_tpdos()

    def _send_tpdos(self) -> None:
        network = self.network
        if network is None:
            return
        for slot in self._tpdos:
            kind = slot.layout.transmission_type
            if 1 <= kind <= 240:
                slot.sync_count += 1
                if slot.sync_count < kind:
                    continue
                slot.sync_count = 0
            elif 241 <= kind <= 253:
                continue  # reserved / RTR only: never on SYNC
            data = slot.message.data
            slot.layout.codec.pack_into(data, 0, *[getter() for getter in slot.getters])
            if kind == 0 or kind >= 254:  # acyclic / event driven: only when the data changed
                if data == slot.last_data:
                    continue
                slot.last_data = bytes(data)
            with network.send_lock:
                network.bus.send(slot.message)
            self.stats.tpdos_sent += 1

    # ------------------------------------------------------------------ CiA 402 drive
    def _set_controlword(self, controlword: int) -> None:
        previous, self.controlword = self.controlword, controlword
        new_state, taken = apply_controlword(self._state, controlword, previous, self._quick_stop_option)
        if taken:
            self._change_state(new_state, taken)
        elif self._state is State.OPERATION_ENABLED and controlword & c.CW_ENABLE_IP and not previous & c.CW_ENABLE_IP:
            self._fresh_ip = False  # IP enabled: hold position until the first new set-point
        self._update_statusword()

    def _change_state(self, new_state: State, taken: list[int]) -> None:
        old = self._state
        self._state = new_state
        self.transitions.extend(taken)
        if new_state is State.OPERATION_ENABLED and old is not State.OPERATION_ENABLED:
            self._hold_position()
        elif new_state is State.QUICK_STOP_ACTIVE and self._quick_stop_option == 0:
            self._state = State.SWITCH_ON_DISABLED  # option 0: disable drive function at once
            self.transitions.append(12)
            self._hold_position()
        elif new_state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
            self._hold_position()
        if 15 in taken:
            self.error_code = 0
            self.error_register = 0
            self._fe_flag = False
            self._fe_cycles = 0
            self._send_emcy(EmcyCode.NO_ERROR, 0)
        log.info(kv("sim.state", node=self.node_id, state=self._state.name, transitions=taken))

    def _hold_position(self) -> None:
        """Stand still where the motor is; set-points count only from the next new one."""
        self.servo.hold(self.servo.actual)
        self._demand = self.servo.actual
        self.following_error = 0
        self._fe_cycles = 0
        self._fresh_target = self._fresh_ip = False

    def _set_mode(self, mode: int) -> None:
        if mode not in SUPPORTED_MODES:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        if mode != self.mode_display:
            self._hold_position()
            log.info(kv("sim.mode", node=self.node_id, mode=mode))
        self.mode = self.mode_display = mode
        self._update_statusword()

    def _set_target_position(self, value: int) -> None:
        self.target_position = value
        self._fresh_target = True

    def _set_ip_setpoint(self, value: int) -> None:
        self.ip_setpoint = value
        self._fresh_ip = True

    def _setpoint_active(self) -> bool:
        """Statusword bit 12: CSP 'target used' / IP 'interpolation active'."""
        if self._state is not State.OPERATION_ENABLED:
            return False
        if self.mode_display == Mode.CYCLIC_SYNC_POSITION:
            return True
        return self.mode_display == Mode.INTERPOLATED_POSITION and bool(self.controlword & c.CW_ENABLE_IP)

    def _motion_step(self, sync_counter: int) -> None:
        """One SYNC of the servo: take the new set-point, move, check the following error."""
        period_s = self.period_s
        state = self._state
        fresh = self._fresh_target if self.mode_display == Mode.CYCLIC_SYNC_POSITION else self._fresh_ip
        self._fresh_target = self._fresh_ip = False
        if state is State.OPERATION_ENABLED:
            if fresh and self._setpoint_active():
                setpoint = self.target_position if self.mode_display == Mode.CYCLIC_SYNC_POSITION else self.ip_setpoint
                if self._limit_min < self._limit_max and not self._limit_min <= setpoint <= self._limit_max:
                    self.stats.setpoints_refused += 1
                    self._raise_fault(EmcyCode.SOFTWARE_LIMIT)
                    return
                self._demand = setpoint
                actual = self.servo.step(setpoint, period_s)
                self.position_actual = int(round(actual))
                self.recorder.append(self._sync_index, self.mode_display, setpoint, self.position_actual, sync_counter)
                self.stats.setpoints_applied += 1
            else:
                if fresh:
                    self.stats.setpoints_ignored += 1
                self.position_actual = int(round(self.servo.step(self._demand, period_s)))
            self._check_following_error(period_s)
        elif state is State.QUICK_STOP_ACTIVE:
            stopped = self.servo.ramp_down(self._quick_stop_decel, period_s)
            self._demand = self.servo.actual
            self.position_actual = int(round(self.servo.actual))
            if stopped and not quick_stop_stays_active(self._quick_stop_option):
                self._change_state(State.SWITCH_ON_DISABLED, [12])
        elif fresh:
            self.stats.setpoints_ignored += 1
        self._update_statusword()

    def _check_following_error(self, period_s: float) -> None:
        """0x60F4 = demand - actual; fault 0x8611 when |e| > 0x6065 for longer than 0x6066 ms."""
        error = int(round(self._demand - self.servo.actual))
        self.following_error = error
        if self._fe_window == FE_WINDOW_DISABLED or abs(error) <= self._fe_window:
            self._fe_cycles = 0
            return
        self._fe_cycles += 1
        if self._fe_cycles * period_s * 1000.0 > self._fe_timeout_ms:
            self._fe_flag = True
            self._raise_fault(EmcyCode.FOLLOWING_ERROR)

    def _update_statusword(self) -> None:
        word = c.STATUSWORD_OF_STATE[self._state] | c.SW_REMOTE
        if self._state in STATES_WITH_VOLTAGE:
            word |= c.SW_VOLTAGE_ENABLED
        if self._setpoint_active():
            word |= c.SW_IP_ACTIVE
        if self._fe_flag:
            word |= c.SW_FOLLOWING_ERROR
        self.statusword = word

    # ------------------------------------------------------------------ faults and EMCY
    def _raise_fault(self, code: int) -> None:
        """Transitions 13 and 14: fault reaction (motor held where it is), then FAULT; EMCY."""
        self.error_code = code
        self.error_register |= error_register_bits(code)
        self.error_history.insert(0, code)
        del self.error_history[ERROR_HISTORY_LENGTH:]
        if self._state is not State.FAULT:
            error_at_fault = self.following_error
            self._state = State.FAULT
            self.transitions.extend([13, 14])
            self._hold_position()
            self.following_error = error_at_fault  # 0x60F4 keeps the error that caused the fault
        self._update_statusword()
        self._send_emcy(code, self.error_register)
        log.warning(kv("sim.fault", node=self.node_id, code=f"0x{code:04X}"))

    def _send_emcy(self, code: int, register: int) -> None:
        if self._emcy_cob & pdo_layout.COB_ID_INVALID_BIT or self.nmt_state == NmtState.STOPPED:
            return
        self._send(self._emcy_cob & 0x7FF, EMCY_STRUCT.pack(code, register))
        self.stats.emcys_sent += 1

    def _apply_injection(self, fault: FaultInjection) -> None:
        log.warning(kv("sim.inject", node=self.node_id, kind=fault.kind, sync=self._sync_index))
        kind = fault.kind
        if kind == "fault":
            self._raise_fault(fault.code if fault.code is not None else DEFAULT_FAULT_CODE)
        elif kind in ("heartbeat_stop", "power_loss"):
            self.silent = True
        elif kind == "ignore_sync":
            self._ignore_syncs = fault.count if fault.count is not None else _FOREVER
        elif kind == "following_error":
            self._fe_flag = True
            self._raise_fault(EmcyCode.FOLLOWING_ERROR)
        elif kind == "stall":
            self.servo.stalled = True
        elif kind == "drop_rpdo":
            self._drop_rpdos += fault.count if fault.count is not None else 1
        elif kind == "sdo_abort":
            code = fault.code if fault.code is not None else DEFAULT_SDO_ABORT_CODE
            remaining = fault.count if fault.count is not None else _FOREVER
            self._sdo_refusals.append([fault.index, fault.subindex, code, remaining])
