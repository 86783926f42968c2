"""What holds the guest kernel's timers up: a bare BCM SYNC at T with one disturbance at a time.

A one-frame BCM TX op sends SYNC every T on vcan0 (python-can's send_periodic); a listener
stamps every SYNC in the kernel. Every 0.3 s this process does one thing (start a thread,
allocate and free 4 MB, write a file, import a module, freeze a 10-thread process for 60 ms
as bench_stream.py freezes the master, fork a child that exits, start a python interpreter) and the SYNC intervals above 1.25 T are attributed to the disturbance
that was running when they began. Run inside scripts/with-vcan (User-Mode Linux); used to
find why SYNC intervals of 10-30 ms appeared in bench_stream.py (docs/benchmarks.md,
"Kernel-timed stream", 2026-11-25).

    scripts/with-vcan --rt-priority 50 .venv/bin/python benchmarks/bench_guest_timer.py
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Callable

import can
import numpy as np

SYNC_ID = 0x80
PAUSE_S = 0.3


def start_thread() -> None:
    thread = threading.Thread(target=time.sleep, args=(0.01,))
    thread.start()
    thread.join()


def alloc_4mb() -> None:
    block = np.ones(500_000)
    del block


def write_file() -> None:
    with tempfile.NamedTemporaryFile("w") as f:
        f.write("x" * 100_000)
        f.flush()


def import_module() -> None:
    for name in ("json", "csv", "decimal"):
        importlib.import_module(name)


def fork_exit() -> None:
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)


def start_python() -> None:
    subprocess.run([sys.executable, "-c", "import numpy, can"], check=True)


THREADED_CHILD = """
import threading, time
def spin():
    while True:
        time.sleep(0.001)
for _ in range(10):
    threading.Thread(target=spin, daemon=True).start()
time.sleep(3600)
"""


class ThreadedChild:
    """A python process with 10 threads waking every 1 ms (as the daemon's are), started
    before the measurement; freezing it is what bench_stream.py's stalls do to the master."""

    def __init__(self) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", THREADED_CHILD])

    def freeze_60ms(self) -> None:
        os.kill(self.process.pid, signal.SIGSTOP)
        time.sleep(0.06)
        os.kill(self.process.pid, signal.SIGCONT)

    def close(self) -> None:
        self.process.kill()
        self.process.wait()


def disturbances(child: ThreadedChild) -> dict[str, Callable[[], None]]:
    return {"thread start": start_thread, "alloc+free 4 MB": alloc_4mb, "write 100 kB file": write_file,
            "import cached modules": import_module, "SIGSTOP 60 ms + SIGCONT of a 10-thread process":
            child.freeze_60ms, "fork + child exit": fork_exit, "python start": start_python}


class SyncListener:
    """Kernel timestamps of every SYNC on vcan0, in a thread."""

    def __init__(self) -> None:
        self.bus = can.Bus(interface="socketcan", channel="vcan0")
        self.stamps: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.1)
            if msg is not None and msg.arbitration_id == SYNC_ID:
                self.stamps.append(msg.timestamp)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.bus.shutdown()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--period-ms", type=float, default=4.0)
    parser.add_argument("--repeat", type=int, default=3, help="times each disturbance is done")
    args = parser.parse_args()
    period_s = args.period_ms / 1000
    child = ThreadedChild()
    time.sleep(2.0)  # its start is not measured
    disturbances_by_name = disturbances(child)
    listener = SyncListener()
    sender = can.Bus(interface="socketcan", channel="vcan0")
    task = sender.send_periodic(can.Message(arbitration_id=SYNC_ID, data=b"", is_extended_id=False), period_s)
    spans: list[tuple[str, float, float]] = []
    time.sleep(1.0)
    for name, disturb in list(disturbances_by_name.items()) * args.repeat:
        start = time.time()
        disturb()
        spans.append((name, start, time.time()))
        time.sleep(PAUSE_S)
    task.stop()
    sender.shutdown()
    listener.stop()
    child.close()
    stamps = np.asarray(listener.stamps)
    intervals_ms = np.diff(stamps) * 1000
    print(f"SYNC intervals: {len(intervals_ms)}, p50 {np.median(intervals_ms):.3f} ms, "
          f"p99 {np.percentile(intervals_ms, 99):.3f} ms, max {intervals_ms.max():.2f} ms")
    print("| disturbance | runs | its time ms (max) | SYNC intervals > 1.25 T it held up (ms) |\n|---|---|---|---|")
    for name in disturbances_by_name:
        mine = [(a, b) for n, a, b in spans if n == name]
        late = [f"{d:.1f}" for t, d in zip(stamps[:-1], intervals_ms)
                if d > 1.25 * args.period_ms and any(a - period_s <= t <= b for a, b in mine)]
        print(f"| {name} | {len(mine)} | {max(b - a for a, b in mine) * 1000:.0f} | {', '.join(late) or 'none'} |")
    quiet = [d for t, d in zip(stamps[:-1], intervals_ms)
             if not any(a - period_s <= t <= b for _, a, b in spans)]
    print(f"between disturbances: max {max(quiet):.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
