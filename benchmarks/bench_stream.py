"""Set-point stream benchmark: what reaches the wire while the master is frozen.

Three CSP drives (nurbsmotion.sim) and a master stream one job of strictly increasing
set-points (a smooth 20 mm move plus one count per cycle, so a lost or repeated set-point
shows). During the job the master's process is frozen with SIGSTOP: once, 40 % into the job,
for the given time (``--stalls 60``), or COUNT times spread over 20-80 % of the job
(``--stalls 60x5``: issue 14's five 60 ms stalls); 0 = no stall. The process that freezes
the master is started during the bring-up and ends after the job: inside User-Mode Linux a
process starting or ending holds the guest's timers up for 5-30 ms (measured: fork + exit
18-31 ms), which would be the harness' doing, not the stream's. An independent listener
records every SYNC and RPDO1 with its timestamp (kernel timestamps on vcan0; send timestamps
on the virtual bus) and gives: SYNC interval min/p50/p99/max and drift in ppm (mean interval
against T), share of intervals outside ±5 % of T, the smallest RPDO-to-next-SYNC margin, per
drive the set-points of the job lost and repeated on the wire, the job's outcome, and
(vcan0, kernel queue) the queue's headroom while moving and its lease expiries (the writer's
``kernel_queue_summary`` line).

Then, on vcan0, one job per ``--requests`` entry (stop, override to 50 %, abort), requested
40 % into the job without a stall: the time from the request (wall clock in the master's
process) to the first RPDO on the wire that differs from the plan (a set-point other than
the planned row of its cycle; for abort the quick-stop controlword), against the claim
(guard + 1)·T and the bound (guard + 1)·T + one wake-up of the cycle thread.

- ``--bus vcan`` (run inside scripts/with-vcan): drives and master are two child processes,
  the master on socketcan with ``--sync kernel`` (the BCM queue) or ``--sync loop``.
  scripts/with-vcan runs the guest's ksoftirqd at SCHED_FIFO 50 (above the master's cycle
  thread, as a real-time machine is set up; ``--softirq-priority 0`` for the kernel's
  default) and, with ``--rt-priority 50``, the guest itself at SCHED_FIFO on the host, so
  the host's other work does not delay the guest's timers (docs/benchmarks.md).
- ``--bus virtual``: drives, master (loop writer: the virtual bus has no kernel queue) and
  listener in this process; a helper process freezes this whole process.

    scripts/with-vcan --rt-priority 50 --timeout 1200 .venv/bin/python benchmarks/bench_stream.py --bus vcan --periods 4
    scripts/with-vcan --rt-priority 50 --timeout 900 .venv/bin/python benchmarks/bench_stream.py --bus vcan \
        --periods 4 --stalls 60x5 --seconds 3 --requests ""
    scripts/with-vcan --timeout 900 .venv/bin/python benchmarks/bench_stream.py --bus vcan --periods 4 \
        --stalls "" --requests stop,stop,stop,override,override,override,abort,abort,abort
    PYTHONPATH=src python benchmarks/bench_stream.py --bus virtual
"""

from __future__ import annotations

import argparse
import json
import logging
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
from nurbsmotion.fieldbus.bcm_queue import GUARD_CYCLES, WAKE_PERIOD_S  # noqa: E402
from nurbsmotion.fieldbus.drive_state import CW_QUICK_STOP  # noqa: E402
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY  # noqa: E402
from nurbsmotion.can.socketcan_batch import BatchedSocketcanBus  # noqa: E402

SYNC_ID = 0x80
NODES = (1, 2, 3)
RPDO_IDS = {0x200 + n: n for n in NODES}
STROKE_MM = 20.0
STALL_AT = 0.4  # share of the job after which the master is frozen
REQUEST_AT = 0.4  # share of the job after which stop / override / abort is requested (moving near full speed)
OVERRIDE_RATE = 0.5
REQUESTS = ("none", "stop", "override", "abort")


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


class QueueSummary(logging.Handler):
    """Keeps the kernel queue's summary line (BcmQueueWriter.close: headroom, lease expiries)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.line = ""

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith("kernel_queue_summary"):
            self.line = message


def make_request(master: Master, job, request: str) -> None:
    """The request under test: a controlled stop, feed override to 50 %, or abort (quick stop)."""
    if request == "stop":
        job.request_stop()
    elif request == "override":
        master.set_rate(OVERRIDE_RATE)
    elif request == "abort":
        job.abort()


def run_master(config_path: str, cycles: int, sync: str, request: str, request_after_s: float) -> int:
    """Child role: bring up, stream, print 'held ...', 'streaming', ('request <wall time>'),
    'result ...', 'queue <summary>'."""
    summary = QueueSummary()
    queue_log = logging.getLogger("nurbsmotion.fieldbus.bcm_queue")
    queue_log.setLevel(logging.INFO)
    queue_log.addHandler(summary)
    with Master(load_config(config_path), sync_source=sync, bootup_timeout_s=10.0, sdo_timeout_s=3.0,
                stuck_timeout_s=5.0, enable_timeout_s=20.0, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze") as master:
        master.bring_up()
        held = [a.position_counts for a in master.status().axes]
        print("held", *held, flush=True)
        job = master.stream(job_rows(held, cycles))
        print("streaming", flush=True)
        result = job.wait(request_after_s) if request != "none" else None
        if request != "none" and result is None:
            print("request", repr(time.time()), flush=True)  # SocketCAN stamps frames with the wall clock
            make_request(master, job, request)
        result = result or job.wait(300.0)
    if result is None:
        print("result none 0 -", flush=True)
        return 1
    kinds = ",".join(sorted({f.kind for f in result.faults})) or "-"
    print("result", result.outcome, result.sent, kinds, flush=True)
    print("queue", summary.line or "-", flush=True)
    return 0


class Listener:
    """SYNC and RPDO1 frames with timestamps, in a thread."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.frames: list[tuple[float, int, int, int]] = []  # stamp, COB-ID, set-point, controlword
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:  # after stop(): drain what the socket still holds (a starved guest lags seconds)
            msg = self.bus.recv(0.0 if self._stop.is_set() else 0.1)
            if msg is None and self._stop.is_set():
                return
            if msg is not None and (msg.arbitration_id == SYNC_ID or msg.arbitration_id in RPDO_IDS):
                if msg.arbitration_id == SYNC_ID:
                    self.frames.append((msg.timestamp, SYNC_ID, 0, 0))
                else:
                    data = bytes(msg.data)
                    self.frames.append((msg.timestamp, msg.arbitration_id, int.from_bytes(data[2:6], "little", signed=True),
                                        int.from_bytes(data[0:2], "little")))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(30.0)


@dataclass
class Figures:
    bus: str
    sync: str
    period_ms: float
    stalls: "Stalls"
    held_ms: list[float]
    outcome: str
    intervals_ms: np.ndarray
    outside_share: float
    drift_ppm: float
    margin_ms: float
    lost: list[int]
    repeated: list[int]
    queue: "QueueFigures"

    def row(self) -> str:
        d = self.intervals_ms
        return (f"| {self.bus} | {self.sync} | {self.period_ms:g} | {self.stalls.label()} ({held_label(self.held_ms)}) | "
                f"{self.outcome} | {d.min():.3f} | {np.median(d):.3f} | {np.percentile(d, 99):.3f} | {d.max():.2f} | "
                f"{self.drift_ppm:+.0f} | {self.outside_share * 100:.1f} | {self.margin_ms:.3f} | "
                f"{'/'.join(map(str, self.lost))} | {'/'.join(map(str, self.repeated))} | {self.queue.cells()} |")


@dataclass
class QueueFigures:
    """The kernel queue's own counters (its summary log line): headroom while moving, in cycles
    still queued beyond the wire when the cycle thread woke, and lease expiries."""

    ring_cycles: int = 0
    headroom_min: int = -1
    headroom_p1: int = -1
    headroom_p50: int = -1
    into_tail: int = 0
    expiries: int = 0

    @classmethod
    def parse(cls, line: str) -> "QueueFigures":
        fields = dict(part.split("=", 1) for part in line.split()[1:] if "=" in part)
        if not fields:
            return cls()
        return cls(int(fields["ring_cycles"]), int(fields["headroom_min"]), int(fields["headroom_p1"]),
                   int(fields["headroom_p50"]), int(fields["into_tail"]), int(fields["lease_expiries"]))

    def cells(self) -> str:
        if self.headroom_min < 0:
            return "- | -"
        return (f"{self.headroom_min}/{self.headroom_p1}/{self.headroom_p50} of {self.ring_cycles}"
                f"{f', tail {self.into_tail}' if self.into_tail else ''} | {self.expiries}")


@dataclass
class RequestFigures:
    """Request to the first frame on the wire that differs from the plan (listener stamps)."""

    period_ms: float
    request: str
    outcome: str
    latency_ms: float  # nan: no differing frame found
    syncs_between: int  # SYNCs on the wire from the request to that frame
    guard: int
    wake_ms: float
    queue: QueueFigures

    def row(self) -> str:
        claim_ms = (self.guard + 1) * self.period_ms
        return (f"| vcan0 | {self.period_ms:g} | {self.request} | {self.outcome} | {self.latency_ms:.1f} | "
                f"{self.latency_ms / self.period_ms:.1f} | {self.syncs_between} | {claim_ms:g} | "
                f"{claim_ms + self.wake_ms:g} | {self.queue.cells()} |")


def request_latency(frames: list[tuple[float, int, int, int]], rows: np.ndarray, request_s: float,
                    request: str) -> tuple[float, int]:
    """(ms, SYNCs) from ``request_s`` to the first RPDO off the plan: for stop / override a
    set-point other than the planned row of its cycle, for abort the quick-stop controlword.
    The RPDOs n SYNCs after those carrying rows[0] carry rows[n]."""
    first_value = int(rows[0, 0])
    start, cycle, syncs_after = None, -1, 0
    for stamp, can_id, value, controlword in frames:
        if can_id == SYNC_ID:
            cycle += 1
            syncs_after += stamp >= request_s
            continue
        node = RPDO_IDS[can_id]
        if start is None:
            if node == NODES[0] and value == first_value:
                start = cycle
            continue
        if stamp < request_s:
            continue
        n = cycle - start
        off_plan = controlword == CW_QUICK_STOP if request == "abort" else \
            (n < len(rows) and value != int(rows[n, NODES.index(node)]))
        if off_plan:
            return (stamp - request_s) * 1000, syncs_after
    return float("nan"), syncs_after


def analyse(frames: list[tuple[float, int, int, int]], rows: np.ndarray, period_s: float) -> tuple:
    """Figures over the SYNCs from the job's first set-point to its last."""
    syncs, per_cycle, last_rpdo = [], [], []
    for stamp, can_id, value, _ in frames:
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


FREEZER_CODE = """
import json, os, signal, sys, time
pid = int(sys.argv[1])
line = sys.stdin.readline()
held = []
if line.strip():
    start = time.perf_counter()
    for at_s, stall_s in json.loads(line):
        time.sleep(max(0.0, start + at_s - time.perf_counter()))
        t = time.perf_counter()
        os.kill(pid, signal.SIGSTOP)
        time.sleep(stall_s)
        os.kill(pid, signal.SIGCONT)
        held.append((time.perf_counter() - t) * 1000)
print(" ".join(f"{h:.1f}" for h in held), flush=True)
sys.stdin.read()
"""


@dataclass(frozen=True)
class Stalls:
    """``count`` freezes of the master of ``length_ms`` each in one job ("60x5"; "60" = one)."""

    length_ms: float
    count: int = 1

    @classmethod
    def parse(cls, text: str) -> "Stalls":
        length, _, count = text.partition("x")
        return cls(float(length), int(count or 1))

    def schedule(self, seconds: float) -> list[tuple[float, float]]:
        """(start s after the job's start, length s): one at STALL_AT of the job, or several
        spread evenly over its middle 20-80 %."""
        if not self.length_ms or not self.count:
            return []
        shares = [STALL_AT] if self.count == 1 else \
            [0.2 + 0.6 * i / (self.count - 1) for i in range(self.count)]
        return [(share * seconds, self.length_ms / 1000) for share in shares]

    def label(self) -> str:
        return f"{self.length_ms:g}" + (f"x{self.count}" if self.count > 1 else "")


class Freezer:
    """A helper process that SIGSTOPs ``pid`` on a schedule. It is started before the job and
    exits after it: starting and ending a process (fork, exec, exit) holds up the kernel's
    timers for 5-30 ms inside User-Mode Linux (measured, docs/benchmarks.md), so the harness'
    own process must not start or end while the job's SYNCs are measured."""

    def __init__(self, pid: int) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", FREEZER_CODE, str(pid)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True)

    def go(self, schedule: list[tuple[float, float]]) -> None:
        """Start the schedule now (an empty one: no stall)."""
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(schedule) + "\n")
        self.process.stdin.flush()

    def held_ms(self) -> list[float]:
        """How long each stall really held the master (waits for the schedule's end)."""
        assert self.process.stdout is not None
        return [float(v) for v in self.process.stdout.readline().split()]

    def close(self) -> None:
        if self.process.stdin is not None and not self.process.stdin.closed:
            self.process.stdin.close()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()


def held_label(held_ms: list[float]) -> str:
    """How long the stalls really held the master: "0", "74" or "62-74" (ms)."""
    if not held_ms:
        return "0"
    low, high = min(held_ms), max(held_ms)
    return f"{high:.0f}" if round(low) == round(high) else f"{low:.0f}-{high:.0f}"


class BringUpFailed(Exception):
    """The master's child process did not bring the drives up."""


@dataclass
class VcanRun:
    """One job on vcan0: what the master's child printed and what the listener heard."""

    held: list[int]
    outcome: str
    held_ms: list[float]  # how long each stall really held the master
    request_s: float  # wall-clock time of the request (nan: none)
    queue: QueueFigures
    frames: list[tuple[float, int, int, int]]


def run_vcan(folder: Path, period_ms: float, stalls: Stalls, seconds: float, sync: str,
             request: str = "none") -> VcanRun:
    """Drives (``nurbsmotion sim``) and master as two child processes, the listener here."""
    config_path = write_config(folder, "socketcan", "vcan0", period_ms)
    cycles = int(seconds / (period_ms / 1000))
    env = dict(os.environ, PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    sim = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "sim", "--config", str(config_path)],
                           stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)
    sim_log: list[str] = []
    assert sim.stderr is not None
    for line in sim.stderr:
        sim_log.append(line)
        if "sim.ready" in line:
            break
    threading.Thread(target=lambda: sim_log.extend(sim.stderr), daemon=True).start()  # type: ignore[arg-type]
    listener = Listener(BatchedSocketcanBus(channel="vcan0"))  # reads each cycle's burst per wake-up, as the drives do
    master = subprocess.Popen([sys.executable, __file__, "--role", "master", "--config", str(config_path),
                               "--cycles", str(cycles), "--sync", sync, "--request", request,
                               "--request-after", str(REQUEST_AT * seconds)], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True, env=env)
    freezer = Freezer(master.pid)  # started during the bring-up, ends after the job
    try:
        run = _run_vcan_job(master, listener, freezer, stalls.schedule(seconds))
    finally:
        if master.poll() is None:
            master.kill()
        freezer.close()
        listener.stop()
        listener.bus.shutdown()
        sim.send_signal(signal.SIGTERM)
        sim.wait(20)
    if os.environ.get("BENCH_STREAM_DUMP"):  # a folder: the listener's frames and the drives' log of every run
        import json
        name = f"{sync}-{period_ms:g}-{stalls.label()}-{request}"
        dump = Path(os.environ["BENCH_STREAM_DUMP"])
        (dump / f"{name}.json").write_text(json.dumps({"held": run.held, "request_s": run.request_s,
                                                       "frames": run.frames}))
        (dump / f"{name}.sim.log").write_text("".join(sim_log))
    return run


def _run_vcan_job(master: subprocess.Popen, listener: Listener, freezer: Freezer,
                  schedule: list[tuple[float, float]]) -> VcanRun:
    assert master.stdout is not None
    held = [int(v) for v in master.stdout.readline().split()[1:]]
    if not held:
        raise BringUpFailed
    master.stdout.readline()
    freezer.go(schedule)
    line = master.stdout.readline().split()
    request_s = float("nan")
    if line[:1] == ["request"]:
        request_s = float(line[1])
        line = master.stdout.readline().split()
    result = line
    queue = QueueFigures.parse(master.stdout.readline().partition(" ")[2])
    held_ms = freezer.held_ms()
    master.wait(60)
    listener.stop()
    outcome = f"{result[1]} {result[3]}" if len(result) >= 4 and result[3] != "-" else (result[1] if result else "?")
    return VcanRun(held, outcome, held_ms, request_s, queue, listener.frames)


def stall_row(folder: Path, period_ms: float, stalls: Stalls, seconds: float, sync: str) -> str:
    """A job with its stalls of the master: the SYNC, content and queue figures."""
    try:
        run = run_vcan(folder, period_ms, stalls, seconds, sync)
    except BringUpFailed:
        return f"| vcan0 | {sync} | {period_ms:g} | {stalls.label()} | bring-up failed |" + " - |" * 11
    figures = analyse(run.frames, job_rows(run.held, int(seconds / (period_ms / 1000))), period_ms / 1000)
    return Figures("vcan0", sync, period_ms, stalls, run.held_ms, run.outcome, *figures, run.queue).row()


def request_row(folder: Path, period_ms: float, request: str, seconds: float) -> str:
    """A job with a stop / override / abort request 40 % in, kernel queue, no stall."""
    try:
        run = run_vcan(folder, period_ms, Stalls(0.0), seconds, "kernel", request)
    except BringUpFailed:
        return f"| vcan0 | {period_ms:g} | {request} | bring-up failed |" + " - |" * 7
    rows = job_rows(run.held, int(seconds / (period_ms / 1000)))
    latency_ms, syncs = request_latency(run.frames, rows, run.request_s, request)
    wake_ms = max(1, round(WAKE_PERIOD_S * 1000 / period_ms)) * period_ms
    return RequestFigures(period_ms, request, run.outcome, latency_ms, syncs, GUARD_CYCLES, wake_ms, run.queue).row()


def run_virtual(folder: Path, period_ms: float, stalls: Stalls, seconds: float) -> Figures:
    from nurbsmotion.sim import SimNetwork

    channel = "bench-stream-" + uuid.uuid4().hex
    config_path = write_config(folder, "virtual", channel, period_ms)
    config = load_config(config_path)
    sim = SimNetwork.for_machine(config)
    sim.start()
    bus = can.Bus(interface="virtual", channel=channel)
    listener = Listener(can.Bus(interface="virtual", channel=channel))
    cycles = int(seconds / (period_ms / 1000))
    freezer = Freezer(os.getpid())
    try:
        with Master(config, bus, bootup_timeout_s=10.0, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze") as master:
            master.bring_up()
            held = [a.position_counts for a in master.status().axes]
            job = master.stream(job_rows(held, cycles))
            freezer.go(stalls.schedule(seconds))
            result = job.wait(300.0)
            held_ms = freezer.held_ms()
    finally:
        freezer.close()
        listener.stop()
        listener.bus.shutdown()
        bus.shutdown()
        sim.stop()
    kinds = ",".join(sorted({f.kind for f in result.faults})) if result and result.faults else ""
    outcome = f"{result.outcome} {kinds}".strip() if result else "none"
    figures = analyse(listener.frames, job_rows(held, cycles), period_ms / 1000)
    return Figures("virtual", "loop", period_ms, stalls, held_ms, outcome, *figures, QueueFigures())


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
    d = np.diff([t for t, i, _, _ in listener.frames if i == SYNC_ID]) * 1000
    outside = np.mean(np.abs(d - period_ms) > 0.05 * period_ms) * 100
    return (f"| vcan0 | bare BCM SYNC | {period_ms:g} | - | - | {d.min():.3f} | {np.median(d):.3f} | "
            f"{np.percentile(d, 99):.3f} | {d.max():.2f} | {(d.mean() / period_ms - 1) * 1e6:+.0f} | {outside:.1f} | - | - | - | - | - |")


HEADER = ("| bus | writer | T ms | stall ms (held) | outcome | min ms | p50 ms | p99 ms | max ms | drift ppm | "
          "outside ±5 % T % | min RPDO→SYNC ms | lost X/Y/Z | repeated X/Y/Z | headroom min/p1/p50 cycles | "
          "lease expiries |\n" + "|---" * 16 + "|")
REQUEST_HEADER = ("| bus | T ms | request | outcome | request → first frame off the plan ms | in T | SYNCs between | "
                  "claim (g+1)·T ms | (g+1)·T + wake ms | headroom min/p1/p50 cycles | lease expiries |\n"
                  + "|---" * 11 + "|")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--role", default="bench", choices=("bench", "master"))
    parser.add_argument("--config")
    parser.add_argument("--cycles", type=int, default=0)
    parser.add_argument("--bus", default="vcan", choices=("vcan", "virtual"))
    parser.add_argument("--sync", default="kernel", help="vcan: comma list of kernel, loop")
    parser.add_argument("--periods", default="4,1", help="cycle periods in ms, comma separated")
    parser.add_argument("--stalls", default="0,10,30,60,100,60x5",
                        help="per job: stall length in ms, or LENGTHxCOUNT for COUNT stalls spread over the job; comma separated")
    parser.add_argument("--seconds", type=float, default=2.0, help="job length")
    parser.add_argument("--requests", default="stop,override,abort",
                        help="vcan: comma list of stop, override, abort (one job each, no stall; empty: none)")
    parser.add_argument("--request", default="none", choices=REQUESTS, help=argparse.SUPPRESS)
    parser.add_argument("--request-after", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--folder", default="/tmp/bench-stream")
    args = parser.parse_args()
    if args.role == "master":
        return run_master(args.config, args.cycles, args.sync, args.request, args.request_after)
    unknown = [r for r in args.requests.split(",") if r and r not in REQUESTS[1:]]
    if unknown:
        parser.error(f"--requests: {unknown[0]!r} is not one of {', '.join(REQUESTS[1:])}")
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    print(f"load average before: {os.getloadavg()[0]:.2f}", flush=True)
    print(HEADER, flush=True)
    for period_ms in [float(p) for p in args.periods.split(",")]:
        if args.bus == "vcan":
            print(run_bare_bcm(period_ms, args.seconds), flush=True)
        for sync in (args.sync.split(",") if args.bus == "vcan" else ["loop"]):
            for stalls in [Stalls.parse(s) for s in args.stalls.split(",") if s]:
                print(stall_row(folder, period_ms, stalls, args.seconds, sync) if args.bus == "vcan"
                      else run_virtual(folder, period_ms, stalls, args.seconds).row(), flush=True)
    requests = [r for r in args.requests.split(",") if r] if args.bus == "vcan" else []
    if requests:
        print(REQUEST_HEADER, flush=True)
    for period_ms in [float(p) for p in args.periods.split(",")] if requests else []:
        for request in requests:
            print(request_row(folder, period_ms, request, args.seconds), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
