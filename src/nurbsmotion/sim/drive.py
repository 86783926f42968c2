"""One simulated CiA-402 servo drive on a canopen Network: the bus side of the drive.

canopen's ``LocalNode`` provides the object dictionary (from the EDS) and the SDO server.
This module adds what a real drive does and ``LocalNode`` does not (reference, section 4):
its own NMT slave (boot-up, heartbeat, PDOs only in OPERATIONAL, SDO silent in STOPPED),
RPDO data written into the drive at the next SYNC (CiA 301), TPDOs on SYNC per the mapping
and transmission type the master wrote, EMCY, the heartbeat consumer and fault injection.
The CiA-402 application itself (state machine, set-points, servo) is ``axis.Cia402Axis``;
the object dictionary and the SDO server's checks are ``drive_objects``, the PDOs
``drive_pdos``, SYNC and RPDO handling with the time-outs ``drive_cycle``, fault injection
``drive_injections``, the pieces every simulated node shares ``slave``.

All handlers run in the network's receive thread (SYNC, RPDO, SDO, NMT) or in the
network's ticker thread (heartbeat, timed faults); one lock per drive serialises them.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import canopen

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import NmtCommand, NmtState, State
from nurbsmotion.log import kv
from nurbsmotion.sim import homing
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.axis import Cia402Axis
from nurbsmotion.sim.drive_cycle import DriveCycle
from nurbsmotion.sim.drive_injections import Injections
from nurbsmotion.sim.drive_objects import DriveObjects
from nurbsmotion.sim.drive_pdos import DrivePdos
from nurbsmotion.sim.eds import default_eds_path
from nurbsmotion.sim.faults import FaultInjection
from nurbsmotion.sim.recording import SetpointRecorder, SyncRecorder
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.slave import EMCY_STRUCT, ConsumedHeartbeats, Subscriptions, addressed_command
from nurbsmotion.sim.stats import DriveStats
from nurbsmotion.sim.timing import SyncSettings

log = logging.getLogger(__name__)

TICK_MAX_S = 0.05  # the ticker looks at a drive at least this often
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
        self.axis = Cia402Axis(self.servo, self.recorder, self.stats, self.send_emcy, self.name, self.objects.stored_mode(),
                               self.timeline)
        self.sync_settings = sync or SyncSettings()
        self.axis.params.missing_setpoint = self.sync_settings.missing_setpoint
        self.axis.home_sensors = home_sensors or homing.HomeSensors()
        self.axis.homing_setup = lambda: homing.setup_from_objects(lambda index, sub: self.objects.value_or(index, sub, 0),
                                                                   home_object)
        self.network: canopen.Network | None = None
        self.nmt_state = NmtState.BOOTUP
        self.silent = False  # power loss: nothing in, nothing out
        self._clock = clock if clock is not None else time.monotonic
        self.lock = threading.RLock()
        self.subscriptions = Subscriptions()
        self.cycle = DriveCycle(self, self.sync_settings, self._clock, frame_times=clock is None)
        self.heartbeats = ConsumedHeartbeats(self.subscriptions, self.lock, self.cycle.frame_time)
        self.injections = Injections(node_id, self.axis, self.servo, silence=lambda: setattr(self, "silent", True))
        self._next_heartbeat = 0.0
        self.objects.serve(self.axis)
        self.objects.refusal = self.injections.check_refusal
        self.objects.written = self._after_sdo_write
        self.pdos = DrivePdos(self.objects, self.subscriptions, self.stats, self.cycle.rpdo_timers, self.cycle.on_rpdo,
                              self.cycle.load_parameters)

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
    def sync_locked(self) -> bool:
        """Statusword bit 8: the drive's cycle is locked onto SYNC."""
        return self.axis.sync_locked

    def now(self) -> float:
        """The drive's clock (s)."""
        return self._clock()

    @property
    def sync_index(self) -> int:
        """SYNCs received since the drive last entered NMT OPERATIONAL (first SYNC = 1)."""
        return self.cycle.sync_index

    def attach(self, network: canopen.Network) -> None:
        """Join a connected network and boot (boot-up message, then PRE-OPERATIONAL)."""
        with self.lock:
            if self.network is not None:
                raise RuntimeError(f"{self.name} is already attached")
            self.network = self.subscriptions.network = network
            self.cycle.attach(network)
            self.node.associate_network(network)
            self.subscriptions.add(c.COB_NMT, self._on_nmt)
            self.subscriptions.add(self.node.sdo.rx_cobid, self._on_sdo_request)
            self._boot(reset_application=True)
            for fault in self.injections.deferred:
                self.injections.apply(fault, self.sync_index)
            self.injections.deferred.clear()

    def detach(self) -> None:
        """Leave the network (no more frames in or out)."""
        with self.lock:
            if self.network is None:
                return
            self.subscriptions.clear()
            self.pdos.forget()
            self.heartbeats.forget()
            self.cycle.forget()
            self.node.remove_network()
            self.network = self.subscriptions.network = None

    def inject(self, fault: FaultInjection) -> None:
        """Inject ``fault`` at once, at its SYNC index, or ``at_s`` seconds after the drive
        was attached (an immediate fault injected before attach fires right after boot)."""
        with self.lock:
            if self.injections.schedule(fault):
                return
            if self.network is None:
                self.injections.deferred.append(fault)
            else:
                self.injections.apply(fault, self.sync_index)

    def clear_injections(self) -> None:
        """Cancel pending and active injections (ignore SYNC, drops, SDO refusals, stall)."""
        with self.lock:
            self.injections.clear()
            self.servo.stalled = False

    def power_on(self) -> None:
        """Power back on after a power loss: boots like a reset node (position is kept)."""
        with self.lock:
            self.silent = False
            self._boot(reset_application=True)

    def tick(self, now: float | None = None) -> float:
        """Send a due heartbeat, fire due timed faults, watch consumed heartbeats, SYNC and
        RPDO deadlines; returns the time (drive clock) this should be called again."""
        with self.lock:
            if now is None:
                now = self._clock()
            if self.network is None:
                return now + TICK_MAX_S
            for fault in self.injections.due_by_time(now, self.cycle.t0):
                self.injections.apply(fault, self.sync_index)
            period_s = self.cycle.heartbeat_period_s
            if period_s > 0 and not self.silent and now >= self._next_heartbeat:
                if self.nmt_state != NmtState.BOOTUP:
                    self.network.send_message(c.COB_HEARTBEAT + self.node_id, bytes([self.nmt_state]))
                    self.stats.heartbeats_sent += 1
                self._next_heartbeat += period_s
                if self._next_heartbeat <= now:  # fell behind: no burst of catch-up heartbeats
                    self._next_heartbeat = now + period_s
            # while frames wait, the receive thread judges at each SYNC it handles (drive_cycle):
            # polling here then would only take the guest's CPU from that thread (docs/vcan.md)
            deadline = min(now + TICK_MAX_S, self.cycle.judge_timeouts(now), self.cycle.t0 + self.injections.next_due_s())
            if period_s > 0:
                deadline = min(deadline, self._next_heartbeat)
            return deadline

    def value(self, index: int, subindex: int = 0) -> Any:
        """An object's current value, as an SDO upload would read it."""
        with self.lock:
            return self.objects.value(index, subindex)

    def write_recording(self, path: str | Path) -> Path:
        """Write the applied set-points as CSV (see ``recording``)."""
        return self.recorder.write_csv(path)

    def write_timeline(self, path: str | Path) -> Path:
        """Write the per-SYNC timeline as CSV (see ``recording``)."""
        return self.timeline.write_csv(path)

    def send_emcy(self, code: int, register: int) -> None:
        """EMCY (CiA 301): code, error register, 5 zero bytes; not in STOPPED or if disabled."""
        emcy_cob = self.cycle.emcy_cob
        if emcy_cob & pdo_layout.COB_ID_INVALID_BIT or self.nmt_state == NmtState.STOPPED:
            return
        if self.silent or self.network is None:
            return
        self.network.send_message(emcy_cob & 0x7FF, EMCY_STRUCT.pack(code, register))
        self.stats.emcys_sent += 1

    # ------------------------------------------------------------------ boot and NMT
    def _boot(self, reset_application: bool) -> None:
        """Reset communication (and the application): stored values back, boot-up message,
        PRE-OPERATIONAL."""
        self.nmt_state = NmtState.BOOTUP
        self.objects.reset(reset_application)
        if reset_application:
            self.axis.reset(self.objects.stored_mode())
            self.cycle.sync_index = 0
        self.pdos.rebuild(self.network is not None)  # every PDO from its objects again, then the parameters
        self.cycle.load_parameters()
        self.heartbeats.configure(self.objects.consumer_entries())
        if self.network is not None and not self.silent:
            self.network.send_message(c.COB_HEARTBEAT + self.node_id, bytes([NmtState.BOOTUP]))
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._next_heartbeat = self._clock() + self.cycle.heartbeat_period_s
        log.info(kv("sim.boot", node=self.node_id, reset_application=reset_application))

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        command = addressed_command(data, self.node_id)
        if command is None:
            return
        with self.lock:
            if self.silent:
                return
            new = NMT_STATES.get(command)
            if new is not None and new != self.nmt_state:
                if new == NmtState.OPERATIONAL:
                    self.pdos.restart()
                    self.cycle.restart()
                log.info(kv("sim.nmt", node=self.node_id, state=new.name, previous=self.nmt_state.name))
                self.nmt_state = new
            elif command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
                self._boot(reset_application=command == NmtCommand.RESET_NODE)

    # ------------------------------------------------------------------ SDO server
    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self.lock:
            if self.silent or self.nmt_state in (NmtState.STOPPED, NmtState.BOOTUP):
                return
            self.node.sdo.on_request(can_id, data, timestamp)

    def _after_sdo_write(self, index: int, subindex: int) -> None:
        log.debug(kv("sim.sdo_write", node=self.node_id, object=f"0x{index:04X}:{subindex:02X}"))
        if pdo_layout.is_pdo_parameter(index):  # a remap: every PDO again, then the parameters
            self.pdos.rebuild(self.network is not None)
            self.cycle.load_parameters()
        elif index == c.CONSUMER_HEARTBEAT_TIME:
            self.heartbeats.configure(self.objects.consumer_entries())
        else:
            self.cycle.load_parameters()
            self.axis.refuse_cyclic_without_period()
