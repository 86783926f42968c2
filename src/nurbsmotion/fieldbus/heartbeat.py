"""The master's own heartbeat (CiA 301 §7.2.8.3.2.1): COB-ID 0x700 + master node id, one
byte, the NMT state (0x05 operational), every ``period_s``.

It is sent by python-can's ``send_periodic``: on SocketCAN the kernel's broadcast manager
(BCM) sends it, so its timing does not depend on Python; when the process dies the kernel
drops the task with the socket and the heartbeat stops at once. The task runs on a lease:
it stops by itself ``LEASE_S`` after the last renewal, and a watchdog thread renews it only
while ``alive()`` says the master makes progress (the cycle loop advances, or bring-up is
under way). So a hung daemon stops its heartbeat too, and every drive's 0x1016 consumer
faults it within lease + consumer time.

A renewal restarts the task's phase (TX_SETUP with STARTTIMER), so one gap may reach two
periods: the drives' consumer time is at least 3 periods
(``monitoring.master_heartbeat_consumer_multiple``).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

import can

from nurbsmotion.can import cia402 as c
from nurbsmotion.log import kv
from nurbsmotion.runtime import set_thread_realtime

log = logging.getLogger(__name__)

LEASE_S = 2.0  # the task stops by itself this long after the last renewal
RENEW_S = 0.5  # the watchdog renews this often while alive() holds


def heartbeat_message(node_id: int, state: int = c.NmtState.OPERATIONAL) -> can.Message:
    return can.Message(arbitration_id=c.COB_HEARTBEAT + node_id, is_extended_id=False, data=bytes([state]))


def started_heartbeat(bus: can.BusABC, node_id: int, period_ms: int, alive: Callable[[], bool],
                      rt_priority: int | None) -> "MasterHeartbeat | None":
    """The master's heartbeat, started (None: ``period_ms`` 0, no heartbeat); its threads run
    just below the cycle thread's ``rt_priority``."""
    if period_ms == 0:
        return None
    heartbeat = MasterHeartbeat(bus, node_id, period_ms / 1000.0, alive,
                                thread_priority=None if rt_priority is None else rt_priority - 1)
    heartbeat.start()
    return heartbeat


class MasterHeartbeat:
    """Produce the master's heartbeat on ``bus`` while ``alive()`` holds (see module doc)."""

    def __init__(self, bus: can.BusABC, node_id: int, period_s: float, alive: Callable[[], bool],
                 lease_s: float = LEASE_S, renew_s: float = RENEW_S, thread_priority: int | None = None) -> None:
        """``thread_priority``: SCHED_FIFO of the watchdog and of a sending thread (python-can's
        on buses without a kernel sender, e.g. ``virtual``): at normal priority a loaded host
        starved them past the drives' consumer time while every thread judging the heartbeat
        ran SCHED_FIFO (the demo beside a CPU burner: EMCY 0x8130 on every drive)."""
        self.thread_priority = thread_priority
        self.node_id = node_id
        self.period_s = period_s
        self._bus = bus
        self._alive = alive
        self._lease_s = max(lease_s, 2 * period_s)
        self._renew_s = min(renew_s, self._lease_s / 2)
        self._task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.renewals = 0

    @property
    def running(self) -> bool:
        return self._task is not None

    def start(self) -> None:
        if self._task is not None:
            return
        self._stop.clear()
        self._task = self._bus.send_periodic(heartbeat_message(self.node_id), self.period_s, duration=self._lease_s)
        if isinstance(self._task, can.broadcastmanager.ThreadBasedCyclicSendTask):
            self._task.on_error = self._send_failed  # keep the thread: a bus error is reported by the cycle loop
            self._raise_sender(self._task)
        self._thread = threading.Thread(target=self._watch, name="nurbsmotion-heartbeat", daemon=True)
        self._thread.start()
        log.debug(kv("master_heartbeat", node=self.node_id, period_ms=round(self.period_s * 1000),
                    lease_s=self._lease_s, sender=type(self._task).__name__))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._task is not None:
            try:
                self._task.stop()
            except (can.CanError, OSError):
                pass
            self._task = None

    def renew(self) -> None:
        """Extend the lease by LEASE_S from now."""
        task = self._task
        if task is None:
            return
        if isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask):
            task.end_time = time.perf_counter() + self._lease_s
            if task.thread is None or not task.thread.is_alive():
                task.start()
                self._raise_sender(task)
        elif isinstance(task, can.broadcastmanager.RestartableCyclicTaskABC):
            task.start()  # SocketCAN: TX_SETUP again, count = lease / period
        self.renewals += 1

    def _send_failed(self, err: Exception) -> bool:
        log.warning(kv("master_heartbeat_send_failed", error=str(err)))
        return True

    def _raise_sender(self, task: can.broadcastmanager.ThreadBasedCyclicSendTask) -> None:
        if task.thread is not None and task.thread.native_id is not None:
            set_thread_realtime(self.thread_priority, task.thread.native_id)

    def _watch(self) -> None:
        set_thread_realtime(self.thread_priority)
        while not self._stop.wait(self._renew_s):
            if self._alive():
                try:
                    self.renew()
                except (can.CanError, OSError) as err:
                    log.warning(kv("master_heartbeat_renew_failed", error=str(err)))
            else:
                log.warning(kv("master_heartbeat_withheld", reason="the cycle loop made no progress"))
