"""gc_clock: the time this process spends in garbage collections, from gc.callbacks."""

from __future__ import annotations

import gc

import pytest

from nurbsmotion.gc_clock import GcClock, process_gc_clock, process_gc_s


class Ticks:
    """A clock that moves by ``step_s`` at every read."""

    def __init__(self, step_s: float) -> None:
        self.now = 0.0
        self.step_s = step_s

    def __call__(self) -> float:
        self.now += self.step_s
        return self.now


def test_each_collection_adds_its_start_to_stop_time():
    clock = GcClock(Ticks(0.25))
    clock.on_gc("start", {"generation": 0})
    clock.on_gc("stop", {"generation": 0, "collected": 3, "uncollectable": 0})
    clock.on_gc("start", {"generation": 2})
    clock.on_gc("stop", {"generation": 2, "collected": 0, "uncollectable": 0})
    assert clock.total_s == pytest.approx(0.5)
    assert (clock.collections, clock.full_collections) == (2, 1)


def test_a_stop_without_its_start_is_not_counted():
    clock = GcClock(Ticks(1.0))
    clock.on_gc("stop", {"generation": 2})  # installed while a collection ran
    assert (clock.total_s, clock.collections) == (0.0, 0)


def test_installed_it_times_real_collections_and_removed_it_stops():
    clock = GcClock()
    clock.install()
    clock.install()  # once only
    try:
        assert gc.callbacks.count(clock.on_gc) == 1
        gc.collect()
        assert clock.full_collections == 1 and clock.total_s > 0.0
    finally:
        clock.remove()
    assert clock.on_gc not in gc.callbacks
    gc.collect()
    assert clock.full_collections == 1


def test_the_process_clock_is_one_and_counts():
    assert process_gc_clock() is process_gc_clock()
    before = process_gc_s()
    gc.collect()
    assert process_gc_s() > before
