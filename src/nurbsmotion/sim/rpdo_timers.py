"""RPDO event timers (CiA 301, 0x14xx sub 5): a deadline for the next RPDO.

For a receive PDO the event timer is the time within which the next RPDO must come; when it
runs out the drive signals EMCY 0x8250 (RPDO time-out) and takes its error reaction.
Monitoring of an RPDO starts with its first reception after the drive entered OPERATIONAL,
and each expiry is reported once (re-armed by the next RPDO).
"""

from __future__ import annotations

import math


class RpdoTimers:
    def __init__(self) -> None:
        self.timeouts_s: dict[int, float] = {}  # RPDO number -> event timer (s), only > 0
        self._deadline: dict[int, float] = {}

    def configure(self, timeouts_s: dict[int, float]) -> None:
        """Set the timers after a remap (monitoring restarts with the next RPDO)."""
        self.timeouts_s = {number: t for number, t in timeouts_s.items() if t > 0}
        self._deadline.clear()

    def reset(self) -> None:
        """Stop monitoring (entering OPERATIONAL: it starts again with the first RPDO)."""
        self._deadline.clear()

    def received(self, number: int, now_s: float) -> None:
        timeout = self.timeouts_s.get(number)
        if timeout is not None:
            self._deadline[number] = now_s + timeout

    def expired(self, now_s: float) -> list[int]:
        """RPDO numbers whose timer just ran out (each once per expiry)."""
        gone = [number for number, deadline in self._deadline.items() if now_s > deadline]
        for number in gone:
            del self._deadline[number]
        return gone

    def next_deadline(self) -> float:
        return min(self._deadline.values(), default=math.inf)
