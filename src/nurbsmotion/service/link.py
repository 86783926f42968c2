"""The real MotionLink: fieldbus.Master (+ a playback rate for the feed override) and, when
``simulate: true``, the simulated drives started first on the same bus channel.

RateMaster is a small wrapper owned by the service: fieldbus.Master streams one planned row
per cycle; here the streaming phase plays the rows at a rate r (fractional rows per cycle,
linear interpolation between rows, like the master's own controlled-stop ramp) and r moves
towards the requested rate by RAMP_SHARE of the master's stop-ramp slope per cycle, so a
rate change adds at most RAMP_SHARE·a_max (see fieldbus.stop_ramp and service.rate). A controlled stop
starts from the current position and rate, with a slope that leaves room for the plan's
own acceleration (service.rate.stop_slope). A controlled stop starts from the current
position and rate. Replace it by the master's own rate control once it has one.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus import Job, Master
from nurbsmotion.fieldbus.stop_ramp import setpoints_at
from nurbsmotion.log import kv
from nurbsmotion.service.rate import RAMP_SHARE, stop_slope

log = logging.getLogger(__name__)


class RateMaster(Master):
    """fieldbus.Master with :meth:`set_rate` (feed override as playback rate)."""

    def __init__(self, config: MachineConfig, *args: Any, **kwargs: Any) -> None:
        super().__init__(config, *args, **kwargs)
        self._rate_target = 1.0
        self._accel_limits = [float(a) for a in self.axis_map.max_accel_counts_s2(config.interpolation.max_accel_mm_s2)]

    def set_rate(self, rate: float) -> None:
        """Playback rate for the running and the next jobs (1.0 = as planned, 0 = pause)."""
        self._rate_target = max(0.0, float(rate))

    def stream(self, counts: np.ndarray, on_progress: Callable[[int, int], None] | None = None) -> Job:
        job = super().stream(counts, on_progress)
        arr = np.asarray(counts, dtype=np.int64)
        job.playback_s = 0.0  # type: ignore[attr-defined]
        job.playback_r = self._rate_target  # type: ignore[attr-defined]
        # per-axis figures for the stop slope, as plain floats for the cycle loop
        job.max_step = (np.abs(np.diff(arr, axis=0)).max(axis=0) if len(arr) > 1  # type: ignore[attr-defined]
                        else np.zeros(arr.shape[1])).astype(float).tolist()
        job.planned_accel = ((np.abs(np.diff(arr, n=2, axis=0)).max(axis=0) if len(arr) > 2  # type: ignore[attr-defined]
                              else np.zeros(arr.shape[1])) / self._period_s**2).astype(float).tolist()
        return job

    def _compute(self, k: int) -> None:
        if self._phase != "streaming":
            super()._compute(k)
            return
        job = self._job
        assert job is not None
        sp, n = self._sp, self._n
        if job.index < 0:
            s = 0.0
        else:
            r, target, dr = job.playback_r, self._rate_target, job.ramp.dr * RAMP_SHARE
            r = min(r + dr, target) if r < target else max(r - dr, target)
            job.playback_r = r
            s = min(job.playback_s + r, float(job.last))
        job.playback_s = s
        setpoints_at(job.rows, s, sp, n)
        self._cw[:] = self._run_cw
        i = int(s)
        job.index = i
        if i == job.last:
            self._hold[:] = sp
            self._set_phase("holding", k)
            job.outcome, job.finish_cycle = "done", k + 1

    def _start_controlled_stop(self, k: int, outcome: str) -> None:
        super()._start_controlled_stop(k, outcome)
        job = self._job
        if job is not None and hasattr(job, "playback_s"):
            job.ramp.s = job.playback_s
            job.ramp.r = job.playback_r
            job.ramp.dr = stop_slope(job.max_step, job.planned_accel, self._accel_limits, self._period_s,
                                     job.playback_r, job.ramp.dr)


class SimulatedDrives:
    """The simulated drives of every configured axis on the configured bus (simulate: true).

    The drives record every applied set-point; the daemon keeps what a job applied (from
    :meth:`clear_recordings` at submit to :meth:`write_recordings` at its end) and drops the
    rest every ``IDLE_CLEAR_S`` while no job records, so an idle daemon does not grow.
    """

    IDLE_CLEAR_S = 10.0

    def __init__(self, config: MachineConfig) -> None:
        from nurbsmotion.sim import SimNetwork

        self.network = SimNetwork.for_machine(config)
        self._lock = threading.Lock()
        self._recording = False
        self._stop = threading.Event()
        self._janitor = threading.Thread(target=self._clear_while_idle, name="sim-recording-janitor", daemon=True)

    def start(self) -> "SimulatedDrives":
        self.network.start()
        self._janitor.start()
        log.info(kv("simulated_drives", channel=self.network.channel, nodes=sorted(self.network.drives)))
        return self

    def inject(self, spec: str) -> None:
        from nurbsmotion.sim import parse_fault_spec

        self.network.inject(parse_fault_spec(spec))

    def clear_recordings(self) -> None:
        """Start a job's recording (before its first set-point is sent)."""
        with self._lock:
            self._recording = True
            self._clear()

    def write_recordings(self, folder: str, settle_s: float = 0.5) -> list[str]:
        """Write each drive's recording once it holds the set-points already sent: the last
        one takes effect at the next SYNC, so wait for two more applied rows (or ``settle_s``,
        e.g. when the drives are disabled and record nothing)."""
        drives = list(self.network.drives.values())
        wanted = [len(d.recorder) + 2 for d in drives]
        deadline = time.monotonic() + settle_s
        while any(len(d.recorder) < n for d, n in zip(drives, wanted)) and time.monotonic() < deadline:
            time.sleep(0.002)
        with self._lock:
            self._recording = False
            return [str(p) for p in self.network.write_recordings(folder)]

    def _clear(self) -> None:
        for drive in self.network.drives.values():
            drive.recorder.clear()

    def _clear_while_idle(self) -> None:
        while not self._stop.wait(self.IDLE_CLEAR_S):
            with self._lock:
                if not self._recording:
                    self._clear()

    def stop(self) -> None:
        self._stop.set()
        if self._janitor.is_alive():
            self._janitor.join(2.0)
        self.network.stop()


def open_link(config: MachineConfig) -> tuple[RateMaster, SimulatedDrives | None]:
    """Start the simulated drives (if configured), bring every axis up; FieldbusError names
    the node and the step if that fails (and everything started is stopped again)."""
    simulation = SimulatedDrives(config).start() if config.simulate else None
    master = RateMaster(config)
    try:
        master.bring_up()
    except BaseException:
        master.shutdown(2.0)
        if simulation is not None:
            simulation.stop()
        raise
    return master, simulation
