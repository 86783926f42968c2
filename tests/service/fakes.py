"""A small in-test MotionLink: a thread plays the set-points one per (short) cycle."""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Callable

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus.reports import AxisStatus, CycleStats, FaultReport, JobResult, MasterStatus
from nurbsmotion.planning import Trajectory
from nurbsmotion.service.job_common import PlannedJob


class FakeJob:
    def __init__(self, link: "FakeLink", counts: np.ndarray) -> None:
        self.link, self.counts = link, counts
        self.index = -1
        self.start_cycle = link.cycle + 1  # the link's cycle counter when the job's first row plays
        self.stop_flag = ""
        self.done = threading.Event()
        self.result: JobResult | None = None
        self.fell_behind_row = -1

    def wait(self, timeout: float | None = None) -> JobResult | None:
        return self.result if self.done.wait(timeout) else None

    def request_stop(self) -> None:
        self.stop_flag = "stopped"

    def abort(self) -> None:
        self.stop_flag = "aborted"


class FakeLink:
    def __init__(self, config: MachineConfig, cycle_s: float = 0.001) -> None:
        self.axis_map = AxisMap.from_config(config)
        self.names = [a.name for a in config.axes]
        self.held = [0] * len(self.names)
        self.phase = "holding"
        self.faults: list[FaultReport] = []
        self.job: FakeJob | None = None
        self.rate = 1.0
        self.cycle_s = cycle_s
        self.shut = False
        self.fault_at: int | None = None  # index at which the running job faults
        self.feedback = None  # record_feedback's sink: called once per axis per played row
        self.fault_kind, self.fault_code = "emcy", 0x2310  # what the fault at fault_at is
        self.cycle = 1000  # a link cycle counter that does not start with the job

    def bring_up(self) -> None:
        self.phase = "holding"

    def stream(self, counts: np.ndarray, on_progress: Callable[[int, int], None] | None = None,
               pauses: tuple[int, ...] = ()) -> FakeJob:
        if self.phase != "holding" or self.job is not None:
            raise FieldbusError(f"stream: the axes are not holding (phase {self.phase})")
        if np.any(counts[0] != self.held):
            raise InputError("set-points", "the job does not start at the held position")
        job = self.job = FakeJob(self, counts)
        self.phase = "streaming"
        threading.Thread(target=self._play, args=(job,), daemon=True).start()
        return job

    def stream_feed(self, feed, on_progress=None) -> FakeJob:
        """A streamed job (fieldbus.row_source.RowFeed): its rows are played as they arrive."""
        if feed.planned_end == 0:
            feed.take_first()
        return self.stream(RowsSoFar(feed))

    def _play(self, job: FakeJob) -> None:
        outcome = "done"
        stop = threading.Event()
        i = -1
        while True:
            i += 1
            if not (job.counts.has(i) if isinstance(job.counts, RowsSoFar) else i < len(job.counts)):
                break
            stop.wait(self.cycle_s)
            job.index = i
            self.cycle = job.start_cycle + i
            self.held = [int(c) for c in job.counts[i]]
            sink = self.feedback
            if sink is not None:
                for axis, position in enumerate(self.held):
                    sink(self.cycle, axis, 0x1237, position, 1000.0 + i * self.cycle_s)
            if self.fault_at is not None and i >= self.fault_at:
                self.faults.append(FaultReport(2, "Y", self.fault_kind, self.fault_code, self.cycle,
                                               f"node 2 (axis Y): {self.fault_kind} at cycle {self.cycle}"))
                self.phase, outcome = "quick_stop", "faulted"
                break
            if job.stop_flag:
                self.phase = "quick_stop" if job.stop_flag == "aborted" else "holding"
                outcome = job.stop_flag
                break
        if outcome == "done":
            self.phase = "holding"
        self.job = None
        job.result = JobResult(outcome, job.index + 1, len(job.counts), tuple(self.faults if outcome == "faulted" else ()),
                               0, 0)
        job.done.set()

    @staticmethod
    def next_cycle_wake_s() -> float | None:
        return None  # no cycle loop: the status publisher only lets go of the lock between its steps

    cycle_slack = None  # no cycle thread: the status publisher runs its rounds itself

    def status(self, percentiles: bool = True) -> MasterStatus:
        job = self.job
        axes = tuple(AxisStatus(n, i + 1, "OPERATION ENABLED", 0x1237, self.held[i], self.held[i], 0, 0, 0, None)
                     for i, n in enumerate(self.names))
        return MasterStatus(self.phase, 0, axes, CycleStats(0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0),
                            job.index if job else None, len(job.counts) if job else None, tuple(self.faults))

    def reset_faults(self) -> None:
        if self.job is not None:
            raise FieldbusError("reset faults: a job is still running")
        self.phase = "holding"

    def set_rate(self, rate: float) -> None:
        self.rate = rate

    def record_traffic(self, path: str | None) -> None:
        self.traffic = path

    def record_feedback(self, sink) -> None:
        self.feedback = sink

    def shutdown(self, timeout_s: float = 5.0) -> None:
        if self.job is not None:
            self.job.request_stop()
            self.job.done.wait(timeout_s)
        self.shut = True
        self.phase = "offline"


class RowsSoFar:
    """The rows of a RowFeed as a growing array for FakeLink._play (index and len only)."""

    def __init__(self, feed) -> None:
        self.feed = feed
        self.last_index = -1.0

    def __len__(self) -> int:
        return self.feed.planned_end

    def has(self, i: int) -> bool:
        """Row i is (or becomes) available: waits for the producer (the playing thread only)."""
        feed = self.feed
        while i >= feed.planned_end:
            if feed.take(self.last_index, False) is None:
                if feed.final or (feed._closed and not feed.waiting):
                    return False
                threading.Event().wait(0.001)
        return True

    def __getitem__(self, i):
        self.last_index = float(i)
        return np.array([self.feed[i, j] for j in range(self.feed.n_axes)])


class FakePlannedJob(PlannedJob):
    def write_trace(self, path) -> None:
        np.savetxt(path, self.trajectory.position_mm, delimiter=",", header="x_mm,y_mm,z_mm", comments="")


def line_plan(config: MachineConfig, start_mm: np.ndarray, end_x_mm: float, cycles: int) -> PlannedJob:
    """A straight X move of ``cycles`` set-points (stand-in for the real planner)."""
    x = np.linspace(start_mm[0], end_x_mm, cycles)
    pos = np.column_stack([x, np.full(cycles, start_mm[1]), np.full(cycles, start_mm[2])])
    traj = Trajectory("fake", config.cycle_period_s, np.zeros(cycles, np.int32), np.linspace(0, 1, cycles), pos,
                      np.full(cycles, 10.0))
    counts = AxisMap.from_config(config).to_counts(pos)
    return FakePlannedJob(traj, counts, {"program": "line", "cycles": cycles}, 1.2)


def fake_planner(config: MachineConfig, cycles: int = 200) -> Callable[..., PlannedJob]:
    """Programs are 'X<end>' (one line) or 'bad' (rejected with a file:line error)."""
    def planner(name: str, text: str, start_mm: np.ndarray, options: object = None) -> PlannedJob:
        if not text.startswith("X"):
            raise InputError(f"{name}:1", f"unknown word {text.split()[0]!r}")
        return line_plan(config, start_mm, float(text[1:]), cycles)
    return planner


def with_data_dir(config: MachineConfig, data_dir: str, socket: str) -> MachineConfig:
    return replace(config, data_dir=data_dir, control=replace(config.control, socket=socket))
