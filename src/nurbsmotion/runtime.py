"""Process settings of the nurbsmotion command (daemon, plan, demo, ...): memory, once
touched, stays mapped.

numpy allocates a fresh buffer for every temporary. glibc serves requests of 128 KiB and more
(a (5500, 3) float64 array) with mmap and gives them back with munmap, and trims free space
at the top of the heap back to the kernel, so the next temporary of that size starts with
fresh page faults: about 500 per plan of Wang's Table 1 curve at T = 1 ms, a quarter of the
planning time on this virtual machine (docs/benchmarks.md, "Throughput"). Real-time Linux
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


def cap_switch_interval(period_s: float) -> float:
    """A thread busy in pure Python keeps the GIL up to the switch interval (5 ms by default)
    before a woken cycle thread gets it: cap it at a quarter period. Returns the interval."""
    if sys.getswitchinterval() > period_s / 4:
        sys.setswitchinterval(period_s / 4)
    return sys.getswitchinterval()


def set_thread_realtime(priority: int | None) -> str:
    """SCHED_FIFO ``priority`` for the calling thread when allowed (root / CAP_SYS_NICE);
    returns the policy in force ('SCHED_FIFO', or 'normal: <reason>')."""
    if priority is None or not hasattr(os, "sched_setscheduler"):
        return "normal: not requested"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, priority)))
    except (PermissionError, OSError) as err:
        return f"normal: {err}"
    return "SCHED_FIFO"


class GcQuiet:
    """Keep the cyclic garbage collector from stalling the process for milliseconds during a job.

    'freeze' moves every object alive now (the job's rows included) out of the collector's
    reach, so collections during the job only scan what is allocated meanwhile; 'disable'
    stops cyclic collection until :meth:`release` (reference counting still frees memory);
    'none' changes nothing."""

    def __init__(self, mode: str = "none") -> None:
        if mode not in GC_MODES:
            raise ValueError(mode)
        self.mode = mode

    def quiet(self) -> None:
        if self.mode == "freeze":
            gc.freeze()
        elif self.mode == "disable":
            gc.disable()

    def release(self) -> None:
        if self.mode == "freeze":
            gc.unfreeze()
        elif self.mode == "disable":
            gc.enable()
