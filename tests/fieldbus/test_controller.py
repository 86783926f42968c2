"""The per-cycle controller without a bus: phases, enabling, streaming, stops, rewinding."""

import numpy as np
import pytest

from nurbsmotion.fieldbus.controller import (TRANSITIONS, CycleController, EnableFailed, Event, HomingEnded, Phase,
                                             PhaseChanged, Ready, Refused, Req, Request, next_phase)
from nurbsmotion.fieldbus.drive_state import CW_ENABLED, CW_QUICK_STOP, CW_SHUTDOWN
from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.stop_ramp import ramp_slope

SW_ENABLED = 0x0237  # OPERATION ENABLED
SW_SWITCH_ON_DISABLED = 0x0240


class Fb:
    def __init__(self, n, status=None, pos=0):
        self.status = [status] * n
        self.pos = [pos] * n
        self.cycle = [-1] * n
        self.last_emcy = [None] * n
        self.wire_cycle = 0


class FakeJob:
    def __init__(self, rows):
        arr = np.asarray(rows, dtype=np.int64)
        steps = np.abs(np.diff(arr, axis=0)).max(axis=0).astype(float).tolist()
        self.playback = Playback(memoryview(arr), ramp_slope(arr, np.full(arr.shape[1], 1e6), 0.004), 1.0, steps,
                                 [0.0] * arr.shape[1])
        self.outcome, self.finish_cycle, self.released = "", -1, False


def holding_controller(n=2):
    ctl = CycleController(n, [False] * n, [1e6] * n, 0.004, stuck_cycles=100, enable_timeout_cycles=1000)
    fb = Fb(n, SW_ENABLED)
    ctl.handle(Request(Req.ENABLE), 0, fb)
    fb.cycle = [5] * n
    ctl.step(1, fb)
    assert ctl.phase is Phase.HOLDING
    return ctl, fb


def test_every_transition_is_in_the_table_and_nothing_else():
    assert next_phase(Phase.HOLDING, Event.JOB) is Phase.STREAMING
    assert next_phase(Phase.HOLDING, Event.LAST_ROW) is None
    assert next_phase(Phase.DISABLED, Event.JOB) is None
    assert all(isinstance(p, Phase) and isinstance(e, Event) for p, e in TRANSITIONS)


def test_enabling_walks_the_state_machine_from_the_feedback():
    ctl = CycleController(1, [False], [1e6], 0.004, stuck_cycles=100, enable_timeout_cycles=1000)
    fb = Fb(1, SW_SWITCH_ON_DISABLED, pos=1234)
    ctl.handle(Request(Req.ENABLE), 0, fb)
    cw, sp = ctl.step(1, fb)
    assert (cw, sp, ctl.phase) == ([CW_SHUTDOWN], [1234], Phase.ENABLING)
    fb.status, fb.cycle = [SW_ENABLED], [3]
    cw, sp = ctl.step(2, fb)
    assert cw == [CW_ENABLED] and ctl.phase is Phase.HOLDING and ctl.hold == [1234]
    assert Ready() in ctl.notices


def test_an_axis_stuck_while_enabling_is_named():
    ctl = CycleController(2, [False, False], [1e6] * 2, 0.004, stuck_cycles=3, enable_timeout_cycles=1000)
    fb = Fb(2, SW_SWITCH_ON_DISABLED)
    ctl.handle(Request(Req.ENABLE), 0, fb)
    k = 0
    while ctl.phase is Phase.ENABLING and k < 10:
        k += 1
        ctl.step(k, fb)
    assert ctl.phase is Phase.QUICK_STOP and k == 4  # unchanged for more than 3 cycles
    assert any(isinstance(n, EnableFailed) and n.axis == 0 for n in ctl.notices)


def test_stream_plays_every_row_once_then_holds_the_last():
    ctl, fb = holding_controller()
    rows = [[i * 10, -i * 5] for i in range(6)]
    job = FakeJob(rows)
    sent = [list(ctl.step(k, fb, [Request(Req.JOB, job)] if k == 2 else [])[1]) for k in range(2, 10)]
    assert sent[:6] == rows and sent[6:] == [rows[-1]] * 2
    assert ctl.phase is Phase.HOLDING and (job.outcome, job.finish_cycle) == ("done", 8)


def test_stop_decelerates_on_the_path_and_ends_at_rest():
    ctl, fb = holding_controller(1)
    job = FakeJob([[i * 100] for i in range(1000)])
    ctl.step(2, fb, [Request(Req.JOB, job)])
    for k in range(3, 50):
        ctl.step(k, fb)
    ctl.step(50, fb, [Request(Req.STOP, job)])
    assert ctl.phase is Phase.STOPPING
    points = [ctl.step(k, fb)[1][0] for k in range(51, 400)]
    steps = np.diff(points)
    assert ctl.phase is Phase.HOLDING and job.outcome == "stopped"
    assert (steps >= 0).all() and steps[-1] == 0 and (np.diff(steps)[:20] <= 0).all()


def test_abort_sends_quick_stop_with_the_actual_position():
    ctl, fb = holding_controller()
    job = FakeJob([[i, i] for i in range(100)])
    ctl.step(2, fb, [Request(Req.JOB, job)])
    fb.pos = [7, 8]
    cw, sp = ctl.step(3, fb, [Request(Req.ABORT, job)])
    assert ctl.phase is Phase.QUICK_STOP and cw == [CW_QUICK_STOP] * 2 and sp == [7, 8]
    assert job.outcome == "aborted" and ctl.job is None


def test_a_job_and_a_quick_stop_in_the_same_step_keep_the_job_in_its_phase_notice():
    """The master reads the job of a STREAMING transition from the notice: a quick stop (the
    e-stop input) handled in the same step has already ended it and cleared ctl.job (seen as
    'cycle loop failed ... NoneType ... start_cycle' under load in test_spindle_io)."""
    ctl, fb = holding_controller()
    ctl.notices.clear()
    job = FakeJob([[i, i] for i in range(100)])
    ctl.step(2, fb, [Request(Req.JOB, job), Request(Req.QUICK_STOP, "e-stop")])
    assert ctl.job is None and job.outcome == "e-stop"
    phases = [(n.phase, n.job) for n in ctl.notices if isinstance(n, PhaseChanged)]
    assert phases == [(Phase.STREAMING, job), (Phase.QUICK_STOP, job)]


def test_tail_is_a_stop_from_the_current_state_and_leaves_the_state_alone():
    ctl, fb = holding_controller(1)
    job = FakeJob([[i * 100] for i in range(1000)])
    ctl.step(2, fb, [Request(Req.JOB, job)])
    for k in range(3, 30):
        ctl.step(k, fb)
    before = ctl.snapshot()
    rows = [[0] for _ in range(ctl.stop_cycles() + 5)]
    at_rest = ctl.tail(rows, [[0] for _ in rows])
    assert at_rest <= ctl.stop_cycles() and rows[at_rest - 1] == rows[-1]
    assert np.diff([r[0] for r in rows]).min() >= 0
    assert ctl.snapshot() == before


def test_rewinding_to_a_snapshot_replays_the_same_commands():
    ctl, fb = holding_controller(1)
    job = FakeJob([[i * i] for i in range(200)])
    ctl.step(2, fb, [Request(Req.JOB, job)])
    snap = ctl.snapshot()
    first = [ctl.step(k, fb)[1][0] for k in range(3, 20)]
    ctl.restore(snap)
    assert [ctl.step(k, fb)[1][0] for k in range(3, 20)] == first


@pytest.mark.parametrize("rate", [0.5, 0.0])
def test_rate_request_changes_the_playback_speed(rate):
    ctl, fb = holding_controller(1)
    job = FakeJob([[i * 100] for i in range(10000)])
    ctl.step(2, fb, [Request(Req.JOB, job)])
    ctl.step(3, fb, [Request(Req.RATE, rate)])
    for k in range(4, 400):
        ctl.step(k, fb)
    assert job.playback.r == pytest.approx(rate)


# ---------------------------------------------------------------- hold / resume / program pauses
def line_job(n=400, pauses=()):
    arr = np.column_stack([np.arange(n) * 50, np.arange(n) * -20]).astype(np.int64)
    steps = np.abs(np.diff(arr, axis=0)).max(axis=0).astype(float).tolist()
    job = FakeJob(arr)
    job.playback = Playback(memoryview(arr), ramp_slope(arr, np.array([2e5, 2e5]), 0.004), 1.0, steps, [0.0, 0.0],
                            pauses)
    return job, arr


def run(ctl, fb, k, requests_at, until):
    """Step from cycle k while ``until(ctl)`` is false; requests_at: {cycle: [requests]}."""
    sent = []
    while not until(ctl) and k < 100000:
        cw, sp = ctl.step(k, fb, requests_at.get(k, []))
        sent.append(list(sp))
        k += 1
    return sent, k


def test_hold_ramps_to_rest_on_the_path_keeps_the_job_and_resume_finishes_it():
    from nurbsmotion.service.verify import on_planned_path

    ctl, fb = holding_controller()
    job, arr = line_job()
    sent, k = run(ctl, fb, 2, {2: [Request(Req.JOB, job)], 60: [Request(Req.HOLD, job)]}, lambda c: c.phase is Phase.HELD)
    assert ctl.phase is Phase.HELD and ctl.job is job and job.outcome == ""
    assert sent[:58] == arr[:58].tolist()  # exact rows until the hold
    assert 60 < k - 2 < 60 + 4 / job.playback.ramp_dr + 2  # the ramp took ~1/dr cycles
    held = sent[-1]
    still = [list(ctl.step(k + i, fb)[1]) for i in range(20)]
    assert still == [held] * 20 and ctl.phase is Phase.HELD  # at rest, nothing moves until resume
    k += 20
    rest, k = run(ctl, fb, k, {k: [Request(Req.RESUME, job)]}, lambda c: c.phase is Phase.HOLDING)
    assert job.outcome == "done" and rest[-1] == arr[-1].tolist()
    played = np.array(sent + still + rest)
    assert on_planned_path(played, arr)
    # the resume ramp goes back to r = 1: the end of the job is exact planned rows again
    tail = 100
    assert rest[-tail:] == arr[-tail:].tolist()


def test_stop_and_abort_work_while_held():
    ctl, fb = holding_controller()
    job, arr = line_job()
    run(ctl, fb, 2, {2: [Request(Req.JOB, job)], 30: [Request(Req.HOLD, job)]}, lambda c: c.phase is Phase.HELD)
    ctl.step(500, fb, [Request(Req.STOP, job)])
    assert ctl.phase is Phase.HOLDING and job.outcome == "stopped" and job.finish_cycle == 500
    ctl2, fb2 = holding_controller()
    job2, _ = line_job()
    run(ctl2, fb2, 2, {2: [Request(Req.JOB, job2)], 30: [Request(Req.HOLD, job2)]}, lambda c: c.phase is Phase.HELD)
    ctl2.step(500, fb2, [Request(Req.ABORT, job2)])
    assert ctl2.phase is Phase.QUICK_STOP and job2.outcome == "aborted"


def test_stop_during_the_hold_ramp_continues_the_same_ramp_and_ends_the_job():
    ctl, fb = holding_controller()
    job, _ = line_job()
    run(ctl, fb, 2, {2: [Request(Req.JOB, job)], 60: [Request(Req.HOLD, job)]}, lambda c: c.phase is Phase.PAUSING)
    ctl.step(61, fb, [Request(Req.STOP, job)])
    assert ctl.phase is Phase.STOPPING and job.outcome == "stopped"
    run(ctl, fb, 62, {}, lambda c: c.phase is Phase.HOLDING)
    assert job.finish_cycle > 61


def test_program_pause_rows_hold_exactly_there_and_resume_plays_every_row_once():
    from nurbsmotion.service.verify import plan_with_holds

    ctl, fb = holding_controller()
    job, arr = line_job(200, pauses=(50, 120))
    sent, k = run(ctl, fb, 2, {2: [Request(Req.JOB, job)]}, lambda c: c.phase is Phase.HELD)
    assert sent[-1] == arr[50].tolist() and job.playback.index == 50
    wait = [list(ctl.step(k + i, fb)[1]) for i in range(10)]
    k += 10
    more, k = run(ctl, fb, k, {k: [Request(Req.RESUME, job)]}, lambda c: c.phase is Phase.HELD and c.job.playback.index == 120)
    assert more[-1] == arr[120].tolist()
    rest, k = run(ctl, fb, k, {k: [Request(Req.RESUME, job)]}, lambda c: c.phase is Phase.HOLDING)
    assert job.outcome == "done"
    assert plan_with_holds(np.array(sent + wait + more + rest), arr)
    assert not plan_with_holds(np.array(sent + wait + more + rest)[::2], arr)


def test_hold_and_pause_state_survives_a_rewind():
    ctl, fb = holding_controller()
    job, arr = line_job(200, pauses=(50,))
    run(ctl, fb, 2, {2: [Request(Req.JOB, job)]}, lambda c: c.phase is Phase.HELD)
    snap = ctl.snapshot()
    ctl.step(1000, fb, [Request(Req.RESUME, job)])
    ctl.step(1001, fb)
    assert ctl.phase is Phase.STREAMING and job.playback.pause_i == 1
    ctl.restore(snap)
    assert ctl.phase is Phase.HELD and job.playback.pause_i == 0 and job.playback.at_pause()


def test_homing_phase_runs_the_procedure_on_one_axis_and_returns_with_the_read_position():
    from nurbsmotion.fieldbus.homing import CW_START_HOMING, HomingProcedure

    ctl = CycleController(2, [True, False], [1e6] * 2, 0.004, stuck_cycles=100, enable_timeout_cycles=1000)
    fb = Fb(2, SW_ENABLED | 0x1000)  # IP active on axis 0
    ctl.handle(Request(Req.ENABLE), 0, fb)
    fb.cycle = [5, 5]
    ctl.step(1, fb)
    ctl.hold[:] = [100, 200]
    cw, sp = ctl.step(2, fb, [Request(Req.HOME, 0)])
    assert ctl.phase is Phase.HOMING and cw == [CW_ENABLED, CW_ENABLED] and sp == [100, 200]  # bit 4 low on axis 0
    assert ctl.step(3, fb, [Request(Req.JOB, "j")]) and Refused("j") in ctl.notices  # no job while homing
    procedure = HomingProcedure(1, 17, 0.004, 1.0, ack_s=0.0)
    fb.pos = [150, 200]
    cw, sp = ctl.step(4, fb, [Request(Req.HOME_START, procedure)])
    assert cw[0] == CW_ENABLED and sp == [150, 200]  # armed: the rising edge comes next cycle
    snap = ctl.snapshot()
    cw, _ = ctl.step(5, fb)
    assert cw[0] == CW_ENABLED | CW_START_HOMING
    ctl.restore(snap)  # a rewind recomputes the cycle from the same procedure state
    cw, _ = ctl.step(5, fb)
    assert cw[0] == CW_ENABLED | CW_START_HOMING and procedure.cycles == 2
    fb.status = [SW_ENABLED | 0x1000 | 0x0400, SW_ENABLED]  # homing attained + target reached
    for k in range(6, 12):
        ctl.step(k, fb)
    assert any(isinstance(n, HomingEnded) and n.outcome.homed for n in ctl.notices)
    cw, sp = ctl.step(12, fb, [Request(Req.HOME_HOLD, -2500)])
    assert (cw, sp) == ([CW_ENABLED, CW_ENABLED], [-2500, 200])
    cw, sp = ctl.step(13, fb, [Request(Req.HOME_END)])
    assert ctl.phase is Phase.HOLDING and ctl.hold == [-2500, 200] and ctl.homing is None
    assert cw == [CW_ENABLED | 0x10, CW_ENABLED] and sp == [-2500, 200]  # IP: bit 4 high again


def test_a_quick_stop_ends_the_homing_phase():
    ctl, fb = holding_controller()
    ctl.step(2, fb, [Request(Req.HOME, 1)])
    ctl.step(3, fb, [Request(Req.QUICK_STOP, "faulted")])
    assert ctl.phase is Phase.QUICK_STOP and ctl.homing is None
    ctl.step(4, fb, [Request(Req.HOME_END)])  # late requests of the homing run change nothing
    assert ctl.phase is Phase.QUICK_STOP
