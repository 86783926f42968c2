"""Process settings of the nurbsmotion command (daemon, plan, demo, ...): memory, once
touched, stays mapped.

numpy allocates a fresh buffer for every temporary. glibc serves requests of 128 KiB and more
(a (5500, 3) float64 array) with mmap and gives them back with munmap, and trims free space
at the top of the heap back to the kernel, so the next temporary of that size starts with
fresh page faults: about 500 per plan of Wang's Table 1 curve at T = 1 ms, a quarter of the
planning time on this virtual machine (docs/benchmarks.md, "Look-ahead throughput"), in a
process whose heap glibc trimmed after the plan before: it trims only the heap's top, so the
same plan pays 0 or ~700 faults by what the process allocated earlier (docs/reliability.md,
flake 15); with keep_freed_memory, none in either case. Real-time Linux
processes turn this off with mallopt (M_MMAP_THRESHOLD, M_TRIM_THRESHOLD) for the same
reason in their cycle loops. The cost: the process keeps up to TRIM_THRESHOLD_BYTES of
freed heap instead of returning it. A library user calls keep_freed_memory() if they want it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

M_TRIM_THRESHOLD = -1  # glibc <malloc.h>
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's largest (DEFAULT_MMAP_THRESHOLD_MAX on 64-bit)
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024


def keep_freed_memory() -> bool:
    """Serve allocations below 32 MiB from the heap and keep up to 256 MiB of freed heap
    (glibc mallopt). False where the C library has no mallopt (musl, macOS): nothing changes."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1 and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1


# ---------------------------------------------------------------- cycle timing of the process
# Applied by the daemon (service.daemon / service.link), never by the fieldbus master itself:
# they change the whole process (switch interval, garbage collector) or its scheduling.

GC_MODES = ("freeze", "disable", "none")
CYCLE_THREAD_PRIORITY = 20  # SCHED_FIFO priority of the master's cycle thread (its receive thread: one less)
# simulate: true: the drives' receive and ticker threads in the daemon's process, below the master's
SIM_DRIVES_PRIORITY = CYCLE_THREAD_PRIORITY - 2
STATUS_PUBLISHER_PRIORITY = 1  # the daemon's status publisher (service.subscriptions): below all of the above


def cap_switch_interval(period_s: float) -> float:
    """A thread busy in pure Python keeps the GIL up to the switch interval (5 ms by default)
    before a woken cycle thread gets it: cap it at a quarter period. Returns the interval."""
    if sys.getswitchinterval() > period_s / 4:
        sys.setswitchinterval(period_s / 4)
    return sys.getswitchinterval()


def set_thread_realtime(priority: int | None, thread_id: int = 0, pin: bool = True) -> str:
    """SCHED_FIFO ``priority`` for the calling thread (or the thread ``thread_id``, its native
    id) when allowed (root / CAP_SYS_NICE), on the real-time CPU (realtime_cpu) when there is
    one and ``pin``; returns the policy in force ('SCHED_FIFO', or 'normal: <reason>')."""
    if priority is None or not hasattr(os, "sched_setscheduler"):
        return "normal: not requested"
    try:
        os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(max(1, priority)))
    except (PermissionError, OSError) as err:
        return f"normal: {err}"
    if pin:
        pin_to_realtime_cpu(thread_id)
    return "SCHED_FIFO"


def realtime_for_normal_threads(priority: int, task_dir: Path = Path("/proc/self/task")) -> list[int]:
    """SCHED_FIFO ``priority`` for every thread of this process still at the normal policy
    (SCHED_OTHER), where allowed; the native ids of those changed. Threads they start later
    inherit it (pthread_create's default). The SCHED_FIFO threads wait for the interpreter
    lock like any other: held by a normal thread that other work has preempted, it keeps them
    all waiting (docs/reliability.md, "The demo under heavy load")."""
    changed: list[int] = []
    if not hasattr(os, "sched_setscheduler") or not task_dir.is_dir():
        return changed
    for entry in task_dir.iterdir():
        tid = int(entry.name)
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                continue
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(max(1, priority)))
        except OSError:  # not allowed (no root or CAP_SYS_NICE), or the thread ended
            continue
        changed.append(tid)
    return changed


def unpin_threads(task_dir: Path = Path("/proc/self/task")) -> list[int]:
    """Every thread of this process allowed on every CPU the calling thread may use (undoes
    pin_to_realtime_cpu); the native ids changed. Every nurbsmotion process pins its
    SCHED_FIFO threads to the same last CPU: two on one host (tests, benchmarks) keep each
    other's simulated drives off it (docs/reliability.md, flake 8)."""
    changed: list[int] = []
    if not hasattr(os, "sched_setaffinity") or not task_dir.is_dir():
        return changed
    cpus = os.sched_getaffinity(0)
    for entry in task_dir.iterdir():
        tid = int(entry.name)
        try:
            if os.sched_getaffinity(tid) == cpus:
                continue
            os.sched_setaffinity(tid, cpus)
        except OSError:  # the thread ended
            continue
        changed.append(tid)
    return changed


def normal_again(thread_ids: list[int], task_dir: Path = Path("/proc/self/task")) -> None:
    """Those of ``thread_ids`` still threads of this process back to SCHED_OTHER (an id of
    an ended thread may be another process' thread by now: it is left alone)."""
    if not hasattr(os, "sched_setscheduler"):
        return
    for tid in thread_ids:
        if not (task_dir / str(tid)).exists():
            continue
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass


# ---------------------------------------------------------------- the real-time CPU
# The daemon's SCHED_FIFO threads (cycle, receive; simulated drives) wake thousands of times a
# second. Spread over every CPU they preempt the planner worker wherever it runs, and its
# whole-program parse before the first motion took 0.92-1.49 s instead of 0.61-0.70 s
# (Wang x 460 on 2 CPUs, interleaved; docs/benchmarks.md). As real-time machines isolate a CPU
# for their real-time work, the daemon runs its SCHED_FIFO threads on the last CPU it may use
# and keeps the planner worker off it (with one CPU nothing is pinned).


def thread_cpus() -> set[int]:
    """The CPUs the calling thread may run on (empty where the platform cannot tell)."""
    return os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()


def realtime_cpu(allowed: set[int] | None = None) -> int | None:
    """The CPU for the SCHED_FIFO threads: the last of ``allowed`` (default: the one
    reserve_realtime_cpu reserved, else the calling thread's CPUs), None when there are fewer
    than two."""
    if allowed is None:
        if _reserved is not None:
            return _reserved.realtime
        if not hasattr(os, "sched_getaffinity"):
            return None
        allowed = os.sched_getaffinity(0)
    return max(allowed) if len(allowed) >= 2 else None


def pin_to_realtime_cpu(thread_id: int = 0) -> int | None:
    """Run the calling thread (or ``thread_id``) on realtime_cpu(); the CPU, or None (one CPU,
    or not allowed)."""
    cpu = realtime_cpu()
    if cpu is None:
        return None
    try:
        os.sched_setaffinity(thread_id, {cpu})
    except OSError:
        return None
    return cpu


def keep_off_realtime_cpu(pid: int) -> set[int] | None:
    """Run process ``pid`` on every CPU but realtime_cpu(); its CPUs, or None (unchanged)."""
    split = _reserved or cpu_split(thread_cpus())
    if split is None:
        return None
    try:
        os.sched_setaffinity(pid, split.normal)
    except OSError:
        return None
    return set(split.normal)


@dataclass(frozen=True)
class CpuSplit:
    """The daemon's CPUs: ``realtime`` for its SCHED_FIFO threads, ``normal`` for the rest."""

    realtime: int
    normal: frozenset[int]


def cpu_split(allowed: set[int]) -> CpuSplit | None:
    """``allowed`` split into realtime_cpu(allowed) and the others; None with fewer than two."""
    cpu = realtime_cpu(allowed)
    return None if cpu is None else CpuSplit(cpu, frozenset(allowed - {cpu}))


_reserved: CpuSplit | None = None  # set once by the daemon's process (reserve_realtime_cpu)


def reserve_realtime_cpu(task_dir: Path = Path("/proc/self/task")) -> CpuSplit | None:
    """Keep every thread of this process that is not SCHED_FIFO/RR off realtime_cpu(), and so
    every thread they start later (a new thread inherits its creator's affinity:
    pthread_create); SCHED_FIFO threads still go onto it (pin_to_realtime_cpu). Call it in the
    main thread before the others start. The split, or None (one CPU: nothing changes).

    A normal thread preempted on the real-time CPU while it holds the interpreter lock keeps
    the woken cycle thread waiting for the lock until the thread runs again (docs/web.md)."""
    global _reserved
    split = cpu_split(thread_cpus())
    if split is None:
        return None
    for entry in task_dir.iterdir() if task_dir.is_dir() else ():
        tid = int(entry.name)
        try:
            if os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR):
                continue
            os.sched_setaffinity(tid, split.normal)
        except OSError:  # the thread ended
            continue
    _reserved = split
    return split


class GcQuiet:
    """Keep the cyclic garbage collector from stalling the process for milliseconds during a job.

    'freeze' moves every object alive now (the job's rows included) out of the collector's
    reach, so collections during the job only scan what is allocated meanwhile; 'disable'
    stops cyclic collection until :meth:`release`, which leaves it as :meth:`quiet` found it
    (reference counting still frees memory); 'none' changes nothing. Also a context manager
    (``with GcQuiet("disable"):``, the planner worker's parse)."""

    def __init__(self, mode: str = "none") -> None:
        if mode not in GC_MODES:
            raise ValueError(mode)
        self.mode = mode
        self._was_enabled = True

    def quiet(self) -> None:
        if self.mode == "freeze":
            gc.freeze()
        elif self.mode == "disable":
            self._was_enabled = gc.isenabled()
            gc.disable()

    def release(self) -> None:
        if self.mode == "freeze":
            gc.unfreeze()
        elif self.mode == "disable" and self._was_enabled:
            gc.enable()

    def __enter__(self) -> "GcQuiet":
        self.quiet()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


# ---------------------------------------------------------------- the kernel's timer threads
# The kernel queue (fieldbus.bcm_queue) is sent by the broadcast manager's hrtimers, which
# Linux runs as soft timers: in softirq context on the way out of an interrupt, or, once
# softirq work piles up (more than 2 ms or 10 rounds, or ksoftirqd already has work), in the
# per-CPU thread ksoftirqd/N (PREEMPT_RT: ktimers/N). That thread is SCHED_OTHER by default
# (PREEMPT_RT: ktimers SCHED_FIFO 1), so a machine busy with our own SCHED_FIFO threads holds
# the SYNC back for as long as they run: measured inside User-Mode Linux, SYNC intervals of
# 10-14 ms at T = 4 ms with ksoftirqd normal, none above 2 T with it SCHED_FIFO above the cycle
# thread (docs/benchmarks.md, "Kernel-timed stream"; docs/fieldbus.md, "The kernel's timer
# threads"). Raising them is the machine's set-up (as for IRQ threads on an RT machine), not
# the daemon's business: the daemon says when they sit below its cycle thread.

KERNEL_TIMER_THREAD_PREFIXES = ("ksoftirqd/", "ktimers/", "ktimersoftd/")
_POLICY_NAMES = {0: "SCHED_OTHER", 1: "SCHED_FIFO", 2: "SCHED_RR", 3: "SCHED_BATCH", 5: "SCHED_IDLE",
                 6: "SCHED_DEADLINE"}


@dataclass(frozen=True)
class KernelThread:
    """A kernel thread's scheduling (/proc/PID/stat: comm, rt_priority (field 40), policy (41))."""

    name: str
    pid: int
    policy: str
    priority: int

    def below(self, fifo_priority: int) -> bool:
        """Would a SCHED_FIFO thread of ``fifo_priority`` keep this one off the CPU?"""
        if self.policy == "SCHED_DEADLINE":  # runs before every SCHED_FIFO thread
            return False
        return self.policy not in ("SCHED_FIFO", "SCHED_RR") or self.priority <= fifo_priority


def process_stats(proc: Path = Path("/proc")) -> Iterator[tuple[int, str, list[str]]]:
    """(pid, name, fields) of every process in ``proc``; ``fields[0]`` is field 3 of
    /proc/PID/stat (state), after the name in parentheses (proc(5))."""
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        yield int(entry.name), stat[stat.find("(") + 1:stat.rfind(")")], stat[stat.rfind(")") + 2:].split()


def kernel_timer_threads(proc: Path = Path("/proc")) -> list[KernelThread]:
    """The threads that run the kernel's soft timers (ksoftirqd/N, ktimers/N), from ``proc``."""
    threads = []
    for pid, name, fields in process_stats(proc):
        if not name.startswith(KERNEL_TIMER_THREAD_PREFIXES):
            continue
        try:
            priority, policy = int(fields[37]), int(fields[38])
        except (IndexError, ValueError):
            continue
        threads.append(KernelThread(name, pid, _POLICY_NAMES.get(policy, str(policy)), priority))
    return sorted(threads, key=lambda t: t.pid)


def timer_threads_below(fifo_priority: int | None, proc: Path = Path("/proc")) -> list[KernelThread]:
    """The kernel's timer threads a SCHED_FIFO thread of ``fifo_priority`` can hold off (none
    when no real-time priority is used, or /proc cannot be read)."""
    if fifo_priority is None:
        return []
    try:
        return [t for t in kernel_timer_threads(proc) if t.below(fifo_priority)]
    except OSError:
        return []
