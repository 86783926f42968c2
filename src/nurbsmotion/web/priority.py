"""The gateway's own scheduling: it never competes with the daemon for a core.

On a real machine the browsers run elsewhere, and the gateway's work (relaying the daemon's
subscription to every WebSocket, answering the API) can always wait a few milliseconds; the
daemon's normal-priority threads cannot, when they hold the interpreter lock its SCHED_FIFO
cycle thread wakes needing (docs/web-log.md, "The gateway's priority"). So the gateway adds
``web.nice`` (default 10) to its niceness at start-up, before it starts any thread (Linux
keeps a niceness per thread; later threads inherit it). The kernel caps niceness at 19.

Niceness alone does not keep it off the CPU of the daemon's cycle thread: there the kernel's
work for its sockets and its threads' cache traffic still cost the cycle (docs/web.md, "What
the subscription costs the cycle"). So ``web.cpus`` (default ``auto``) also moves it, before
any thread starts, off the daemon's real-time CPU (runtime.realtime_cpu: the last one).
"""

from __future__ import annotations

import os

from nurbsmotion.config import GatewayCpus
from nurbsmotion.errors import InputError
from nurbsmotion.runtime import cpu_split

NICE_RANGE = (0, 19)  # web.nice: 0 leaves the gateway as started; 19 is the kernel's lowest priority


def lower_own_priority(increment: int) -> int:
    """Add ``increment`` (NICE_RANGE) to the calling thread's niceness, which every thread it
    starts later inherits; the niceness now (capped at 19 by the kernel)."""
    low, high = NICE_RANGE
    if not low <= increment <= high:
        raise ValueError(f"web.nice: must be {low}-{high}, got {increment}")
    return os.nice(increment)


def cpus_for(choice: GatewayCpus | tuple[int, ...], allowed: set[int], machine_cpus: int) -> set[int]:
    """The CPUs ``web.cpus`` asks for, given the CPUs the gateway was started on
    (``allowed``) and the machine's count: auto is every allowed CPU but the real-time one
    (all of them with one CPU); a list must name CPUs of this machine (InputError)."""
    if choice is GatewayCpus.ALL:
        return set(allowed)
    if choice is GatewayCpus.AUTO:
        split = cpu_split(allowed)
        return set(split.normal) if split is not None else set(allowed)
    assert isinstance(choice, tuple)
    missing = [n for n in choice if n >= machine_cpus]
    if missing:
        raise InputError("web.cpus", f"no CPU {missing[0]} on this machine (its CPUs are 0-{machine_cpus - 1})")
    return set(choice)


def place_own_threads(choice: GatewayCpus | tuple[int, ...]) -> set[int]:
    """Run the calling thread, and every thread it starts later (they inherit its affinity),
    on cpus_for(choice); the CPUs now (empty where the platform cannot set them)."""
    if not hasattr(os, "sched_setaffinity"):
        return set()
    cpus = cpus_for(choice, os.sched_getaffinity(0), os.cpu_count() or 1)
    try:
        os.sched_setaffinity(0, cpus)
    except OSError as err:  # e.g. a cpuset that excludes them
        raise InputError("web.cpus", f"cannot run on CPUs {sorted(cpus)}: {err.strerror}") from None
    return cpus
