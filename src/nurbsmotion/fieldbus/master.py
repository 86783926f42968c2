"""CANopen master: bring-up of CiA-402 drives and cyclic set-point streaming (the facade).

:class:`Master` keeps the connection, the bring-up and the public API; the parts, each
testable alone:

- :mod:`~nurbsmotion.fieldbus.connection`: the bus, canopen's Network, the receive thread,
  the traffic record;
- :mod:`~nurbsmotion.fieldbus.bringup`: NMT and SDO steps of bring-up, one drive at a time;
- :mod:`~nurbsmotion.fieldbus.cycle_loop`: the cycle thread (read, supervise, step, write;
  the horizon of queued cycles and their rewind);
- :mod:`~nurbsmotion.fieldbus.controller`: the pure per-cycle controller (phases as a
  transition table; controlwords and set-points of cycle k from the feedback and requests);
- :mod:`~nurbsmotion.fieldbus.job` / :mod:`~nurbsmotion.fieldbus.playback`: one job's
  handle, position, rate, override and stop ramp;
- :mod:`~nurbsmotion.fieldbus.supervisor`: fault checks and reactions (statusword, following
  error, heartbeat, EMCY, TPDO silence);
- :mod:`~nurbsmotion.fieldbus.writer` / :mod:`~nurbsmotion.fieldbus.bcm_queue`: the only code
  that puts SYNC and RPDOs on the bus, right after each deadline (virtual bus) or queued in
  the kernel ahead of time (SocketCAN);
- :mod:`~nurbsmotion.fieldbus.feedback`: the drives' answers, stored by canopen's notifier.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

import can
import canopen
import numpy as np

from nurbsmotion.can import cia402 as c
from nurbsmotion.axes import AxisMap
from nurbsmotion.config import SYNC_SOURCES, MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.bringup_plan import DrivePlan, plan_within_load, rpdo_packer
from nurbsmotion.fieldbus.busload import BusLoad, check_bus_load, config_bus_load
from nurbsmotion.fieldbus.controller import CycleController, Phase, Req, Request
from nurbsmotion.fieldbus.connection import BusConnection, send_quick_stop
from nurbsmotion.fieldbus.cycle_loop import HISTORY_CYCLES, CycleLoop
from nurbsmotion.fieldbus.cycle_slack import CycleSlack
from nurbsmotion.fieldbus.cyclic_velocity import spindle_cyclic_velocity
from nurbsmotion.fieldbus.drive_state import state_name
from nurbsmotion.fieldbus.feedback import Feedback
from nurbsmotion.fieldbus.heartbeat import MasterHeartbeat, started_heartbeat
from nurbsmotion.fieldbus.homing import HomingOutcome, HomingPlan, HomingProcedure
from nurbsmotion.fieldbus.homing_run import READY_TIMEOUT_S, HomingRun
from nurbsmotion.fieldbus.job import (Job, ProgressCallback, check_start_row, checked_rows, feed_playback,
                                      first_chunk_of, rows_playback)
from nurbsmotion.fieldbus.pdo import cycles_of_ms
from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.reports import AxisStatus, CycleStats, FaultReport, MasterStatus
from nurbsmotion.fieldbus.row_source import RowFeed
from nurbsmotion.fieldbus.supervisor import CycleHistory, Supervisor
from nurbsmotion.fieldbus.writer import CycleSlot, CycleWriter, CyclicFrames, LoopWriter, Retimed
from nurbsmotion.log import kv
from nurbsmotion.runtime import GC_MODES, GcQuiet, timer_threads_below

log = logging.getLogger(__name__)

FeedbackSink = Callable[[int, int, int, int, float], None]  # see Master.record_feedback
# a status read computes the lateness p50 and p99 anew at most once in this many cycles (0.5 s
# at T = 1 ms: the status publisher's whole reads follow every event; the two percentiles were
# most of a read's CPU, and a histogram of the whole run hardly moves in 500 cycles)
LATENESS_QUANTILES_EVERY_CYCLES = 500


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
        self.config = config
        self.axis_map = AxisMap.from_config(config)
        self.bus_load: BusLoad = check_bus_load(config) if check_load else config_bus_load(config)
        self._bootup_timeout_s = bootup_timeout_s
        self._enable_timeout_s = enable_timeout_s
        self._stuck_timeout_s = stuck_timeout_s
        self._spin_s = spin_s
        self._late_threshold_s = late_threshold_s if late_threshold_s is not None else 0.1 * config.cycle_period_s
        self._period_s = config.cycle_period_s
        self._progress_every = cycles_of_ms(progress_period_s * 1000.0, self._period_s)

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
        self._bootup = bringup.BootupWatch(self._node_ids)
        self._conn = BusConnection(config, self.plans, self._fb, self._bootup, bus, sync_source, traffic_log,
                                   sdo_timeout_s, rt_priority)
        self._gc = GcQuiet(gc_mode)
        # the csv spindle's 0x60FF, sent with every SYNC after the axes' RPDOs (fieldbus.cyclic_velocity)
        self.cyclic_velocity = spindle_cyclic_velocity(config)
        self._lateness_quantiles_s = (0.0, 0.0)  # p50, p99 of the last status read that computed them
        self._lateness_quantiles_count = -LATENESS_QUANTILES_EVERY_CYCLES  # the cycles counted then
        self._loop = CycleLoop(self._ctl, self._fb, self._history, self._supervisor, self._gc, enable_timeout_s,
                               self._late_threshold_s, self.cyclic_velocity,
                               lambda: send_quick_stop(self._conn.bus, self._frames.rpdos, self._ctl.sp))
        extras: list[CycleSlot] = []
        retimed: list[Retimed] = []
        if self.cyclic_velocity is not None:
            self.cyclic_velocity.notify = lambda: self._loop.request(Request(Req.CYCLIC_VELOCITY))
            self.cyclic_velocity.wire_cycle = lambda: self._loop.cycle
            extras.append((self.cyclic_velocity.cob_id, self.cyclic_velocity.dlc, self.cyclic_velocity.pack))
            retimed.append(self.cyclic_velocity)
        self._frames = CyclicFrames([(frame.cob_id, frame.dlc, i, rpdo_packer(frame))
                                     for i, plan in enumerate(self.plans) for frame in plan.layout.rpdos],
                                    extras, retimed)
        self._heartbeat: MasterHeartbeat | None = None
        self._writer: CycleWriter | None = None
        # perf_counter time the cycle thread wakes next, None while no cycle loop runs; any
        # thread (the status publisher keeps its steps out of the cycle's way: service.subscriptions)
        self.next_cycle_wake_s: Callable[[], float | None] = self._loop.next_wake_s
        # other threads' short steps, run by the cycle thread in its slack (fieldbus.cycle_slack)
        self.cycle_slack: CycleSlack = self._loop.slack

    @property
    def network(self) -> canopen.Network | None:
        """The connected canopen Network (after connect()): other nodes (spindle, I/O) join it."""
        return self._conn.network

    def receive_from(self, node_id: int, cob_ids: tuple[int, ...] = ()) -> None:
        """Also accept another node's EMCY, SDO answers, heartbeat and ``cob_ids`` (its TPDOs)
        when the kernel-queue receive filter is on (fieldbus.spindle, fieldbus.io)."""
        self._conn.receive_from(node_id, cob_ids)

    def judging_time_s(self) -> float:
        """Now on the frames' arrival timeline (perf_counter based, nurbsmotion.can.arrival_clock):
        what another node's heartbeat consumer judges on (fieldbus.io)."""
        return self._fb.judging_time_s()

    def quick_stop(self, reason: str) -> None:
        """Quick stop every axis now, with or without a job (then disabled, as an abort):
        the machine I/O's e-stop input (service.machine_io)."""
        self._loop.request(Request(Req.QUICK_STOP, reason))

    def connect(self) -> None:
        """Open the bus (if not given), start canopen's notifier and the feedback callbacks."""
        self._conn.open()

    # ------------------------------------------------------------------ bring-up
    def bring_up(self) -> None:
        """Reset, check, configure, start and enable every axis; FieldbusError names node and step."""
        self.connect()
        network = self._conn.network
        assert network is not None
        if self._loop.running:
            raise FieldbusError("bring-up: the cycle loop is already running (call shutdown() first)")
        if self._heartbeat is None:  # before any drive is told to consume it
            assert self._conn.bus is not None
            self._heartbeat = started_heartbeat(self._conn.bus, self.config.master.node_id,
                                                self.config.monitoring.master_heartbeat_ms,
                                                self._loop.making_progress, self._rt_priority)
        try:
            self._bring_up_by_sdo(network)
        except FieldbusError as err:
            err = self._bootup.twin_error() or err  # duplicate SDO answers make some step fail first: name the cause
            self._supervisor.faults.append(FaultReport(None, None, "bringup", 0, -1, str(err)))
            raise err from None
        for node_id in self._node_ids:
            network[node_id].nmt.send_command(c.NmtCommand.START)
        if self.cyclic_velocity is not None:  # its RPDO goes out from the first SYNC: PRE-OPERATIONAL ignores
            network.send_message(c.COB_NMT,  # PDOs (CiA 301 §7.3.2.2) until its own bring-up starts it
                                 bytes([c.NmtCommand.PRE_OPERATIONAL, self.cyclic_velocity.node_id]))
        self._fb.hb_time[:] = [time.perf_counter()] * self._n
        if self._writer is None:  # the cycle loop's writer, kept across bring-ups
            self._writer = self._make_writer()
            kernel = self._conn.kernel_queue()
            log.info(kv("cycle_writer", sync_source="kernel" if kernel else "loop", writer=type(self._writer).__name__))
            if kernel:
                self._warn_timer_threads_below()
        self._conn.filter_received()
        self._loop.start(self._writer, self._rt_priority)
        self._wait_enabled()

    def _bring_up_by_sdo(self, network: canopen.Network) -> None:
        bringup.reset_and_await_bootup(network, self._bootup, self.config.axes, self._bootup_timeout_s)
        for i, (axis, plan) in enumerate(zip(self.config.axes, self.plans)):
            position, statusword = bringup.set_up_drive(network, self._conn.trails[i], axis, plan,
                                                        bool(self.config.monitoring.master_heartbeat_ms))
            self._fb.pos[i], self._fb.status[i] = position, statusword
            self._ctl.hold[i] = self._ctl.sp[i] = position
        twin = self._bootup.twin_error()  # checked after the SDO steps, so a late twin's boot-up is seen too
        if twin is not None:
            raise twin
        if self._heartbeat is not None:  # CiA 301: a drive monitors from the first heartbeat it receives after
            time.sleep(1.5 * self._heartbeat.period_s)  # 0x1016 is written: let every drive hear one first

    def _wait_enabled(self) -> None:
        """Wait for the loop's state machine: every axis ready, or a named error."""
        if not self._loop.ready.wait(self._enable_timeout_s + 2.0):
            self._loop.request(Request(Req.QUICK_STOP))
            raise FieldbusError(f"bring-up: drives not enabled within {self._enable_timeout_s:.1f} s "
                                f"(states: {', '.join(f'node {a.node_id} {a.state}' for a in self.status().axes)})")
        if self._loop.enable_error is not None:
            raise self._loop.enable_error
        if self._ctl.phase is not Phase.HOLDING:
            raise FieldbusError(f"bring-up: the cycle loop stopped in phase {self._ctl.phase.value} (see the log)")

    def reset_faults(self) -> None:
        """Acknowledge faults and re-enable every axis (fault reset, state machine), then hold."""
        if not self._loop.running:
            if not self._supervisor.faults:
                raise FieldbusError("reset faults: the drives are not brought up (call bring_up())")
            self.bring_up()  # an earlier bring-up failed (e.g. a drive was still off): try it again
            return
        if self._loop.job is not None:
            raise FieldbusError("reset faults: a job is still running")
        if any(state != c.NmtState.OPERATIONAL for state in self._fb.hb_state) or \
                min(self._fb.cycle) < self._loop.cycle - 3 or self._ctl.phase is Phase.OFFLINE:
            # a drive restarted or went silent (power loss), or the queue stalled: the drives lost
            # their configuration or faulted, so bring every axis up again (or name the missing node)
            self.shutdown()
            self.bring_up()
            return
        self._loop.ready.clear()
        self._loop.enable_error = None
        self._loop.request(Request(Req.ENABLE))
        self._wait_enabled()

    # ------------------------------------------------------------------ streaming API
    def set_rate(self, rate: float) -> None:
        """Playback rate for the running and the next jobs (1.0 = as planned, 0 = pause). The
        running job's rate moves there by RATE_RAMP_SHARE of its stop slope per cycle; the
        caller keeps the rate within what the plan allows (service.rate)."""
        self._rate_target = max(0.0, float(rate))
        self._loop.request(Request(Req.RATE, self._rate_target))

    def home(self, i: int, plan: HomingPlan, procedure: HomingProcedure) -> HomingOutcome:
        """Home axis i on its drive (CiA-402 mode 6, fieldbus.homing_run) while the others
        hold; blocks until the axis holds again. FieldbusError names axis, node and step."""
        loop = self._loop
        if not loop.running or loop.job is not None or loop.homing_run is not None:
            raise FieldbusError(f"home: the axes are not holding (phase {self._ctl.phase.value})")
        run = HomingRun(i, self._names[i], plan, procedure, self._conn.trails[i], self._ip[i], loop.request,
                        lambda: loop.cycle, lambda: self._ctl.phase, lambda: self._fb.status[i], self._period_s,
                        ready_timeout_s=max(READY_TIMEOUT_S, self._stuck_timeout_s))
        loop.homing_run = run
        self._supervisor.homing_axis = i
        try:
            return run.run()
        finally:
            self._supervisor.homing_axis = -1
            loop.homing_run = None

    def stop_homing(self, quick: bool = False) -> None:
        """Stop a homing under way: its procedure ends (bit 4 low, the drive stops its search,
        then the streaming mode is restored), or with ``quick`` every axis is quick-stopped."""
        self._loop.request(Request(Req.QUICK_STOP, "aborted") if quick else Request(Req.HOME_CANCEL))

    def record_feedback(self, sink: FeedbackSink | None) -> None:
        """Hand every valid TPDO1 to ``sink(cycle, axis_index, statusword, position_counts,
        timestamp)`` (None: stop). Read-only: called on canopen's receive thread right after
        the master stored the values, so it must only append somewhere and return; ``cycle``
        is the master's cycle counter when the TPDO arrived (a job's cycle 0 is its
        ``start_cycle``), ``timestamp`` the frame's receive time."""
        self._fb.sink = sink

    def stream(self, counts: np.ndarray, on_progress: ProgressCallback | None = None,
               pauses: tuple[int, ...] = ()) -> Job:
        """Start streaming an (N, n_axes) int32 array of set-points, one row per cycle.

        The first row must be within each axis' following-error window of the held
        position (no jump at the start). ``on_progress(sent, length)`` is called from the
        cycle loop every ~50 ms and must return quickly. ``pauses``: rows (sorted) where the
        playback stops and holds (phase 'held') until :meth:`Job.resume`; the axes must be at
        rest there (the planner's exact stop before M0/M1/M6).
        """
        as_int64 = checked_rows(counts, self._n)
        self._loop.check_can_stream()
        check_start_row(as_int64[0], self._ctl.hold, self._fe_window, self._names)
        playback = rows_playback(as_int64, self._accel_counts_s2, self._period_s, self._rate_target, pauses)
        return self._start_job(playback.rows, playback, on_progress, None)

    def stream_feed(self, feed: RowFeed, on_progress: ProgressCallback | None = None) -> Job:
        """Start a job whose rows arrive over time (fieldbus.row_source): its first chunk must
        be queued already (and start within the following-error window of the held position);
        the producer keeps putting chunks while the job plays and closes the feed after the
        last. The stop ramp always has the newest chunk's stop tail to stop on; a job that
        runs onto it ends at rest there (``Job.fell_behind_row``). Program pauses come with
        the chunks. Other arguments as :meth:`stream`."""
        if feed.n_axes != self._n:
            raise InputError("set-points", f"expected rows of {self._n} axes, got {feed.n_axes}")
        self._loop.check_can_stream()
        first = first_chunk_of(feed)
        check_start_row(np.asarray(feed.buf[0]), self._ctl.hold, self._fe_window, self._names)
        playback = feed_playback(feed, first, self._accel_counts_s2, self._period_s, self._rate_target)
        return self._start_job(feed, playback, on_progress, feed)

    def _start_job(self, rows: object, playback: Playback, on_progress: ProgressCallback | None,
                   feed: RowFeed | None) -> Job:
        job = Job(self._loop.request, self.status, rows, playback, on_progress, self._progress_every, feed)
        self._gc.quiet()
        self._loop.request(Request(Req.JOB, job))
        return job

    def status(self, percentiles: bool = True) -> MasterStatus:
        """A consistent-enough snapshot (lists copied) for the daemon; any thread.
        The lateness p50 and p99 are computed anew when LATENESS_QUANTILES_EVERY_CYCLES cycles
        were counted since the last read that computed them (else they are that read's);
        ``percentiles`` False: never (the two are most of a read's CPU: the status publisher's
        reads between events take them from its whole reads, docs/web.md)."""
        writer = self._writer
        stats = self._loop.stats()
        fb, history = self._fb, self._history
        k = self._loop.cycle
        sent = history.sp[k % history.size] if k else self._ctl.sp
        axes = []
        for i in range(self._n):
            sw = fb.status[i]
            fe = fb.fe[i]
            if fe is None and fb.cycle[i] >= 1:  # no TPDO2: the master's estimate
                fe = history.sp[(fb.cycle[i] - 1) % history.size][i] - fb.pos[i]
            axes.append(AxisStatus(self._names[i], self._node_ids[i], state_name(sw), sw, fb.pos[i],
                                   sent[i], fe, fb.bad_tpdo[i], fb.emcy_count[i], fb.last_emcy[i]))
        if percentiles and not 0 <= stats.count - self._lateness_quantiles_count < LATENESS_QUANTILES_EVERY_CYCLES:
            self._lateness_quantiles_s = (stats.percentile_s(0.5), stats.percentile_s(0.99))
            self._lateness_quantiles_count = stats.count  # a new writer's stats count from 0 again
        p50_s, p99_s = self._lateness_quantiles_s
        timing = CycleStats(stats.count, stats.late, stats.missed, stats.late_threshold_s, p50_s, p99_s, stats.max_s,
                            writer.send_errors if writer is not None else 0)
        job = self._loop.job
        ctl_job = self._ctl.job
        pause = ctl_job.playback.pause_i if ctl_job is not None and self._ctl.phase is Phase.HELD \
            and ctl_job.playback.at_pause() else None
        return MasterStatus(self._ctl.phase.value, k, tuple(axes), timing,
                            self._loop.wire_index(job) if job else None, job.length if job else None,
                            tuple(self._supervisor.faults), pause, ctl_job.playback.r if ctl_job is not None else None)

    def faults(self) -> list[FaultReport]:
        return list(self._supervisor.faults)

    def record_traffic(self, path: str | Path | None) -> None:
        """Record every frame into ``path`` from now on (candump .log, .asc, ... by extension),
        closing the previous file; None stops recording. Used for one traffic log per job."""
        self._conn.record_traffic(path)

    def shutdown(self, timeout_s: float = 5.0) -> None:
        """Controlled stop of a running job, disable the drives, NMT stop, close (if ours)."""
        self._loop.stop(timeout_s)
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._heartbeat is not None:
            self._heartbeat.stop()
            self._heartbeat = None
        self._conn.close()
        self._ctl.phase = Phase.OFFLINE

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # ------------------------------------------------------------------ the cycle loop's writer
    def _make_writer(self) -> CycleWriter:
        bus = self._conn.bus
        assert bus is not None
        if self._conn.kernel_queue():
            from nurbsmotion.fieldbus.bcm_queue import BcmQueueWriter

            channel = getattr(bus, "channel", None) or self.config.bus.channel
            return BcmQueueWriter(str(channel), self._frames, self._history, self._period_s, self._late_threshold_s,
                                  bus)
        return LoopWriter(bus, self._frames, self._history, self._period_s, self._spin_s,
                          self._late_threshold_s, self._conn.log_cycle, self._loop.on_send_error)

    def _warn_timer_threads_below(self) -> None:
        """The kernel queue's SYNC leaves from the kernel's soft-timer threads when softirq
        work piles up; below our SCHED_FIFO threads they wait for them (runtime.py)."""
        below = timer_threads_below(self._rt_priority)
        if below:
            log.warning(kv("kernel_timers_below_cycle_thread", cycle_thread_priority=self._rt_priority,
                           threads=",".join(f"{t.name}:{t.policy}:{t.priority}" for t in below),
                           fix="; ".join(f"chrt -f -p {(self._rt_priority or 0) + 1} {t.pid}" for t in below),
                           why="SYNC can wait for the cycle thread: docs/fieldbus.md, 'The kernel's timer threads'"))


__all__ = ["Master", "Job"]
