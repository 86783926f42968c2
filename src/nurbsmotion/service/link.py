"""The real MotionLink: fieldbus.Master (whose playback rate carries the feed override, see
fieldbus.stop_ramp) and, when ``simulate: true``, the simulated drives started first on the
same bus channel.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.cycle_slack import CycleSlack, run_steps
from nurbsmotion.log import kv
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY, SIM_DRIVES_PRIORITY

log = logging.getLogger(__name__)


class SimulatedDrives:
    """The simulated drives of every configured axis on the configured bus (simulate: true).

    The drives record every applied set-point; the daemon keeps what a job applied (from
    :meth:`clear_recordings` at submit to :meth:`write_recordings` at its end) and drops the
    rest every ``IDLE_CLEAR_S`` while no job records, so an idle daemon does not grow.
    """

    IDLE_CLEAR_S = 10.0

    def __init__(self, config: MachineConfig, home_sensors: dict[int, Any] | None = None,
                 rt_priority: int | None = None) -> None:
        """``rt_priority``: SCHED_FIFO priority of the drives' receive and ticker threads, for
        drives sharing the process with a SCHED_FIFO master (sim.network.SimNetwork.rt_priority)."""
        from nurbsmotion.sim import SimNetwork

        from nurbsmotion.sim.machine_sensors import machine_home_sensors

        sensors = {**machine_home_sensors(config), **(home_sensors or {})}  # axes[i].sim, then the caller's
        self.network = SimNetwork.for_machine(config, home_sensors=sensors)
        self._lock = threading.Lock()
        self._recording = False
        self._stop = threading.Event()
        self._janitor = threading.Thread(target=self._clear_while_idle, name="sim-recording-janitor", daemon=True)
        self.rt_priority = rt_priority

    def start(self) -> "SimulatedDrives":
        self.network.rt_priority = self.rt_priority
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

    def write_recordings(self, folder: str, slack: CycleSlack | None = None, settle_s: float = 0.5) -> list[str]:
        """Write each drive's recording once it holds the set-points already sent: the last
        one takes effect at the next SYNC, so wait for two more applied rows (or ``settle_s``,
        e.g. when the drives are disabled and record nothing). The rows are formatted in
        the cycle thread's ``slack`` while it runs (fieldbus.cycle_slack): in one go they held
        the interpreter lock ~30 ms per drive of a 20 s job, and the cycle thread waited;
        the files are written here (chunked_file)."""
        from nurbsmotion.sim.network import write_tables

        drives = list(self.network.drives.values())
        wanted = [len(d.recorder) + 2 for d in drives]
        deadline = time.monotonic() + settle_s
        while any(len(d.recorder) < n for d, n in zip(drives, wanted)) and time.monotonic() < deadline:
            time.sleep(0.002)
        with self._lock:
            self._recording = False
            tables = run_steps(self.network.recording_steps(folder), slack, bulk=True)
        return [str(p) for p in write_tables(tables)]  # in this thread, a system call a chunk

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


ENABLE_STEPS = 4  # CiA 402 power-up: shutdown, switch on, enable operation, enable interpolation (IP)
MIN_ENABLE_PHASE_S = 5.0  # the master's own default for the whole enable phase


def enable_phase_timeout_s(step_timeout_s: float) -> float:
    """The drives' whole enable phase may take every step's time-out (``bus.drive_step_timeout_ms``):
    a drive that answers each step within its limit must not fail the phase; at least 5 s."""
    return max(MIN_ENABLE_PHASE_S, ENABLE_STEPS * step_timeout_s)


def open_link(config: MachineConfig, home_sensors: dict[int, Any] | None = None
              ) -> tuple[Master, SimulatedDrives | None]:
    """Start the simulated drives (if configured; their switches and index pulses from each
    axis' ``sim`` section, or ``home_sensors`` {node id: sim.HomeSensors} for a node), bring every axis up; FieldbusError names the node and the step if
    that fails (and everything started is stopped again)."""
    # the drives' threads SCHED_FIFO just below the master's: each stands in for a drive's own CPU
    simulation = SimulatedDrives(config, home_sensors, SIM_DRIVES_PRIORITY).start() if config.simulate else None
    step_timeout_s = config.bus.drive_step_timeout_ms / 1000.0
    master = Master(config, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze",  # the daemon's process settings
                    stuck_timeout_s=step_timeout_s, enable_timeout_s=enable_phase_timeout_s(step_timeout_s),
                    sdo_timeout_s=config.bus.sdo_timeout_ms / 1000.0)
    try:
        master.bring_up()
    except BaseException:
        master.shutdown(2.0)
        if simulation is not None:
            simulation.stop()
        raise
    return master, simulation
