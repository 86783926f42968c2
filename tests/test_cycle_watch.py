"""cycle_watch: the cycle_thread_late line names what held the cycle thread (injected clocks)."""

from __future__ import annotations

import logging
import threading

import pytest

from nurbsmotion.cycle_watch import CycleWatch, busiest, held_by, threads_cpu_s

T = 0.004
THRESHOLD_S = 0.128  # half of 64 cycles at 4 ms


class Clocks:
    """Wall clock, process CPU clock and per-thread CPU the test moves by hand."""

    def __init__(self) -> None:
        self.now = 0.0
        self.cpu = 0.0
        self.threads = {"nurbsmotion-cycle": 0.0, "job-receiver": 0.0, "control-client": 0.0}
        self.gc = 0.0

    def watch(self) -> CycleWatch:
        return CycleWatch(T, THRESHOLD_S, clock=lambda: self.now, process_cpu=lambda: self.cpu,
                          threads_cpu=lambda: dict(self.threads), gc_time=lambda: self.gc)

    def step(self, seconds: float, cpu_s: float = 0.0, busy: str = "", gc_s: float = 0.0) -> None:
        self.now += seconds
        self.cpu += cpu_s
        self.gc += gc_s
        if busy:
            self.threads[busy] += cpu_s


def on_time(watch: CycleWatch, clocks: Clocks, wakes: int) -> None:
    for _ in range(wakes):
        clocks.step(0.008, 0.0005, "nurbsmotion-cycle")
        assert watch.woke(0.0001, 2) is None


def test_a_thread_of_the_process_holding_the_cycle_thread_is_named(caplog):
    clocks = Clocks()
    watch = clocks.watch()
    on_time(watch, clocks, 3)
    clocks.step(0.300, 0.280, "job-receiver")  # the process ran 280 ms of the 300: one of its threads
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.cycle_watch"):
        wake = watch.woke(0.292, 70)
    assert wake is not None and wake.held_by == "thread:job-receiver"
    [line] = [r.getMessage() for r in caplog.records]
    assert line.startswith("cycle_thread_late ") and "held_by=thread:job-receiver" in line
    assert "late_ms=292" in line and "away_ms=300" in line and "wire_cycles=70" in line and "process_cpu_ms=280" in line
    assert "gc_ms=0 " in line


def test_garbage_collections_filling_the_gap_are_named_with_their_time(caplog):
    clocks = Clocks()
    watch = clocks.watch()
    clocks.step(0.0, gc_s=5.0)  # collections before the watch began are not this gap's
    on_time(watch, clocks, 3)
    clocks.step(0.140, 0.120, "job-receiver", gc_s=0.110)  # a full collection: 110 of the 140 ms
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.cycle_watch"):
        wake = watch.woke(0.132, 35)
    assert wake is not None and wake.held_by == "gc" and wake.gc_s == pytest.approx(0.110)
    [line] = [r.getMessage() for r in caplog.records]
    assert "gc_ms=110 " in line and "held_by=gc" in line


def test_the_kernel_sending_while_the_process_got_no_cpu_is_other_work():
    clocks = Clocks()
    watch = clocks.watch()
    on_time(watch, clocks, 2)
    clocks.step(0.500, 0.006)  # 6 ms of CPU in 500 ms, while the kernel sent 70 SYNCs (280 ms of wire)
    wake = watch.woke(0.492, 70)
    assert wake is not None and wake.held_by == "other_work"
    clocks.step(0.500, 0.002)  # the queue ran out: SYNC stopped, the wire count says little
    assert watch.woke(0.492, 20, queue_ran_out=True).held_by == "other_work"  # type: ignore[union-attr]


def test_no_sync_and_no_cpu_for_the_whole_gap_is_the_machine():
    clocks = Clocks()
    watch = clocks.watch()
    on_time(watch, clocks, 2)
    clocks.step(0.400, 0.001)
    wake = watch.woke(0.392, 3)
    assert wake is not None and wake.held_by == "machine"


def test_quiet_below_the_threshold_and_at_most_one_line_a_second(caplog):
    clocks = Clocks()
    watch = clocks.watch()
    on_time(watch, clocks, 2)
    with caplog.at_level(logging.WARNING, logger="nurbsmotion.cycle_watch"):
        clocks.step(0.120)
        assert watch.woke(0.112, 28) is None  # late, but under half the queue
        clocks.step(0.200)
        assert watch.woke(0.192, 0) is not None
        clocks.step(0.200)
        assert watch.woke(0.192, 0) is not None  # counted, not logged
        clocks.step(1.0)
        assert watch.woke(0.992, 0) is not None
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "suppressed=0" in lines[0] and "suppressed=1" in lines[1]
    assert watch.late_wakes == 3


def test_the_first_wake_up_has_no_gap_to_judge():
    clocks = Clocks()
    clocks.step(5.0)
    assert clocks.watch().woke(1.0, 0) is None


def test_a_catch_up_wake_up_soon_after_a_late_one_is_not_reported_again():
    clocks = Clocks()
    watch = clocks.watch()
    on_time(watch, clocks, 2)
    clocks.step(0.300, 0.001)
    assert watch.woke(0.292, 70) is not None
    clocks.step(0.001)  # its deadline passed long ago, but the thread was away 1 ms
    assert watch.woke(0.293, 0) is None


@pytest.mark.parametrize("cpu_s, wire, ran_out, expected", [
    (0.2, 0, False, "thread:x"), (0.01, 60, False, "other_work"), (0.01, 5, True, "other_work"),
    (0.01, 5, False, "machine")])
def test_held_by(cpu_s, wire, ran_out, expected):
    assert held_by(0.3, cpu_s, wire, T, ran_out, "x") == expected
    assert held_by(0.3, cpu_s, wire, T, ran_out, "x", gc_s=0.149) == expected  # under half the gap
    assert held_by(0.3, cpu_s, wire, T, ran_out, "x", gc_s=0.150) == "gc"


def test_busiest_leaves_out_the_cycle_thread_and_counts_new_threads():
    before = {"nurbsmotion-cycle": 1.0, "a": 1.0}
    after = {"nurbsmotion-cycle": 9.0, "a": 1.1, "control-client": 0.3}
    assert busiest(before, after, "nurbsmotion-cycle") == "control-client"


def test_threads_cpu_names_this_processes_python_threads():
    stop = threading.Event()
    worker = threading.Thread(target=stop.wait, name="watched-worker")
    worker.start()
    try:
        cpu = threads_cpu_s()
    finally:
        stop.set()
        worker.join()
    if not cpu:
        pytest.skip("no /proc/self/task here")
    assert threading.current_thread().name in cpu and "watched-worker" in cpu
    assert all(v >= 0.0 for v in cpu.values())
