"""runtime's CPU and priority rules for the daemon's real-time threads: the kernel's timer
threads that send the kernel queue's SYNC under load (kernel_timer_threads /
timer_threads_below), and the real-time CPU the SCHED_FIFO threads share while the planner
worker keeps off it."""

from __future__ import annotations

from pathlib import Path

from nurbsmotion.runtime import KernelThread, kernel_timer_threads, timer_threads_below

# /proc/PID/stat lines as Linux 6.x writes them (policy is field 41, rt_priority field 40)
KSOFTIRQD_NORMAL = ("14 (ksoftirqd/0) S 2 0 0 0 -1 69238848 0 0 0 0 12 335 0 0 20 0 1 0 24 0 0 "
                    "18446744073709551615 0 0 0 0 0 0 0 2147483647 0 1 0 0 17 0 0 0 0 0 0 0 0 0 0 0 0 0 0")
MIGRATION_FIFO_99 = ("18 (migration/0) S 2 0 0 0 -1 69238848 0 0 0 0 0 129 0 0 -100 0 1 0 24 0 0 "
                     "18446744073709551615 0 0 0 0 0 0 0 2147483647 0 1 0 0 17 0 99 1 0 0 0 0 0 0 0 0 0 0 0")


def fake_proc(tmp_path: Path, threads: dict[int, str]) -> Path:
    for pid, stat in threads.items():
        (tmp_path / str(pid)).mkdir()
        (tmp_path / str(pid) / "stat").write_text(stat + "\n")
    (tmp_path / "self").mkdir()  # not a pid
    return tmp_path


def stat_of(pid: int, name: str, priority: int, policy: int) -> str:
    return KSOFTIRQD_NORMAL.replace("14 (ksoftirqd/0)", f"{pid} ({name})").replace(
        " 17 0 0 0 0 0", f" 17 0 {priority} {policy} 0 0", 1)


def test_finds_the_soft_timer_threads_and_their_policy(tmp_path):
    proc = fake_proc(tmp_path, {14: KSOFTIRQD_NORMAL, 18: MIGRATION_FIFO_99,
                                22: stat_of(22, "ksoftirqd/1", 50, 1), 30: stat_of(30, "ktimers/0", 1, 1)})
    assert kernel_timer_threads(proc) == [KernelThread("ksoftirqd/0", 14, "SCHED_OTHER", 0),
                                          KernelThread("ksoftirqd/1", 22, "SCHED_FIFO", 50),
                                          KernelThread("ktimers/0", 30, "SCHED_FIFO", 1)]


def test_below_the_cycle_thread_means_normal_or_a_fifo_priority_not_above_it(tmp_path):
    proc = fake_proc(tmp_path, {14: KSOFTIRQD_NORMAL, 22: stat_of(22, "ksoftirqd/1", 50, 1),
                                30: stat_of(30, "ktimers/0", 20, 1), 31: stat_of(31, "ktimers/1", 21, 2)})
    assert [t.pid for t in timer_threads_below(20, proc)] == [14, 30]  # FIFO 20 ties: the running one stays
    assert [t.pid for t in timer_threads_below(60, proc)] == [14, 22, 30, 31]


def test_no_real_time_priority_no_complaint(tmp_path):
    assert timer_threads_below(None, fake_proc(tmp_path, {14: KSOFTIRQD_NORMAL})) == []


def test_an_unreadable_or_odd_entry_is_skipped(tmp_path):
    proc = fake_proc(tmp_path, {14: KSOFTIRQD_NORMAL, 15: "15 (ksoftirqd/9) S 2"})
    (proc / "16").mkdir()  # a process that ended between listing and reading: no stat file
    assert [t.pid for t in kernel_timer_threads(proc)] == [14]
    assert timer_threads_below(20, tmp_path / "missing") == []


# ---------------------------------------------------------------- the real-time CPU
from nurbsmotion import runtime  # noqa: E402


def test_the_realtime_cpu_is_the_last_allowed_one_and_none_with_one_cpu():
    assert runtime.realtime_cpu({0, 1}) == 1
    assert runtime.realtime_cpu({2, 5, 3}) == 5
    assert runtime.realtime_cpu({0}) is None


def test_the_worker_keeps_off_the_realtime_cpu_and_fifo_threads_go_onto_it(monkeypatch):
    calls = []
    monkeypatch.setattr(runtime.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    monkeypatch.setattr(runtime.os, "sched_setaffinity", lambda pid, cpus: calls.append((pid, set(cpus))))
    monkeypatch.setattr(runtime.os, "sched_setscheduler", lambda pid, policy, param: None)
    assert runtime.keep_off_realtime_cpu(4242) == {0, 1, 2}
    assert runtime.set_thread_realtime(20) == "SCHED_FIFO"
    assert calls == [(4242, {0, 1, 2}), (0, {3})]


def test_nothing_is_pinned_on_one_cpu_or_without_real_time(monkeypatch):
    calls = []
    monkeypatch.setattr(runtime.os, "sched_getaffinity", lambda pid: {0})
    monkeypatch.setattr(runtime.os, "sched_setaffinity", lambda pid, cpus: calls.append(pid))
    monkeypatch.setattr(runtime.os, "sched_setscheduler", lambda pid, policy, param: None)
    assert runtime.keep_off_realtime_cpu(4242) is None and runtime.set_thread_realtime(20) == "SCHED_FIFO"

    def refused(pid, policy, param):
        raise PermissionError("Operation not permitted")
    monkeypatch.setattr(runtime.os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(runtime.os, "sched_setscheduler", refused)
    assert runtime.set_thread_realtime(20).startswith("normal:")
    assert calls == []


def test_reserving_the_realtime_cpu_moves_normal_threads_off_it_and_keeps_it_for_fifo_ones(monkeypatch, tmp_path):
    """runtime.reserve_realtime_cpu: normal threads (and so those they start) on the others,
    SCHED_FIFO ones left; afterwards a thread already off it still pins onto it, and the
    planner worker still goes to the others."""
    for tid in (11, 12, 13):
        (tmp_path / str(tid)).mkdir()
    affinity: dict[int, set[int]] = {0: {0, 1, 2, 3}}
    monkeypatch.setattr(runtime, "_reserved", None)  # restored after the test
    monkeypatch.setattr(runtime.os, "sched_getaffinity", lambda pid: affinity.get(pid, {0, 1, 2, 3}))
    monkeypatch.setattr(runtime.os, "sched_setaffinity", lambda pid, cpus: affinity.__setitem__(pid, set(cpus)))
    monkeypatch.setattr(runtime.os, "sched_getscheduler", lambda tid: runtime.os.SCHED_FIFO if tid == 12 else 0)
    monkeypatch.setattr(runtime.os, "sched_setscheduler", lambda pid, policy, param: None)
    split = runtime.reserve_realtime_cpu(tmp_path)
    assert split == runtime.CpuSplit(3, frozenset({0, 1, 2}))
    assert affinity[11] == affinity[13] == {0, 1, 2} and 12 not in affinity
    affinity[0] = {0, 1, 2}  # the calling thread, now off the real-time CPU like its new threads
    assert runtime.realtime_cpu() == 3
    assert runtime.set_thread_realtime(20) == "SCHED_FIFO" and affinity[0] == {3}
    assert runtime.keep_off_realtime_cpu(4242) == {0, 1, 2} and affinity[4242] == {0, 1, 2}


def test_with_one_cpu_nothing_is_reserved(monkeypatch, tmp_path):
    (tmp_path / "11").mkdir()
    calls = []
    monkeypatch.setattr(runtime, "_reserved", None)
    monkeypatch.setattr(runtime.os, "sched_getaffinity", lambda pid: {0})
    monkeypatch.setattr(runtime.os, "sched_setaffinity", lambda pid, cpus: calls.append(pid))
    assert runtime.reserve_realtime_cpu(tmp_path) is None and runtime._reserved is None and calls == []
