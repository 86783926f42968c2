"""A simulated drive's fault injections (see ``faults``): pending ones by time and by SYNC
index, and the active effects (SYNCs ignored, RPDOs dropped, SDO writes refused)."""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Callable
from typing import Any

from canopen.sdo import SdoAbortedError

from nurbsmotion.can.cia402 import EmcyCode
from nurbsmotion.log import kv
from nurbsmotion.sim.axis import Cia402Axis
from nurbsmotion.sim.faults import DEFAULT_FAULT_CODE, DEFAULT_SDO_ABORT_CODE, FaultInjection
from nurbsmotion.sim.servo import ServoModel

log = logging.getLogger(__name__)

_FOREVER = math.inf


class Injections:
    """Pending and active injections of drive ``node_id``; ``silence`` makes it go silent."""

    def __init__(self, node_id: int, axis: Cia402Axis, servo: ServoModel, silence: Callable[[], None]) -> None:
        self._node_id = node_id
        self._axis = axis
        self._servo = servo
        self._silence = silence
        self._seq = 0
        self.clear()

    def clear(self) -> None:
        """Cancel pending and active injections (the servo's stall is the caller's)."""
        self.ignore_syncs: float = 0
        self.drop_rpdos = 0
        self.sdo_refusals: list[list[Any]] = []  # [index|None, subindex|None, code, remaining]
        self.time_faults: list[tuple[float, int, FaultInjection]] = []  # (at_s, order, fault)
        self.sync_faults: list[tuple[int, int, FaultInjection]] = []  # (at_sync, order, fault)
        self.deferred: list[FaultInjection] = []  # immediate, injected before attach

    def schedule(self, fault: FaultInjection) -> bool:
        """Keep ``fault`` for its SYNC index or time; False if it is due at once."""
        self._seq += 1
        if fault.at_sync is not None:
            bisect.insort(self.sync_faults, (fault.at_sync, self._seq, fault))
        elif fault.at_s is not None:
            bisect.insort(self.time_faults, (fault.at_s, self._seq, fault))
        else:
            return False
        return True

    def due_by_time(self, now: float, t0: float) -> list[FaultInjection]:
        """The timed faults due at ``now`` (attached at ``t0``), taken off the list."""
        due = []
        while self.time_faults and t0 + self.time_faults[0][0] <= now:
            due.append(self.time_faults.pop(0)[2])
        return due

    def next_due_s(self) -> float:
        """When (s after attach) the next timed fault is due (inf: none)."""
        return self.time_faults[0][0] if self.time_faults else math.inf

    def next_due_at_sync(self, sync_index: int) -> FaultInjection | None:
        """The next fault due at or before SYNC ``sync_index``, taken off the list."""
        if self.sync_faults and self.sync_faults[0][0] <= sync_index:
            return self.sync_faults.pop(0)[2]
        return None

    def take_ignored_sync(self) -> bool:
        """True if this SYNC is to be ignored (one fewer to ignore)."""
        if self.ignore_syncs > 0:
            self.ignore_syncs -= 1
            return True
        return False

    def take_dropped_rpdo(self) -> bool:
        """True if this RPDO is to be dropped (one fewer to drop)."""
        if self.drop_rpdos > 0:
            self.drop_rpdos -= 1
            return True
        return False

    def check_refusal(self, index: int, subindex: int) -> None:
        """Raise the SDO abort of an active refusal that matches (index, subindex)."""
        for refusal in self.sdo_refusals:
            want_index, want_sub, code, remaining = refusal
            if (want_index is None or want_index == index) and (want_sub is None or want_sub == subindex):
                refusal[3] = remaining - 1
                if refusal[3] <= 0:
                    self.sdo_refusals.remove(refusal)
                raise SdoAbortedError(code)

    def apply(self, fault: FaultInjection, sync_index: int) -> None:
        """The effect of ``fault`` (faults module docstring), now (at SYNC ``sync_index``)."""
        log.warning(kv("sim.inject", node=self._node_id, kind=fault.kind, sync=sync_index))
        kind = fault.kind
        if kind == "fault":
            self._axis.raise_fault(fault.code if fault.code is not None else DEFAULT_FAULT_CODE)
        elif kind in ("heartbeat_stop", "power_loss"):
            self._silence()
        elif kind == "ignore_sync":
            self.ignore_syncs = fault.count if fault.count is not None else _FOREVER
        elif kind == "following_error":
            self._axis.raise_fault(EmcyCode.FOLLOWING_ERROR, following_error=True)
        elif kind == "stall":
            self._servo.stalled = True
        elif kind == "drop_rpdo":
            self.drop_rpdos += fault.count if fault.count is not None else 1
        elif kind == "sdo_abort":
            code = fault.code if fault.code is not None else DEFAULT_SDO_ABORT_CODE
            remaining = fault.count if fault.count is not None else _FOREVER
            self.sdo_refusals.append([fault.index, fault.subindex, code, remaining])
