"""Set-point stream benchmark: what reaches the wire while the master is frozen.

Three CSP drives (nurbsmotion.sim) and a master stream one job of strictly increasing
set-points (a smooth 20 mm move plus one count per cycle, so a lost or repeated set-point
shows). Once per run, 40 % into the job, the master's process is frozen with SIGSTOP for
the given time (0 = no stall). An independent listener records every SYNC and RPDO1 with
its timestamp (kernel timestamps on vcan0; send timestamps on the virtual bus) and gives:
SYNC interval min/p50/p99/max, drift in ppm (mean interval against T), share of intervals
outside ±5 % of T, the smallest RPDO-to-next-SYNC margin, per drive the set-points of the
job lost and repeated on the wire, and the job's outcome.

- ``--bus vcan`` (run inside scripts/with-vcan): drives and master are two child processes,
  the master on socketcan with ``--sync kernel`` (the BCM queue) or ``--sync loop``.
- ``--bus virtual``: drives, master (loop writer: the virtual bus has no kernel queue) and
  listener in this process; a helper process freezes this whole process.

    scripts/with-vcan --timeout 900 .venv/bin/python benchmarks/bench_stream.py --bus vcan
    PYTHONPATH=src python benchmarks/bench_stream.py --bus virtual
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from nurbsmotion.config import load_config  # noqa: E402
from nurbsmotion.fieldbus import Master  # noqa: E402
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY  # noqa: E402

SYNC_ID = 0x80
NODES = (1, 2, 3)
RPDO_IDS = {0x200 + n: n for n in NODES}
STROKE_MM = 20.0
STALL_AT = 0.4  # share of the job after which the master is frozen


def write_config(folder: Path, interface: str, channel: str, period_ms: float) -> Path:
    config = {
        "cycle_period_ms": period_ms,
        "bus": {"interface": interface, "channel": channel, "bitrate": 1_000_000},
        "axes": [{"name": "XYZ"[i], "node_id": n, "mode": "csp", "counts_per_mm": 1000, "soft_limits_mm": [-200, 200],
                  "max_velocity_mm_s": 400, "max_accel_mm_s2": 5000, "following_error_window_mm": 2.0}
                 for i, n in enumerate(NODES)],
        "monitoring": {"heartbeat_producer_ms": 100, "heartbeat_consumer_ms": 500, "max_bus_load": 0.8},
        "data_dir": str(folder / "var"),
    }
    path = folder / f"stream-{period_ms:g}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def job_rows(held: list[int], cycles: int) -> np.ndarray:
    s = (1.0 - np.cos(np.pi * np.arange(1, cycles + 1) / cycles)) / 2.0
    rows = np.asarray(held)[None, :] + np.round(s[:, None] * STROKE_MM * 1000).astype(np.int64)
    return (rows + np.arange(1, cycles + 1)[:, None]).astype(np.int32)


def run_master(config_path: str, cycles: int, sync: str) -> int:
    """Child role: bring up, stream, print 'held ...', 'streaming', 'result ...'."""
    with Master(load_config(config_path), sync_source=sync, bootup_timeout_s=10.0, sdo_timeout_s=3.0,
                stuck_timeout_s=5.0, enable_timeout_s=20.0, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze") as master:
        master.bring_up()
        held = [a.position_counts for a in master.status().axes]
        print("held", *held, flush=True)
        job = master.stream(job_rows(held, cycles))
        print("streaming", flush=True)
        result = job.wait(300.0)
    if result is None:
        print("result none 0 -", flush=True)
        return 1
    kinds = ",".join(sorted({f.kind for f in result.faults})) or "-"
    print("result", result.outcome, result.sent, kinds, flush=True)
    return 0


class Listener:
    """SYNC and RPDO1 frames with timestamps, in a thread."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.frames: list[tuple[float, int, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:  # after stop(): drain what the socket still holds (a starved guest lags seconds)
            msg = self.bus.recv(0.0 if self._stop.is_set() else 0.1)
            if msg is None and self._stop.is_set():
                return
            if msg is not None and (msg.arbitration_id == SYNC_ID or msg.arbitration_id in RPDO_IDS):
                value = int.from_bytes(bytes(msg.data[2:6]), "little", signed=True) if msg.arbitration_id != SYNC_ID \
                    else 0
                self.frames.append((msg.timestamp, msg.arbitration_id, value))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(30.0)


@dataclass
class Figures:
    bus: str
    sync: str
    period_ms: float
    stall_ms: float
    held_ms: float
    outcome: str
    intervals_ms: np.ndarray
    outside_share: float
    drift_ppm: float
    margin_ms: float
    lost: list[int]
    repeated: list[int]

    def row(self) -> str:
        d = self.intervals_ms
        return (f"| {self.bus} | {self.sync} | {self.period_ms:g} | {self.stall_ms:g} ({self.held_ms:.0f}) | "
                f"{self.outcome} | {d.min():.3f} | {np.median(d):.3f} | {np.percentile(d, 99):.3f} | {d.max():.2f} | "
                f"{self.drift_ppm:+.0f} | {self.outside_share * 100:.1f} | {self.margin_ms:.3f} | "
                f"{'/'.join(map(str, self.lost))} | {'/'.join(map(str, self.repeated))} |")


def analyse(frames: list[tuple[float, int, int]], rows: np.ndarray, period_s: float) -> tuple:
    """Figures over the SYNCs from the job's first set-point to its last."""
    syncs, per_cycle, last_rpdo = [], [], []
    for stamp, can_id, value in frames:
        if can_id == SYNC_ID:
            syncs.append(stamp)
            per_cycle.append({})
            last_rpdo.append(None)
        elif per_cycle:
            per_cycle[-1].setdefault(RPDO_IDS[can_id], []).append(value)
            last_rpdo[-1] = stamp
    first_value, last_value = int(rows[0, 0]), int(rows[-1, 0])
    start = next((n for n, c in enumerate(per_cycle) if first_value in c.get(1, [])), 0)
    end = next((n for n in range(start, len(per_cycle)) if last_value in per_cycle[n].get(1, [])),
               len(per_cycle) - 1)  # the first cycle with the last row (the hold repeats it)
    times = np.array(syncs[start:end + 2])
    intervals = np.diff(times)
    margins = [syncs[n + 1] - last_rpdo[n] for n in range(start, min(end + 1, len(syncs) - 1)) if last_rpdo[n]]
    lost, repeated = [], []
    for j, node in enumerate(NODES):
        seen = [v for c in per_cycle[start:end + 1] for v in c.get(node, [])]
        counts = dict(zip(*np.unique(seen, return_counts=True))) if seen else {}
        planned = rows[:, j].tolist()
        lost.append(sum(1 for v in planned if v not in counts))
        repeated.append(sum(int(counts[v]) - 1 for v in planned if counts.get(v, 0) > 1))
    outside = float(np.mean(np.abs(intervals - period_s) > 0.05 * period_s)) if len(intervals) else float("nan")
    drift = (intervals.mean() / period_s - 1.0) * 1e6 if len(intervals) else float("nan")
    return intervals * 1000, outside, drift, (min(margins) * 1000 if margins else float("nan")), lost, repeated


def freeze(pid: int, after_s: float, stall_s: float) -> subprocess.Popen:
    """A helper process that SIGSTOPs ``pid`` after ``after_s`` for ``stall_s``; prints the time held."""
    code = ("import os,signal,sys,time;pid,a,s=int(sys.argv[1]),float(sys.argv[2]),float(sys.argv[3]);"
            "time.sleep(a);t=time.perf_counter();os.kill(pid,signal.SIGSTOP);time.sleep(s);"
            "os.kill(pid,signal.SIGCONT);print((time.perf_counter()-t)*1000,flush=True)")
    return subprocess.Popen([sys.executable, "-c", code, str(pid), str(after_s), str(stall_s)], stdout=subprocess.PIPE,
                            text=True)


class BringUpFailed(Exception):
    """The master's child process did not bring the drives up."""


def run_vcan(folder: Path, period_ms: float, stall_ms: float, seconds: float, sync: str) -> Figures | str:
    config_path = write_config(folder, "socketcan", "vcan0", period_ms)
    cycles = int(seconds / (period_ms / 1000))
    env = dict(os.environ, PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    sim = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "sim", "--config", str(config_path)],
                           stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)
    assert sim.stderr is not None
    for line in sim.stderr:
        if "sim.ready" in line:
            break
    threading.Thread(target=lambda: [None for _ in sim.stderr], daemon=True).start()  # type: ignore[union-attr]
    listener = Listener(can.Bus(interface="socketcan", channel="vcan0", receive_own_messages=False))
    master = subprocess.Popen([sys.executable, __file__, "--role", "master", "--config", str(config_path),
                               "--cycles", str(cycles), "--sync", sync], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        return _run_vcan_job(master, listener, period_ms, stall_ms, seconds, sync, cycles)
    except BringUpFailed:
        return f"| vcan0 | {sync} | {period_ms:g} | {stall_ms:g} | bring-up failed | - | - | - | - | - | - | - | - | - |"
    finally:
        if master.poll() is None:
            master.kill()
        listener.stop()
        listener.bus.shutdown()
        sim.send_signal(signal.SIGTERM)
        sim.wait(20)


def _run_vcan_job(master: subprocess.Popen, listener: Listener, period_ms: float, stall_ms: float, seconds: float,
                  sync: str, cycles: int) -> Figures:
    held_ms = 0.0
    assert master.stdout is not None
    held = [int(v) for v in master.stdout.readline().split()[1:]]
    if not held:
        raise BringUpFailed
    master.stdout.readline()
    stopper = freeze(master.pid, STALL_AT * seconds, stall_ms / 1000) if stall_ms else None
    result = master.stdout.readline().split()
    if stopper is not None:
        held_ms = float(stopper.communicate()[0] or 0.0)
    master.wait(60)
    listener.stop()
    outcome = f"{result[1]} {result[3]}" if len(result) >= 4 and result[3] != "-" else (result[1] if result else "?")
    if os.environ.get("BENCH_STREAM_DUMP"):  # a folder: the listener's frames of every run, for a closer look
        import json
        dump = Path(os.environ["BENCH_STREAM_DUMP"]) / f"{sync}-{period_ms:g}-{stall_ms:g}.json"
        dump.write_text(json.dumps({"held": held, "frames": listener.frames}))
    figures = analyse(listener.frames, job_rows(held, cycles), period_ms / 1000)
    return Figures("vcan0", sync, period_ms, stall_ms, held_ms, outcome, *figures)


def run_virtual(folder: Path, period_ms: float, stall_ms: float, seconds: float) -> Figures:
    from nurbsmotion.sim import SimNetwork

    channel = "bench-stream-" + uuid.uuid4().hex
    config_path = write_config(folder, "virtual", channel, period_ms)
    config = load_config(config_path)
    sim = SimNetwork.for_machine(config)
    sim.start()
    bus = can.Bus(interface="virtual", channel=channel)
    listener = Listener(can.Bus(interface="virtual", channel=channel))
    cycles = int(seconds / (period_ms / 1000))
    held_ms = 0.0
    try:
        with Master(config, bus, bootup_timeout_s=10.0, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze") as master:
            master.bring_up()
            held = [a.position_counts for a in master.status().axes]
            job = master.stream(job_rows(held, cycles))
            stopper = freeze(os.getpid(), STALL_AT * seconds, stall_ms / 1000) if stall_ms else None
            result = job.wait(300.0)
            if stopper is not None:
                held_ms = float(stopper.communicate()[0] or 0.0)
    finally:
        listener.stop()
        listener.bus.shutdown()
        bus.shutdown()
        sim.stop()
    kinds = ",".join(sorted({f.kind for f in result.faults})) if result and result.faults else ""
    outcome = f"{result.outcome} {kinds}".strip() if result else "none"
    figures = analyse(listener.frames, job_rows(held, cycles), period_ms / 1000)
    return Figures("virtual", "loop", period_ms, stall_ms, held_ms, outcome, *figures)


def run_bare_bcm(period_ms: float, seconds: float) -> str:
    """The guest's own timer: SYNC alone from python-can's send_periodic (one BCM op, one
    frame), no master, no drives, the same listener. A row of SYNC figures only."""
    period_s = period_ms / 1000
    listener = Listener(can.Bus(interface="socketcan", channel="vcan0"))
    sender = can.Bus(interface="socketcan", channel="vcan0")
    task = sender.send_periodic(can.Message(arbitration_id=SYNC_ID, data=b"", is_extended_id=False), period_s)
    time.sleep(seconds)
    task.stop()
    listener.stop()
    listener.bus.shutdown()
    sender.shutdown()
    d = np.diff([t for t, i, _ in listener.frames if i == SYNC_ID]) * 1000
    outside = np.mean(np.abs(d - period_ms) > 0.05 * period_ms) * 100
    return (f"| vcan0 | bare BCM SYNC | {period_ms:g} | - | - | {d.min():.3f} | {np.median(d):.3f} | "
            f"{np.percentile(d, 99):.3f} | {d.max():.2f} | {(d.mean() / period_ms - 1) * 1e6:+.0f} | {outside:.1f} | - | - | - |")


HEADER = ("| bus | writer | T ms | stall ms (held) | outcome | min ms | p50 ms | p99 ms | max ms | drift ppm | "
          "outside ±5 % T % | min RPDO→SYNC ms | lost X/Y/Z | repeated X/Y/Z |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--role", default="bench", choices=("bench", "master"))
    parser.add_argument("--config")
    parser.add_argument("--cycles", type=int, default=0)
    parser.add_argument("--bus", default="vcan", choices=("vcan", "virtual"))
    parser.add_argument("--sync", default="kernel", help="vcan: comma list of kernel, loop")
    parser.add_argument("--periods", default="4,1", help="cycle periods in ms, comma separated")
    parser.add_argument("--stalls", default="0,10,30,60,100", help="stall lengths in ms, comma separated")
    parser.add_argument("--seconds", type=float, default=2.0, help="job length")
    parser.add_argument("--folder", default="/tmp/bench-stream")
    args = parser.parse_args()
    if args.role == "master":
        return run_master(args.config, args.cycles, args.sync)
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    print(f"load average before: {os.getloadavg()[0]:.2f}", flush=True)
    print(HEADER, flush=True)
    for period_ms in [float(p) for p in args.periods.split(",")]:
        if args.bus == "vcan":
            print(run_bare_bcm(period_ms, args.seconds), flush=True)
        for sync in (args.sync.split(",") if args.bus == "vcan" else ["loop"]):
            for stall_ms in [float(s) for s in args.stalls.split(",")]:
                figures = run_vcan(folder, period_ms, stall_ms, args.seconds, sync) if args.bus == "vcan" \
                    else run_virtual(folder, period_ms, stall_ms, args.seconds)
                print(figures if isinstance(figures, str) else figures.row(), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
