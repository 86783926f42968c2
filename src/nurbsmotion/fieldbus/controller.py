"""The master's per-cycle controller: phase, controlwords and set-points of one cycle.

``CycleController.step(cycle, feedback, requests)`` computes the commands (one controlword
and one set-point per axis) of cycle k, to be sent after SYNC k and applied by the drives at
SYNC k+1 (CiA 301). It touches no bus and no clock: the cycle writer decides when the
commands go out (right after SYNC k, or queued in the kernel many cycles ahead), the
supervisor judges the drives' answers and turns faults into requests. Phases and their
transitions are one table (:data:`TRANSITIONS`), as in sim/statemachine.py:

enabling (CiA-402 state machine towards OPERATION ENABLED, target = actual position) ->
holding (re-send the held position) <-> streaming (the job's rows at the playback rate) ->
stopping (controlled stop on the path) / quick_stop (quick-stop controlword) -> disabled;
disabling at shutdown. A job can be held: streaming -> pausing (the stop ramp) -> held (the
job stays, the position is re-sent) -> streaming on resume; a program pause row goes from
streaming to held directly (the plan is at rest there). Homing one axis (fieldbus.homing,
driven by fieldbus.homing_run): holding -> homing (that axis gets bit 4 low, then the
homing procedure's controlword each cycle while its set-point follows its position actual,
then a fixed hold target; the other axes keep holding) -> holding.
"""

from __future__ import annotations

import collections
import enum
from dataclasses import dataclass
from typing import Any, Protocol, Sequence, Union

from nurbsmotion.can import cia402 as c
from nurbsmotion.fieldbus.drive_state import (CW_DISABLE_VOLTAGE, CW_ENABLED, CW_QUICK_STOP, CW_SHUTDOWN, enable_step,
                                              is_ready, running_controlword)
from nurbsmotion.fieldbus.homing import HomingOutcome, HomingProcedure
from nurbsmotion.fieldbus.playback import Playback, PlaybackState

OE_MASK, OE_VALUE = 0x6F, 0x27  # statusword coding of OPERATION ENABLED
QS_VALUE = 0x07  # QUICK STOP ACTIVE under the same mask


class Phase(enum.Enum):
    OFFLINE = "offline"
    ENABLING = "enabling"
    HOLDING = "holding"
    STREAMING = "streaming"
    STOPPING = "stopping"
    QUICK_STOP = "quick_stop"
    DISABLED = "disabled"
    DISABLING = "disabling"
    PAUSING = "pausing"  # a hold's stop ramp; the job stays
    HELD = "held"  # a job held (hold request or program pause), waiting for resume
    HOMING = "homing"  # one axis homes (mode 6) or changes mode around it; the others hold


RUNNING_PHASES = frozenset((Phase.HOLDING, Phase.STREAMING, Phase.STOPPING, Phase.PAUSING, Phase.HELD, Phase.HOMING))
MOVING_PHASES = frozenset((Phase.STREAMING, Phase.STOPPING, Phase.PAUSING))


class Event(enum.Enum):
    ENABLE = "enable"  # bring-up or reset_faults
    READY = "ready"  # every axis follows set-points
    ENABLE_FAILED = "enable failed"  # an axis stuck on its way to OPERATION ENABLED
    JOB = "job"
    LAST_ROW = "last row"  # the job's last planned row handed out
    STOP = "stop"  # controlled stop requested (stop, or a fault while the drives follow)
    AT_REST = "at rest"  # the stop ramp reached rate 0 (or nothing of the job was sent)
    QUICK_STOP = "quick stop"  # abort, or a fault the drives may not follow through
    DRIVES_STOPPED = "drives stopped"  # every axis left OPERATION ENABLED / QUICK STOP ACTIVE
    DISABLE = "disable"  # shutdown
    HOLD = "hold"  # hold the job: ramp to rest on the path, keep it
    PAUSE_ROW = "pause row"  # a program pause row (M0/M1/M6) handed out
    RESUME = "resume"
    HOME = "home"  # home one axis (from holding)
    HOME_END = "home end"  # the homed axis follows set-points again


class Req(enum.Enum):
    """What the API, the supervisor and a homing run ask of the controller (its ``arg``)."""

    JOB = "job"  # start streaming the job (arg: the job)
    STOP = "stop"  # controlled stop of the job (arg: the job)
    FAULT_STOP = "fault_stop"  # controlled stop of whatever job runs, outcome 'faulted'
    HOLD = "hold"  # ramp the job to rest on the path and keep it (arg: the job)
    RESUME = "resume"  # continue a held job (arg: the job)
    ABORT = "abort"  # quick stop if the job runs (arg: the job)
    QUICK_STOP = "quick_stop"  # quick stop every axis (arg: the job's outcome, None: 'aborted')
    RATE = "rate"  # playback rate, the feed override (arg: the rate)
    ENABLE = "enable"  # bring-up or fault reset
    DISABLE = "disable"  # shutdown
    HOME = "home"  # start homing (arg: the axis)
    HOME_START = "home_start"  # the homing procedure steps from now on (arg: the procedure)
    HOME_CANCEL = "home_cancel"  # the procedure ends (bit 4 low)
    HOME_HOLD = "home_hold"  # the homed axis holds there (arg: counts)
    HOME_END = "home_end"  # the homed axis follows set-points again
    CYCLIC_VELOCITY = "cyclic_velocity"  # the spindle's 0x60FF target changed (the scheduler's, not the axes')


@dataclass(frozen=True)
class Request:
    kind: Req
    arg: Any = None


HOMING_REQUESTS = frozenset((Req.HOME, Req.HOME_START, Req.HOME_CANCEL, Req.HOME_HOLD, Req.HOME_END))


# ------------------------------------------------------------------ notices: what the cycle loop acts on
@dataclass(frozen=True)
class PhaseChanged:
    phase: Phase
    cycle: int
    job: Any  # the job as of this transition


@dataclass(frozen=True)
class Ready:
    """Every axis follows set-points (bring-up done)."""


@dataclass(frozen=True)
class EnableFailed:
    axis: int
    cycle: int
    stuck: bool  # stuck in one state (the step's time-out), else the phase's time-out


@dataclass(frozen=True)
class QuickStopped:
    cycle: int


@dataclass(frozen=True)
class Refused:
    job: Any  # a job asked for when the axes were not holding


@dataclass(frozen=True)
class Quit:
    """The drives are disabled: the cycle loop ends."""


@dataclass(frozen=True)
class HomingEnded:
    axis: int
    outcome: HomingOutcome
    cycle: int


@dataclass(frozen=True)
class HomeRefused:
    axis: int
    phase: Phase


Notice = Union[PhaseChanged, Ready, EnableFailed, QuickStopped, Refused, Quit, HomingEnded, HomeRefused]


P, E = Phase, Event
_ANY_ONLINE = (P.ENABLING, P.HOLDING, P.STREAMING, P.STOPPING, P.QUICK_STOP, P.DISABLED, P.HOMING)
TRANSITIONS: dict[tuple[Phase, Event], Phase] = {
    **{(p, E.ENABLE): P.ENABLING for p in (P.OFFLINE, *_ANY_ONLINE)},
    (P.ENABLING, E.READY): P.HOLDING,
    (P.ENABLING, E.ENABLE_FAILED): P.QUICK_STOP,
    (P.ENABLING, E.QUICK_STOP): P.QUICK_STOP,
    (P.HOLDING, E.JOB): P.STREAMING,
    (P.STREAMING, E.LAST_ROW): P.HOLDING,
    (P.STREAMING, E.STOP): P.STOPPING,
    (P.STREAMING, E.AT_REST): P.HOLDING,
    (P.STOPPING, E.AT_REST): P.HOLDING,
    (P.STREAMING, E.HOLD): P.PAUSING,
    (P.STREAMING, E.PAUSE_ROW): P.HELD,
    (P.PAUSING, E.AT_REST): P.HELD,
    (P.PAUSING, E.STOP): P.STOPPING,
    (P.HELD, E.RESUME): P.STREAMING,
    (P.HELD, E.STOP): P.HOLDING,
    (P.HOLDING, E.HOME): P.HOMING,
    (P.HOMING, E.HOME_END): P.HOLDING,
    **{(p, E.QUICK_STOP): P.QUICK_STOP for p in RUNNING_PHASES},
    (P.QUICK_STOP, E.DRIVES_STOPPED): P.DISABLED,
    **{(p, E.DISABLE): P.DISABLING for p in _ANY_ONLINE},
}


def next_phase(phase: Phase, event: Event) -> Phase | None:
    """The phase ``event`` leads to from ``phase``; None: the event does not apply there."""
    return TRANSITIONS.get((phase, event))


@dataclass
class HomingSlot:
    """The axis being homed: before ``procedure`` is given it holds with bit 4 low (the
    master switches 0x6060 to 6 meanwhile); then the procedure's controlword each cycle and
    the set-point follows the position actual; with ``hold_counts`` it holds there, bit 4
    low (the master switches 0x6060 back), until ``home_end``."""

    axis: int
    procedure: HomingProcedure | None = None
    hold_counts: int | None = None

    def snapshot(self) -> tuple[Any, ...]:
        proc = self.procedure
        return (self.axis, proc, proc.snapshot() if proc is not None else None, self.hold_counts)

    @staticmethod
    def restored(snap: tuple[Any, ...] | None) -> "HomingSlot | None":
        if snap is None:
            return None
        axis, proc, state, hold = snap
        if proc is not None:
            proc.restore(state)
        return HomingSlot(axis, proc, hold)


class Feedback(Protocol):
    """What the controller reads of the drives' answers (fieldbus.feedback.Feedback)."""

    status: list[int | None]
    pos: list[int]
    cycle: list[int]
    last_emcy: list[int | None]
    wire_cycle: int


class JobLike(Protocol):
    playback: Playback
    outcome: str
    finish_cycle: int
    released: bool


class CycleController:
    """Phase and per-axis commands; ``sp``/``cw`` are reused lists (no allocation per cycle).

    ``notices`` collects what the caller must act on outside the cycle (the :data:`Notice`
    classes above).
    """

    def __init__(self, n_axes: int, ip_mode: list[bool], accel_limits: list[float], period_s: float,
                 stuck_cycles: int, enable_timeout_cycles: float) -> None:
        self.n = n_axes
        self.ip = ip_mode
        self.accel_limits = accel_limits
        self.period_s = period_s
        self.stuck_cycles = stuck_cycles
        self.enable_timeout_cycles = enable_timeout_cycles
        self.run_cw = [running_controlword(ip) for ip in ip_mode]
        self.sp = [0] * n_axes
        self.cw = [0] * n_axes
        self.hold = [0] * n_axes
        self.axis_enabled = [False] * n_axes
        self.since_cycle = [0] * n_axes
        self.since_status: list[int | None] = [None] * n_axes
        self.phase = Phase.OFFLINE
        self.phase_cycle = 0
        self.job: Any = None  # the job streaming or stopping (a JobLike)
        self.rate = 1.0  # playback rate for the next jobs (feed override)
        self.homing: HomingSlot | None = None  # phase HOMING: the axis being homed
        self.notices: collections.deque[Notice] = collections.deque()

    # ------------------------------------------------------------------ the cycle
    def step(self, k: int, fb: Feedback, requests: Sequence[Request] = ()) -> tuple[list[int], list[int]]:
        """Handle ``requests`` (in order), then return (controlwords, set-points) of cycle k."""
        for request in requests:
            self.handle(request, k, fb)
        phase = self.phase
        sp, cw = self.sp, self.cw
        if phase is Phase.STREAMING:
            job = self.job
            cw[:] = self.run_cw
            if job.playback.advance(sp):
                self.hold[:] = sp
                job.outcome, job.finish_cycle = "done", k + 1
                self._set_phase(Event.LAST_ROW, k)
            elif job.playback.at_pause():
                self.hold[:] = sp
                self._set_phase(Event.PAUSE_ROW, k)
        elif phase is Phase.HOLDING or phase is Phase.HELD:
            sp[:] = self.hold
            cw[:] = self.run_cw
        elif phase is Phase.STOPPING or phase is Phase.PAUSING:
            job = self.job
            cw[:] = self.run_cw
            if not job.playback.stop_step(sp):
                self.hold[:] = sp
                if phase is Phase.STOPPING:
                    job.finish_cycle = k + 1
                self._set_phase(Event.AT_REST, k)
        elif phase is Phase.ENABLING:
            self._enabling(k, fb)
        elif phase is Phase.HOMING:
            self._homing_step(k, fb)
        elif phase is Phase.QUICK_STOP:
            sp[:] = fb.pos
            cw[:] = [CW_QUICK_STOP] * self.n
            if k - self.phase_cycle > 2 and all(self._stopped_or_silent(i, fb) for i in range(self.n)):
                self._set_phase(Event.DRIVES_STOPPED, k)
        elif phase is Phase.DISABLED:
            sp[:] = fb.pos
            cw[:] = [CW_DISABLE_VOLTAGE] * self.n
        elif phase is Phase.DISABLING:
            sp[:] = self.hold
            cw[:] = [CW_SHUTDOWN] * self.n
            if all((s or 0) & OE_MASK != OE_VALUE for s in fb.status) and k - self.phase_cycle > 2 \
                    or k - self.phase_cycle > self.stuck_cycles:
                self.notices.append(Quit())
        return cw, sp

    def handle(self, request: Request, k: int, fb: Feedback) -> None:
        """One request (:class:`Req`); the homing ones act on one axis' homing (HomingSlot)."""
        phase, what, arg = self.phase, request.kind, request.arg
        if what in HOMING_REQUESTS:
            self._handle_homing(what, arg, k)
            return
        if what is Req.JOB:
            if phase is Phase.HOLDING and self.job is None:
                self.job = arg
                self._set_phase(Event.JOB, k)
            else:
                self.notices.append(Refused(arg))
        elif what is Req.STOP or what is Req.FAULT_STOP:
            if self.job is None or not (what is Req.FAULT_STOP or self.job is arg):
                return
            outcome = "stopped" if what is Req.STOP else "faulted"
            if phase is Phase.STREAMING:
                self._controlled_stop(k, outcome)
            elif phase is Phase.PAUSING:  # the hold's ramp becomes the stop's
                self.job.outcome = outcome
                self._set_phase(Event.STOP, k)
            elif phase is Phase.HELD:  # at rest already: the job ends here
                self.job.outcome, self.job.finish_cycle = outcome, k
                self._set_phase(Event.STOP, k)
        elif what is Req.HOLD:
            if phase is Phase.STREAMING and self.job is arg:
                if self.job.playback.index < 0:  # nothing sent yet: held before the first row
                    self._set_phase(Event.PAUSE_ROW, k)
                else:
                    self.job.playback.start_stop(self.accel_limits, self.period_s)
                    self._set_phase(Event.HOLD, k)
        elif what is Req.RESUME:
            if phase is Phase.HELD and self.job is arg:
                self.job.playback.resume(self.rate)
                self._set_phase(Event.RESUME, k)
        elif what is Req.ABORT:
            if self.job is arg and phase in RUNNING_PHASES:
                self._quick_stop(k, "aborted")
        elif what is Req.QUICK_STOP:
            if phase in RUNNING_PHASES or phase is Phase.ENABLING:
                self._quick_stop(k, arg or "aborted")
        elif what is Req.RATE:
            self.rate = arg
            if self.job is not None:
                self.job.playback.target = arg
        elif what is Req.ENABLE:
            self._enter_enabling(k, fb)
        elif what is Req.DISABLE:
            self._end_job("aborted", k)
            self._set_phase(Event.DISABLE, k)

    # ------------------------------------------------------------------ what a stall would leave on the wire
    def stop_cycles(self) -> int:
        """Cycles from now until the axes are at rest if no further request came: the length
        of the controlled stop a queue must end with (1 when not moving)."""
        if self.phase in MOVING_PHASES and self.job is not None:
            return self.job.playback.stop_cycles(self.accel_limits, self.period_s)
        return 1

    def tail(self, sp_rows: list[list[int]], cw_rows: list[list[int]]) -> int:
        """Fill the rows with what follows the last step if no request came: a controlled stop
        from the playback state (streaming), the rest of the stop (stopping), else the last
        commands repeated. The controller's state is left unchanged. Returns the number of
        rows until rest (the rest repeats the final row)."""
        job = self.job
        moving = self.phase in MOVING_PHASES and job is not None
        saved = job.playback.snapshot() if moving else None
        out, cw = list(self.sp), list(self.cw)
        if moving and not job.playback.stopping:
            job.playback.start_stop(self.accel_limits, self.period_s)
        at_rest = 0 if not moving else len(sp_rows)
        for row in range(len(sp_rows)):
            if row < at_rest and not job.playback.stop_step(out):
                at_rest = row + 1
            sp_rows[row][:] = out
            cw_rows[row][:] = cw
        if saved is not None:
            job.playback.restore(saved)
        return at_rest

    # ------------------------------------------------------------------ rewinding (queued cycles)
    def snapshot(self) -> tuple[Any, ...]:
        job = self.job
        state: PlaybackState | None = job.playback.snapshot() if job is not None else None
        return (self.phase, self.phase_cycle, job, state, job.outcome if job else "", job.finish_cycle if job else -1,
                tuple(self.hold), tuple(self.sp), tuple(self.cw), self.rate,
                self.homing.snapshot() if self.homing is not None else None)

    def restore(self, snap: tuple[Any, ...]) -> None:
        """Back to the state right after an earlier step (snapshot taken then)."""
        phase, self.phase_cycle, job, state, outcome, finish, hold, sp, cw, self.rate, homing = snap
        self.phase = phase
        self.homing = HomingSlot.restored(homing)
        if job is not None and job.released and phase not in MOVING_PHASES:
            job = None  # its end already reached the wire
        self.job = job
        if job is not None:
            job.playback.restore(state)
            job.outcome, job.finish_cycle = outcome, finish
        self.hold[:] = hold
        self.sp[:] = sp
        self.cw[:] = cw

    # ------------------------------------------------------------------ transitions
    def _set_phase(self, event: Event, k: int) -> None:
        phase = next_phase(self.phase, event)
        if phase is None:
            raise RuntimeError(f"controller: event {event.value} in phase {self.phase.value}")
        self.phase = phase
        self.phase_cycle = k
        if phase is not Phase.HOMING:
            self.homing = None
        self.notices.append(PhaseChanged(phase, k, self.job))

    def _enter_enabling(self, k: int, fb: Feedback) -> None:
        for i in range(self.n):
            self.since_cycle[i] = k
            self.since_status[i] = fb.status[i]
            self.axis_enabled[i] = False
        self._set_phase(Event.ENABLE, k)

    def _controlled_stop(self, k: int, outcome: str) -> None:
        job = self.job
        job.outcome = outcome
        if job.playback.index < 0:  # nothing of the job sent yet: keep holding
            job.finish_cycle = k
            self._set_phase(Event.AT_REST, k)
            self.job = None
            return
        job.playback.start_stop(self.accel_limits, self.period_s)
        self._set_phase(Event.STOP, k)

    def _quick_stop(self, k: int, outcome: str) -> None:
        self._set_phase(Event.QUICK_STOP, k)
        self.notices.append(QuickStopped(k))
        self._end_job(outcome, k)

    def _end_job(self, outcome: str, k: int) -> None:
        job = self.job
        if job is not None:
            job.outcome, job.finish_cycle = outcome, k
            self.job = None

    def release_job(self, job: Any) -> None:
        """The job's end reached the wire: forget it."""
        job.released = True
        if self.job is job and self.phase not in MOVING_PHASES:
            self.job = None

    # ------------------------------------------------------------------ homing one axis
    def _handle_homing(self, what: Req, arg: Any, k: int) -> None:
        slot = self.homing
        if what is Req.HOME:
            if self.phase is Phase.HOLDING and self.job is None:
                self.homing = HomingSlot(int(arg))
                self._set_phase(Event.HOME, k)
            else:
                self.notices.append(HomeRefused(arg, self.phase))
        elif slot is None or self.phase is not Phase.HOMING:
            return  # the homing ended meanwhile (fault, quick stop, reset): the master sees the phase
        elif what is Req.HOME_START:
            slot.procedure = arg
        elif what is Req.HOME_CANCEL:
            if slot.procedure is not None:
                slot.procedure.cancel()
        elif what is Req.HOME_HOLD:
            slot.procedure, slot.hold_counts = None, int(arg)
        elif what is Req.HOME_END:
            i = slot.axis
            self.hold[i] = slot.hold_counts if slot.hold_counts is not None else self.hold[i]
            self._set_phase(Event.HOME_END, k)

    def _homing_step(self, k: int, fb: Feedback) -> None:
        """The other axes hold; the homed axis as its HomingSlot says."""
        slot = self.homing
        assert slot is not None
        sp, cw, i = self.sp, self.cw, slot.axis
        sp[:] = self.hold
        cw[:] = self.run_cw
        cw[i] = CW_ENABLED  # bit 4 low: no interpolation (IP) / no homing start (mode 6)
        if slot.hold_counts is not None:
            sp[i] = slot.hold_counts
        elif slot.procedure is not None:
            step = slot.procedure.step(fb.status[i])
            cw[i] = step.controlword
            sp[i] = fb.pos[i]  # ignored in mode 6; follows the drive so no target is stale
            if step.outcome is not None:
                self.notices.append(HomingEnded(i, step.outcome, k))

    def _enabling(self, k: int, fb: Feedback) -> None:
        sp, cw = self.sp, self.cw
        for i in range(self.n):
            sw = fb.status[i]
            state = c.state_of_statusword(sw) if sw is not None else None
            if state is c.State.OPERATION_ENABLED:
                if not self.axis_enabled[i]:
                    self.axis_enabled[i] = True
                    self.hold[i] = sp[i]
                sp[i] = self.hold[i]
            else:
                self.axis_enabled[i] = False
                sp[i] = fb.pos[i]
            cw[i] = enable_step(state, cw[i], self.ip[i])[1]
        self._check_enabling(k, fb)

    def _check_enabling(self, k: int, fb: Feedback) -> None:
        ready = True
        for i in range(self.n):
            sw = fb.status[i]
            if sw is not None and is_ready(sw, self.ip[i]) and fb.cycle[i] > self.phase_cycle:
                continue
            ready = False
            if sw != self.since_status[i]:
                self.since_status[i], self.since_cycle[i] = sw, k
            elif (stuck := k - self.since_cycle[i] > self.stuck_cycles) or \
                    k - self.phase_cycle > self.enable_timeout_cycles:
                self.notices.append(EnableFailed(i, k, stuck))
                self._set_phase(Event.ENABLE_FAILED, k)
                return
        if ready:
            self.hold[:] = self.sp
            self._set_phase(Event.READY, k)
            self.notices.append(Ready())

    def _stopped_or_silent(self, i: int, fb: Feedback) -> bool:
        """Axis i no longer enabled nor quick-stopping, or its TPDO1 stopped coming."""
        return (fb.status[i] or 0) & OE_MASK not in (OE_VALUE, QS_VALUE) or fb.cycle[i] < fb.wire_cycle - 3
