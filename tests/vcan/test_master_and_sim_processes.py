"""The master and the simulated drives in two processes on a real kernel vcan0: what users
run (`nurbsmotion sim --config` next to the controller). Every streamed set-point must be
applied by its drive exactly once, in order."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

import nurbsmotion
from nurbsmotion.config import load_config
from nurbsmotion.fieldbus import Master
from nurbsmotion.sim import read_csv

from tests.vcan.conftest import CYCLE_PERIOD_S

pytestmark = pytest.mark.vcan

SIM_READY_TIMEOUT_S = 30.0  # python start-up inside User-Mode Linux takes a few seconds
SIM_STOP_TIMEOUT_S = 10.0
JOB_CYCLES = 300  # 1.2 s at 4 ms
JOB_TIMEOUT_S = 30.0
AXES = [  # name, node, mode, stroke in mm
    ("X", 1, "csp", 20.0),
    ("Y", 2, "csp", 12.0),
    ("Z", 3, "ip", 5.0),
]
# Inside User-Mode Linux (one slow CPU shared by both processes) feedback can arrive tens of
# ms late, which the master would report as a following error: this test is about every
# set-point arriving, so the window is wider than any stroke.
FOLLOWING_ERROR_WINDOW_MM = 50.0
COUNTS_PER_MM = 1000


def write_vcan_config(tmp_path: Path, channel: str) -> Path:
    """A machine of three drives (two CSP, one IP) on `channel` at CYCLE_PERIOD_S."""
    config = {
        "cycle_period_ms": CYCLE_PERIOD_S * 1000,
        "bus": {"interface": "socketcan", "channel": channel, "bitrate": 1_000_000},
        "axes": [{"name": name, "node_id": node, "mode": mode, "counts_per_mm": COUNTS_PER_MM,
                  "soft_limits_mm": [-100, 100], "max_velocity_mm_s": 400, "max_accel_mm_s2": 5000,
                  "following_error_window_mm": FOLLOWING_ERROR_WINDOW_MM} for name, node, mode, _ in AXES],
        "monitoring": {"heartbeat_producer_ms": 100, "heartbeat_consumer_ms": 500, "max_bus_load": 0.8},
        "data_dir": str(tmp_path / "var"),
    }
    path = tmp_path / "vcan.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def strictly_increasing_job(start_counts: list[int], cycles: int) -> np.ndarray:
    """(cycles, n_axes) int32 set-points: a smooth move of each axis' stroke, every row
    different from the one before, so a lost or repeated set-point shows in the recording."""
    s = (1.0 - np.cos(np.pi * np.arange(1, cycles + 1) / cycles)) / 2.0  # 0..1, smooth ends
    strokes = np.array([stroke * COUNTS_PER_MM for *_, stroke in AXES])
    rows = np.asarray(start_counts) + np.round(s[:, None] * strokes[None, :]).astype(np.int64)
    rows += np.arange(1, cycles + 1)[:, None]  # +1 count per cycle: strictly increasing
    return rows.astype(np.int32)


class SimProcess:
    """`python -m nurbsmotion sim` as a child process, started and stopped by the test."""

    def __init__(self, config_path: Path, record_dir: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(Path(nurbsmotion.__file__).parents[1]))
        self.process = subprocess.Popen(
            [sys.executable, "-m", "nurbsmotion", "sim", "--config", str(config_path), "--record-dir", str(record_dir)],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)
        self.log: list[str] = []
        self.ready = threading.Event()
        self._reader = threading.Thread(target=self._read_log, daemon=True)
        self._reader.start()

    def _read_log(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.log.append(line.rstrip())
            if "sim.ready" in line:
                self.ready.set()

    def wait_ready(self) -> None:
        if not self.ready.wait(SIM_READY_TIMEOUT_S):
            self.stop()
            pytest.fail("simulated drives not ready within "
                        f"{SIM_READY_TIMEOUT_S:g} s; their log:\n" + "\n".join(self.log))

    def stop(self) -> int:
        """SIGTERM (the sim writes its recordings on the way out), kill if it hangs."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(SIM_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(SIM_STOP_TIMEOUT_S)
        self._reader.join(SIM_STOP_TIMEOUT_S)
        return self.process.returncode


@pytest.fixture
def sim_process(vcan0: str, tmp_path: Path):
    """Factory: start the simulated drives of a config in a separate process; always stopped."""
    started: list[SimProcess] = []

    def start(config_path: Path) -> SimProcess:
        sim = SimProcess(config_path, tmp_path / "recordings")
        started.append(sim)
        sim.wait_ready()
        return sim

    yield start
    for sim in started:
        sim.stop()


def applied_setpoints(record_dir: Path, node_id: int) -> np.ndarray:
    return np.array([r.setpoint_counts for r in read_csv(record_dir / f"node{node_id}.csv")], dtype=np.int64)


def assert_applied_once_in_order(applied: np.ndarray, sent: np.ndarray, hold_before: int, name: str) -> None:
    """The drive applied: the held position, then every sent set-point once in order, then
    the last one held."""
    moving = np.flatnonzero(applied != hold_before)
    assert moving.size, f"axis {name}: no set-point of the job was applied"
    first = moving[0]
    streamed = applied[first:first + len(sent)]
    lost_or_repeated = np.flatnonzero(streamed != sent[:len(streamed)])
    assert len(streamed) == len(sent) and not lost_or_repeated.size, (
        f"axis {name}: applied set-points differ from the sent ones from job row "
        f"{lost_or_repeated[0] if lost_or_repeated.size else len(streamed)} on")
    assert (applied[first + len(sent):] == sent[-1]).all(), f"axis {name}: did not hold the last set-point"


def test_master_streams_to_simulated_drives_in_another_process_on_vcan0(vcan0, tmp_path, sim_process):
    config_path = write_vcan_config(tmp_path, vcan0)
    sim = sim_process(config_path)

    # SYNC from the cycle loop: see docs/vcan.md for why the kernel-BCM SYNC ('auto' on
    # socketcan) loses set-points when its period drifts against the loop's.
    with Master(load_config(config_path), sync_source="loop") as master:
        master.bring_up()
        held = [axis.position_counts for axis in master.status().axes]
        job_rows = strictly_increasing_job(held, JOB_CYCLES)
        result = master.stream(job_rows).wait(JOB_TIMEOUT_S)
        timing = master.status().timing
    assert sim.stop() == 0, "\n".join(sim.log)

    diagnosis = f"master {timing}; drives: " + "; ".join(line.split("sim.summary ")[-1] for line in sim.log
                                                         if "sim.summary" in line)
    assert result is not None, f"job not finished within {JOB_TIMEOUT_S:g} s; {diagnosis}"
    assert result.outcome == "done", f"{result}; {diagnosis}"
    for j, (name, node_id, _, _) in enumerate(AXES):
        applied = applied_setpoints(tmp_path / "recordings", node_id)
        assert_applied_once_in_order(applied, job_rows[:, j].astype(np.int64), held[j], f"{name} ({diagnosis})")
