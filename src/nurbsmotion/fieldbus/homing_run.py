"""One drive homing run by the master while the cycle loop keeps every other axis holding.

The order (CiA 402-2 homing mode, CiA 301 SDO), each step from the caller's thread while
the cycle loop runs the controller's ``homing`` phase (fieldbus.controller.HomingSlot):

1. ``home``: the axis holds with controlword bit 4 low (IP: interpolation off), 3 cycles;
2. the plan's SDO writes (0x6098, 0x6099, 0x609A, the home offset unless 0 or applied by the
   master: fieldbus.homing_check, 0x6060 = 6), 0x6061 read back;
3. ``home_start``: the procedure (fieldbus.homing.HomingProcedure) steps once per cycle
   in the cycle loop, its set-point follows the position actual; wait for its outcome;
4. 0x6064 read by SDO; ``home_hold`` there: the target the drive will follow is the
   position it stands at BEFORE the mode switches back (no jump), 3 cycles;
5. the restore writes (0x6060 = 7 / 8), 0x6061 read back;
6. ``home_end``: the axis' hold becomes that position, its running controlword returns
   (IP: bit 4 high), phase holding; the axis must be ready again (IP: bit 12) in 2 s.

A failed homing (drive error, interruption, time-out) is restored the same way and
returned as the outcome; an SDO failure is a FieldbusError naming node and step, after
which the axes are quick-stopped if the mode could not be restored.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from nurbsmotion.can import cia402 as c
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.bringup_plan import ReadBack
from nurbsmotion.fieldbus.controller import Phase, Req, Request
from nurbsmotion.fieldbus.drive_state import is_ready
from nurbsmotion.fieldbus.homing import HomingOutcome, HomingPlan, HomingProcedure
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

SETTLE_CYCLES = 3  # an RPDO sent after SYNC n acts at SYNC n+1, its TPDO is read at n+2: one more for margin
PHASE_TIMEOUT_S = 1.0
READY_TIMEOUT_S = 2.0  # the statusword may lag the wire as the SDO answers do (HOMING_SDO_TIMEOUT_S)
OUTCOME_MARGIN_S = 2.0  # beyond the procedure's own time-out (it counts cycles, the loop may lag)
# SDO answer time-out during a homing (bring-up uses the master's sdo_timeout_s, 0.5 s). The
# homing's SDO traffic is off the cycle's path and nothing waits on it but the operator; on
# vcan0 inside User-Mode Linux on a loaded host the simulated drives' process answered 0.5 s
# and once more than 2 s late (the test failed on both), so a drive gets 5 s: a dead drive is
# reported that much later, a slow one is not mistaken for a dead one.
HOMING_SDO_TIMEOUT_S = 5.0


class HomingRun:
    """One axis' homing (module docstring); :meth:`run` blocks until the axis holds again."""

    def __init__(self, axis: int, name: str, plan: HomingPlan, procedure: HomingProcedure,
                 trail: bringup.SdoTrail, ip_mode: bool, request: Callable[[Request], None],
                 wire_cycle: Callable[[], int], phase: Callable[[], Phase],
                 statusword: Callable[[], int | None], period_s: float, ready_timeout_s: float = READY_TIMEOUT_S) -> None:
        """``ready_timeout_s``: how long the drive may take to follow set-points again after
        the mode is restored (a state-machine step: the master's drive_step_timeout, at least
        READY_TIMEOUT_S)."""
        self._ready_timeout_s = ready_timeout_s
        self.axis = axis
        self.name = name
        self.plan = plan
        self.procedure = procedure
        self.trail = trail
        self.ip_mode = ip_mode
        self._request = request
        self._wire_cycle = wire_cycle
        self._phase = phase
        self._statusword = statusword
        self._period_s = period_s
        self._outcome: HomingOutcome | None = None
        self._refused: Phase | None = None
        self._done = threading.Event()

    # the cycle loop's notices (fieldbus.cycle_loop)
    def on_outcome(self, outcome: HomingOutcome) -> None:
        if self._outcome is None:
            self._outcome = outcome
            self._done.set()

    def on_refused(self, phase: Phase) -> None:
        self._refused = phase
        self._done.set()

    # ------------------------------------------------------------------ the run
    def run(self) -> HomingOutcome:
        sdo = self.trail.node.sdo
        plain_timeout = sdo.RESPONSE_TIMEOUT
        sdo.RESPONSE_TIMEOUT = max(plain_timeout, HOMING_SDO_TIMEOUT_S)
        try:
            return self._run()
        finally:
            sdo.RESPONSE_TIMEOUT = plain_timeout

    def _run(self) -> HomingOutcome:
        where = f"axis {self.name}: node {self.trail.node_id}: homing method {self.procedure.method}"
        self._request(Request(Req.HOME, self.axis))
        self._wait_for_phase(Phase.HOMING, where)
        self._settle()
        try:
            for write in self.plan.writes:
                bringup._write(self.trail, write)  # type: ignore[arg-type]  # ObjectWrite has Write's fields
            bringup._read_back(self.trail, ReadBack("set homing mode", c.MODES_OF_OPERATION_DISPLAY, 0,
                                                    self.plan.mode_check))
        except FieldbusError as err:
            self._restore(where)
            raise FieldbusError(f"{where}: {_sdo_step(err)}") from None
        self._done.clear()
        self._request(Request(Req.HOME_START, self.procedure))
        outcome = self._wait_for_outcome(where)
        self._restore(where)
        return outcome

    def _wait_for_phase(self, phase: Phase, where: str) -> None:
        end = time.monotonic() + PHASE_TIMEOUT_S
        while self._phase() is not phase:
            if self._refused is not None:
                raise FieldbusError(f"{where}: not started: the axes are not holding (phase {self._refused.value})")
            if time.monotonic() > end:
                raise FieldbusError(f"{where}: the cycle loop did not reach phase {phase.value} "
                                    f"(phase {self._phase().value})")
            time.sleep(self._period_s)

    def _settle(self, cycles: int = SETTLE_CYCLES) -> None:
        """Wait until the commands computed so far have been on the wire for ``cycles`` cycles."""
        target = self._wire_cycle() + cycles + 1
        end = time.monotonic() + (cycles + 2) * self._period_s + PHASE_TIMEOUT_S
        while self._wire_cycle() < target and time.monotonic() < end:
            time.sleep(self._period_s)

    def _wait_for_outcome(self, where: str) -> HomingOutcome:
        end = time.monotonic() + self.procedure.timeout_s + OUTCOME_MARGIN_S
        while not self._done.wait(0.05):
            if self._phase() is not Phase.HOMING:
                word = self._statusword()
                raise FieldbusError(f"{where}: ended by a fault or stop while homing (phase {self._phase().value}, "
                                    f"statusword {'none' if word is None else f'0x{word:04X}'}); see the faults")
            if time.monotonic() > end:
                return HomingOutcome(False, f"{where}: no outcome from the cycle loop within "
                                            f"{self.procedure.timeout_s + OUTCOME_MARGIN_S:g} s")
        assert self._outcome is not None
        return self._outcome

    def _read_position(self) -> int:
        """0x6064 by SDO; read again once when the answer was a stray one meant for an earlier
        request (canopen: "Node returned a value for 0x6061:00 instead", "Unexpected response
        0x60"): seen on vcan0 inside User-Mode Linux after a homing, cause not found."""
        step = "homing: read position actual"
        try:
            return bringup.read(self.trail, step, c.POSITION_ACTUAL)
        except FieldbusError as err:
            if "instead" not in str(err) and "Unexpected response" not in str(err):
                raise
            log.warning(kv("homing_sdo_stale_answer", axis=self.name, node=self.trail.node_id, error=err))
            return bringup.read(self.trail, step, c.POSITION_ACTUAL)

    def _restore(self, where: str) -> None:
        """Steps 4-6: hold where the drive stands, streaming mode back, follow set-points again."""
        if self._phase() is not Phase.HOMING:
            return  # a fault ended the phase: the drives are quick-stopped; reset brings them up again
        try:
            position = self._read_position()
            self._request(Request(Req.HOME_HOLD, position))
            self._settle()
            for write in self.plan.restore:
                bringup._write(self.trail, write)  # type: ignore[arg-type]
                bringup._read_back(self.trail, ReadBack(write.step, c.MODES_OF_OPERATION_DISPLAY, 0, write.value))
        except FieldbusError as err:
            self._request(Request(Req.QUICK_STOP, "faulted"))
            log.error(kv("homing_restore_failed", axis=self.name, error=err))
            raise FieldbusError(f"{where}: the streaming mode could not be restored ({_sdo_step(err)}); the axes "
                                f"were quick-stopped: send reset") from None
        self._request(Request(Req.HOME_END))
        self._wait_for_phase(Phase.HOLDING, where)
        self._settle()
        end = time.monotonic() + self._ready_timeout_s
        while not is_ready(self._statusword() or 0, self.ip_mode):
            if time.monotonic() > end:
                word = self._statusword()
                raise FieldbusError(f"{where}: the drive does not follow set-points again after homing "
                                    f"(statusword {'none' if word is None else f'0x{word:04X}'})")
            time.sleep(self._period_s)
        log.info(kv("homing_restored", axis=self.name, node=self.trail.node_id, position_counts=position))


def _sdo_step(err: FieldbusError) -> str:
    """A bring-up helper's SDO error without its "node N: bring-up step" prefix (the homing
    error names axis, node and method already): "step 'set homing mode': SDO abort ..."."""
    text = str(err)
    return text.split(": bring-up ", 1)[1] if ": bring-up step " in text else text
