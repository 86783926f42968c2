"""What the service needs from the fieldbus: the MotionLink protocol (fieldbus.Master has
this shape), the BusHost part of it other nodes join (service.devices) and the simulation
hooks available when ``simulate: true``.

The service only ever sees counts, status snapshots (fieldbus.reports records) and job
handles; open_link() in service.link builds the real thing.
"""

from __future__ import annotations

from typing import Callable, Protocol

import canopen
import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.fieldbus.cycle_slack import CycleSlack
from nurbsmotion.fieldbus.cyclic_velocity import CyclicVelocity
from nurbsmotion.fieldbus.homing import HomingOutcome, HomingPlan, HomingProcedure
from nurbsmotion.fieldbus.reports import JobResult, MasterStatus
from nurbsmotion.fieldbus.row_source import RowFeed


class JobHandle(Protocol):
    start_cycle: int  # master cycle that sends the job's first set-point (-1 until it started)

    @property
    def fell_behind_row(self) -> int: ...  # a streamed job that ran onto its stop tail: its last planned row (-1: did not)


    def wait(self, timeout: float | None = None) -> JobResult | None: ...
    def request_stop(self) -> None: ...
    def abort(self) -> None: ...
    def hold(self) -> None: ...
    def resume(self) -> None: ...


class BusHost(Protocol):
    """The bus the axes run on, as the spindle and I/O node join it (service.devices)."""

    cyclic_velocity: CyclicVelocity | None  # the csv spindle's per-SYNC 0x60FF slot

    @property
    def network(self) -> canopen.Network | None: ...  # None until connected
    def receive_from(self, node_id: int, cob_ids: tuple[int, ...] = ()) -> None: ...  # its frames pass the filter
    def judging_time_s(self) -> float: ...  # now on the frames' arrival timeline (heartbeat judging)
    def quick_stop(self, reason: str) -> None: ...  # every axis, now (an e-stop input)


class MotionLink(BusHost, Protocol):
    axis_map: AxisMap
    next_cycle_wake_s: Callable[[], float | None]  # perf_counter time the cycle thread wakes next

    @property
    def cycle_slack(self) -> CycleSlack | None: ...  # runs short steps in the cycle thread's slack (None: no such thread)

    def bring_up(self) -> None: ...
    def stream(self, counts: np.ndarray, on_progress: Callable[[int, int], None] | None = None,
               pauses: tuple[int, ...] = ()) -> JobHandle: ...
    def stream_feed(self, feed: RowFeed, on_progress: Callable[[int, int], None] | None = None) -> JobHandle: ...
    def status(self, percentiles: bool = True) -> MasterStatus: ...  # False: the last read's lateness quantiles
    def reset_faults(self) -> None: ...
    def set_rate(self, rate: float) -> None: ...
    def record_traffic(self, path: str | None) -> None: ...
    def record_feedback(self, sink: Callable[[int, int, int, int, float], None] | None) -> None: ...
    def shutdown(self, timeout_s: float = 5.0) -> None: ...
    def home(self, i: int, plan: HomingPlan, procedure: HomingProcedure) -> HomingOutcome: ...
    def stop_homing(self, quick: bool = False) -> None: ...


class Simulation(Protocol):
    """Simulated drives in the daemon's process: fault injection and set-point recordings."""

    def inject(self, spec: str) -> None: ...
    def clear_recordings(self) -> None: ...
    def write_recordings(self, folder: str, slack: CycleSlack | None = None) -> list[str]: ...
    def stop(self) -> None: ...
