"""One simulated CiA-402 servo drive on a canopen Network: the bus side of the drive.

canopen's ``LocalNode`` provides the object dictionary (from the EDS) and the SDO server.
This module adds what a real drive does and ``LocalNode`` does not (reference, section 4):
its own NMT slave (boot-up, heartbeat, PDOs only in OPERATIONAL, SDO silent in STOPPED),
RPDO data written into the drive at the next SYNC (CiA 301), TPDOs on SYNC per the mapping
and transmission type the master wrote, EMCY, the heartbeat consumer and fault injection.
The CiA-402 application itself (state machine, set-points, servo) is ``axis.Cia402Axis``.

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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODArray, ObjectDictionary
from canopen.sdo import SdoAbortedError

from nurbsmotion import cia402 as c
from nurbsmotion.cia402 import EmcyCode, NmtCommand, NmtState, State
from nurbsmotion.log import kv
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.axis import Cia402Axis, UnsupportedMode
from nurbsmotion.sim.eds import default_eds_path
from nurbsmotion.sim.faults import DEFAULT_FAULT_CODE, DEFAULT_SDO_ABORT_CODE, FaultInjection
from nurbsmotion.sim.heartbeat import HeartbeatConsumer
from nurbsmotion.sim.recording import SetpointRecorder
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.stats import DriveStats

log = logging.getLogger(__name__)

EMCY_STRUCT = struct.Struct("<HB5x")
ABORT_NO_SUBINDEX = 0x06090011
IP_LINEAR = 0  # 0x60C0 sub-mode
DEFAULT_PERIOD_S = 1e-3  # if 0x60C2 is 0
TICK_MAX_S = 0.05  # the ticker looks at a drive at least this often
_FOREVER = math.inf


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


class _DriveNode(canopen.LocalNode):
    """LocalNode whose SDO writes go through the drive (validation before, effects after)."""

    def __init__(self, node_id: int, od: ObjectDictionary, drive: SimDrive) -> None:
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
            raise SdoAbortedError(ABORT_NO_SUBINDEX)
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
    value} are the drive's stored values, restored instead of the EDS defaults on every reset;
    ``record`` keeps every applied set-point in ``recorder``.
    """

    def __init__(
        self,
        node_id: int,
        eds: str | Path | None = None,
        *,
        lag_cycles: int = 1,
        max_velocity_counts_s: float = math.inf,
        identity: tuple[int, int] | None = None,
        parameters: dict[tuple[int, int], int] | None = None,
        record: bool = True,
        name: str | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} outside 1..127")
        self.node_id = node_id
        self.name = name or f"node{node_id}"
        self.eds_path = Path(eds) if eds else default_eds_path()
        self.od = canopen.import_od(str(self.eds_path), node_id)
        self.node = _DriveNode(node_id, self.od, self)
        self._stored = self._encode_parameters(parameters or {})
        if identity is not None:
            self._stored[(c.IDENTITY, 1)] = struct.pack("<I", identity[0])
            self._stored[(c.IDENTITY, 2)] = struct.pack("<I", identity[1])
        self.servo = ServoModel(lag_cycles, max_velocity_counts_s)
        self.recorder = SetpointRecorder(enabled=record)
        self.stats = DriveStats()
        self.axis = Cia402Axis(self.servo, self.recorder, self.stats, self._send_emcy, self.name, self._stored_mode())
        self.network: canopen.Network | None = None
        self.nmt_state = NmtState.BOOTUP
        self.silent = False  # power loss: nothing in, nothing out
        self._clock = clock
        self._t0 = clock()
        self._lock = threading.RLock()
        self._subscriptions: list[tuple[int, Callable[..., None]]] = []
        self._sync_cob: int | None = None
        self._rpdo_by_cob: dict[int, _RpdoSlot] = {}
        self._tpdos: list[_TpdoSlot] = []
        self._pending: dict[int, tuple[list[Callable[[Any], None]], tuple]] = {}
        self._sync_index = 0
        self._fault_seq = 0
        self._heartbeat_consumer = HeartbeatConsumer()
        self._consumed_cobs: list[int] = []
        self._heartbeat_period_s = 0.0
        self._next_heartbeat = 0.0
        self._emcy_cob = pdo_layout.COB_ID_INVALID_BIT
        self._init_injections()
        axis = self.axis
        self._live_read: dict[tuple[int, int], Callable[[], Any]] = {
            (c.STATUSWORD, 0): lambda: axis.statusword,
            (c.CONTROLWORD, 0): lambda: axis.controlword,
            (c.MODES_OF_OPERATION, 0): lambda: axis.mode,
            (c.MODES_OF_OPERATION_DISPLAY, 0): lambda: axis.mode_display,
            (c.POSITION_ACTUAL, 0): lambda: axis.position_actual,
            (c.FOLLOWING_ERROR_ACTUAL, 0): lambda: axis.following_error,
            (c.TARGET_POSITION, 0): lambda: axis.target_position,
            (c.IP_DATA_RECORD, 1): lambda: axis.ip_setpoint,
            (c.ERROR_CODE, 0): lambda: axis.error_code,
            (c.ERROR_REGISTER, 0): lambda: axis.error_register,
            (c.PREDEFINED_ERROR_FIELD, 0): lambda: len(axis.error_history),
        }
        self._live_write: dict[tuple[int, int], Callable[[Any], None]] = {
            (c.CONTROLWORD, 0): axis.set_controlword,
            (c.MODES_OF_OPERATION, 0): self._set_mode,
            (c.TARGET_POSITION, 0): axis.set_target_position,
            (c.IP_DATA_RECORD, 1): axis.set_ip_setpoint,
        }

    # ------------------------------------------------------------------ public API
    @property
    def state(self) -> State:
        """The CiA-402 state."""
        return self.axis.state

    @property
    def statusword(self) -> int:
        return self.axis.statusword

    @property
    def controlword(self) -> int:
        return self.axis.controlword

    @property
    def position_actual(self) -> int:
        """0x6064, counts."""
        return self.axis.position_actual

    @property
    def following_error(self) -> int:
        """0x60F4, counts."""
        return self.axis.following_error

    @property
    def transitions(self) -> list[int]:
        """CiA-402 transition numbers taken since the last reset (starts with 0, 1)."""
        return self.axis.transitions

    @property
    def period_s(self) -> float:
        """The cycle the servo model assumes now: 0x60C2 in IP, 0x1006 in CSP."""
        return self.axis.params.period_s(self.axis.mode_display)

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
            for fault in self._deferred:
                self._apply_injection(fault)
            self._deferred.clear()

    def detach(self) -> None:
        """Leave the network (no more frames in or out)."""
        with self._lock:
            if self.network is None:
                return
            for can_id, callback in list(self._subscriptions):
                self._unsubscribe(can_id, callback)
            self._rpdo_by_cob.clear()
            self._consumed_cobs = []
            self._sync_cob = None
            self.node.remove_network()
            self.network = None

    def inject(self, fault: FaultInjection) -> None:
        """Inject ``fault`` at once, at its SYNC index, or ``at_s`` seconds after the drive
        was attached (an immediate fault injected before attach fires right after boot)."""
        with self._lock:
            self._fault_seq += 1
            if fault.at_sync is not None:
                bisect.insort(self._sync_faults, (fault.at_sync, self._fault_seq, fault))
            elif fault.at_s is not None:
                bisect.insort(self._time_faults, (fault.at_s, self._fault_seq, fault))
            elif self.network is None:
                self._deferred.append(fault)
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
        """Send a due heartbeat, fire due timed faults, watch consumed heartbeats; returns
        the time this should be called again."""
        with self._lock:
            if self.network is None:
                return now + TICK_MAX_S
            while self._time_faults and self._t0 + self._time_faults[0][0] <= now:
                self._apply_injection(self._time_faults.pop(0)[2])
            if self._heartbeat_period_s > 0 and not self.silent and now >= self._next_heartbeat:
                self._send_heartbeat()
                self._next_heartbeat += self._heartbeat_period_s
                if self._next_heartbeat <= now:  # fell behind: no burst of catch-up heartbeats
                    self._next_heartbeat = now + self._heartbeat_period_s
            for producer in self._heartbeat_consumer.newly_failed(now):
                if not self.silent:
                    log.warning(kv("sim.heartbeat_lost", node=self.node_id, producer=producer))
                    self.axis.raise_fault(EmcyCode.HEARTBEAT)
            deadline = min(now + TICK_MAX_S, self._heartbeat_consumer.next_deadline())
            if self._heartbeat_period_s > 0:
                deadline = min(deadline, self._next_heartbeat)
            if self._time_faults:
                deadline = min(deadline, self._t0 + self._time_faults[0][0])
            return deadline

    def value(self, index: int, subindex: int = 0) -> Any:
        """An object's current value, as an SDO upload would read it."""
        with self._lock:
            return self._od_value(index, subindex)

    def write_recording(self, path: str | Path) -> Path:
        """Write the applied set-points as CSV (see ``recording``)."""
        return self.recorder.write_csv(path)

    # ------------------------------------------------------------------ boot and NMT
    def _encode_parameters(self, parameters: dict[tuple[int, int], int]) -> dict[tuple[int, int], bytes]:
        encoded = {}
        for (index, subindex), value in parameters.items():
            var = pdo_layout.find_variable(self.od, index, subindex)
            if var is None:
                raise ValueError(f"node {self.node_id}: no object 0x{index:04X} sub {subindex} in {self.eds_path}")
            encoded[(index, subindex)] = var.encode_raw(value)
        return encoded

    def _stored_mode(self) -> int:
        var = self.od[c.MODES_OF_OPERATION]
        stored = self._stored.get((c.MODES_OF_OPERATION, 0))
        return int(var.decode_raw(stored)) if stored else int(var.default)

    def _init_injections(self) -> None:
        self._ignore_syncs: float = 0
        self._drop_rpdos = 0
        self._sdo_refusals: list[list[Any]] = []  # [index|None, subindex|None, code, remaining]
        self._time_faults: list[tuple[float, int, FaultInjection]] = []  # (at_s, order, fault)
        self._sync_faults: list[tuple[int, int, FaultInjection]] = []  # (at_sync, order, fault)
        self._deferred: list[FaultInjection] = []  # immediate, injected before attach

    def _boot(self, reset_application: bool) -> None:
        """Reset communication (and the application): stored values back, boot-up message,
        PRE-OPERATIONAL."""
        self.nmt_state = NmtState.BOOTUP
        store = self.node.data_store
        for index in list(store):
            if reset_application or 0x1000 <= index <= 0x1FFF:
                del store[index]
        for (index, subindex), data in self._stored.items():
            if reset_application or 0x1000 <= index <= 0x1FFF:
                store.setdefault(index, {})[subindex] = data
        if reset_application:
            self.axis.reset(self._stored_mode())
            self._sync_index = 0
        self._pending.clear()
        self._rebuild_all_pdos()
        self._configure_heartbeat_consumer()
        self._send(c.COB_HEARTBEAT + self.node_id, bytes([NmtState.BOOTUP]))
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._next_heartbeat = self._clock() + self._heartbeat_period_s
        log.info(kv("sim.boot", node=self.node_id, reset_application=reset_application))

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

    def _send_heartbeat(self) -> None:
        if self.nmt_state != NmtState.BOOTUP:
            self._send(c.COB_HEARTBEAT + self.node_id, bytes([self.nmt_state]))
            self.stats.heartbeats_sent += 1

    def _configure_heartbeat_consumer(self) -> None:
        """Watch the producers listed in 0x1016 (EMCY 0x8130 and fault when one goes silent)."""
        count = self._od_value(c.CONSUMER_HEARTBEAT_TIME, 0)
        self._heartbeat_consumer.configure([self._od_value(c.CONSUMER_HEARTBEAT_TIME, n) for n in range(1, count + 1)])
        for cob in self._consumed_cobs:
            self._unsubscribe(cob, self._on_peer_heartbeat)
        self._consumed_cobs = [c.COB_HEARTBEAT + n for n in self._heartbeat_consumer.timeouts_s]
        if self.network is not None:
            for cob in self._consumed_cobs:
                self._subscribe(cob, self._on_peer_heartbeat)

    def _on_peer_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            self._heartbeat_consumer.seen(can_id - c.COB_HEARTBEAT, self._clock())

    def _send(self, can_id: int, data: bytes) -> None:
        if self.network is not None and not self.silent:
            self.network.send_message(can_id, data)

    def _send_emcy(self, code: int, register: int) -> None:
        """EMCY (CiA 301): code, error register, 5 zero bytes; not in STOPPED or if disabled."""
        if self._emcy_cob & pdo_layout.COB_ID_INVALID_BIT or self.nmt_state == NmtState.STOPPED:
            return
        if self.silent or self.network is None:
            return
        self._send(self._emcy_cob & 0x7FF, EMCY_STRUCT.pack(code, register))
        self.stats.emcys_sent += 1

    def _subscribe(self, can_id: int, callback: Callable[..., None]) -> None:
        assert self.network is not None
        self.network.subscribe(can_id, callback)
        self._subscriptions.append((can_id, callback))

    def _unsubscribe(self, can_id: int, callback: Callable[..., None]) -> None:
        if (can_id, callback) in self._subscriptions:
            self._subscriptions.remove((can_id, callback))
            assert self.network is not None
            self.network.unsubscribe(can_id, callback)

    # ------------------------------------------------------------------ parameters
    def _od_value(self, index: int, subindex: int = 0) -> Any:
        var = pdo_layout.find_variable(self.od, index, subindex)
        assert var is not None, (hex(index), subindex)
        return var.decode_raw(self.node.get_data(index, subindex))

    def _load_parameters(self) -> None:
        """Cache the parameters SYNC handling uses (after boot and every SDO write)."""
        params = self.axis.params
        value, exponent = self._od_value(c.IP_TIME_PERIOD, 1), self._od_value(c.IP_TIME_PERIOD, 2)
        ip_period_s = value * 10.0**exponent
        params.ip_period_s = ip_period_s if ip_period_s > 0 else DEFAULT_PERIOD_S
        params.sync_period_s = self._od_value(c.COMM_CYCLE_PERIOD) * 1e-6
        params.fe_window_counts = self._od_value(c.FOLLOWING_ERROR_WINDOW)
        params.fe_timeout_ms = self._od_value(c.FOLLOWING_ERROR_TIMEOUT)
        params.quick_stop_option = self._od_value(c.QUICK_STOP_OPTION)
        params.quick_stop_decel_counts_s2 = float(self._od_value(c.QUICK_STOP_DECELERATION))
        params.limit_min_counts = self._od_value(c.SOFTWARE_POSITION_LIMIT, 1)
        params.limit_max_counts = self._od_value(c.SOFTWARE_POSITION_LIMIT, 2)
        self._emcy_cob = self._od_value(c.EMCY_COB_ID)
        self._heartbeat_period_s = self._od_value(c.PRODUCER_HEARTBEAT_TIME) / 1000.0
        sync_cob = self._od_value(c.SYNC_COB_ID) & 0x7FF
        if sync_cob != self._sync_cob and self.network is not None:
            if self._sync_cob is not None:
                self._unsubscribe(self._sync_cob, self._on_sync)
            self._subscribe(sync_cob, self._on_sync)
            self._sync_cob = sync_cob

    def _set_mode(self, mode: int) -> None:
        try:
            self.axis.set_mode(mode)
        except UnsupportedMode:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID) from None

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
            history = self.axis.error_history
            return history[subindex - 1] if subindex <= len(history) else 0
        return None

    def _before_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Validate an SDO write (raise SdoAbortedError to refuse) and apply live objects."""
        self._check_refusal(index, subindex)
        value = od.decode_raw(data)
        pdo_layout.check_parameter_write(self.od, self._od_value, index, subindex, value)
        if index == c.PREDEFINED_ERROR_FIELD:
            if subindex != 0 or value != 0:
                raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
            self.axis.error_history.clear()
        elif index in (c.SYNC_COB_ID, c.EMCY_COB_ID) and value & pdo_layout.COB_ID_EXTENDED_BIT:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)
        elif index == c.IP_SUB_MODE and value != IP_LINEAR:
            raise SdoAbortedError(pdo_layout.ABORT_VALUE_INVALID)  # only linear interpolation
        setter = self._live_write.get((index, subindex))
        if setter is not None:
            setter(value)

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        log.debug(kv("sim.sdo_write", node=self.node_id, object=f"0x{index:04X}:{subindex:02X}"))
        if pdo_layout.is_pdo_parameter(index):
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

    # ------------------------------------------------------------------ PDO layouts
    def _mapping(self, map_index: int) -> list[int]:
        count = self._od_value(map_index, 0)
        return [self._od_value(map_index, n) for n in range(1, count + 1)]

    def _layout(self, comm_index: int, map_index: int, number: int) -> pdo_layout.PdoLayout:
        return pdo_layout.build_layout(
            self.od, number, self._od_value(comm_index, 1), self._od_value(comm_index, 2), self._mapping(map_index)
        )

    def _rebuild_all_pdos(self) -> None:
        """Recompute every PDO's struct, setters/getters and subscription (after a remap)."""
        for cob_id in list(self._rpdo_by_cob):
            self._unsubscribe(cob_id, self._on_rpdo)
        self._rpdo_by_cob.clear()
        self._tpdos = []
        for n in range(1, 5):
            layout = self._layout(0x1400 + n - 1, 0x1600 + n - 1, n)
            if layout.enabled and layout.keys:
                if layout.cob_id not in self._rpdo_by_cob and self.network is not None:
                    self._subscribe(layout.cob_id, self._on_rpdo)
                self._rpdo_by_cob[layout.cob_id] = _RpdoSlot(layout, [self._setter(key) for key in layout.keys])
            layout = self._layout(0x1800 + n - 1, 0x1A00 + n - 1, n)
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
                self._send_emcy(EmcyCode.PDO_LENGTH, self.axis.error_register)
                return
            values = slot.layout.codec.unpack_from(data)
            if slot.layout.synchronous:
                if slot.layout.number in self._pending:
                    self.stats.rpdos_overwritten += 1
                self._pending[slot.layout.number] = (slot.setters, values)
            else:
                self._apply_values(slot.setters, values)

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
        self.axis.step(self._sync_index, sync_counter)
        self._send_tpdos()

    def _send_tpdos(self) -> None:
        """TPDOs of this SYNC: type 1..240 every n-th SYNC; 0, 254, 255 when the data
        changed; 241..253 never."""
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
                continue
            data = slot.message.data
            slot.layout.codec.pack_into(data, 0, *[getter() for getter in slot.getters])
            if kind == 0 or kind >= 254:
                if data == slot.last_data:
                    continue
                slot.last_data = bytes(data)
            with network.send_lock:
                network.bus.send(slot.message)
            self.stats.tpdos_sent += 1

    # ------------------------------------------------------------------ fault injection
    def _apply_injection(self, fault: FaultInjection) -> None:
        log.warning(kv("sim.inject", node=self.node_id, kind=fault.kind, sync=self._sync_index))
        kind = fault.kind
        if kind == "fault":
            self.axis.raise_fault(fault.code if fault.code is not None else DEFAULT_FAULT_CODE)
        elif kind in ("heartbeat_stop", "power_loss"):
            self.silent = True
        elif kind == "ignore_sync":
            self._ignore_syncs = fault.count if fault.count is not None else _FOREVER
        elif kind == "following_error":
            self.axis.raise_fault(EmcyCode.FOLLOWING_ERROR, following_error=True)
        elif kind == "stall":
            self.servo.stalled = True
        elif kind == "drop_rpdo":
            self._drop_rpdos += fault.count if fault.count is not None else 1
        elif kind == "sdo_abort":
            code = fault.code if fault.code is not None else DEFAULT_SDO_ABORT_CODE
            remaining = fault.count if fault.count is not None else _FOREVER
            self._sdo_refusals.append([fault.index, fault.subindex, code, remaining])
