"""Other threads' short work, run by the cycle thread in the slack after its cycle.

In CPython one thread runs Python at a time (the interpreter lock). A thread that holds the
lock when the cycle thread wakes delays the cycle: until it lets go, or until the cycle thread's
wait reaches the switch interval (T/4). Timing another thread's steps around the cycle
thread's wake-up (service.subscriptions before issue 22's last change) leaves hand-overs of
the lock that take tens of microseconds on a virtual machine. The one thread whose work can
never be in the way of the cycle thread's wake-up is the cycle thread itself.

So background work that must run in the daemon's process (the status publisher's rounds,
the ``status`` answers, the formatting of a job's files) is handed over as an iterator of
short steps. After its cycle's commit the cycle thread starts steps only while its next
wake-up is at least ``room_s`` away and within ``budget_s`` of the slack's beginning; queued
works take turns step by step; the rest waits for the next cycle. Bulk work (a job's files:
many steps, nobody waiting on a reply) runs only when no other work is queued, so a status
round or answer is not held behind a job's feedback.csv lines (why every step keeps the
budget: docs/web.md, "What the subscription costs the cycle"). This is the background
slot of a real-time task: LinuxCNC's servo thread likewise copies its status for the user
interfaces in its own period.

Work submitted while no cycle thread runs is refused (``submit`` returns None): the
submitter runs it itself. Work still queued when the cycle thread ends is handed back
(``SlackWork.returned``).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterator, TypeVar

from nurbsmotion.steps import Steps, drained

log = logging.getLogger(__name__)

# a step starts only this long before the next wake-up: a step (10-150 us) and the work of the
# lower-priority real-time threads (receive, simulated drives) it pushes back, which runs only
# once the cycle thread sleeps. Steps past the wake-up in 48 jobs of 20 s: 111 at 300 us, 7 at
# 600 us; 10 clients' added late cycles per 1000: +2.8 to +4.7, then +1.5 to +2.0 (docs/web.md).
ROOM_S = 600e-6
# and only this long after the slack began: the other real-time threads' work it pushes back
# stays short however much is queued (a job's feedback.csv lines: 60 steps a second)
BUDGET_S = 100e-6
# work the cycle thread ran no step of in this long (it has no slack: overloaded) is taken
# back and finished by the thread that submitted it
WAIT_S = 0.25
T = TypeVar("T")


@dataclass
class SlackWork:
    """Steps handed to the cycle thread, and how they ended."""

    steps: Iterator[object]
    done: threading.Event = field(default_factory=threading.Event)
    error: Exception | None = None  # a step raised: the submitter raises it again
    result: object = None  # what the steps returned (a generator's return value)
    returned: bool = False  # the cycle thread ended first: the submitter runs the rest of the steps
    steps_run: int = 0  # by the cycle thread so far (run_steps takes work back that makes no progress)
    bulk: bool = False  # a job's files: run when no other work is queued


class CycleSlack:
    """The queue of background work the cycle thread runs after its cycles."""

    def __init__(self, room_s: float = ROOM_S, clock: Callable[[], float] = time.perf_counter,
                 budget_s: float = BUDGET_S) -> None:
        self.room_s = room_s
        self.budget_s = budget_s
        self._clock = clock
        self._queue: collections.deque[SlackWork] = collections.deque()
        self._bulk: collections.deque[SlackWork] = collections.deque()
        self._lock = threading.Lock()  # held by the cycle thread while it runs a step
        self._open = False
        self.steps_run = 0
        self.overruns = 0  # steps that ended after the next wake-up: each may have made a cycle late
        self.overrun_places: collections.Counter[str] = collections.Counter()  # step_place of each overrun
        self.withdrawn = 0  # work the submitter took back after waiting (run_steps)

    @property
    def open(self) -> bool:
        return self._open

    def start(self) -> None:
        """The cycle thread runs: accept work from now on."""
        with self._lock:
            self._open = True

    def stop(self) -> None:
        """The cycle thread ends: refuse new work and hand back what is queued."""
        with self._lock:
            self._open = False
            for queue in (self._queue, self._bulk):
                while queue:
                    work = queue.popleft()
                    work.returned = True
                    work.done.set()

    def submit(self, steps: Iterator[object], bulk: bool = False) -> SlackWork | None:
        """Queue ``steps`` for the cycle thread (``bulk``: only when no other work is
        queued); None when no cycle thread runs."""
        work = SlackWork(steps, bulk=bulk)
        with self._lock:
            if not self._open:
                return None
            (self._bulk if bulk else self._queue).append(work)
        return work

    def withdraw(self, work: SlackWork) -> bool:
        """Take ``work`` back before the cycle thread started it or between two of its steps:
        True when it was still queued (the submitter runs the rest of its steps itself)."""
        queue = self._bulk if work.bulk else self._queue
        with self._lock:
            if work in queue:
                queue.remove(work)
                self.withdrawn += 1
                return True
            return False

    def run(self, next_wake_s: float) -> None:
        """The cycle thread, after its commit: start queued steps while ``next_wake_s`` (its
        next wake-up, on this clock) is at least ``room_s`` away and ``budget_s`` has not
        passed since this call began; bulk steps only once no other work is queued. A step
        that raises ends its work (the submitter sees the error); the cycle goes on."""
        queue, bulk = self._queue, self._bulk
        if not queue and not bulk:
            return
        with self._lock:
            last_start_s = min(next_wake_s - self.room_s, self._clock() + self.budget_s)
            while (queue or bulk) and self._clock() <= last_start_s:
                self._step(queue if queue else bulk, next_wake_s)

    def _step(self, queue: collections.deque[SlackWork], next_wake_s: float) -> None:
        """One step of the first work in ``queue``, which then goes to the back (queued works
        take turns: a long one starves none) or, once it ended, out."""
        work = queue[0]
        try:
            next(work.steps)
            work.steps_run += 1
            queue.rotate(-1)
            return
        except StopIteration as done:
            work.result = done.value
        except Exception as err:  # noqa: BLE001 - another thread's bug must not stop the cycle
            work.error = err
        finally:
            self.steps_run += 1
            if self._clock() > next_wake_s:
                self.overruns += 1
                self.overrun_places[step_place(work.steps)] += 1
        queue.popleft()
        work.done.set()


def step_place(steps: Iterator[object]) -> str:
    """Where the last step of ``steps`` ended: ``function:line`` of the innermost generator
    (through ``yield from``) at its yield, ``function:end`` once it returned; for telling
    which step overran a wake-up."""
    inner = steps
    while getattr(inner, "gi_yieldfrom", None) is not None:
        inner = inner.gi_yieldfrom  # type: ignore[attr-defined]
    code, frame = getattr(inner, "gi_code", None), getattr(inner, "gi_frame", None)
    name = code.co_qualname if code is not None else type(inner).__name__
    return f"{name}:{frame.f_lineno if frame is not None else 'end'}"


def run_steps(steps: Steps[T], slack: CycleSlack | None = None, between: Callable[[object], None] = lambda _: None,
              wait_s: float = WAIT_S, bulk: bool = False) -> T:
    """Run ``steps`` to their end and return their result: in the cycle thread's ``slack``
    while one runs (this thread waits; ``bulk`` as in CycleSlack.submit); else, or when the
    cycle thread ran none of them for ``wait_s`` (it has no slack: overloaded), here, calling ``between`` with each step's
    value. A step's exception is raised here."""
    work = slack.submit(steps, bulk) if slack is not None else None
    if work is not None and slack is not None and not taken_back(work, slack, wait_s):
        work.done.wait()
        if work.error is not None:
            raise work.error
        if not work.returned:
            return work.result  # type: ignore[return-value]  # the generator's own return value
    return drained(steps, between)


def taken_back(work: SlackWork, slack: CycleSlack, wait_s: float) -> bool:
    """Wait while the cycle thread makes progress on ``work``; True when it ran none of its
    steps for ``wait_s`` and the work was taken back (the caller runs the rest)."""
    seen = 0
    while not work.done.wait(wait_s):
        if work.steps_run == seen:
            return slack.withdraw(work)
        seen = work.steps_run
    return False
