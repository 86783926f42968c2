"""CANopen master: bring-up of CiA-402 drives and cyclic set-point streaming (the facade).

The parts, each testable alone:

- :mod:`~nurbsmotion.fieldbus.controller`: the pure per-cycle controller (phases as a
  transition table; controlwords and set-points of cycle k from the feedback and requests);
- :mod:`~nurbsmotion.fieldbus.playback`: one job's position, rate, override and stop ramp;
- :mod:`~nurbsmotion.fieldbus.supervisor`: fault checks and reactions (statusword, following
  error, heartbeat, EMCY, TPDO silence);
- :mod:`~nurbsmotion.fieldbus.writer` / :mod:`~nurbsmotion.fieldbus.bcm_queue`: the only code
  that puts SYNC and RPDOs on the bus, right after each deadline (virtual bus) or queued in
  the kernel ahead of time (SocketCAN);
- :mod:`~nurbsmotion.fieldbus.feedback`: the drives' answers, stored by canopen's notifier;
- bring-up by SDO/NMT (:mod:`~nurbsmotion.fieldbus.bringup` and the methods below).

One thread (the *cycle loop*) owns the cyclic traffic once the drives are configured. Each
iteration it learns the wire cycle c from the writer, lets the supervisor judge the feedback,
hands requests (API, fault reactions) to the controller, computes the commands of every
cycle up to the writer's horizon and commits them. Commands of cycle k go out after SYNC k
and take effect at SYNC k+1 (CiA 301). Requests change only cycles beyond c + guard (the
queued ones are rewritten from there: the controller state of each queued cycle is kept).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from pathlib import Path
from typing import Any, Callable

import can
import canopen
from can.interfaces.socketcan import SocketcanBus
import numpy as np

from nurbsmotion import cia402 as c
from nurbsmotion.arrival_clock import socket_pending
from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.bringup_plan import DrivePlan, Field, PdoFrame, plan_within_load, rpdo_packer
from nurbsmotion.fieldbus.busload import BusLoad, check_bus_load, config_bus_load
from nurbsmotion.fieldbus.cycle import LatenessStats
from nurbsmotion.fieldbus.cyclic_velocity import spindle_cyclic_velocity
from nurbsmotion.fieldbus.controller import MOVING_PHASES, CycleController, Phase
from nurbsmotion.fieldbus.drive_state import CW_QUICK_STOP, state_name
from nurbsmotion.fieldbus.feedback import Feedback
from nurbsmotion.fieldbus.heartbeat import MasterHeartbeat
from nurbsmotion.fieldbus.homing import HomingOutcome, HomingPlan, HomingProcedure
from nurbsmotion.fieldbus.homing_run import READY_TIMEOUT_S, HomingRun
from nurbsmotion.fieldbus.pdo import cycles_of_ms
from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.row_source import RowFeed
from nurbsmotion.fieldbus.reports import AxisStatus, CycleStats, FaultReport, JobResult, MasterStatus
from nurbsmotion.fieldbus.stop_ramp import ramp_slope
from nurbsmotion.fieldbus.supervisor import CycleHistory, Supervisor
from nurbsmotion.fieldbus.traffic import TrafficLog
from nurbsmotion.fieldbus.writer import CycleWriter, CyclicFrames, LoopWriter
from nurbsmotion.log import kv
from nurbsmotion.runtime import GC_MODES, GcQuiet, set_thread_realtime, thread_cpus, timer_threads_below
from nurbsmotion.socketcan_batch import BatchedSocketcanBus, BatchNotifier  # fewer system calls per cycle (its docstring)

log = logging.getLogger(__name__)

RUNNING_PHASES = ("holding", "streaming", "stopping", "pausing", "held")
HISTORY_CYCLES = 512  # cycles of commands kept: the kernel queue (<= 256) plus the following-error search
SYNC_SOURCES = ("auto", "loop", "kernel")
FeedbackSink = Callable[[int, int, int, int, float], None]  # see Master.record_feedback


class Job:
    """Handle of one streamed set-point sequence; every method is thread-safe."""

    def __init__(self, master: "Master", rows: Any, playback: Playback,
                 on_progress: Callable[[int, int], None] | None, progress_every: int,
                 feed: RowFeed | None = None) -> None:
        self._master = master
        self.rows = rows
        self.feed = feed  # a streamed job's rows (fieldbus.row_source), None: all given at the start
        self._length = rows.shape[0]
        self.playback = playback
        self.on_progress = on_progress
        self.progress_every = progress_every
        self.faults: list[FaultReport] = []
        self.start_cycle = -1  # master cycle that sends the job's first set-point (its cycle 0)
        self.finish_cycle = -1  # wire cycle at which the job's end has been sent (-1: not yet planned)
        self.outcome = ""
        self.released = False
        self._done = threading.Event()
        self._result: JobResult | None = None

    @property
    def index(self) -> int:
        """Index of the last planned set-point handed to the bus (queued included)."""
        return self.playback.index

    @property
    def length(self) -> int:
        """Planned rows: all of them, or for a streamed job those received so far."""
        return self.feed.planned_end if self.feed is not None else self._length

    @property
    def fell_behind_row(self) -> int:
        """A streamed job that ran onto a stop tail: its last planned row (-1: it did not)."""
        return self.feed.fell_behind_row if self.feed is not None else -1

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

    def hold(self) -> None:
        """Hold: decelerate along the path with the stop ramp, then wait (phase 'held') with
        the job alive; ignored unless streaming."""
        self._master._request("hold", self)

    def resume(self) -> None:
        """Continue a held job (or one paused at a pause row) from exactly where it rests."""
        self._master._request("resume", self)

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
    ``config.bus``. ``sync_source``: 'loop' (the cycle thread sends SYNC and RPDOs at each
    deadline), 'kernel' (SocketCAN only: SYNC and RPDOs of the coming cycles queued in the
    kernel's broadcast manager, fieldbus.bcm_queue), 'auto' (kernel on socketcan, else loop);
    None (default) takes ``config.bus.sync_source``. ``traffic_log``: file for every frame
    (.log candump, .asc ...). ``rt_priority`` (SCHED_FIFO of the cycle thread) and
    ``gc_mode`` (garbage collector during a job, runtime.GcQuiet) change the process: the
    daemon chooses them (service.link); the defaults change nothing.
    """

    def __init__(self, config: MachineConfig, bus: can.BusABC | None = None, *,
                 traffic_log: str | None = None, sync_source: str | None = None, check_load: bool = True,
                 bootup_timeout_s: float = 2.0, stuck_timeout_s: float = 0.5, enable_timeout_s: float = 5.0,
                 sdo_timeout_s: float = 0.5, spin_s: float = 60e-6, late_threshold_s: float | None = None,
                 progress_period_s: float = 0.05, rt_priority: int | None = None, gc_mode: str = "none") -> None:
        if sync_source is None:
            sync_source = config.bus.sync_source
        if sync_source not in SYNC_SOURCES:
            raise InputError("sync_source", f"must be auto, loop or kernel, got {sync_source!r}")
        if gc_mode not in GC_MODES:
            raise InputError("gc_mode", f"must be freeze, disable or none, got {gc_mode!r}")
        self._rt_priority = rt_priority
        self._receive_priority_set = False
        self._gc = GcQuiet(gc_mode)
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
        self._stuck_timeout_s = stuck_timeout_s
        self._sdo_timeout_s = sdo_timeout_s
        self._spin_s = spin_s
        self._late_threshold_s = late_threshold_s if late_threshold_s is not None else 0.1 * config.cycle_period_s
        self._period_s = config.cycle_period_s
        self._progress_every = cycles_of_ms(progress_period_s * 1000.0, self._period_s)
        self._network: canopen.Network | None = None
        self._extra_receive_ids: list[int] = []  # receive_from(): the spindle's and I/O node's frames

        axes = config.axes
        n = self._n = len(axes)
        self._names = [a.name for a in axes]
        self._node_ids = [a.node_id for a in axes]
        self._ip = [a.mode == "ip" for a in axes]
        self._fe_window = [int(w) for w in self.axis_map.following_error_window_counts()]
        self._accel_counts_s2 = self.axis_map.max_accel_counts_s2(config.interpolation.max_accel_mm_s2)
        self._rate_target = 1.0  # playback rate requested by set_rate (feed override)
        self._fb = Feedback(n)
        self._history = CycleHistory(HISTORY_CYCLES, n)
        self._snaps: list[tuple[Any, ...] | None] = [None] * HISTORY_CYCLES
        self._ctl = CycleController(n, self._ip, [float(a) for a in self._accel_counts_s2], self._period_s,
                                    cycles_of_ms(stuck_timeout_s * 1000.0, self._period_s),
                                    enable_timeout_s / self._period_s)
        self._supervisor = Supervisor(self._node_ids, self._names, self._fe_window,
                                      [cycles_of_ms(a.following_error_timeout_ms, self._period_s) for a in axes],
                                      config.monitoring.heartbeat_consumer_ms / 1000.0, self._period_s, self._fb,
                                      self._history)
        # each axis' bring-up plan from its EDS: refused here (one line per axis) before the bus is touched
        self.plans: list[DrivePlan] = plan_within_load(config, self._fe_window, check_load)
        self.following_error_tpdo = any(p.layout.has_following_error for p in self.plans)
        self._trails: list[bringup.SdoTrail] = []  # per axis after connect(): its SDO access, named in errors
        # the csv spindle's 0x60FF, sent with every SYNC after the axes' RPDOs (fieldbus.cyclic_velocity)
        self.cyclic_velocity = spindle_cyclic_velocity(config)
        extras = []
        if self.cyclic_velocity is not None:
            self.cyclic_velocity.notify = lambda: self._request("cyclic_velocity", None)
            self.cyclic_velocity.wire_cycle = lambda: self._cycle
            extras.append((self.cyclic_velocity.cob_id, self.cyclic_velocity.dlc, self.cyclic_velocity.pack))
        self._frames = CyclicFrames([(frame.cob_id, frame.dlc, i, rpdo_packer(frame))
                                     for i, plan in enumerate(self.plans) for frame in plan.layout.rpdos], extras)
        self._heartbeat: MasterHeartbeat | None = None
        self._heartbeat_cycle = -1  # the cycle the heartbeat watchdog saw last
        self._writer: CycleWriter | None = None
        self._bootup = bringup.BootupWatch(self._node_ids)
        self._cycle = 0
        self._horizon = 0  # last cycle whose commands are computed
        self._no_rewind_before = 0
        self._first_new = 1 << 62  # lowest cycle computed since the last commit
        self._job: Job | None = None
        self._requests: collections.deque[tuple[str, object]] = collections.deque()
        self._ready = threading.Event()
        self._enable_error: FieldbusError | None = None
        self._thread: threading.Thread | None = None
        self._quit = False
        self._stats_idle = LatenessStats(self._late_threshold_s)
        self._pending_reactions: list[tuple[str, Any]] = []
        self._homing_run: HomingRun | None = None

    # the feedback and controller lists bring-up reads and writes (by these names)
    @property
    def _fb_status(self) -> list[int | None]:
        return self._fb.status

    @property
    def _fb_pos(self) -> list[int]:
        return self._fb.pos

    @property
    def _hb_time(self) -> list[float]:
        return self._fb.hb_time

    @_hb_time.setter
    def _hb_time(self, times: list[float]) -> None:
        self._fb.hb_time[:] = times

    @property
    def _hold(self) -> list[int]:
        return self._ctl.hold

    @property
    def _sp(self) -> list[int]:
        return self._ctl.sp

    @property
    def _faults(self) -> list[FaultReport]:
        return self._supervisor.faults

    @property
    def _phase(self) -> str:
        return self._ctl.phase.value

    @property
    def network(self) -> canopen.Network | None:
        """The connected canopen Network (after connect()): other nodes (spindle, I/O) join it."""
        return self._network

    def receive_from(self, node_id: int, cob_ids: tuple[int, ...] = ()) -> None:
        """Also accept another node's EMCY, SDO answers, heartbeat and ``cob_ids`` (its TPDOs)
        when the kernel-queue receive filter is on (fieldbus.spindle, fieldbus.io)."""
        self._extra_receive_ids += [c.COB_EMCY + node_id, c.COB_SDO_TX + node_id, c.COB_HEARTBEAT + node_id, *cob_ids]
        self._filter_received()

    def judging_time_s(self) -> float:
        """Now on the frames' arrival timeline (perf_counter based, nurbsmotion.arrival_clock):
        what another node's heartbeat consumer judges on (fieldbus.io)."""
        return self._fb.judging_time_s()

    def quick_stop(self, reason: str) -> None:
        """Quick stop every axis now, with or without a job (then disabled, as an abort):
        the machine I/O's e-stop input (service.machine_io)."""
        self._request("quick_stop", reason)

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the bus (if not given), start canopen's notifier and the feedback callbacks."""
        if self._network is not None:
            return
        if self._bus is None:
            bus_cfg = self.config.bus
            try:
                self._bus = BatchedSocketcanBus(channel=bus_cfg.channel) if bus_cfg.interface == "socketcan" else \
                    can.Bus(interface=bus_cfg.interface, channel=bus_cfg.channel, bitrate=bus_cfg.bitrate)
            except (can.CanError, OSError, ValueError, ImportError) as err:
                raise FieldbusError(f"bus {bus_cfg.interface}:{bus_cfg.channel}: cannot open ({err})") from None
        network = canopen.Network(self._bus)
        self._traffic_log = TrafficLog(self._traffic_path)  # paused without a path
        network.listeners.append(self._traffic_log)
        read_time = (lambda bus=self._bus: bus.read_perf_s) if isinstance(self._bus, BatchedSocketcanBus) else None
        network.listeners.append(self._fb.watch_reception(socket_pending(self._bus), read_time))
        self._wrap_network_send(network, self._traffic_log)
        self._traffic = self._traffic_log if self._traffic_path else None
        # canopen's connect() with the bus given only starts python-can's Notifier; ours reads
        # a batch of frames per wake-up on SocketCAN (socketcan_batch: the per-cycle TPDOs)
        network.notifier = BatchNotifier(self._bus, network.listeners, network.NOTIFIER_CYCLE,
                                         on_thread_start=self._raise_receive_thread_priority)
        self._trails = []
        for i, (axis, plan) in enumerate(zip(self.config.axes, self.plans)):
            assert axis.od is not None  # loaded with the configuration
            node, trail = bringup.open_node(network, axis.node_id, axis.od, self._sdo_timeout_s, self._fb.judging_time_s)
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
        return self._fb.tpdo1_callback(i)

    def _tpdo2_callback(self, i: int) -> Callable[[int, bytearray, float], None]:
        return self._fb.tpdo2_callback(i)

    def _tpdo_callback(self, i: int, frame: PdoFrame) -> Callable[[int, bytearray, float], None]:
        """The decoder of one TPDO of axis i's layout (statusword + position, or split)."""
        if frame.fields == (Field.STATUSWORD, Field.POSITION):
            return self._tpdo1_callback(i)
        if frame.fields == (Field.FOLLOWING_ERROR,):
            return self._tpdo2_callback(i)
        return self._fb.split_tpdo_callback(i, frame.dlc, frame.fmt.unpack_from, frame.fields == (Field.STATUSWORD,))

    def _emcy_callback(self, i: int) -> Callable[[canopen.emcy.EmcyError], None]:
        return self._fb.emcy_callback(i)

    def _heartbeat_callback(self, i: int) -> Callable[[int, bytearray, float], None]:
        node_id = self._node_ids[i]
        return self._fb.heartbeat_callback(i, lambda state: self._bootup.heard(node_id, state))

    def _on_sync_seen(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC on the bus (the cycle writers keep their own account of the wire)."""

    def _raise_receive_thread_priority(self) -> None:
        """Run canopen's receive thread SCHED_FIFO just below the cycle thread: a normal-priority
        thread preempted while it holds the GIL would stall the cycle thread (priority inversion)."""
        if self._rt_priority is not None:
            set_thread_realtime(self._rt_priority - 1)

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
        if self.cyclic_velocity is not None:  # its RPDO goes out from the first SYNC: PRE-OPERATIONAL ignores
            self._network.send_message(c.COB_NMT,  # PDOs (CiA 301 §7.3.2.2) until its own bring-up starts it
                                       bytes([c.NmtCommand.PRE_OPERATIONAL, self.cyclic_velocity.node_id]))
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
                                          self._making_progress, thread_priority=None if self._rt_priority is None
                                          else self._rt_priority - 1)
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
            unwatched = next((s for s in plan.skipped if s.what == "0x1016:01"
                              and self.config.monitoring.master_heartbeat_ms), None)
            if unwatched is not None:  # an operator must know which drive keeps moving if the daemon dies
                log.warning(kv("master_heartbeat_unwatched", node=axis.node_id, axis=axis.name,
                               reason=unwatched.reason))
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
        if any(state != c.NmtState.OPERATIONAL for state in self._fb.hb_state) or \
                min(self._fb.cycle) < self._cycle - 3 or self._phase == "offline":
            # a drive restarted or went silent (power loss), or the queue stalled: the drives lost
            # their configuration or faulted, so bring every axis up again (or name the missing node)
            self.shutdown()
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
        self._request("rate", self._rate_target)

    def home(self, i: int, plan: HomingPlan, procedure: HomingProcedure) -> HomingOutcome:
        """Home axis i on its drive (CiA-402 mode 6, fieldbus.homing_run) while the others
        hold; blocks until the axis holds again. FieldbusError names axis, node and step."""
        if self._thread is None or self._job is not None or self._homing_run is not None:
            raise FieldbusError(f"home: the axes are not holding (phase {self._phase})")
        run = HomingRun(i, self._names[i], plan, procedure, self._trails[i], self._ip[i], self._request,
                        lambda: self._cycle, lambda: self._ctl.phase, lambda: self._fb.status[i], self._period_s,
                        ready_timeout_s=max(READY_TIMEOUT_S, self._stuck_timeout_s))
        self._homing_run = run
        self._supervisor.homing_axis = i
        try:
            return run.run()
        finally:
            self._supervisor.homing_axis = -1
            self._homing_run = None

    def stop_homing(self, quick: bool = False) -> None:
        """Stop a homing under way: its procedure ends (bit 4 low, the drive stops its search,
        then the streaming mode is restored), or with ``quick`` every axis is quick-stopped."""
        self._request(*(("quick_stop", "aborted") if quick else ("home_cancel", None)))

    def record_feedback(self, sink: FeedbackSink | None) -> None:
        """Hand every valid TPDO1 to ``sink(cycle, axis_index, statusword, position_counts,
        timestamp)`` (None: stop). Read-only: called on canopen's receive thread right after
        the master stored the values, so it must only append somewhere and return; ``cycle``
        is the master's cycle counter when the TPDO arrived (a job's cycle 0 is its
        ``start_cycle``), ``timestamp`` the frame's receive time."""
        self._fb.sink = sink

    def stream(self, counts: np.ndarray, on_progress: Callable[[int, int], None] | None = None,
               pauses: tuple[int, ...] = ()) -> Job:
        """Start streaming an (N, n_axes) int32 array of set-points, one row per cycle.

        The first row must be within each axis' following-error window of the held
        position (no jump at the start). ``on_progress(sent, length)`` is called from the
        cycle loop every ~50 ms and must return quickly. ``pauses``: rows (sorted) where the
        playback stops and holds (phase 'held') until :meth:`Job.resume`; the axes must be at
        rest there (the planner's exact stop before M0/M1/M6).
        """
        arr = np.asarray(counts)
        if arr.ndim != 2 or arr.shape[1] != self._n or arr.shape[0] < 1:
            raise InputError("set-points", f"expected an array of shape (N >= 1, {self._n}) of counts, "
                             f"got shape {arr.shape}")
        if not np.issubdtype(arr.dtype, np.integer):
            raise InputError("set-points", f"counts must be integers (int32), got dtype {arr.dtype}")
        if arr.size and (arr.min() < -(2**31) or arr.max() > 2**31 - 1):
            raise InputError("set-points", "counts outside the int32 range")
        self._check_can_stream()
        self._check_start_row(arr[0])
        # A 2-D memoryview: 8 bytes per set-point, read per cycle as rows[i, j] -> int
        # (nested lists would cost ~10x the memory for a long program).
        as_int64 = np.ascontiguousarray(arr, dtype=np.int64)
        rows = memoryview(as_int64)
        # per-axis figures for the stop slope, as plain floats for the cycle loop
        max_step = (np.abs(np.diff(as_int64, axis=0)).max(axis=0) if len(arr) > 1 else np.zeros(self._n))
        planned_accel = (np.abs(np.diff(as_int64, n=2, axis=0)).max(axis=0) if len(arr) > 2
                         else np.zeros(self._n)) / self._period_s**2
        playback = Playback(rows, ramp_slope(arr, self._accel_counts_s2, self._period_s), self._rate_target,
                            max_step.astype(float).tolist(), planned_accel.astype(float).tolist(),
                            tuple(sorted(int(p) for p in pauses)))
        job = Job(self, rows, playback, on_progress, self._progress_every)
        self._gc.quiet()
        self._request("job", job)
        return job

    def stream_feed(self, feed: RowFeed, on_progress: Callable[[int, int], None] | None = None) -> Job:
        """Start a job whose rows arrive over time (fieldbus.row_source): its first chunk must
        be queued already (and start within the following-error window of the held position);
        the producer keeps putting chunks while the job plays and closes the feed after the
        last. The stop ramp always has the newest chunk's stop tail to stop on; a job that
        runs onto it ends at rest there (``Job.fell_behind_row``). Program pauses come with
        the chunks. Other arguments as :meth:`stream`."""
        if feed.n_axes != self._n:
            raise InputError("set-points", f"expected rows of {self._n} axes, got {feed.n_axes}")
        self._check_can_stream()
        if feed.planned_end == 0:
            first = feed.take_first()
            if first is None or len(first.rows) == 0:
                raise InputError("set-points", "the streamed job has no first chunk of rows")
        else:
            first = None
        self._check_start_row(np.asarray(feed.buf[0]))
        step = list(first.max_step) if first is not None and first.max_step else [0.0] * self._n
        accel = list(first.max_accel) if first is not None and first.max_accel else [0.0] * self._n
        slope = 1.0  # ramp_slope of the first chunk's steps (lowered as larger steps arrive)
        for j in range(self._n):
            if step[j] > 0:
                slope = min(slope, float(self._accel_counts_s2[j]) * self._period_s**2 / step[j])
        playback = Playback(feed, slope, self._rate_target, step, accel,
                            tuple(first.pauses) if first is not None else (), feed=feed,
                            accel_limits=[float(a) for a in self._accel_counts_s2], period_s=self._period_s)
        job = Job(self, feed, playback, on_progress, self._progress_every, feed)
        self._gc.quiet()
        self._request("job", job)
        return job

    def _check_can_stream(self) -> None:
        if self._phase != "holding" or self._thread is None:
            raise FieldbusError(f"stream: the axes are not holding (phase {self._phase}); "
                                f"{'call reset_faults()' if self._thread is not None else 'call bring_up()'} first")
        # tuple(): copied in one C call; the cycle thread pops requests meanwhile (iterating the
        # deque itself raised 'deque mutated during iteration' in 1 of 50 demo runs under load)
        if self._job is not None or any(r[0] == "job" for r in tuple(self._requests)):
            raise FieldbusError("stream: a job is already running")
        if self._supervisor.reported:
            raise FieldbusError("stream: faults not acknowledged; call reset_faults() first")

    def _check_start_row(self, row: np.ndarray) -> None:
        """The first set-point is within each axis' following-error window of the held position."""
        hold = self._hold
        for j in range(self._n):
            if abs(int(row[j]) - hold[j]) > self._fe_window[j]:
                raise InputError("set-points", f"axis {self._names[j]}: the job starts at {int(row[j])} counts "
                                 f"but the axis holds {hold[j]} counts (more than the following-error window "
                                 f"{self._fe_window[j]} counts away)")

    def status(self) -> MasterStatus:
        """A consistent-enough snapshot (lists copied) for the daemon; any thread."""
        writer = self._writer
        stats = writer.stats if writer is not None else self._stats_idle
        fb, history = self._fb, self._history
        k = self._cycle
        sent = history.sp[k % history.size] if k else self._sp
        axes = []
        for i in range(self._n):
            sw = fb.status[i]
            fe = fb.fe[i]
            if fe is None and fb.cycle[i] >= 1:  # no TPDO2: the master's estimate
                fe = history.sp[(fb.cycle[i] - 1) % history.size][i] - fb.pos[i]
            axes.append(AxisStatus(self._names[i], self._node_ids[i], state_name(sw), sw, fb.pos[i],
                                   sent[i], fe, fb.bad_tpdo[i], fb.emcy_count[i], fb.last_emcy[i]))
        timing = CycleStats(stats.count, stats.late, stats.missed, stats.late_threshold_s, stats.percentile_s(0.5),
                            stats.percentile_s(0.99), stats.max_s, writer.send_errors if writer is not None else 0)
        job = self._job
        ctl_job = self._ctl.job
        pause = ctl_job.playback.pause_i if ctl_job is not None and self._ctl.phase is Phase.HELD \
            and ctl_job.playback.at_pause() else None
        return MasterStatus(self._phase, k, tuple(axes), timing, self._wire_index(job) if job else None,
                            job.length if job else None, tuple(self._faults), pause,
                            ctl_job.playback.r if ctl_job is not None else None)

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
        self._filter_received()

    def _filter_received(self) -> None:
        """With the kernel queue our own SYNC and RPDOs come back to our raw socket (the BCM is
        another socket): 4 frames a cycle of receive work for nothing. Accept only what the
        drives send (EMCY, TPDO1/2, SDO answers, heartbeat) unless the traffic is recorded."""
        if self._bus is None or not self._use_kernel_queue():
            return
        if self._traffic is not None:
            self._bus.set_filters(None)
            return
        ids = [base + node for node in self._node_ids for base in (c.COB_EMCY, c.COB_SDO_TX, c.COB_HEARTBEAT)]
        ids += [frame.cob_id for plan in self.plans for frame in plan.layout.tpdos] + self._extra_receive_ids
        self._bus.set_filters([{"can_id": can_id, "can_mask": 0x7FF, "extended": False} for can_id in ids])

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
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._stop_heartbeat()
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
        self._ctl.phase = Phase.OFFLINE

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def _request(self, what: str, arg: object) -> None:
        self._requests.append((what, arg))

    # ------------------------------------------------------------------ the cycle loop
    def _use_kernel_queue(self) -> bool:
        """'auto': any SocketCAN bus, python-can's or a subclass (the master's own is the
        batched one, nurbsmotion.socketcan_batch; comparing the class name sent the daemon on
        socketcan to the loop writer)."""
        if self._sync_source == "auto":
            return isinstance(self._bus, SocketcanBus)
        return self._sync_source == "kernel"

    def _make_writer(self) -> CycleWriter:
        assert self._bus is not None
        if self._use_kernel_queue():
            from nurbsmotion.fieldbus.bcm_queue import BcmQueueWriter

            channel = getattr(self._bus, "channel", None) or self.config.bus.channel
            return BcmQueueWriter(str(channel), self._frames, self._history, self._period_s, self._late_threshold_s,
                                  self._bus)
        return LoopWriter(self._bus, self._frames, self._history, self._period_s, self._spin_s,
                          self._late_threshold_s, self._log_cycle, self._on_send_error)

    def _start_loop(self) -> None:
        self._quit = False
        self._ready.clear()
        self._enable_error = None
        if self._writer is None:
            self._writer = self._make_writer()
            log.info(kv("cycle_writer", sync_source="kernel" if self._use_kernel_queue() else "loop",
                        writer=type(self._writer).__name__))
            if self._use_kernel_queue():
                self._warn_timer_threads_below()
        self._filter_received()
        self._supervisor.reset()
        self._ctl.handle("enable", None, 0, self._fb)
        self._thread = threading.Thread(target=self._run, name="nurbsmotion-cycle", daemon=True)
        self._thread.start()

    def _warn_timer_threads_below(self) -> None:
        """The kernel queue's SYNC leaves from the kernel's soft-timer threads when softirq
        work piles up; below our SCHED_FIFO threads they wait for them (runtime.py)."""
        below = timer_threads_below(self._rt_priority)
        if below:
            log.warning(kv("kernel_timers_below_cycle_thread", cycle_thread_priority=self._rt_priority,
                           threads=",".join(f"{t.name}:{t.policy}:{t.priority}" for t in below),
                           fix="; ".join(f"chrt -f -p {(self._rt_priority or 0) + 1} {t.pid}" for t in below),
                           why="SYNC can wait for the cycle thread: docs/fieldbus.md, 'The kernel's timer threads'"))

    def _run(self) -> None:
        writer = self._writer
        assert writer is not None
        policy = set_thread_realtime(self._rt_priority)
        log.info(kv("cycle_thread_priority", policy=policy, cpus=",".join(map(str, sorted(thread_cpus())))))
        k = 0
        try:
            self._cycle = self._horizon = self._fb.wire_cycle = self._no_rewind_before = 0
            self._plan(0, [])
            writer.start()
            writer.commit(0, self._horizon, self._take_first_new(), self._ctl.tail)
            while not self._quit:
                k = writer.next_cycle()
                self._cycle = self._fb.wire_cycle = k
                if writer.stalled():
                    self._on_stall(k)
                requests = list(self._drain_requests())
                phase = self._ctl.phase
                if any(what == "enable" for what, _ in requests):
                    self._supervisor.reset()  # faults acknowledged: report them again when they recur
                    phase = Phase.ENABLING
                requests += self._supervisor.check(k, phase, self._job)
                self._plan(k, requests)
                writer.commit(k, self._horizon, self._take_first_new(), self._ctl.tail)
                self._after_cycle(k)
            if self._job is not None:  # shutdown before its end reached the wire
                self._finish_job(self._job, self._job.outcome or "aborted")
        except Exception as err:  # pragma: no cover - a bug must still stop the axes
            log.exception("cycle loop failed")
            self._supervisor.report(None, None, "bus_error", 0, k, f"cycle loop failed at cycle {k}: {err!r}",
                                    Phase.DISABLED, self._job, [])
            self._emergency_quick_stop()
            self._finish_job(self._job, "faulted")
            self._ctl.phase = Phase.DISABLED
            self._ready.set()

    def _drain_requests(self) -> Any:
        requests = self._requests
        while requests:
            yield requests.popleft()

    def _plan(self, k: int, requests: list[tuple[str, Any]]) -> None:
        """Commands of every cycle up to the writer's horizon; requests act from k +
        change_guard + 1 on (queued cycles beyond that are computed again from the state kept
        for each; the kernel queue widens its change guard when the wire overtook a change)."""
        writer, ctl, fb, snaps = self._writer, self._ctl, self._fb, self._snaps
        assert writer is not None
        if any(what in ("abort", "quick_stop") for what, _ in requests):
            writer.quick_stop_now(k, [CW_QUICK_STOP] * self._n, list(fb.pos))
        if self._horizon < k + writer.guard:
            self._adopt_tail(k, k + writer.guard)
        first = k + writer.change_guard + 1
        velocity = any(what == "cyclic_velocity" for what, _ in requests)  # a new 0x60FF target: not the axes'
        if velocity:
            requests = [r for r in requests if r[0] != "cyclic_velocity"]
        if (requests or velocity) and self._horizon >= first:
            back = max(first - 1, self._no_rewind_before)
            snap = snaps[back % HISTORY_CYCLES]
            if back < self._horizon and snap is not None:
                ctl.restore(snap)
                self._horizon = back
        if velocity and self.cyclic_velocity is not None:  # from the first cycle packed again: no jump
            self.cyclic_velocity.apply(self._horizon + 1)
            self._first_new = min(self._first_new, self._horizon + 1)
        while True:
            if self._horizon >= writer.horizon(k, ctl.stop_cycles(), ctl.phase in MOVING_PHASES) and not requests:
                break
            self._step_next(requests)
            requests = []

    def _step_next(self, requests: list[tuple[str, Any]]) -> None:
        """Commands of the cycle after the horizon, kept with the controller state after them."""
        ctl = self._ctl
        h = self._horizon + 1
        self._first_new = min(self._first_new, h)
        cw, sp = ctl.step(h, self._fb, requests)
        self._history.store(h, cw, sp)
        self._snaps[h % HISTORY_CYCLES] = ctl.snapshot()
        self._horizon = h
        if ctl.notices:
            self._notices(h)

    def _adopt_tail(self, k: int, until: int) -> None:
        """The cycle thread came back after the kernel went past its horizon: the cycles up to
        ``until`` are (or may be) on the wire from the queue's tail. Compute them as the tail
        was (a controlled stop while moving, the last commands otherwise), so the controller
        continues from what the drives got; a stop that was not asked for is a 'stall' fault."""
        ctl = self._ctl
        requests: list[tuple[str, Any]] = []
        if ctl.phase is Phase.STREAMING:
            self._supervisor.report(None, None, "stall", self._horizon, k, f"stall: the cycle thread was away "
                                    f"past the queued set-points (cycle {self._horizon}, now {k}); the queue went on "
                                    f"with its controlled stop", ctl.phase, self._job, [])
            requests.append(("fault_stop", None))
        while self._horizon < until:
            self._step_next(requests)
            requests = []

    def _take_first_new(self) -> int:
        """Lowest cycle computed (or recomputed) since the last commit, then reset."""
        first, self._first_new = self._first_new, 1 << 62
        return first

    def _notices(self, h: int) -> None:
        notices = self._ctl.notices
        while notices:
            notice = notices.popleft()
            what = notice[0]
            if what == "phase":
                phase, cycle = notice[1], notice[2]
                log.info(kv("phase", phase=phase.value, cycle=cycle))
                self._no_rewind_before = cycle  # a rewind never undoes a phase change (bring-up, job start...)
                if phase is Phase.STREAMING:
                    # the job of the transition: a request later in the same step (the e-stop's
                    # quick stop, a disable) may have ended it and cleared the controller's
                    self._job = job = notice[3]
                    if job.start_cycle < 0:  # not on resume
                        job.start_cycle = cycle  # the step that starts streaming computes row 0
            elif what == "ready":
                self._ready.set()
            elif what == "enable_failed":
                i, cycle, stuck = notice[1], notice[2], notice[3]
                message = self._supervisor.enable_failed(i, cycle, self._ctl.since_cycle[i], self._ip[i],
                                                         None if stuck else self._enable_timeout_s)
                self._enable_error = FieldbusError(message)
                self._ready.set()
            elif what == "quick_stop":
                for i in range(self._n):  # what the drives report now belongs to the job's faults too
                    self._supervisor.check_statusword(i, self._cycle, False, Phase.QUICK_STOP, self._job, [])
            elif what == "refused":
                self._gc.release()
                job = notice[1]
                job._finish(JobResult("aborted", 0, job.length, (), 0, 0))
            elif what == "quit":
                self._quit = True
            elif what in ("homing_outcome", "home_refused") and self._homing_run is not None:
                if what == "homing_outcome":
                    self._no_rewind_before = notice[3]  # the outcome is final: never recomputed
                    self._homing_run.on_outcome(notice[2])
                else:
                    self._homing_run.on_refused(notice[2])

    def _after_cycle(self, k: int) -> None:
        """Finish the job whose end is on the wire; progress."""
        job = self._job
        if job is None:
            return
        if 0 <= job.finish_cycle <= k:
            self._finish_job(job, job.outcome)
        elif job.on_progress is not None and k % job.progress_every == 0:
            try:
                job.on_progress(self._wire_index(job) + 1, job.length)
            except Exception:  # a broken callback must not stop the machine
                log.exception("on_progress callback failed; it is not called again")
                job.on_progress = None

    def _wire_index(self, job: Job) -> int:
        """Index of the last planned row on the wire (the queue holds later ones)."""
        snap = self._snaps[self._cycle % HISTORY_CYCLES]
        if snap is not None and snap[2] is job:
            return int(snap[3][3])
        return job.index

    def _finish_job(self, job: Job | None, outcome: str) -> None:
        if job is None:
            return
        self._job = None
        self._ctl.release_job(job)
        self._gc.release()
        if outcome == "done" and job.faults:
            outcome = "faulted"
        stats = self._writer.stats if self._writer is not None else self._stats_idle
        job._finish(JobResult(outcome or "aborted", job.index + 1, job.length, tuple(job.faults), stats.missed,
                              stats.late))

    def _on_stall(self, k: int) -> None:
        """The kernel queue ran out (the cycle thread was held longer than the queue): the
        axes are at rest at the end of its stop; the drives see SYNC stop."""
        writer = self._writer
        assert writer is not None
        self._supervisor.report(None, None, "stall", 0, k, f"stall: the cycle thread did not renew the kernel queue "
                                f"in time; the queue ended in a stop at cycle {k} and SYNC stopped",
                                self._ctl.phase, self._job, [])
        self._ctl.handle("quick_stop", "faulted", k, self._fb)
        while self._ctl.notices:
            self._notices(k)
        self._horizon = k
        self._no_rewind_before = k
        writer.restart(k)

    def _log_cycle(self, msgs: list[can.Message]) -> None:
        traffic = self._traffic
        if traffic is not None:
            for msg in msgs:
                traffic.sent(msg)

    def _emergency_quick_stop(self) -> None:
        assert self._bus is not None
        for can_id, dlc, i, pack in self._frames.rpdos:
            try:
                data = bytearray(dlc)
                pack(data, CW_QUICK_STOP, self._sp[i])
                self._bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
            except (can.CanError, OSError):
                pass

    def _on_send_error(self, k: int, err: Exception) -> None:
        self._supervisor.report(None, None, "bus_error", 0, k, f"bus: sending the cyclic frames failed at cycle {k}: "
                                f"{err}", self._ctl.phase, self._job, self._pending_reactions)
        self._requests.extend(self._pending_reactions)
        self._pending_reactions.clear()


__all__ = ["Master", "Job"]
