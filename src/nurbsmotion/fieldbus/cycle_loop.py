"""The cycle loop: the one thread that owns the cyclic traffic once the drives are configured.

Each iteration (as LinuxCNC's motion controller: read, supervise, step, write) it learns the
wire cycle k from the writer, lets the supervisor judge the drives' answers, hands the
requests (API, fault reactions) to the controller, computes the commands of every cycle up
to the writer's horizon and commits them. Commands of cycle k go out after SYNC k and take
effect at SYNC k+1 (CiA 301).

The writer may hold many cycles queued (the kernel queue, fieldbus.bcm_queue): a request
changes only cycles beyond k + the writer's change guard; the queued cycles after that are
computed again from the controller state kept for each (the *rewind*). A phase change is
never rewound. The controller's notices (fieldbus.controller: phase changes, ready, refused
jobs, homing outcomes) are acted on here: jobs start and finish, bring-up is woken. After
each commit it runs other threads' short steps while its next wake-up is far enough away
(fieldbus.cycle_slack: the status publisher's rounds).
"""

from __future__ import annotations

import collections
import logging
import threading
from typing import Any, Callable, Iterator

from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.controller import (MOVING_PHASES, CycleController, EnableFailed, HomeRefused, HomingEnded,
                                             Notice, PhaseChanged, Quit, QuickStopped, Ready, Refused, Req, Request,
                                             Phase)
from nurbsmotion.fieldbus.cycle import LatenessStats
from nurbsmotion.fieldbus.cycle_slack import CycleSlack
from nurbsmotion.fieldbus.cyclic_velocity import CyclicVelocity
from nurbsmotion.fieldbus.drive_state import CW_QUICK_STOP
from nurbsmotion.fieldbus.feedback import Feedback
from nurbsmotion.fieldbus.homing_run import HomingRun
from nurbsmotion.fieldbus.job import Job
from nurbsmotion.fieldbus.reports import JobResult
from nurbsmotion.fieldbus.supervisor import CycleHistory, Supervisor
from nurbsmotion.fieldbus.writer import CycleWriter
from nurbsmotion.log import kv
from nurbsmotion.runtime import GcQuiet, set_thread_realtime, thread_cpus

log = logging.getLogger(__name__)

HISTORY_CYCLES = 512  # cycles of commands kept: the kernel queue (<= 256) plus the following-error search
NOTHING_NEW = 1 << 62  # no cycle computed since the last commit


class CycleLoop:
    """The cycle thread and the state it keeps (module docstring); ``request`` is thread-safe."""

    def __init__(self, ctl: CycleController, fb: Feedback, history: CycleHistory, supervisor: Supervisor,
                 gc: GcQuiet, enable_timeout_s: float, late_threshold_s: float,
                 cyclic_velocity: CyclicVelocity | None, emergency_stop: Callable[[], None]) -> None:
        """``emergency_stop``: sends the quick-stop controlword directly when the loop fails."""
        self.ctl = ctl
        self.fb = fb
        self.history = history
        self.supervisor = supervisor
        self.gc = gc
        self.enable_timeout_s = enable_timeout_s
        self.cyclic_velocity = cyclic_velocity
        self.emergency_stop = emergency_stop
        self.writer: CycleWriter | None = None
        self.requests: collections.deque[Request] = collections.deque()
        self.job: Job | None = None
        self.cycle = 0  # the wire cycle
        self.horizon = 0  # last cycle whose commands are computed
        self.homing_run: HomingRun | None = None  # set by Master.home while a homing runs
        self.ready = threading.Event()
        self.enable_error: FieldbusError | None = None
        self.stats_idle = LatenessStats(late_threshold_s)
        self._no_rewind_before = 0
        self._first_new = NOTHING_NEW  # lowest cycle computed since the last commit
        self._snaps: list[tuple[Any, ...] | None] = [None] * HISTORY_CYCLES
        self._pending_reactions: list[Request] = []
        self._thread: threading.Thread | None = None
        self._quit = False
        self._rt_priority: int | None = None
        self._heartbeat_cycle = -1  # the cycle the heartbeat watchdog saw last
        self.slack = CycleSlack()  # other threads' short steps, run after a cycle's commit (fieldbus.cycle_slack)

    # ------------------------------------------------------------------ from other threads
    @property
    def running(self) -> bool:
        return self._thread is not None

    def request(self, request: Request) -> None:
        self.requests.append(request)

    def start(self, writer: CycleWriter, rt_priority: int | None) -> None:
        """Enable the drives and run the loop on its own thread with ``writer``."""
        self.writer = writer
        self._rt_priority = rt_priority
        self._quit = False
        self.ready.clear()
        self.enable_error = None
        self.supervisor.reset()
        self.ctl.handle(Request(Req.ENABLE), 0, self.fb)
        self._thread = threading.Thread(target=self._run, name="nurbsmotion-cycle", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float) -> None:
        """Controlled stop of a running job, the drives disabled, the thread ended."""
        if self._thread is None:
            return
        job = self.job
        if job is not None:
            job.request_stop()
            job.wait(timeout_s)
        self.request(Request(Req.DISABLE))
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            self._quit = True
            self._thread.join(1.0)
        self._thread = None

    def next_wake_s(self) -> float | None:
        """``time.perf_counter`` time this thread wakes next, None while it does not run."""
        writer = self.writer
        return writer.next_wake_s() if writer is not None and self._thread is not None else None

    def stats(self) -> LatenessStats:
        return self.writer.stats if self.writer is not None else self.stats_idle

    def check_can_stream(self) -> None:
        """FieldbusError unless a new job may start: the axes hold, no job, faults acknowledged."""
        phase = self.ctl.phase.value
        if self.ctl.phase is not Phase.HOLDING or self._thread is None:
            raise FieldbusError(f"stream: the axes are not holding (phase {phase}); "
                                f"{'call reset_faults()' if self._thread is not None else 'call bring_up()'} first")
        # tuple(): copied in one C call; the cycle thread pops requests meanwhile (iterating the
        # deque itself raised 'deque mutated during iteration' in 1 of 50 demo runs under load)
        if self.job is not None or any(r.kind is Req.JOB for r in tuple(self.requests)):
            raise FieldbusError("stream: a job is already running")
        if self.supervisor.reported:
            raise FieldbusError("stream: faults not acknowledged; call reset_faults() first")

    def making_progress(self) -> bool:
        """For the master heartbeat's watchdog: no cycle loop yet (bring-up), or it advanced."""
        k = self.cycle
        moved = self._thread is None or k != self._heartbeat_cycle
        self._heartbeat_cycle = k
        return moved

    def wire_index(self, job: Job) -> int:
        """Index of the last planned row on the wire (the queue holds later ones)."""
        snap = self._snaps[self.cycle % HISTORY_CYCLES]
        if snap is not None and snap[2] is job:
            return int(snap[3][3])
        return job.index

    def on_send_error(self, k: int, err: Exception) -> None:
        """The loop writer could not send cycle k's frames (a bus error fault)."""
        self.supervisor.report(None, None, "bus_error", 0, k, f"bus: sending the cyclic frames failed at cycle {k}: "
                               f"{err}", self.ctl.phase, self.job, self._pending_reactions)
        self.requests.extend(self._pending_reactions)
        self._pending_reactions.clear()

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        writer = self.writer
        assert writer is not None
        policy = set_thread_realtime(self._rt_priority)
        log.info(kv("cycle_thread_priority", policy=policy, cpus=",".join(map(str, sorted(thread_cpus())))))
        k = 0
        try:
            self.cycle = self.horizon = self.fb.wire_cycle = self._no_rewind_before = 0
            self._plan(0, [])
            writer.start()
            writer.commit(0, self.horizon, self._take_first_new(), self.ctl.tail)
            self.slack.start()
            while not self._quit:
                k = writer.next_cycle()
                self.cycle = self.fb.wire_cycle = k
                if writer.stalled():
                    self._on_stall(k)
                requests = list(self._drain_requests())
                phase = self.ctl.phase
                if any(r.kind is Req.ENABLE for r in requests):
                    self.supervisor.reset()  # faults acknowledged: report them again when they recur
                    phase = Phase.ENABLING
                requests += self.supervisor.check(k, phase, self.job)
                self._plan(k, requests)
                writer.commit(k, self.horizon, self._take_first_new(), self.ctl.tail)
                self._after_cycle(k)
                self.slack.run(writer.next_wake_s())
            self.slack.stop()
            if self.job is not None:  # shutdown before its end reached the wire
                self._finish_job(self.job, self.job.outcome or "aborted")
        except Exception as err:  # pragma: no cover - a bug must still stop the axes
            log.exception("cycle loop failed")
            self.slack.stop()
            self.supervisor.report(None, None, "bus_error", 0, k, f"cycle loop failed at cycle {k}: {err!r}",
                                   Phase.DISABLED, self.job, [])
            self.emergency_stop()
            self._finish_job(self.job, "faulted")
            self.ctl.phase = Phase.DISABLED
            self.ready.set()

    def _drain_requests(self) -> Iterator[Request]:
        requests = self.requests
        while requests:
            yield requests.popleft()

    def _plan(self, k: int, requests: list[Request]) -> None:
        """Commands of every cycle up to the writer's horizon; requests act from k +
        change_guard + 1 on (queued cycles beyond that are computed again from the state kept
        for each; the kernel queue widens its change guard when the wire overtook a change)."""
        writer, ctl, fb = self.writer, self.ctl, self.fb
        assert writer is not None
        if any(r.kind is Req.ABORT or r.kind is Req.QUICK_STOP for r in requests):
            writer.quick_stop_now(k, [CW_QUICK_STOP] * ctl.n, list(fb.pos))
        if self.horizon < k + writer.guard:
            self._adopt_tail(k, k + writer.guard)
        velocity = any(r.kind is Req.CYCLIC_VELOCITY for r in requests)  # a new 0x60FF target: not the axes'
        if velocity:
            requests = [r for r in requests if r.kind is not Req.CYCLIC_VELOCITY]
        if requests or velocity:
            self._rewind(k + writer.change_guard + 1)
        if velocity and self.cyclic_velocity is not None:  # from the first cycle packed again: no jump
            self.cyclic_velocity.apply(self.horizon + 1)
            self._first_new = min(self._first_new, self.horizon + 1)
        while True:
            if self.horizon >= writer.horizon(k, ctl.stop_cycles(), ctl.phase in MOVING_PHASES) and not requests:
                break
            self._step_next(requests)
            requests = []

    def _rewind(self, first: int) -> None:
        """Back to the controller state after cycle ``first`` - 1 (or the last phase change),
        so requests act from ``first`` on."""
        if self.horizon < first:
            return
        back = max(first - 1, self._no_rewind_before)
        snap = self._snaps[back % HISTORY_CYCLES]
        if back < self.horizon and snap is not None:
            self.ctl.restore(snap)
            self.horizon = back

    def _step_next(self, requests: list[Request]) -> None:
        """Commands of the cycle after the horizon, kept with the controller state after them."""
        ctl = self.ctl
        h = self.horizon + 1
        self._first_new = min(self._first_new, h)
        cw, sp = ctl.step(h, self.fb, requests)
        self.history.store(h, cw, sp)
        self._snaps[h % HISTORY_CYCLES] = ctl.snapshot()
        self.horizon = h
        if ctl.notices:
            self._act_on_notices()

    def _adopt_tail(self, k: int, until: int) -> None:
        """The cycle thread came back after the kernel went past its horizon: the cycles up to
        ``until`` are (or may be) on the wire from the queue's tail. Compute them as the tail
        was (a controlled stop while moving, the last commands otherwise), so the controller
        continues from what the drives got; a stop that was not asked for is a 'stall' fault."""
        ctl = self.ctl
        requests: list[Request] = []
        if ctl.phase is Phase.STREAMING:
            self.supervisor.report(None, None, "stall", self.horizon, k, f"stall: the cycle thread was away "
                                   f"past the queued set-points (cycle {self.horizon}, now {k}); the queue went on "
                                   f"with its controlled stop", ctl.phase, self.job, [])
            requests.append(Request(Req.FAULT_STOP))
        while self.horizon < until:
            self._step_next(requests)
            requests = []

    def _take_first_new(self) -> int:
        """Lowest cycle computed (or recomputed) since the last commit, then reset."""
        first, self._first_new = self._first_new, NOTHING_NEW
        return first

    def _on_stall(self, k: int) -> None:
        """The kernel queue ran out (the cycle thread was held longer than the queue): the
        axes are at rest at the end of its stop; the drives see SYNC stop."""
        writer = self.writer
        assert writer is not None
        self.supervisor.report(None, None, "stall", 0, k, f"stall: the cycle thread did not renew the kernel queue "
                               f"in time; the queue ended in a stop at cycle {k} and SYNC stopped",
                               self.ctl.phase, self.job, [])
        self.ctl.handle(Request(Req.QUICK_STOP, "faulted"), k, self.fb)
        self._act_on_notices()
        self.horizon = k
        self._no_rewind_before = k
        writer.restart(k)

    # ------------------------------------------------------------------ the controller's notices
    def _act_on_notices(self) -> None:
        notices = self.ctl.notices
        while notices:
            self._act_on(notices.popleft())

    def _act_on(self, notice: Notice) -> None:
        if isinstance(notice, PhaseChanged):
            self._on_phase(notice)
        elif isinstance(notice, Ready):
            self.ready.set()
        elif isinstance(notice, EnableFailed):
            message = self.supervisor.enable_failed(notice.axis, notice.cycle, self.ctl.since_cycle[notice.axis],
                                                    self.ctl.ip[notice.axis],
                                                    None if notice.stuck else self.enable_timeout_s)
            self.enable_error = FieldbusError(message)
            self.ready.set()
        elif isinstance(notice, QuickStopped):
            for i in range(self.ctl.n):  # what the drives report now belongs to the job's faults too
                self.supervisor.check_statusword(i, self.cycle, False, Phase.QUICK_STOP, self.job, [])
        elif isinstance(notice, Refused):
            self.gc.release()
            notice.job.finish(JobResult("aborted", 0, notice.job.length, (), 0, 0))
        elif isinstance(notice, Quit):
            self._quit = True
        elif isinstance(notice, HomingEnded) and self.homing_run is not None:
            self._no_rewind_before = notice.cycle  # the outcome is final: never recomputed
            self.homing_run.on_outcome(notice.outcome)
        elif isinstance(notice, HomeRefused) and self.homing_run is not None:
            self.homing_run.on_refused(notice.phase)

    def _on_phase(self, notice: PhaseChanged) -> None:
        log.info(kv("phase", phase=notice.phase.value, cycle=notice.cycle))
        self._no_rewind_before = notice.cycle  # a rewind never undoes a phase change (bring-up, job start...)
        if notice.phase is Phase.STREAMING:
            # the job of the transition: a request later in the same step (the e-stop's
            # quick stop, a disable) may have ended it and cleared the controller's
            self.job = job = notice.job
            if job.start_cycle < 0:  # not on resume
                job.start_cycle = notice.cycle  # the step that starts streaming computes row 0

    # ------------------------------------------------------------------ a job's end and progress
    def _after_cycle(self, k: int) -> None:
        """Finish the job whose end is on the wire; progress."""
        job = self.job
        if job is None:
            return
        if 0 <= job.finish_cycle <= k:
            self._finish_job(job, job.outcome)
        elif job.on_progress is not None and k % job.progress_every == 0:
            try:
                job.on_progress(self.wire_index(job) + 1, job.length)
            except Exception:  # a broken callback must not stop the machine
                log.exception("on_progress callback failed; it is not called again")
                job.on_progress = None

    def _finish_job(self, job: Job | None, outcome: str) -> None:
        if job is None:
            return
        self.job = None
        self.ctl.release_job(job)
        self.gc.release()
        if outcome == "done" and job.faults:
            outcome = "faulted"
        stats = self.stats()
        job.finish(JobResult(outcome or "aborted", job.index + 1, job.length, tuple(job.faults), stats.missed,
                             stats.late))
