"""fieldbus.cycle_slack: other threads' steps run by the cycle thread only where they fit
before its next wake-up; the master's cycle thread runs them (simulated drives)."""

from __future__ import annotations

import threading
from typing import Iterator

from nurbsmotion.fieldbus.cycle_slack import CycleSlack, run_steps, step_place
from nurbsmotion.steps import Steps
from tests.helpers import wait_for


class StepClock:
    """A clock each step moves on by ``step_s``."""

    def __init__(self, step_s: float) -> None:
        self.now = 0.0
        self.step_s = step_s

    def __call__(self) -> float:
        return self.now


def counted_steps(clock: StepClock, n: int, ran: list[int]) -> Iterator[None]:
    for i in range(n):
        ran.append(i)
        clock.now += clock.step_s
        yield


def test_steps_run_only_while_the_next_wake_up_is_at_least_the_room_away():
    clock = StepClock(step_s=100e-6)
    slack = CycleSlack(room_s=300e-6, clock=clock, budget_s=1.0)
    slack.start()
    ran: list[int] = []
    work = slack.submit(counted_steps(clock, 10, ran))
    assert work is not None
    slack.run(next_wake_s=clock.now + 550e-6)  # room at 0, 100 and 200 us: three steps, then 250 us left
    assert ran == [0, 1, 2] and not work.done.is_set()
    slack.run(next_wake_s=clock.now + 299e-6)  # less than the room: nothing
    assert ran == [0, 1, 2]
    slack.run(next_wake_s=clock.now + 10.0)
    assert ran == list(range(10)) and work.done.is_set() and work.error is None and not work.returned
    assert slack.steps_run == 11  # ten yields and the step that ends the generator
    assert slack.overruns == 0  # the third step ended 250 us before the wake-up


def test_steps_start_only_within_the_budget_after_the_slack_began():
    clock = StepClock(step_s=40e-6)
    slack = CycleSlack(room_s=300e-6, clock=clock, budget_s=100e-6)
    slack.start()
    ran: list[int] = []
    slack.submit(counted_steps(clock, 10, ran), bulk=True)
    slack.run(next_wake_s=clock.now + 1.0)  # steps start at 0, 40 and 80 us: the one at 120 us waits
    assert ran == [0, 1, 2]
    slack.run(next_wake_s=clock.now + 1.0)  # the next cycle's slack: a budget of its own
    assert ran == [0, 1, 2, 3, 4, 5]


def test_bulk_work_runs_only_when_no_other_work_is_queued():
    clock = StepClock(step_s=40e-6)
    slack = CycleSlack(room_s=300e-6, clock=clock, budget_s=100e-6)
    slack.start()
    files: list[int] = []
    answer: list[int] = []
    bulk = slack.submit(counted_steps(clock, 10, files), bulk=True)
    reply = slack.submit(counted_steps(clock, 4, answer))
    assert bulk is not None and reply is not None and bulk.bulk and not reply.bulk
    slack.run(next_wake_s=clock.now + 1.0)  # the answer's steps at 0, 40 and 80 us: the budget
    assert answer == [0, 1, 2] and files == []
    slack.run(next_wake_s=clock.now + 1.0)  # its last step and its end, then bulk at 40 and 80 us
    assert answer == [0, 1, 2, 3] and reply.done.is_set() and files == [0, 1]
    slack.run(next_wake_s=clock.now + 250e-6)  # the room too: nothing
    assert files == [0, 1]


def test_bulk_work_is_withdrawn_and_handed_back_like_other_work():
    slack = CycleSlack(clock=StepClock(step_s=0.0))
    slack.start()
    taken, kept = slack.submit(iter([None]), bulk=True), slack.submit(iter([None, None]), bulk=True)
    assert taken is not None and kept is not None
    assert slack.withdraw(taken) and not slack.withdraw(taken) and slack.withdrawn == 1
    slack.stop()
    assert kept.returned and kept.done.is_set() and not taken.done.is_set()


def test_a_step_that_ends_after_the_wake_up_is_counted_as_an_overrun():
    clock = StepClock(step_s=400e-6)  # longer than the room: a step that overran
    slack = CycleSlack(room_s=300e-6, clock=clock, budget_s=1.0)
    slack.start()
    ran: list[int] = []
    slack.submit(counted_steps(clock, 3, ran))
    slack.run(next_wake_s=clock.now + 350e-6)
    assert ran == [0] and slack.overruns == 1
    slack.run(next_wake_s=clock.now + 10.0)
    assert ran == [0, 1, 2] and slack.overruns == 1 and slack.steps_run == 4
    assert slack.overrun_places == {f"counted_steps:{YIELD_LINE}": 1}  # the step that ended at the first yield


YIELD_LINE = counted_steps.__code__.co_firstlineno + 4  # counted_steps' yield


def outer_steps(clock: StepClock, ran: list[int]) -> Iterator[None]:
    yield from counted_steps(clock, 1, ran)


def test_an_overrun_is_placed_at_the_innermost_generators_yield_or_end():
    clock = StepClock(step_s=400e-6)
    slack = CycleSlack(room_s=300e-6, clock=clock)
    slack.start()
    slack.submit(outer_steps(clock, []))
    slack.run(next_wake_s=clock.now + 350e-6)  # through yield from: counted_steps' yield
    assert slack.overruns == 1 and slack.overrun_places == {f"counted_steps:{YIELD_LINE}": 1}
    ended = outer_steps(clock, [])
    list(ended)
    assert step_place(ended) == "outer_steps:end"


def test_queued_works_take_turns_step_by_step():
    clock = StepClock(step_s=0.0)
    slack = CycleSlack(clock=clock)
    slack.start()
    ran: list[tuple[str, int]] = []

    def named(name: str, n: int) -> Iterator[None]:
        for i in range(n):
            ran.append((name, i))
            yield

    long, short = slack.submit(named("long", 4)), slack.submit(named("short", 2))
    assert long is not None and short is not None
    slack.run(next_wake_s=1.0)
    assert ran == [("long", 0), ("short", 0), ("long", 1), ("short", 1), ("long", 2), ("long", 3)]
    assert long.done.is_set() and short.done.is_set() and (long.steps_run, short.steps_run) == (4, 2)


def test_a_raising_step_ends_only_its_own_work():
    clock = StepClock(step_s=0.0)
    slack = CycleSlack(clock=clock)
    slack.start()

    def failing() -> Iterator[None]:
        yield
        raise ValueError("a bug in the publisher")

    ran: list[int] = []
    bad, good = slack.submit(failing()), slack.submit(counted_steps(clock, 2, ran))
    assert bad is not None and good is not None
    slack.run(next_wake_s=1.0)
    assert isinstance(bad.error, ValueError) and bad.done.is_set()
    assert ran == [0, 1] and good.done.is_set() and good.error is None


def test_no_cycle_thread_refuses_work_and_its_end_hands_back_what_is_queued():
    slack = CycleSlack()
    assert slack.submit(iter(())) is None  # not started: the submitter runs it itself
    slack.start()
    work = slack.submit(iter([None, None]))
    assert work is not None
    slack.stop()
    assert work.done.is_set() and work.returned and work.error is None
    assert slack.submit(iter(())) is None


def test_work_withdrawn_before_the_cycle_thread_took_it_is_the_submitters_again():
    clock = StepClock(step_s=0.0)
    slack = CycleSlack(clock=clock)
    slack.start()
    ran: list[int] = []
    steps = counted_steps(clock, 3, ran)
    work = slack.submit(steps)
    assert work is not None
    slack.run(next_wake_s=0.0)  # no room
    assert slack.withdraw(work)
    slack.run(next_wake_s=1.0)
    assert ran == [] and not work.done.is_set()
    assert list(steps) == [None, None, None]  # the rest runs where the submitter wants
    assert not slack.withdraw(work)


def test_the_masters_cycle_thread_runs_the_steps_against_its_next_wake_up(monkeypatch):
    from tests.fieldbus.test_master_sim import rig

    with rig() as (master, _, _):
        slack = master.cycle_slack
        wait_for(lambda: slack.open, what="the cycle thread accepting work")
        run, given = slack.run, []
        monkeypatch.setattr(slack, "run", lambda next_wake_s: given.append(next_wake_s) or run(next_wake_s))
        seen: list[tuple[str, float | None, float]] = []

        def steps() -> Iterator[None]:
            for _ in range(50):
                seen.append((threading.current_thread().name, master.next_cycle_wake_s(), given[-1]))
                yield

        work = slack.submit(steps())
        assert work is not None
        assert work.done.wait(30.0) and work.error is None and not work.returned
        assert {name for name, _, _ in seen} == {"nurbsmotion-cycle"}
        # the room is judged against the writer's next wake-up, the one the cycle thread sleeps for
        assert all(wake_s == judged_s for _, wake_s, judged_s in seen)
        assert slack.steps_run == 51
    assert not slack.open  # the cycle thread ended: work is refused again


def test_run_steps_returns_the_result_from_the_cycle_thread_or_from_here():
    def answer() -> Steps[tuple[str, str]]:
        first = threading.current_thread().name
        yield None
        return first, threading.current_thread().name

    assert run_steps(answer()) == ("MainThread", "MainThread")  # no slack: here
    slack = CycleSlack()
    slack.start()
    stop = threading.Event()

    def cycle() -> None:
        while not stop.wait(1e-3):
            slack.run(float("inf"))

    thread = threading.Thread(target=cycle, name="nurbsmotion-cycle")
    thread.start()
    try:
        assert run_steps(answer(), slack, wait_s=30.0) == ("nurbsmotion-cycle", "nurbsmotion-cycle")
    finally:
        stop.set()
        thread.join()
    between: list[object] = []
    assert run_steps(answer(), slack, between.append, wait_s=0.0) == ("MainThread", "MainThread")  # no room
    assert between == [None] and slack.withdrawn == 1


def test_run_steps_waits_while_the_cycle_thread_makes_progress_and_takes_back_work_that_makes_none():
    clock = StepClock(step_s=0.0)
    slack = CycleSlack(room_s=0.0, clock=lambda: clock.now)
    slack.start()
    stop, paused = threading.Event(), threading.Event()

    def one_step_a_millisecond() -> None:  # the slack of a busy cycle
        while not stop.wait(1e-3):
            if not paused.is_set():
                clock.now += 1.0
                slack.run(next_wake_s=clock.now)  # room for one step: then the wake-up is reached
                clock.now += 1.0

    def names(n: int) -> Steps[set[str]]:
        seen = set()
        for _ in range(n):
            seen.add(threading.current_thread().name)
            clock.now += 0.5
            yield None
        return seen

    thread = threading.Thread(target=one_step_a_millisecond, name="nurbsmotion-cycle")
    thread.start()
    try:
        # 400 steps at about one a millisecond outlast the 0.2 s wait: progress keeps the work there
        assert run_steps(names(400), slack, wait_s=0.2) == {"nurbsmotion-cycle"}
        assert slack.withdrawn == 0
        paused.set()  # an overloaded cycle: no step for the wait, so the work comes back here
        assert run_steps(names(3), slack, wait_s=0.2) == {"MainThread"}
        assert slack.withdrawn == 1
    finally:
        stop.set()
        thread.join()
