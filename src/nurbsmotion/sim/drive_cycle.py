"""A simulated drive's cyclic side (CiA 301): SYNC (counter, window, loss), RPDOs and their
event timers, the heartbeat consumer's judgement, the communication parameters they use,
and the frames' arrival times on the drive's clock.

Runs under the drive's lock, in the network's receive thread (SYNC, RPDO) or its ticker
(``judge_timeouts``).
"""

from __future__ import annotations

import logging
import math
import time
import threading
from collections.abc import Callable
from typing import Protocol

import canopen

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.arrival_clock import ArrivalClock, socket_pending
from nurbsmotion.can.cia402 import EmcyCode, NmtState
from nurbsmotion.log import kv
from nurbsmotion.sim import axis as axis_module
from nurbsmotion.sim import eds as eds_rules
from nurbsmotion.sim import homing, velocity
from nurbsmotion.sim import pdo as pdo_layout
from nurbsmotion.sim.axis import EMCY_SYNC_LOSS, AxisParameters, Cia402Axis
from nurbsmotion.sim.drive_injections import Injections
from nurbsmotion.sim.drive_objects import SYNC_COUNTER_OVERFLOW, DriveObjects
from nurbsmotion.sim.drive_pdos import DrivePdos, RpdoSlot
from nurbsmotion.sim.eds import find_variable
from nurbsmotion.sim.rpdo_timers import RpdoTimers
from nurbsmotion.sim.slave import ConsumedHeartbeats, Subscriptions
from nurbsmotion.sim.stats import DriveStats
from nurbsmotion.sim.timing import SyncMonitor, SyncSettings

log = logging.getLogger(__name__)

SYNC_WINDOW_LENGTH = 0x1007  # µs after SYNC in which synchronous RPDOs count (0 = no window)
EMCY_SYNC_LENGTH = 0x8240  # CiA 301: unexpected SYNC data length
EMCY_RPDO_TIMEOUT = 0x8250  # CiA 301: RPDO time-out
FE_WINDOW_DISABLED = 0xFFFF_FFFF  # no 0x6065: no following-error monitor
DEFAULT_QUICK_STOP_OPTION = 2  # no 0x605A: CiA 402 default (quick-stop ramp, then disabled)
DEFAULT_QUICK_STOP_DECEL = math.inf  # no 0x6085: the drive stops at once


class CycleHost(Protocol):
    """What the cyclic side uses of its drive (``sim.drive.SimDrive``)."""

    node_id: int
    objects: DriveObjects
    axis: Cia402Axis
    stats: DriveStats
    network: canopen.Network | None
    subscriptions: Subscriptions
    lock: threading.RLock
    silent: bool
    nmt_state: NmtState
    injections: Injections
    heartbeats: ConsumedHeartbeats

    @property
    def pdos(self) -> DrivePdos: ...
    @property
    def period_s(self) -> float: ...
    def send_emcy(self, code: int, register: int) -> None: ...


def velocity_modes_missing(objects: DriveObjects) -> frozenset[int]:
    """The velocity modes whose objects the EDS lacks (0x6502 alone is not enough)."""
    return frozenset(mode for mode, required in velocity.REQUIRED_OBJECTS.items()
                     if any(find_variable(objects.od, index, 0) is None for index in required))


def load_axis_params(params: AxisParameters, objects: DriveObjects, cycle_period_s: float,
                     modes_missing: frozenset[int]) -> None:
    """The CiA-402 application's parameters from the object dictionary (EDS defaults where absent)."""
    value = objects.value_or
    params.cycle_period_s = cycle_period_s
    params.fe_window_counts = value(c.FOLLOWING_ERROR_WINDOW, 0, FE_WINDOW_DISABLED)
    params.fe_timeout_ms = value(c.FOLLOWING_ERROR_TIMEOUT, 0, 0)
    params.quick_stop_option = value(c.QUICK_STOP_OPTION, 0, DEFAULT_QUICK_STOP_OPTION)
    params.quick_stop_decel_counts_s2 = float(value(c.QUICK_STOP_DECELERATION, 0, DEFAULT_QUICK_STOP_DECEL))
    params.limit_min_counts = value(c.SOFTWARE_POSITION_LIMIT, 1, 0)
    params.limit_max_counts = value(c.SOFTWARE_POSITION_LIMIT, 2, 0)
    params.modes = eds_rules.supported_modes(value(c.SUPPORTED_DRIVE_MODES, 0, 0),
                                             find_variable(objects.od, c.MODES_OF_OPERATION, 0)) - modes_missing
    params.velocity_profile = velocity.VelocityProfile(
        float(value(velocity.PROFILE_ACCELERATION, 0, 0)),
        float(value(velocity.PROFILE_DECELERATION, 0, value(velocity.PROFILE_ACCELERATION, 0, 0))),
        float(value(velocity.VELOCITY_WINDOW, 0, 0)), float(value(velocity.VELOCITY_WINDOW_TIME, 0, 0)))


class DriveCycle:
    """SYNC and RPDO handling of ``drive``, on the clock ``clock`` (frames stamped by their
    receive time when ``frame_times``)."""

    def __init__(self, drive: CycleHost, sync: SyncSettings, clock: Callable[[], float], frame_times: bool) -> None:
        self._drive = drive
        self._clock = clock
        self._frame_times = frame_times  # stamp SYNC/RPDO/heartbeats with the frames' receive time
        # the monitors (0x1016, SYNC loss, RPDO timers) judge on the frames' arrival timeline
        self._arrival = ArrivalClock(lambda: False)
        self.wall_to_clock_s = time.monotonic() - time.time()
        self.t0 = clock()
        self.sync_monitor = SyncMonitor(sync)
        self.rpdo_timers = RpdoTimers()
        self.sync_index = 0
        self._sync_window_s = 0.0
        self._sync_counter_overflow: int | None = None  # None: the EDS has no 0x1019
        self._last_sync_counter: int | None = None
        self._period_source = eds_rules.cycle_period_source(drive.objects.od)
        self._modes_missing = velocity_modes_missing(drive.objects)
        self._sync_cob: int | None = None
        self.emcy_cob = pdo_layout.COB_ID_INVALID_BIT
        self.heartbeat_period_s = 0.0

    # ------------------------------------------------------------------ clock
    def attach(self, network: canopen.Network) -> None:
        """Joined ``network``: frames arrive from its bus; the attach time is t0."""
        self._arrival = ArrivalClock(socket_pending(network.bus) if self._frame_times else lambda: False)
        self.t0 = self._clock()
        self.wall_to_clock_s = time.monotonic() - time.time()

    def frame_time(self, timestamp: float) -> float:
        """When a frame arrived, on the drive's clock: its receive timestamp (wall clock,
        kernel time on SocketCAN) unless a clock was injected."""
        if self._frame_times and timestamp > 0:
            return self._arrival.arrived(timestamp + self.wall_to_clock_s, self._clock())
        return self._clock()

    def restart(self) -> None:
        """Entered NMT OPERATIONAL: SYNC counting, monitors and RPDO timers start afresh."""
        self.sync_index = 0
        self.sync_monitor.reset()
        self.rpdo_timers.reset()
        self._last_sync_counter = None

    def forget(self) -> None:
        """Detached: no SYNC subscription any more."""
        self._sync_cob = None

    # ------------------------------------------------------------------ parameters
    def load_parameters(self) -> None:
        """Cache the parameters SYNC handling uses (after boot and every SDO write)."""
        drive, value = self._drive, self._drive.objects.value_or
        load_axis_params(drive.axis.params, drive.objects, self._cycle_period_s(), self._modes_missing)
        self._sync_window_s = value(SYNC_WINDOW_LENGTH, 0, 0) * 1e-6
        self._sync_counter_overflow = value(SYNC_COUNTER_OVERFLOW, 0, None)
        self.emcy_cob = value(c.EMCY_COB_ID, 0, pdo_layout.COB_ID_INVALID_BIT)
        self.heartbeat_period_s = value(c.PRODUCER_HEARTBEAT_TIME, 0, 0) / 1000.0
        sync_cob = value(c.SYNC_COB_ID, 0, c.COB_SYNC) & 0x7FF
        if sync_cob != self._sync_cob and drive.network is not None:
            if self._sync_cob is not None:
                drive.subscriptions.remove(self._sync_cob, self.on_sync)
            drive.subscriptions.add(sync_cob, self.on_sync)
            self._sync_cob = sync_cob

    def _cycle_period_s(self) -> float:
        """0x60C2 (value·10^exponent s) if the EDS has it, else 0x1006 (µs), else the
        measured SYNC interval (a drive that can only lock onto SYNC)."""
        objects = self._drive.objects
        if self._period_source == c.IP_TIME_PERIOD:
            value = objects.value(c.IP_TIME_PERIOD, 1)
            exponent = objects.value_or(c.IP_TIME_PERIOD, 2, -3)
            return max(value * 10.0**exponent, 0.0)
        if self._period_source == c.COMM_CYCLE_PERIOD:
            return objects.value(c.COMM_CYCLE_PERIOD) * 1e-6
        return self.sync_monitor.measured_period_s

    def _homing_period_s(self) -> float:
        """The drive's own cycle in homing mode: 0x1006, else the measured SYNC interval,
        else 1 ms."""
        period_us = self._drive.objects.value_or(c.COMM_CYCLE_PERIOD, 0, 0)
        if period_us > 0:
            return period_us * 1e-6
        measured = self.sync_monitor.measured_period_s
        return measured if measured > 0 else axis_module.DEFAULT_CYCLE_S

    # ------------------------------------------------------------------ timeouts
    def judge_timeouts(self, now: float) -> float:
        """Heartbeat consumer, SYNC loss and RPDO timers at ``now`` seen through the reception
        lag (nurbsmotion.can.arrival_clock); returns when (drive clock) the next of them falls due."""
        arrival_now = self._arrival.judging_time(now)
        self._judge_at(arrival_now)
        due = min(self._drive.heartbeats.consumer.next_deadline(),
                  self.sync_monitor.loss_deadline(self._drive.period_s), self.rpdo_timers.next_deadline())
        return due + max(0.0, now - arrival_now)

    def _judge_at(self, arrival_now: float) -> None:
        """Heartbeat consumer, SYNC loss and RPDO timers at ``arrival_now`` on the arrival
        timeline: from the ticker (judging_time) and from the receive thread at each SYNC's
        arrival, before the SYNC counts (a gap before it is judged as a firmware judges it)."""
        drive = self._drive
        for producer in drive.heartbeats.consumer.newly_failed(arrival_now):
            if not drive.silent:
                # judged_at_s: the arrival-timeline time of the judgement, as wall-clock time
                log.warning(kv("sim.heartbeat_lost", node=drive.node_id, producer=producer,
                               rx_lag_s=round(drive.heartbeats.rx_lag_s.get(producer, 0.0), 3),
                               judged_at_s=f"{arrival_now - self.wall_to_clock_s:.3f}"))
                drive.axis.raise_fault(EmcyCode.HEARTBEAT)
        self._watch_sync_and_rpdos(arrival_now)

    def _watch_sync_and_rpdos(self, now: float) -> None:
        """Sync loss (no SYNC for loss_periods, while IP/CSP is running: EMCY 0x8700, fault)
        and RPDO event timers (0x14xx:05 ran out: EMCY 0x8250, fault)."""
        drive = self._drive
        if drive.silent or drive.nmt_state != NmtState.OPERATIONAL:
            return
        if self.sync_monitor.lost(now, drive.period_s):
            drive.axis.sync_locked = False
            if drive.axis.setpoint_active():
                drive.stats.sync_losses += 1
                log.warning(kv("sim.sync_lost", node=drive.node_id, periods=self.sync_monitor.settings.loss_periods))
                drive.axis.raise_fault(EMCY_SYNC_LOSS)
            else:
                drive.axis.refresh_statusword()
        for number in self.rpdo_timers.expired(now):
            drive.stats.rpdo_timeouts += 1
            log.warning(kv("sim.rpdo_timeout", node=drive.node_id, rpdo=number))
            drive.axis.raise_fault(EMCY_RPDO_TIMEOUT)

    # ------------------------------------------------------------------ PDO traffic
    def on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        drive = self._drive
        with drive.lock:
            if drive.silent or drive.nmt_state != NmtState.OPERATIONAL:
                return
            slot = drive.pdos.rpdo_by_cob.get(can_id)
            if slot is None:
                return
            drive.stats.rpdos_received += 1
            if drive.injections.take_dropped_rpdo():
                drive.stats.rpdos_dropped += 1
                return
            self._receive(slot, data, timestamp)

    def _receive(self, slot: RpdoSlot, data: bytes, timestamp: float) -> None:
        """An RPDO's data kept for the next SYNC unless too short (EMCY 0x8210) or outside
        the SYNC window."""
        drive = self._drive
        if len(data) < slot.layout.size:
            drive.stats.rpdo_length_errors += 1
            drive.send_emcy(EmcyCode.PDO_LENGTH, drive.axis.error_register)
            return
        now = self.frame_time(timestamp)
        if slot.layout.synchronous and self._outside_sync_window(now):
            drive.stats.rpdos_outside_window += 1
            return
        self.rpdo_timers.received(slot.layout.number, now)
        drive.pdos.receive(slot, data)

    def _outside_sync_window(self, now: float) -> bool:
        """CiA 301 0x1007: a synchronous RPDO later than the window after SYNC is discarded."""
        last_sync = self.sync_monitor.last_sync_s
        return self._sync_window_s > 0 and last_sync is not None and now - last_sync > self._sync_window_s

    def on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        """CiA 301 SYNC: apply RPDO data received since the last SYNC, move, send TPDOs."""
        drive = self._drive
        with drive.lock:
            if drive.silent or drive.nmt_state != NmtState.OPERATIONAL:
                return
            try:
                self._handle_sync(data, self.frame_time(timestamp))
            finally:
                drive.stats.syncs += 1  # counted once the SYNC's TPDOs are out

    def _handle_sync(self, data: bytes, now: float) -> None:
        drive = self._drive
        if self._frame_times:  # ``now`` is this SYNC's arrival: the bus is known up to here
            self._judge_at(now)
        self.sync_index += 1
        while (fault := drive.injections.next_due_at_sync(self.sync_index)) is not None:
            drive.injections.apply(fault, self.sync_index)
            if drive.silent:
                return
        if drive.injections.take_ignored_sync():
            drive.stats.syncs_ignored += 1
            return
        sync_counter = self._check_sync_counter(data)
        timing = self.sync_monitor.on_sync(now, drive.period_s)
        if self._period_source is None:
            self.load_parameters()  # the cycle is the measured SYNC interval
        if timing.missed_ticks:
            drive.stats.syncs_late += 1
            drive.stats.ticks_missed += timing.missed_ticks
        drive.axis.sync_locked = self.sync_monitor.locked
        if drive.axis.mode_display == homing.MODE_HOMING:
            drive.axis.params.homing_period_s = self._homing_period_s()
        drive.axis.run_missed_cycles(timing)  # they ran before this SYNC: with the old RPDO data
        drive.pdos.apply_pending()
        drive.axis.step(self.sync_index, sync_counter, timing)
        if drive.network is not None:
            drive.pdos.send_tpdos(drive.network)

    def _check_sync_counter(self, data: bytes) -> int:
        """The SYNC counter byte (-1 without). With 0x1019 in the EDS the length must fit it
        (0: no data, else 1 byte; EMCY 0x8240 otherwise) and the counter must run 1..0x1019
        without a jump (a jump means a SYNC was lost on the way)."""
        counter = data[0] if data else -1
        overflow = self._sync_counter_overflow
        if overflow is None:
            return counter
        drive = self._drive
        if len(data) != (1 if overflow > 0 else 0):
            drive.stats.sync_length_errors += 1
            drive.send_emcy(EMCY_SYNC_LENGTH, drive.axis.error_register)
            return counter
        if overflow > 0:
            last, self._last_sync_counter = self._last_sync_counter, counter
            if last is not None and counter != last % overflow + 1:
                drive.stats.sync_counter_jumps += 1
                log.warning(kv("sim.sync_counter_jump", node=drive.node_id, previous=last, counter=counter))
        return counter
