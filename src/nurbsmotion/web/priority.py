"""The gateway's own scheduling: it never competes with the daemon for a core.

On a real machine the browsers run elsewhere, and the gateway's work (relaying the daemon's
subscription to every WebSocket, answering the API) can always wait a few milliseconds; the
daemon's normal-priority threads cannot, when they hold the interpreter lock its SCHED_FIFO
cycle thread wakes needing (docs/web-log.md, "The gateway's priority"). So the gateway adds
``web.nice`` (default 10) to its niceness at start-up, before it starts any thread (Linux
keeps a niceness per thread; later threads inherit it). The kernel caps niceness at 19.
"""

from __future__ import annotations

import os

NICE_RANGE = (0, 19)  # web.nice: 0 leaves the gateway as started; 19 is the kernel's lowest priority


def lower_own_priority(increment: int) -> int:
    """Add ``increment`` (NICE_RANGE) to the calling thread's niceness, which every thread it
    starts later inherits; the niceness now (capped at 19 by the kernel)."""
    low, high = NICE_RANGE
    if not low <= increment <= high:
        raise ValueError(f"web.nice: must be {low}-{high}, got {increment}")
    return os.nice(increment)
