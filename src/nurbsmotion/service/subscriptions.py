"""Status and events pushed to subscribed clients (Moonraker's ``notify_status_update``).

After ``{"cmd": "subscribe"}`` a control connection receives, one JSON line each:

- ``{"notify": "status", "seq": n, "t": epoch_s, "changes": {...}}``: only the status fields
  that changed since the last status line this client got (nested objects by key; a list,
  such as ``axes``, whole when any element changed), at most ``max_hz`` lines a second;
- ``{"notify": "event", "seq": n, "t": epoch_s, "event": NAME, "level": "INFO",
  "fields": {...}, "line": "..."}``: every daemon log line at INFO or above (job_started,
  job_ended with outcome and line reached, fault with node, kind, EMCY code and text,
  homing_done, override_changed, faults_reset, ...), as soon as it is logged;
- ``{"notify": "dropped", "error": "..."}`` before the daemon closes a client that fell
  too far behind (it never blocks the daemon: each client has its own bounded queue).

One publisher thread reads the status for all subscribers on a shared grid of ticks at the
fastest rate any of them asked for (subscribers at one rate fall due together: one read for
all), and only while someone is subscribed; a logged event wakes it at once, so a state change
reaches clients with the event, not a period later. It also writes every subscriber's lines to
its connection (``Subscription.attach``: a non-blocking send; what the socket cannot take now
waits for the next round), so a round wakes one thread for all clients instead of one per
client.

The cycle thread must not pay for it (issue 22): every microsecond another thread runs Python
holds the interpreter lock the cycle thread may wake up needing, and a cycle thread that waits
for it longer than the spin before its deadline starts the cycle late. So
- a round is short steps (``_round_steps``: the status read's parts, the diff, the encoding,
  each send) and, while the cycle thread runs, the cycle thread itself runs them in the slack
  after its cycle, each only while its next wake-up is far enough away (fieldbus.cycle_slack);
  the publisher thread only waits for the round (docs/web.md, "The round in the cycle's slack");
- between events it reads only the fields that move with the machine (``read_fast``:
  positions, cycle counters, job progress, state); the rest (override, offsets, homing,
  spindle, I/O, queue, last job) whole in the round of an event and the next, and every
  FULL_READ_PERIOD_S;
- with no cycle thread (before bring-up, after a fault disabled the drives), or when the
  cycle thread had no slack for SLACK_WAIT_S, the publisher thread runs the steps itself,
  letting go of the lock between them and starting one only where it ends before the cycle
  thread's next wake-up (``between_steps``; docs/web-log.md, "Out of the cycle thread's way"),
  at SCHED_FIFO 1 where allowed, below every thread of the cycle.
The cycle thread pays one ``deque.append`` and ``Event.set`` per log line it writes (faults).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from nurbsmotion.fieldbus.cycle_slack import WAIT_S, CycleSlack, run_steps
from nurbsmotion.steps import Steps
from nurbsmotion.log import attach_handler, kv, parse_kv
from nurbsmotion.runtime import set_thread_realtime
from nurbsmotion.service.protocol import Status, encode, merge_changes, status_changes

log = logging.getLogger(__name__)

DEFAULT_MAX_HZ = 20.0  # status lines per second per client (positions), Moonraker's default rate
MAX_HZ_RANGE = (0.5, 100.0)
MAX_PENDING_LINES = 2000  # a client this far behind is dropped (events queue; status lines merge)
FULL_READ_PERIOD_S = 0.5  # between events, the fields that do not move with the machine are read this often
TICK_SLACK_S = 1e-3  # a subscriber due this soon is served in this round
FULL_READS_AFTER_EVENT = 2  # rounds that read the whole status after an event (this one and the next)
MAX_UNSENT_BYTES = 4 * 1024 * 1024  # an attached client whose socket leaves this much unsent is dropped
# a step starts only this long before the cycle thread's next wake-up: longer than a step on a
# quiet core (10-150 µs, the diff the longest) with the lock's hand-over; else it waits ...
STEP_ROOM_S = 300e-6
# ... until this long after that wake-up: the cycle thread has taken the lock and holds it
# through its spin (60 µs) and its sends; the step waits for its cycle's work
AFTER_WAKE_S = 100e-6
# a round the cycle thread has not finished in this long (no slack: it is overloaded) is
# finished by the publisher's thread instead: subscribers still get their status
SLACK_WAIT_S = WAIT_S
StatusRead = Callable[[], "Status | Steps[Status]"]  # the status at once, or in steps (fieldbus.cycle_slack)
Writer = Callable[[bytes], int]  # a non-blocking send: bytes taken (BlockingIOError: none); OSError: gone


@dataclass
class Subscription:
    """One client's queue: encoded lines waiting to be sent, and status changes not yet due."""

    period_s: float
    lines: collections.deque[bytes] = field(default_factory=collections.deque)
    pending: Status = field(default_factory=dict)
    next_status_s: float = 0.0
    dropped: str | None = None
    seq: int = 0
    wake: threading.Condition = field(default_factory=threading.Condition)
    writer: Writer | None = None  # attached: the publisher sends the lines (flush), nobody takes them
    on_drop: Callable[[], None] | None = None  # attached: wakes the connection's thread when dropped
    unsent: bytes = b""
    mid_line: bool = False  # the socket took part of a line whose rest is at the front of ``unsent``

    def put(self, body: bytes) -> None:
        """Queue one line: ``body`` is an encoded JSON object, shared by every subscriber;
        this connection's ``seq`` goes in front."""
        with self.wake:
            if self.dropped is not None:
                return
            self.seq += 1
            self.lines.append(b'{"seq":%d,' % self.seq + body[1:])
            if len(self.lines) > MAX_PENDING_LINES:
                self.lines.clear()
                self._drop(f"client too slow: more than {MAX_PENDING_LINES} lines behind", notice=True)
            elif self.writer is None:
                self.wake.notify()  # a reader waits in take(); an attached subscriber is flushed instead

    def attach(self, writer: Writer, on_drop: Callable[[], None] | None = None) -> None:
        """From now on the publisher sends this subscriber's lines with ``writer`` (flush), and
        calls ``on_drop`` (once, holding no other lock) when it drops the subscriber, so the
        connection's thread can sleep until then instead of polling."""
        with self.wake:
            self.writer, self.on_drop = writer, on_drop

    def _drop(self, reason: str, notice: bool) -> None:
        """Drop this subscriber (holding ``wake``): ``notice`` queues the 'dropped' line its
        connection's thread sends before closing."""
        self.dropped = reason
        if notice:
            self.lines.append(encode({"notify": "dropped", "error": reason}))
        self.wake.notify()
        if self.on_drop is not None:
            self.on_drop()

    def flush(self) -> None:
        """Send what waits (the publisher's thread; attached subscribers only): what the
        socket does not take now is kept for the next flush; a socket that keeps more than
        MAX_UNSENT_BYTES, or fails, drops the subscriber (its connection's thread sees it)."""
        with self.wake:
            if self.writer is None or self.dropped is not None or (not self.lines and not self.unsent):
                return  # a dropped client's notice is sent by its connection's thread
            data = self.unsent + b"".join(self.lines)
            self.lines.clear()
            try:
                sent = self.writer(data)
            except BlockingIOError:
                sent = 0
            except OSError as err:
                self.unsent = b""
                self._drop(f"connection lost: {err}", notice=False)
                return
            self.unsent = data[sent:]
            if sent:
                self.mid_line = data[sent - 1:sent] != b"\n"
            if len(self.unsent) > MAX_UNSENT_BYTES:  # keep only the rest of a line the socket took part of
                self.unsent = self.unsent[:self.unsent.find(b"\n") + 1] if self.mid_line else b""
                self._drop(f"client too slow: more than {MAX_UNSENT_BYTES} bytes unsent", notice=True)

    def take(self, timeout_s: float) -> list[bytes]:
        """The lines waiting now (after at most ``timeout_s``); empty when none came."""
        with self.wake:
            if not self.lines:
                self.wake.wait(timeout_s)
            lines = list(self.lines)
            self.lines.clear()
            return lines


class StatusHub:
    """Samples ``read_status`` for the subscribers and fans out status changes and events."""

    def __init__(self, read_status: StatusRead, clock: Callable[[], float] = time.monotonic,
                 wall_clock: Callable[[], float] = time.time, publisher_thread: bool = True,
                 read_fast: StatusRead | None = None, realtime_priority: int | None = None,
                 next_cycle_wake_s: Callable[[], float | None] | None = None, slack: CycleSlack | None = None) -> None:
        """``read_status``: the whole status, at once or in steps (fieldbus.cycle_slack).
        ``read_fast``: the fields of the status that move with the machine (the rest is
        read whole only after events and every FULL_READ_PERIOD_S; None: always whole).
        ``slack``: the cycle thread's slack, where the rounds' steps run while a cycle
        thread runs (fieldbus.cycle_slack; None: always in the publisher's thread).
        ``realtime_priority``: the publisher thread's SCHED_FIFO priority where allowed.
        ``next_cycle_wake_s``: ``time.perf_counter`` time the cycle thread wakes next (None:
        no cycle runs); the publisher's steps keep out of its way (between_steps).
        ``publisher_thread`` False: nothing publishes but ``publish_once`` calls (tests
        drive the hub step by step with an injected clock)."""
        self._read_status = read_status
        self._read_fast = read_fast
        self._realtime_priority = realtime_priority
        self._next_cycle_wake_s = next_cycle_wake_s
        self._slack = slack
        self._next_full_s = 0.0
        self._full_reads_due = 0  # an event was published: read the whole status this many rounds
        self._publisher_thread = publisher_thread
        self._clock = clock
        self._wall = wall_clock
        self._subscribers: list[Subscription] = []
        self._last: Status | None = None
        self._events: collections.deque[dict[str, Any]] = collections.deque(maxlen=MAX_PENDING_LINES)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ clients
    def subscribe(self, max_hz: float = DEFAULT_MAX_HZ) -> tuple[Subscription, Status]:
        """A new subscription and the full status it starts from."""
        status = run_steps(read_in_steps(self._read_status), self._slack, wait_s=SLACK_WAIT_S)
        sub = Subscription(period_s=1.0 / max_hz)
        with self._lock:
            self._subscribers.append(sub)
            if self._last is None:
                self._last = status
            sub.pending = status_changes(self._last, status)  # what moved since the shared sample
            sub.next_status_s = next_tick_s(self._clock(), sub.period_s)
            self._ensure_thread()
        self._wake.set()
        return sub, status

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subscribers:
                self._subscribers.remove(sub)
            if not self._subscribers:
                self._last = None  # the next subscriber starts from a fresh sample

    @property
    def subscribers(self) -> int:
        with self._lock:
            return len(self._subscribers)

    def publish_event(self, event: dict[str, Any]) -> None:
        """Queue an event for every subscriber (any thread; never blocks)."""
        if not self._subscribers:
            return
        self._events.append(event)
        self._wake.set()

    def close(self) -> None:
        self._stopping = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None

    # ------------------------------------------------------------------ publisher
    def _ensure_thread(self) -> None:
        if self._publisher_thread and (self._thread is None or not self._thread.is_alive()):
            self._thread = threading.Thread(target=self._run, name="status-publisher", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        if self._realtime_priority is not None:
            # never preempted by other work while it holds the interpreter lock the cycle
            # thread waits for (it only runs a few hundred µs per round: docs/web.md)
            policy = set_thread_realtime(self._realtime_priority, pin=False)
            log.debug(kv("status_publisher_policy", policy=policy, priority=self._realtime_priority))
        while not self._stopping:
            with self._lock:
                subscribers = list(self._subscribers)
            if not subscribers:
                self._wake.wait(1.0)
                self._wake.clear()
                continue
            now = self._clock()
            wait_s = min(max(s.next_status_s - now, 0.0) for s in subscribers)
            if wait_s > 0 and not self._events:
                self._wake.wait(wait_s)
            self._wake.clear()
            self.publish_once()

    def publish_once(self) -> None:
        """Send queued events, then the status changes of every subscriber that is due (or
        that an event just woke): one round (_round_steps). The publisher thread's step;
        tests call it directly. With a cycle thread running, its steps run in that thread's
        slack (fieldbus.cycle_slack) while this thread waits; else here, letting go of the
        interpreter lock between them and keeping out of the cycle thread's way (between_steps)."""
        run_steps(self._round_steps(), self._slack, lambda let_go: self.between_steps(let_go is not False),
                  SLACK_WAIT_S)

    def _round_steps(self) -> Steps[None]:
        """The round of publish_once in steps: it yields where the round may pause (False:
        before a send after the first, which lets go of the interpreter lock itself)."""
        with self._lock:
            subscribers = list(self._subscribers)
        if not subscribers:
            return
        yield True
        events = []
        while self._events:
            events.append(self._events.popleft())
        stamp = self._wall()
        for event in events:
            body = encode({"notify": "event", "t": stamp, **event})
            for sub in subscribers:
                sub.put(body)
        status = yield from self._sample(bool(events))
        yield True
        with self._lock:
            changes = status_changes(self._last, status)
            self._last = status
        if changes:
            yield True
        due_s = self._clock() + TICK_SLACK_S
        encoded: dict[int, bytes] = {}  # subscribers at one rate share their pending changes: encode once
        for sub in subscribers:
            if changes:
                sub.pending = merge_changes(sub.pending, changes) if sub.pending else changes
            if due_s < sub.next_status_s and not events:
                continue
            # due (or woken by an event): its next tick is after this one even when nothing
            # changed, so the publisher sleeps until then instead of going round again at once
            sub.next_status_s = next_tick_s(due_s, sub.period_s)
            if sub.pending:
                key = id(sub.pending)
                if key not in encoded:
                    encoded[key] = encode({"notify": "status", "t": stamp, "changes": sub.pending})
                sub.put(encoded[key])
                sub.pending = {}
        for i, sub in enumerate(subscribers):
            yield bool(encoded) and i == 0
            sub.flush()

    def between_steps(self, let_go: bool = True) -> None:
        """Between two steps of a round run in the publisher's thread: let go of the
        interpreter lock (``let_go``), and when the next step could still run when the cycle
        thread wakes, wait until just after that wake-up (wait_before_step_s)."""
        wake_s = self._next_cycle_wake_s() if self._next_cycle_wake_s is not None else None
        wait_s = wait_before_step_s(wake_s, time.perf_counter())
        if wait_s > 0.0 or let_go:
            time.sleep(wait_s)  # sleep(0) lets go of the lock too

    def _sample(self, after_event: bool) -> Steps[Status]:
        """The status now. Whole when there is no fast read, after an event (in this round
        and the next: a change is logged just before or after it is made) and every
        FULL_READ_PERIOD_S; otherwise the last sample with the fields that move with the
        machine read again (``read_fast``): the same values a ``status`` request gives, the
        rest at most FULL_READ_PERIOD_S old."""
        now = self._clock()
        if after_event:
            self._full_reads_due = FULL_READS_AFTER_EVENT
        last = self._last
        if self._read_fast is None or last is None or self._full_reads_due > 0 or now >= self._next_full_s:
            self._full_reads_due = max(0, self._full_reads_due - 1)
            self._next_full_s = now + FULL_READ_PERIOD_S
            return (yield from read_in_steps(self._read_status))
        fast = yield from read_in_steps(self._read_fast)
        return {**last, **fast}


def read_in_steps(read: StatusRead) -> Steps[Status]:
    """What ``read`` gives: a status at once, or its steps (fieldbus.cycle_slack) run one by one."""
    result = read()
    if isinstance(result, dict):
        return result
    return (yield from result)


def next_tick_s(now_s: float, period_s: float) -> float:
    """The next multiple of ``period_s`` after ``now_s`` (clock seconds): subscribers at one
    rate fall due together, so one status read serves them all (not one read per client
    at its own phase)."""
    return (math.floor(now_s / period_s + 1e-9) + 1) * period_s


def wait_before_step_s(wake_s: float | None, now_s: float) -> float:
    """How long the publisher sleeps before its next step (``time.perf_counter`` seconds):
    0 (``let_go``: only sleep(0)) when the cycle thread's next wake-up ``wake_s`` is at least
    STEP_ROOM_S away or unknown (None: no cycle loop); else until AFTER_WAKE_S after it. A
    wake-up already past means the cycle thread woke and waits for the lock the publisher
    holds (it moves ``wake_s`` on as soon as it has the lock): then too it sleeps
    AFTER_WAKE_S, for real. A sleep(0) hands the lock over to nobody: it signals the waiter,
    takes the lock back before the woken thread has run (tens of µs on a virtual machine),
    and the cycle thread gets it only when its wait reaches the switch interval (T/4), which
    is later than its 100 µs late threshold."""
    if wake_s is None:
        return 0.0
    ahead_s = wake_s - now_s
    return max(ahead_s, 0.0) + AFTER_WAKE_S if ahead_s < STEP_ROOM_S else 0.0


class EventLogHandler(logging.Handler):
    """Every record of the ``nurbsmotion`` loggers at INFO or above becomes a hub event."""

    def __init__(self, hub: StatusHub) -> None:
        super().__init__(logging.INFO)
        self.hub = hub

    def emit(self, record: logging.LogRecord) -> None:
        try:
            line = record.getMessage()
            name, fields = parse_kv(line)
            self.hub.publish_event({"event": name, "level": record.levelname, "logger": record.name,
                                    "fields": fields, "line": line, "logged_t": record.created})
        except Exception:  # noqa: BLE001 - logging must never raise into the caller
            self.handleError(record)


def attach_event_log(hub: StatusHub, logger_name: str = "nurbsmotion") -> Callable[[], None]:
    """Route the package's INFO+ log records to ``hub``; returns the function that detaches it."""
    return attach_handler(EventLogHandler(hub), logger_name)
