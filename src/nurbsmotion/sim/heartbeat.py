"""Heartbeat consumer (CiA 301, object 0x1016): watch other nodes' heartbeats.

Each 0x1016 entry is ``node_id << 16 | time_ms`` (0 or time 0: unused). Monitoring of a
producer starts with its first heartbeat; it has failed when no heartbeat came for longer
than its time. It re-arms when heartbeats come back.
"""

from __future__ import annotations

import math


def decode_consumer_entry(entry: int) -> tuple[int, float] | None:
    """(producer node id, time-out in s) of a 0x1016 entry, None if unused."""
    node_id, time_ms = (entry >> 16) & 0xFF, entry & 0xFFFF
    if node_id == 0 or node_id > 127 or time_ms == 0:
        return None
    return node_id, time_ms / 1000.0


class HeartbeatConsumer:
    def __init__(self) -> None:
        self.timeouts_s: dict[int, float] = {}
        self._last_seen: dict[int, float] = {}
        self._failed: set[int] = set()

    def configure(self, entries: list[int]) -> None:
        """Set the watched producers from the 0x1016 entries (monitoring restarts)."""
        self.timeouts_s = dict(e for e in map(decode_consumer_entry, entries) if e is not None)
        self._last_seen.clear()
        self._failed.clear()

    def seen(self, node_id: int, now: float) -> None:
        if node_id in self.timeouts_s:
            self._last_seen[node_id] = now
            self._failed.discard(node_id)

    def newly_failed(self, now: float) -> list[int]:
        """Producers whose heartbeat time just ran out (each reported once per loss)."""
        failed = [n for n, t in self._last_seen.items() if n not in self._failed and now - t > self.timeouts_s[n]]
        self._failed.update(failed)
        return failed

    def next_deadline(self) -> float:
        times = [t + self.timeouts_s[n] for n, t in self._last_seen.items() if n not in self._failed]
        return min(times, default=math.inf)
