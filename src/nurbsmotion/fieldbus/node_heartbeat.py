"""The master's heartbeat consumer for a node that is not an axis (the CiA-401 I/O node).

The axes' heartbeats are judged by the cycle loop (fieldbus.supervisor); a node outside the
set-point rows gets this watch instead: canopen's ``RemoteNode.nmt`` receives the node's
heartbeat (COB-ID 0x700 + id, CiA 301 §7.2.8.3.2.1) and calls :meth:`HeartbeatWatch.heard`;
a thread looks every ``consumer_s / 4`` (at most 50 ms) and calls ``on_lost(message)`` once
when :func:`heartbeat_problem` finds one:

- no heartbeat for longer than the consumer time (CiA 301 §7.2.8.3.2.1: 'heartbeat event');
- a boot-up (state 0): the node restarted, its PDO mapping and outputs are its defaults;
- a state other than OPERATIONAL once it had been OPERATIONAL, or not OPERATIONAL within the
  consumer time after the NMT start.

It is armed again by :meth:`start` (after the node was brought up again).

Heartbeats are judged as they arrived (nurbsmotion.can.arrival_clock, as the axes' supervisor
does): :meth:`heard` takes the frame's arrival time and ``clock`` is the judging time (the
master's arrival timeline), so a receive thread held back by load does not turn heartbeats
that arrived in time into a lost node.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from nurbsmotion.can import cia402 as c
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

MAX_POLL_S = 0.05


@dataclass
class HeartbeatSeen:
    """What the consumer knows (monotonic seconds): since ``started_s`` (the NMT start)."""

    started_s: float
    last_s: float
    state: int | None = None
    operational_seen: bool = False
    bootup_seen: bool = False


def nmt_name(state: int) -> str:
    try:
        return c.NmtState(state).name.replace("_", "-")
    except ValueError:
        return f"0x{state:02X}"


def heartbeat_problem(seen: HeartbeatSeen, now_s: float, consumer_s: float) -> str | None:
    """The one-line reason the node is lost, or None while its heartbeat is as it must be."""
    silent_s = now_s - seen.last_s
    if silent_s > consumer_s:
        return f"no heartbeat for {silent_s * 1000:.0f} ms (consumer time {consumer_s * 1000:.0f} ms)"
    if seen.bootup_seen:
        return "heartbeat reports boot-up: the node restarted (its PDO mapping and outputs are back to defaults)"
    if seen.state is None or seen.state == c.NmtState.OPERATIONAL:
        return None
    if seen.operational_seen:
        return f"heartbeat reports NMT state {nmt_name(seen.state)} instead of OPERATIONAL"
    if now_s - seen.started_s > consumer_s:
        return f"heartbeat reports NMT state {nmt_name(seen.state)}, not OPERATIONAL " \
               f"{consumer_s * 1000:.0f} ms after the NMT start"
    return None


class HeartbeatWatch:
    """Consume ``node``'s heartbeat (a canopen RemoteNode) with ``consumer_s``; see module doc."""

    def __init__(self, node_id: int, consumer_s: float, on_lost: Callable[[str], None],
                 clock: Callable[[], float] = time.perf_counter) -> None:
        """``clock``: the judging time, on the same timeline as the arrival times given to heard()."""
        self.node_id = node_id
        self.consumer_s = consumer_s
        self.on_lost = on_lost
        self._clock = clock
        self._lock = threading.Lock()
        self._seen: HeartbeatSeen | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.lost: str | None = None  # the reason, once lost (until start())

    def heard(self, state: int, arrival_s: float | None = None) -> None:
        """A heartbeat (receive thread): ``state`` with the toggle bit masked, arrived at
        ``arrival_s`` (default: now)."""
        now = self._clock() if arrival_s is None else arrival_s
        with self._lock:
            seen = self._seen
            if seen is None:
                return
            seen.last_s, seen.state = max(seen.last_s, now), state
            seen.operational_seen |= state == c.NmtState.OPERATIONAL
            seen.bootup_seen |= state == c.NmtState.BOOTUP

    def start(self) -> None:
        """Watch from now (call right after the NMT start); armed again after a loss."""
        self.stop()
        now = self._clock()
        with self._lock:
            self._seen = HeartbeatSeen(started_s=now, last_s=now)
            self.lost = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._watch, name=f"heartbeat-node{self.node_id}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(1.0)
        self._thread = None

    def _watch(self) -> None:
        poll_s = min(MAX_POLL_S, self.consumer_s / 4)
        while not self._stop.wait(poll_s):
            with self._lock:
                problem = heartbeat_problem(self._seen, self._clock(), self.consumer_s) if self._seen else None
                if problem is not None:
                    self.lost, self._seen = problem, None
            if problem is not None:
                log.warning(kv("node_heartbeat_lost", node=self.node_id, reason=problem))
                self.on_lost(problem)
                return
