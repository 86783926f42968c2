"""One simulated CiA-402 servo drive on a canopen Network: the bus side of the drive.

canopen's ``LocalNode`` provides the object dictionary (from the EDS) and the SDO server.
This module adds what a real drive does and ``LocalNode`` does not (reference, section 4):
its own NMT slave (boot-up, heartbeat, PDOs only in OPERATIONAL, SDO silent in STOPPED),
RPDO data written into the drive at the next SYNC (CiA 301), TPDOs on SYNC per the mapping
and transmission type the master wrote, EMCY, the heartbeat consumer and fault injection.
The CiA-402 application itself (state machine, set-points, servo) is ``axis.Cia402Axis``;
the object dictionary and the SDO server's checks are ``drive_objects``, the PDOs
``drive_pdos``, the pieces every simulated node shares ``slave``.

All handlers run in the network's receive thread (SYNC, RPDO, SDO, NMT) or in the
network's ticker thread (heartbeat, timed faults); one lock per drive serialises them.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import canopen
from canopen.sdo import SdoAbortedError

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.arrival_clock import ArrivalClock, socket_pending
from nurbsmotion.can.cia402 import EmcyCode, NmtCommand, NmtState, State
from nurbsmotion.log import kv
from nurbsmotion.sim import axis as axis_module
from nurbsmotion.sim import eds as eds_rules
from nurbsmotion.sim import homing, velocity
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.axis import EMCY_SYNC_LOSS, Cia402Axis
from nurbsmotion.sim.drive_objects import SYNC_COUNTER_OVERFLOW, DriveObjects
from nurbsmotion.sim.drive_pdos import DrivePdos
from nurbsmotion.sim.eds import default_eds_path, find_variable
from nurbsmotion.sim.faults import DEFAULT_FAULT_CODE, DEFAULT_SDO_ABORT_CODE, FaultInjection
from nurbsmotion.sim.heartbeat import HeartbeatConsumer
from nurbsmotion.sim.recording import SetpointRecorder, SyncRecorder
from nurbsmotion.sim.rpdo_timers import RpdoTimers
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.slave import EMCY_STRUCT, Subscriptions, addressed_command
from nurbsmotion.sim.stats import DriveStats
from nurbsmotion.sim.timing import SyncMonitor, SyncSettings

log = logging.getLogger(__name__)

SYNC_WINDOW_LENGTH = 0x1007  # µs after SYNC in which synchronous RPDOs count (0 = no window)
EMCY_SYNC_LENGTH = 0x8240  # CiA 301: unexpected SYNC data length
EMCY_RPDO_TIMEOUT = 0x8250  # CiA 301: RPDO time-out
TICK_MAX_S = 0.05  # the ticker looks at a drive at least this often
FE_WINDOW_DISABLED = 0xFFFF_FFFF  # no 0x6065: no following-error monitor
DEFAULT_QUICK_STOP_OPTION = 2  # no 0x605A: CiA 402 default (quick-stop ramp, then disabled)
DEFAULT_QUICK_STOP_DECEL = math.inf  # no 0x6085: the drive stops at once
_FOREVER = math.inf
NMT_STATES = {NmtCommand.START: NmtState.OPERATIONAL, NmtCommand.STOP: NmtState.STOPPED,
              NmtCommand.PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL}  # the NMT commands that change state


class SimDrive:
    """A simulated CiA-402 servo drive with node id ``node_id``, described by ``eds`` (any
    vendor EDS/DCF; default the packaged one) and exactly as capable as that description.

    Create it, then :meth:`attach` it to a connected ``canopen.Network`` (``SimNetwork`` does
    both). ``lag_cycles`` and ``max_velocity_counts_s`` set the servo model; ``identity``
    (vendor id, product code) overrides 0x1018 sub 1/2; ``parameters`` {(index, subindex):
    value} are the drive's stored values, restored instead of the EDS defaults on every reset;
    ``record`` keeps every applied set-point in ``recorder`` and every SYNC in ``timeline``.
    ``sync`` (:class:`SyncSettings`) sets hold/extrapolate and the sync-loss fault.
    ``clock`` (seconds, monotonic) is the drive's time: without one the drive uses the
    frames' receive timestamps (kernel timestamps on SocketCAN) and ``time.monotonic``; with
    one, every event is stamped by calling it, so a test decides exactly when a SYNC came.
    ``home_sensors`` (:class:`sim.homing.HomeSensors`, raw counts at power-on) are the limit
    switches and index pulses homing mode (6) finds; mode 6 exists if
    0x6502 allows it; a homing object the EDS lacks reads 0 (no speed: the homing never ends).
    ``home_object`` (index, sign): a vendor object (sub-index 0) whose value times sign the
    home reads instead of -0x607C, as the drive's manual says (maxon EPOS4 0x30B0: +1); an
    EDS says nothing of what a vendor object does.
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
        sync: SyncSettings | None = None,
        clock: Callable[[], float] | None = None,
        home_sensors: homing.HomeSensors | None = None,
        home_object: tuple[int, int] | None = None,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} outside 1..127")
        self.node_id = node_id
        self.name = name or f"node{node_id}"
        self.eds_path = Path(eds) if eds else default_eds_path()
        self.objects = DriveObjects(node_id, self.eds_path, parameters or {}, identity)
        self.od = self.objects.od
        self.node = self.objects.node
        self.servo = ServoModel(lag_cycles, max_velocity_counts_s)
        self.recorder = SetpointRecorder(enabled=record)
        self.timeline = SyncRecorder(enabled=record)
        self.stats = DriveStats()
        self.axis = Cia402Axis(self.servo, self.recorder, self.stats, self._send_emcy, self.name, self.objects.stored_mode(),
                               self.timeline)
        self.axis.params.missing_setpoint = (sync or SyncSettings()).missing_setpoint
        self.axis.home_sensors = home_sensors or homing.HomeSensors()
        # a velocity mode runs only with its objects in the EDS (0x6502 alone is not enough)
        self._velocity_modes_missing = frozenset(
            mode for mode, objects in velocity.REQUIRED_OBJECTS.items()
            if any(find_variable(self.od, index, 0) is None for index in objects))
        self.axis.homing_setup = lambda: homing.setup_from_objects(lambda index, sub: self.objects.value_or(index, sub, 0),
                                                                   home_object)
        self.network: canopen.Network | None = None
        self.nmt_state = NmtState.BOOTUP
        self.silent = False  # power loss: nothing in, nothing out
        self._clock = clock if clock is not None else time.monotonic
        self._heartbeat_rx_lag_s: dict[int, float] = {}  # producer -> reception lag of its last heartbeat
        self._frame_times = clock is None  # stamp SYNC/RPDO/heartbeats with the frames' receive time
        # the monitors (0x1016, SYNC loss, RPDO timers) judge on the frames' arrival timeline
        self._arrival = ArrivalClock(lambda: False)
        self._wall_to_clock_s = time.monotonic() - time.time()
        self._t0 = self._clock()
        self._sync_monitor = SyncMonitor(sync or SyncSettings())
        self._rpdo_timers = RpdoTimers()
        self._sync_window_s = 0.0
        self._sync_counter_overflow: int | None = None  # None: the EDS has no 0x1019
        self._last_sync_counter: int | None = None
        self._period_source = eds_rules.cycle_period_source(self.od)
        self._lock = threading.RLock()
        self._subscriptions = Subscriptions()
        self._sync_cob: int | None = None
        self._sync_index = 0
        self._fault_seq = 0
        self._heartbeat_consumer = HeartbeatConsumer()
        self._consumed_cobs: list[int] = []
        self._heartbeat_period_s = 0.0
        self._next_heartbeat = 0.0
        self._emcy_cob = pdo_layout.COB_ID_INVALID_BIT
        self._init_injections()
        self.objects.serve(self.axis)
        self.objects.refusal = self._check_refusal
        self.objects.written = self._after_sdo_write
        self.pdos = DrivePdos(self.objects, self._subscriptions, self.stats, self._rpdo_timers, self._on_rpdo,
                              self._load_parameters)

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
        """The drive's IP/CSP cycle: 0x60C2 if the EDS has it, else 0x1006, else the measured
        SYNC interval; 0 when not configured (then IP/CSP cannot be enabled)."""
        return self.axis.params.cycle_period_s

    @property
    def sync_settings(self) -> SyncSettings:
        return self._sync_monitor.settings

    @property
    def sync_locked(self) -> bool:
        """Statusword bit 8: the drive's cycle is locked onto SYNC."""
        return self.axis.sync_locked

    def now(self) -> float:
        """The drive's clock (s)."""
        return self._clock()

    @property
    def sync_index(self) -> int:
        """SYNCs received since the drive last entered NMT OPERATIONAL (first SYNC = 1)."""
        return self._sync_index

    def attach(self, network: canopen.Network) -> None:
        """Join a connected network and boot (boot-up message, then PRE-OPERATIONAL)."""
        with self._lock:
            if self.network is not None:
                raise RuntimeError(f"{self.name} is already attached")
            self.network = self._subscriptions.network = network
            self._arrival = ArrivalClock(socket_pending(network.bus) if self._frame_times else lambda: False)
            self.node.associate_network(network)
            self._subscriptions.add(c.COB_NMT, self._on_nmt)
            self._subscriptions.add(self.node.sdo.rx_cobid, self._on_sdo_request)
            self._t0 = self._clock()
            self._wall_to_clock_s = time.monotonic() - time.time()
            self._boot(reset_application=True)
            for fault in self._deferred:
                self._apply_injection(fault)
            self._deferred.clear()

    def detach(self) -> None:
        """Leave the network (no more frames in or out)."""
        with self._lock:
            if self.network is None:
                return
            self._subscriptions.clear()
            self.pdos.forget()
            self._consumed_cobs = []
            self._sync_cob = None
            self.node.remove_network()
            self.network = self._subscriptions.network = None

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

    def tick(self, now: float | None = None) -> float:
        """Send a due heartbeat, fire due timed faults, watch consumed heartbeats, SYNC and
        RPDO deadlines; returns the time (drive clock) this should be called again."""
        with self._lock:
            if now is None:
                now = self._clock()
            if self.network is None:
                return now + TICK_MAX_S
            while self._time_faults and self._t0 + self._time_faults[0][0] <= now:
                self._apply_injection(self._time_faults.pop(0)[2])
            if self._heartbeat_period_s > 0 and not self.silent and now >= self._next_heartbeat:
                self._send_heartbeat()
                self._next_heartbeat += self._heartbeat_period_s
                if self._next_heartbeat <= now:  # fell behind: no burst of catch-up heartbeats
                    self._next_heartbeat = now + self._heartbeat_period_s
            # while frames wait, the receive thread judges at each SYNC it handles (_handle_sync):
            # polling here then would only take the guest's CPU from that thread (docs/vcan.md)
            deadline = min(now + TICK_MAX_S, self._judge_timeouts(now))
            if self._heartbeat_period_s > 0:
                deadline = min(deadline, self._next_heartbeat)
            if self._time_faults:
                deadline = min(deadline, self._t0 + self._time_faults[0][0])
            return deadline

    def _judge_timeouts(self, now: float) -> float:
        """Heartbeat consumer, SYNC loss and RPDO timers at ``now`` seen through the reception
        lag (nurbsmotion.can.arrival_clock); returns when (drive clock) the next of them falls due."""
        arrival_now = self._arrival.judging_time(now)
        self._judge_at(arrival_now)
        due = min(self._heartbeat_consumer.next_deadline(), self._sync_monitor.loss_deadline(self.period_s),
                  self._rpdo_timers.next_deadline())
        return due + max(0.0, now - arrival_now)

    def _judge_at(self, arrival_now: float) -> None:
        """Heartbeat consumer, SYNC loss and RPDO timers at ``arrival_now`` on the arrival
        timeline: from the ticker (judging_time) and from the receive thread at each SYNC's
        arrival, before the SYNC counts (a gap before it is judged as a firmware judges it)."""
        for producer in self._heartbeat_consumer.newly_failed(arrival_now):
            if not self.silent:
                # judged_at_s: the arrival-timeline time of the judgement, as wall-clock time
                log.warning(kv("sim.heartbeat_lost", node=self.node_id, producer=producer,
                               rx_lag_s=round(self._heartbeat_rx_lag_s.get(producer, 0.0), 3),
                               judged_at_s=f"{arrival_now - self._wall_to_clock_s:.3f}"))
                self.axis.raise_fault(EmcyCode.HEARTBEAT)
        self._watch_sync_and_rpdos(arrival_now)

    def _watch_sync_and_rpdos(self, now: float) -> None:
        """Sync loss (no SYNC for loss_periods, while IP/CSP is running: EMCY 0x8700, fault)
        and RPDO event timers (0x14xx:05 ran out: EMCY 0x8250, fault)."""
        if self.silent or self.nmt_state != NmtState.OPERATIONAL:
            return
        if self._sync_monitor.lost(now, self.period_s):
            self.axis.sync_locked = False
            if self.axis.setpoint_active():
                self.stats.sync_losses += 1
                log.warning(kv("sim.sync_lost", node=self.node_id, periods=self.sync_settings.loss_periods))
                self.axis.raise_fault(EMCY_SYNC_LOSS)
            else:
                self.axis.refresh_statusword()
        for number in self._rpdo_timers.expired(now):
            self.stats.rpdo_timeouts += 1
            log.warning(kv("sim.rpdo_timeout", node=self.node_id, rpdo=number))
            self.axis.raise_fault(EMCY_RPDO_TIMEOUT)

    def value(self, index: int, subindex: int = 0) -> Any:
        """An object's current value, as an SDO upload would read it."""
        with self._lock:
            return self.objects.value(index, subindex)

    def write_recording(self, path: str | Path) -> Path:
        """Write the applied set-points as CSV (see ``recording``)."""
        return self.recorder.write_csv(path)

    def write_timeline(self, path: str | Path) -> Path:
        """Write the per-SYNC timeline as CSV (see ``recording``)."""
        return self.timeline.write_csv(path)

    # ------------------------------------------------------------------ boot and NMT
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
        self.objects.reset(reset_application)
        if reset_application:
            self.axis.reset(self.objects.stored_mode())
            self._sync_index = 0
        self._rebuild_pdos()
        self._configure_heartbeat_consumer()
        self._send(c.COB_HEARTBEAT + self.node_id, bytes([NmtState.BOOTUP]))
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._next_heartbeat = self._clock() + self._heartbeat_period_s
        log.info(kv("sim.boot", node=self.node_id, reset_application=reset_application))

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        command = addressed_command(data, self.node_id)
        if command is None:
            return
        with self._lock:
            if self.silent:
                return
            if command in NMT_STATES:
                self._enter_nmt(NMT_STATES[command])
            elif command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
                self._boot(reset_application=command == NmtCommand.RESET_NODE)

    def _enter_nmt(self, new: NmtState) -> None:
        if new == self.nmt_state:
            return
        if new == NmtState.OPERATIONAL:
            self._sync_index = 0
            self.pdos.restart()
            self._sync_monitor.reset()
            self._rpdo_timers.reset()
            self._last_sync_counter = None
        log.info(kv("sim.nmt", node=self.node_id, state=new.name, previous=self.nmt_state.name))
        self.nmt_state = new

    def _send_heartbeat(self) -> None:
        if self.nmt_state != NmtState.BOOTUP:
            self._send(c.COB_HEARTBEAT + self.node_id, bytes([self.nmt_state]))
            self.stats.heartbeats_sent += 1

    def _configure_heartbeat_consumer(self) -> None:
        """Watch the producers listed in 0x1016 (EMCY 0x8130 and fault when one goes silent)."""
        self._heartbeat_consumer.configure(self.objects.consumer_entries())
        for cob in self._consumed_cobs:
            self._subscriptions.remove(cob, self._on_peer_heartbeat)
        self._consumed_cobs = [c.COB_HEARTBEAT + n for n in self._heartbeat_consumer.timeouts_s]
        if self.network is not None:
            for cob in self._consumed_cobs:
                self._subscriptions.add(cob, self._on_peer_heartbeat)

    def _on_peer_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            producer = can_id - c.COB_HEARTBEAT
            self._heartbeat_consumer.seen(producer, self._frame_time(timestamp))
            # how late this process handles the frame after the kernel received it (SocketCAN
            # stamps frames with wall-clock time; a process inside a starved guest lags by seconds)
            self._heartbeat_rx_lag_s[producer] = time.time() - timestamp if timestamp > 1e9 else 0.0

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

    # ------------------------------------------------------------------ parameters
    def _frame_time(self, timestamp: float) -> float:
        """When a frame arrived, on the drive's clock: its receive timestamp (wall clock,
        kernel time on SocketCAN) unless a clock was injected."""
        if self._frame_times and timestamp > 0:
            return self._arrival.arrived(timestamp + self._wall_to_clock_s, self._clock())
        return self._clock()

    def _cycle_period_s(self) -> float:
        """0x60C2 (value·10^exponent s) if the EDS has it, else 0x1006 (µs), else the
        measured SYNC interval (a drive that can only lock onto SYNC)."""
        if self._period_source == c.IP_TIME_PERIOD:
            value = self.objects.value(c.IP_TIME_PERIOD, 1)
            exponent = self.objects.value_or(c.IP_TIME_PERIOD, 2, -3)
            return max(value * 10.0**exponent, 0.0)
        if self._period_source == c.COMM_CYCLE_PERIOD:
            return self.objects.value(c.COMM_CYCLE_PERIOD) * 1e-6
        return self._sync_monitor.measured_period_s

    def _load_parameters(self) -> None:
        """Cache the parameters SYNC handling uses (after boot and every SDO write)."""
        params = self.axis.params
        value = self.objects.value_or
        params.cycle_period_s = self._cycle_period_s()
        params.fe_window_counts = value(c.FOLLOWING_ERROR_WINDOW, 0, FE_WINDOW_DISABLED)
        params.fe_timeout_ms = value(c.FOLLOWING_ERROR_TIMEOUT, 0, 0)
        params.quick_stop_option = value(c.QUICK_STOP_OPTION, 0, DEFAULT_QUICK_STOP_OPTION)
        params.quick_stop_decel_counts_s2 = float(value(c.QUICK_STOP_DECELERATION, 0, DEFAULT_QUICK_STOP_DECEL))
        params.limit_min_counts = value(c.SOFTWARE_POSITION_LIMIT, 1, 0)
        params.limit_max_counts = value(c.SOFTWARE_POSITION_LIMIT, 2, 0)
        params.modes = eds_rules.supported_modes(value(c.SUPPORTED_DRIVE_MODES, 0, 0),
                                                 find_variable(self.od, c.MODES_OF_OPERATION, 0)) - self._velocity_modes_missing
        params.velocity_profile = velocity.VelocityProfile(
            float(value(velocity.PROFILE_ACCELERATION, 0, 0)),
            float(value(velocity.PROFILE_DECELERATION, 0, value(velocity.PROFILE_ACCELERATION, 0, 0))),
            float(value(velocity.VELOCITY_WINDOW, 0, 0)), float(value(velocity.VELOCITY_WINDOW_TIME, 0, 0)))
        self._sync_window_s = value(SYNC_WINDOW_LENGTH, 0, 0) * 1e-6
        self._sync_counter_overflow = value(SYNC_COUNTER_OVERFLOW, 0, None)
        self._emcy_cob = value(c.EMCY_COB_ID, 0, pdo_layout.COB_ID_INVALID_BIT)
        self._heartbeat_period_s = value(c.PRODUCER_HEARTBEAT_TIME, 0, 0) / 1000.0
        sync_cob = value(c.SYNC_COB_ID, 0, c.COB_SYNC) & 0x7FF
        if sync_cob != self._sync_cob and self.network is not None:
            if self._sync_cob is not None:
                self._subscriptions.remove(self._sync_cob, self._on_sync)
            self._subscriptions.add(sync_cob, self._on_sync)
            self._sync_cob = sync_cob

    def _homing_period_s(self) -> float:
        """The drive's own cycle in homing mode: 0x1006, else the measured SYNC interval,
        else 1 ms."""
        period_us = self.objects.value_or(c.COMM_CYCLE_PERIOD, 0, 0)
        if period_us > 0:
            return period_us * 1e-6
        measured = self._sync_monitor.measured_period_s
        return measured if measured > 0 else axis_module.DEFAULT_CYCLE_S

    # ------------------------------------------------------------------ SDO server
    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self.silent or self.nmt_state in (NmtState.STOPPED, NmtState.BOOTUP):
                return
            self.node.sdo.on_request(can_id, data, timestamp)

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        log.debug(kv("sim.sdo_write", node=self.node_id, object=f"0x{index:04X}:{subindex:02X}"))
        if pdo_layout.is_pdo_parameter(index):
            self._rebuild_pdos()
        elif index == c.CONSUMER_HEARTBEAT_TIME:
            self._configure_heartbeat_consumer()
        else:
            self._load_parameters()
            self.axis.refuse_cyclic_without_period()

    def _check_refusal(self, index: int, subindex: int) -> None:
        for refusal in self._sdo_refusals:
            want_index, want_sub, code, remaining = refusal
            if (want_index is None or want_index == index) and (want_sub is None or want_sub == subindex):
                refusal[3] = remaining - 1
                if refusal[3] <= 0:
                    self._sdo_refusals.remove(refusal)
                raise SdoAbortedError(code)

    # ------------------------------------------------------------------ PDOs (sim.drive_pdos)
    def _rebuild_pdos(self) -> None:
        """Every PDO from its objects again (after boot or a remap), then the parameters."""
        self.pdos.rebuild(self.network is not None)
        self._load_parameters()

    # ------------------------------------------------------------------ PDO traffic
    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if self.silent or self.nmt_state != NmtState.OPERATIONAL:
                return
            slot = self.pdos.rpdo_by_cob.get(can_id)
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
            now = self._frame_time(timestamp)
            if slot.layout.synchronous and self._outside_sync_window(now):
                self.stats.rpdos_outside_window += 1
                return
            self._rpdo_timers.received(slot.layout.number, now)
            self.pdos.receive(slot, data)

    def _outside_sync_window(self, now: float) -> bool:
        """CiA 301 0x1007: a synchronous RPDO later than the window after SYNC is discarded."""
        last_sync = self._sync_monitor.last_sync_s
        return self._sync_window_s > 0 and last_sync is not None and now - last_sync > self._sync_window_s

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        """CiA 301 SYNC: apply RPDO data received since the last SYNC, move, send TPDOs."""
        with self._lock:
            if self.silent or self.nmt_state != NmtState.OPERATIONAL:
                return
            try:
                self._handle_sync(data, self._frame_time(timestamp))
            finally:
                self.stats.syncs += 1  # counted once the SYNC's TPDOs are out

    def _handle_sync(self, data: bytes, now: float) -> None:
        if self._frame_times:  # ``now`` is this SYNC's arrival: the bus is known up to here
            self._judge_at(now)
        self._sync_index += 1
        while self._sync_faults and self._sync_faults[0][0] <= self._sync_index:
            self._apply_injection(self._sync_faults.pop(0)[2])
            if self.silent:
                return
        if self._ignore_syncs > 0:
            self._ignore_syncs -= 1
            self.stats.syncs_ignored += 1
            return
        sync_counter = self._check_sync_counter(data)
        timing = self._sync_monitor.on_sync(now, self.period_s)
        if self._period_source is None:
            self._load_parameters()  # the cycle is the measured SYNC interval
        if timing.missed_ticks:
            self.stats.syncs_late += 1
            self.stats.ticks_missed += timing.missed_ticks
        self.axis.sync_locked = self._sync_monitor.locked
        if self.axis.mode_display == homing.MODE_HOMING:
            self.axis.params.homing_period_s = self._homing_period_s()
        self.axis.run_missed_cycles(timing)  # they ran before this SYNC: with the old RPDO data
        self.pdos.apply_pending()
        self.axis.step(self._sync_index, sync_counter, timing)
        if self.network is not None:
            self.pdos.send_tpdos(self.network)

    def _check_sync_counter(self, data: bytes) -> int:
        """The SYNC counter byte (-1 without). With 0x1019 in the EDS the length must fit it
        (0: no data, else 1 byte; EMCY 0x8240 otherwise) and the counter must run 1..0x1019
        without a jump (a jump means a SYNC was lost on the way)."""
        counter = data[0] if data else -1
        overflow = self._sync_counter_overflow
        if overflow is None:
            return counter
        if len(data) != (1 if overflow > 0 else 0):
            self.stats.sync_length_errors += 1
            self._send_emcy(EMCY_SYNC_LENGTH, self.axis.error_register)
            return counter
        if overflow > 0:
            last, self._last_sync_counter = self._last_sync_counter, counter
            if last is not None and counter != last % overflow + 1:
                self.stats.sync_counter_jumps += 1
                log.warning(kv("sim.sync_counter_jump", node=self.node_id, previous=last, counter=counter))
        return counter

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
