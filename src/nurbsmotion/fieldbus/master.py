"""CANopen master: bring-up of CiA-402 drives and cyclic set-point streaming.

One thread (the *cycle loop*) owns the cyclic traffic once the drives are configured. Each
cycle k it sends SYNC k (unless the kernel sends it) and right after it one RPDO per axis:
controlword + the set-point for cycle k, which the drive applies at SYNC k+1 (CiA 301).
The drives answer every SYNC with TPDO1 (statusword + position actual) and, if it fits the
bus, TPDO2 (following error); the notifier thread of canopen stores them without
allocation-heavy work and the loop checks them after its sends.

Phases of the loop: 'enabling' (per-cycle CiA-402 state machine towards OPERATION
ENABLED, target = actual position) -> 'holding' (re-send the held position every cycle so
CSP/IP drives stay enabled) <-> 'streaming' (the planned set-points played at the
playback rate of set_rate(): one row per cycle at 1.0, interpolated between rows otherwise,
see stop_ramp) ->
'stopping' (controlled stop on the path, see stop_ramp) / 'quick_stop' (quick stop
controlword to all axes) -> 'disabled'; 'disabling' at shutdown.
"""

from __future__ import annotations

import collections
import gc
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import Callable

import can
import canopen
import numpy as np

from nurbsmotion import cia402 as c
from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.bringup_plan import DrivePlan, Field, PdoFrame, plan_within_load, rpdo_packer
from nurbsmotion.fieldbus.busload import BusLoad, check_bus_load, config_bus_load
from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats, wait_until
from nurbsmotion.fieldbus.drive_state import (CW_DISABLE_VOLTAGE, CW_QUICK_STOP, CW_SHUTDOWN, enable_step, is_ready,
                                              running_controlword, state_name)
from nurbsmotion.fieldbus.heartbeat import MasterHeartbeat
from nurbsmotion.fieldbus.pdo import TPDO1_FORMAT, TPDO2_FORMAT, cycles_of_ms
from nurbsmotion.fieldbus.reports import AxisStatus, CycleStats, FaultReport, JobResult, MasterStatus
from nurbsmotion.fieldbus.stop_ramp import RATE_RAMP_SHARE, StopRamp, ramp_slope, setpoints_at, stop_slope
from nurbsmotion.fieldbus.traffic import TrafficLog
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

RUNNING_PHASES = ("holding", "streaming", "stopping")
_OE_MASK, _OE_VALUE = 0x6F, 0x27  # statusword coding of OPERATION ENABLED
_QS_VALUE = 0x07  # QUICK STOP ACTIVE under the same mask
_HISTORY = 8  # cycles of sent set-points kept for the computed following error
FeedbackSink = Callable[[int, int, int, int, float], None]  # see Master.record_feedback


class Job:
    """Handle of one streamed set-point sequence; every method is thread-safe."""

    def __init__(self, master: "Master", rows: memoryview, dr: float,
                 on_progress: Callable[[int, int], None] | None, progress_every: int,
                 max_step: list[float] | None = None, planned_accel: list[float] | None = None) -> None:
        self._master = master
        self.rows = rows
        self.length = rows.shape[0]
        self.last = rows.shape[0] - 1
        self.ramp = StopRamp(rows, dr)
        self.index = -1  # index of the last planned set-point handed to the bus
        self.playback_s = 0.0  # fractional row played last
        self.playback_r = 1.0  # rows per cycle
        n_axes = rows.shape[1]
        self.max_step = max_step if max_step is not None else [0.0] * n_axes  # counts per cycle, per axis
        self.planned_accel = planned_accel if planned_accel is not None else [0.0] * n_axes  # counts/s^2
        self.on_progress = on_progress
        self.progress_every = progress_every
        self.faults: list[FaultReport] = []
        self.start_cycle = -1  # master cycle that sends the job's first set-point (its cycle 0)
        self.finish_cycle = -1
        self.outcome = ""
        self._done = threading.Event()
        self._result: JobResult | None = None

    def wait(self, timeout: float | None = None) -> JobResult | None:
        """Block until the job ended (or ``timeout`` s passed: None)."""
        return self._result if self._done.wait(timeout) else None

    def done(self) -> bool:
        return self._done.is_set()

    @property
    def result(self) -> JobResult | None:
        return self._result

    def request_stop(self) -> None:
        """Controlled stop: decelerate along the path within a_max, then hold."""
        self._master._request("stop", self)

    def abort(self) -> None:
        """Quick stop controlword to every axis (drives stop on their own ramp and disable)."""
        self._master._request("abort", self)

    def status(self) -> MasterStatus:
        return self._master.status()

    def _finish(self, result: JobResult) -> None:
        self._result = result
        self._done.set()


class Master:
    """CANopen master for the configured axes (see module docstring).

    ``bus``: an open python-can bus to use (not closed at shutdown); None opens
    ``config.bus``. ``sync_source``: 'loop' (the cycle loop sends SYNC right before the
    RPDOs), 'kernel' (SocketCAN broadcast manager via send_periodic), 'auto' (kernel on
    socketcan, else loop); None (default) takes ``config.bus.sync_source`` ('loop' unless
    configured: it never loses a set-point to a late cycle). ``traffic_log``: file for every frame (.log candump, .asc ...).
    """

    def __init__(self, config: MachineConfig, bus: can.BusABC | None = None, *,
                 traffic_log: str | None = None, sync_source: str | None = None, check_load: bool = True,
                 bootup_timeout_s: float = 2.0, stuck_timeout_s: float = 0.5, enable_timeout_s: float = 5.0,
                 sdo_timeout_s: float = 0.5, spin_s: float = 60e-6, late_threshold_s: float | None = None,
                 progress_period_s: float = 0.05, rt_priority: int | None = 20, gc_mode: str = "freeze") -> None:
        if sync_source is None:
            sync_source = config.bus.sync_source
        if sync_source not in ("auto", "loop", "kernel"):
            raise InputError("sync_source", f"must be auto, loop or kernel, got {sync_source!r}")
        if gc_mode not in ("freeze", "disable", "none"):
            raise InputError("gc_mode", f"must be freeze, disable or none, got {gc_mode!r}")
        self._rt_priority = rt_priority
        self._receive_priority_set = False
        self._gc_mode = gc_mode
        self.config = config
        self.axis_map = AxisMap.from_config(config)
        self.bus_load: BusLoad = check_bus_load(config) if check_load else config_bus_load(config)
        self._bus = bus
        self._own_bus = bus is None
        self._traffic_path = traffic_log
        self._traffic_log: TrafficLog | None = None
        self._traffic: TrafficLog | None = None  # the log while it records (the loop's fast check)
        self._sync_source = sync_source
        self._bootup_timeout_s = bootup_timeout_s
        self._enable_timeout_s = enable_timeout_s
        self._sdo_timeout_s = sdo_timeout_s
        self._spin_s = spin_s
        self._period_s = config.cycle_period_s
        self._stuck_cycles = cycles_of_ms(stuck_timeout_s * 1000.0, self._period_s)
        self._progress_every = cycles_of_ms(progress_period_s * 1000.0, self._period_s)
        self._hb_timeout_s = config.monitoring.heartbeat_consumer_ms / 1000.0
        self._network: canopen.Network | None = None

        axes = config.axes
        n = self._n = len(axes)
        self._names = [a.name for a in axes]
        self._node_ids = [a.node_id for a in axes]
        self._ip = [a.mode == "ip" for a in axes]
        self._run_cw = [running_controlword(ip) for ip in self._ip]
        self._cw_quick_stop = [CW_QUICK_STOP] * n
        self._cw_disable_voltage = [CW_DISABLE_VOLTAGE] * n
        self._cw_shutdown = [CW_SHUTDOWN] * n
        self._fe_window = [int(w) for w in self.axis_map.following_error_window_counts()]
        self._fe_timeout_cycles = [cycles_of_ms(a.following_error_timeout_ms, self._period_s) for a in axes]
        self._accel_counts_s2 = self.axis_map.max_accel_counts_s2(config.interpolation.max_accel_mm_s2)
        self._accel_limits = [float(a) for a in self._accel_counts_s2]
        self._rate_target = 1.0  # playback rate requested by set_rate (feed override)
        self._feedback_sink: FeedbackSink | None = None  # record_feedback()
        # feedback, written by the notifier thread (plain lists: item stores are atomic)
        self._fb_status: list[int | None] = [None] * n
        self._fb_pos: list[int] = [0] * n
        self._fb_fe: list[int | None] = [None] * n
        self._fb_cycle = [-1] * n
        self._fb_time = [0.0] * n  # receive timestamp of the last TPDO1 (time.time() based)
        self._fe_checked_time = [0.0] * n
        self._bad_tpdo = [0] * n
        self._emcy_count = [0] * n
        self._last_emcy: list[int | None] = [None] * n
        self._hb_time = [0.0] * n
        self._hb_state: list[int | None] = [None] * n
        self._events: collections.deque[tuple[int, ...]] = collections.deque()
        self._bootup = bringup.BootupWatch(self._node_ids)
        # loop state
        self._sp = [0] * n
        self._cw = [0] * n
        self._hold = [0] * n
        self._sp_history = [[0] * n for _ in range(_HISTORY)]
        self._fe_cycles = [0] * n
        self._axis_enabled = [False] * n
        self._since_cycle = [0] * n
        self._since_status: list[int | None] = [None] * n
        self._phase = "offline"
        self._phase_cycle = 0
        self._cycle = 0
        self._stats = LatenessStats(late_threshold_s if late_threshold_s is not None else 0.1 * self._period_s)
        self._send_errors = 0
        self._job: Job | None = None
        self._requests: collections.deque[tuple[str, object]] = collections.deque()
        self._faults: list[FaultReport] = []
        self._reported: set[tuple[int | None, str]] = set()
        self._bad_tpdo_warned: set[int] = set()
        self._ready = threading.Event()
        self._enable_error: FieldbusError | None = None
        self._thread: threading.Thread | None = None
        self._quit = False
        self._sync_task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self._sync_bus: can.BusABC | None = None
        self._sync_seen_s = 0.0  # perf_counter when a SYNC sent by the kernel was last received
        self._sync_seen_stamp = 0.0  # its frame timestamp
        self._sync_time = [0.0] * _HISTORY  # time.time() of the SYNC each cycle's RPDOs follow
        self._sync_msg = can.Message(arbitration_id=c.COB_SYNC, is_extended_id=False, data=b"")
        # each axis' bring-up plan from its EDS: refused here (one line per axis) before the bus is touched
        self.plans: list[DrivePlan] = plan_within_load(config, self._fe_window, check_load)
        self.following_error_tpdo = any(p.layout.has_following_error for p in self.plans)
        self._trails: list[bringup.SdoTrail] = []  # per axis after connect(): its SDO access, named in errors
        self._rpdo_slots = [(can.Message(arbitration_id=frame.cob_id, is_extended_id=False,
                                         data=bytearray(frame.dlc)), i, rpdo_packer(frame))
                            for i, plan in enumerate(self.plans) for frame in plan.layout.rpdos]
        self._rpdo_msgs = [msg for msg, _, _ in self._rpdo_slots]
        self._heartbeat: MasterHeartbeat | None = None
        self._heartbeat_cycle = -1  # the cycle the heartbeat watchdog saw last

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the bus (if not given), start canopen's notifier and the feedback callbacks."""
        if self._network is not None:
            return
        if self._bus is None:
            bus_cfg = self.config.bus
            try:
                self._bus = can.Bus(interface=bus_cfg.interface, channel=bus_cfg.channel, bitrate=bus_cfg.bitrate)
            except (can.CanError, OSError, ValueError, ImportError) as err:
                raise FieldbusError(f"bus {bus_cfg.interface}:{bus_cfg.channel}: cannot open ({err})") from None
        network = canopen.Network(self._bus)
        self._traffic_log = TrafficLog(self._traffic_path)  # paused without a path
        network.listeners.append(self._traffic_log)
        self._wrap_network_send(network, self._traffic_log)
        self._traffic = self._traffic_log if self._traffic_path else None
        network.connect()
        self._trails = []
        for i, (axis, plan) in enumerate(zip(self.config.axes, self.plans)):
            assert axis.od is not None  # loaded with the configuration
            node, trail = bringup.open_node(network, axis.node_id, axis.od, self._sdo_timeout_s)
            self._trails.append(trail)
            for frame in plan.layout.tpdos:
                network.subscribe(frame.cob_id, self._tpdo_callback(i, frame))
            node.emcy.add_callback(self._emcy_callback(i))
            network.subscribe(c.COB_HEARTBEAT + axis.node_id, self._heartbeat_callback(i))
        network.subscribe(c.COB_SYNC, self._on_sync_seen)
        self._network = network

    @staticmethod
    def _wrap_network_send(network: canopen.Network, traffic: TrafficLog) -> None:
        """Also log the frames canopen sends (NMT, SDO) in the traffic record."""
        plain = network.send_message

        def send_message(can_id: int, data: bytes, remote: bool = False) -> None:
            plain(can_id, data, remote)
            traffic.sent(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False))

        network.send_message = send_message  # type: ignore[method-assign]

    # ------------------------------------------------------------------ feedback callbacks (notifier thread)
    def _tpdo1_callback(self, i: int) -> Callable[[int, bytearray, float], None]:
        size = TPDO1_FORMAT.size
        unpack = TPDO1_FORMAT.unpack_from

        def on_tpdo1(can_id: int, data: bytearray, timestamp: float) -> None:
            if not self._receive_priority_set:
                self._raise_receive_thread_priority()
            if len(data) != size:
                self._bad_tpdo[i] += 1
                self._events.append((3, i, len(data)))
                return
            self._fb_status[i], self._fb_pos[i] = unpack(data)
            self._fb_cycle[i] = self._cycle
            self._fb_time[i] = timestamp
            sink = self._feedback_sink
            if sink is not None:
                sink(self._cycle, i, self._fb_status[i], self._fb_pos[i], timestamp)
        return on_tpdo1

    def _tpdo_callback(self, i: int, frame: PdoFrame) -> Callable[[int, bytearray, float], None]:
        """The decoder of one TPDO of axis i's layout (statusword + position, or split)."""
        if frame.fields == (Field.STATUSWORD, Field.POSITION):
            return self._tpdo1_callback(i)
        if frame.fields == (Field.FOLLOWING_ERROR,):
            return self._tpdo2_callback(i)
        size, unpack = frame.dlc, frame.fmt.unpack_from
        status = frame.fields == (Field.STATUSWORD,)

        def on_split_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != size:
                self._bad_tpdo[i] += 1
                self._events.append((3, i, len(data)))
                return
            if status:
                self._fb_status[i] = unpack(data)[0]
                return
            self._fb_pos[i] = unpack(data)[0]
            self._fb_cycle[i] = self._cycle
            self._fb_time[i] = timestamp
            sink = self._feedback_sink
            if sink is not None:
                sink(self._cycle, i, self._fb_status[i] or 0, self._fb_pos[i], timestamp)
        return on_split_tpdo

    def _tpdo2_callback(self, i: int) -> Callable[[int, bytearray, float], None]:
        size = TPDO2_FORMAT.size
        unpack = TPDO2_FORMAT.unpack_from

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != size:
                self._bad_tpdo[i] += 1
                self._events.append((3, i, len(data)))
                return
            self._fb_fe[i] = unpack(data)[0]
        return on_tpdo2

    def _emcy_callback(self, i: int) -> Callable[[canopen.emcy.EmcyError], None]:
        def on_emcy(entry: canopen.emcy.EmcyError) -> None:
            code = entry.code
            self._emcy_count[i] += 1
            self._last_emcy[i] = code
            self._events.append((1, i, code))
        return on_emcy

    def _heartbeat_callback(self, i: int) -> Callable[[int, bytearray, float], None]:
        node_id = self._node_ids[i]

        def on_heartbeat(can_id: int, data: bytearray, timestamp: float) -> None:
            if not data:
                return
            state = data[0] & 0x7F
            self._hb_time[i] = time.perf_counter()
            if state != self._hb_state[i]:
                self._hb_state[i] = state
                self._events.append((2, i, state))
            self._bootup.heard(node_id, state)
        return on_heartbeat

    # ------------------------------------------------------------------ bring-up
    def bring_up(self) -> None:
        """Reset, check, configure, start and enable every axis; FieldbusError names node and step."""
        self.connect()
        assert self._network is not None
        if self._thread is not None:
            raise FieldbusError("bring-up: the cycle loop is already running (call shutdown() first)")
        self._start_heartbeat()
        try:
            self._bring_up_by_sdo(self._network)
        except FieldbusError as err:
            err = self._twin_error() or err  # duplicate SDO answers make some step fail first: name the cause
            self._faults.append(FaultReport(None, None, "bringup", 0, -1, str(err)))
            raise err from None
        for node_id in self._node_ids:
            self._network[node_id].nmt.send_command(c.NmtCommand.START)
        now = time.perf_counter()
        self._hb_time = [now] * self._n
        self._start_loop()
        self._wait_enabled()

    def _start_heartbeat(self) -> None:
        """The master's heartbeat (fieldbus.heartbeat), before any drive is told to consume it."""
        period_ms = self.config.monitoring.master_heartbeat_ms
        if period_ms == 0 or self._heartbeat is not None:
            return
        assert self._bus is not None
        self._heartbeat = MasterHeartbeat(self._bus, self.config.master.node_id, period_ms / 1000.0,
                                          self._making_progress)
        self._heartbeat.start()

    def _making_progress(self) -> bool:
        """For the heartbeat's watchdog: no cycle loop yet (bring-up), or it advanced."""
        k = self._cycle
        moved = self._thread is None or k != self._heartbeat_cycle
        self._heartbeat_cycle = k
        return moved

    def _stop_heartbeat(self) -> None:
        if self._heartbeat is not None:
            self._heartbeat.stop()
            self._heartbeat = None

    def _bring_up_by_sdo(self, network: canopen.Network) -> None:
        self._bootup.arm()
        for node_id in self._node_ids:
            network[node_id].nmt.send_command(c.NmtCommand.RESET_COMMUNICATION)
        missing = self._bootup.wait(self._bootup_timeout_s)
        if missing:
            names = ", ".join(f"{n} (axis {self._names[self._node_ids.index(n)]})" for n in missing)
            raise FieldbusError(f"node {missing[0]}: bring-up step 'boot-up': no boot-up message within "
                                f"{self._bootup_timeout_s * 1000:.0f} ms after NMT reset communication "
                                f"(missing: node {names}; unpowered, unplugged or wrong node id?)")
        for i, (axis, plan) in enumerate(zip(self.config.axes, self.plans)):
            trail = self._trails[i]
            network[axis.node_id].emcy.reset()  # canopen keeps every EMCY in a list: start it empty
            bringup.check_identity(trail, axis)
            bringup.check_supported_mode(trail, plan)
            bringup.configure(trail, plan)
            self._fb_pos[i] = bringup.read_position(trail)
            self._fb_status[i] = bringup.read_statusword(trail)
            self._hold[i] = self._sp[i] = self._fb_pos[i]
            log.info(kv("drive_configured", node=axis.node_id, axis=axis.name, mode=axis.mode,
                        rpdos=len(plan.layout.rpdos), tpdos=len(plan.layout.tpdos),
                        skipped=",".join(s.what for s in plan.skipped), position=self._fb_pos[i],
                        statusword=f"0x{self._fb_status[i]:04X}"))
        twin = self._twin_error()  # checked after the SDO steps, so a late twin's boot-up is seen too
        if twin is not None:
            raise twin
        if self._heartbeat is not None:  # CiA 301: a drive monitors from the first heartbeat it receives after
            time.sleep(1.5 * self._heartbeat.period_s)  # 0x1016 is written: let every drive hear one first

    def _twin_error(self) -> FieldbusError | None:
        """Two boot-ups of one node after one NMT reset: two devices with that node id."""
        for node_id, count in self._bootup.count.items():
            if count > 1:
                return FieldbusError(f"node {node_id}: bring-up step 'boot-up': {count} boot-up messages after one "
                                     f"NMT reset: two devices with the same node id?")
        return None

    def _wait_enabled(self) -> None:
        """Wait for the loop's state machine: every axis ready, or a named error."""
        if not self._ready.wait(self._enable_timeout_s + 2.0):
            self._request("quick_stop", None)
            raise FieldbusError(f"bring-up: drives not enabled within {self._enable_timeout_s:.1f} s "
                                f"(states: {', '.join(f'node {a.node_id} {a.state}' for a in self.status().axes)})")
        if self._enable_error is not None:
            raise self._enable_error
        if self._phase != "holding":
            raise FieldbusError(f"bring-up: the cycle loop stopped in phase {self._phase} (see the log)")

    def reset_faults(self) -> None:
        """Acknowledge faults and re-enable every axis (fault reset, state machine), then hold."""
        if self._thread is None:
            if not self._faults:
                raise FieldbusError("reset faults: the drives are not brought up (call bring_up())")
            self.bring_up()  # an earlier bring-up failed (e.g. a drive was still off): try it again
            return
        if self._job is not None:
            raise FieldbusError("reset faults: a job is still running")
        if any(state != c.NmtState.OPERATIONAL for state in self._hb_state) or \
                min(self._fb_cycle) < self._cycle - 3:  # a drive restarted or went silent (power loss):
            self.shutdown()  # it lost its configuration, so bring every axis up again (or name the missing node)
            self.bring_up()
            return
        self._ready.clear()
        self._enable_error = None
        self._request("enable", None)
        self._wait_enabled()

    # ------------------------------------------------------------------ streaming API
    def set_rate(self, rate: float) -> None:
        """Playback rate for the running and the next jobs (1.0 = as planned, 0 = pause). The
        running job's rate moves there by RATE_RAMP_SHARE of its stop slope per cycle; the
        caller keeps the rate within what the plan allows (service.rate)."""
        self._rate_target = max(0.0, float(rate))

    def record_feedback(self, sink: FeedbackSink | None) -> None:
        """Hand every valid TPDO1 to ``sink(cycle, axis_index, statusword, position_counts,
        timestamp)`` (None: stop). Read-only: called on canopen's receive thread right after
        the master stored the values, so it must only append somewhere and return; ``cycle``
        is the master's cycle counter when the TPDO arrived (a job's cycle 0 is its
        ``start_cycle``), ``timestamp`` the frame's receive time."""
        self._feedback_sink = sink

    def stream(self, counts: np.ndarray, on_progress: Callable[[int, int], None] | None = None) -> Job:
        """Start streaming an (N, n_axes) int32 array of set-points, one row per cycle.

        The first row must be within each axis' following-error window of the held
        position (no jump at the start). ``on_progress(sent, length)`` is called from the
        cycle loop every ~50 ms and must return quickly.
        """
        arr = np.asarray(counts)
        if arr.ndim != 2 or arr.shape[1] != self._n or arr.shape[0] < 1:
            raise InputError("set-points", f"expected an array of shape (N >= 1, {self._n}) of counts, "
                             f"got shape {arr.shape}")
        if not np.issubdtype(arr.dtype, np.integer):
            raise InputError("set-points", f"counts must be integers (int32), got dtype {arr.dtype}")
        if arr.size and (arr.min() < -(2**31) or arr.max() > 2**31 - 1):
            raise InputError("set-points", "counts outside the int32 range")
        if self._phase != "holding" or self._thread is None:
            raise FieldbusError(f"stream: the axes are not holding (phase {self._phase}); "
                                f"{'call reset_faults()' if self._thread is not None else 'call bring_up()'} first")
        if self._job is not None or any(r[0] == "job" for r in self._requests):
            raise FieldbusError("stream: a job is already running")
        if self._reported:
            raise FieldbusError("stream: faults not acknowledged; call reset_faults() first")
        hold = self._hold
        for j in range(self._n):
            if abs(int(arr[0, j]) - hold[j]) > self._fe_window[j]:
                raise InputError("set-points", f"axis {self._names[j]}: the job starts at {int(arr[0, j])} counts "
                                 f"but the axis holds {hold[j]} counts (more than the following-error window "
                                 f"{self._fe_window[j]} counts away)")
        # A 2-D memoryview: 8 bytes per set-point, read per cycle as rows[i, j] -> int
        # (nested lists would cost ~10x the memory for a long program).
        as_int64 = np.ascontiguousarray(arr, dtype=np.int64)
        rows = memoryview(as_int64)
        # per-axis figures for the stop slope, as plain floats for the cycle loop
        max_step = (np.abs(np.diff(as_int64, axis=0)).max(axis=0) if len(arr) > 1 else np.zeros(self._n))
        planned_accel = (np.abs(np.diff(as_int64, n=2, axis=0)).max(axis=0) if len(arr) > 2
                         else np.zeros(self._n)) / self._period_s**2
        job = Job(self, rows, ramp_slope(arr, self._accel_counts_s2, self._period_s),
                  on_progress, self._progress_every, max_step.astype(float).tolist(),
                  planned_accel.astype(float).tolist())
        job.playback_r = self._rate_target
        self._quiet_gc()
        self._request("job", job)
        return job

    def _quiet_gc(self) -> None:
        """Keep the cyclic garbage collector from stalling the loop for milliseconds during a job.

        'freeze' moves every object alive now (the job's rows included) out of the collector's
        reach, so collections during the job only scan what is allocated meanwhile; 'disable'
        stops cyclic collection until the job ends (reference counting still frees memory).
        """
        if self._gc_mode == "freeze":
            gc.freeze()
        elif self._gc_mode == "disable":
            gc.disable()

    def _release_gc(self) -> None:
        if self._gc_mode == "freeze":
            gc.unfreeze()
        elif self._gc_mode == "disable":
            gc.enable()

    def status(self) -> MasterStatus:
        """A consistent-enough snapshot (lists copied) for the daemon; any thread."""
        stats = self._stats
        axes = []
        sent = self._sp_history[self._cycle % _HISTORY] if self._cycle else self._sp
        for i in range(self._n):
            sw = self._fb_status[i]
            fe = self._fb_fe[i]
            if fe is None and self._fb_cycle[i] >= 1:  # no TPDO2: the master's estimate
                fe = self._sp_history[(self._fb_cycle[i] - 1) % _HISTORY][i] - self._fb_pos[i]
            axes.append(AxisStatus(self._names[i], self._node_ids[i], state_name(sw), sw, self._fb_pos[i],
                                   sent[i], fe, self._bad_tpdo[i], self._emcy_count[i], self._last_emcy[i]))
        timing = CycleStats(stats.count, stats.late, stats.missed, stats.late_threshold_s, stats.percentile_s(0.5),
                            stats.percentile_s(0.99), stats.max_s, self._send_errors)
        job = self._job
        return MasterStatus(self._phase, self._cycle, tuple(axes), timing, job.index if job else None,
                            job.length if job else None, tuple(self._faults))

    def faults(self) -> list[FaultReport]:
        return list(self._faults)

    def record_traffic(self, path: str | Path | None) -> None:
        """Record every frame into ``path`` from now on (candump .log, .asc, ... by extension),
        closing the previous file; None stops recording. Used for one traffic log per job."""
        if self._traffic_log is None:
            raise FieldbusError("record_traffic: connect() first")
        if path is None:
            self._traffic = None
            self._traffic_log.switch(None)
        else:
            self._traffic_log.switch(path)
            self._traffic = self._traffic_log

    def shutdown(self, timeout_s: float = 5.0) -> None:
        """Controlled stop of a running job, disable the drives, NMT stop, close (if ours)."""
        if self._thread is not None:
            job = self._job
            if job is not None:
                job.request_stop()
                job.wait(timeout_s)
            self._request("disable", None)
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                self._quit = True
                self._thread.join(1.0)
            self._thread = None
        if self._sync_task is not None:
            self._sync_task.stop()
            self._sync_task = None
        self._stop_heartbeat()
        if self._sync_bus is not None:
            self._sync_bus.shutdown()
            self._sync_bus = None
        if self._network is not None:
            for node_id in self._node_ids:
                try:
                    self._network.send_message(c.COB_NMT, bytes([c.NmtCommand.STOP, node_id]))
                except (can.CanError, OSError):
                    pass
            if self._network.notifier is not None:
                self._network.notifier.stop(2.0)
            self._network = None
        self._traffic = None
        if self._traffic_log is not None:
            self._traffic_log.stop()
            self._traffic_log = None
        if self._own_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None
        self._phase = "offline"

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def _request(self, what: str, arg: object) -> None:
        self._requests.append((what, arg))

    # ------------------------------------------------------------------ the cycle loop
    def _start_loop(self) -> None:
        self._quit = False
        self._ready.clear()
        self._enable_error = None
        self._enter_enabling(0)
        self._thread = threading.Thread(target=self._run, name="nurbsmotion-cycle", daemon=True)
        self._thread.start()

    def _sync_sender(self) -> can.BusABC:
        """Bus whose send_periodic sends the SYNC. SocketCAN: the bus itself (its broadcast
        manager socket's frames reach our raw socket, so the SYNC is seen). Virtual: a second
        bus on the channel, so the SYNC is seen too (a python-can bus does not hear itself)."""
        assert self._bus is not None
        if type(self._bus).__name__ == "VirtualBus":
            self._sync_bus = can.Bus(interface="virtual", channel=self._bus.channel_id)
            return self._sync_bus
        return self._bus

    def _on_sync_seen(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC the kernel sent: its frame timestamp (time.time based) says when, even if
        this receive thread runs late; convert it to perf_counter for the loop's grid."""
        now_wall, now_perf = time.time(), time.perf_counter()
        age = now_wall - timestamp
        self._sync_seen_s = now_perf - age if 0.0 <= age < 1.0 else now_perf
        self._sync_seen_stamp = timestamp

    def _use_kernel_sync(self) -> bool:
        if self._sync_source == "auto":
            return type(self._bus).__name__ == "SocketcanBus"
        return self._sync_source == "kernel"

    def _run(self) -> None:
        period = self._period_s
        kernel_sync = self._use_kernel_sync()
        assert self._bus is not None
        send = self._bus.send
        if kernel_sync:
            self._sync_task = self._sync_sender().send_periodic(self._sync_msg, period)
            grid = DeadlineGrid(period, time.perf_counter() + 0.5 * period, 0.5 * period)  # half a cycle after SYNC
        else:
            grid = DeadlineGrid(period, time.perf_counter() + period)
        sync_msg = None if kernel_sync else self._sync_msg
        slots, sp, cw, n = self._rpdo_slots, self._sp, self._cw, self._n
        spin_s = self._spin_s
        stats = self._stats
        history = self._sp_history
        sync_time = self._sync_time
        k = 0
        anchor_s = 0.0
        self._set_realtime_priority()
        if self._rt_priority is not None:
            self._shorten_gil_switch_interval()
        try:
            self._compute(1)
            while not self._quit:
                if kernel_sync and self._sync_seen_s > anchor_s:
                    anchor_s = self._sync_seen_s  # re-anchor on the SYNC the kernel really sent
                    grid.next_s = anchor_s + (int((grid.next_s - anchor_s) / period) + 0.5) * period
                woke = wait_until(grid.next_s, spin_s)
                lateness, missed = grid.advance(woke)
                stats.add(lateness, missed)
                k += 1
                self._cycle = k
                try:
                    if sync_msg is not None:
                        sync_time[k % _HISTORY] = time.time()  # frame timestamps are time.time() based
                        send(sync_msg)
                    else:
                        sync_time[k % _HISTORY] = self._sync_seen_stamp
                    for msg, i, pack in slots:  # one or two RPDOs per axis (its PDO layout)
                        pack(msg.data, cw[i], sp[i])
                        send(msg)
                except (can.CanError, OSError) as err:
                    self._on_send_error(k, err)
                row = history[k % _HISTORY]
                for i in range(n):
                    row[i] = sp[i]
                if self._traffic is not None:
                    self._log_cycle(sync_msg)
                if missed:
                    log.warning(kv("missed_cycle", cycle=k, lateness_ms=lateness * 1000))
                self._supervise(k)
                self._compute(k + 1)
        except Exception as err:  # pragma: no cover - a bug must still stop the axes
            log.exception("cycle loop failed")
            self._report(None, None, "bus_error", 0, k, f"cycle loop failed at cycle {k}: {err!r}")
            self._emergency_quick_stop()
            self._finish_job("faulted")
            self._phase = "disabled"
            self._ready.set()

    def _set_realtime_priority(self) -> None:
        """SCHED_FIFO for the cycle thread when allowed (root / CAP_SYS_NICE); else normal."""
        if self._rt_priority is None or not hasattr(os, "sched_setscheduler"):
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._rt_priority))
            log.info(kv("cycle_thread_priority", policy="SCHED_FIFO", priority=self._rt_priority))
        except (PermissionError, OSError) as err:
            log.info(kv("cycle_thread_priority", policy="normal", reason=str(err)))

    def _raise_receive_thread_priority(self) -> None:
        """Run canopen's receive thread SCHED_FIFO just below the cycle thread: a normal-priority
        thread preempted while it holds the GIL would stall the cycle thread (priority inversion)."""
        self._receive_priority_set = True
        if self._rt_priority is None or not hasattr(os, "sched_setscheduler"):
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, self._rt_priority - 1)))
        except (PermissionError, OSError):
            pass

    def _shorten_gil_switch_interval(self) -> None:
        """A thread busy in pure Python keeps the GIL up to the switch interval (5 ms by
        default) before the woken cycle thread gets it: cap it at a quarter period."""
        if sys.getswitchinterval() > self._period_s / 4:
            sys.setswitchinterval(self._period_s / 4)

    def _log_cycle(self, sync_msg: can.Message | None) -> None:
        assert self._traffic is not None
        if sync_msg is not None:
            self._traffic.sent(sync_msg)
        for msg in self._rpdo_msgs:
            self._traffic.sent(msg)

    def _emergency_quick_stop(self) -> None:
        assert self._bus is not None
        for msg, i, pack in self._rpdo_slots:
            try:
                pack(msg.data, CW_QUICK_STOP, self._sp[i])
                self._bus.send(msg)
            except (can.CanError, OSError):
                pass

    def _on_send_error(self, k: int, err: Exception) -> None:
        self._send_errors += 1
        self._report(None, None, "bus_error", 0, k, f"bus: sending the cyclic frames failed at cycle {k}: {err}")

    # ---------------------------------------------------------------- set-points for the next cycle
    def _compute(self, k: int) -> None:
        """Controlwords and set-points to send in cycle k (applied by the drives at SYNC k+1)."""
        phase = self._phase
        sp, cw, n = self._sp, self._cw, self._n
        if phase == "streaming":
            job = self._job
            assert job is not None
            if job.index < 0:
                s = 0.0
            else:
                r, target, dr = job.playback_r, self._rate_target, job.ramp.dr * RATE_RAMP_SHARE
                r = min(r + dr, target) if r < target else max(r - dr, target)
                job.playback_r = r
                s = min(job.playback_s + r, float(job.last))
            job.playback_s = s
            setpoints_at(job.rows, s, sp, n)
            cw[:] = self._run_cw
            idx = int(s)
            job.index = idx
            if idx == job.last:
                self._hold[:] = sp
                self._set_phase("holding", k)
                job.outcome, job.finish_cycle = "done", k + 1
        elif phase == "holding":
            sp[:] = self._hold
            cw[:] = self._run_cw
        elif phase == "stopping":
            job = self._job
            assert job is not None
            cw[:] = self._run_cw
            if not job.ramp.step(sp):
                self._hold[:] = sp
                self._set_phase("holding", k)
                job.finish_cycle = k + 1
        elif phase == "enabling":
            self._compute_enabling()
        elif phase == "quick_stop":
            sp[:] = self._fb_pos
            cw[:] = self._cw_quick_stop
        elif phase == "disabled":
            sp[:] = self._fb_pos
            cw[:] = self._cw_disable_voltage
        elif phase == "disabling":
            sp[:] = self._hold
            cw[:] = self._cw_shutdown

    def _compute_enabling(self) -> None:
        sp, cw = self._sp, self._cw
        for i in range(self._n):
            sw = self._fb_status[i]
            state = c.state_of_statusword(sw) if sw is not None else None
            if state is c.State.OPERATION_ENABLED:
                if not self._axis_enabled[i]:
                    self._axis_enabled[i] = True
                    self._hold[i] = sp[i]
                sp[i] = self._hold[i]
            else:
                self._axis_enabled[i] = False
                sp[i] = self._fb_pos[i]
            cw[i] = enable_step(state, cw[i], self._ip[i])[1]

    def _set_phase(self, phase: str, k: int) -> None:
        self._phase = phase
        self._phase_cycle = k
        log.info(kv("phase", phase=phase, cycle=k))

    def _enter_enabling(self, k: int) -> None:
        for i in range(self._n):
            self._since_cycle[i] = k
            self._since_status[i] = self._fb_status[i]
            self._axis_enabled[i] = False
            self._fe_cycles[i] = 0
        self._reported.clear()
        self._set_phase("enabling", k)

    # ---------------------------------------------------------------- supervision after the sends
    def _supervise(self, k: int) -> None:
        while self._requests:
            self._handle_request(*self._requests.popleft(), k)
        while self._events:
            self._handle_event(self._events.popleft(), k)
        phase = self._phase
        if phase in RUNNING_PHASES:
            self._check_axes(k, running=True)
        elif phase == "enabling":
            self._check_enabling(k)
        elif phase == "disabled":
            self._check_axes(k, running=False)
        elif phase == "quick_stop":
            self._check_axes(k, running=False)
            if k - self._phase_cycle > 2 and all(self._stopped_or_silent(i, k) for i in range(self._n)):
                self._set_phase("disabled", k)
        elif phase == "disabling":
            if all((s or 0) & _OE_MASK != _OE_VALUE for s in self._fb_status) and k - self._phase_cycle > 2 \
                    or k - self._phase_cycle > self._stuck_cycles:
                self._quit = True
        job = self._job
        if job is not None:
            if job.finish_cycle == k:
                self._finish_job(job.outcome)
            elif job.on_progress is not None and k % job.progress_every == 0:
                self._call_progress(job)

    def _stopped_or_silent(self, i: int, k: int) -> bool:
        """Axis i no longer enabled nor quick-stopping, or its TPDO1 stopped coming."""
        return (self._fb_status[i] or 0) & _OE_MASK not in (_OE_VALUE, _QS_VALUE) or self._fb_cycle[i] < k - 3

    def _call_progress(self, job: Job) -> None:
        try:
            job.on_progress(job.index + 1, job.length)  # type: ignore[misc]
        except Exception:  # a broken callback must not stop the machine
            log.exception("on_progress callback failed; it is not called again")
            job.on_progress = None

    def _handle_request(self, what: str, arg: object, k: int) -> None:
        phase = self._phase
        if what == "job":
            assert isinstance(arg, Job)
            if phase == "holding" and self._job is None:
                self._job = arg
                arg.start_cycle = k + 1
                self._set_phase("streaming", k)
            else:
                self._release_gc()
                arg._finish(JobResult("aborted", 0, arg.length, (), 0, 0))
        elif what == "stop":
            if self._job is arg and phase == "streaming":
                self._start_controlled_stop(k, "stopped")
        elif what == "abort":
            if self._job is arg and phase in RUNNING_PHASES:
                self._quick_stop(k, "aborted")
        elif what == "quick_stop":
            if phase in RUNNING_PHASES or phase == "enabling":
                self._quick_stop(k, "aborted")
        elif what == "enable":
            self._enter_enabling(k)
        elif what == "disable":
            self._finish_job("aborted")
            self._set_phase("disabling", k)

    def _handle_event(self, event: tuple[int, ...], k: int) -> None:
        kind, i, value = event
        node, name = self._node_ids[i], self._names[i]
        if kind == 3:
            if node not in self._bad_tpdo_warned:
                self._bad_tpdo_warned.add(node)
                log.warning(kv("bad_tpdo_length", node=node, axis=name, length=value, cycle=k))
            return
        if self._phase in ("enabling", "offline"):
            return
        if kind == 1 and value & 0xFF00:  # 0x00xx = error reset / no error (CiA 301)
            self._report(node, name, "emcy", value, k,
                         f"node {node} (axis {name}): EMCY 0x{value:04X}{_emcy_text(value)} at cycle {k}")
        elif kind == 2 and value != c.NmtState.OPERATIONAL:
            what = "boot-up: the drive restarted" if value == c.NmtState.BOOTUP else \
                f"NMT state {_nmt_name(value)} instead of OPERATIONAL"
            self._report(node, name, "heartbeat", value, k, f"node {node} (axis {name}): heartbeat reports {what} "
                         f"at cycle {k}")

    def _check_axes(self, k: int, running: bool) -> None:
        """Per axis: statusword bits, computed following error (running only), heartbeat."""
        now = time.perf_counter()
        for i in range(self._n):
            self._check_statusword(i, k, running)
            if running:
                self._check_following_error(i, k)
            if now - self._hb_time[i] > self._hb_timeout_s:
                node = self._node_ids[i]
                self._report(node, self._names[i], "heartbeat", -1, k,
                             f"node {node} (axis {self._names[i]}): no heartbeat for "
                             f"{(now - self._hb_time[i]) * 1000:.0f} ms (consumer time "
                             f"{self._hb_timeout_s * 1000:.0f} ms) at cycle {k}")
            elif running and k - self._fb_cycle[i] > max(self._fe_timeout_cycles[i] + 3,
                                                          self._hb_timeout_s / self._period_s):
                node = self._node_ids[i]  # alive but its feedback stopped: the following error is unknown
                self._report(node, self._names[i], "following_error", 0, k, f"node {node} (axis {self._names[i]}): "
                             f"no TPDO1 (position actual) for {k - self._fb_cycle[i]} cycles at cycle {k}")

    def _check_statusword(self, i: int, k: int, running: bool) -> None:
        """Following error bit 13, fault bit 3, and (running) leaving OPERATION ENABLED."""
        sw = self._fb_status[i] or 0
        node, name = self._node_ids[i], self._names[i]
        if sw & c.SW_FOLLOWING_ERROR:
            self._report(node, name, "following_error", self._fb_fe[i] or 0, k,
                         f"node {node} (axis {name}): drive reports following error (statusword bit 13)"
                         f" in {state_name(sw)} at cycle {k}")
        elif sw & c.SW_FAULT:
            code = self._last_emcy[i] or 0
            self._report(node, name, "fault_bit", code, k, f"node {node} (axis {name}): drive in {state_name(sw)} "
                         f"at cycle {k}{f' (last EMCY 0x{code:04X})' if code else ''}")
        elif running and sw & _OE_MASK != _OE_VALUE:
            self._report(node, name, "fault_bit", sw, k, f"node {node} (axis {name}): drive left OPERATION ENABLED, "
                         f"now {state_name(sw)} at cycle {k}")

    def _check_following_error(self, i: int, k: int) -> None:
        """|set-point in force at the answered SYNC - actual| > window for longer than the time-out.

        The TPDO answers the latest SYNC sent before its receive timestamp (so a lagging
        receive thread does not matter); the set-point in force at SYNC c was sent in cycle
        c-1. Servo lag: the nearest of the set-points of cycles c-1, c-2, c-3 counts. Each
        TPDO is judged once; one older than the set-point history is not judged (the drive's
        own check, statusword bit 13, still is)."""
        stamp = self._fb_time[i]
        if stamp == self._fe_checked_time[i]:
            return
        self._fe_checked_time[i] = stamp
        times, history = self._sync_time, self._sp_history
        answered = -1
        for c in range(k, k - _HISTORY + 3, -1):
            if 0.0 < times[c % _HISTORY] <= stamp:
                answered = c
                break
        if answered < _HISTORY:
            return
        actual = self._fb_pos[i]
        error = history[(answered - 1) % _HISTORY][i] - actual
        for back in (2, 3):
            e = history[(answered - back) % _HISTORY][i] - actual
            if abs(e) < abs(error):
                error = e
        if abs(error) <= self._fe_window[i]:
            self._fe_cycles[i] = 0
            return
        self._fe_cycles[i] += 1
        if self._fe_cycles[i] > self._fe_timeout_cycles[i]:
            node = self._node_ids[i]
            self._report(node, self._names[i], "following_error", error, k,
                         f"node {node} (axis {self._names[i]}): following error {error} counts exceeds the "
                         f"window {self._fe_window[i]} counts for {self._fe_cycles[i]} cycles at cycle {k}")

    def _check_enabling(self, k: int) -> None:
        ready = True
        for i in range(self._n):
            sw = self._fb_status[i]
            if sw is not None and is_ready(sw, self._ip[i]) and self._fb_cycle[i] > self._phase_cycle:
                continue
            ready = False
            if sw != self._since_status[i]:
                self._since_status[i], self._since_cycle[i] = sw, k
            elif k - self._since_cycle[i] > self._stuck_cycles or k - self._phase_cycle > \
                    self._enable_timeout_s / self._period_s:
                self._enable_failed(i, k)
                return
        if ready:
            self._hold[:] = self._sp
            self._set_phase("holding", k)
            self._ready.set()

    def _enable_failed(self, i: int, k: int) -> None:
        node, sw = self._node_ids[i], self._fb_status[i]
        state = c.state_of_statusword(sw) if sw is not None else None
        step = enable_step(state, 0, self._ip[i])[0]
        waited_ms = (k - self._since_cycle[i]) * self._period_s * 1000
        if self._fb_cycle[i] < 0:
            where = f"no TPDO1 received (last statusword by SDO: {state_name(sw)})"
        else:
            where = f"stuck in {state_name(sw)}"
        emcy = self._last_emcy[i]
        message = (f"node {node}: bring-up step '{step}': {where} after {waited_ms:.0f} ms"
                   f"{f' (last EMCY 0x{emcy:04X})' if emcy else ''}")
        self._enable_error = FieldbusError(message)
        self._faults.append(FaultReport(node, self._names[i], "bringup", sw or 0, k, message))
        self._reported.add((node, "bringup"))
        self._set_phase("quick_stop", k)
        self._ready.set()

    # ---------------------------------------------------------------- reactions
    def _report(self, node: int | None, axis: str | None, kind: str, code: int, k: int, message: str) -> None:
        """Record a fault once per (node, kind) until reset_faults(), then react."""
        if (node, kind) in self._reported:
            return
        self._reported.add((node, kind))
        report = FaultReport(node, axis, kind, code, k, message)
        self._faults.append(report)
        if self._job is not None:
            self._job.faults.append(report)
        log.warning(kv("fault", node=node, axis=axis, kind=kind, code=code, cycle=k, message=message))
        phase = self._phase
        if phase not in RUNNING_PHASES:
            return
        if kind in ("emcy", "heartbeat") and self._drives_follow(k):
            if phase == "streaming":
                self._start_controlled_stop(k, "faulted")
            return
        self._quick_stop(k, "faulted")

    def _drives_follow(self, k: int) -> bool:
        """Every drive enabled, without following error, and its TPDO1 fresh."""
        for i in range(self._n):
            sw = self._fb_status[i] or 0
            if sw & _OE_MASK != _OE_VALUE or sw & c.SW_FOLLOWING_ERROR or self._fe_cycles[i] \
                    or self._fb_cycle[i] < k - 3:
                return False
        return True

    def _start_controlled_stop(self, k: int, outcome: str) -> None:
        job = self._job
        assert job is not None
        job.outcome = outcome
        if job.index < 0:  # nothing of the job sent yet: keep holding
            self._set_phase("holding", k)
            self._finish_job(outcome)
            return
        job.ramp.start(job.playback_s, job.playback_r)  # from where and how fast it plays now
        job.ramp.dr = stop_slope(job.max_step, job.planned_accel, self._accel_limits, self._period_s,
                                 job.playback_r, job.ramp.dr)
        self._set_phase("stopping", k)

    def _quick_stop(self, k: int, outcome: str) -> None:
        self._set_phase("quick_stop", k)
        for i in range(self._n):  # what the drives report now belongs to the job's faults too
            self._check_statusword(i, k, running=False)
        self._finish_job(outcome)

    def _finish_job(self, outcome: str) -> None:
        job = self._job
        if job is None:
            return
        self._job = None
        self._release_gc()
        if outcome == "done" and job.faults:
            outcome = "faulted"
        job._finish(JobResult(outcome, job.index + 1, job.length, tuple(job.faults), self._stats.missed,
                              self._stats.late))


_EMCY_TEXT = {int(code): code.name.lower().replace("_", " ") for code in c.EmcyCode}


def _emcy_text(code: int) -> str:
    text = _EMCY_TEXT.get(code)
    return f" ({text})" if text else ""


def _nmt_name(state: int) -> str:
    try:
        return c.NmtState(state).name.replace("_", "-")
    except ValueError:
        return f"0x{state:02X}"


__all__ = ["Master", "Job"]
