"""Fault reactions of the master: the drives' answers judged once per cycle.

Checked each cycle on the feedback (fieldbus.feedback) against what went on the wire
(:class:`CycleHistory`): statusword fault bit 3 and following-error bit 13, leaving
OPERATION ENABLED, the following error computed from set-point and position actual, the
heartbeat (consumer time), TPDO1 silence, EMCY and NMT state changes. Each fault is reported
once per (node, kind) until reset; the reaction is a request for the controller: a
controlled stop on the path while every drive still follows (EMCY, heartbeat), else a quick
stop.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from nurbsmotion.can import cia402 as c
from nurbsmotion.fieldbus.controller import OE_MASK, OE_VALUE, RUNNING_PHASES, Phase, Req, Request
from nurbsmotion.fieldbus.drive_state import enable_step, state_name
from nurbsmotion.fieldbus.feedback import EVENT_BAD_TPDO, EVENT_EMCY, EVENT_NMT, Feedback, arrival_perf_s
from nurbsmotion.fieldbus.reports import FaultReport
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

SEARCH_CYCLES = 5  # SYNCs searched back for the one a TPDO1 answers


class CycleHistory:
    """Set-points per cycle (a ring of ``size`` rows, indexed by cycle % size) and the time
    (time.time() based, as frame timestamps) of each SYNC on the wire."""

    def __init__(self, size: int, n_axes: int) -> None:
        self.size = size
        self.sp = [[0] * n_axes for _ in range(size)]
        self.cw = [[0] * n_axes for _ in range(size)]
        self.sync_time = [0.0] * size

    def store(self, k: int, cw: list[int], sp: list[int]) -> None:
        row = k % self.size
        self.sp[row][:] = sp
        self.cw[row][:] = cw


class Supervisor:
    """Judges the feedback each cycle; ``faults`` lists every report since construction."""

    def __init__(self, node_ids: list[int], names: list[str], fe_window: list[int], fe_timeout_cycles: list[int],
                 hb_timeout_s: float, period_s: float, feedback: Feedback, history: CycleHistory) -> None:
        self.node_ids = node_ids
        self.names = names
        self.fe_window = fe_window
        self.fe_timeout_cycles = fe_timeout_cycles
        self.hb_timeout_s = hb_timeout_s
        self.period_s = period_s
        self.fb = feedback
        self.history = history
        n = len(node_ids)
        self.fe_cycles = [0] * n
        self.fe_checked_time = [0.0] * n
        self.fe_answered = [0] * n  # SYNC the last judged TPDO1 answered
        self.backlog_floor = [1 << 30] * n  # least SYNCs-minus-TPDO1s since enabled
        self.late_warned: set[int] = set()
        self.faults: list[FaultReport] = []
        self.reported: set[tuple[int | None, str]] = set()
        self.bad_tpdo_warned: set[int] = set()
        self.homing_axis = -1  # an axis in homing mode: bit 13 is 'homing error', its set-point follows it

    def reset(self) -> None:
        """Faults acknowledged (re-enabling): report them again when they recur."""
        self.reported.clear()
        self.fe_cycles[:] = [0] * len(self.fe_cycles)
        self.backlog_floor[:] = [1 << 30] * len(self.backlog_floor)
        self.late_warned.clear()

    # ------------------------------------------------------------------ once per cycle
    def check(self, k: int, phase: Phase, job: Any) -> list[Request]:
        """Events and per-axis checks at wire cycle k; returns the controller requests."""
        reactions: list[Request] = []
        events = self.fb.events
        while events:
            self._event(events.popleft(), k, phase, job, reactions)
        if phase in RUNNING_PHASES:
            self._check_axes(k, phase, job, reactions, running=True)
        elif phase in (Phase.DISABLED, Phase.QUICK_STOP):
            self._check_axes(k, phase, job, reactions, running=False)
        return reactions

    def _event(self, event: tuple[int, int, int], k: int, phase: Phase, job: Any,
               reactions: list[Request]) -> None:
        kind, i, value = event
        node, name = self.node_ids[i], self.names[i]
        if kind == EVENT_BAD_TPDO:
            if node not in self.bad_tpdo_warned:
                self.bad_tpdo_warned.add(node)
                log.warning(kv("bad_tpdo_length", node=node, axis=name, length=value, cycle=k))
            return
        if phase in (Phase.ENABLING, Phase.OFFLINE):
            return
        if kind == EVENT_EMCY and value & 0xFF00:  # 0x00xx = error reset / no error (CiA 301)
            self.report(node, name, "emcy", value, k, f"node {node} (axis {name}): EMCY 0x{value:04X}"
                        f"{_emcy_text(value)} at cycle {k}", phase, job, reactions)
        elif kind == EVENT_NMT and value != c.NmtState.OPERATIONAL:
            what = "boot-up: the drive restarted" if value == c.NmtState.BOOTUP else \
                f"NMT state {_nmt_name(value)} instead of OPERATIONAL"
            self.report(node, name, "heartbeat", value, k, f"node {node} (axis {name}): heartbeat reports {what} "
                        f"at cycle {k}", phase, job, reactions)

    def _check_axes(self, k: int, phase: Phase, job: Any, reactions: list[Request], running: bool) -> None:
        """Per axis: statusword bits, computed following error (running only), heartbeat."""
        fb = self.fb
        now = time.perf_counter()
        for i in range(len(self.node_ids)):
            self.check_statusword(i, k, running, phase, job, reactions)
            if running and i != self.homing_axis:
                self._check_following_error(i, k, phase, job, reactions)
            node, name = self.node_ids[i], self.names[i]
            silent_s = self._heartbeat_silence_s(i, now)
            if silent_s > self.hb_timeout_s:
                self.report(node, name, "heartbeat", -1, k, f"node {node} (axis {name}): no heartbeat for "
                            f"{silent_s * 1000:.0f} ms (consumer time "
                            f"{self.hb_timeout_s * 1000:.0f} ms) at cycle {k}", phase, job, reactions)
            elif running and k - fb.cycle[i] > max(self.fe_timeout_cycles[i] + 3, self.hb_timeout_s / self.period_s) \
                    and fb.arrival.caught_up() and self._heard_since_tpdo1(i):  # a TPDO1 waiting unread is not missing
                self.report(node, name, "following_error", 0, k, f"node {node} (axis {name}): no TPDO1 (position "
                            f"actual) for {k - fb.cycle[i]} cycles at cycle {k}", phase, job, reactions)

    def _heard_since_tpdo1(self, i: int) -> bool:
        """Axis i's drive sent a heartbeat after its last TPDO1 (or never sent a TPDO1): it is
        there but does not answer SYNC, which only this check finds. A drive silent altogether
        is the heartbeat check's: both wait the consumer time, so which fired first turned on
        tens of ms (a killed drives' process read as 'following_error' on vcan0)."""
        stamp = self.fb.time[i]
        return stamp <= 0.0 or self.fb.hb_time[i] > arrival_perf_s(stamp)

    def _heartbeat_silence_s(self, i: int, now_s: float) -> float:
        """How long axis i's drive has been silent, judged as its heartbeats arrived (CiA 301
        heartbeat consumer): only when the process clock says the consumer time has run out is
        the arrival timeline asked (one look at the socket), since it never runs ahead of it."""
        silent_s = now_s - self.fb.hb_time[i]
        if silent_s <= self.hb_timeout_s:
            return silent_s
        return self.fb.judging_time_s() - self.fb.hb_time[i]

    def check_statusword(self, i: int, k: int, running: bool, phase: Phase, job: Any,
                         reactions: list[Request]) -> None:
        """Following error bit 13, fault bit 3, and (running) leaving OPERATION ENABLED."""
        sw = self.fb.status[i] or 0
        node, name = self.node_ids[i], self.names[i]
        if sw & c.SW_FOLLOWING_ERROR and i != self.homing_axis:
            self.report(node, name, "following_error", self.fb.fe[i] or 0, k, f"node {node} (axis {name}): drive "
                        f"reports following error (statusword bit 13) in {state_name(sw)} at cycle {k}",
                        phase, job, reactions)
        elif sw & c.SW_FAULT:
            code = self.fb.last_emcy[i] or 0
            self.report(node, name, "fault_bit", code, k, f"node {node} (axis {name}): drive in {state_name(sw)} at "
                        f"cycle {k}{f' (last EMCY 0x{code:04X})' if code else ''}", phase, job, reactions)
        elif running and sw & OE_MASK != OE_VALUE:
            self.report(node, name, "fault_bit", sw, k, f"node {node} (axis {name}): drive left OPERATION ENABLED, "
                        f"now {state_name(sw)} at cycle {k}", phase, job, reactions)

    def _check_following_error(self, i: int, k: int, phase: Phase, job: Any,
                               reactions: list[Request]) -> None:
        """|set-point in force at the answered SYNC - actual| > window for longer than the time-out.

        The TPDO answers the latest SYNC on the wire before its receive timestamp (so a
        lagging receive thread does not matter); the set-point in force at SYNC n was sent
        after SYNC n-1. Servo lag: the nearest of the set-points sent after SYNCs n-1, n-2,
        n-3 counts. Each TPDO is judged once; one older than the search is not judged (the
        drive's own check, statusword bit 13, still is)."""
        fb = self.fb
        stamp = fb.time[i]
        if stamp == self.fe_checked_time[i]:
            return
        self.fe_checked_time[i] = stamp
        history = self.history
        size, times, rows = history.size, history.sync_time, history.sp
        answered = -1
        for n in range(k, k - SEARCH_CYCLES, -1):
            if 0.0 < times[n % size] <= stamp:
                answered = n
                break
        if answered < 8 or self._answers_late(i, k):
            return
        actual = fb.pos[i]
        error = rows[(answered - 1) % size][i] - actual
        for back in (2, 3):
            e = rows[(answered - back) % size][i] - actual
            if abs(e) < abs(error):
                error = e
        since, self.fe_answered[i] = answered - self.fe_answered[i], answered
        if abs(error) <= self.fe_window[i]:
            self.fe_cycles[i] = 0
            return
        self.fe_cycles[i] += min(since, SEARCH_CYCLES) if since > 0 else 1  # cycles, also when judged every few
        if self.fe_cycles[i] > self.fe_timeout_cycles[i]:
            node, name = self.node_ids[i], self.names[i]
            self.report(node, name, "following_error", error, k, f"node {node} (axis {name}): following error {error} "
                        f"counts exceeds the window {self.fe_window[i]} counts for {self.fe_cycles[i]} cycles at "
                        f"cycle {k}", phase, job, reactions)

    def _answers_late(self, i: int, k: int) -> bool:
        """The drive works through a backlog: more SYNCs on the wire than TPDO1s from it,
        beyond the least such difference since the axes were enabled. Its TPDO1 then answers
        an earlier SYNC than the latest one, so no computed error is judged (the drive's own
        check, statusword bit 13, still is); logged once per enable. Real drives answer
        within the cycle; a simulated drive in a starved process (User-Mode Linux) falls
        behind by seconds, growing slowly. A lost TPDO1 also counts as one cycle behind."""
        backlog = k - self.fb.tpdo_count[i]
        if backlog < self.backlog_floor[i]:
            self.backlog_floor[i] = backlog
        late = backlog - self.backlog_floor[i] > 1
        node = self.node_ids[i]
        if late and node not in self.late_warned:
            self.late_warned.add(node)
            log.warning(kv("drive_answers_late", node=node, axis=self.names[i], cycles=backlog - self.backlog_floor[i],
                           cycle=k, note="computed following error not judged while it lags"))
        return late

    # ------------------------------------------------------------------ reports and reactions
    def report(self, node: int | None, axis: str | None, kind: str, code: int, k: int, message: str,
               phase: Phase, job: Any, reactions: list[Request]) -> None:
        """Record a fault once per (node, kind) until reset(), then choose the reaction."""
        if (node, kind) in self.reported:
            return
        self.reported.add((node, kind))
        report = FaultReport(node, axis, kind, code, k, message)
        self.faults.append(report)
        if job is not None:
            job.faults.append(report)
        log.warning(kv("fault", node=node, axis=axis, kind=kind, code=code, cycle=k, message=message))
        if phase not in RUNNING_PHASES:
            return
        if kind in ("emcy", "heartbeat") and self._drives_follow(k):
            if phase in (Phase.STREAMING, Phase.PAUSING, Phase.HELD):  # a held job ends too
                reactions.append(Request(Req.FAULT_STOP))
            return
        reactions.append(Request(Req.QUICK_STOP, "faulted"))

    def _drives_follow(self, k: int) -> bool:
        """Every drive enabled, without following error, and its TPDO1 fresh."""
        fb = self.fb
        for i in range(len(self.node_ids)):
            sw = fb.status[i] or 0
            if sw & OE_MASK != OE_VALUE or sw & c.SW_FOLLOWING_ERROR or self.fe_cycles[i] or fb.cycle[i] < k - 3:
                return False
        return True

    def enable_failed(self, i: int, k: int, since_cycle: int, ip_mode: bool, phase_timeout_s: float | None = None) -> str:
        """Message (and report) for an axis stuck on its way to OPERATION ENABLED: in one
        state for the step time-out, or (``phase_timeout_s``) still short of it when the
        whole enable phase's time-out ran out."""
        fb = self.fb
        node, sw = self.node_ids[i], fb.status[i]
        state = c.state_of_statusword(sw) if sw is not None else None
        step = enable_step(state, 0, ip_mode)[0]
        waited_ms = (k - since_cycle) * self.period_s * 1000
        where = f"no TPDO1 received (last statusword by SDO: {state_name(sw)})" if fb.cycle[i] < 0 else \
            f"stuck in {state_name(sw)} (statusword 0x{sw or 0:04X}, controlword sent 0x{self.history.cw[k % self.history.size][i]:04X})"
        when = f"after {waited_ms:.0f} ms" if phase_timeout_s is None else \
            f"for {waited_ms:.0f} ms when the drives' enable time-out of {phase_timeout_s:.1f} s ran out"
        emcy = fb.last_emcy[i]
        message = (f"node {node}: bring-up step '{step}': {where} {when}"
                   f"{f' (last EMCY 0x{emcy:04X})' if emcy else ''}")
        self.faults.append(FaultReport(node, self.names[i], "bringup", sw or 0, k, message))
        self.reported.add((node, "bringup"))
        return message


_EMCY_TEXT = {int(code): code.name.lower().replace("_", " ") for code in c.EmcyCode}


def _emcy_text(code: int) -> str:
    text = _EMCY_TEXT.get(code)
    return f" ({text})" if text else ""


def _nmt_name(state: int) -> str:
    try:
        return c.NmtState(state).name.replace("_", "-")
    except ValueError:
        return f"0x{state:02X}"
