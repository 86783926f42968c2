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
